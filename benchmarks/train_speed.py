"""How fast does COMA train? Missions per second of ``learn()`` for 1 and 2 workers, with a breakdown.

    python benchmarks/train_speed.py                          # the main config: env3 entry of coma.yml (SenDFuse)
    python benchmarks/train_speed.py --variant mean-cbam      # the same with mean fusion
    python benchmarks/train_speed.py --workers 1,2,4 --threads 2

The model and env are built exactly as ``sb3-coma train`` builds them from ``zoo_configs/coma.yml``
(8 env copies, 4 UAVs, budget 15, CBAM actor and critic, gain inputs, the library defaults), without
the validation missions, once per ``--workers`` value (the env copies and their fusion in that many
worker processes; 1 = in the learner's process). Prints joint steps/s and missions/s of ``learn()``
and where the time goes: collection (env stepping and fusion; with one worker split into env and
fusion), the actor's forward passes while collecting, the critic's update (targets, forward,
backward) and the actor's update (the rest of ``train``). The first rollout is a warm-up (imports,
allocator, oneDNN kernel selection, worker start-up) and is not timed. The same run times the raw
ParallelEnv on one core (random valid actions), so the ratio learn / raw env compares across
machines.
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

import numpy as np
import torch as th
from stable_baselines3.common.callbacks import BaseCallback

import uav_ipp
from sb3_coma.app.export import fusion_wrapper
from sb3_coma.app.training import build_model, make_training_env, plan_run

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
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts to time")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads of the learner")
    parser.add_argument("--raw-missions", type=int, default=40, help="missions of the raw env timing")
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args()


def raw_env_missions_per_s(env: str, missions: int, seed: int) -> float:
    """Missions/s of the raw ParallelEnv in this process (one core), random valid actions."""
    world = uav_ipp.make_env(env, split="train", reward="metrics", action_gain=True)
    rng = np.random.default_rng(seed)
    start = 0.0
    for k in range(-1, missions):  # mission -1 is a warm-up: numba kernels compiled or loaded from cache
        if k == 0:
            start = time.perf_counter()
        obs, _ = world.reset(seed=seed + k + 1)
        while world.agents:
            actions = {a: int(rng.choice(np.flatnonzero(obs[a]["action_mask"]))) for a in world.agents}
            obs, *_ = world.step(actions)
    return missions / (time.perf_counter() - start)


def time_learn(args: argparse.Namespace, workers: int) -> tuple[int, float, dict[str, float], str]:
    """(missions, wall seconds, breakdown, setting line) of ``--rollouts`` timed rollouts with ``workers``."""
    plan = plan_run(env=args.env, variant=args.variant, seed=args.seed, device="cpu")
    venv = make_training_env(plan.cfg, seed=plan.seed, workers=workers)
    model = build_model(plan, venv, device="cpu")
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
    start = time.perf_counter()
    model.learn(args.rollouts * per_rollout, callback=PhaseTimer(), reset_num_timesteps=False)
    wall = time.perf_counter() - start
    venv.close()
    critic = seconds["critic update"] + seconds["critic forward"]
    where = "in the learner" if workers == 1 else f"in {workers} worker processes"
    parts = {
        f"collection: env ({where})": seconds["env + fusion"] - seconds["fusion"],
        f"collection: fusion ({fusion.name if fusion is not None else 'with the env'})": seconds["fusion"],
        "actor forward (collect)": seconds["actor (collect)"],
        "critic update": critic,
        "actor update": seconds["train"] - critic,
    }
    parts["other (buffer, callbacks, logging)"] = wall - sum(parts.values())
    setting = (
        f"{plan.cfg.env_id} (variant {args.variant or 'none'}), {model.n_copies} env copies x n_steps "
        f"{model.n_steps}, {model.n_agents} UAVs, {type(model.policy).__name__}, batch {model.batch_size}, "
        f"{args.threads} torch thread(s) in the learner"
    )
    return args.rollouts * per_rollout // int(plan.cfg.env_kwargs.get("budget", 15)), wall, parts, setting


def main() -> None:
    """Time ``learn()`` per worker count and the raw env; print missions/s, ratios and the split."""
    args = parse_args()
    th.set_num_threads(args.threads)
    raw = raw_env_missions_per_s(args.env, args.raw_missions, args.seed)
    print(f"device     : cpu ({os.cpu_count()} cores), torch {th.__version__}")
    print(f"raw env    : {raw:.1f} missions/s ({args.env}, one process, random valid actions)")
    speeds: dict[int, float] = {}
    for workers in (int(w) for w in args.workers.split(",")):
        missions, wall, parts, setting = time_learn(args, workers)
        speeds[workers] = missions / wall
        print(f"\nworkers {workers}  : {setting}")
        print(
            f"  learn()  : {speeds[workers]:.2f} missions/s ({missions} missions in {wall:.1f} s); "
            f"learn / raw env = {speeds[workers] / raw:.2f} (target >= 0.30; 20 missions/s)"
        )
        for name, value in parts.items():
            print(f"  {name:44s} {value:6.2f} s  {100 * value / wall:5.1f} %")
    if 1 in speeds and len(speeds) > 1:
        for workers, speed in speeds.items():
            if workers != 1:
                print(f"\nscaling    : {workers} workers at {speed / speeds[1]:.2f}x the speed of 1")


if __name__ == "__main__":
    main()
