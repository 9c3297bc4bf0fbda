"""The roles of the missions, as every comparing study's ``--split`` argument.

Train scenes train; validation missions (train scenes, seeds of their own, every scene equally:
the ``"validation"`` protocol of :mod:`sb3_coma.common.evaluation`) choose checkpoints, seeds,
recipes, observation versions and weightings; the test scenes (the ``"unseen"`` protocol) report.
A study that compares variants to pick one therefore flies validation missions unless told
otherwise, and a flight on the test split says on every output that it reports and chooses nothing.
Defined once here so that every study states the rule in the same words.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

#: ``--split`` values: the missions a study flies; the first is the default.
SPLIT_CHOICES: tuple[str, ...] = ("validation", "test")
#: Printed (and written into reports) whenever a comparing study flies the test split.
TEST_SPLIT_NOTE = "test split: reporting only (no choice may be made on these missions)"
_PROTOCOL_OF_SPLIT = {"validation": "validation", "test": "unseen"}

#: AG's entropy weighting is chosen (``sb3-coma ag-weighting``) on validation missions of its own:
#: train scenes (never "test", the unseen protocol's, nor "paper", Table I's), env seeds from 2000
#: (disjoint from the validation protocol's 1000+ and the reported 0+), 60 per map (20 left env2
#: and env3 undecided; 60 take about 5 s per map).
AG_WEIGHTING_SPLIT = "train"
AG_WEIGHTING_SEED = 2000
AG_WEIGHTING_MISSIONS = 60


def add_split_argument(parser: argparse.ArgumentParser) -> None:
    """``--split {validation,test}``, default validation: what a comparing study flies."""
    parser.add_argument(
        "--split",
        choices=SPLIT_CHOICES,
        default=SPLIT_CHOICES[0],
        help="missions flown: 'validation' (train scenes, seeds from 1000, every scene equally; for choices; "
        "default) or 'test' (the unseen test scenes; reporting only)",
    )


def protocol_for_split(split: str, say: Callable[[str], None] = print) -> str:
    """The evaluation protocol of a study's ``--split``; says :data:`TEST_SPLIT_NOTE` for the test split."""
    if split == "test":
        say(TEST_SPLIT_NOTE)
    return _PROTOCOL_OF_SPLIT[split]
