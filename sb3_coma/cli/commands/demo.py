"""``sb3-coma demo``: one mission with random valid actions, printing F1 and entropy per step."""

from __future__ import annotations

import argparse

import numpy as np

import uav_ipp
from sb3_coma.app.arguments import add_env_argument, add_seed_argument
from uav_ipp import layout
from uav_ipp.config import count_value

NAME = "demo"
HELP = "fly one mission with random valid actions and print F1 / entropy per step"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_env_argument(parser)
    parser.add_argument("--noise", default="moderate", help="channel noise: none, moderate, loud")
    parser.add_argument("--uavs", type=count_value, default=4, help="number of UAVs (default 4)")
    parser.add_argument("--budget", type=count_value, default=15, help="decisions per UAV (default 15)")
    add_seed_argument(parser)


def run(args: argparse.Namespace) -> int:
    env = uav_ipp.make_env(args.env, noise=args.noise, n_uavs=args.uavs, budget=args.budget)
    rng = np.random.default_rng(args.seed)
    obs, _ = env.reset(seed=args.seed)
    m = env.metrics()
    print(f"{args.env}: {args.uavs} UAVs, budget {args.budget}, noise {args.noise}, random valid actions")
    print(f"step  0  f1={m['f1']:.3f}  entropy={m['entropy']:.3f}")
    total = 0.0
    while env.agents:
        actions = {a: int(rng.choice(np.flatnonzero(obs[a][layout.KEY_MASK]))) for a in env.agents}
        obs, rewards, _, _, infos = env.step(actions)
        total += rewards["uav_0"]
        info = infos["uav_0"]
        print(
            f"step {env._steps:2d}  f1={info['f1']:.3f}  entropy={info['entropy']:.3f}  reward={rewards['uav_0']:+.3f}"
        )
    print(f"team return {total:+.3f}")
    return 0
