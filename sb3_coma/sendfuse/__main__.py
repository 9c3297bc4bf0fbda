"""``python -m sb3_coma.sendfuse [--tune-malloc]``: time one SenDFuse deployment step on the CPU."""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Sequence

import torch

from sb3_coma.sendfuse.network import DEFAULT_GRID_SIZE, SenDFuseNet, tune_cpu_allocator
from uav_ipp.config import count_value


def main(argv: Sequence[str] | None = None) -> None:
    """Time one deployment step on the CPU (an untrained network of the shipped size, random maps).

    Reports wall time and the CPU time of the timing thread: on a
    shared machine other processes inflate wall time, while thread CPU time stays close to what
    an idle core would give.
    """
    parser = argparse.ArgumentParser(description="Time SenDFuseNet.fuse for one multi-UAV step.")
    parser.add_argument("--uavs", type=count_value, default=4, help="fusions per step (B)")
    parser.add_argument("--sources", type=count_value, default=4, help="received maps per fusion (n)")
    parser.add_argument("--grid", type=count_value, default=DEFAULT_GRID_SIZE, help="R")
    parser.add_argument("--threads", type=count_value, default=1, help="torch.set_num_threads")
    parser.add_argument("--repeats", type=count_value, default=500)
    parser.add_argument(
        "--tune-malloc", action="store_true", help="call tune_cpu_allocator() first (as the env wrapper may)"
    )
    args = parser.parse_args(argv)
    tuned = tune_cpu_allocator() if args.tune_malloc else False
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    model = SenDFuseNet(grid_size=args.grid).eval()
    maps = torch.rand(args.uavs, args.sources, args.grid, args.grid)
    valid = torch.ones(args.uavs, args.sources, dtype=torch.bool)
    wall: list[float] = []
    cpu: list[float] = []
    with torch.inference_mode():
        for _ in range(30):  # warm-up: oneDNN primitive creation, allocator
            model.fuse(maps, valid)
        for _ in range(args.repeats):
            start_wall, start_cpu = time.perf_counter(), time.thread_time()
            model.fuse(maps, valid)
            cpu.append((time.thread_time() - start_cpu) * 1e3)
            wall.append((time.perf_counter() - start_wall) * 1e3)
    print(
        f"SenDFuse fuse: B={args.uavs} fusions x n={args.sources} sources, R={args.grid}, "
        f"{args.threads} thread(s), {model.num_parameters()} parameters, "
        f"allocator tuned: {'yes' if tuned else 'no'}"
    )
    for name, times in (("wall", sorted(wall)), ("thread CPU", sorted(cpu))):
        median = statistics.median(times)
        print(
            f"  {name:>10}: median {median:.2f} ms, p10 {times[len(times) // 10]:.2f} ms, "
            f"p90 {times[len(times) * 9 // 10]:.2f} ms per step; {median / args.uavs:.2f} ms per UAV-step"
        )


if __name__ == "__main__":
    main()
