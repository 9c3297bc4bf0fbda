"""``sb3-coma ag-weighting``: choose AG's entropy weighting per map family on validation missions.

Example::

    sb3-coma ag-weighting --env env1,env2,env3 --missions 60     # about 15 s

Flies AG with the class-weighted and the plain entropy on the same ``split="train"`` validation
missions (env seeds 2000.., never the test split nor the paper's mission), prints both weightings'
means and the paired differences, and the weighting the rule picks (``sb3_coma.experiments.ag_weighting``).
The shipped default (``sb3_coma.baselines.adaptive_gain.WEIGHTING_BY_MAP``) records this output.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sb3_coma.app.arguments import (
    add_env_argument,
    add_missions_argument,
    add_seed_argument,
    add_workers_argument,
    count_value,
)
from sb3_coma.experiments.ag_weighting import VALIDATION_MISSIONS, VALIDATION_SEED, pick_ag_weighting

NAME = "ag-weighting"
#: The picker refuses a bad count, seed or option with a ``ValueError``: this command's user errors.
USER_ERRORS = (ValueError,)
HELP = "choose AG's entropy weighting (class / plain) per map on validation missions (never test missions)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_workers_argument(parser)

    add_env_argument(parser, several=True)
    add_missions_argument(parser, VALIDATION_MISSIONS, "weighting (validation missions)")
    add_seed_argument(parser, VALIDATION_SEED, note="; smaller seeds are refused: they are the protocols'")
    parser.add_argument("--noise", default="moderate", help="channel noise (default moderate)")
    parser.add_argument("--uavs", type=count_value, default=None, help="number of UAVs (env default 4)")
    parser.add_argument("--budget", type=count_value, default=None, help="decisions per UAV (env default 15)")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write the measurements as JSON")


def run(args: argparse.Namespace) -> int:
    from sb3_coma.app.config import map_list  # here: the parser alone must not load torch
    from sb3_coma.baselines.adaptive_gain import WEIGHTING_BY_MAP

    names = map_list(args.env)  # each map once (evaluate's rule): env1,env1 is one line, not two flights
    options = {k: v for k, v in (("n_uavs", args.uavs), ("budget", args.budget)) if v is not None}
    choices = []
    for name in names:
        choice = pick_ag_weighting(
            name,
            n_missions=args.missions,
            seed=args.seed,
            noise=args.noise,
            log=lambda m: print(m, flush=True),
            **options,
        )
        choices.append(choice)
    print()
    for c in choices:
        shipped = WEIGHTING_BY_MAP.get(c.env)
        note = (
            ""
            if shipped is None
            else (" (= the shipped default)" if shipped == c.choice else f" (the shipped default is {shipped!r})")
        )
        print(f"#: {c.comment()}{note}")
    if args.json:
        Path(args.json).write_text(json.dumps([c.as_dict() for c in choices], indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0
