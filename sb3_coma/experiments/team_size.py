"""Team size at deployment: the shipped env3 model (trained with 4 UAVs) flown by K = 2..8 UAVs.

What it measures: whether a model trained with one team size still plans well with another,
against AG and the lawnmower on the same missions. The actor is shared and per agent: its input
is the UAV's 8 local 11 x 11 channels, whatever N is. What depends on N: the id channel
((i+1)/N: spread over the same range for any N), the `received` maps (N slots, consumed by the
fusion, which averages / attends over any number of sources) and the critic (not used when
flying). So the model flies any team size without change.

    python -m sb3_coma.experiments.team_size [--missions 10] [--env env3] [--sizes 2 3 4 5 6 8]

Prints F1 / entropy (global map) and team entropy at 100 % budget, mean over the same seeded
split="test" missions for the model, AG and the lawnmower.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Sequence

import numpy as np

from sb3_coma import load_pretrained
from sb3_coma.app.arguments import add_env_argument, add_missions_argument
from sb3_coma.app.evaluation import Missions, fly, resolve_method
from uav_ipp.config import count_value


def main(argv: Sequence[str] | None = None) -> int:
    """Print one table row per team size: the model, AG and the lawnmower on the same missions."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_env_argument(parser)
    add_missions_argument(parser, 10, "method and team size")
    parser.add_argument("--sizes", type=count_value, nargs="+", default=[2, 3, 4, 5, 6, 8])
    args = parser.parse_args(argv)
    # Flying the model with K != its 4 UAVs is the point here: silence evaluate's team-size warning.
    warnings.filterwarnings("ignore", message=r".* was trained with \d+ UAVs but flies with", category=UserWarning)
    methods = [resolve_method(policy) for policy in (load_pretrained(args.env), "ag", "lawnmower")]
    print(
        f"{args.env}, split=test, {args.missions} missions, moderate noise, 100 % budget: F1 / entropy / team entropy"
    )
    print("| UAVs | COMA (trained on 4) | AG | lawnmower |")
    print("| --- | --- | --- | --- |")
    for k in args.sizes:
        cells = []
        missions = Missions(env=args.env, count=args.missions, record=1, options={"split": "test", "n_uavs": k})
        for method in methods:
            res = fly(method, missions)
            f1, ent, team = (np.asarray(getattr(res, m))[:, -1].mean() for m in ("f1", "entropy", "team_entropy"))
            cells.append(f"{f1:.3f} / {ent:.3f} / {team:.3f}")
        print(f"| {k} | " + " | ".join(cells) + " |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
