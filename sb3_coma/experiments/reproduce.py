"""Reproduce the paper's results and the project's own checks: ``sb3-coma reproduce``.

``reproduce()`` evaluates the shipped COMA models (or, with ``train=True``, models retrained
through ``zoo_configs/coma.yml``), every other shipped model of each map, and the baselines (AG with
the map's validated weighting, AG with look-ahead 2 and 3, lawnmower, random; IPPO / MAPPO rows
when such models are shipped) in named steps (:data:`STEPS`), writing into ``out``:

* ``table.md`` / ``table.csv`` -- Table I, the **paper protocol** (split "paper", 10 seeded trials):
  F1 and entropy of the global map at 33/67/100 % of the budget, mean +- std;
  ``team_table.md`` / ``.csv`` the team metrics (each UAV's own map) the same way;
  ``paper_verdicts.md`` / ``.csv`` the paired verdicts; ``per_step.csv``, ``planning_time.csv``
* ``acceptance.md`` -- does COMA beat every baseline on F1 *and* entropy (paired tests), per env
* ``ablation.md`` / ``.csv`` -- the env3 SenDFuse x CBAM ablation at three noise levels
* ``paired.md`` -- COMA vs AG and the full model vs each ablation arm on more paper-split missions
* ``unseen_*.md`` / ``.csv`` -- the **unseen protocol** (50 missions on split "test", random
  starts): tables, team tables, verdicts
* ``generalisation.md`` -- each env's model on the other maps and a fresh env1 star seed
* ``noise_sweep.md`` / ``.csv`` -- AG and each ablation arm over sigma, a_low, drop probability
  and both decoders (``sb3_coma.experiments.noise_sweep``)
* ``latency.md`` -- the deployment cost per UAV decision (``sb3_coma.experiments.costs``)
* ``summary.json`` -- every number above; ``figures/``; ``RESULTS.md`` (``sb3_coma.experiments.report``),
  with ``docs=...`` also written there (figures next to it)

``out`` is written as one staged output (``sb3_coma.app.outputs.staged_output``): everything goes
into ``<out>.partial-<pid>`` and replaces ``out`` only when the run is complete, so an interrupted
run (SIGKILL, SIGTERM, an error) leaves the previous results as they were. The ``docs`` copy is
written at the end of the run, just before that swap.

Every "A beats B" in the report is a paired test on shared missions (``sb3_coma.stats.paired``);
everything in it is measured by the run that writes it; nothing is copied in.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
import json
import platform
import shutil
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

import uav_ipp
from sb3_coma import COMA
from sb3_coma.app import evaluation as ev
from sb3_coma.app import pretrained as pt
from sb3_coma.app.outputs import staged_output
from sb3_coma.app.pretrained import PretrainedError
from sb3_coma.app.training import train
from sb3_coma.baselines.adaptive_gain import default_weighting
from sb3_coma.common.callbacks import ProgressLinesCallback
from sb3_coma.experiments import ablation as ab
from sb3_coma.experiments import plots as pl
from sb3_coma.experiments import report
from sb3_coma.experiments import user_maps as um
from sb3_coma.experiments.ablation import LABELS
from sb3_coma.experiments.costs import _torch_fusion, costs_markdown, decision_costs, one_thread, time_call
from sb3_coma.experiments.noise_sweep import run_noise_sweep
from sb3_coma.experiments.protocols import (
    BASELINE_METHODS,
    LEARNED_BASELINES,
    Method,
    outdated_note,
    run_protocol,
    shipped_methods,
)
from sb3_coma.stats import tables
from sb3_coma.stats.paired import holm_adjust, paired_difference, paired_markdown
from uav_ipp import WORLD_VERSION
from uav_ipp.maps.ground_truth import available_maps

DEFAULT_ENVS: tuple[str, ...] = ("env1", "env2", "env3")
#: The baselines of Table I (the protocols also fly AG's look-ahead variants: sb3_coma.experiments.protocols).
BASELINES: tuple[str, ...] = report.PLANNER_NAMES
#: the shipped model flown on the user-map images, and the missions per image
USER_MAP_MODEL = "env3"
USER_MAP_MISSIONS = 5
#: map seed of the "fresh" env1 star layout used for generalisation (env1's default map_seed is 0)
FRESH_ENV1_SEED = 7
#: tiny training used by ``quick=True`` together with ``train=True`` (joint steps and overrides)
QUICK_TIMESTEPS = 32
#: --quick trains a few steps without the warm start (sb3_coma.app.warm_start has its own tests)
QUICK_OVERRIDES = {"n_envs": 2, "n_steps": 8, "batch_size": 16, "n_critic_epochs": 1, "warm_start": None}
#: evaluation seed base; training seed of the shipped models
TRAIN_SEED = 0
#: the shipped SenDFuse models train on their map's default config entry (no variant); a mean-fusion
#: retrain uses the ablation's "CBAM only" arm
MEAN_FUSION_VARIANT = "mean-cbam"
#: the shipped models are the best of the run's checkpoints on the SAME 10 validation missions
#: (split train, env seeds 1000..1009, never the test split), scored every 3000 joint steps
#: (``best_model.zip``)
TRAIN_EVAL_FREQ = 3000
#: the map of the paper's ablation and the shipped models of its four arms, all trained by COMA from
#: scratch with one recipe (the main env3 model is warm-started, so it would compare the warm start,
#: not SenDFuse and CBAM; it is the full arm only where no shipped arm exists)
ABLATION_ENV = "env3"
ABLATION_ARMS: dict[tuple[str, str], str] = {
    ("sendfuse", "cbam"): "env3-sendfuse-cbam",
    ("sendfuse", "cnn"): "env3-sendfuse-cnn",
    ("mean", "cbam"): "env3-mean-cbam",
    ("mean", "cnn"): "env3-mean-cnn",
}
#: the arm every other arm is compared with, and the noise level of that comparison
ABLATION_FULL = ("sendfuse", "cbam")
ABLATION_CHECK_NOISE = "loud"
#: Missions of the paired check on the paper split that backs Table I's and the ablation's verdicts.
WIDE_TRIALS = 50
#: Missions of the unseen protocol (sb3_coma.common.evaluation.PROTOCOLS["unseen"]) and of the noise sweep,
#: which flies the same missions (env seeds 0..49 of split "test") at every channel setting (20
#: missions, the command's default, left every arm tied with AG on the paired test).
UNSEEN_MISSIONS = 50
SWEEP_MISSIONS = UNSEEN_MISSIONS
#: ``quick``: missions of every protocol, sweep and check; cost-table repeats.
QUICK_TRIALS = 2
QUICK_REPEATS = 5
COST_REPEATS = 200
#: What ``reproduce`` writes into ``out`` (``fnmatch`` patterns): how a results folder written
#: before outputs carried a manifest tells this command's files from others' (those are kept).
OUTPUT_PATTERNS: tuple[str, ...] = (
    "table.*",
    "team_table.*",
    "per_step.csv",
    "planning_time.*",
    "acceptance.md",
    "ablation.*",
    "paired.md",
    "paper_*",
    "unseen_*",
    "generalisation.md",
    "user_maps.md",
    "noise_sweep.*",
    "latency.md",
    "summary.json",
    "RESULTS.md",
    "figures",
    "runs",
)
#: Errors that make an optional step or row "skipped, with the reason" instead of a failed run.
OPTIONAL_ERRORS: tuple[type[BaseException], ...] = (ImportError, FileNotFoundError, ValueError, RuntimeError, OSError)


# ---------------------------------------------------------------------------------------------
# options and the run's state
# ---------------------------------------------------------------------------------------------
@dataclass
class ReproduceOptions:
    """Everything ``reproduce`` can be told (keyword arguments of :func:`reproduce`).

    :param env_names: maps to evaluate
    :param trials: missions of the paper protocol (Table I) and the ablation
    :param unseen_missions: missions of the unseen protocol (0: skip it)
    :param sweep_missions: missions of the noise sweep (0: skip it)
    :param wide_trials: missions of the paired check on the paper split (0: skip)
    :param seed: base env seed: mission ``k`` of every protocol is seed ``seed + k``
    :param noise: channel noise of the protocols
    :param train: retrain each env's model through the zoo config instead of loading the shipped one
    :param quick: smoke test: :data:`QUICK_TRIALS` missions everywhere, a small sweep, and with
        ``train`` a tiny training
    :param timesteps: with ``train``: joint steps (default: the shipped model's run length)
    :param fusion: fusion of retrained models (default: the shipped model's, else sendfuse when its
        weights exist, else mean)
    :param deterministic: argmax actions or seeded draws (default: the shipped model's entry)
    :param docs: also write ``RESULTS.md`` at this path and its figures in ``<docs dir>/figures``
    :param ship: with ``train``: copy the trained zips into ``sb3_coma/pretrained`` and update ``models.json``
    :param record: write the measured Table I numbers of the shipped models into ``models.json``
    :param extra_models: ``{env: {label: model}}`` more learned methods to fly (e.g. IPPO / MAPPO
        models loaded by the caller); labels starting with "ippo" / "mappo" are treated as those kinds
    :param cost_envs: maps whose AG planning cost the cost table times (default: all evaluated maps)
    :param baselines_only: fly no learned model at all (the baselines' rows of every step). Without
        it, a map with no shipped model (an install without ``sb3_coma/pretrained``) gets baseline
        rows only, with the reason under "Skipped"
    """

    env_names: Sequence[str] = DEFAULT_ENVS
    trials: int = 10
    unseen_missions: int = UNSEEN_MISSIONS
    sweep_missions: int = SWEEP_MISSIONS
    wide_trials: int = WIDE_TRIALS
    seed: int = 0
    noise: str = "moderate"
    train: bool = False
    quick: bool = False
    timesteps: int | None = None
    fusion: str | None = None
    deterministic: bool | None = None
    docs: str | Path | None = None
    plots: bool = True
    ship: bool = False
    record: bool = False
    generalisation: bool = True
    ablation: bool = True
    costs: bool = True
    extra_models: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    cost_envs: Sequence[str] | None = None
    baselines_only: bool = False

    def checked(self) -> ReproduceOptions:
        """Validated, with ``quick`` applied."""
        self.env_names = list(self.env_names)
        if not self.env_names:
            raise ValueError("env_names is empty")
        for name in ("trials", "unseen_missions", "sweep_missions", "wide_trials", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if name == "trials" else 0):
                raise ValueError(f"{name} must be an integer >= {1 if name == 'trials' else 0}, got {value!r}")
        if self.quick:
            self.trials = min(self.trials, QUICK_TRIALS)
            self.wide_trials = min(self.wide_trials, self.trials)
            self.unseen_missions = min(self.unseen_missions, QUICK_TRIALS)
            self.sweep_missions = min(self.sweep_missions, QUICK_TRIALS)
        if self.wide_trials == 1:
            raise ValueError(f"wide_trials must be 0 (skip) or an integer >= 2, got {self.wide_trials!r}")
        if self.ship and (not self.train or self.quick):
            raise ValueError("ship=True needs train=True and quick=False")
        if self.baselines_only and (self.train or self.record):
            raise ValueError("baselines_only=True flies no model: it cannot train, ship or record one")
        return self


@dataclass
class ModelSource:
    env: str
    model: Any
    fusion: str
    source: str  # "shipped" or the run folder
    command: str
    train_wall_s: float | None
    timesteps: int | None
    training_curve: list[float] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    deterministic: bool = True  # argmax actions (True) or seeded draws from the policy (False)


@dataclass
class Run:
    """What the steps share: the options, the models, the results, the report's parts."""

    opts: ReproduceOptions
    out: Path
    say: Callable[[str], None]
    #: Where ``out`` (the staging folder) goes when the run is complete (``None``: ``out`` itself).
    target: Path | None = None
    started: float = field(default_factory=time.perf_counter)
    sources: dict[str, ModelSource] = field(default_factory=dict)
    arms: dict[tuple[str, str], Any] = field(default_factory=dict)
    methods: dict[str, list[Any]] = field(default_factory=dict)
    paper: Any = None
    unseen: Any = None
    ablation: Any = None
    sweep: Any = None
    summary: dict[str, Any] = field(default_factory=dict)
    sections: dict[str, str] = field(default_factory=dict)
    figures: list[Path] = field(default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def results(self) -> list[Any]:
        """The paper protocol's results (Table I), in table order."""
        return [row.result for row in self.paper.rows()] if self.paper is not None else []

    def final(self, path: Path) -> Path:
        """Where ``path``, written under the staging folder, lies once the run is in place: what
        the summary and the log name."""
        if self.target is None:
            return path
        try:
            return self.target / Path(path).relative_to(self.out)
        except ValueError:
            return path


def attempt(run: Run, what: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)``, or ``None`` with the reason in ``run.skipped[what]`` and the log
    when it fails for a reason this install can have (a missing optional part, a model that cannot
    be loaded): the one place optional parts of the run are guarded."""
    try:
        return fn(*args, **kwargs)
    except OPTIONAL_ERRORS as exc:
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        run.skipped[what] = reason
        run.say(f"skipping {what}: {reason}")
        return None


def manifest_value(env: str, key: str, default: Any = None) -> Any:
    """``models.json``'s ``key`` of the shipped model ``env``, ``default`` when either is missing."""
    try:
        return pt.model_info(env).get(key, default)
    except (ImportError, ValueError):
        return default


# ---------------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------------
def reproduce(
    out: str | Path = "results", *, log: Callable[[str], None] | None = print, **options: Any
) -> dict[str, Any]:
    """Run the reproduction (see module docstring) and return the summary dict.

    ``options`` are the fields of :class:`ReproduceOptions` (``env_names``, ``trials``,
    ``unseen_missions``, ``train``, ``quick``, ``docs`` ...).
    """
    unknown = sorted(set(options) - {f.name for f in dataclasses.fields(ReproduceOptions)})
    if unknown:
        raise TypeError(f"reproduce() got unknown options {unknown}")
    opts = ReproduceOptions(**options).checked()
    say = log or (lambda _m: None)
    with staged_output(out, command="reproduce", own=OUTPUT_PATTERNS, say=say) as staging:
        run = Run(opts, staging, say, target=Path(out))
        start = time.perf_counter()
        for number, step in enumerate(STEPS, start=1):
            tic = time.perf_counter()
            say(f"[{number}/{len(STEPS)}] {step.__name__.replace('_', ' ')} ({tic - start:.0f} s elapsed)")
            step(run)
            run.timings[step.__name__] = round(time.perf_counter() - tic, 1)
    return run.summary


# ---------------------------------------------------------------------------------------------
# step 1: models
# ---------------------------------------------------------------------------------------------
def load_models(run: Run) -> None:
    """Each env's COMA model (shipped or retrained), the ablation arms, and the methods of the
    protocols per env: that model, every other model shipped for the env, extra models, baselines."""

    o = run.opts
    for env in o.env_names:
        if o.baselines_only:
            continue
        if o.train:
            run.sources[env] = _retrained_model(run, env)
        else:
            src = _shipped_or_none(run, env)
            if src is not None:
                run.sources[env] = src
    if o.ablation and ABLATION_ENV in run.sources:
        run.arms = ablation_models(run.sources[ABLATION_ENV].model, run.say)
    loaded = {ABLATION_ARMS[v]: m for v, m in run.arms.items() if v in ABLATION_ARMS}
    for env, src in run.sources.items():
        note = outdated_note(src.info) if src.source == "shipped" else ""
        own = Method("coma", src.model, kind="coma", fusion=src.fusion, deterministic=src.deterministic, note=note)
        others = (
            attempt(
                run, f"other shipped models of {env}", shipped_methods, env, loaded=loaded, skip=(env,), log=run.say
            )
            or []
        )
        extra = [Method(label, model, kind=_kind_of(label)) for label, model in o.extra_models.get(env, {}).items()]
        run.methods[env] = [own, *others, *extra, *BASELINE_METHODS]
    for env in o.env_names:
        run.methods.setdefault(env, list(BASELINE_METHODS))


def _shipped_or_none(run: Run, env: str) -> ModelSource | None:
    """The shipped model of ``env``; ``None`` (baseline rows only, the reason under "Skipped") when
    this install has none for a built-in map; an unknown name is an error."""

    try:
        return _shipped_model(env, run.opts.deterministic)
    except PretrainedError as exc:
        if env not in available_maps():
            raise
        run.skipped[f"COMA on {env}"] = f"no shipped model ({exc}); baseline rows only"
        run.say(f"no shipped model for {env}: baseline rows only ({exc})")
        return None


def _kind_of(label: str) -> str:

    return next((k for k in LEARNED_BASELINES if label.lower().startswith(k)), "coma")


def sendfuse_available() -> bool:
    """Whether ``fusion="sendfuse"`` can be built (its pre-trained weights exist)."""

    try:
        uav_ipp.make_vec_env("env1", fusion="sendfuse").close()
        return True
    except Exception:  # any failure means: not usable here
        return False


def _variant_for(env: str, fusion: str) -> str | None:
    """The zoo config variant of a shipped model's settings for a fusion (None: the map's entry)."""
    return None if fusion == "sendfuse" else MEAN_FUSION_VARIANT


def train_command(env: str, fusion: str, seed: int = TRAIN_SEED, validate: bool = True) -> str:
    """The command that retrains a shipped model (with ``validate``, its ``best_model.zip`` is the model)."""
    variant = _variant_for(env, fusion)
    command = f"sb3-coma train --env {env}" + (f" --variant {variant}" if variant else "") + f" --seed {seed}"
    return command + (f" --eval-freq {TRAIN_EVAL_FREQ}" if validate else "")


def curve_from_metrics(path: Path) -> list[float]:
    """The ``reward`` column of a run's ``metrics.csv`` (the team reward of every finished mission),
    the training curve that ``models.json`` records; empty when the run wrote none."""
    if not path.is_file():
        return []
    with path.open() as fh:
        return [round(float(row["reward"]), 4) for row in csv.DictReader(fh)]


def shipped_seed(env: str) -> int:
    """The training seed of the shipped model of ``env`` (the seed whose run won on the validation
    missions, models.json), so ``--train`` retrains that very model; ``TRAIN_SEED`` without one."""
    return int(manifest_value(env, "seed", TRAIN_SEED))


def shipped_timesteps(env: str) -> int | None:
    """The joint steps the shipped model of ``env`` was trained for when its command sets them
    (``--timesteps``, recorded as ``train_timesteps``); ``None``: the config's ``n_timesteps``."""
    value = manifest_value(env, "train_timesteps")
    return None if value is None else int(value)


def _retrained_model(run: Run, env: str) -> ModelSource:
    o = run.opts
    fusion = o.fusion or manifest_value(env, "fusion")
    if fusion in ("sendfuse", None):
        fusion = "sendfuse" if sendfuse_available() else "mean"
    deterministic = o.deterministic if o.deterministic is not None else bool(manifest_value(env, "deterministic", True))
    src = _train_model(env, fusion, run.out, o.quick, o.timesteps, run.say, deterministic)
    src.source = str(run.final(Path(src.source)))  # the run folder where it will be, not the staging one
    return src


def _train_model(
    env: str,
    fusion: str,
    out: Path,
    quick: bool,
    timesteps: int | None,
    log: Callable[[str], None],
    deterministic: bool = True,
) -> ModelSource:

    overrides: dict[str, Any] = dict(QUICK_OVERRIDES) if quick else {}
    total = QUICK_TIMESTEPS if quick else (timesteps or shipped_timesteps(env))
    variant = _variant_for(env, fusion)
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


def _shipped_model(env: str, deterministic: bool | None = None) -> ModelSource:

    model = pt.load_pretrained(env)
    info = model.pretrained_info
    det = bool(info.get("deterministic", True)) if deterministic is None else deterministic
    return ModelSource(
        env,
        model,
        info.get("fusion", "sendfuse"),
        "shipped",
        info.get("command", ""),
        info.get("train_wall_s"),
        info.get("timesteps"),
        list(info.get("training_curve", [])),
        info,
        det,
    )


def ablation_models(full_model: Any, say: Callable[[str], None] = print) -> dict[tuple[str, str], Any]:
    """The four ablation arms: the shipped model of each (:data:`ABLATION_ARMS`); an arm whose
    shipped model cannot be loaded is left out with a message, except the full arm, which is then
    ``full_model`` (the env3 model in use)."""

    models: dict[tuple[str, str], Any] = {}
    for arm, name in ABLATION_ARMS.items():
        try:
            models[arm] = pt.load_pretrained(name)
        except PretrainedError as exc:
            if arm == ABLATION_FULL:
                models[arm] = full_model
            else:
                say(f"ablation: leaving out {arm[0]}_{arm[1]}: {exc}")
    return models


# ---------------------------------------------------------------------------------------------
# step 2: the paper protocol (Table I)
# ---------------------------------------------------------------------------------------------
def paper_protocol(run: Run) -> None:
    """Table I on split "paper": every method, global and team tables, paired verdicts, acceptance."""

    o = run.opts
    run.paper = run_protocol("paper", run.methods, n_trials=o.trials, seed=o.seed, noise=o.noise, log=run.say)
    run.paper.write(run.out, "paper")
    run.skipped.update({f"paper protocol: {k}": v for k, v in run.paper.skipped.items()})
    rows = run.paper.rows()
    tables.write_table_csv(rows, run.out / "table.csv")
    tables.write_table_csv(rows, run.out / "team_table.csv", metrics="team")
    tables.write_per_step_csv(rows, run.out / "per_step.csv")
    tables.write_planning_time_csv(rows, run.out / "planning_time.csv")
    run.sections["table"] = run.paper.table("global")
    (run.out / "table.md").write_text(run.sections["table"])
    (run.out / "team_table.md").write_text(run.paper.table("team"))
    run.summary.update(table={f"{r.env}/{r.method}": r.summary() for r in run.results}, paper=run.paper.summary())


def _competitors(run: Run) -> list[str]:
    """The methods a COMA model must beat: every baseline, never the upper references."""
    return list(dict.fromkeys(m.label for ms in run.methods.values() for m in ms if m.kind in ("baseline",)))


def acceptance(
    results: Sequence[Any],
    model_label: str = "coma",
    baselines: Sequence[str] | None = None,
    verdicts: Mapping[tuple[str, str], Mapping[str, Any]] | None = None,
) -> dict[str, dict[str, Any]]:
    """Per env: does ``model_label`` beat every baseline on F1 and on entropy at 100 %, each by a
    paired test on the shared missions (``sb3_coma.stats.paired``: a tie is not a win)?

    :param baselines: the methods to beat (default: every other method whose label does not start
        with ``model_label``, i.e. not another COMA model)
    :param verdicts: ``{(env, baseline): {metric: difference}}`` already Holm-adjusted in the
        protocol's verdict table, so that the acceptance and that table say the same; without it
        each env's row is its own Holm family
    """

    out: dict[str, dict[str, Any]] = {}
    for env in dict.fromkeys(r.env for r in results):
        group = {r.method: r for r in results if r.env == env}
        if model_label not in group:
            continue
        mine = group[model_label]
        others = {
            k: v
            for k, v in group.items()
            if k != model_label and (k in baselines if baselines is not None else not k.startswith(model_label))
        }
        if verdicts is not None and all((env, k) in verdicts for k in others):
            diffs = {k: {m: verdicts[(env, k)][m] for m in ("f1", "entropy")} for k in others}
        else:
            diffs = _holm_nested(
                {k: {m: paired_difference(mine, v, m) for m in ("f1", "entropy")} for k, v in others.items()}
            )
        finals = {k: _final(v) for k, v in others.items()}
        best_f1 = max(finals.items(), key=lambda kv: kv[1]["f1"]) if finals else None
        best_en = min(finals.items(), key=lambda kv: kv[1]["entropy"]) if finals else None
        beats = {m: all(d[m].winner == model_label for d in diffs.values()) for m in ("f1", "entropy")}
        out[env] = {
            "coma": _final(mine),
            "best_f1_baseline": best_f1[0] if best_f1 else None,
            "best_f1": best_f1[1]["f1"] if best_f1 else None,
            "best_entropy_baseline": best_en[0] if best_en else None,
            "best_entropy": best_en[1]["entropy"] if best_en else None,
            "paired": {k: {m: d.as_dict() for m, d in v.items()} for k, v in diffs.items()},
            "beats_f1": beats["f1"],
            "beats_entropy": beats["entropy"],
            "beats_all": beats["f1"] and beats["entropy"],
            "missions": mine.n_trials,
        }
    return out


def _holm_nested(diffs: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Holm over every comparison of one acceptance row (all baselines x both metrics)."""
    keys = [(k, m) for k, per in diffs.items() for m in per]
    adjusted = holm_adjust([diffs[k][m] for k, m in keys])
    out: dict[str, dict[str, Any]] = {k: {} for k in diffs}
    for (k, m), d in zip(keys, adjusted):
        out[k][m] = d
    return out


def _final(result: Any) -> dict[str, float]:
    """Mean and std (over the missions) of F1 and entropy at 100 % of the budget."""
    f1, en = np.asarray(result.f1)[:, -1], np.asarray(result.entropy)[:, -1]
    return {
        "f1": float(f1.mean()),
        "f1_std": float(f1.std()),
        "entropy": float(en.mean()),
        "entropy_std": float(en.std()),
    }


# ---------------------------------------------------------------------------------------------
# step 3: the ablation and the paired check on more paper-split missions
# ---------------------------------------------------------------------------------------------
def ablation_step(run: Run) -> None:
    """The env3 ablation: the four arms at three noise levels on the Table I missions."""
    if not run.arms:
        return

    run.ablation = ab.run_ablation(
        run.arms,
        env=ABLATION_ENV,
        n_trials=run.opts.unseen_missions or run.opts.trials,
        seed=run.opts.seed,
        log=run.say,
        protocol="unseen",
    )
    tables.write_table_csv(run.ablation.rows(), run.out / "ablation.csv", group_title="noise")
    run.sections["ablation"] = run.ablation.markdown()
    (run.out / "ablation.md").write_text(run.sections["ablation"])
    full = ab.LABELS[ABLATION_FULL]
    keys = [
        (noise, label)
        for (label, noise) in run.ablation.results
        if label != full and (full, noise) in run.ablation.results
    ]
    adjusted = holm_adjust(
        [paired_difference(run.ablation.results[(full, n)], run.ablation.results[(lb, n)], "entropy") for n, lb in keys]
    )
    paired = [(noise, d) for (noise, _), d in zip(keys, adjusted)]
    run.sections["ablation_paired"] = report.paired_table(paired, "noise")
    run.arms = {v: m for v, m in run.arms.items() if ab.LABELS[v] not in run.ablation.skipped}  # flown above
    run.summary["ablation"] = {
        **ablation_acceptance(run.ablation),
        "paired": [{"noise": n, **d.as_dict()} for n, d in paired],
    }


def ablation_acceptance(result: Any, noise: str = ABLATION_CHECK_NOISE) -> dict[str, Any]:
    """The paper's ablation criterion by the means: is the full model's entropy at 100 % of the
    budget under ``noise`` at most every other arm's? Returns the entropies by arm label and the
    verdict (``None`` when an arm is missing). The paired differences are reported next to it."""

    full = LABELS[ABLATION_FULL]
    entropy = {label: float(r.mean_std("entropy", 1.0)[0]) for (label, n), r in result.results.items() if n == noise}
    others = {k: v for k, v in entropy.items() if k != full}
    met = (
        None
        if full not in entropy or len(others) < len(LABELS) - 1
        else all(entropy[full] <= v for v in others.values())
    )
    return {"noise": noise, "full": full, "entropy": entropy, "met": met}


def wide_paired_check(run: Run) -> None:
    """COMA vs AG per env and the full model vs every other ablation arm (loud noise), each pair on
    the same ``wide_trials`` paper-split missions."""
    if not run.opts.wide_trials or not (run.sources or run.arms):
        run.summary["paired"] = None
        return
    numbers, table = _paired_check(run.sources, run.arms, run.opts.wide_trials, run.opts.seed, run.opts.noise, run.say)
    (run.out / "paired.md").write_text(table)
    run.sections["paired"] = table
    run.summary["paired"] = numbers


def _evaluate_model(src: ModelSource, env: str, trials: int, seed: int, noise: str, label: str, **extra: Any) -> Any:
    """``evaluate`` a COMA model; sampled actions come from torch's generator, seeded here with ``seed``."""

    th.manual_seed(seed)
    return ev.evaluate(
        src.model,
        env=env,
        n_trials=trials,
        seed=seed,
        fusion=src.fusion,
        label=label,
        deterministic=src.deterministic,
        noise=noise,
        record=0,
        **extra,
    )


def _paired_check(
    sources: dict[str, ModelSource],
    arms: dict[tuple[str, str], Any],
    trials: int,
    seed: int,
    noise: str,
    say: Callable[[str], None],
) -> tuple[dict[str, Any], str]:

    table1 = []
    for env, src in sources.items():
        say(f"paired check: coma vs ag on {env} ({trials} missions) ...")
        coma = _evaluate_model(src, env, trials, seed, noise, "coma", protocol="unseen")
        ag = ev.evaluate("ag", env=env, n_trials=trials, seed=seed, noise=noise, record=0, protocol="unseen")
        table1 += [(env, paired_difference(coma, ag, "f1")), (env, paired_difference(coma, ag, "entropy"))]
    runs = {}
    for variant, model in arms.items():
        label = ab.LABELS[variant]
        say(f"paired check: {label} on {ABLATION_ENV}, noise {ABLATION_CHECK_NOISE} ({trials} missions) ...")
        runs[label] = ev.evaluate(
            model,
            env=ABLATION_ENV,
            n_trials=trials,
            seed=seed,
            fusion=variant[0],
            label=label,
            noise=ABLATION_CHECK_NOISE,
            record=0,
            protocol="unseen",
        )
    table1 = list(zip([env for env, _ in table1], holm_adjust([d for _, d in table1])))
    full = ab.LABELS[ABLATION_FULL]
    diffs = holm_adjust(
        [paired_difference(runs[full], r, "entropy") for label, r in runs.items() if label != full and full in runs]
    )
    met = all(d.diff <= 0 for d in diffs) if len(diffs) == len(ABLATION_ARMS) - 1 else None

    missions = f"{trials} unseen missions (split `test`, random starts, env seeds {seed}..{seed + trials - 1})"
    parts = [
        f"COMA vs AG on the same {missions} per env, noise `{noise}`. Holm family: the "
        f"{len(table1)} comparisons of this table (COMA − AG, per map and metric). The unseen protocol's "
        "tables (`unseen_verdicts.md`, `acceptance.md`) fly the same missions and correct over every pair of "
        "methods of their table: where they say tie and this table says better, the family differs, not the "
        "data (docs/statistics.md).\n",
        paired_markdown([d for _, d in table1], [env for env, _ in table1]),
    ]
    if diffs:
        verdict = "at most" if met else "NOT at most"
        parts += [
            f"\nThe full model against each other ablation arm on the same {missions}, "
            f"`{ABLATION_CHECK_NOISE}` noise: its mean entropy is {verdict} every other arm's "
            f"(verdicts: scene-clustered t test, Holm-corrected within the table; docs/statistics.md).\n",
            paired_markdown(diffs, [ABLATION_CHECK_NOISE] * len(diffs), first_title="noise"),
        ]
    numbers = {
        "trials": trials,
        "seed": seed,
        "noise": noise,
        "table1": [{"env": env, **d.as_dict()} for env, d in table1],
        "ablation": [d.as_dict() for d in diffs],
        "ablation_noise": ABLATION_CHECK_NOISE,
        "ablation_met": met,
    }
    return numbers, "\n".join(parts)


# ---------------------------------------------------------------------------------------------
# step 4: the unseen protocol
# ---------------------------------------------------------------------------------------------
def unseen_protocol(run: Run) -> None:
    """Every method on ``unseen_missions`` missions of split "test" with random starts."""
    if not run.opts.unseen_missions:
        return

    o = run.opts
    run.unseen = run_protocol(
        "unseen", run.methods, n_trials=o.unseen_missions, seed=o.seed, noise=o.noise, log=run.say
    )
    run.unseen.write(run.out, "unseen")
    run.skipped.update({f"unseen protocol: {k}": v for k, v in run.unseen.skipped.items()})
    run.summary["unseen"] = run.unseen.summary()
    unseen_results = [row.result for row in run.unseen.rows()]
    table = {(c.env, c.b): c.diffs for c in run.unseen.comparisons() if c.a == "coma"}
    accept = acceptance(unseen_results, baselines=_competitors(run), verdicts=table)
    (run.out / "acceptance.md").write_text(report.acceptance_markdown(accept))
    run.summary["acceptance"] = accept


# ---------------------------------------------------------------------------------------------
# step 5: generalisation and what training adds
# ---------------------------------------------------------------------------------------------
def generalisation_step(run: Run) -> None:
    """Each env's model on the other paper maps and on a fresh env1 star (baselines there too)."""

    o = run.opts
    gen: list[dict[str, Any]] = []
    if o.generalisation:
        # quick: only the fresh env1 layout (the cross-map runs are the same code path)
        targets: list[tuple[str, dict[str, Any]]] = ([] if o.quick else [(e, {}) for e in o.env_names]) + [
            (f"env1 (map_seed={FRESH_ENV1_SEED})", {"map_seed": FRESH_ENV1_SEED})
        ]
        fresh_label = targets[-1][0]
        for env, src in run.sources.items():
            for target, extra in targets:
                if target == env:
                    continue  # in Table I
                run.say(f"generalisation: {env} model on {target} ...")
                r = _evaluate_model(
                    src, "env1" if extra else target, o.trials, o.seed, o.noise, f"coma[{env}]", **extra
                )
                gen.append({"model": env, "target": target, **_final(r)})
        for name in BASELINES:
            r = ev.evaluate(
                name, env="env1", n_trials=o.trials, seed=o.seed, noise=o.noise, record=0, map_seed=FRESH_ENV1_SEED
            )
            gen.append({"model": name, "target": fresh_label, **_final(r)})
    for r in run.results:  # own-map numbers for reference
        if r.method == "coma":
            gen.append({"model": r.env, "target": r.env, **_final(r)})
    (run.out / "generalisation.md").write_text(report.generalisation_markdown(gen))
    run.summary["generalisation"] = gen
    if o.generalisation and not o.quick and USER_MAP_MODEL in run.sources:
        user_map_step(run, run.sources[USER_MAP_MODEL])


def user_map_step(run: Run, src: ModelSource) -> None:
    """A user's own map: the model on the user-map images (Landsat-8 colour crops no model trained
    on, ``sb3_coma.experiments.user_maps``) against AG and AG-k3, clustered by image."""
    run.say(f"user maps: {USER_MAP_MODEL} model, AG, AG-k3 and the oracle on {len(um.CROPS)} images ...")
    results = um.fly(src.model, um.images(), USER_MAP_MISSIONS, run.opts.noise)
    rows = um.verdicts(results)
    text = um.table_markdown(results, f"COMA {USER_MAP_MODEL}", USER_MAP_MISSIONS, run.opts.noise)
    (run.out / "user_maps.md").write_text(text + "\n")
    run.sections["user_maps"] = text
    run.summary["user_maps"] = {
        "means": {label: _final(res) for label, res in results.items()},
        "verdicts": [d.as_dict() for d in rows],
    }


def untrained_prior(model: Any) -> Any:
    """The policy a gain-prior model starts from: its prior weights at their initial value and the
    network's contribution removed (output layer zeroed; at initialisation it is ~0.01 of the
    prior). ``None`` for a model without a gain prior. Evaluated with argmax actions, this is the
    greedy planner on the untrained mix of the two information gains, so comparing it with the
    trained model shows what COMA's training adds."""

    actor = model.policy.actor
    if getattr(actor, "prior_theta", None) is None:
        return None
    policy = copy.deepcopy(model.policy)
    with th.no_grad():
        policy.actor.head.weight.zero_()
        policy.actor.head.bias.zero_()
        policy.actor.prior_theta.copy_(th.tensor(policy.gain_prior_init) / policy.gain_prior_speed)
    return policy


def untrained_prior_step(run: Run) -> None:
    """The untrained gain prior of each model vs the trained model on the Table I missions."""

    o = run.opts
    rows: list[dict[str, Any]] = []
    for env, src in run.sources.items():
        policy = untrained_prior(src.model)
        if policy is None:
            continue
        run.say(f"evaluating the untrained gain prior of the {env} model ...")
        r = ev.evaluate(
            policy,
            env=env,
            n_trials=o.trials,
            seed=o.seed,
            fusion=src.fusion,
            deterministic=True,
            noise=o.noise,
            label="prior",
            record=0,
        )
        rows.append(
            {
                "env": env,
                "prior": _final(r),
                "trained": _final(run.paper.result(env, "coma")),
                "weights_start": [float(w) for w in policy.gain_prior_init],
                "weights_trained": [round(float(w), 3) for w in src.model.policy.actor.prior_weights.detach()],
            }
        )
    run.summary["untrained_prior"] = rows


# ---------------------------------------------------------------------------------------------
# step 6: the noise sweep
# ---------------------------------------------------------------------------------------------
def sweep_arms(run: Run) -> tuple[str, list[Any]]:
    """(map, arms) of the noise sweep: AG and every trained ablation arm on env3 when it is
    evaluated, else AG and the first map's model."""

    env = ABLATION_ENV if ABLATION_ENV in run.sources else run.opts.env_names[0]
    arms = [Method("ag", "ag")]
    if env == ABLATION_ENV and run.arms:
        arms += [Method(ab.LABELS[v], m, kind="coma", fusion=v[0], deterministic=True) for v, m in run.arms.items()]
    elif env in run.sources:
        src = run.sources[env]
        arms.append(Method("coma", src.model, kind="coma", fusion=src.fusion, deterministic=src.deterministic))
    return env, arms


def noise_sweep_step(run: Run) -> None:
    """``sb3_coma.experiments.noise_sweep`` on the sweep arms, shared unseen missions; table, CSV, figure."""
    if not run.opts.sweep_missions:
        return

    env, arms = sweep_arms(run)
    run.sweep = run_noise_sweep(
        arms, env=env, n_missions=run.opts.sweep_missions, seed=run.opts.seed, quick=run.opts.quick, log=run.say
    )
    run.sweep.write_csv(run.out / "noise_sweep.csv")
    run.skipped.update({f"noise sweep: {k}": v for k, v in run.sweep.skipped.items()})
    run.sections["noise_sweep"] = run.sweep.markdown()
    (run.out / "noise_sweep.md").write_text(run.sections["noise_sweep"])
    run.summary["noise_sweep"] = run.sweep.summary()


# ---------------------------------------------------------------------------------------------
# step 7: the deployment cost table
# ---------------------------------------------------------------------------------------------
def cost_models(run: Run) -> dict[str, tuple[Any, str, str]]:
    """One model per architecture in use (fusion x extractor), each timed on its own map: the maps'
    models, then the ablation arms of other architectures."""

    out: dict[str, tuple[Any, str, str]] = {}
    seen = set()
    candidates = [(f"COMA {src.env}", src.model, src.fusion, src.env) for src in run.sources.values()] + [
        (f"COMA {ab.LABELS[v]}", m, v[0], ABLATION_ENV) for v, m in run.arms.items()
    ]
    for label, model, fusion, env in candidates:
        arch = (fusion, type(model.policy.actor.features_extractor).__name__)
        if arch not in seen:
            seen.add(arch)
            out[f"{label} ({fusion} + {'CBAM' if 'CBAM' in arch[1] else 'CNN'})"] = (model, fusion, env)
    return out


def cost_table(run: Run) -> None:
    """Decision time per UAV (batch of one, one thread): actor + fusion in PyTorch and ONNX Runtime,
    AG with look-ahead 1, 2, 3 (``sb3_coma.experiments.costs``)."""
    if not run.opts.costs:
        run.summary["latency"] = []
        return

    o = run.opts
    models = cost_models(run)
    if o.quick:
        models = dict(list(models.items())[:1])
    rows = decision_costs(
        models, envs=list(o.cost_envs or o.env_names), repeats=QUICK_REPEATS if o.quick else COST_REPEATS, log=run.say
    )
    run.sections["latency"] = costs_markdown(rows)
    (run.out / "latency.md").write_text(run.sections["latency"])
    run.summary["latency"] = [r.as_dict() for r in rows]


def _time_fusion(fusion: str, n_agents: int, reps: int = 200) -> float | None:
    """ms per UAV decision of fusing the N received maps of one UAV (batch of one, PyTorch, with
    the projection to the lattice); ``None`` when the fusion cannot be built here."""

    try:
        fn = _torch_fusion(fusion, n_agents, 44, 11)
    except Exception:  # weights missing or unreadable: report n/a, not a crash
        return None
    with one_thread():
        return time_call(fn, reps, warmup=1)[0]


# ---------------------------------------------------------------------------------------------
# step 8: ship / record, then the report
# ---------------------------------------------------------------------------------------------
def ship_or_record(run: Run) -> None:
    """With ``ship``: the retrained zips into sb3_coma/pretrained; with ``record``: the measured
    Table I numbers of the shipped models into models.json."""
    if run.opts.ship:
        _ship(run.sources, run.results, run.say)
    elif run.opts.record and not run.opts.train:
        record_metrics(run.results, run.say)


def _metrics_entry(res: Any) -> dict[str, Any]:
    return {
        "metrics": {k: round(v, 4) for k, v in res.summary().items()},
        "metrics_note": f"measured by sb3-coma reproduce: {res.n_trials} trials, env seeds "
        f"{res.seed}..{res.seed + res.n_trials - 1}, noise {res.env_options.get('noise')}, "
        f"fusion {res.fusion}",
    }


def _manifest_name(env: str, method: str) -> str | None:
    """The shipped model a result row flew: ``coma`` -> ``env``, ``coma[paper-actor]`` ->
    ``env-paper-actor`` (``protocols.shipped_label`` the other way); ``None`` for a baseline."""
    if method == "coma":
        return env
    if method.startswith("coma[") and method.endswith("]"):
        return f"{env}-{method[5:-1]}"
    return None


def record_metrics(results: Sequence[Any], say: Callable[[str], None] = print) -> None:
    """Store the measured metrics of the shipped models in ``models.json``."""

    manifest = pt.read_manifest()
    for res in results:
        name = _manifest_name(res.env, res.method)
        if name in manifest["models"]:
            manifest["models"][name].update(_metrics_entry(res))
    say(f"recorded metrics in {pt.write_manifest(manifest)}")


def _ship(sources: dict[str, ModelSource], results: Sequence[Any], say: Callable[[str], None]) -> None:

    directory = pt.pretrained_dir()
    directory.mkdir(parents=True, exist_ok=True)
    try:
        manifest = pt.read_manifest()
    except pt.PretrainedError:
        manifest = {"format": 1, "models": {}}
    for env, src in sources.items():
        res = next(r for r in results if r.env == env and r.method == "coma")
        manifest["models"][env] = {
            **pt.save_for_shipping(src.model, f"coma_{env}.zip", directory),
            "env": env,
            "fusion": src.fusion,
            "variant": _variant_for(env, src.fusion),
            "seed": shipped_seed(env),
            "deterministic": src.deterministic,
            "timesteps": src.timesteps,
            "command": src.command,
            "train_wall_s": round(float(src.train_wall_s or 0), 1),
            **_metrics_entry(res),
            "training_curve": src.training_curve,
        }
        manifest["models"][env]["world"] = WORLD_VERSION
        say(f"shipped {directory / manifest['models'][env]['file']}")
    pt.write_manifest(manifest)


def figures_step(run: Run) -> None:
    """Metric curves per protocol, training reward, ablation, noise sweep."""
    if not run.opts.plots:
        return

    fig_dir = run.out / "figures"
    o = run.opts
    grids = [("paper", run.paper, "table1_curves.png", f"{o.trials} trials")]
    if run.unseen is not None:
        grids.append(("unseen", run.unseen, "unseen_curves.png", f"{run.unseen.n_trials} missions"))
    for name, protocol, file, count in grids:
        results = {
            env: [protocol.result(env, m.label) for m in ms if (env, m.label) in protocol.results]
            for env, ms in run.methods.items()
        }
        title = f"{name} protocol: F1 and entropy vs step, noise {o.noise}, {count}"
        titles = report.model_titles(run)  # "COMA (oracle warm start)" where the map's models were warm-started
        labels = {env: [titles.get(r.method, r.method) for r in rs] for env, rs in results.items()}
        run.figures.append(pl.plot_metric_grid(results, fig_dir / file, title=title, labels=labels))
    curves = {
        env: pl.TrainingCurve(np.arange(1, len(s.training_curve) + 1), np.asarray(s.training_curve), s.source)
        for env, s in run.sources.items()
        if s.training_curve
    }
    if curves:
        run.figures.append(pl.plot_training_reward(curves, fig_dir / "training_reward.png"))
    if run.ablation is not None and run.ablation.results:
        run.figures.append(
            pl.plot_metric_grid(
                run.ablation.by_noise(),
                fig_dir / "ablation_curves.png",
                title=f"{ABLATION_ENV}: F1 and entropy vs step per noise level",
            )
        )
        run.figures.append(
            pl.plot_ablation(
                dict(run.ablation.results),
                fig_dir / "ablation_bars.png",
                title=f"{ABLATION_ENV}: ablation at 100 % of the budget",
            )
        )
    if run.sweep is not None and run.sweep.results:
        run.figures.append(pl.plot_noise_sweep(run.sweep, fig_dir / "noise_sweep.png"))


def seed_spread_rows() -> list[dict[str, Any]]:
    """Per shipped model: its seeds and their unseen results as ``ship_models`` recorded them."""
    rows = []
    for name, entry in pt.read_manifest()["models"].items():
        spread = entry.get("seeds_unseen") or {}
        rows.append(
            {
                "model": name,
                "shipped": f"seed {entry['seed']}",
                "candidates": sorted(entry["selection"]["candidates"], key=lambda c: int(c.split()[-1])),
                "missions": spread.get("missions"),
                "metrics": spread.get("metrics", {}),
            }
        )
    return rows


def write_results(run: Run) -> None:
    """summary.json, RESULTS.md (and the docs copy with its figures)."""
    o = run.opts
    run.summary.update(
        command=" ".join(
            ["sb3-coma reproduce"]
            + (["--train"] if o.train else [])
            + (["--quick"] if o.quick else [])
            + (["--record"] if o.record and not o.train else [])
        ),
        command_line=command_line(o),
        date=time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        python=sys.version.split()[0],
        machine=f"{platform.machine()} {platform.processor() or ''}".strip(),
        trials=o.trials,
        seed=o.seed,
        noise=o.noise,
        envs=list(o.env_names),
        ag_weighting=_ag_weightings(o.env_names),
        seed_spread=[] if o.train else seed_spread_rows(),
        models={
            env: {
                "source": s.source,
                "fusion": s.fusion,
                "command": s.command,
                "train_wall_s": s.train_wall_s,
                "timesteps": s.timesteps,
                "deterministic": s.deterministic,
                "note": next((m.note for m in run.methods.get(env, []) if m.label == "coma"), ""),
            }
            for env, s in run.sources.items()
        },
        skipped=dict(run.skipped),
        step_seconds=dict(run.timings),
        wall_s=round(time.perf_counter() - run.started, 1),
    )
    (run.out / "summary.json").write_text(json.dumps(run.summary, indent=2, default=_jsonable) + "\n")
    (run.out / "RESULTS.md").write_text(report.results_markdown(run, run.figures, run.out))
    if o.docs is not None:
        docs = Path(o.docs)
        fig_docs = docs.parent / "figures"
        fig_docs.mkdir(parents=True, exist_ok=True)
        for f in run.figures:
            shutil.copyfile(f, fig_docs / f.name)
        docs.write_text(report.results_markdown(run, [fig_docs / f.name for f in run.figures], docs.parent))
        run.say(f"wrote {docs}")
        readme = docs.parent.parent / "README.md"
        if write_readme_block(readme, report.readme_paragraph(run)):
            run.say(f"wrote the results block of {readme}")
    if "acceptance" in run.summary:
        run.say(report.acceptance_markdown(run.summary["acceptance"]))
    if run.summary.get("ablation"):
        run.say(report.ablation_verdict(run.summary["ablation"]))
    run.say(
        f"wrote {run.target or run.out}/ (table.md, team_table.md, paper_verdicts.md, acceptance.md, unseen_*.md, "
        f"noise_sweep.md, generalisation.md, latency.md, summary.json, RESULTS.md) in {run.summary['wall_s']} s"
    )


#: README's results block lies between these markers; ``reproduce`` writes it, nobody pastes it.
README_MARKERS = ("<!-- results:start (written by sb3-coma reproduce) -->", "<!-- results:end -->")


def write_readme_block(readme: Path, text: str) -> bool:
    """Replace what lies between :data:`README_MARKERS` in ``readme`` by ``text`` (atomically);
    ``False`` when the file or its markers are missing (nothing is written then)."""
    if not readme.is_file():
        return False
    content = readme.read_text(encoding="utf-8")
    start, end = README_MARKERS
    if start not in content or end not in content.split(start, 1)[1]:
        return False
    head, rest = content.split(start, 1)
    tail = rest.split(end, 1)[1]
    staging = readme.with_name(readme.name + ".tmp")
    staging.write_text(f"{head}{start}\n{text.strip()}\n{end}{tail}", encoding="utf-8")
    staging.replace(readme)
    return True


def _jsonable(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return float(value)


def _ag_weightings(env_names: Sequence[str]) -> dict[str, str]:

    return {env: default_weighting(env) for env in env_names}


def command_line(o: ReproduceOptions) -> str:
    """The ``sb3-coma reproduce`` command line that gives these options."""
    parts = (
        ["sb3-coma reproduce"]
        + (["--train"] if o.train else [])
        + (["--quick"] if o.quick else [])
        + (["--record"] if o.record and not o.train else [])
    )
    defaults = ReproduceOptions()
    for name, flag in (
        ("unseen_missions", "--unseen-missions"),
        ("sweep_missions", "--sweep-missions"),
        ("wide_trials", "--wide-trials"),
    ):
        if not o.quick and getattr(o, name) != getattr(defaults, name):
            parts.append(f"{flag} {getattr(o, name)}")
    if list(o.env_names) != list(DEFAULT_ENVS):
        parts.append(f"--env {','.join(o.env_names)}")
    if o.trials != defaults.trials and not o.quick:
        parts.append(f"--trials {o.trials}")
    return " ".join(parts)


#: The named steps of :func:`reproduce`, in order.
STEPS: tuple[Callable[[Run], None], ...] = (
    load_models,
    paper_protocol,
    ablation_step,
    wide_paired_check,
    unseen_protocol,
    generalisation_step,
    untrained_prior_step,
    noise_sweep_step,
    cost_table,
    ship_or_record,
    figures_step,
    write_results,
)
