"""What ``reproduce`` can be told, its fixed numbers, and the guard of its optional parts.

The constants are the protocol's choices (missions, seeds, the shipped models' recipe), named
once so that the steps, the report and ``ship_models`` use the same numbers.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from sb3_coma.common.numbers import is_whole
from sb3_coma.experiments import report

T = TypeVar("T")

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


@dataclass
class ReproduceOptions:
    """Everything ``reproduce`` can be told (keyword arguments of ``reproduce``).

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
        """Validated, with ``quick`` applied: the steps then trust every field.

        One table of (field, rule, what is allowed) and one raise; ``wide_trials`` is checked
        again once ``quick`` has capped it (a quick run of one trial has one wide trial)."""
        self.env_names = list(self.env_names)

        def count(name: str, least: int) -> bool:
            value = getattr(self, name)
            return is_whole(value) and value >= least

        rules: list[tuple[str, bool, str]] = [
            ("env_names", bool(self.env_names), "a non-empty list of maps"),
            ("trials", count("trials", 1), "an integer >= 1"),
            *((name, count(name, 0), "an integer >= 0") for name in ("unseen_missions", "sweep_missions", "seed")),
            ("wide_trials", count("wide_trials", 0) and self.wide_trials != 1, "0 (skip) or an integer >= 2"),
            ("timesteps", self.timesteps is None or count("timesteps", 1), "None or an integer >= 1"),
            ("ship", not self.ship or (self.train and not self.quick), "used with train=True and quick=False"),
            ("baselines_only", not self.baselines_only or not (self.train or self.record), "without train or record"),
        ]
        if self.quick and all(ok for _, ok, _ in rules):
            self.trials = min(self.trials, QUICK_TRIALS)
            self.wide_trials = min(self.wide_trials, self.trials)
            self.unseen_missions = min(self.unseen_missions, QUICK_TRIALS)
            self.sweep_missions = min(self.sweep_missions, QUICK_TRIALS)
            rules.append(
                ("wide_trials", self.wide_trials != 1, "0 (skip) or an integer >= 2 (with quick: trials >= 2)")
            )
        for name, ok, allowed in rules:
            if not ok:
                raise ValueError(f"{name} must be {allowed}, got {getattr(self, name)!r}")
        return self


@dataclass(frozen=True)
class Folders:
    """Where a run writes (``staging``) and where that folder goes once the run is complete
    (``target``; ``None``: ``staging`` itself), so that what the summary and the log name is the
    final place, not the staging one."""

    staging: Path
    target: Path | None = None

    def final(self, path: Path) -> Path:
        """Where ``path``, written under the staging folder, lies once the run is in place."""
        if self.target is None:
            return path
        try:
            return self.target / Path(path).relative_to(self.staging)
        except ValueError:
            return path


def attempt(
    skipped: dict[str, str], say: Callable[[str], None], what: str, fn: Callable[..., T], *args: Any, **kwargs: Any
) -> T | None:
    """``fn(*args, **kwargs)``, or ``None`` with the reason in ``skipped[what]`` (the calling step's
    own record of what it left out) and the log when it fails for a reason this install can have
    (a missing optional part, a model that cannot be loaded): the one place optional parts of the
    run are guarded."""
    try:
        return fn(*args, **kwargs)
    except OPTIONAL_ERRORS as exc:
        reason = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        skipped[what] = reason
        say(f"skipping {what}: {reason}")
        return None
