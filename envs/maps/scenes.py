"""Mission splits: which scenes (and stars) the ``"paper"``, ``"train"`` and ``"test"`` splits draw from.

* ``"paper"``: today's maps, unchanged: the env1 star of ``seed``, the one shipped env2 / env3 scene.
* ``"train"`` / ``"test"``: disjoint mission distributions.

  - env1: fresh stars from disjoint star-seed ranges (:data:`ENV1_SEED_RANGES`): the split's
    ``seed`` becomes star seed ``start + seed % (stop - start)``.
  - env2 / env3: many scenes cut from the *same* public sources as the shipped ones
    (:data:`SCENES`: 9 train and 8 test for env2, 12 train and 9 test for env3; crops never
    overlap, and every test crop keeps :data:`SPLIT_GAP` source pixels away from every train
    crop). ``seed`` picks the scene and one of its 8 flips / rotations (:func:`pick`), so each
    scene gives 8 missions. The shipped scene is a train scene, never a test scene.

Roles of the splits (:data:`SPLIT_ROLES`): "train" missions train models *and* select them: the
validation missions (checkpoint choice, AG's entropy weighting, any tuning) are train-split
missions flown with their own env seeds (:data:`VALIDATION_SPLIT`), i.e. new flips, starts and
noise of the train scenes, never a test scene. The test scenes are used for the final verdicts
only and never for any choice, so the unseen protocol's numbers are not selected on.

Why the crops are smaller than the paper scene: the sources hold little cloud-free land (the
Landsat scene is mostly cumulus, half of the Sentinel-2 scene is sea), so 16 or more disjoint
crops only fit at 48 px (env2, 1.44 km) and 240 px (env3, 2.4 km) instead of the paper's 140 px /
493 px; every crop is resampled to the belief grid as the paper scene is (:data:`PIXEL_METRES`
gives each source's ground resolution, :attr:`Scene.side_m` a crop's side).

This module is the catalogue only (pure data and the dihedral transforms): the loader
(:mod:`.ground_truth`) and the maintainer tool that cuts the crops (:mod:`.build_shipped_maps`) both
read the crop rectangles from here, so the shipped files and their description cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import MapError

#: Every allowed ``split``; "paper" is the paper's fixed mission (today's maps).
SPLITS: tuple[str, ...] = ("paper", "train", "test")

#: What each split is for. Written down here because the code that honours it (training, the
#: protocols, the AG weighting picker) lives in ``sb3_coma``, and ``sb3-coma scenes`` prints it.
SPLIT_ROLES: dict[str, str] = {
    "paper": "the paper's fixed mission (Table I): comparison with the paper only",
    "train": "training missions, and the validation missions every model choice is made on",
    "test": "final verdicts only (the unseen protocol); never used for any choice",
}

#: The split validation missions come from: model selection (best checkpoint, AG's weighting,
#: tuning) flies train-split missions with env seeds of its own (e.g. 1000.. for checkpoints,
#: 2000.. for the AG weighting), so no choice ever looks at a test scene.
VALIDATION_SPLIT = "train"

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

#: Ground size of one source pixel, metres: Landsat-8's 30 m product grid (TIRS itself resolves
#: 100 m) and Sentinel-2's 10 m bands.
PIXEL_METRES: dict[str, float] = {"env2": 30.0, "env3": 10.0}

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
            env3: ``(valuable, builtup)`` (1-bit, 493 x 493: NDVI > 0.5 and the built-up mask,
            computed after resampling the crop's bands to 493 x 493).
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

    @property
    def side_px(self) -> int:
        """Side of the (square) crop in source pixels."""
        return self.rows[1] - self.rows[0]

    @property
    def side_m(self) -> float:
        """Side of the crop on the ground, metres (the simulated field is 50 m whatever this is)."""
        return self.side_px * PIXEL_METRES[self.family]


def _env2(key: str, split: str, rows: tuple[int, int], cols: tuple[int, int], note: str) -> Scene:
    return Scene("env2", key, split, rows, cols, () if key == "paper" else (f"env2_{key}_thermal.png",), note)


def _env3(key: str, split: str, rows: tuple[int, int], cols: tuple[int, int], note: str) -> Scene:
    files = () if key == "paper" else (f"env3_{key}_valuable.png", f"env3_{key}_builtup.png")
    return Scene("env3", key, split, rows, cols, files, note)


#: Every train / test scene, in split order: within a family and split, a scene's position is its
#: index for :func:`pick`. env2 crops lie on the cloud-free ground along the southern edge of the
#: Landsat scene (north of it the scene is a cumulus field, and a thin cirrus deck, visible in band
#: 9, covers the northern edge); the new crops are 48 px (1.44 km) squares, the train scenes the
#: shipped crop and two rows east of it, the test scenes two rows west of it, 14 px away, leaving
#: out a cirrus speck (band 9) at columns 144-181. env3 crops are 240 px (2.4 km) squares of the
#: land in the 10 m bands: the train scenes the shipped crop and the land north and east of it
#: (rows 0-720), the test scenes the land south of it (rows 920-1880, 7 px below the shipped
#: crop). Every crop leaves the default start columns (lattice (2, 2), (8, 2), (8, 8), (2, 8), a
#: set every transform maps onto itself) flyable and its flyable columns connected, so
#: ``start="fixed"`` works in every mission. The env3 positions come from a raster scan of each
#: split's land for squares that pass those checks; PROVENANCE.md has the details and the numbers.
SCENES: tuple[Scene, ...] = (
    _env2("paper", "train", (463, 603), (243, 383), "the shipped env2 crop: fields, towns, woods"),
    _env2("e1", "train", (507, 555), (383, 431), "woods, clearings and a hamlet in the south-east"),
    _env2("e2", "train", (507, 555), (431, 479), "a small town's street grid in woods"),
    _env2("e3", "train", (507, 555), (479, 527), "woods with a track, houses to the north"),
    _env2("e4", "train", (555, 603), (383, 431), "woods and a clearing in the east"),
    _env2("e5", "train", (555, 603), (431, 479), "woods, roads and clearings"),
    _env2("e6", "train", (555, 603), (479, 527), "bare ground of a pit or works, and tracks"),
    _env2("e7", "train", (555, 603), (527, 575), "bare pits and tracks in woods"),
    _env2("e8", "train", (555, 603), (575, 623), "woods crossed by a road and a power line, a bare lot"),
    _env2("w1", "test", (507, 555), (0, 48), "woods with small clearings"),
    _env2("w2", "test", (507, 555), (48, 96), "a large square clearing in woods"),
    _env2("w3", "test", (507, 555), (96, 144), "fields in the north, plots and roads"),
    _env2("w4", "test", (507, 555), (181, 229), "a clearing and a track in woods"),
    _env2("w5", "test", (555, 603), (0, 48), "woods with tracks and small clearings"),
    _env2("w6", "test", (555, 603), (48, 96), "a cleared tract east of woods"),
    _env2("w7", "test", (555, 603), (96, 144), "cleared tracts and a road in woods"),
    _env2("w8", "test", (555, 603), (181, 229), "woods, a cleared patch in the east"),
    _env3("paper", "train", (420, 913), (0, 493), "the shipped env3 crop: a small town, crop fields, woods"),
    _env3("n1", "train", (0, 240), (248, 488), "crop fields, woods and a few farmsteads"),
    _env3("n2", "train", (0, 240), (488, 728), "fields, woods, a hamlet and a bright bare field (marked built-up)"),
    _env3("n3", "train", (0, 240), (728, 968), "fields and woods, houses along a road"),
    _env3("n4", "train", (0, 240), (968, 1208), "large fields and woods"),
    _env3("n5", "train", (64, 304), (0, 240), "fields and woods"),
    _env3("n6", "train", (240, 480), (496, 736), "a village with an industrial site, fields"),
    _env3("n7", "train", (240, 480), (736, 976), "fields, woods and farmsteads"),
    _env3(
        "n8", "train", (240, 480), (976, 1216), "fields and a tidal creek whose mud banks the SWIR rule marks built-up"
    ),
    _env3("n9", "train", (480, 720), (496, 736), "fields, woods and a tidal creek"),
    _env3("n10", "train", (480, 720), (736, 976), "fields, woods and a creek mouth"),
    _env3("n11", "train", (480, 720), (976, 1216), "bay shore: open water, woods and marsh"),
    _env3("s1", "test", (920, 1160), (0, 240), "fields, woods and a poultry farm's long sheds"),
    _env3("s2", "test", (920, 1160), (240, 480), "crop fields and woods"),
    _env3("s3", "test", (920, 1160), (568, 808), "fields and woods along a creek valley"),
    _env3("s4", "test", (1160, 1400), (0, 240), "fields, woods and farmsteads"),
    _env3("s5", "test", (1160, 1400), (256, 496), "fields, woods, a creek and a poultry farm"),
    _env3("s6", "test", (1160, 1400), (504, 744), "bay shore: fields and woods by open water"),
    _env3("s7", "test", (1400, 1640), (0, 240), "fields and woods"),
    _env3("s8", "test", (1400, 1640), (240, 480), "marsh creeks and the bay, fields"),
    _env3("s9", "test", (1640, 1880), (0, 240), "woods and a few fields"),
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
