"""The wheel holds every data file the code opens at run time.

The files are enumerated from the code's own path constants and registries (the shipped maps'
names in ``uav_ipp.maps.shipped`` and the scene catalogue, the PROVENANCE checksum lists, the
``models.json`` manifest, the SenDFuse weights' checksum table, the user-map crops, the default zoo
config), never from a hand-typed list, so a new data file the code reads but ``setup.cfg``'s
``package_data`` / ``data_files`` forgets fails here instead of in a user's install. The wheel is
built once per module from a copy of the checkout (nothing is written into the repository).
"""

from __future__ import annotations

import configparser
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from sb3_coma.app import pretrained
from sb3_coma.app.config import default_config_path
from sb3_coma.experiments import user_maps
from sb3_coma.experiments.marl_benchmark import TRAINED
from sb3_coma.sendfuse import weights
from uav_ipp.maps import build_shipped_maps, scenes, shipped

REPO = Path(__file__).resolve().parents[1]
SETUP_CFG = configparser.ConfigParser()
SETUP_CFG.read(REPO / "setup.cfg")
#: Source folder -> installed package of setup.cfg's ``package_dir`` (``envs`` -> ``uav_ipp``).
PACKAGE_DIR = {
    src.strip(): pkg.strip()
    for pkg, _, src in (
        line.partition("=") for line in SETUP_CFG["options"]["package_dir"].splitlines() if line.strip()
    )
}
#: Files of setup.cfg's ``data_files`` (relative to the checkout) -> their folder under ``<name>.data/data``.
DATA_FILES = {f.strip(): target for target, files in SETUP_CFG["options.data_files"].items() for f in files.split(",")}
#: Top-level source folders of the packages (``sb3_coma`` and the world's ``envs``).
PACKAGE_ROOTS = ("sb3_coma", *PACKAGE_DIR)


def _runtime_files() -> dict[str, list[Path]]:
    """Every data file the code opens at run time, by category, as the code names it."""
    maps = [shipped.DATA_DIR / f for f in (shipped.ENV2_FILE, shipped.ENV3_RGB_FILE, shipped.ENV3_NIR_FILE)]
    maps.append(shipped.DATA_DIR / shipped.ENV3_BUILTUP_FILE)
    maps += [shipped.DATA_DIR / f for scene in scenes.SCENES for f in scene.files]
    maps += [shipped.DATA_DIR / f for f in build_shipped_maps.recorded_checksums()]
    maps.append(build_shipped_maps.PROVENANCE)

    folder = pretrained.pretrained_dir()
    manifest = pretrained.read_manifest()
    models = [folder / pretrained.MANIFEST] + [folder / entry["file"] for entry in manifest["models"].values()]
    sendfuse = [weights.default_weights_path(grid) for grid in weights.SHIPPED_SHA256]
    sendfuse.append(weights.default_weights_path())

    user_provenance = user_maps.IMAGE_DIR / "PROVENANCE.md"
    user = list(user_maps.images())
    user += [user_maps.IMAGE_DIR / f for f in build_shipped_maps.recorded_checksums(user_provenance)]
    user.append(user_provenance)

    found = {
        "shipped maps": maps,
        "shipped models (models.json)": models,
        "SenDFuse weights": sendfuse,
        "user-map images": user,
        "default zoo config": [default_config_path()],
        "learner benchmark configs": [default_config_path(f"marl/{learner}.yml") for learner in TRAINED],
    }
    return {category: sorted({p.resolve() for p in paths}) for category, paths in found.items()}


def _installed_path(path: Path, data_dir: str) -> str:
    """Where a checkout file lands in the wheel: ``sb3_coma/...``, ``uav_ipp/...`` for ``envs/...``,
    ``<name>.data/data/<target>/<file>`` for a ``data_files`` entry."""
    try:
        rel = path.resolve().relative_to(REPO)
    except ValueError:
        pytest.fail(f"{path} is not in the checkout {REPO}: run this test against the editable install")
    if rel.as_posix() in DATA_FILES:
        return f"{data_dir}/data/{DATA_FILES[rel.as_posix()]}/{rel.name}"
    top, *rest = rel.parts
    assert top in PACKAGE_ROOTS, f"{rel} is outside the package folders {PACKAGE_ROOTS}"
    return "/".join([PACKAGE_DIR.get(top, top), *rest])


RUNTIME_FILES = _runtime_files()


@pytest.mark.parametrize("category", sorted(RUNTIME_FILES))
def test_every_runtime_data_file_is_in_the_checkout(category):
    paths = RUNTIME_FILES[category]
    assert paths, f"{category}: the code names no file (the check would pass vacuously)"
    missing = [str(p) for p in paths if not p.is_file()]
    assert not missing, f"{category}: named by the code but missing: {missing}"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> tuple[set[str], str]:
    """(member names, ``<name>.data`` folder) of a wheel built from a copy of the checkout."""
    src = tmp_path_factory.mktemp("src") / "sb3-coma"
    junk = ("build", "dist", "*.egg-info", "__pycache__", ".*cache", ".git", ".hypothesis", ".benchmarks")
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(*junk), symlinks=True)
    out = tmp_path_factory.mktemp("wheel")
    cmd = [sys.executable, "-m", "pip", "wheel", str(src), "--no-deps", "--no-build-isolation", "--no-index", "-q"]
    done = subprocess.run([*cmd, "-w", str(out)], capture_output=True, text=True, cwd=out)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    (whl,) = out.glob("*.whl")
    name, version = whl.name.split("-")[:2]
    with zipfile.ZipFile(whl) as zf:
        return set(zf.namelist()), f"{name}-{version}.data"


def test_the_wheel_holds_every_runtime_data_file(wheel):
    names, data_dir = wheel
    missing = {
        category: [_installed_path(p, data_dir) for p in paths if _installed_path(p, data_dir) not in names]
        for category, paths in RUNTIME_FILES.items()
    }
    assert not any(missing.values()), f"not in the wheel: { {k: v for k, v in missing.items() if v} }"


def test_the_wheel_holds_every_package_and_no_envs_package(wheel):
    names, _ = wheel
    folders = sorted(
        {p.parent for root in PACKAGE_ROOTS for p in (REPO / root).rglob("*.py") if "__pycache__" not in p.parts}
    )
    assert len(folders) > len(PACKAGE_ROOTS)
    missing = [init for init in (_installed_path(f / "__init__.py", "") for f in folders) if init not in names]
    assert not missing, f"package folders without their __init__.py in the wheel: {missing}"
    assert not [n for n in names if n.startswith("envs/")], "the source folder envs/ went into the wheel as a package"
