"""Learned policies against each other (and AG) on the same unseen missions: paired differences.

What it measures: whether one learner (e.g. COMA) beats another (IPPO, MAPPO) or AG on shared
unseen missions (``protocol="unseen"``: ``split="test"``, random starts), with the scene-clustered
paired test that says when a gap is a tie.

    python -m sb3_coma.experiments.learners_paired --env env1 --missions 50 --fusion mean \\
        coma=/tmp/coma_env1/coma_env1.zip ippo=/tmp/ippo_env1/ippo_env1.zip mappo=/tmp/mappo_env1/mappo_env1.zip

Each ``label=path`` is a COMA zip or an SB3 PPO zip from ``python -m sb3_coma.experiments.ippo_vs_ag``
(IPPO / MAPPO); the first one is compared with every other and with AG. Every method flies the
same unseen missions (trial k = env seed k); a model's observation options (``action_gain``,
``observation``) follow what it was trained with. Prints final F1 / entropy and team F1 / entropy,
mean over the missions, and the paired difference first - other +- standard error clustered by
scene, with the t-test verdict of ``sb3_coma.common.paired`` (no Holm correction here: one
question per cell).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import PPO

import sb3_coma.common.marl_baselines  # noqa: F401  (the IPPO / MAPPO policy classes PPO.load needs)
from sb3_coma import COMA, evaluate
from sb3_coma.common.paired import paired_difference

__all__ = ["METRICS", "load", "main"]

#: Final metrics compared, in table order.
METRICS = ("f1", "entropy", "team_f1", "team_entropy")


def load(path: str) -> Any:
    """A COMA zip, else an SB3 PPO zip (IPPO / MAPPO): the zip does not say which it holds."""
    try:
        return COMA.load(path, device="cpu")
    except (KeyError, ValueError, TypeError, AttributeError):
        return PPO.load(path, device="cpu")


def _print_tables(env: str, missions: int, results: dict[str, Any]) -> None:
    """The mean of every metric per method, then the first method minus every other, paired."""
    print(f"{env}, {missions} shared unseen missions (split test, random starts), moderate noise, 100 % budget")
    print("| method | " + " | ".join(METRICS) + " |\n| --- | --- | --- | --- | --- |")
    for label, res in results.items():
        print(f"| {label} | " + " | ".join(f"{np.asarray(getattr(res, m))[:, -1].mean():.4f}" for m in METRICS) + " |")
    first = next(iter(results))
    print("\n| paired | " + " | ".join(METRICS) + " |\n| --- | --- | --- | --- | --- |")
    for other in list(results)[1:]:
        cells = []
        for m in METRICS:
            d = paired_difference(results[first], results[other], m)
            cells.append(f"{d.diff:+.4f} ± {d.se:.4f} ({d.winner or 'tie'})")
        print(f"| {first} - {other} | " + " | ".join(cells) + " |")


def main(argv: Sequence[str] | None = None) -> int:
    """Fly every model and AG on the same missions and print both tables."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("models", nargs="+", help="label=path.zip; the first is compared with the others")
    parser.add_argument("--env", default="env1")
    parser.add_argument("--missions", type=int, default=50)
    parser.add_argument("--fusion", default="mean", choices=["mean", "sendfuse"])
    args = parser.parse_args(argv)
    th.set_num_threads(1)
    options = dict(env=args.env, n_trials=args.missions, seed=0, fusion=args.fusion, protocol="unseen")
    results = {}
    for spec in args.models:
        label, path = spec.split("=", 1)
        model = load(path)
        gain = model.observation_space.spaces.get("action_gain") is not None  # flown as it was trained
        results[label] = evaluate(model, label=label, deterministic=True, action_gain=gain, **options)
    results["ag"] = evaluate("ag", **options)
    _print_tables(args.env, args.missions, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
