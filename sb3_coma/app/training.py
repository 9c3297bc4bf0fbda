"""Training as users run it: the trainer behind ``sb3-coma train`` (and ``reproduce``)::

    from sb3_coma.app.training import train
    model, run_dir = train(env="env3", variant="mean-cnn", total_timesteps=18_000, seed=0)

:func:`train` is a sequence of named steps: load the config (:func:`plan_run`), build the envs
(:func:`make_training_env`), build the model (:func:`build_model`), prepare the run folder
(:func:`prepare_run_folder`), attach the callbacks (:func:`attach_callbacks`), learn
(:func:`learn`) and save (:func:`save_final`). The run folder layout is in :mod:`sb3_coma.app.runs`,
the config format in :mod:`sb3_coma.app.config` (see ``docs/modules/cli.md``).

The trainer core that ``python -m sb3_coma.zoo`` shares: :func:`mission_callbacks` (metrics CSV,
checkpoints in joint steps, seeded validation missions, clean stop on signals),
:func:`record_env_options` (what a saved model records about its env) and
:func:`sb3_coma.app.config.make_vec_env_from_kwargs` (the envs).
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import sys
import traceback
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common import callbacks as sb3_callbacks
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_coma import __version__
from sb3_coma.app.config import (
    WARM_START_KEY,
    TrainConfig,
    TrainingError,
    WorldSpec,
    check_warm_start,
    checked_count,
    coma_kwargs,
    construct,
    env_options_of,
    is_int,
    load_config,
    make_training_env,
    make_validation_env,
    named_objects,
    plain,
    resolve_env_id,
)
from sb3_coma.app.outputs import FolderLock
from sb3_coma.app.runs import (
    CHECKPOINT_DIR,
    CONFIG_FILE,
    METRICS_FILE,
    MODEL_FILE,
    TENSORBOARD_DIR,
    check_run_dir,
    claim_run_dir,
    load_checkpoint,
    lock_run_folder,
    newest_model,
    read_run_config,
    resolve_resume,
    run_folder_of,
    write_run_config,
)
from sb3_coma.app.warm_start import (
    WARM_START_MODEL,
    WARM_START_STATE,
    WarmStartInterrupted,
    warm_start_pending,
    warm_start_run,
)
from sb3_coma.coma import COMA
from sb3_coma.coma.validation import check_device as validation_check_device
from sb3_coma.common.callbacks import (
    EpisodeMetricsCallback,
    JointCheckpointCallback,
    MissionEvalCallback,
    SignalStopCallback,
    truncate_metrics_csv,
)
from sb3_coma.common.checkpoints import atomic_save, training_options, validate_checkpoint
from sb3_coma.common.evaluation import VALIDATION_SEED as _VALIDATION_SEED
from sb3_coma.common.evaluation import validation_missions
from sb3_coma.common.memory import release_freed_memory

# the trainer

TB_LOG_NAME = "COMA"
#: Env seed of the validation missions that ``--eval-freq`` flies (seeds 1000, 1001, ...): far
#: from the seeds 0..n-1 that ``evaluate`` and ``reproduce`` report, so picking the best
#: checkpoint never looks at the test missions.
VALIDATION_SEED = _VALIDATION_SEED
#: Config keys whose change a resumed run applies (its world and its parallel layout: the env
#: options, fusion and team included): a resume refuses such a change unless ``allow_change``.
#: Every other key but the run length the checkpoint keeps as it was saved, so a change of it is
#: refused outright (config.yml would misstate the run).
RESUME_APPLIED_KEYS = ("env_kwargs", "n_envs", "vec_env_wrapper", "workers", "backend", "callback")
#: Config keys a resume may change freely: the run length (``--timesteps``).
RESUME_FREE_KEYS = ("n_timesteps",)


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped on SIGINT/SIGTERM after saving a checkpoint (during the warm start: after
    its last finished round, :attr:`checkpoint` its progress folder, at 0 joint steps); resume
    from :attr:`run_dir`."""

    def __init__(self, run_dir: Path, checkpoint: Path, num_timesteps: int, signum: int) -> None:
        super().__init__(f"interrupted at {num_timesteps} joint steps; checkpoint {checkpoint}")
        self.run_dir = run_dir
        self.checkpoint = checkpoint
        self.num_timesteps = num_timesteps
        self.signum = signum


# =========================================================================== shared trainer core
def record_env_options(model: COMA, world: WorldSpec) -> None:
    """Record on the model (and so in every zip saved from it) the env it trains on."""
    model.env_options = world.record()


@dataclass
class MissionCallbacks:
    """The callbacks every COMA training run gets (both trainers)."""

    metrics: EpisodeMetricsCallback
    checkpoints: JointCheckpointCallback | None
    evaluation: MissionEvalCallback | None
    stopper: SignalStopCallback | None

    def as_list(self) -> list[BaseCallback]:
        return [cb for cb in (self.metrics, self.checkpoints, self.evaluation) if cb is not None]


def selection_end(entry: Mapping[str, Any], n_timesteps: int) -> int:
    """Joint steps up to which a run's checkpoints cannot be its best model: the critic warm-up of
    a warm-started entry (the actor is the clone, held still), else 0."""
    spec = entry.get(WARM_START_KEY)
    if not spec:
        return 0
    return math.ceil(float(spec.get("critic_warmup", 0.0)) * int(n_timesteps))


def mission_callbacks(
    folder: Path,
    save_freq: int,
    checkpoint_dir: Path,
    eval_env: VecEnv | None = None,
    eval_freq: int = 0,
    eval_missions: int = 5,
    eval_seed: int | None = None,
    eval_log_path: Path | None = None,
    deterministic: bool = True,
    stop_on_signal: bool = True,
    verbose: int = 0,
    stop_verbose: int | None = None,
    select_after: int = 0,
) -> MissionCallbacks:
    """Per-mission metrics (TensorBoard + ``folder/metrics.csv``), a checkpoint every ``save_freq``
    joint steps (none when ``save_freq <= 0``), with ``eval_env`` the validation missions every
    ``eval_freq`` joint steps (best model -> ``folder/best_model.zip``) and the clean stop on
    SIGINT / SIGTERM (``stop_verbose``: its verbosity, default ``verbose``); evaluations at or
    before ``select_after`` joint steps never become the best model (:func:`selection_end`)."""
    evaluation = None
    if eval_env is not None and eval_freq > 0:
        evaluation = MissionEvalCallback(
            eval_env,
            eval_freq=eval_freq,
            n_eval_missions=eval_missions,
            best_model_save_path=folder,
            log_path=eval_log_path or folder,
            deterministic=deterministic,
            verbose=verbose,
            eval_seed=eval_seed,
            select_after=select_after,
        )
    return MissionCallbacks(
        metrics=EpisodeMetricsCallback(csv_path=folder / METRICS_FILE),
        checkpoints=JointCheckpointCallback(save_freq, checkpoint_dir, verbose=verbose) if save_freq > 0 else None,
        evaluation=evaluation,
        stopper=SignalStopCallback(verbose=verbose if stop_verbose is None else stop_verbose)
        if stop_on_signal
        else None,
    )


# =========================================================================== the steps of train()
@dataclass
class RunPlan:
    """Step 1 of :func:`train`: what to train, from where, with which seed."""

    cfg: TrainConfig
    seed: int
    resume_model: Path | None = None
    #: The run folder a resume continues in place (``None``: a new folder is made).
    run_path: Path | None = None
    done_steps: int = 0
    eval_seed: int = VALIDATION_SEED
    #: Settings a resume changes with ``allow_change``: ``{key: {"from": old, "to": new}}``.
    changes: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: The run folder's lock, held from planning (a resume) or from the folder's creation.
    lock: FolderLock | None = None

    @property
    def resumed_in_place(self) -> bool:
        return self.run_path is not None

    def release(self) -> None:
        """Let go of the run folder (the run is over, or never started)."""
        if self.lock is not None:
            self.lock.release()


def check_device(device: Any) -> None:
    """:func:`sb3_coma.coma.validation.check_device` as a :class:`TrainingError`, checked before
    the run folder is made."""
    try:
        validation_check_device(device)
    except ValueError as exc:
        raise TrainingError(str(exc)) from None


def _resumed_config(
    resume_run: Path,
    resume: Any,
    env: str | None,
    config: Any,
    variant: str | None,
    overrides: Mapping[str, Any] | None,
) -> TrainConfig:
    """The config of the run folder a resume continues in (its own, plus ``overrides``)."""
    cfg = read_run_config(resume_run)
    asked = resolve_env_id(env) if env is not None else cfg.env_id
    # A resumed run continues its checkpoint (whose settings are saved in it) on its own env: a
    # --set would either be ignored (COMA's arguments) or change the world mid-run (env_kwargs,
    # e.g. the fusion), and config.yml would then misstate the run. One rule: nothing but the run's
    # own config, refused naming what was given.
    refused = (
        (
            config is not None or variant is not None,
            f"continues run {resume_run} with its own config; drop --config/--variant",
        ),
        (asked != cfg.env_id, f"that run trains {cfg.env_id}, not {asked}"),
        (
            bool(overrides),
            f"--set {', '.join(sorted(overrides or {}))} cannot apply to a resumed run (the checkpoint keeps its "
            "settings and its env); start a new run to change them",
        ),
    )
    problem = next((why for given, why in refused if given), None)
    if problem is not None:
        raise TrainingError(f"--resume {resume}: {problem}")
    return cfg


def run_settings(entry: Mapping[str, Any]) -> dict[str, Any]:
    """What a run record keeps of its config entry (all but the run length), so that a resume can
    tell a change of ``config.yml`` made by hand after the run started."""
    return {str(k): plain(v) for k, v in entry.items() if k not in RESUME_FREE_KEYS}


def _spread(entry: Mapping[str, Any], env_id: str) -> dict[str, Any]:
    """An entry as comparable settings: ``env_kwargs`` spread into ``env_kwargs.<option>`` and
    resolved (an option written out equals the same default left out), ``n_envs`` filled in."""
    flat = {str(k): plain(v) for k, v in entry.items() if k != "env_kwargs" and k not in RESUME_FREE_KEYS}
    flat.setdefault("n_envs", 1)
    env_kwargs = dict(entry.get("env_kwargs") or {})
    try:
        options = env_options_of(env_id, env_kwargs)
        options.pop("map", None)
    except (ValueError, TypeError):  # an option this version does not know: compare as written
        options = plain(env_kwargs)
    flat.update({f"env_kwargs.{k}": v for k, v in options.items()})
    return flat


def _differences(before: Mapping[str, Any], after: Mapping[str, Any], why: str) -> dict[str, tuple[Any, Any, str]]:
    keys = sorted(set(before) | set(after))
    return {k: (before.get(k), after.get(k), why) for k in keys if before.get(k) != after.get(k)}


def _resume_changes(cfg: TrainConfig, resume_model: Path | None, n_envs: int | None) -> dict[str, tuple[Any, Any, str]]:
    """``{key: (the run's value, the resumed run's value, why)}`` for every setting that differs.

    The run's values are the copy its record took at the start (or at the last allowed change);
    a run recorded before that copy existed is compared with its ``config.yml`` as it stands (so
    only ``--n-envs`` shows). Either way the env options saved in the checkpoint are compared
    too: they are what the model actually trained on.
    """
    entry = {**cfg.entry, **({"n_envs": n_envs} if n_envs is not None else {})}
    now = _spread(entry, cfg.env_id)
    recorded = cfg.run.get("settings")
    base = recorded if isinstance(recorded, Mapping) else cfg.entry
    changes = _differences(_spread(base, cfg.env_id), now, "config.yml was edited after the run started")
    if n_envs is not None and "n_envs" in changes:
        changes["n_envs"] = (changes["n_envs"][0], n_envs, "--n-envs")
    saved = training_options(resume_model) if resume_model is not None else None  # None: in its warm start
    trained = {f"env_kwargs.{k}": v for k, v in (saved or {}).items() if k != "map"}
    seen = {k: now.get(k) for k in trained}
    for key, change in _differences(trained, seen, "the checkpoint recorded another env").items():
        changes.setdefault(key, change)
    return changes


def _allowed_changes(
    resume: Any, changes: Mapping[str, tuple[Any, Any, str]], allow_change: bool
) -> dict[str, dict[str, Any]]:
    """The changes a resume may make, as its ``resumes:`` entry records them.

    :raises TrainingError: a change of a setting the checkpoint keeps (always), or of the world or
        the layout without ``allow_change``; one line naming each option and both values
    """

    def listing(items: Mapping[str, tuple[Any, Any, str]]) -> str:
        return ", ".join(f"{k} from {old!r} to {new!r} ({why})" for k, (old, new, why) in items.items())

    kept = {k: c for k, c in changes.items() if k.split(".")[0] not in RESUME_APPLIED_KEYS}
    if kept or (changes and not allow_change):
        raise TrainingError(
            f"--resume {resume} would change {listing(kept)}, which the checkpoint keeps as it was saved; "
            "restore config.yml or start a new run"
            if kept
            else f"--resume {resume} would change {listing(changes)}; pass --allow-change to resume with the "
            "change (it is recorded in config.yml)"
        )
    return {k: {"from": old, "to": new} for k, (old, new, _) in changes.items()}


def _check_not_a_fork(run_dir: Path, model: Path, fork: bool) -> bool:
    """Whether resuming ``model`` forks ``run_dir``'s history (it is older than the run's newest
    model); without ``fork`` that is one line, since resuming it in place would replace the final
    model, cut ``metrics.csv`` back and leave the next resume on the other branch."""
    newest = newest_model(run_dir)
    if newest is None or newest.resolve() == model.resolve():
        return False
    at, latest = validate_checkpoint(model).num_timesteps, validate_checkpoint(newest).num_timesteps
    if at >= latest:
        return False
    if not fork:
        raise TrainingError(
            f"--resume {model} is at {at} joint steps but run {run_dir} already reached {latest} ({newest.name}): "
            "resuming it in place would fork the run's history; resume the run folder (its newest), or pass "
            "--fork to continue from that checkpoint in a new run folder"
        )
    return True


def _resolve_resume(resume: str | os.PathLike[str]) -> tuple[Path | None, Path | None]:
    """:func:`~sb3_coma.app.runs.resolve_resume`, plus a run folder stopped before its first
    checkpoint: ``(folder, None)`` while its warm start is unfinished (the warm start continues),
    ``(folder, warm_start.zip)`` once the clone was saved (a COMA model at 0 joint steps that holds
    the KL reference and the actor's hold)."""
    p = Path(resume)
    if p.is_dir() and (p / CONFIG_FILE).is_file():
        if warm_start_pending(p):
            return p, None
        clone = p / WARM_START_MODEL
        if clone.is_file() and newest_model(p) is None:
            validate_checkpoint(clone)
            return p, clone
    return resolve_resume(resume)


def plan_run(
    env: str | None = None,
    config: str | os.PathLike[str] | None = None,
    variant: str | None = None,
    overrides: Mapping[str, Any] | None = None,
    resume: str | os.PathLike[str] | None = None,
    total_timesteps: int | None = None,
    n_envs: int | None = None,
    seed: int | None = None,
    eval_seed: int | None = None,
    device: str = "auto",
    allow_change: bool = False,
    fork: bool = False,
) -> RunPlan:
    """Load the config (or the resumed run's), apply the command-line settings, pick the seed.

    A resume in place takes the run folder's lock first (a second writer is refused before it
    reads or touches anything) and holds it in the plan; :meth:`RunPlan.release` lets it go.
    A checkpoint older than its run's newest model is a fork of the run's history: refused in place
    (:func:`_check_not_a_fork`), or, with ``fork``, continued in a new run folder with the parent
    run's config, recorded as ``forked_from``.
    """
    if total_timesteps is not None:
        total_timesteps = checked_count("total_timesteps", total_timesteps)
    if n_envs is not None:
        n_envs = checked_count("n_envs", n_envs)
    for name, value, least in (("seed", seed, None), ("eval_seed", eval_seed, 0)):  # one rule for the seeds
        if value is not None and (not is_int(value) or (least is not None and value < least)):
            raise TrainingError(f"{name} must be an integer{'' if least is None else f' >= {least}'}, got {value!r}")
    seed = None if seed is None else int(seed)  # a numpy integer as an int: config.yml records it
    check_device(device)
    resume_run, resume_model = _resolve_resume(resume) if resume is not None else (None, None)
    parent = None
    if resume_run is not None and resume_model is not None and _check_not_a_fork(resume_run, resume_model, fork):
        parent, resume_run = resume_run, None  # continue the parent's recipe in a new folder
    lock = lock_run_folder(resume_run, resuming=True) if resume_run is not None else None
    try:
        changes: dict[str, dict[str, Any]] = {}
        if resume_run is not None or parent is not None:
            source = resume_run or parent
            assert source is not None
            cfg = _resumed_config(source, resume, env, config, variant, overrides)
            changes = _allowed_changes(resume, _resume_changes(cfg, resume_model, n_envs), allow_change)
            if parent is not None:
                cfg.run = {**cfg.run, "forked_from": str(parent)}
        else:
            cfg = load_config(env, config, variant, overrides)
        if n_envs is not None:
            cfg.entry["n_envs"] = n_envs
        if total_timesteps is not None:
            cfg.entry["n_timesteps"] = total_timesteps
        info = validate_checkpoint(resume_model) if resume_model is not None else None
        if info is not None and info.n_agents is not None and info.n_agents != cfg.n_agents:
            raise TrainingError(
                f"checkpoint {resume_model} was trained with {info.n_agents} UAVs but the config has {cfg.n_agents}"
            )
    except BaseException:
        if lock is not None:
            lock.release()
        raise
    done = info.num_timesteps if info is not None else 0
    if seed is None:  # a resumed run continues its own seed, moved on by the steps done
        base = cfg.run.get("seed") if resume_run is not None or parent is not None else None
        seed = int(base) + done if is_int(base) else int(np.random.randint(0, 2**31 - 1))
    return RunPlan(
        cfg=cfg,
        seed=seed,
        resume_model=resume_model,
        run_path=resume_run,
        done_steps=done,
        eval_seed=VALIDATION_SEED if eval_seed is None else int(eval_seed),
        changes=changes,
        lock=lock,
    )


def _assertion_site(exc: BaseException) -> str:
    """``"AssertionError in <file>:<line>"`` for a bare ``assert`` without a message."""
    text = str(exc).strip()
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" in {Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else ""
    return f"AssertionError{where}" + (f": {text}" if text else "")


def _restore_recipe(model: COMA, plan: RunPlan) -> None:
    """Make sure a resumed warm-started run trains the same recipe: its checkpoint restores the KL
    reference actor and the actor's hold (``COMA.load``). A checkpoint saved before they were saved
    takes them from where they are still known, the run's ``warm_start.zip`` (the clone, which was
    the reference) and the config's ``critic_warmup``, with a warning; without that file the resume
    is refused, since it would train without the pull and the hold.

    :raises TrainingError: a warm-started run's checkpoint without a reference, and no clone
    """
    spec = plan.cfg.entry.get(WARM_START_KEY)
    if not spec or model.reference_actor is not None:
        return
    assert plan.resume_model is not None
    folder = run_folder_of(plan.resume_model)
    clone = folder / WARM_START_MODEL if folder is not None else None
    if clone is None or not clone.is_file():
        raise TrainingError(
            f"--resume {plan.resume_model}: the checkpoint of this warm-started run holds no KL reference actor "
            f"(saved by an older sb3-coma) and no {WARM_START_MODEL} of its run is there to take it from; resuming "
            "would train without the KL pull and the actor's hold, another recipe: start a new run"
        )
    warnings.warn(
        f"{plan.resume_model} holds no KL reference actor (saved by an older sb3-coma): the reference is taken "
        f"from {clone} and the actor's hold from critic_warmup in config.yml",
        stacklevel=2,
    )
    model.set_reference_actor()  # a frozen actor of the right shape, given the clone's weights
    assert model.reference_actor is not None
    model.reference_actor.load_state_dict(load_checkpoint(clone, device=model.device).policy.actor.state_dict())
    model.hold_actor(float(check_warm_start(spec, plan.cfg.where)["critic_warmup"]))


def build_model(plan: RunPlan, venv: VecEnv, device: str = "auto", verbose: int = 0) -> COMA:
    """A new COMA model from the config, or the resumed checkpoint on the new env (with its KL
    reference and actor hold, :func:`_restore_recipe`); either way it records the env options it
    trains with (:func:`record_env_options`)."""
    if plan.resume_model is not None:
        model = load_checkpoint(
            plan.resume_model, env=venv, device=device, tensorboard_log=None, verbose=verbose, seed=plan.seed
        )
        _restore_recipe(model, plan)
    else:
        try:
            model = COMA(
                env=venv,
                tensorboard_log=None,
                seed=plan.seed,
                verbose=verbose,
                device=device,
                **coma_kwargs(plan.cfg.entry),
            )
        except (AssertionError, TypeError, ValueError) as exc:  # one line naming the config entry
            if isinstance(exc, TrainingError):  # already names it (a bad policy name, ...)
                message = str(exc)
            elif isinstance(exc, AssertionError):  # e.g. SB3's bare `assert features_dim > 0`
                message = (
                    f"{plan.cfg.where}: COMA rejected a setting ({_assertion_site(exc)}); check "
                    f"policy_kwargs={plan.cfg.entry.get('policy_kwargs')!r}"
                )
            else:
                message = f"{plan.cfg.where}: {exc}"
            raise TrainingError(message) from exc
    record_env_options(model, plan.cfg.world)
    return model


def _run_record(plan: RunPlan) -> dict[str, Any]:
    """The ``run`` block of ``config.yml``: where the run came from (or one more resume of it)."""
    now = _dt.datetime.now().isoformat(timespec="seconds")
    if plan.resumed_in_place:
        assert plan.run_path is not None  # resumed in place
        origin = plan.resume_model or plan.run_path / WARM_START_STATE  # none: stopped in its warm start
        resume: dict[str, Any] = {"from": str(origin), "at": plan.done_steps, "seed": plan.seed, "when": now}
        if plan.changes:
            resume["changes"] = plan.changes
        resumes = [*list(plan.cfg.run.get("resumes") or []), resume]
        # the settings copy follows an allowed change, so the next resume compares with what runs now
        return {**plan.cfg.run, "settings": run_settings(plan.cfg.entry), "resumes": resumes}
    run: dict[str, Any] = {
        "env": plan.cfg.env_id,
        "variant": plan.cfg.variant,
        "seed": plan.seed,
        "config": str(Path(plan.cfg.source).resolve()) if plan.cfg.source is not None else None,
        "created": now,
        "sb3_coma": __version__,
        "command": " ".join(getattr(sys, "orig_argv", sys.argv)),
        # its checkpoints are validated on the validation protocol's missions (make_validation_env);
        # runs without this key flew the drawn train missions of their env seeds
        "validation_protocol": "validation",
    }
    if plan.resume_model is not None:
        run["resumed_from"] = str(plan.resume_model)
    if plan.cfg.run.get("forked_from"):  # a branch of another run (resume --fork): its parent
        run["forked_from"] = plan.cfg.run["forked_from"]
    run["settings"] = run_settings(plan.cfg.entry)  # to tell a later hand edit of the entry above
    return run


def prepare_run_folder(
    plan: RunPlan,
    model: COMA,
    run_dir: str | os.PathLike[str] | None = None,
    runs_root: str | os.PathLike[str] = "runs",
) -> Path:
    """The run folder (new, or the resumed one) with its ``config.yml``; TensorBoard logs go there.

    The folder's lock is taken here for a new run (a resume took it when planning) and kept in
    ``plan.lock`` for the whole run.
    """
    if plan.run_path is None:
        run_path, plan.lock = claim_run_dir(run_dir, plan.cfg.env_id, plan.cfg.variant, runs_root)
    else:
        run_path = plan.run_path
        if plan.lock is None:
            plan.lock = lock_run_folder(run_path, resuming=True)
    plan.cfg.run = _run_record(plan)
    write_run_config(run_path, plan.cfg)
    model.tensorboard_log = str(run_path / TENSORBOARD_DIR)  # read when learn() sets up its logger
    if plan.resumed_in_place:
        truncate_metrics_csv(run_path / METRICS_FILE, plan.done_steps)  # those missions are flown again
    return run_path


def attach_callbacks(
    plan: RunPlan,
    run_path: Path,
    save_freq: int | None = None,
    eval_freq: int = 0,
    eval_missions: int | None = None,
    extra: list[BaseCallback] | None = None,
    handle_signals: bool = True,
    verbose: int = 1,
) -> tuple[MissionCallbacks, list[BaseCallback]]:
    """The run's callbacks: :func:`mission_callbacks`, the config's ``callback`` entries, ``extra``,
    and the signal stop last. Returns the standard set and the list to pass to ``learn``."""
    # save_freq and eval_freq were checked once, in _check_counts (app.config.checked_count)
    every = max(plan.cfg.n_timesteps // 10, 1) if save_freq is None else int(save_freq)
    eval_env = None
    missions = validation_missions(plan.cfg.map_name) if eval_missions is None else eval_missions
    if eval_freq and eval_freq > 0:
        missions = checked_count("eval_missions", missions)
        eval_env = make_validation_env(plan.cfg, missions, plan.eval_seed)
    standard = mission_callbacks(
        run_path,
        every,
        checkpoint_dir=run_path / CHECKPOINT_DIR,
        eval_env=eval_env,
        eval_freq=eval_freq,
        eval_missions=missions,
        eval_seed=plan.eval_seed,
        eval_log_path=run_path / "eval",
        stop_on_signal=handle_signals,
        verbose=max(verbose - 1, 0),
        stop_verbose=verbose,
        select_after=selection_end(plan.cfg.entry, plan.cfg.n_timesteps),
    )
    configured = [
        construct(cls, kwargs, "callback") if isinstance(cls, type) else cls
        for cls, kwargs in named_objects(plan.cfg.entry.get("callback"), "callback")
    ]
    stop = [standard.stopper] if standard.stopper is not None else []
    return standard, [*standard.as_list(), *configured, *(extra or []), *stop]


def learn(
    model: COMA,
    plan: RunPlan,
    standard: MissionCallbacks,
    callback_list: list[BaseCallback],
    progress_bar: bool = True,
    say: Callable[[str], None] = print,
) -> None:
    """Train up to the plan's total; always restores signal handlers and closes the envs."""
    remaining = plan.cfg.n_timesteps - int(model.num_timesteps)
    try:
        if remaining > 0:
            say(
                f"Training {plan.cfg.env_id}"
                + (f" ({plan.cfg.variant})" if plan.cfg.variant else "")
                + f" for {remaining} joint steps (to {plan.cfg.n_timesteps}); "
                + f"TensorBoard: tensorboard --logdir {model.tensorboard_log}"
            )
            model.learn(
                total_timesteps=remaining,
                callback=callback_list,
                tb_log_name=TB_LOG_NAME,
                reset_num_timesteps=plan.resume_model is None,
                progress_bar=progress_bar and getattr(sb3_callbacks, "tqdm", None) is not None,
            )
        else:
            say(f"Nothing to train: the model is at {model.num_timesteps} >= {plan.cfg.n_timesteps} joint steps")
    finally:
        _close_run(model, standard)


def _close_run(model: COMA, standard: MissionCallbacks) -> None:
    """Restore the signal handlers, close the metrics file and the envs: the end of every run,
    however it ends (trained, stopped, failed)."""
    if standard.stopper is not None:
        standard.stopper.restore()
    standard.metrics.close()
    if standard.evaluation is not None:
        standard.evaluation.eval_env.close()
    if model.env is not None:
        model.env.close()
    release_freed_memory()  # the training envs' maps, before whatever the process does next


def _warm_start(
    model: COMA,
    plan: RunPlan,
    run_path: Path,
    standard: MissionCallbacks,
    say: Callable[[str], None],
    handle_signals: bool,
) -> None:
    """The warm start of a new run, or the rest of one stopped during it (a resume in place without
    a checkpoint); a signal stops it after saving its progress (:class:`TrainingInterrupted`).
    The run's envs are closed when it does not go on to :func:`learn`."""
    try:
        warm_start_run(
            model,
            plan.cfg,
            plan.seed,
            run_path,
            say,
            resume=plan.resumed_in_place,
            stop_on_signal=handle_signals,
        )
    except WarmStartInterrupted as exc:
        _close_run(model, standard)
        say(
            f"Interrupted during the warm start after round {exc.rounds_done}/{exc.rounds} (progress in "
            f"{exc.state}); resume with: sb3-coma train --resume {run_path}"
        )
        raise TrainingInterrupted(run_path, exc.state, 0, exc.signum) from None
    except BaseException:
        _close_run(model, standard)
        raise


def _summary(history: list[dict[str, Any]], last: int = 20) -> str:
    if not history:
        return "no mission finished"
    recent = history[-last:]

    def mean(key: str) -> float:
        values = [r[key] for r in recent if not math.isnan(r[key])]
        return float(sum(values) / len(values)) if values else math.nan

    return (
        f"last {len(recent)} missions: team reward {mean('reward'):+.3f}, "
        f"F1 {mean('f1'):.3f}, entropy {mean('entropy'):.3f}"
    )


def save_final(
    model: COMA, plan: RunPlan, run_path: Path, standard: MissionCallbacks, say: Callable[[str], None] = print
) -> Path:
    """``model.zip`` when training completed; after a signal, a checkpoint at the last rollout
    boundary and :class:`TrainingInterrupted`."""
    stopper = standard.stopper
    if stopper is not None and stopper.received is not None and model.num_timesteps < plan.cfg.n_timesteps:
        at, reached = stopper.boundary_timesteps, int(model.num_timesteps)
        assert standard.checkpoints is not None, "train() always checkpoints"
        model.num_timesteps = at
        try:
            path = standard.checkpoints.save_now(at)
        finally:
            model.num_timesteps = reached
        say(f"Interrupted: checkpoint {path} ({at} joint steps); resume with: sb3-coma train --resume {run_path}")
        raise TrainingInterrupted(run_path, path, at, stopper.received)
    final = atomic_save(model, run_path / MODEL_FILE)
    say(f"Saved {final} ({model.num_timesteps} joint steps); {_summary(standard.metrics.history)}")
    return final


# =========================================================================== train()
def _check_counts(eval_freq: Any, save_freq: Any) -> None:
    """The frequencies, refused before anything is built (the seeds: :func:`plan_run`)."""
    for name, value in (("eval_freq", eval_freq), ("save_freq", save_freq)):
        if value is not None:
            checked_count(name, value)


def train(
    env: str | None = None,
    *,
    config: str | os.PathLike[str] | None = None,
    variant: str | None = None,
    total_timesteps: int | None = None,
    seed: int | None = None,
    run_dir: str | os.PathLike[str] | None = None,
    resume: str | os.PathLike[str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    n_envs: int | None = None,
    save_freq: int | None = None,
    eval_freq: int = 0,
    eval_missions: int | None = None,
    eval_seed: int | None = None,
    callbacks: list[BaseCallback] | None = None,
    progress_bar: bool = True,
    device: str = "auto",
    verbose: int = 1,
    handle_signals: bool = True,
    runs_root: str | os.PathLike[str] = "runs",
    log: Callable[[str], None] | None = None,
    allow_change: bool = False,
    fork: bool = False,
) -> tuple[COMA, Path]:
    """Train COMA and return ``(model, run_dir)``.

    The returned model's training env is closed (``model.env``); give it a new one
    (``uav_ipp.make_vec_env``) to predict or evaluate, or load ``run_dir / "model.zip"``.

    :param env: ``"env1"``/``"env2"``/``"env3"`` or a gymnasium id (default ``"env3"``; with
        ``resume`` of a run folder, the run's own env)
    :param config: rl-zoo3 style YAML (default ``zoo_configs/coma.yml``)
    :param variant: a name from the config's ``variants`` mapping (ablation arm)
    :param total_timesteps: joint steps to reach in total (default: the config's ``n_timesteps``);
        when resuming, the total to reach, counting the steps already done
    :param seed: seed of model and env (default: random, recorded in ``config.yml``; when
        resuming, the run's seed plus the joint steps done)
    :param run_dir: run folder (default ``runs/<env id>[-<variant>]_<n>``; a folder that holds
        anything gets a ``_<n>`` suffix instead of being reused)
    :param resume: a run folder or checkpoint zip to continue from (same timestep count,
        optimiser states restored, ``reset_num_timesteps=False``)
    :param fork: with ``resume`` of a checkpoint older than its run's newest model: continue from it
        in a new run folder (its ``config.yml`` names the parent as ``forked_from``) instead of refusing
    :param overrides: config keys to change, dots reach into mappings (``{"env_kwargs.noise": "loud"}``)
    :param n_envs: env copies (default: the config's ``n_envs``)
    :param save_freq: joint steps between checkpoints (default: a tenth of the run)
    :param eval_freq: joint steps between evaluations (0: none); best model -> ``best_model.zip``
    :param eval_missions: missions per evaluation (default: the validation protocol's, 4 per train
        scene: env3 48, env2 36, env1 48)
    :param eval_seed: env seed of the validation missions, the same at every evaluation (default
        :data:`VALIDATION_SEED`, disjoint from the seeds ``evaluate`` and ``reproduce`` test on)
    :param callbacks: extra SB3 callbacks
    :param progress_bar: show SB3's progress bar (joint steps)
    :param device: torch device
    :param verbose: 0 silent, 1 run information, 2 also SB3's training tables
    :param handle_signals: on SIGINT/SIGTERM save a checkpoint and raise :class:`TrainingInterrupted`
    :param runs_root: parent of default run folders
    :param log: where information lines go (default ``print`` when ``verbose >= 1``)
    :param allow_change: let a resume change the world or the layout (:data:`RESUME_APPLIED_KEYS`;
        a hand-edited ``config.yml``, ``n_envs``), recorded in its ``resumes:`` entry
    :raises TrainingError: bad env id, variant, config file or key, resume path, device (or none
        here), a ``run_dir`` that cannot be made or is in use, a resume that changes the settings
    :raises CheckpointError: a resume zip that is truncated or not a COMA model
    :raises TrainingInterrupted: stopped by a signal (after saving a checkpoint)
    """
    say = log or (print if verbose >= 1 else (lambda _msg: None))
    _check_counts(eval_freq, save_freq)
    check_run_dir(run_dir)
    plan = plan_run(
        env, config, variant, overrides, resume, total_timesteps, n_envs, seed, eval_seed, device, allow_change, fork
    )
    callback_args = (save_freq, eval_freq, eval_missions, callbacks, handle_signals)
    try:  # the run folder stays locked until the run is over, however it ends
        model, run_path, standard, callback_list = _set_up(plan, run_dir, runs_root, device, verbose, callback_args)
        _fly(model, plan, run_path, (standard, callback_list), progress_bar, say, handle_signals)
    finally:
        plan.release()
    return model, run_path


def _fly(
    model: COMA,
    plan: RunPlan,
    run_path: Path,
    callbacks: tuple[MissionCallbacks, list[BaseCallback]],
    progress_bar: bool,
    say: Callable[[str], None],
    handle_signals: bool,
) -> None:
    """A set-up run, its folder locked by :func:`train`: resume or warm-start, learn, save."""
    standard, callback_list = callbacks
    say(f"Run folder: {run_path}")
    if plan.resume_model is not None:
        say(f"Resuming from {plan.resume_model} at {plan.done_steps} joint steps")
    elif plan.cfg.entry.get(WARM_START_KEY) is not None:
        _warm_start(model, plan, run_path, standard, say, handle_signals)
    learn(model, plan, standard, callback_list, progress_bar=progress_bar, say=say)
    save_final(model, plan, run_path, standard, say=say)


def _set_up(
    plan: RunPlan,
    run_dir: str | os.PathLike[str] | None,
    runs_root: str | os.PathLike[str],
    device: str,
    verbose: int,
    callback_args: tuple[int | None, int, int | None, list[BaseCallback] | None, bool],
) -> tuple[COMA, Path, MissionCallbacks, list[BaseCallback]]:
    """Steps 2-5 of :func:`train`: envs, model, run folder, callbacks (``callback_args``: the
    arguments of :func:`attach_callbacks` after the run folder). Nothing is written before the
    env and the model exist; the env is closed if a later step fails."""
    venv = make_training_env(plan.cfg, seed=plan.seed)
    try:
        model = build_model(plan, venv, device=device, verbose=max(int(verbose) - 1, 0))
        run_path = prepare_run_folder(plan, model, run_dir, runs_root)
        standard, callback_list = attach_callbacks(plan, run_path, *callback_args, verbose=verbose)
    except BaseException:
        venv.close()
        raise
    return model, run_path, standard, callback_list
