"""How fast does COMA train? Missions per second of ``learn()`` with a breakdown.

    python benchmarks/train_speed.py                          # the main config: env3 entry of coma.yml (SenDFuse)
    python benchmarks/train_speed.py --variant mean-cbam      # the same with mean fusion
    python benchmarks/train_speed.py --env env1 --threads 2

The model and env are built exactly as ``sb3-coma train`` builds them from ``zoo_configs/coma.yml``
(8 env copies, 4 UAVs, budget 15, CBAM actor and critic, gain inputs, the library defaults), without
the validation missions. Prints joint steps/s and missions/s of ``learn()`` and where the time
goes: env stepping (world, sensor, channel), fusion (SenDFuse or mean), the actor's forward passes
while collecting, the critic's update (targets, forward, backward) and the actor's update
(the rest of ``train``). The first rollout is a warm-up (imports, allocator, oneDNN kernel
selection) and is not timed.
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from collections.abc import Callable
from typing import Any

# Idle OpenMP threads sleep instead of spinning: on a shared 2-core machine, spinning threads
# steal the core the env (or another process) needs, and small batches run several times slower.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch as th  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402

from sb3_coma.app.export import fusion_wrapper  # noqa: E402
from sb3_coma.app.training import build_model, make_training_env, plan_run  # noqa: E402

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


def timed(obj: Any, name: str, seconds: dict[str, float], bucket: str) -> None:
    """Replace ``obj.name`` by a wrapper that adds its wall time to ``seconds[bucket]``."""
    inner: Callable[..., Any] = getattr(obj, name)

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        tic = time.perf_counter()
        try:
            return inner(*args, **kwargs)
        finally:
            seconds[bucket] += time.perf_counter() - tic

    setattr(obj, name, wrapper)


def parse_args() -> argparse.Namespace:
    """The command-line options (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="env3")
    parser.add_argument("--variant", default=None, help="a variant of zoo_configs/coma.yml, e.g. mean-cbam")
    parser.add_argument("--rollouts", type=int, default=6, help="timed rollouts after the warm-up one")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def main() -> None:
    """Warm up, time ``--rollouts`` rollouts + updates with every part instrumented, print the split."""
    args = parse_args()
    th.set_num_threads(args.threads)
    plan = plan_run(env=args.env, variant=args.variant, seed=args.seed, device="cpu")
    venv = make_training_env(plan.cfg, seed=plan.seed)
    model = build_model(plan, venv, device="cpu")
    budget = int(plan.cfg.env_kwargs.get("budget", 15))
    per_rollout = model.n_steps * model.n_copies  # joint steps
    model.learn(per_rollout)  # warm-up rollout + update, not timed

    seconds: dict[str, float] = defaultdict(float)
    timed(model.env, "step_wait", seconds, "env + fusion")
    fusion = fusion_wrapper(model.env)
    if fusion is not None:
        timed(fusion, "fuse", seconds, "fusion")
    timed(model.policy, "act", seconds, "actor (collect)")
    for name in ("_td_targets", "_critic_step"):
        timed(model, name, seconds, "critic update")
    timed(model.policy, "q_values", seconds, "critic forward")
    timed(model, "train", seconds, "train")
    timer = PhaseTimer()
    joint_steps = args.rollouts * per_rollout
    start = time.perf_counter()
    model.learn(joint_steps, callback=timer, reset_num_timesteps=False)
    wall = time.perf_counter() - start

    steps_per_s = joint_steps / wall
    critic = seconds["critic update"] + seconds["critic forward"]
    parts = {
        "env (world, sensor, channel)": seconds["env + fusion"] - seconds["fusion"],
        f"fusion ({fusion.name if fusion is not None else 'none'})": seconds["fusion"],
        "actor forward (collect)": seconds["actor (collect)"],
        "critic update": critic,
        "actor update": seconds["train"] - critic,
    }
    parts["other (buffer, callbacks, logging)"] = wall - sum(parts.values())
    print(
        f"setting    : {plan.cfg.env_id} (variant {args.variant or 'none'}), {model.n_copies} env copies x "
        f"n_steps {model.n_steps}, {model.n_agents} UAVs, budget {budget}, {type(model.policy).__name__}, "
        f"batch {model.batch_size}, {args.threads} torch thread(s)"
    )
    print(f"timed      : {joint_steps} joint steps ({args.rollouts} rollouts + updates) in {wall:.1f} s")
    print(
        f"throughput : {steps_per_s:.0f} joint steps/s = {steps_per_s / budget:.2f} missions/s "
        f"(target 20 with SenDFuse)"
    )
    for name, value in parts.items():
        print(f"  {name:36s} {value:6.2f} s  {100 * value / wall:5.1f} %")


if __name__ == "__main__":
    main()
