"""Ground-truth maps: the shipped images, the env1 star, user images with every rule, and errors."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image, ImageOps

from uav_ipp.maps import MapError, available_maps, block_fraction, block_index, load_ground_truth, parse_rule
from uav_ipp.maps.rules import orient, read_image

STARTS = [(2, 2), (8, 2), (8, 8), (2, 8)]  # default start columns, lattice (x, y)


# ------------------------------------------------------------------ shipped maps
def test_available_maps():
    assert available_maps() == ("env1", "env2", "env3")


@pytest.mark.parametrize("name", available_maps())
def test_shipped_maps_shapes_dtypes_and_fractions(name):
    g = load_ground_truth(name)
    assert g.name == name and isinstance(g.source, str) and g.source and "\n" not in g.source
    assert g.valuable.shape == (493, 493) and g.valuable.dtype == np.bool_
    assert g.no_fly.shape == (11, 11) and g.no_fly.dtype == np.bool_
    assert 0.2 <= g.valuable.mean() <= 0.45
    assert not g.valuable.flags.writeable and not g.no_fly.flags.writeable


def test_env2_hottest_fraction_and_no_no_fly():
    g = load_ground_truth("env2")
    assert g.valuable.mean() == pytest.approx(0.3, abs=0.01)
    assert not g.no_fly.any()
    # structure, not one blob: several separate hot patches
    n_labels, _ = cv2.connectedComponents(g.valuable.astype(np.uint8))
    assert n_labels - 1 >= 5


def test_env3_vegetation_no_fly_and_free_starts():
    g = load_ground_truth("env3")
    assert 0.2 <= g.valuable.mean() <= 0.5
    assert 0.05 <= g.no_fly.mean() <= 0.2
    for x, y in STARTS:
        assert not g.no_fly[y, x], (x, y)


def test_env3_other_sizes_and_override():
    g = load_ground_truth("env3", grid=100, lattice=6)
    assert g.valuable.shape == (100, 100) and g.no_fly.shape == (6, 6)
    exg = load_ground_truth("env3", valuable="excess-green")
    assert 0.05 < exg.valuable.mean() < 0.95
    assert np.array_equal(exg.no_fly, load_ground_truth("env3").no_fly)  # rule never moves buildings
    hot = load_ground_truth("Env2", valuable="hottest:0.1")  # names are case-insensitive
    assert hot.valuable.mean() == pytest.approx(0.1, abs=0.01)


# ------------------------------------------------------------------ env1
def test_env1_seed_determinism_and_variety():
    a, b = (load_ground_truth("env1", seed=3).valuable for _ in range(2))
    np.testing.assert_array_equal(a, b)
    others = [load_ground_truth("env1", seed=s).valuable for s in range(4, 9)]
    assert all((a != o).mean() > 0.05 for o in others)
    fresh = [load_ground_truth("env1", seed=None).valuable for _ in range(2)]
    assert (fresh[0] != fresh[1]).any()


def test_env1_fraction_range_and_speed():
    fractions = [load_ground_truth("env1", seed=s).valuable.mean() for s in range(60)]
    assert min(fractions) >= 0.2 and max(fractions) <= 0.45
    t0 = time.perf_counter()
    for s in range(50):
        load_ground_truth("env1", seed=1000 + s)
    assert (time.perf_counter() - t0) / 50 < 0.01
    assert not load_ground_truth("env1").no_fly.any()


def test_env1_override_reads_star_as_black_drawing():
    star = load_ground_truth("env1", seed=5).valuable
    np.testing.assert_array_equal(load_ground_truth("env1", seed=5, valuable="dark:0.5").valuable, star)
    np.testing.assert_array_equal(load_ground_truth("env1", seed=5, valuable="threshold:0.5").valuable, ~star)


# ------------------------------------------------------------------ blocks
def test_block_index_and_fraction():
    k = block_index(493, 11)
    assert k[0] == 0 and k[-1] == 10 and np.all(np.diff(k) >= 0)
    counts = np.bincount(k)
    assert counts[0] < counts[5] and counts[10] < counts[5]  # half squares at the borders
    centres = (np.arange(493) + 0.5) * 50 / 493
    np.testing.assert_array_equal(k, np.argmin(np.abs(centres[:, None] - 5.0 * np.arange(11)), axis=1))
    np.testing.assert_allclose(block_fraction(np.ones((493, 493), bool), 11), 1.0)
    m = np.zeros((493, 493), bool)
    m[k == 3] = True
    bf = block_fraction(m, 11)
    assert np.all(bf[3] == 1.0) and bf.sum() == 11.0


# ------------------------------------------------------------------ user images
@pytest.fixture
def images(tmp_path):
    gray = np.tile(np.linspace(0, 255, 64).round().astype(np.uint8), (48, 1))  # left dark, right bright
    colour = np.zeros((40, 80, 3), np.uint8)
    colour[:, :30] = (40, 200, 40)  # green (BGR)
    colour[:, 30:] = (150, 140, 160)  # greyish
    drawing = np.full((70, 50), 255, np.uint8)
    cv2.circle(drawing, (25, 35), 15, 0, -1)  # black disc on white
    gray16 = (np.tile(np.linspace(0, 65535, 64), (64, 1))).astype(np.uint16)
    paths = {}
    for name, img in (("gray.png", gray), ("colour.png", colour), ("drawing.png", drawing), ("gray16.png", gray16)):
        paths[name] = tmp_path / name
        assert cv2.imwrite(str(paths[name]), img)
    return paths


@pytest.mark.parametrize(
    "rule,expected",
    [
        ("threshold:0.5", 0.5),
        ("threshold", 0.5),
        (None, 0.5),
        ("dark:0.25", 0.25),
        ("dark", 0.5),
        ("hottest:0.3", 0.3),
        ("coldest:0.2", 0.2),
    ],
)
def test_user_gray_rules(images, rule, expected):
    g = load_ground_truth("mine", map_path=images["gray.png"], valuable=rule, grid=64, lattice=5)
    assert g.name == "mine" and g.valuable.shape == (64, 64) and g.no_fly.shape == (5, 5)
    assert not g.no_fly.any()
    assert g.valuable.mean() == pytest.approx(expected, abs=0.04)
    bright = rule is None or rule.startswith(("threshold", "hottest"))
    assert g.valuable[:, -1].all() == bright and g.valuable[:, 0].all() != bright


def test_user_16bit_and_resize(images):
    g = load_ground_truth("x", map_path=images["gray16.png"], valuable="threshold:0.75", grid=32, lattice=4)
    assert g.valuable.shape == (32, 32) and g.valuable.mean() == pytest.approx(0.25, abs=0.05)


@pytest.mark.parametrize("rule", ["excess-green", "excess-green:0.2", "exg"])
def test_user_excess_green(images, rule):
    g = load_ground_truth("veg", map_path=images["colour.png"], valuable=rule, grid=80, lattice=5)
    # the 80 x 40 image is stretched to 80 x 80; the green left 30 columns stay green
    assert g.valuable[:, :29].all() and not g.valuable[:, 31:].any()


def test_user_dark_drawing_and_name_from_stem(images):
    g = load_ground_truth("env3", map_path=images["drawing.png"], valuable="dark:0.5", grid=100, lattice=11)
    assert g.name == "drawing"  # a built-in name next to map_path is only a default
    assert g.valuable[50, 50] and not g.valuable[2, 2]
    assert g.valuable.mean() == pytest.approx(np.pi * 15**2 / (70 * 50), abs=0.03)
    assert "drawing.png" in g.source


# ------------------------------------------------------------------ user images: EXIF orientation
def _corner_image() -> np.ndarray:
    """40 x 60 white with a dark block in the top-left corner: every flip / turn looks different."""
    a = np.full((40, 60), 255, np.uint8)
    a[:10, :20] = 0
    return a


def _with_orientation(path, array: np.ndarray, orientation: int, **save) -> None:
    exif = Image.Exif()
    exif[0x0112] = orientation  # the EXIF Orientation tag
    Image.fromarray(array).save(path, exif=exif, **save)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_is_applied_as_exif_transpose_does(tmp_path, orientation):
    path = tmp_path / f"o{orientation}.png"  # PNG (eXIf chunk): lossless, so pixels compare exactly
    _with_orientation(path, _corner_image(), orientation)
    with Image.open(path) as im:
        expected = np.asarray(ImageOps.exif_transpose(im), dtype=np.float32) / 255.0
    got = read_image(path)
    assert got.orientation == orientation
    np.testing.assert_array_equal(got.gray, expected)
    np.testing.assert_array_equal(orient(_corner_image(), orientation) / 255.0, expected)


def test_exif_rotated_jpeg_is_read_upright(tmp_path):
    """A phone photo stored sideways (Orientation 6: turn a quarter clockwise to show)."""
    path = tmp_path / "photo.jpg"
    _with_orientation(path, np.dstack([_corner_image()] * 3), 6, quality=95)
    g = load_ground_truth("photo", map_path=path, valuable="dark:0.5", grid=60, lattice=5)
    shown = np.rot90(_corner_image(), -1) < 128  # 60 rows x 40 columns, dark block top-right
    resized = cv2.resize(shown.astype(np.float32), (60, 60), interpolation=cv2.INTER_AREA) > 0.5
    assert (g.valuable != resized).mean() < 0.02  # JPEG ringing at the block's edge only
    assert g.valuable[:5, -5:].all() and not g.valuable[:5, :5].any()
    assert not g.valuable[-5:, -5:].any()


def test_image_without_exif_is_read_as_stored(images):
    assert read_image(images["colour.png"]).orientation == 1
    assert read_image(images["gray.png"]).alpha is None


# ------------------------------------------------------------------ user images: transparency
def _rgba(tmp_path, name: str = "logo.png"):
    """20 x 20: columns 0-4 transparent (stored black, which 'dark' would take), a dark 5 x 5 block
    at rows 5-9, columns 5-9, the rest opaque white."""
    rgba = np.zeros((20, 20, 4), np.uint8)
    rgba[..., :3] = 255
    rgba[..., 3] = 255
    rgba[:, :5] = 0  # colour black, alpha 0
    rgba[5:10, 5:10, :3] = 0
    path = tmp_path / name
    Image.fromarray(rgba).save(path)
    return path


def test_rgba_transparent_pixels_are_never_valuable_and_warned(tmp_path):
    path = _rgba(tmp_path)
    with pytest.warns(UserWarning, match=r"logo\.png'?: 100 of 400 pixels \(25\.0 %\) are transparent; 100 of 400"):
        g = load_ground_truth("logo", map_path=path, valuable="dark:0.5", grid=20, lattice=4)
    assert not g.valuable[:, :5].any()  # stored black, but transparent
    assert g.valuable[5:10, 5:10].all() and g.valuable.sum() == 25
    assert "100 transparent cells never valuable" in g.source


def test_transparent_pixels_take_no_part_in_a_rules_threshold(tmp_path):
    path = _rgba(tmp_path)
    with pytest.warns(UserWarning):
        g = load_ground_truth("logo", map_path=path, valuable="coldest:0.1", grid=20, lattice=4)
    # 10 % of the 300 opaque cells (not of all 400): the dark block's 25 cells are the coldest
    assert g.valuable.sum() == 25 and not g.valuable[:, :5].any()
    with pytest.warns(UserWarning):  # Otsu on the opaque cells alone splits block from white
        otsu = load_ground_truth("logo", map_path=path, valuable="dark", grid=20, lattice=4)
    np.testing.assert_array_equal(otsu.valuable, g.valuable)


def test_colour_under_transparent_pixels_does_not_leak_into_cells(tmp_path):
    """Every other column transparent (stored black): cells of 2 x 2 pixels are half opaque, so
    valid, and show the opaque white, not the 50 % gray a plain average would give."""
    rgba = np.full((40, 40, 4), 255, np.uint8)
    rgba[:, ::2] = (0, 0, 0, 0)
    rgba[20:, :, :3] = 0  # the lower half is opaque black where opaque
    path = tmp_path / "stripes.png"
    Image.fromarray(rgba).save(path)
    with pytest.warns(UserWarning, match="800 of 1,600 pixels .* 0 of 400 grid cells"):
        g = load_ground_truth("s", map_path=path, valuable="threshold:0.75", grid=20, lattice=4)
    assert g.valuable[:10].all() and not g.valuable[10:].any()


def test_palette_png_with_trns_transparency(tmp_path):
    index = np.ones((20, 20), np.uint8)  # palette 1: white
    index[:, :4] = 0  # palette 0: black, made transparent by tRNS
    index[10:, 10:] = 2  # palette 2: dark gray, opaque
    im = Image.fromarray(index).convert("P")
    im.putpalette([0, 0, 0, 255, 255, 255, 40, 40, 40] + [0] * 759)
    path = tmp_path / "palette.png"
    im.save(path, transparency=0)
    with Image.open(path) as check:
        assert check.mode == "P" and check.info["transparency"] == 0
    with pytest.warns(UserWarning, match="80 of 400 pixels"):
        g = load_ground_truth("p", map_path=path, valuable="dark:0.5", grid=20, lattice=4)
    assert g.valuable.sum() == 100 and g.valuable[10:, 10:].all() and not g.valuable[:, :4].any()


def test_colour_key_trns_and_gray_alpha(tmp_path):
    key = np.full((20, 20), 200, np.uint8)
    key[:, :6] = 7  # the key colour: transparent (OpenCV ignores this tRNS; PIL reads it)
    key[:5, 10:15] = 20
    Image.fromarray(key).save(tmp_path / "key.png", transparency=7)
    with pytest.warns(UserWarning, match="120 of 400 pixels"):
        g = load_ground_truth("k", map_path=tmp_path / "key.png", valuable="dark:0.5", grid=20, lattice=4)
    assert g.valuable.sum() == 25 and not g.valuable[:, :6].any()
    la = np.dstack([key, np.where(key == 7, 0, 255).astype(np.uint8)])
    Image.fromarray(la).save(tmp_path / "la.png")  # (H, W, 2) uint8: mode LA
    with pytest.warns(UserWarning, match="120 of 400 pixels"):
        h = load_ground_truth("la", map_path=tmp_path / "la.png", valuable="dark:0.5", grid=20, lattice=4)
    np.testing.assert_array_equal(h.valuable, g.valuable)


def test_opaque_alpha_channel_changes_nothing_and_warns_nothing(tmp_path, images):
    bgr = cv2.imread(str(images["colour.png"]))
    cv2.imwrite(str(tmp_path / "opaque.png"), np.dstack([bgr, np.full(bgr.shape[:2], 255, np.uint8)]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # the picture is 80 x 40: its stretch onto the square field is said (test_user_image_aspect.py)
        warnings.filterwarnings("ignore", message=r".*not square; it is stretched", category=UserWarning)
        a = load_ground_truth("a", map_path=tmp_path / "opaque.png", valuable="excess-green", grid=80, lattice=5)
    b = load_ground_truth("b", map_path=images["colour.png"], valuable="excess-green", grid=80, lattice=5)
    np.testing.assert_array_equal(a.valuable, b.valuable)


def test_fully_transparent_image_is_an_error(tmp_path):
    Image.fromarray(np.zeros((10, 10, 4), np.uint8)).save(tmp_path / "ghost.png")
    with pytest.raises(MapError, match=r"ghost\.png' is fully transparent"):
        load_ground_truth(map_path=tmp_path / "ghost.png")


def test_transparent_image_whose_opaque_part_is_flat_names_the_transparency(tmp_path):
    rgba = np.zeros((10, 10, 4), np.uint8)
    rgba[:, 5:] = 255  # opaque white right half, transparent left half
    Image.fromarray(rgba).save(tmp_path / "half.png")
    with pytest.raises(MapError, match=r"no pixel .* 50 transparent grid cells"):
        load_ground_truth(map_path=tmp_path / "half.png", grid=10, lattice=2)


# ------------------------------------------------------------------ errors
@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"name": "env7"}, "env7"),
        ({"name": "env7"}, "env1"),  # lists what is allowed
        ({"name": "my_map.png"}, "map_path"),
        ({"name": 3}, "3"),
        ({"map_path": "/nonexistent/map.png"}, "/nonexistent/map.png"),
        ({"valuable": "hottest:abc", "name": "env2"}, "abc"),
        ({"valuable": "hottest:1.5", "name": "env2"}, "1.5"),
        ({"valuable": "hottest:0", "name": "env2"}, "between 0 and 1"),
        ({"valuable": "hottest", "name": "env2"}, "fraction"),
        ({"valuable": "hottest:", "name": "env2"}, "hottest:"),
        ({"valuable": "magic:0.3", "name": "env2"}, "magic"),
        ({"valuable": "magic:0.3", "name": "env2"}, "excess-green"),  # lists what is allowed
        ({"valuable": "threshold:nan", "name": "env2"}, "nan"),
        ({"valuable": "threshold:2", "name": "env2"}, "2"),
        ({"valuable": 0.3, "name": "env2"}, "0.3"),
        ({"valuable": "ndvi", "name": "env2"}, "near-infrared"),
        ({"lattice": 1}, "lattice=1"),
        ({"lattice": 2.5}, "lattice=2.5"),
        ({"grid": 5}, "grid=5"),
        ({"grid": True}, "grid=True"),
        ({"grid": 100_000}, "grid=100000"),
        ({"seed": -1}, "seed=-1"),
        ({"seed": "abc"}, "seed='abc'"),
    ],
)
def test_bad_inputs_raise_map_error(kwargs, match):
    with pytest.raises(MapError, match=match.replace(".", r"\.").replace("(", r"\(")):
        load_ground_truth(**{"name": "env1", **kwargs})


def test_map_error_is_value_error():
    assert issubclass(MapError, ValueError)


def test_bad_files(tmp_path, images):
    bad = tmp_path / "bad.png"
    bad.write_bytes(b"not an image at all")
    with pytest.raises(MapError, match=r"bad\.png"):
        load_ground_truth(map_path=bad)
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    with pytest.raises(MapError, match=r"empty\.png.*empty"):
        load_ground_truth(map_path=empty)
    with pytest.raises(MapError, match="not a file"):
        load_ground_truth(map_path=tmp_path)
    with pytest.raises(MapError, match="map_path"):
        load_ground_truth(map_path=12)


def test_degenerate_masks(tmp_path, images):
    flat = tmp_path / "flat.png"
    cv2.imwrite(str(flat), np.full((10, 10), 255, np.uint8))
    with pytest.raises(MapError, match=r"threshold:0\.1.*every pixel"):
        load_ground_truth(map_path=flat, valuable="threshold:0.1", grid=10, lattice=2)
    with pytest.raises(MapError, match=r"dark:0\.5.*no pixel"):
        load_ground_truth(map_path=flat, valuable="dark:0.5", grid=10, lattice=2)
    with pytest.raises(MapError, match="no pixel"):
        load_ground_truth(map_path=flat, grid=10, lattice=2)  # Otsu on a constant image
    with pytest.raises(MapError, match="colour"):
        load_ground_truth(map_path=images["gray.png"], valuable="excess-green", grid=64, lattice=5)
    with pytest.raises(MapError, match="near-infrared"):
        load_ground_truth(map_path=images["colour.png"], valuable="ndvi:0.3", grid=64, lattice=5)


def test_parse_rule_round_trip():
    assert str(parse_rule(" Hottest:0.25 ")) == "hottest:0.25"
    assert str(parse_rule("excess_green")) == "excess-green"
    assert parse_rule("dark").value is None


# ------------------------------------------------------------------ docs/errors.md rows of this module
def _doc_message(row_id: str) -> str:
    """The message column of a row of docs/errors.md."""
    doc = (Path(__file__).resolve().parent.parent / "docs" / "errors.md").read_text(encoding="utf-8")
    row = next(line for line in doc.splitlines() if line.startswith(f"| `{row_id}` |"))
    return row.rstrip(" |").rsplit(" | ", 1)[1]


def test_transparency_rows_of_the_errors_doc_are_the_real_messages(tmp_path):
    import uav_ipp

    maps = tmp_path / "maps"
    maps.mkdir()
    logo = np.full((100, 100, 4), 255, np.uint8)
    logo[:, :25, 3] = 0
    logo[40:60, 40:60, :3] = 0
    Image.fromarray(logo).save(maps / "logo.png")
    Image.fromarray(np.zeros((10, 10, 4), np.uint8)).save(maps / "ghost.png")
    half = np.zeros((10, 10, 4), np.uint8)
    half[:, 5:] = 255
    Image.fromarray(half).save(maps / "half.png")

    def shown(message: str) -> str:
        return message.replace(str(tmp_path), "<tmp>")

    with pytest.warns(UserWarning) as caught:
        uav_ipp.make_env("mine", map_path=str(maps / "logo.png"), valuable="dark:0.5")
    assert [shown(str(w.message)) for w in caught] == [_doc_message("map-path-transparent-pixels")]
    for row_id, file in (("map-path-fully-transparent", "ghost.png"), ("map-path-transparent-rest-flat", "half.png")):
        with pytest.raises(MapError) as info:
            uav_ipp.make_env("mine", map_path=str(maps / file))
        assert shown(str(info.value)) == _doc_message(row_id)
