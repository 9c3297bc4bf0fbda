"""``sb3-coma scenes``: list the mission splits' scenes (family, split, key, crop, valuable fraction, note).

The unseen protocol's verdicts rest on the test scenes and every model choice on validation
missions of the train scenes, so which ground each split holds should be visible without reading
``envs/maps/scenes.py``. The valuable fraction and the no-fly count are measured by loading each
scene untransformed with its family's default rule, exactly as a mission would.
"""

from __future__ import annotations

import argparse

from uav_ipp.maps import ENV1_SEED_RANGES, SCENES, SPLITS, load_ground_truth, scene_count, split_scenes
from uav_ipp.maps.scenes import SPLIT_ROLES, Scene, check_split

NAME = "scenes"
HELP = "list the scenes of each mission split: crop rectangle, ground size, valuable fraction, note"

_FAMILIES = ("env1", "env2", "env3")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--env", default=None, help="env1, env2 or env3 (default: all three)")
    parser.add_argument("--split", default=None, help=f"one of {list(SPLITS)} (default: all)")


def _scenes(family: str, split: str) -> list[tuple[int, Scene]]:
    """(seed of the untransformed mission, scene) of a split; the paper split has its one scene."""
    if split == "paper":
        return [(0, s) for s in SCENES if s.family == family and s.is_paper]
    return list(enumerate(split_scenes(family, split)))


def _rows(family: str, split: str) -> list[str]:
    """One line per scene: key, crop, ground side, valuable fraction, no-fly columns, note."""
    lines = [f"  {'key':<6} {'crop (source pixels)':<28} {'side':>8} {'valuable':>8} {'no-fly':>6}  note"]
    for seed, scene in _scenes(family, split):
        truth = load_ground_truth(family, seed=seed, split=split)
        lines.append(
            f"  {scene.key:<6} {scene.crop:<28} {scene.side_m / 1000:>5.2f} km {truth.valuable.mean():>8.3f} "
            f"{int(truth.no_fly.sum()):>6}  {scene.note}"
        )
    return lines


def _block(family: str, split: str) -> list[str]:
    """The header of one (family, split) and its scenes (env1: its star-seed range)."""
    role = SPLIT_ROLES[split]
    if family == "env1":
        start, stop = ENV1_SEED_RANGES[split]
        what = "seed passed through" if split == "paper" else f"star seeds [{start:,}, {stop:,})"
        return [f"env1 {split}: synthetic stars, {what}; {role}"]
    if split == "paper":
        head = f"{family} paper: the shipped scene, untransformed; {role}"
    else:
        head = f"{family} {split}: {scene_count(family, split)} scenes, each in 8 flips / rotations; {role}"
    return [head, *_rows(family, split)]


def run(args: argparse.Namespace) -> int:
    families = _FAMILIES if args.env is None else (args.env.strip().lower(),)
    splits = SPLITS if args.split is None else (check_split(args.split),)
    for family in families:
        scene_count(family, "paper")  # an unknown name is a MapError naming it (exit status 2)
    blocks = [_block(family, split) for family in families for split in splits]
    print("\n\n".join("\n".join(block) for block in blocks))
    return 0
