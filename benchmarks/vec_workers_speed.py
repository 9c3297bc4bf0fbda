"""Collection speed with the env copies in this process, in worker processes and in Ray actors.

Setting of ``env_throughput.py`` (env3, 4 UAVs, budget 15, moderate noise, uniformly random
*valid* actions, one thread per process) with ``n_envs`` copies: the raw PettingZoo env (one copy,
this process), then ``uav_ipp.make_vec_env`` with ``workers=1`` (in process), ``workers=2``
(subprocess backend) and ``workers=2`` (Ray backend, a local Ray), for the ``mean`` and
``sendfuse`` fusions. A joint step is one step of one env copy (all its UAVs); a mission is
``budget`` joint steps. Each vec env flies one warm-up mission per copy before the timed missions;
building it (processes, Ray, kernels) is reported apart.

    python benchmarks/vec_workers_speed.py [--map env3] [--n-envs 8] [--missions 48] [--parts raw,1,2,ray]

Collection only: no learner runs, so this is the most the workers can add to ``learn()``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")  # also for the workers, which inherit the environment

import numpy as np

import uav_ipp
from uav_ipp import layout

BUDGET, N_UAVS = 15, 4
#: ``--parts`` name -> (workers, backend) of ``uav_ipp.make_vec_env``.
SETUPS = {"1": (1, "subprocess"), "2": (2, "subprocess"), "ray": (2, "ray")}


def pick_valid(masks: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Uniform valid action per row from pre-drawn uniforms (cheap, no per-agent rng calls)."""
    counts = masks.sum(axis=1)
    k = np.floor(u[: len(masks)] * counts).astype(int)
    cum = np.cumsum(masks, axis=1)
    return (cum <= k[:, None]).sum(axis=1)


def bench_raw(name: str, missions: int, seed: int) -> tuple[float, float]:
    """The raw ParallelEnv, one copy in this process: (joint steps/s, missions/s)."""
    env = uav_ipp.make_env(name, n_uavs=N_UAVS, budget=BUDGET)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    steps = 0
    start = time.perf_counter()
    for m in range(missions):
        obs, _ = env.reset(seed=seed + m)
        while env.agents:
            masks = np.stack([obs[a][layout.KEY_MASK] for a in env.possible_agents])
            acts = pick_valid(masks, rng.random(N_UAVS))
            obs, *_ = env.step({a: int(acts[i]) for i, a in enumerate(env.possible_agents)})
            steps += 1
    elapsed = time.perf_counter() - start
    return steps / elapsed, missions / elapsed


def bench_vec(name: str, n_envs: int, missions: int, seed: int, fusion: str, part: str) -> tuple[float, float, float]:
    """``make_vec_env`` with the part's workers/backend: (build s, joint steps/s, missions/s)."""
    workers, backend = SETUPS[part]
    start = time.perf_counter()
    venv = uav_ipp.make_vec_env(
        name, n_envs=n_envs, fusion=fusion, seed=seed, workers=workers, backend=backend, n_uavs=N_UAVS, budget=BUDGET
    )
    rng = np.random.default_rng(seed)
    try:
        obs = venv.reset()
        build = time.perf_counter() - start
        for _ in range(BUDGET):  # warm-up: one mission per copy (first SenDFuse passes, caches)
            obs, *_ = venv.step(pick_valid(obs[layout.KEY_MASK], rng.random(venv.num_envs)))
        vec_steps = max(1, round(missions / n_envs)) * BUDGET
        start = time.perf_counter()
        for _ in range(vec_steps):
            obs, *_ = venv.step(pick_valid(obs[layout.KEY_MASK], rng.random(venv.num_envs)))
        elapsed = time.perf_counter() - start
    finally:
        venv.close()
    joint = vec_steps * n_envs / elapsed
    return build, joint, joint / BUDGET


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="env3")
    parser.add_argument("--n-envs", type=int, default=8)
    parser.add_argument("--missions", type=int, default=48, help="timed missions per setting (all copies together)")
    parser.add_argument("--fusions", default="mean,sendfuse")
    parser.add_argument("--parts", default="raw,1,2,ray", help="raw and/or workers settings: 1, 2, ray")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    parts = args.parts.split(",")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{args.map}, {N_UAVS} UAVs, budget {BUDGET}, n_envs={args.n_envs}, {args.missions} timed missions per row;")
    print(f"{os.cpu_count()} cores, load average {load:.2f} at start")
    print(f"{'setting':<34} {'build s':>8} {'joint steps/s':>14} {'missions/s':>11}")
    if "raw" in parts:
        joint, per_s = bench_raw(args.map, max(1, args.missions // 4), args.seed)
        print(f"{'raw ParallelEnv, 1 copy, 1 process':<34} {'':>8} {joint:>14.0f} {per_s:>11.2f}")
    for fusion in args.fusions.split(","):
        for part in (p for p in parts if p in SETUPS):
            workers, backend = SETUPS[part]
            build, joint, per_s = bench_vec(args.map, args.n_envs, args.missions, args.seed, fusion, part)
            label = f"{fusion}, workers={workers}" + (f" ({backend})" if workers > 1 or backend == "ray" else "")
            print(f"{label:<34} {build:>8.1f} {joint:>14.0f} {per_s:>11.2f}")


if __name__ == "__main__":  # the worker processes (forkserver / spawn) import this module
    main()
