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

import uav_ipp
from sb3_coma.baselines import make_planner
from sb3_coma.common.joint import resolve_n_agents

__all__ = ["KEYS", "fly", "main"]

#: The final metrics of one mission, in table order.
KEYS = ("f1", "entropy", "team_f1", "team_entropy")


def fly(name: str, trials: int, **options: Any) -> np.ndarray:
    """(trials, 4) final metrics of AG on ``trials`` seeded paper missions (one env copy per trial)."""
    venv = uav_ipp.make_vec_env(name, n_envs=trials, fusion="mean", seed=0, monitor=False, **options)
    planner = make_planner("ag", venv, seed=0)
    obs = venv.reset()
    n = resolve_n_agents(venv)
    final = np.zeros((trials, len(KEYS)))
    for _ in range(venv.get_attr("config", indices=[0])[0].budget):
        assert isinstance(obs, dict)  # the vec envs of uav_ipp.make_vec_env have Dict observations
        actions, _ = planner.predict(obs)
        obs, _, dones, infos = venv.step(actions)
        for c in range(trials):
            if dones[c * n]:
                final[c] = [infos[c * n][k] for k in KEYS]
    venv.close()
    return final


def main(argv: Sequence[str] | None = None) -> int:
    """Fly AG under every (noise, decoder) setting of every map and print one table row each."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=10)
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
