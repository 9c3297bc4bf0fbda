"""One ``learn()`` of a benchmark learner on a benchmark task, as a whole process.

    python benchmarks/learn_once.py rware_tiny coma

The learner benchmark's speed phase (``marl_benchmark --phases speed``) times ``learn()`` inside one
process; this script is the same work as a whole process, start-up included, so that an outside timer
can pair COMA against SB3's PPO run by run (``benchmarks/learn_pairs.py`` does, with the standard
library), a ratio that survives a machine whose speed drifts. The model is the benchmark's trainee (its
entry in ``zoo_configs/marl/``, seed 0, one torch thread), trained by the speed phase's own function; it
prints that phase's in-process rate too.
"""

from __future__ import annotations

import argparse
import dataclasses

from sb3_coma.experiments.marl_benchmark import TASKS, TRAINED, _learn_rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", choices=sorted(TASKS), help="a benchmark task key")
    parser.add_argument("learner", choices=TRAINED, help="its entry in zoo_configs/marl/")
    parser.add_argument("--joint-steps", type=int, default=20_480, help="joint env steps to learn")
    args = parser.parse_args()
    task = dataclasses.replace(TASKS[args.task], joint_steps=args.joint_steps)
    # the speed phase's own measurement, so that both time the same work
    print(f"{args.learner} on {args.task}: {_learn_rate(args.learner, task):.0f} learn() joint steps/s")


if __name__ == "__main__":
    main()
