"""Environment throughput: joint steps/s and missions/s on one thread, with peak memory.

Setting of issues #2 / #14: env3, 4 UAVs, budget 15, 493 x 493 belief grid, moderate noise,
per-cell local beliefs fed by cell-level messages, action gains and observations built,
uniformly random *valid* actions, one thread. Measures the raw PettingZoo env and the SB3 vec env
with the ``mean`` and ``sendfuse`` fusion wrappers (SuperSuit + adapter + VecMonitor), after a
warm-up that compiles the kernels, and the memory one env copy holds.

    python benchmarks/env_throughput.py [--map env3] [--missions 200] [--parts raw,mean,sendfuse]

``--parts raw`` times the raw env alone (the kernels' share, a short run for A/B comparisons).
"""

from __future__ import annotations

import argparse
import os
import resource
import time

os.environ.setdefault("NUMBA_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

import uav_ipp
from uav_ipp import layout


def pick_valid(masks: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Uniform valid action per row from pre-drawn uniforms (cheap, no per-agent rng calls)."""
    counts = masks.sum(axis=1)
    k = np.floor(u[: len(masks)] * counts).astype(int)
    cum = np.cumsum(masks, axis=1)
    return (cum <= k[:, None]).sum(axis=1)


def bench_raw(name: str, missions: int, seed: int) -> tuple[float, float]:
    env = uav_ipp.make_env(name, n_uavs=4, budget=15)
    rng = np.random.default_rng(seed)
    env.reset(seed=seed)
    steps = 0
    start = time.perf_counter()
    for m in range(missions):
        obs, _ = env.reset(seed=seed + m)
        while env.agents:
            masks = np.stack([obs[a][layout.KEY_MASK] for a in env.possible_agents])
            acts = pick_valid(masks, rng.random(4))
            obs, *_ = env.step({a: int(acts[i]) for i, a in enumerate(env.possible_agents)})
            steps += 1
    elapsed = time.perf_counter() - start
    return steps / elapsed, missions / elapsed


def bench_vec(name: str, missions: int, seed: int, fusion: str) -> tuple[float, float]:
    venv = uav_ipp.make_vec_env(name, n_envs=1, fusion=fusion, seed=seed, n_uavs=4, budget=15)
    rng = np.random.default_rng(seed)
    obs = venv.reset()
    steps = 0
    start = time.perf_counter()
    for _ in range(missions * 15):
        acts = pick_valid(obs[layout.KEY_MASK], rng.random(4))
        obs, *_ = venv.step(acts)
        steps += 1
    elapsed = time.perf_counter() - start
    return steps / elapsed, steps / 15 / elapsed


def env_state_mib(name: str) -> float:
    """MiB of numpy arrays one env copy holds after a reset (beliefs, tables, sums, scratch)."""
    env = uav_ipp.make_env(name, n_uavs=4, budget=15)
    env.reset(seed=0)
    arrays = [v for v in vars(env).values() if isinstance(v, np.ndarray)]
    arrays += [v for v in vars(env.geometry).values() if isinstance(v, np.ndarray)]
    return sum(a.nbytes for a in arrays) / 2**20


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--map", default="env3")
    parser.add_argument("--missions", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--parts", default="raw,mean,sendfuse", help="comma-separated subset of raw, mean, sendfuse to time"
    )
    args = parser.parse_args()
    parts = set(args.parts.split(","))
    unknown = parts - {"raw", "mean", "sendfuse"}
    if unknown:
        parser.error(f"unknown --parts {sorted(unknown)}; choose from raw, mean, sendfuse")
    bench_raw(args.map, 2, args.seed)  # warm-up: numba cache load / compile
    print(f"map={args.map} uavs=4 budget=15 grid=493x493 missions={args.missions} (one thread)")
    if "raw" in parts:
        sps, mps = bench_raw(args.map, args.missions, args.seed)
        print(f"raw ParallelEnv         : {sps:8.0f} joint steps/s  {mps:7.1f} missions/s")
    if "mean" in parts:
        bench_vec(args.map, 2, args.seed, "mean")  # warm-up: the wrappers
        sps, mps = bench_vec(args.map, args.missions, args.seed, "mean")
        print(f"vec env + mean fusion   : {sps:8.0f} joint steps/s  {mps:7.1f} missions/s")
    if "sendfuse" in parts:
        bench_vec(args.map, 1, args.seed, "sendfuse")  # warm-up: weights, oneDNN kernels
        sps, mps = bench_vec(args.map, max(args.missions // 4, 1), args.seed, "sendfuse")
        print(f"vec env + SenDFuse      : {sps:8.0f} joint steps/s  {mps:7.1f} missions/s (one copy, 4 UAVs per pass)")
    print(f"state of one env copy   : {env_state_mib(args.map):8.1f} MiB (every numpy array the env holds)")
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak resident memory    : {peak_mib:8.0f} MiB (whole process, torch/SB3 imports included)")


if __name__ == "__main__":
    main()
