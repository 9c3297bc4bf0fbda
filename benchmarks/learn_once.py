"""One ``learn()`` of a benchmark learner on a benchmark task, as a whole process, for ``farm-bench``.

    farm-bench -n 5 --timeout 600 --vs "python benchmarks/learn_once.py rware_tiny ippo" \\
        -- python benchmarks/learn_once.py rware_tiny coma

The learner benchmark's speed phase (``marl_benchmark --phases speed``) times ``learn()`` inside one
process; this script lets ``farm-bench`` time the same work from outside, start-up included, pairing
COMA against SB3's PPO run by run so that the ratio survives a machine whose speed drifts. The model is
the benchmark's trainee (its entry in ``zoo_configs/marl/``, seed 0, one torch thread).
"""

from __future__ import annotations

import argparse
import dataclasses

import torch as th

from sb3_coma.experiments.marl_benchmark import TASKS, _joint_to_learn, _trainee


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("task", choices=sorted(TASKS), help="a benchmark task key")
    parser.add_argument("learner", choices=("coma", "mappo", "ippo"), help="its entry in zoo_configs/marl/")
    parser.add_argument("--joint-steps", type=int, default=20_480, help="joint env steps to learn")
    args = parser.parse_args()
    th.set_num_threads(1)
    task = dataclasses.replace(TASKS[args.task], joint_steps=args.joint_steps)
    model, venv, recorder = _trainee(args.learner, task, 0)
    model.learn(_joint_to_learn(args.learner, task, recorder.n_agents))
    venv.close()


if __name__ == "__main__":
    main()
