"""How fast does COMA train on the paper's setting? Missions per second of ``learn()``.

    python benchmarks/train_speed.py                      # env3, 4 UAVs, budget 15, CBAM, batch 512
    python benchmarks/train_speed.py --fusion sendfuse    # with the SenDFuse wrapper
    python benchmarks/train_speed.py --policy CnnPolicy --n-envs 4 --threads 1

Prints joint steps/s, missions/s, the split between collecting rollouts (env + actor) and
training (critic + actor updates), and the projected wall-clock of the paper's 1200 missions.
The first rollout is a warm-up (imports, allocator, oneDNN kernel selection) and is not timed.
"""

from __future__ import annotations

import argparse
import os
import time

# Idle OpenMP threads sleep instead of spinning: on a shared 2-core machine, spinning threads
# steal the core the env (or another process) needs, and small batches run several times slower.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch as th  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402

PAPER_MISSIONS = 1200


class PhaseTimer(BaseCallback):
    """Wall time spent collecting rollouts; the rest of ``learn()`` is training and logging."""

    def __init__(self) -> None:
        super().__init__()
        self.rollout_s = 0.0
        self._start = 0.0

    def _on_rollout_start(self) -> None:
        self._start = time.perf_counter()

    def _on_rollout_end(self) -> None:
        self.rollout_s += time.perf_counter() - self._start

    def _on_step(self) -> bool:
        return True


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="env3")
    parser.add_argument("--fusion", default="mean", choices=["mean", "sendfuse"])
    parser.add_argument("--uavs", type=int, default=4)
    parser.add_argument("--budget", type=int, default=15)
    parser.add_argument("--policy", default="CBAMPolicy", choices=["CBAMPolicy", "CnnPolicy"])
    parser.add_argument("--batch-size", type=int, default=512, help="joint steps per minibatch (paper: 512)")
    parser.add_argument("--n-envs", type=int, default=8, help="env copies stepped together")
    parser.add_argument("--rollouts", type=int, default=3, help="timed rollouts after the warm-up one")
    parser.add_argument("--threads", type=int, default=2, help="torch intra-op threads (2 cores: 2)")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    th.set_num_threads(args.threads)
    import envs
    from sb3_coma.coma import COMA

    venv = envs.make_vec_env(
        args.env, n_envs=args.n_envs, fusion=args.fusion, seed=args.seed, n_uavs=args.uavs, budget=args.budget
    )
    model = COMA(args.policy, venv, batch_size=args.batch_size, seed=args.seed)
    per_rollout = model.n_steps * model.n_copies  # joint steps
    model.learn(per_rollout)  # warm-up rollout + update, not timed

    timer = PhaseTimer()
    joint_steps = args.rollouts * per_rollout
    start = time.perf_counter()
    model.learn(joint_steps, callback=timer, reset_num_timesteps=False)
    wall = time.perf_counter() - start

    steps_per_s = joint_steps / wall
    missions_per_s = steps_per_s / args.budget
    paper_s = PAPER_MISSIONS / missions_per_s
    print(
        f"setting    : {args.env}, {args.uavs} UAVs, budget {args.budget}, fusion {args.fusion}, "
        f"{args.policy}, batch {args.batch_size} joint steps, {args.n_envs} env copies x n_steps {model.n_steps}, "
        f"{args.threads} torch threads"
    )
    print(f"timed      : {joint_steps} joint steps ({args.rollouts} rollouts + updates) in {wall:.1f} s")
    print(
        f"split      : rollouts {timer.rollout_s:.1f} s ({100 * timer.rollout_s / wall:.0f} %), "
        f"training {wall - timer.rollout_s:.1f} s ({100 * (1 - timer.rollout_s / wall):.0f} %)"
    )
    print(
        f"throughput : {steps_per_s:.0f} joint steps/s = {missions_per_s:.2f} missions/s "
        f"({steps_per_s * args.uavs:.0f} agent transitions/s)"
    )
    print(
        f"projection : {PAPER_MISSIONS} missions = {PAPER_MISSIONS * args.budget} joint steps in "
        f"{paper_s:.0f} s ({paper_s / 60:.1f} min; target <= 5 min)"
    )


if __name__ == "__main__":
    main()
