"""How fast does evaluation fly? Missions per second of ``sb3_coma.evaluate`` for 1 and 2 workers.

    python benchmarks/evaluation_speed.py                       # env3 unseen protocol, AG and the shipped env3 model
    python benchmarks/evaluation_speed.py --missions 50 --workers 1,2,4

Each method flies the unseen protocol's ``--missions`` missions once per ``--workers`` value
(whole batches of 10 missions per worker process, ``sb3_coma.app.evaluation``); the worker pool
is started by an untimed warm-up evaluation first, as ``reproduce`` pays that once for dozens of
calls. The same run times the raw ParallelEnv on one core (random valid actions), so the ratios
compare across machines. Checks that every worker count gives the same final metrics.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np
import torch as th

import uav_ipp
from sb3_coma import evaluate


def raw_env_rate(env: str, missions: int) -> float:
    """Missions/s of the raw ParallelEnv in this process (one core), masked random actions."""
    world = uav_ipp.make_env(env, split="train", start="random")
    world.reset(seed=0)  # numba kernels compiled or loaded from cache before the clock starts
    tic = time.perf_counter()
    for seed in range(1, missions + 1):
        obs, _ = world.reset(seed=seed)
        while world.agents:
            obs, *_ = world.step({a: world.action_space(a).sample(mask=obs[a]["action_mask"]) for a in world.agents})
    return missions / (time.perf_counter() - tic)


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="env3")
    parser.add_argument("--methods", default="ag,env3", help="comma-separated methods (default ag,env3)")
    parser.add_argument("--missions", type=int, default=50)
    parser.add_argument("--workers", default="1,2")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    th.set_num_threads(1)
    counts = [int(w) for w in args.workers.split(",")]
    raw = raw_env_rate(args.env, 30)
    print(f"raw env ({args.env}, one core, random valid actions): {raw:.1f} missions/s")
    for method in args.methods.split(","):
        finals = {}
        base = None
        for workers in counts:
            evaluate(method, env=args.env, protocol="unseen", n_trials=20, record=0, workers=workers)  # warm-up
            tic = time.perf_counter()
            result = evaluate(
                method, env=args.env, protocol="unseen", n_trials=args.missions, record=0, workers=workers
            )
            rate = args.missions / (time.perf_counter() - tic)
            base = base or rate
            finals[workers] = np.stack([result.f1[:, -1], result.entropy[:, -1]])
            print(
                f"{method:>8} workers={workers}: {rate:6.2f} missions/s  x{rate / base:.2f} vs workers={counts[0]}"
                f"  ratio to raw env {rate / raw:.3f}"
            )
        same = all(np.array_equal(finals[counts[0]], f) for f in finals.values())
        print(f"{method:>8} same final metrics for every worker count: {same}")


if __name__ == "__main__":
    main()
