"""COMA against SB3's PPO as whole processes, in interleaved pairs: the ratio of their wall times.

    python benchmarks/learn_pairs.py rware_tiny --pairs 5

Each pair runs ``benchmarks/learn_once.py TASK coma`` then ``benchmarks/learn_once.py TASK ippo`` (the
benchmark's trainee: its zoo entry, seed 0, one torch thread; start-up included), so a machine whose
speed drifts moves both runs of a pair alike. It prints each pair's COMA / PPO wall-time ratio and the
median, minimum and maximum of the ratios: below 1 COMA is faster. One warm-up pair is not counted (the
first run pays for the operating system's file cache). Only the standard library times; no thresholds.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

from sb3_coma.experiments.marl_benchmark import TASKS

LEARN_ONCE = Path(__file__).resolve().with_name("learn_once.py")


def wall_seconds(task: str, learner: str, joint_steps: int) -> float:
    """One whole process of ``learn_once.py``: its wall time from start to exit (it must succeed)."""
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, str(LEARN_ONCE), task, learner, "--joint-steps", str(joint_steps)],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", choices=sorted(TASKS), help="a benchmark task key")
    parser.add_argument("--pairs", type=int, default=5, help="counted pairs (after one warm-up pair)")
    parser.add_argument("--joint-steps", type=int, default=20_480, help="joint env steps each run learns")
    args = parser.parse_args()
    for flag, value in (("--pairs", args.pairs), ("--joint-steps", args.joint_steps)):
        if value < 1:
            parser.error(f"{flag} {value}: must be at least 1")
    ratios = []
    for pair in range(args.pairs + 1):
        coma = wall_seconds(args.task, "coma", args.joint_steps)
        ppo = wall_seconds(args.task, "ippo", args.joint_steps)
        if pair == 0:
            continue
        ratios.append(coma / ppo)
        print(f"pair {pair}: COMA {coma:.2f} s, PPO {ppo:.2f} s, ratio {ratios[-1]:.3f}", flush=True)
    print(
        f"{args.task}: COMA / PPO wall time, median {statistics.median(ratios):.3f} "
        f"(min {min(ratios):.3f}, max {max(ratios):.3f}) over {len(ratios)} pair{'s' if len(ratios) > 1 else ''}"
    )


if __name__ == "__main__":
    main()
