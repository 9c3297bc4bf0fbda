"""Ground-truth maps: shipped images, the synthetic star, user images and their rules."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from envs.maps import MapError, available_maps, block_fraction, load_ground_truth


@pytest.mark.parametrize("name", available_maps())
def test_shipped_maps_shapes_and_fractions(name):
    g = load_ground_truth(name)
    assert g.valuable.shape == (493, 493) and g.valuable.dtype == bool
    assert g.no_fly.shape == (11, 11) and g.no_fly.dtype == bool
    assert 0.15 <= g.valuable.mean() <= 0.5
    assert g.source


def test_env3_no_fly_columns_and_free_starts():
    g = load_ground_truth("env3")
    assert 0.05 <= g.no_fly.mean() <= 0.2
    for x, y in [(2, 2), (8, 2), (8, 8), (2, 8)]:
        assert not g.no_fly[y, x]


def test_env1_seeded_star():
    a, b, c = (load_ground_truth("env1", seed=s).valuable for s in (3, 3, 4))
    np.testing.assert_array_equal(a, b)
    assert (a != c).mean() > 0.05
    fractions = [load_ground_truth("env1", seed=s).valuable.mean() for s in range(20)]
    assert 0.18 <= min(fractions) and max(fractions) <= 0.4


def test_grid_and_lattice_sizes():
    g = load_ground_truth("env3", grid=100, lattice=6)
    assert g.valuable.shape == (100, 100) and g.no_fly.shape == (6, 6)


def test_block_fraction_of_full_mask_is_one():
    np.testing.assert_allclose(block_fraction(np.ones((493, 493), bool), 11), 1.0)


@pytest.fixture
def images(tmp_path):
    gray = np.tile(np.linspace(0, 255, 64, dtype=np.uint8), (64, 1))
    colour = np.zeros((64, 64, 3), np.uint8)
    colour[:, :32] = (40, 200, 40)     # green (BGR)
    colour[:, 32:] = (128, 128, 128)   # grey
    paths = {}
    for name, img in (("gray.png", gray), ("colour.png", colour)):
        paths[name] = tmp_path / name
        cv2.imwrite(str(paths[name]), img)
    return paths


@pytest.mark.parametrize("rule,expected", [
    ("threshold:0.5", 0.5), ("dark:0.25", 0.25), ("hottest:0.3", 0.3), ("coldest:0.2", 0.2), (None, 0.5),
])
def test_user_image_gray_rules(images, rule, expected):
    g = load_ground_truth("mine", map_path=images["gray.png"], valuable=rule, grid=64, lattice=5)
    assert g.name == "mine"
    assert g.valuable.mean() == pytest.approx(expected, abs=0.04)


def test_user_image_excess_green(images):
    g = load_ground_truth("veg", map_path=images["colour.png"], valuable="excess-green", grid=64, lattice=5)
    assert g.valuable[:, :30].all() and not g.valuable[:, 34:].any()


@pytest.mark.parametrize("kwargs,match", [
    ({"name": "env7"}, "env7"),
    ({"map_path": "/nonexistent/map.png"}, "does not exist"),
    ({"valuable": "hottest:abc", "name": "env2"}, "abc"),
    ({"valuable": "hottest:1.5", "name": "env2"}, "fraction"),
    ({"valuable": "magic", "name": "env2"}, "magic"),
    ({"valuable": "hottest", "name": "env2"}, "fraction"),
    ({"lattice": 1}, "lattice"),
    ({"grid": 5}, "grid"),
    ({"seed": -1}, "seed"),
])
def test_bad_inputs(kwargs, match):
    with pytest.raises(MapError, match=match):
        load_ground_truth(**{"name": "env1", **kwargs})


def test_unreadable_and_empty_images(tmp_path, images):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image at all")
    with pytest.raises(MapError, match="not a readable image"):
        load_ground_truth("x", map_path=bad)
    with pytest.raises(MapError, match="directory"):
        load_ground_truth("x", map_path=tmp_path)
    flat = tmp_path / "flat.png"
    cv2.imwrite(str(flat), np.full((10, 10), 255, np.uint8))
    with pytest.raises(MapError, match="every cell"):
        load_ground_truth("x", map_path=flat, valuable="threshold:0.1", grid=10, lattice=2)
    with pytest.raises(MapError, match="no cell"):
        load_ground_truth("x", map_path=flat, valuable="dark:0.5", grid=10, lattice=2)
    with pytest.raises(MapError, match="colour"):
        load_ground_truth("x", map_path=images["gray.png"], valuable="excess-green", grid=64, lattice=5)
