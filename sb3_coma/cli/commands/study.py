"""``sb3-coma study NAME [ARGS...]``: the studies of ``sb3_coma.experiments`` from the one CLI.

Every study keeps its own options (``sb3-coma study dagger --help`` prints them); this verb names
them in one place, as rl-zoo's one entry point names its scripts, so a user does not have to know
the module paths. ``python -m sb3_coma.experiments.NAME`` still works and runs the same ``main``.
The study's module is imported only when it runs (``sb3-coma --help`` stays quick).
"""

from __future__ import annotations

import argparse
import importlib

from sb3_coma.cli import UserError

NAME = "study"
HELP = "run one of the studies (dagger, attribution, learners_paired, ...); study NAME --help for its options"

#: Study name -> what it measures (one line; the module docstring says how).
STUDIES: dict[str, str] = {
    "ag_channel_table": "AG with shared positions vs comm-only vs central, per map",
    "attribution": "each shipped warm-started model against its own DAgger clone, AG and COMA from scratch",
    "budget_sweep": "the shipped model, AG and AG-k3 at several budgets",
    "coma_study": "why COMA trails MAPPO on third-party envs: COMA variants on validation seeds",
    "dagger": "DAgger from the oracle, optional COMA fine-tuning, paired against AG",
    "ippo_vs_ag": "train COMA, IPPO or MAPPO and fly it against AG and random",
    "learners_paired": "learners (each its best seed on validation) against each other and AG",
    "learning_curves": "validation curves of training runs, mean and spread over seeds",
    "marl_benchmark": "COMA, MAPPO, IPPO and random on third-party PettingZoo envs",
    "paired_se": "paired standard errors on more missions",
    "ship_models": "maintainer tool: pick the shipped models from runs on validation missions",
    "team_size": "the shipped model, AG and the lawnmower with other team sizes",
    "user_maps": "the env3 model on user map images no model trained on",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "name",
        metavar="NAME",
        help="one of: " + "; ".join(f"{name} ({what})" for name, what in STUDIES.items()),
    )
    parser.add_argument("args", nargs=argparse.REMAINDER, help="the study's own options (NAME --help lists them)")


def run(args: argparse.Namespace) -> int:
    if args.name not in STUDIES:
        raise UserError(f"unknown study {args.name!r}; studies: {', '.join(STUDIES)}")
    module = importlib.import_module(f"sb3_coma.experiments.{args.name}")
    result = module.main(list(args.args))
    return result if isinstance(result, int) else 0
