"""SenDFuse deployment speed: the fused map per UAV-step, and the env step rate it leaves.

Two figures (docs/design.md §4; target <= 2 ms per UAV-step on one core):

1. ``SenDFuseNet.fuse`` for 4 UAVs x 4 received maps (R = 44) on one thread, with the shipped
   weights (a fresh network if the file is missing: the cost does not depend on the values);
   realistic inputs come from a lockstep mission on env3 so invalid slots are skipped as in use.
   Reported as the median over repeats, in ms per step and per UAV-step, wall and thread-CPU time
   (on a shared machine other processes inflate wall time, not the thread's CPU time).
2. Joint steps per second of ``uav_ipp.make_vec_env("env3", fusion=...)`` for "mean" vs "sendfuse"
   (4 UAVs, budget 15, one copy, random valid actions), one thread.

Run: ``python benchmarks/sendfuse_speed.py [--repeats 300] [--steps 600]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

import uav_ipp
from sb3_coma.sendfuse.network import SenDFuseNet, tune_cpu_allocator
from sb3_coma.sendfuse.weights import SenDFuseWeightsError, default_weights_path, load_weights
from uav_ipp import layout


def _network() -> tuple[SenDFuseNet, str]:
    """The shipped network, else a fresh one: the fusion's cost does not depend on the weights."""
    try:
        return load_weights(default_weights_path(44)), "shipped weights"
    except SenDFuseWeightsError:
        torch.manual_seed(0)
        return SenDFuseNet(grid_size=44).eval(), "untrained network (shipped weights missing)"


def _realistic_inputs(uavs: int, sources: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Received maps after a few steps of a random env3 mission, all slots valid (worst case)."""
    env = uav_ipp.make_env("env3", n_uavs=max(uavs, sources), noise="moderate", comm_range=float("inf"))
    obs, _ = env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        masks = env.action_masks()
        obs, *_ = env.step({a: int(rng.choice(np.flatnonzero(masks[i]))) for i, a in enumerate(env.possible_agents)})
    maps = np.stack([obs[a][layout.KEY_RECEIVED][:sources] for a in env.possible_agents[:uavs]])
    return torch.from_numpy(maps), torch.ones(uavs, sources, dtype=torch.bool)


def time_fusion(uavs: int = 4, sources: int = 4, repeats: int = 300) -> dict[str, float]:
    """Median wall / thread-CPU milliseconds of one batched fusion step on the current thread count."""
    network, which = _network()
    maps, valid = _realistic_inputs(uavs, sources)
    wall, cpu = [], []
    with torch.inference_mode():
        for _ in range(20):
            network.fuse(maps, valid)
        for _ in range(repeats):
            w0, c0 = time.perf_counter(), time.thread_time()
            network.fuse(maps, valid)
            cpu.append((time.thread_time() - c0) * 1e3)
            wall.append((time.perf_counter() - w0) * 1e3)
    return {
        "wall_ms": statistics.median(wall),
        "cpu_ms": statistics.median(cpu),
        "cpu_p10_ms": sorted(cpu)[len(cpu) // 10],
        "uavs": uavs,
        "sources": sources,
        "weights": which,
    }


def env_rate(fusion: str, steps: int = 600, seed: int = 0) -> float:
    """Joint steps per second of the SB3 vec env with the given fusion wrapper (one copy)."""
    venv = uav_ipp.make_vec_env("env3", n_envs=1, fusion=fusion, seed=seed, n_uavs=4, budget=15)
    rng = np.random.default_rng(seed)
    obs = venv.reset()

    def act(o) -> np.ndarray:
        return np.array([rng.choice(np.flatnonzero(m)) for m in o["action_mask"]])

    for _ in range(20):  # warm-up (numba, oneDNN primitives)
        obs, *_ = venv.step(act(obs))
    start = time.perf_counter()
    for _ in range(steps):
        obs, *_ = venv.step(act(obs))
    rate = steps / (time.perf_counter() - start)
    venv.close()
    return rate


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=300, help="timed fusion steps")
    parser.add_argument("--steps", type=int, default=600, help="timed env steps per fusion")
    parser.add_argument("--tune-malloc", action="store_true", help="apply tune_cpu_allocator() first")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.tune_malloc:
        tune_cpu_allocator()
    t = time_fusion(repeats=args.repeats)
    per_wall, per_cpu = t["wall_ms"] / t["uavs"], t["cpu_ms"] / t["uavs"]
    verdict = "meets" if per_cpu <= 2.0 else "MISSES"
    print(f"SenDFuse fusion, {t['uavs']} UAVs x {t['sources']} received maps, R = 44, 1 thread ({t['weights']}):")
    print(
        f"  {t['wall_ms']:.2f} ms wall / {t['cpu_ms']:.2f} ms thread CPU per step -> "
        f"{per_wall:.2f} ms wall / {per_cpu:.2f} ms CPU per UAV-step ({verdict} the 2 ms target); "
        f"p10 {t['cpu_p10_ms'] / t['uavs']:.2f} ms CPU per UAV-step"
    )
    rates = {fusion: env_rate(fusion, args.steps) for fusion in ("mean", "sendfuse")}
    print("env3 vec env, 4 UAVs, budget 15, 1 copy, random valid actions, 1 thread:")
    for fusion, rate in rates.items():
        print(f"  fusion={fusion:<8} {rate:7.0f} joint steps/s ({4 * rate:7.0f} agent steps/s)")
    print(f"  sendfuse / mean: {rates['sendfuse'] / rates['mean']:.2f}x")


if __name__ == "__main__":
    main()
