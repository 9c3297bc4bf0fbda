"""Mission splits: which scenes (and stars) the ``"paper"``, ``"train"`` and ``"test"`` splits draw from.

* ``"paper"``: today's maps, unchanged: the env1 star of ``seed``, the one shipped env2 / env3 scene.
* ``"train"`` / ``"test"``: disjoint mission distributions.

  - env1: fresh stars from disjoint star-seed ranges (:data:`ENV1_SEED_RANGES`): the split's
    ``seed`` becomes star seed ``start + seed % (stop - start)``.
  - env2 / env3: several scenes cut from the *same* public sources as the shipped ones
    (:data:`SCENES`; crops never overlap, and every test crop keeps :data:`SPLIT_GAP` source pixels
    away from every train crop). ``seed`` picks the scene and one of its 8 flips / rotations
    (:func:`pick`), so each scene gives 8 missions. The shipped scene is a train scene, never a
    test scene.

This module is the catalogue only (pure data and the dihedral transforms): the loader
(:mod:`.ground_truth`) and the maintainer tool that cuts the crops (:mod:`.build_shipped_maps`) both
read the crop rectangles from here, so the shipped files and their description cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import MapError

__all__ = [
    "ENV1_SEED_RANGES",
    "SCENES",
    "SOURCE_SHAPES",
    "SPLITS",
    "SPLIT_GAP",
    "TRANSFORMS",
    "Scene",
    "check_split",
    "dihedral",
    "pick",
    "scene_count",
    "split_scenes",
]

#: Every allowed ``split``; "paper" is the paper's fixed mission (today's maps).
SPLITS: tuple[str, ...] = ("paper", "train", "test")

#: env1 star seeds of each split, half-open ``[start, stop)``. "paper" passes its seed through
#: unchanged (any seed >= 0 works; the benchmark's missions use 0..999,999, reserved here); "train"
#: and "test" map theirs into ranges that never meet each other nor the paper's. All stay below
#: 2**32, so each star seed is a single 32-bit word of NumPy's seed sequence.
ENV1_SEED_RANGES: dict[str, tuple[int, int]] = {
    "paper": (0, 1_000_000),
    "train": (1_000_000_000, 2_000_000_000),
    "test": (2_000_000_000, 3_000_000_000),
}

#: The 8 elements of the square's symmetry group, in :func:`dihedral`'s numbering. Arrays are
#: (row = y, column = x); ``rotK`` is ``np.rot90(a, K // 90)`` (counter-clockwise as displayed with
#: row 0 on top), ``transpose`` swaps x and y, ``flip-y`` reverses the rows, ``flip-x`` the columns,
#: ``anti-transpose`` mirrors about the other diagonal.
TRANSFORMS: tuple[str, ...] = (
    "identity",
    "rot90",
    "rot180",
    "rot270",
    "transpose",
    "flip-y",
    "anti-transpose",
    "flip-x",
)

#: (rows, columns) of each family's source image, in which the crops below are given:
#: env2: Landsat-8 ``l8_B10.tif`` (30 m grid); env3: the Sentinel-2 10 m bands ``s2_B0*.jp2``.
SOURCE_SHAPES: dict[str, tuple[int, int]] = {"env2": (603, 627), "env3": (1947, 1933)}

#: Smallest distance (source pixels, along rows or columns) between any train and any test crop.
#: env2: 14 px = 420 m > the 400 m support of the cubic convolution that put TIRS's 100 m pixels
#: on the product's 30 m grid, so no test pixel shares a native thermal pixel with a train pixel.
#: env3: 7 px = 70 m, beyond the 20 m SWIR band's bilinear support that the built-up mask uses.
SPLIT_GAP: dict[str, int] = {"env2": 14, "env3": 7}


@dataclass(frozen=True)
class Scene:
    """One crop of a family's source image and the split it belongs to.

    Attributes:
        family: ``"env2"`` or ``"env3"``.
        key: short name, unique within the family (``"paper"`` is the shipped scene).
        split: ``"train"`` or ``"test"``.
        rows, cols: the crop, half-open, 0-based, in the source image (row 0 = north).
        files: the shipped PNGs (``data/``); empty for the paper scene, which is read through the
            paper loader. env2: ``(thermal,)`` (8-bit gray at the crop's own size, white = hot);
            env3: ``(valuable, builtup)`` (1-bit, 493 x 493: NDVI > 0.5 and the built-up mask).
        note: what is on the ground, for logs and PROVENANCE.md.
    """

    family: str
    key: str
    split: str
    rows: tuple[int, int]
    cols: tuple[int, int]
    files: tuple[str, ...]
    note: str

    @property
    def is_paper(self) -> bool:
        """Whether this is the shipped paper scene (read from the paper's own files)."""
        return not self.files

    @property
    def crop(self) -> str:
        """The crop as ``"rows a:b, cols c:d"``."""
        return f"rows {self.rows[0]}:{self.rows[1]}, cols {self.cols[0]}:{self.cols[1]}"


def _env2(key: str, split: str, rows: tuple[int, int], cols: tuple[int, int], note: str) -> Scene:
    return Scene("env2", key, split, rows, cols, () if key == "paper" else (f"env2_{key}_thermal.png",), note)


def _env3(key: str, split: str, rows: tuple[int, int], cols: tuple[int, int], note: str) -> Scene:
    files = () if key == "paper" else (f"env3_{key}_valuable.png", f"env3_{key}_builtup.png")
    return Scene("env3", key, split, rows, cols, files, note)


#: Every train / test scene, in split order: within a family and split, a scene's position is its
#: index for :func:`pick`. env2 crops lie on the cloud-free ground along the southern edge of the
#: Landsat scene (north of it the scene is a cumulus field, and a thin cirrus deck, visible in band
#: 9, covers the northern edge); its train scenes are the shipped crop and two east of it, the test
#: scenes two west of it. env3 crops are 493 x 493 at the native 10 m (no resampling); the test
#: scenes are the south-west land block, the train scenes the shipped crop and the land north and
#: east of it. Every crop leaves the default start columns (lattice (2, 2), (8, 2), (8, 8), (2, 8),
#: a set every transform maps onto itself) flyable, so ``start="fixed"`` works in every mission.
SCENES: tuple[Scene, ...] = (
    _env2("paper", "train", (463, 603), (243, 383), "the shipped env2 crop: fields, towns, woods"),
    _env2("east1", "train", (503, 603), (383, 483), "warm fields and a town east of the paper crop"),
    _env2("east2", "train", (513, 603), (483, 573), "fields and woods at the cumulus field's southern edge"),
    _env2("west1", "test", (489, 603), (0, 114), "one large warm clearing in woods"),
    _env2("west2", "test", (489, 603), (114, 228), "clearings and a road in woods"),
    _env3("paper", "train", (420, 913), (0, 493), "the shipped env3 crop: a small town, crop fields, woods"),
    _env3("north", "train", (0, 493), (493, 986), "crop fields, woods and a village"),
    _env3("centre", "train", (493, 986), (500, 993), "crop fields and woods along a tidal creek"),
    _env3("estuary", "train", (986, 1479), (500, 993), "marsh islands and open water of the bay, fields"),
    _env3("south1", "test", (944, 1437), (0, 493), "crop fields, woods and farmsteads"),
    _env3("south2", "test", (1437, 1930), (0, 493), "fields, woods, tidal creeks and a village by the bay"),
)


def check_split(split: object) -> str:
    """``split`` as one of :data:`SPLITS` (case and surrounding blanks ignored), else :class:`MapError`."""
    key = split.strip().lower() if isinstance(split, str) else None
    if key not in SPLITS:
        raise MapError(f"split={split!r} is not a mission split; allowed splits: {list(SPLITS)}")
    return key


def split_scenes(name: str, split: str) -> tuple[Scene, ...]:
    """The scenes of image family ``name`` (``"env2"``/``"env3"``) in a train / test ``split``, in order."""
    return tuple(s for s in SCENES if s.family == name and s.split == split)


def scene_count(name: str, split: str) -> int:
    """How many distinct maps (before the 8 transforms) split ``split`` of built-in map ``name`` has.

    env2 / env3: 1 for "paper", else the number of scenes. env1: the size of the split's star-seed
    range (:data:`ENV1_SEED_RANGES`; for "paper" the reserved seeds, although any seed >= 0 works).
    """
    key = name.strip().lower() if isinstance(name, str) else None
    split = check_split(split)
    if key == "env1":
        start, stop = ENV1_SEED_RANGES[split]
        return stop - start
    if key in SOURCE_SHAPES:
        return 1 if split == "paper" else len(split_scenes(key, split))
    raise MapError(f"scene_count needs a built-in map name, got {name!r}; built-in maps are ['env1', 'env2', 'env3']")


def pick(seed: int, n_scenes: int) -> tuple[int, int]:
    """(scene index, transform index) of ``seed``: ``seed % n`` and ``(seed // n) % 8``.

    Consecutive seeds visit every scene before the next transform, so any ``8 n`` consecutive
    seeds cover every mission of the split exactly once.
    """
    return seed % n_scenes, (seed // n_scenes) % len(TRANSFORMS)


def dihedral(a: np.ndarray, t: int) -> np.ndarray:
    """Element ``t`` (0-7, see :data:`TRANSFORMS`) of the square's symmetry group applied to the
    first two axes of ``a``: a transpose for ``t >= 4``, then ``t % 4`` quarter turns. A view."""
    if not 0 <= t < len(TRANSFORMS):
        raise MapError(f"transform index {t!r} must be in [0, {len(TRANSFORMS) - 1}]")
    if t >= 4:
        a = np.swapaxes(a, 0, 1)
    return np.rot90(a, t % 4)
