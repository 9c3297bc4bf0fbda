"""COMA, IPPO or MAPPO (SB3 PPO, parameter sharing) against AG and random on shared missions.

What it measures: how well one learner, trained for a given number of missions, plans on
missions it never saw, next to AG and random on the very same missions (paired differences),
and how long its training took.

    python -m sb3_coma.experiments.ippo_vs_ag --algo ippo --missions 1000 --out /tmp/ippo_env1
    python -m sb3_coma.experiments.ippo_vs_ag --algo mappo --missions 1000 --out /tmp/mappo_env1
    python -m sb3_coma.experiments.ippo_vs_ag --algo coma --trunk cbam --missions 1000 --out /tmp/coma_env1

COMA uses its library defaults (the paper's actor: 8 local channels, no gain term; CBAM with
``--trunk cbam``) and counts its timesteps in joint steps (``missions * budget``).

Trains on ``split="train"`` (env1: random stars, random starts) with one torch thread (``--threads``;
with more, set ``OMP_WAIT_POLICY=PASSIVE`` in the shell on a shared machine: torch reads it when
it loads, before this module runs), then flies the trained model (argmax actions), AG and random
on the same ``--eval-missions`` seeded missions of ``--split`` (the validation missions by
default; ``--split test``, the unseen test scenes, reports only; trial k = env seed
``eval_seed + k`` for every method, ``sb3_coma.evaluate``) and prints final F1 / entropy (global
map) and team F1 / entropy (the UAVs' own beliefs) as mean +- std over the missions, and the
paired differences model - AG and model - random +- standard error (``sb3_coma.stats.paired``).
Missions are counted honestly: SB3 counts agent-steps, so ``total_timesteps = missions * n_uavs *
budget``. The model zip, a metrics JSON and the learning curve CSV go to ``--out`` (keep them out
of the repository).

Selection is the one every shipped COMA model gets (``sb3-coma train --eval-freq 3000
--eval-missions 10``): every ``--val-freq`` joint steps the model flies ``--val-missions``
validation missions (the validation protocol's: split train, env seeds 1000+, every train scene
equally, the same missions each time), the best becomes
``best_model.zip`` (with ``eval/evaluations.npz``) and is the model compared; several seeds are
then compared with ``python -m sb3_coma.experiments.learners_paired``, which keeps each learner's
best seed by the same score. ``--workers`` steps the env copies in worker processes (same
trajectories as one process).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback

import uav_ipp
from sb3_coma import COMA
from sb3_coma.app.arguments import (
    add_env_argument,
    add_out_argument,
    add_threads_argument,
)
from sb3_coma.app.config import eval_copies
from sb3_coma.app.evaluation import Method, Missions, fly
from sb3_coma.app.roles import TEST_SPLIT_NOTE, add_split_argument, protocol_for_split
from sb3_coma.common.callbacks import MissionEvalCallback
from sb3_coma.common.evaluation import PROTOCOLS, VALIDATION_SEED, validation_missions
from sb3_coma.mappo.mappo import make_ippo, make_mappo, missions_of, timesteps_for_missions
from sb3_coma.stats.paired import paired_difference
from uav_ipp.config import count_or_none_value, count_value, seed_value

#: Final metrics reported, in table order.
METRICS = ("f1", "entropy", "team_f1", "team_entropy")
#: How this module is run, as recorded in ``report.json``.
COMMAND = "python -m sb3_coma.experiments.ippo_vs_ag"


class Curve(BaseCallback):
    """After every rollout: missions so far, wall time, mean per-agent episode return and final F1 /
    entropy of the last 100 finished agent-episodes (VecMonitor's buffer)."""

    def __init__(self, per_mission: int, path: Path, every: int = 5) -> None:
        super().__init__()
        self.per_mission = per_mission
        self.path = path
        self.every = every
        self.rows: list[dict[str, float]] = []
        self.tic = time.perf_counter()

    def _on_step(self) -> bool:
        """Nothing per step: the curve is read once per rollout."""
        return True

    def _on_rollout_end(self) -> None:
        """Append one row (and print every ``every``-th)."""
        buf = list(self.model.ep_info_buffer or ())  # set by learn() before the first rollout
        row = {
            "missions": self.num_timesteps / self.per_mission,
            "seconds": time.perf_counter() - self.tic,
            "return": float(np.mean([e["r"] for e in buf])) if buf else float("nan"),
            "f1": float(np.mean([e["f1"] for e in buf])) if buf else float("nan"),
            "entropy": float(np.mean([e["entropy"] for e in buf])) if buf else float("nan"),
        }
        self.rows.append(row)
        if len(self.rows) % self.every == 1:
            print(
                f"  {row['missions']:7.0f} missions  {row['seconds']:6.0f} s  return {row['return']:+.3f}  "
                f"train F1 {row['f1']:.3f}  entropy {row['entropy']:.3f}",
                flush=True,
            )

    def _on_training_end(self) -> None:
        """Write the rows to ``path`` as CSV."""
        with open(self.path, "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(self.rows[0]) if self.rows else ["missions"])
            writer.writeheader()
            writer.writerows(self.rows)


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The command-line options (module docstring)."""
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algo", default="ippo", choices=["ippo", "mappo", "coma"])
    add_env_argument(p)
    p.add_argument(
        "--missions", type=count_value, default=1000, help="training missions (SB3 timesteps / (n_uavs * budget))"
    )
    p.add_argument("--n-envs", type=count_value, default=8, help="env copies (vec-env rows = n_envs * n_uavs)")
    p.add_argument("--uavs", type=count_value, default=4)
    p.add_argument("--budget", type=count_value, default=15)
    p.add_argument("--noise", default="moderate", choices=["none", "moderate", "loud"])
    p.add_argument("--fusion", default="mean", choices=["mean", "sendfuse"])
    p.add_argument("--reward", default="metrics", help="env reward option (COMA's shipped models use 'metrics')")
    p.add_argument("--trunk", default="cnn", choices=["cnn", "cbam"])
    p.add_argument(
        "--gain-inputs",
        action="store_true",
        help="the actor also reads the on-board action_gain as inputs (COMA, IPPO and MAPPO alike)",
    )
    p.add_argument("--seed", type=seed_value, default=0, help="training seed (PPO and the training env)")
    p.add_argument(
        "--eval-missions",
        type=count_or_none_value,
        default=None,
        help="missions of the comparison (default: the protocol's; 0: none)",
    )
    add_split_argument(p)
    p.add_argument(
        "--val-freq",
        type=count_or_none_value,
        default=3000,
        help="joint steps between validations (split train, env seeds 1000+, as `sb3-coma train --eval-freq`); "
        "the best one is best_model.zip and is the model compared (0: none, the last model)",
    )
    p.add_argument(
        "--val-missions", type=count_value, default=None, help="missions per validation (default: 4 per train scene)"
    )
    p.add_argument("--workers", type=count_value, default=1, help="worker processes stepping the env copies")
    p.add_argument(
        "--eval-seed",
        type=seed_value,
        default=None,
        help="trial k flies env seed eval_seed + k (default: the protocol's)",
    )
    add_threads_argument(p)
    add_out_argument(p, "/tmp/marl_baselines")
    args = p.parse_args(argv)
    if args.val_missions is None:
        args.val_missions = validation_missions(args.env)
    if args.workers > args.n_envs:
        p.error(f"--workers {args.workers}: more worker processes than env copies ({args.n_envs})")
    return args


def fmt(values: np.ndarray) -> str:
    """``mean ± std`` of one metric over the missions."""
    return f"{values.mean():.4f} ± {values.std():.4f}"


def _env_options(args: argparse.Namespace) -> dict[str, Any]:
    """Env options shared by training and evaluation. The paper's actor reads the 8 local channels
    only; ``--gain-inputs`` adds the on-board gains."""
    return dict(n_uavs=args.uavs, budget=args.budget, noise=args.noise, action_gain=bool(args.gain_inputs))


def _build(args: argparse.Namespace, venv: Any) -> tuple[BaseAlgorithm, int]:
    """The learner and the ``total_timesteps`` that make ``--missions`` missions in its own unit."""
    if args.algo == "coma":
        policy = "CBAMPolicy" if args.trunk == "cbam" else "UavCnnPolicy"
        model = COMA(policy, venv, seed=args.seed, policy_kwargs=dict(gain_inputs=bool(args.gain_inputs)))
        return model, args.missions * args.budget  # COMA counts joint steps
    factory = {"ippo": make_ippo, "mappo": make_mappo}[args.algo]
    extractor = dict(trunk=args.trunk, gain_inputs=bool(args.gain_inputs))
    learner = factory(venv, seed=args.seed, policy_kwargs=dict(features_extractor_kwargs=extractor))
    return learner, timesteps_for_missions(args.missions, venv)


def _validation(args: argparse.Namespace, out: Path, train_options: dict[str, Any]) -> MissionEvalCallback:
    """The validation every shipped COMA run gets: ``--val-missions`` missions of the train scenes
    from env seed ``VALIDATION_SEED`` (the same each time) every ``--val-freq`` joint steps; the
    best checkpoint becomes ``out/best_model.zip``."""
    val_env = uav_ipp.make_vec_env(
        args.env,
        n_envs=eval_copies(args.val_missions),
        seed=VALIDATION_SEED,
        **{**train_options, **PROTOCOLS["validation"].env_options()},
    )
    return MissionEvalCallback(
        val_env,
        eval_freq=args.val_freq,
        n_eval_missions=args.val_missions,
        best_model_save_path=out,
        log_path=out / "eval",
        eval_seed=VALIDATION_SEED,
        verbose=0,
    )


def _train(args: argparse.Namespace, out: Path) -> tuple[BaseAlgorithm, dict[str, Any]]:
    """Train on ``split="train"``; returns the model compared (the validation's choice, else the
    last) and the record: training seconds, missions and agent-steps flown, best validation return
    (``None`` without validation)."""
    options = _env_options(args)
    train_options = dict(fusion=args.fusion, split="train", reward=args.reward, **options)
    venv = uav_ipp.make_vec_env(args.env, n_envs=args.n_envs, seed=args.seed, workers=args.workers, **train_options)
    model, timesteps = _build(args, venv)
    per_mission = args.budget if args.algo == "coma" else args.uavs * args.budget  # COMA: joint steps
    validation = _validation(args, out, train_options) if args.val_freq > 0 else None
    callbacks: list[BaseCallback] = [Curve(per_mission, out / "curve.csv"), *([validation] if validation else [])]
    print(
        f"{args.algo}: {args.missions} missions = {timesteps} agent-steps on {args.env} split=train, "
        f"{args.n_envs} copies x {args.uavs} UAVs, budget {args.budget}, noise {args.noise}, fusion {args.fusion}, "
        f"reward {args.reward}, {sum(p.numel() for p in model.policy.parameters())} parameters",
        flush=True,
    )
    tic = time.perf_counter()
    model.learn(total_timesteps=timesteps, callback=callbacks)
    train_s = time.perf_counter() - tic
    flown = model.num_timesteps / args.budget if args.algo == "coma" else missions_of(model.num_timesteps, venv)
    model.save(out / f"{args.algo}_{args.env}")
    venv.close()
    print(f"trained {flown:.0f} missions ({model.num_timesteps} agent-steps) in {train_s:.0f} s", flush=True)
    record = {"train_seconds": train_s, "missions_trained": flown, "agent_steps": int(model.num_timesteps)}
    if validation is None:
        return model, {**record, "best_validation_return": None}
    validation.eval_env.close()
    best = float(validation.best_mean_reward)
    print(f"compared: best_model.zip (best validation return {best:+.3f})", flush=True)
    return type(model).load(out / "best_model.zip", device="cpu"), {**record, "best_validation_return": best}


def _compare(args: argparse.Namespace, model: BaseAlgorithm, report: dict[str, Any]) -> str:
    """Fly the model, AG and random on the same missions of ``--split``; fill ``report``, return the table."""
    options = _env_options(args)
    protocol = protocol_for_split(args.split)
    missions = Missions(
        env=args.env, protocol=protocol, count=args.eval_missions, seed=args.eval_seed, record=1, options=options
    )
    planners = replace(missions, options={**options, "action_gain": True})
    results = {
        args.algo: fly(Method(args.algo, model, fusion=args.fusion, deterministic=True), missions),
        "ag": fly(Method("ag", "ag", fusion=args.fusion), planners),
        "random": fly(Method("random", "random", fusion=args.fusion), planners),
    }
    lines = ["| method | F1 | entropy | team F1 | team entropy |", "| --- | --- | --- | --- | --- |"]
    for name, res in results.items():
        finals = {m: np.asarray(getattr(res, m))[:, -1] for m in METRICS}
        report["methods"][name] = {m: {"mean": float(v.mean()), "std": float(v.std())} for m, v in finals.items()}
        lines.append(f"| {name} | " + " | ".join(fmt(finals[m]) for m in METRICS) + " |")
    lines += [
        "",
        f"| paired ({results['ag'].n_trials} missions) | " + " | ".join(METRICS) + " |",
        "| --- | --- | --- | --- | --- |",
    ]
    for other in ("ag", "random"):
        cells = []
        for m in METRICS:
            d = paired_difference(results[args.algo], results[other], m)
            report["paired"].append(d.as_dict())
            cells.append(f"{d.diff:+.4f} ± {d.se:.4f} ({d.winner or 'tie'})")
        lines.append(f"| {args.algo} - {other} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    """Train, compare, print the tables and write ``report.json``; returns the report."""
    args = parse_args(argv)
    th.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model, record = _train(args, out)
    report: dict[str, Any] = {
        "command": " ".join([COMMAND, *(argv if argv is not None else sys.argv[1:])]),
        "args": vars(args),
        **record,
        "methods": {},
        "paired": [],
    }
    if args.eval_missions is not None and args.eval_missions < 1:
        (out / "report.json").write_text(json.dumps(report, indent=2))
        return report
    table = _compare(args, model, report)
    print(
        f"\nfinal step ({args.budget}) on the {args.split} missions"
        f"{' (' + TEST_SPLIT_NOTE + ')' if args.split == 'test' else ''}, mean ± std over missions; "
        f"paired: mean difference ± standard error\n\n{table}"
    )
    report["table"] = table
    (out / "report.json").write_text(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
