"""AG under the channel: Table I metrics (global map) and team metrics (each UAV's own M_i) at
100 % budget, for every map, noise preset and decoder, on the paper's missions.

What it measures: whether, and through which path, channel noise reaches AG's results. The
global metrics never see the channel (fixed actions give bit-identical global maps); AG plans
from each UAV's own M_i, so the channel reaches the global metrics only through AG's decisions,
and reaches the team metrics directly.

    python -m sb3_coma.experiments.ag_channel_table [--trials 10] [--maps env1 env2 env3]

Prints a Markdown table (mean +- std over the trials) and the wall time. The AG kernels are
single-threaded numba code, so the figures do not depend on thread settings.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from sb3_coma.app.evaluation import Method, Missions
from sb3_coma.app.evaluation import fly as fly_method
from uav_ipp.config import count_value

#: The final metrics of one mission, in table order.
KEYS = ("f1", "entropy", "team_f1", "team_entropy")

#: AG as this table names it: ipp-marl's class weighting, greedy (not the map family's default).
AG_CLASS = Method("ag", "ag", planner_kwargs={"weighting": "class"})


def fly(name: str, trials: int, **options: Any) -> np.ndarray:
    """(trials, 4) final metrics of AG on ``trials`` seeded paper missions (one batch: one env copy per trial)."""
    result = fly_method(AG_CLASS, Missions(env=name, count=trials, seed=0, n_envs=trials, options=options))
    return np.column_stack([np.asarray(getattr(result, key))[:, -1] for key in KEYS])


def main(argv: Sequence[str] | None = None) -> int:
    """Fly AG under every (noise, decoder) setting of every map and print one table row each."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=count_value, default=10)
    parser.add_argument("--maps", nargs="+", default=["env1", "env2", "env3"])
    args = parser.parse_args(argv)
    print(f"AG (class weighting, greedy), split=paper, {args.trials} trials, 100 % budget, mean +- std")
    print("| map | noise | decoder | F1 | entropy | team F1 | team entropy |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    start = time.perf_counter()
    for name in args.maps:
        for noise in ("none", "moderate", "loud"):
            for decoder in ("soft", "threshold"):
                if noise == "none" and decoder == "threshold":
                    continue  # identical to soft without noise
                m = fly(name, args.trials, noise=noise, decoder=decoder)
                cells = " | ".join(f"{mu:.3f} +- {sd:.3f}" for mu, sd in zip(m.mean(0), m.std(0)))
                print(f"| {name} | {noise} | {decoder} | {cells} |", flush=True)
    print(f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
