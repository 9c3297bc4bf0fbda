"""Ground-truth maps: which belief-grid cells are valuable, and which lattice columns are no-fly.

* ``env1``: a synthetic star with random structure, drawn from a seed (:mod:`.synthetic`);
* ``env2``: a real thermal (long-wave infrared) image, Landsat-8 band 10, hottest 30 % valuable;
* ``env3``: a real Sentinel-2 scene, vegetation (NDVI > 0.5) valuable, built-up columns no-fly;
* any image file: ``map_path=`` plus a ``valuable=`` rule string (:mod:`.rules`).

``split=`` chooses the mission distribution (:mod:`.scenes`): ``"paper"`` (the maps above, the
default), or the disjoint ``"train"`` / ``"test"`` sets of stars and of further scenes cut from the
same sources, each scene in its 8 flips and rotations, ``seed`` picking one. Validation missions
(every model choice) are train-split missions; the test scenes serve the final verdicts only.

The real images ship as small PNGs in ``data/`` with their provenance (``data/PROVENANCE.md``);
nothing is downloaded or read from other packages at run time.

Example::

    >>> from uav_ipp.maps import load_ground_truth
    >>> truth = load_ground_truth("env3")
    >>> truth.valuable.shape, truth.no_fly.shape
    ((493, 493), (11, 11))
"""

from __future__ import annotations

from .errors import MapError
from .ground_truth import BUILTIN_MAPS, GroundTruth, available_maps, block_fraction, block_index, load_ground_truth
from .rules import RULE_NAMES, parse_rule
from .scenes import (
    ENV1_SEED_RANGES,
    SCENES,
    SPLIT_ROLES,
    SPLITS,
    TRANSFORMS,
    VALIDATION_SPLIT,
    Scene,
    dihedral,
    scene_count,
    split_scenes,
)
from .synthetic import star_map

__all__ = [
    "BUILTIN_MAPS",
    "ENV1_SEED_RANGES",
    "RULE_NAMES",
    "SCENES",
    "SPLITS",
    "SPLIT_ROLES",
    "TRANSFORMS",
    "VALIDATION_SPLIT",
    "GroundTruth",
    "MapError",
    "Scene",
    "available_maps",
    "block_fraction",
    "block_index",
    "dihedral",
    "load_ground_truth",
    "parse_rule",
    "scene_count",
    "split_scenes",
    "star_map",
]
