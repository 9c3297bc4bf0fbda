"""Paired standard errors of planner comparisons on shared unseen missions.

    python -m sb3_coma.experiments.paired_se --env env3 --missions 32

Flies AG, AG with look-ahead 2, AG with communication-only knowledge and the lawnmower on the same
unseen missions and prints, for each comparison with AG, the paired difference of final F1 and
entropy with its per-mission and scene-clustered standard errors. Run on two versions of the
world (for example before and after common random numbers: docs/environment.md) it measures how
much of a paired standard error is noise that the methods did not share.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from sb3_coma.app.arguments import add_env_argument, add_missions_argument, add_seed_argument
from sb3_coma.app.evaluation import Method, Missions, fly
from sb3_coma.stats.paired import paired_difference

#: (label, baseline name, planner options) of the methods compared with AG.
METHODS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("ag-k2", "ag", {"lookahead": 2}),
    ("ag-comm", "ag", {"knowledge": "comm"}),
    ("lawnmower", "lawnmower", {}),
)


def main(argv: list[str] | None = None) -> int:
    """Fly the methods, print one JSON line per comparison and metric."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_env_argument(parser)
    add_missions_argument(parser, 32, "method (unseen missions)")
    add_seed_argument(parser)
    args = parser.parse_args(argv)
    unseen = Missions(env=args.env, protocol="unseen", count=args.missions, seed=args.seed)
    ag = fly(Method("ag", "ag"), unseen)
    for label, name, options in METHODS:
        try:
            other = fly(Method(label, name, planner_kwargs=options), unseen)
        except ValueError as exc:  # a planner option this version does not have
            print(json.dumps({"b": label, "skipped": str(exc)}))
            continue
        for metric in ("f1", "entropy"):
            d = paired_difference(other, ag, metric)
            row: dict[str, Any] = {"a": label, "b": "ag", "metric": metric, "diff": d.diff, "se_missions": d.se}
            row["se_scenes"] = getattr(d, "se_clustered", None)
            print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())
