"""Per-step planning time of each method: AG, lawnmower, random and a COMA actor.

Run: ``python benchmarks/planning_time.py [--env env1] [--missions 5] [--copies 1,10]``

Times only the ``predict`` call (what a UAV team would run on board each step), with the env
stepping outside the timer. ``copies`` sets how many missions decide in one batched call: 1 is
one team of 4 UAVs deciding alone; larger batches show the amortised cost in evaluation. The COMA
actor is an untrained ``CBAMPolicy`` (same network, same cost as a trained one) on CPU.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

import numpy as np
import torch

import uav_ipp
from sb3_coma import COMA
from sb3_coma.baselines import make_planner


def _coma(venv: Any) -> COMA:
    """An untrained COMA actor on this env, on one torch thread: the same network, so the same cost
    per decision as a trained one."""
    torch.set_num_threads(1)
    return COMA("CBAMPolicy", venv, seed=0, device="cpu")


def time_method(method: str, env: str, copies: int, missions: int, seed: int) -> np.ndarray:
    """Wall time (ms) of every ``predict`` call over ``missions`` batches of ``copies`` missions."""
    venv = uav_ipp.make_vec_env(env, n_envs=copies, fusion="mean", seed=seed)
    policy = _coma(venv) if method == "coma" else make_planner(method, venv, seed=seed)
    budget = venv.get_attr("config", indices=[0])[0].budget
    times = []
    obs = venv.reset()
    policy.predict(obs, deterministic=True)  # warm-up: caches, first-call allocations
    for _ in range(missions):
        obs = venv.reset()
        for _ in range(budget):
            tic = time.perf_counter()
            actions, _ = policy.predict(obs, deterministic=True)
            times.append((time.perf_counter() - tic) * 1e3)
            obs, _, _, _ = venv.step(actions)
    venv.close()
    return np.asarray(times)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="env1")
    parser.add_argument("--missions", type=int, default=5)
    parser.add_argument("--copies", default="1,10", help="comma-separated batch sizes (missions per predict call)")
    parser.add_argument("--methods", default="random,lawnmower,ag,coma")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    n_agents = uav_ipp.make_env(args.env).n_uavs
    print(f"{args.env}: predict wall time, {args.missions} missions per row, {n_agents} UAVs per mission")
    print(f"{'method':<10} {'copies':>6} {'ms/step (mean)':>15} {'ms/step (p95)':>14} {'ms/UAV decision':>16}")
    for copies in [int(c) for c in args.copies.split(",")]:
        for method in [m.strip() for m in args.methods.split(",") if m.strip()]:
            t = time_method(method, args.env, copies, args.missions, args.seed)
            if t.size == 0:
                continue
            print(
                f"{method:<10} {copies:>6} {t.mean():>15.3f} {np.percentile(t, 95):>14.3f} "
                f"{t.mean() / (copies * n_agents):>16.4f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
