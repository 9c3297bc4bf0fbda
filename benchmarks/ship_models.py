"""Maintainer tool: pick the shipped COMA models from training runs, on validation missions only.

Each shipped model is trained with several seeds, every run with ``--eval-freq 1024
--eval-missions 20``: its ``best_model.zip`` is its best checkpoint on 20 validation missions
(env seeds 1000..1019, re-seeded at every evaluation, never the test seeds 0..9). This script
reads each run's ``eval/evaluations.npz``, keeps the run whose best validation return is highest,
re-saves that ``best_model.zip`` into ``sb3_coma/pretrained/`` with Adam's moments cleared (the
weights are unchanged; the zip is less than half the size) and writes its ``models.json`` entry:
checksum, the exact command, the validation scores of every candidate, training wall-clock and
curve. Test metrics are added afterwards by ``sb3-coma reproduce --record``.

    python benchmarks/ship_models.py env1=runs/env1_s0,runs/env1_s1 \
        env3-mean-cnn=runs/meancnn_s0,runs/meancnn_s1 ...

A name ``envN`` ships the model of that map; ``env3-{fusion}-{extractor}`` an ablation arm.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import yaml

from sb3_coma import COMA
from sb3_coma import pretrained as pt
from sb3_coma.reproduce import TRAIN_EVAL_FREQ, TRAIN_EVAL_MISSIONS, _curve_from_metrics
from sb3_coma.training import load_config


def validation_best(run: Path) -> tuple[float, int]:
    """(best mean validation return, joint steps of that evaluation) of a run."""
    data = np.load(run / "eval" / "evaluations.npz")
    means = data["results"].mean(axis=1)
    best = int(np.argmax(means))  # the first of equal bests, as EvalCallback keeps it
    return float(means[best]), int(data["timesteps"][best])


def run_length(run: Path) -> int:
    """Joint steps the run trained for (its last evaluation)."""
    return int(np.load(run / "eval" / "evaluations.npz")["timesteps"][-1])


def run_timesteps(run: Path) -> int | None:
    """The run's ``--timesteps`` when it differs from its variant's ``n_timesteps``, else None."""
    config = yaml.safe_load((run / "config.yml").read_text())
    info = config["run"]
    total = int(config[info["env"]]["n_timesteps"])
    return None if total == load_config(info["env"], variant=info["variant"]).n_timesteps else total


def run_command(run: Path) -> tuple[str, dict]:
    """The ``sb3-coma train`` command a run folder records, and its ``run`` section."""
    config = yaml.safe_load((run / "config.yml").read_text())
    info = config["run"]
    env = info["env"].split("-")[1].lower()
    command = (f"sb3-coma train --env {env} --variant {info['variant']} --seed {info['seed']} "
               f"--eval-freq {TRAIN_EVAL_FREQ} --eval-missions {TRAIN_EVAL_MISSIONS}")
    total = run_timesteps(run)
    return command + (f" --timesteps {total}" if total is not None else ""), info


def ship(name: str, runs: list[Path]) -> dict:
    scored = {run: validation_best(run) for run in runs}
    chosen = max(runs, key=lambda r: scored[r][0])
    command, info = run_command(chosen)
    total = run_timesteps(chosen)
    model = COMA.load(chosen / "best_model.zip", device="cpu")
    fusion = "mean" if "mean" in info["variant"] else "sendfuse"
    extractor = "cnn" if "cnn" in info["variant"] else "cbam"
    wall = (chosen / "model.zip").stat().st_mtime - (chosen / "config.yml").stat().st_mtime
    entry = {
        **pt.save_for_shipping(model, f"coma_{name.replace('-', '_')}.zip"),
        "env": info["env"].split("-")[1].lower(), "fusion": fusion, "extractor": extractor,
        "variant": info["variant"], "seed": int(info["seed"]), "deterministic": True,
        "timesteps": int(model.num_timesteps), "command": command, "config": "zoo_configs/coma.yml",
        "model_file_of_run": "best_model.zip",
        "selection": {"rule": "highest mean return on 20 validation missions (env seeds 1000..1019, argmax), "
                              "over every 1024-step evaluation of every seed",
                      "candidates": {f"seed {run_command(r)[1]['seed']}": {"best_validation_return": round(v, 4),
                                                                            "at_joint_steps": t}
                                     for r, (v, t) in scored.items()}},
        "train_wall_s": round(wall, 1),
        "train_wall_note": f"wall-clock of that command (whole run, {run_length(chosen)} joint steps) on 2 CPU cores "
                           "shared by 2-6 trainings, 1 torch thread each",
        "optimizer_state": "cleared for shipping (Adam moments dropped; weights unchanged)",
        "gain_prior_weights": [round(float(x), 4) for x in model.policy.actor.prior_weights.detach()],
        "training_curve": _curve_from_metrics(chosen / "metrics.csv"),
    }
    if total is not None:
        entry["train_timesteps"] = total  # reproduce --train trains this long
    if "-" in name:
        entry["ablation_arm"] = [fusion, extractor]
    return entry


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    manifest = pt.read_manifest()
    for spec in argv:
        name, runs = spec.split("=", 1)
        entry = ship(name, [Path(r) for r in runs.split(",")])
        old = manifest["models"].get(name, {})
        manifest["models"][name] = entry
        print(f"{name}: {entry['command']} -> {entry['file']} ({entry['size_bytes']} bytes); "
              f"candidates {entry['selection']['candidates']}" + (" (replaced)" if old else ""))
    pt.write_manifest(manifest)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
