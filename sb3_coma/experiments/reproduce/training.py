"""``reproduce --train``: retrain a shipped model the way it was trained, from its manifest entry.

The seed, run length, fusion and config variant come from ``models.json`` so that ``--train``
retrains the very model that ships, not a neighbour of it; ``ship_models`` reads the training
curve the same way (:func:`curve_from_metrics`).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import uav_ipp
from sb3_coma import COMA
from sb3_coma.app import pretrained as pt
from sb3_coma.app.runs import curve_from_metrics
from sb3_coma.app.training import train
from sb3_coma.common.callbacks import ProgressLinesCallback
from sb3_coma.experiments.reproduce.options import (
    MEAN_FUSION_VARIANT,
    QUICK_OVERRIDES,
    QUICK_TIMESTEPS,
    TRAIN_EVAL_FREQ,
    TRAIN_SEED,
)
from sb3_coma.experiments.reproduce.results import ModelSource


def manifest_value(env: str, key: str, default: Any = None) -> Any:
    """``models.json``'s ``key`` of the shipped model ``env``, ``default`` when either is missing."""
    try:
        return pt.model_info(env).get(key, default)
    except (ImportError, ValueError):
        return default


def shipped_seed(env: str) -> int:
    """The training seed of the shipped model of ``env`` (the seed whose run won on the validation
    missions, models.json), so ``--train`` retrains that very model; ``TRAIN_SEED`` without one."""
    return int(manifest_value(env, "seed", TRAIN_SEED))


def shipped_timesteps(env: str) -> int | None:
    """The joint steps the shipped model of ``env`` was trained for when its command sets them
    (``--timesteps``, recorded as ``train_timesteps``); ``None``: the config's ``n_timesteps``."""
    value = manifest_value(env, "train_timesteps")
    return None if value is None else int(value)


def sendfuse_available() -> bool:
    """Whether ``fusion="sendfuse"`` can be built (its pre-trained weights exist)."""
    try:
        uav_ipp.make_vec_env("env1", fusion="sendfuse").close()
        return True
    except Exception:  # any failure means: not usable here
        return False


def variant_for(env: str, fusion: str) -> str | None:
    """The zoo config variant of a shipped model's settings for a fusion (None: the map's entry)."""
    return None if fusion == "sendfuse" else MEAN_FUSION_VARIANT


def train_command(env: str, fusion: str, seed: int = TRAIN_SEED, validate: bool = True) -> str:
    """The command that retrains a shipped model (with ``validate``, its ``best_model.zip`` is the model)."""
    variant = variant_for(env, fusion)
    command = f"sb3-coma train --env {env}" + (f" --variant {variant}" if variant else "") + f" --seed {seed}"
    return command + (f" --eval-freq {TRAIN_EVAL_FREQ}" if validate else "")


def _train_model(
    env: str,
    fusion: str,
    out: Path,
    quick: bool,
    timesteps: int | None,
    log: Callable[[str], None],
    deterministic: bool = True,
) -> ModelSource:
    """Train COMA on ``env`` into ``out/runs/<env>`` with the shipped model's seed and settings
    (``quick``: a few steps, no warm start, no validation) and return the chosen model."""
    overrides: dict[str, Any] = dict(QUICK_OVERRIDES) if quick else {}
    total = QUICK_TIMESTEPS if quick else (timesteps or shipped_timesteps(env))
    variant = variant_for(env, fusion)
    seed = shipped_seed(env)
    run_dir = out / "runs" / env
    if run_dir.exists():
        shutil.rmtree(run_dir)
    log(f"training COMA on {env} (fusion {fusion}{', quick' if quick else ''}) ...")

    def indented(line: str) -> None:
        log(f"  {line}")

    # Training runs with verbose 0 and no bar; its own lines (run folder, each warm-start round)
    # and a line every tenth of the COMA run keep a long job from looking stuck.
    progress = ProgressLinesCallback(every=0.1, label=f"training {env}", log=indented)
    tic = time.perf_counter()
    _, run_path = train(
        env=env,
        variant=variant,
        seed=seed,
        total_timesteps=total,
        run_dir=run_dir,
        overrides=overrides or None,
        progress_bar=False,
        verbose=0,
        log=indented,
        callbacks=[progress],
        handle_signals=False,
        save_freq=10**9,
        eval_freq=0 if quick else TRAIN_EVAL_FREQ,
    )
    wall = time.perf_counter() - tic
    model = COMA.load(str(_chosen_model(Path(run_path))), env=None, device="cpu")
    command = train_command(env, fusion, seed, validate=not quick) + (f" --timesteps {total}" if total else "")
    if overrides:
        command += "".join(f" --set {k}={v}" for k, v in overrides.items())
    log(f"  trained {env} in {wall:.1f} s -> {run_path}")
    return ModelSource(
        env,
        model,
        fusion,
        str(run_path),
        command,
        wall,
        int(model.num_timesteps),
        curve_from_metrics(Path(run_path) / "metrics.csv"),
        deterministic=deterministic,
    )


def _chosen_model(run_path: Path) -> Path:
    """The run's model that reproduce uses and ships: the best checkpoint on the validation
    missions when the run evaluated, else the final one."""
    best = run_path / "best_model.zip"
    return best if best.is_file() else run_path / "model.zip"
