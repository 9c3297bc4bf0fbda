"""Mission splits of the ground-truth maps: disjoint train / test scenes and stars, their 8 transforms,
determinism, caching, and the unchanged "paper" split."""

from __future__ import annotations

import hashlib
import inspect
import itertools
import time

import cv2
import numpy as np
import pytest

from uav_ipp.maps import (
    ENV1_SEED_RANGES,
    SCENES,
    SPLITS,
    TRANSFORMS,
    MapError,
    block_fraction,
    block_index,
    build_shipped_maps,
    dihedral,
    load_ground_truth,
    scene_count,
    shipped,
    split_scenes,
)
from uav_ipp.maps.scenes import SOURCE_SHAPES, SPLIT_GAP, pick

FAMILIES = ("env2", "env3")
STARTS = [(2, 2), (8, 2), (8, 8), (2, 8)]  # default start columns, lattice (x, y)
SPLIT_PAIRS = [(f, s) for f in FAMILIES for s in ("train", "test")]


def _missions(name: str, split: str, **kwargs):
    """Every mission of a split, seed = scene index + n * transform: {(scene, transform): truth}."""
    n = scene_count(name, split)
    return {
        (i, t): load_ground_truth(name, seed=i + n * t, split=split, **kwargs)
        for i in range(n)
        for t in range(len(TRANSFORMS))
    }


# ------------------------------------------------------------------ the catalogue
def test_split_constants_and_counts():
    assert SPLITS == ("paper", "train", "test")
    assert inspect.signature(load_ground_truth).parameters["split"].default == "paper"
    for name in FAMILIES:
        assert scene_count(name, "paper") == 1
        assert scene_count(name, "train") >= 8 and scene_count(name, "test") >= 8  # verdicts rest on many scenes
        assert scene_count(name.upper(), " Train ") == scene_count(name, "train")
    assert (scene_count("env2", "train"), scene_count("env2", "test")) == (9, 8)
    assert (scene_count("env3", "train"), scene_count("env3", "test")) == (12, 9)
    assert scene_count("env1", "train") == scene_count("env1", "test") == 1_000_000_000
    assert len(TRANSFORMS) == len(set(TRANSFORMS)) == 8
    with pytest.raises(MapError, match="env7"):
        scene_count("env7", "train")
    with pytest.raises(MapError, match="split='val'"):
        scene_count("env2", "val")


def test_paper_scene_is_train_and_matches_the_build_constants():
    papers = [s for s in SCENES if s.is_paper]
    assert sorted(s.family for s in papers) == ["env2", "env3"]
    assert all(s.split == "train" and split_scenes(s.family, "train")[0] is s for s in papers)
    by_family = {s.family: s for s in papers}
    assert (by_family["env2"].rows, by_family["env2"].cols) == ((463, 603), (243, 383))
    assert (by_family["env3"].rows, by_family["env3"].cols) == ((420, 913), (0, 493))
    assert (build_shipped_maps.THERMAL_ROWS, build_shipped_maps.THERMAL_COLS) == ((463, 603), (243, 383))
    assert (build_shipped_maps.SATELLITE_ROWS, build_shipped_maps.SATELLITE_COLS) == ((420, 913), (0, 493))


def _gap(a, b) -> int:
    """Chebyshev gap (pixels) between two half-open rectangles; negative when they overlap."""
    row_gap = max(a.rows[0], b.rows[0]) - min(a.rows[1], b.rows[1])
    col_gap = max(a.cols[0], b.cols[0]) - min(a.cols[1], b.cols[1])
    return max(row_gap, col_gap)


@pytest.mark.parametrize("family", FAMILIES)
def test_crops_are_square_inside_the_source_and_never_overlap(family):
    scenes = [s for s in SCENES if s.family == family]
    rows, cols = SOURCE_SHAPES[family]
    assert len({s.key for s in scenes}) == len(scenes)
    for s in scenes:
        assert s.split in ("train", "test")
        assert 0 <= s.rows[0] < s.rows[1] <= rows and 0 <= s.cols[0] < s.cols[1] <= cols, s
        assert s.rows[1] - s.rows[0] == s.cols[1] - s.cols[0], s  # the field is square
        if not s.is_paper:  # one crop size per family, so train and test scenes share a ground scale
            assert s.side_px == {"env2": 48, "env3": 240}[family], s
    for a, b in itertools.combinations(scenes, 2):
        assert _gap(a, b) >= 0, (a.key, b.key)  # no two crops share a pixel
    for a in split_scenes(family, "train"):
        for b in split_scenes(family, "test"):
            assert _gap(a, b) >= SPLIT_GAP[family], (a.key, b.key)


def test_shipped_scene_files_exist_and_stay_small():
    files = [f for s in SCENES for f in s.files]
    assert len(files) == len(set(files))
    sizes = [(shipped.DATA_DIR / f).stat().st_size for f in files]
    assert all(size > 0 for size in sizes)
    assert sum(sizes) < 600_000
    assert {p.name for p in shipped.DATA_DIR.glob("*.png")} == set(files) | {
        shipped.ENV2_FILE,
        shipped.ENV3_RGB_FILE,
        shipped.ENV3_NIR_FILE,
        shipped.ENV3_BUILTUP_FILE,
    }


def test_env1_seed_ranges_are_disjoint():
    ranges = sorted(ENV1_SEED_RANGES.values())
    assert ranges[0] == (0, 1_000_000)
    assert all(a[1] <= b[0] for a, b in itertools.pairwise(ranges))
    assert ranges[-1][1] <= 2**32
    for split in ("train", "test"):
        start, stop = ENV1_SEED_RANGES[split]
        for seed in (0, 7, stop - start + 7, 2**40 + 3):
            star_seed = int(load_ground_truth("env1", seed=seed, split=split).name.rsplit("star", 1)[1])
            assert start <= star_seed < stop and star_seed == start + seed % (stop - start)


# ------------------------------------------------------------------ transforms
def test_dihedral_is_the_square_group():
    a = np.arange(12).reshape(3, 4)
    expected = [a, np.rot90(a), np.rot90(a, 2), np.rot90(a, 3), a.T, a[::-1], a[::-1, ::-1].T, a[:, ::-1]]
    for t, e in enumerate(expected):
        np.testing.assert_array_equal(dihedral(a, t), e, err_msg=TRANSFORMS[t])
    sq = np.random.default_rng(0).random((5, 5))
    images = [dihedral(sq, t) for t in range(8)]
    assert len({im.tobytes() for im in images}) == 8
    for t, u in itertools.product(range(8), repeat=2):  # closed under composition
        assert any(np.array_equal(dihedral(dihedral(sq, t), u), im) for im in images)
    with pytest.raises(MapError, match="8"):
        dihedral(sq, 8)


def test_pick_cycles_scenes_then_transforms():
    assert [pick(s, 3) for s in range(7)] == [(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (2, 1), (0, 2)]
    assert sorted(pick(s, 3) for s in range(24)) == sorted(itertools.product(range(3), range(8)))
    assert pick(24, 3) == pick(0, 3)


@pytest.mark.parametrize("grid,lattice", [(493, 11), (100, 6)])
def test_blocks_are_mirror_symmetric(grid, lattice):
    k = block_index(grid, lattice)
    np.testing.assert_array_equal(k[::-1], lattice - 1 - k)


@pytest.mark.parametrize("grid,lattice", [(493, 11), (100, 6)])
@pytest.mark.parametrize("split", ["train", "test"])
def test_no_fly_transforms_with_the_valuable_mask(split, grid, lattice):
    """Transforming the cells and recomputing the block no-fly equals transforming the lattice mask."""
    n = scene_count("env3", split)
    for i, scene in enumerate(split_scenes("env3", split)):
        if scene.is_paper:
            built = shipped.env3_builtup(grid)
        else:
            built = shipped.env3_scene_masks(scene.files[0], scene.files[1], grid)[1]
        base = load_ground_truth("env3", seed=i, split=split, grid=grid, lattice=lattice)
        np.testing.assert_array_equal(base.no_fly, block_fraction(built, lattice) > shipped.ENV3_NO_FLY_FRACTION)
        for t in range(8):
            truth = load_ground_truth("env3", seed=i + n * t, split=split, grid=grid, lattice=lattice)
            np.testing.assert_array_equal(truth.valuable, dihedral(base.valuable, t))
            recomputed = block_fraction(dihedral(built, t), lattice) > shipped.ENV3_NO_FLY_FRACTION
            np.testing.assert_array_equal(truth.no_fly, recomputed)
            np.testing.assert_array_equal(truth.no_fly, dihedral(base.no_fly, t), err_msg=f"{scene.key} {t}")


# ------------------------------------------------------------------ disjointness of the missions
@pytest.mark.parametrize("family", FAMILIES)
def test_no_test_mask_equals_any_train_mask_under_any_transform(family):
    train = [m.valuable for (_, t), m in _missions(family, "train").items() if t == 0]
    test = [m.valuable for (_, t), m in _missions(family, "test").items() if t == 0]
    for a in test:
        for b in train:
            for t in range(8):
                image = dihedral(b, t)
                assert not np.array_equal(a, image)
                assert (a != image).mean() > 0.1  # not even nearly equal


def test_env1_train_and_test_stars_differ_from_each_other_and_from_paper():
    for seed in range(5):
        stars = [load_ground_truth("env1", seed=seed, split=s).valuable for s in SPLITS]
        for a, b in itertools.combinations(stars, 2):
            assert (a != b).mean() > 0.05


# ------------------------------------------------------------------ determinism and variety
@pytest.mark.parametrize("name,split", [*SPLIT_PAIRS, ("env1", "train"), ("env1", "test")])
def test_same_seed_same_map(name, split):
    for seed in (0, 5, 123_456_789, 2**31 - 2):
        a = load_ground_truth(name, seed=seed, split=split)
        b = load_ground_truth(name, seed=np.int64(seed), split=split.upper())
        assert a.name == b.name and a.source == b.source
        np.testing.assert_array_equal(a.valuable, b.valuable)
        np.testing.assert_array_equal(a.no_fly, b.no_fly)
        assert not a.valuable.flags.writeable and not a.no_fly.flags.writeable


@pytest.mark.parametrize("name,split", SPLIT_PAIRS)
def test_different_seeds_give_every_mission_once(name, split):
    missions = _missions(name, split)
    assert len(missions) == 8 * scene_count(name, split)
    assert len({m.name for m in missions.values()}) == len(missions)
    digests = {hashlib.sha256(np.packbits(m.valuable).tobytes()).hexdigest() for m in missions.values()}
    assert len(digests) == len(missions)  # no scene is symmetric
    for (i, t), m in missions.items():
        scene = split_scenes(name, split)[i]
        assert m.name == f"{name}/{split}/{scene.key}/{TRANSFORMS[t]}"
        assert scene.key in m.source and TRANSFORMS[t] in m.source and scene.crop in m.source
        assert "\n" not in m.source


def test_env1_different_seeds_different_stars():
    stars = [load_ground_truth("env1", seed=s, split="train").valuable for s in range(6)]
    assert all((a != b).mean() > 0.05 for a, b in itertools.combinations(stars, 2))


def test_seed_none_draws_a_replayable_mission():
    seen = set()
    for _ in range(12):
        truth = load_ground_truth("env3", seed=None, split="train")
        drawn = int(truth.source.rsplit("drew ", 1)[1].rstrip(")"))
        replay = load_ground_truth("env3", seed=drawn, split="train")
        assert replay.name == truth.name
        np.testing.assert_array_equal(replay.valuable, truth.valuable)
        seen.add(truth.name)
    assert len(seen) > 1
    assert (
        load_ground_truth("env1", seed=None, split="test").valuable
        != load_ground_truth("env1", seed=None, split="test").valuable
    ).any()


# ------------------------------------------------------------------ every scene is a usable mission
@pytest.mark.parametrize("name,split", SPLIT_PAIRS)
def test_every_scene_has_a_reasonable_fraction_and_room_for_8_uavs(name, split):
    for m in _missions(name, split).values():
        assert m.valuable.shape == (493, 493) and m.valuable.dtype == np.bool_
        assert m.no_fly.shape == (11, 11) and m.no_fly.dtype == np.bool_
        assert 0.10 <= m.valuable.mean() <= 0.60, m.name
        assert int((~m.no_fly).sum()) >= 8, m.name
        assert m.no_fly.mean() <= 0.2, m.name
        assert not any(m.no_fly[y, x] for x, y in STARTS), m.name  # start="fixed" works everywhere
        n_parts, _ = cv2.connectedComponents((~m.no_fly).astype(np.uint8), connectivity=4)
        assert n_parts - 1 == 1, m.name  # no UAV is ever walled in


def test_other_grid_and_lattice():
    for name, split in SPLIT_PAIRS:
        for i in range(scene_count(name, split)):
            m = load_ground_truth(name, seed=i + 3 * scene_count(name, split), split=split, grid=100, lattice=6)
            assert m.valuable.shape == (100, 100) and m.no_fly.shape == (6, 6)
            assert 0.10 <= m.valuable.mean() <= 0.60, m.name


def test_env2_rules_apply_to_every_scene():
    for split in ("train", "test"):
        for i in range(scene_count("env2", split)):
            m = load_ground_truth("env2", seed=i, split=split, valuable="hottest:0.1")
            assert m.valuable.mean() == pytest.approx(0.1, abs=0.01) and "hottest:0.1" in m.source


def test_train_seed_0_is_the_paper_map():
    for name in FAMILIES:
        paper, train = load_ground_truth(name), load_ground_truth(name, seed=0, split="train")
        np.testing.assert_array_equal(train.valuable, paper.valuable)
        np.testing.assert_array_equal(train.no_fly, paper.no_fly)
        assert train.name == f"{name}/train/paper/identity"


# ------------------------------------------------------------------ errors
@pytest.mark.parametrize("split", ["val", "", "validation", None, 3, ("train",)])
def test_bad_split_raises_map_error_naming_it(split):
    with pytest.raises(MapError, match=r"split=.*allowed splits: \['paper', 'train', 'test'\]") as info:
        load_ground_truth("env2", split=split)
    assert repr(split) in str(info.value)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"name": "env3", "split": "train", "valuable": "excess-green"}, "excess-green.*split='train'"),
        ({"name": "env3", "split": "test", "valuable": "ndvi:0.3"}, "ndvi:0.3.*ndvi:0.5"),
        ({"name": "env2", "split": "train", "valuable": "ndvi"}, "near-infrared"),
        ({"name": "env2", "split": "train", "seed": -1}, "seed=-1"),
        ({"name": "env3", "split": "test", "seed": "abc"}, "seed='abc'"),
        ({"name": "env1", "split": "train", "seed": 1.5}, "seed=1.5"),
        ({"name": "env1", "split": "test", "map_path": "/tmp/x.png"}, "split='test'.*map_path"),
    ],
)
def test_bad_split_inputs(kwargs, match):
    with pytest.raises(MapError, match=match):
        load_ground_truth(**kwargs)


def test_env3_default_rule_spelled_out_is_accepted():
    a = load_ground_truth("env3", seed=9, split="test")
    for rule in ("ndvi", "ndvi:0.5", " NDVI:0.50 "):
        np.testing.assert_array_equal(
            load_ground_truth("env3", seed=9, split="test", valuable=rule).valuable, a.valuable
        )


# ------------------------------------------------------------------ the paper split is today's loader
#: sha256 (first 16 hex digits) of valuable + no-fly + shapes + name + source of the loader before
#: splits existed (commit 6e6dad8), for calls that now default to split="paper".
PAPER_FINGERPRINTS = [
    ("env1", {"seed": 0}, "d08946d712e716ba"),
    ("env1", {"seed": 7}, "9f1b68a71a6e8b83"),
    ("env1", {"seed": 123456}, "738125e3479ec5d2"),
    ("env1", {"seed": 3, "valuable": "threshold:0.5"}, "d8622abcaf3a965c"),
    ("env2", {}, "d1ff4f837e05acf4"),
    ("env2", {"valuable": "hottest:0.1"}, "5b519d6af615d880"),
    ("env2", {"grid": 100, "lattice": 6}, "75045f420d9c314b"),
    ("env3", {}, "1811336b2f9a4aec"),
    ("env3", {"valuable": "excess-green"}, "19ed04bef7e27a8e"),
    ("env3", {"grid": 100, "lattice": 6}, "ba49930848a2e033"),
    ("env3", {"seed": 5}, "1811336b2f9a4aec"),
]


def _fingerprint(g) -> str:
    payload = (
        np.packbits(g.valuable).tobytes()
        + np.packbits(g.no_fly).tobytes()
        + repr((g.valuable.shape, g.no_fly.shape, g.name, g.source)).encode()
    )
    return hashlib.sha256(payload).hexdigest()[:16]


@pytest.mark.parametrize("name,kwargs,digest", PAPER_FINGERPRINTS)
def test_paper_split_is_unchanged(name, kwargs, digest):
    assert _fingerprint(load_ground_truth(name, **kwargs)) == digest
    assert _fingerprint(load_ground_truth(name, split="paper", **kwargs)) == digest
    assert _fingerprint(load_ground_truth(name, split=" PAPER ", **kwargs)) == digest


# ------------------------------------------------------------------ the env's call, cached
def test_env_call_signature_works_and_is_cached():
    call = {"map_path": None, "valuable": None, "grid": 493, "lattice": 11}
    for name, split in SPLIT_PAIRS:
        first = load_ground_truth(name, seed=17, split=split, **call)
        assert load_ground_truth(name, seed=17, split=split, **call) is first  # one shared, read-only truth
    _missions("env3", "train")  # warm every mission
    t0 = time.perf_counter()
    for seed in range(4000):
        load_ground_truth("env3", seed=seed, split="train", **call)
    assert (time.perf_counter() - t0) / 4000 < 1e-4  # well under 0.1 ms a reset
