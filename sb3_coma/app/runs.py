"""Run folders: what ``sb3-coma train`` writes for one training run, and how to find it again.

::

    runs/UavIpp-Env3-v0_1/
        config.yml         the resolved config (itself a valid rl-zoo3 config file) + run info
        tb/COMA_1/         TensorBoard logs (SB3's values, mission/* per mission)
        checkpoints/       rl_model_<joint steps>_steps.zip, written atomically
        metrics.csv        one row per mission: reward, length, final F1 and entropy
        model.zip          the final model, written atomically when training completes
        best_model.zip     with --eval-freq: the best checkpoint on the validation missions
        .lock              held (flock) by the process training in the folder; names its pid

The layout is a data format: the trainer writes it, ``--resume`` and ``sb3-coma export`` read it
(:func:`load_checkpoint`: a checkpoint validated, then loaded as ``COMA``).
One process writes a run folder at a time (:func:`lock_run_folder`): a second ``train`` into it
(a resume, or a new run with that ``--run-dir``) is refused while the first runs.
"""

from __future__ import annotations

import csv
import os
import pickle
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

import yaml

from sb3_coma.app.config import (
    RUN_KEY,
    TrainConfig,
    TrainingError,
    plain,
    read_config_file,
    resolve_env_id,
    train_config,
)
from sb3_coma.app.outputs import (
    LOCK_FILE,
    FolderInUseError,
    FolderLock,
    LockHolder,
    folder_name_problem,
    lock_holder,
)
from sb3_coma.coma import COMA
from sb3_coma.common.checkpoints import (
    CheckpointError,
    atomic_write_text,
    find_checkpoints,
    folder_write_problem,
    validate_checkpoint,
)

CONFIG_FILE = "config.yml"
MODEL_FILE = "model.zip"
METRICS_FILE = "metrics.csv"
CHECKPOINT_DIR = "checkpoints"
TENSORBOARD_DIR = "tb"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "run"


def check_run_dir(run_dir: str | os.PathLike[str] | None) -> None:
    """Refuse an explicit run folder that cannot be made (it or a parent is a file, or its
    location is not writable) before the env and the model are built, rather than in ``mkdir``
    after them; and one whose name is no folder name (:func:`folder_name_problem`: a control
    character, ``.``/``..``, a leading dot), since ``--run-dir .`` trained into a hidden ``._2``."""
    if run_dir is None:
        return
    problem = folder_name_problem(run_dir)
    if problem is not None:
        problem = f"run folder {os.fspath(run_dir)!r} {problem}: pass a visible folder name such as runs/my-run"
    elif (made := folder_write_problem(run_dir)) is not None:
        problem = f"run folder {run_dir} cannot be made: {made}"
    elif Path(run_dir).is_dir() and (holder := lock_holder(run_dir)) is not None:
        problem = _in_use(Path(run_dir), holder, resuming=False)
    if problem is not None:  # one rule: a folder this run can make and hold alone
        raise TrainingError(problem)


def _in_use(run_dir: Path, holder: LockHolder, resuming: bool) -> str:
    """The one line that refuses a second writer, naming the holder so the user can find it."""
    tail = "wait for it to finish before resuming" if resuming else "wait for it or pass another --run-dir"
    return f"run folder {run_dir} is in use by {holder.describe()}; {tail}"


def lock_run_folder(run_dir: Path, resuming: bool = False) -> FolderLock:
    """Take the run folder's lock for this process (held until released or the process ends).

    Two trainers in one folder would interleave checkpoints, truncate each other's
    ``metrics.csv`` and rewrite ``config.yml``; the lock makes the second one stop before it
    touches anything.

    :raises TrainingError: another process holds it (the message names its pid and start time)
    """
    try:
        return FolderLock(run_dir).acquire()
    except FolderInUseError as exc:
        raise TrainingError(_in_use(run_dir, exc.holder, resuming)) from None


def claim_run_dir(
    run_dir: str | os.PathLike[str] | None,
    env_id: str,
    variant: str | None = None,
    root: str | os.PathLike[str] = "runs",
) -> tuple[Path, FolderLock]:
    """:func:`new_run_dir` with its lock taken: an explicit ``run_dir`` that a running trainer
    holds is refused instead of being passed over for ``<run_dir>_2``."""
    check_run_dir(run_dir)
    path = new_run_dir(run_dir, env_id, variant, root)
    return path, lock_run_folder(path)


def new_run_dir(
    run_dir: str | os.PathLike[str] | None,
    env_id: str,
    variant: str | None = None,
    root: str | os.PathLike[str] = "runs",
) -> Path:
    """Create and return a fresh run folder; never reuses a folder that holds anything.

    ``run_dir=None``: ``<root>/<env id>[-<variant>]_<n>`` with the next free ``n`` (rl-zoo3's
    scheme). An explicit ``run_dir`` is used when it does not exist or is empty, else
    ``<run_dir>_2``, ``<run_dir>_3``, ... Folders are created with ``mkdir`` (atomic), so two runs
    started together never share one.
    """
    if run_dir is None:
        base = Path(root) / _slug(env_id + (f"-{variant}" if variant else ""))
        candidates = (Path(f"{base}_{n}") for n in range(1, 1_000_000))
    else:
        base = Path(run_dir)
        if base.is_dir() and not any(p.name != LOCK_FILE for p in base.iterdir()):
            return base  # empty, or left with only the lock file of a run that died at once
        check_run_dir(base)
        candidates = (base if n == 1 else Path(f"{base}_{n}") for n in range(1, 1_000_000))
    for candidate in candidates:
        candidate.parent.mkdir(parents=True, exist_ok=True)
        try:
            candidate.mkdir()
        except FileExistsError:
            continue
        return candidate
    raise TrainingError(f"no free run folder name next to {base}")  # pragma: no cover


def write_run_config(run_dir: Path, cfg: TrainConfig) -> Path:
    """``config.yml``: the entry the run trains with (a valid rl-zoo3 config) + the run record."""
    header = (
        "# sb3-coma run config: the entry below is what this run trained with (a valid rl-zoo3 config);\n"
        "# 'run' records where it came from. Resume with: sb3-coma train --resume " + str(run_dir) + "\n"
    )
    body = {cfg.env_id: plain(cfg.entry), RUN_KEY: plain(cfg.run)}
    return atomic_write_text(run_dir / CONFIG_FILE, header + yaml.safe_dump(body, sort_keys=False))


def read_run_config(run_dir: Path) -> TrainConfig:
    """The :class:`TrainConfig` a run folder's ``config.yml`` records (validated again)."""
    path = run_dir / CONFIG_FILE
    data = read_config_file(path)
    run = data.get(RUN_KEY)
    if not isinstance(run, dict) or "env" not in run:
        raise TrainingError(f"{path} is not an sb3-coma run config (no '{RUN_KEY}.env')")
    env_id = resolve_env_id(run["env"])
    cfg = train_config(path, env_id, data=data, run=run)  # the entry as recorded: its variant already merged
    cfg.variant = run.get("variant")
    return cfg


def newest_model(run_dir: Path) -> Path | None:
    """Newest valid checkpoint or final model of a run folder (by joint steps)."""
    candidates = [p for _, p in find_checkpoints(run_dir / CHECKPOINT_DIR)]
    if (run_dir / MODEL_FILE).is_file():
        candidates.append(run_dir / MODEL_FILE)
    best: tuple[int, Path] | None = None
    for path in candidates:
        try:
            info = validate_checkpoint(path)
        except CheckpointError as exc:
            warnings.warn(f"skipping {exc}", stacklevel=3)
            continue
        if best is None or info.num_timesteps > best[0]:
            best = (info.num_timesteps, path)
    return best[1] if best else None


def run_folder_of(zip_path: Path) -> Path | None:
    """The run folder of a model zip: its own folder (``model.zip``, ``best_model.zip``) or the one
    above ``checkpoints/``, when that holds a ``config.yml``."""
    parent = zip_path.parent
    for folder in (parent, parent.parent if parent.name == CHECKPOINT_DIR else None):
        if folder is not None and (folder / CONFIG_FILE).is_file():
            return folder
    return None


def resolve_resume(resume: str | os.PathLike[str]) -> tuple[Path | None, Path]:
    """``(run folder or None, model zip)`` for ``--resume PATH``.

    ``PATH`` is a run folder (its newest checkpoint or final model), a checkpoint or model zip
    inside a run folder, or any COMA model zip (then a new run folder is made).

    :raises TrainingError: the path does not exist, is a folder but not a run folder, or a run
        folder without a usable checkpoint
    :raises CheckpointError: the zip is truncated/corrupt or not a COMA model
    """
    p = Path(resume)
    if p.is_file():
        validate_checkpoint(p)
        return run_folder_of(p), p
    run_folder = p.is_dir() and (p / CONFIG_FILE).is_file()
    model = newest_model(p) if run_folder else None
    if model is None:  # one rule: a checkpoint, or a run folder holding one
        why = (
            "no such file or folder"
            if not p.exists()
            else f"the run folder has no valid checkpoint or {MODEL_FILE}"
            if run_folder
            else f"not a run folder (no {CONFIG_FILE}); pass a run folder or a checkpoint .zip"
        )
        raise TrainingError(f"cannot resume from {p}: {why}")
    return p, model


def load_checkpoint(path: str | os.PathLike[str], env: Any = None, **kwargs: Any) -> COMA:
    """Validate, then ``COMA.load(path, env=env, **kwargs)``; errors name the file."""
    validate_checkpoint(path)
    try:
        return COMA.load(str(path), env=env, **kwargs)
    except (pickle.UnpicklingError, KeyError, ValueError, RuntimeError, zipfile.BadZipFile, EOFError) as exc:
        why = (  # torch's "Weights only load failed ..." on a damaged member
            "is corrupt: a network or optimizer member is not a readable PyTorch file"
            if isinstance(exc, pickle.UnpicklingError)
            else f"could not be loaded: {exc}"
        )
        raise CheckpointError(f"checkpoint {path} {why}") from exc


def curve_from_metrics(path: Path) -> list[float]:
    """The ``reward`` column of a run's ``metrics.csv`` (the team reward of every finished mission),
    the training curve that ``models.json`` records; empty when the run wrote none."""
    if not path.is_file():
        return []
    with path.open() as fh:
        return [round(float(row["reward"]), 4) for row in csv.DictReader(fh)]
