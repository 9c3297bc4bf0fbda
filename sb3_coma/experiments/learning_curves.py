"""Learning curves: validation F1 / entropy against missions trained, mean ± std over seeds, with
the levels of AG, AG look-ahead 3, the oracle (upper reference) and random on the same validation
missions; one row per map family or ablation arm.

    python -m sb3_coma.experiments.learning_curves --out docs/figures/learning_curves.png \\
        --table docs/figures/learning_curves.md \\
        env1=runs/env1_s0,runs/env1_s1,runs/env1_s2 \\
        env2=runs/env2_s0,runs/env2_s1,runs/env2_s2 \\
        env3=runs/env3_s0,runs/env3_s1,runs/env3_s2 \\
        "env3[mean-cnn]=runs/env3_meancnn_s0,runs/env3_meancnn_s1,runs/env3_meancnn_s2"

Every ``GROUP=RUN_DIR[,RUN_DIR...]`` is one row of the figure and of the table; its run folders
are the seeds of one setting, each written by ``sb3-coma train ... --seed S --eval-freq 3000
--eval-missions 10`` (docs/training.md, "Picking the model" and "The run folder").

Why: the final test numbers (Table I, ``sb3-coma reproduce``) say where a model ended, not whether
training had converged, how much seeds disagree, or when COMA passed AG or random. These curves
answer that on the validation missions only (env seeds 1000+, never the test missions).

Where the numbers come from, per run folder:

* ``config.yml``: env id, ``env_kwargs`` (map, team size, budget, noise, split, ...) and the seed;
* ``eval/evaluations.npz``: the evaluation steps (joint steps) and SB3's per-row returns; its
  width is ``missions x UAVs`` (SB3 counts one episode per vec-env row), which gives the number
  of validation missions M;
* the TensorBoard scalars ``eval/mean_f1`` and ``eval/mean_entropy`` under ``tb/``, which
  ``MissionEvalCallback`` logs once per evaluation at the evaluation's joint step: the mean over
  the M missions of the final global F1 / entropy.

x = joint steps / budget (missions trained per env copy count: one mission is ``budget`` joint
steps). A group's curve is the mean ± std (population, ``ddof=0``) over its runs at their shared
evaluation steps (the common prefix when one run stopped earlier).

The baselines' levels (dashed lines) are flown on exactly the validation missions, through the
mechanism the callback uses, not with ``sb3_coma.evaluate``: training builds its eval env as
``make_training_env(cfg, n_envs=eval_copies(M), seed=eval_seed)`` (C = 5, 4, 3, 2 or 1 env copies,
the largest that divides M) and every evaluation calls ``eval_env.seed(eval_seed)`` and then SB3's
``evaluate_policy`` for ``M x UAVs`` episodes: copy ``c`` resets with env seed ``eval_seed + c`` and
flies M / C missions in a row, the later ones drawn by auto-reset from the copy's own stream.
``evaluate(seed=S, n_trials=M)`` instead flies one mission per env seed S..S+M-1, which are other
missions whenever M > 5 (M = 10: 5 copies x 2 missions). So the levels here are the same
``evaluate_policy`` call on the same vec env and seed, with the planner's ``predict`` in place of
the model's, read the way the callback reads its infos (the final F1 / entropy of each mission, on
the first UAV's row), averaged over the M missions. A copy's missions do not depend on the
actions flown (its random stream is drawn at reset and once per step, never by what the UAVs do),
so every method meets the same maps, starts and noise. As ``evaluate`` flies baselines, the
baselines' env fuses with ``mean`` (they never read the fused channel, and the global map and the
env's streams do not depend on the fusion) and the config's ``vec_env_wrapper`` is left out (it
changes what a learner sees, not the missions); AG takes its map family's weighting
(``sb3_coma.common.evaluation.planner_options``) and both planners are seeded with the eval seed.

The eval seed is the one the run's command recorded (``--eval-seed``), else
``sb3_coma.app.training.VALIDATION_SEED`` (1000); ``--eval-seed`` here overrides it for runs made
from Python with another seed.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from stable_baselines3.common.vec_env import VecEnv
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sb3_coma.app.config import TrainConfig, TrainingError, plain
from sb3_coma.app.evaluation import planner_options
from sb3_coma.app.runs import CONFIG_FILE, TENSORBOARD_DIR, read_run_config
from sb3_coma.app.training import VALIDATION_SEED
from sb3_coma.app.validation_flights import MissionScores, Validation, fly_validation
from sb3_coma.baselines import make_planner
from sb3_coma.common.evaluation import PROTOCOLS
from sb3_coma.experiments.figure_style import method_styles
from uav_ipp.config import seed_value

#: The TensorBoard scalars ``MissionEvalCallback`` logs at each evaluation.
TAGS: dict[str, str] = {"f1": "eval/mean_f1", "entropy": "eval/mean_entropy"}
#: The baselines whose levels are drawn: label -> (planner, its options); their looks come from
#: ``figure_style.method_styles``, as in every figure. The oracle knows the ground truth: the
#: headroom left, an upper reference, never a competitor.
BASELINES: dict[str, tuple[str, dict[str, Any]]] = {
    "ag": ("ag", {}),
    "ag-k3": ("ag", {"lookahead": 3}),
    "oracle": ("oracle", {}),
    "random": ("random", {}),
}
EVALUATIONS = Path("eval") / "evaluations.npz"


class RunDirError(ValueError):
    """A run folder that cannot be read as a run with validation missions (the message names it)."""


# ------------------------------------------------------------------------------------ run folders
@dataclass
class RunCurve:
    """Validation F1 / entropy of one run at each evaluation."""

    path: Path
    seed: int | None
    budget: int
    validation: Validation
    steps: np.ndarray
    f1: np.ndarray
    entropy: np.ndarray
    #: missions the teacher labelled before COMA (a DAgger warm start: rounds x missions), 0 without
    teacher_missions: int = 0


def _teacher_missions(run: Path) -> int:
    """Teacher-labelled missions of a warm-started run (its ``warm_start.json``), else 0."""
    record = run / "warm_start.json"
    if not record.is_file():
        return 0
    spec = json.loads(record.read_text())
    return int(spec.get("rounds", 0) or 0) * int(spec.get("missions", 0) or 0)


def _run_config(run: Path) -> TrainConfig:
    """The run's recorded config, or a :class:`RunDirError` naming the folder and what is wrong.

    One rule, one raise: the folder holds what a curve reads (``config.yml``, a valid one,
    ``eval/evaluations.npz`` and TensorBoard events under ``tb/``); the first thing missing is named
    with how to get it."""
    needs = (
        (run.is_dir(), "not a folder"),
        ((run / CONFIG_FILE).is_file(), f"no {CONFIG_FILE} (not an sb3-coma train run folder)"),
        ((run / EVALUATIONS).is_file(), f"no {EVALUATIONS} (train it with --eval-freq N --eval-missions M)"),
        (
            any((run / TENSORBOARD_DIR).glob("**/events.out.tfevents.*")),
            f"no TensorBoard event file under {TENSORBOARD_DIR}/",
        ),
    )
    problem = next((message for ok, message in needs if not ok), None)
    if problem is None:
        try:
            return read_run_config(run)
        except TrainingError as exc:
            problem = str(exc)
    raise RunDirError(f"run folder {run}: {problem}")


def _flag(command: str, name: str) -> str | None:
    """The value of ``--name V`` / ``--name=V`` in a recorded command line (the last one wins)."""
    words = shlex.split(command) if command else []
    value = None
    for k, word in enumerate(words):
        if word == name and k + 1 < len(words):
            value = words[k + 1]
        elif word.startswith(name + "="):
            value = word.split("=", 1)[1]
    return value


def _eval_seed(cfg: TrainConfig, override: int | None) -> int:
    """The validation env seed: ``override``, else the run's recorded ``--eval-seed``, else the default."""
    if override is not None:
        return int(override)
    recorded = _flag(str(cfg.run.get("command") or ""), "--eval-seed")
    return int(recorded) if recorded is not None else VALIDATION_SEED


def _evaluations(run: Path, n_agents: int) -> tuple[np.ndarray, int]:
    """(evaluation steps, validation missions M) from ``eval/evaluations.npz``."""
    path = run / EVALUATIONS  # there: _run_config checked it
    with np.load(path) as data:
        steps, results = np.asarray(data["timesteps"], dtype=np.int64), np.asarray(data["results"])
    if steps.size == 0 or results.ndim != 2 or results.shape[1] % n_agents:
        raise RunDirError(
            f"run folder {run}: {EVALUATIONS} holds no evaluation of whole missions "
            f"(results {results.shape}, {n_agents} UAVs per mission)"
        )
    return steps, results.shape[1] // n_agents


def _tensorboard_scalars(run: Path, tags: Sequence[str], steps: np.ndarray) -> dict[str, np.ndarray]:
    """``{tag: values at every evaluation step}`` over every event file under ``run/tb`` (a
    resumed run appends files; the last value written at a step wins).
    ``sb3_coma.experiments.plots._read_tensorboard`` numbers the points 1..n instead of keeping their
    steps, which these curves need, so this reads the same ``EventAccumulator`` keeping them.

    One rule, one raise: every tag has a value at every evaluation step (a step without one is an
    error, not a gap); a tag missing altogether is named with the scalars the log does hold."""
    folders = sorted({p.parent for p in (run / TENSORBOARD_DIR).glob("**/events.out.tfevents.*")})
    found: dict[str, dict[int, float]] = {tag: {} for tag in tags}
    seen: set[str] = set()
    for folder in folders:
        acc = EventAccumulator(str(folder), size_guidance={"scalars": 0})
        acc.Reload()
        present = set(acc.Tags().get("scalars", []))
        seen |= present
        for tag in tags:
            if tag in present:
                found[tag].update({int(e.step): float(e.value) for e in acc.Scalars(tag)})
    missing = [tag for tag in tags if not found[tag]]
    lost = {tag: [int(s) for s in steps if int(s) not in found[tag]] for tag in tags if found[tag]}
    lost = {tag: at for tag, at in lost.items() if at}
    if missing or lost:
        problem = (
            f"no {', '.join(missing)} in its TensorBoard log (scalars: {sorted(seen) or 'none'})"
            if missing
            else "; ".join(f"{tag} is missing at evaluation steps {at} of {EVALUATIONS}" for tag, at in lost.items())
        )
        raise RunDirError(f"run folder {run}: {problem}")
    return {tag: np.array([found[tag][int(s)] for s in steps], dtype=np.float64) for tag in tags}


def read_run(run: str | Path, eval_seed: int | None = None) -> RunCurve:
    """The validation curve and validation missions of one ``sb3-coma train`` run folder."""
    run = Path(run)
    cfg = _run_config(run)
    n_agents = int(cfg.n_agents)
    steps, missions = _evaluations(run, n_agents)
    scalars = _tensorboard_scalars(run, list(TAGS.values()), steps)
    env_kwargs = {k: v for k, v in cfg.env_kwargs.items() if k not in ("fusion", "fusion_kwargs")}
    if cfg.run.get("validation_protocol") == "validation" and env_kwargs.get("split", "paper") == "train":
        env_kwargs.update(PROTOCOLS["validation"].env_options())  # as make_validation_env built it
    validation = Validation(
        env_id=cfg.env_id,
        options_json=json.dumps(plain(env_kwargs), sort_keys=True),
        missions=missions,
        seed=_eval_seed(cfg, eval_seed),
        n_agents=n_agents,
    )
    seed = cfg.run.get("seed")
    return RunCurve(
        path=run,
        seed=int(seed) if isinstance(seed, int) else None,
        budget=int(cfg.world.config.budget),
        validation=validation,
        steps=steps,
        f1=scalars[TAGS["f1"]],
        entropy=scalars[TAGS["entropy"]],
        teacher_missions=_teacher_missions(run),
    )


# ------------------------------------------------------------------------------------ validation missions
def baseline_scores(validation: Validation, name: str) -> MissionScores:
    """Baseline ``name`` (built as ``evaluate`` builds it) flown on the validation missions."""

    kind, options = BASELINES[name]

    def planner(venv: VecEnv) -> Any:
        config = venv.get_attr("config", indices=[0])[0]
        return make_planner(kind, venv, seed=validation.seed, **planner_options(kind, config, options))

    scores = fly_validation(validation, planner)
    # evaluate_policy counts missions exactly: another count is our bug, not the user's
    assert len(scores.f1) == validation.missions, f"{name}: flew {len(scores.f1)} of {validation.missions} missions"
    return scores


def baseline_level(validation: Validation, name: str) -> tuple[float, float]:
    """(mean final F1, mean final entropy) of baseline ``name`` on the validation missions."""
    scores = baseline_scores(validation, name)
    return float(scores.f1.mean()), float(scores.entropy.mean())


# ------------------------------------------------------------------------------------ groups
@dataclass
class GroupCurve:
    """Mean ± std over the runs (seeds) of one group, and the baselines' levels."""

    name: str
    runs: list[RunCurve]
    steps: np.ndarray
    #: missions seen at each evaluation: the teacher-labelled ones first, then COMA's
    missions: np.ndarray
    f1: np.ndarray  # (runs, evaluations)
    entropy: np.ndarray
    levels: dict[str, tuple[float, float]]
    teacher_missions: int = 0

    @property
    def validation(self) -> Validation:
        return self.runs[0].validation

    def mean_std(self, metric: str) -> tuple[np.ndarray, np.ndarray]:
        """Mean and population std (``ddof=0``) over the seeds at every shared evaluation."""
        values = getattr(self, metric)
        return values.mean(axis=0), values.std(axis=0)


def _check_same(name: str, runs: Sequence[RunCurve], what: str, key: Callable[[RunCurve], Any]) -> None:
    """Refuse a group whose runs differ in ``key``: averaging over seeds needs one setting."""
    if len({key(r) for r in runs}) > 1:
        listed = "; ".join(f"{r.path}: {key(r)}" for r in runs)
        raise RunDirError(f"group {name}: its runs differ in {what} ({listed}); a group is seeds of one setting")


def build_group(
    name: str, runs: Sequence[RunCurve], levels: Callable[[Validation], dict[str, tuple[float, float]]]
) -> GroupCurve:
    """A group's curves on the evaluation steps all its runs share (the common prefix)."""
    assert runs, f"group {name}: no run folder"  # parse_groups gives every group at least one
    _check_same(name, runs, "validation missions", lambda r: r.validation)
    _check_same(name, runs, "budget", lambda r: r.budget)
    _check_same(name, runs, "teacher-labelled missions", lambda r: r.teacher_missions)
    n = min(len(r.steps) for r in runs)
    _check_same(name, runs, f"evaluation steps (first {n})", lambda r: tuple(int(s) for s in r.steps[:n]))
    steps = runs[0].steps[:n]
    return GroupCurve(
        name=name,
        runs=list(runs),
        steps=steps,
        missions=runs[0].teacher_missions + steps / runs[0].budget,
        f1=np.stack([r.f1[:n] for r in runs]),
        entropy=np.stack([r.entropy[:n] for r in runs]),
        levels=levels(runs[0].validation),
        teacher_missions=runs[0].teacher_missions,
    )


def baseline_levels_cache() -> Callable[[Validation], dict[str, tuple[float, float]]]:
    """The baselines' levels per set of validation missions, flown once for all groups sharing it
    (the ablation arms of one map: the fusion is not part of the missions)."""
    cache: dict[Validation, dict[str, tuple[float, float]]] = {}

    def levels(validation: Validation) -> dict[str, tuple[float, float]]:
        if validation not in cache:
            cache[validation] = {name: baseline_level(validation, name) for name in BASELINES}
        return cache[validation]

    return levels


# ------------------------------------------------------------------------------------ output
def draw_groups(groups: Sequence[GroupCurve]) -> Figure:
    """The figure of :func:`plot_groups`: one row per group, validation F1 (left) and entropy
    (right) against missions trained; COMA's mean with a band of ±1 s.d. over seeds, each
    baseline's level a flat line in its own colour, line style and marker, and the row's legend
    (with the levels' values) right of its axes."""
    # A bare Figure (no pyplot): no backend to choose, nothing global to close, PNG through Agg.
    fig = Figure(figsize=(12.5, 3.0 * len(groups)), layout="constrained")
    axes = fig.subplots(len(groups), 2, squeeze=False)
    styles = method_styles(["coma", *BASELINES])
    for row, group in zip(axes, groups):
        seeds = f"{len(group.runs)} seed{'s' if len(group.runs) > 1 else ''}"
        n = len(group.missions)
        for ax, metric, title in zip(row, ("f1", "entropy"), ("validation F1 ↑", "validation entropy ↓")):
            mean, std = group.mean_std(metric)
            coma = styles["coma"]
            ax.plot(group.missions, mean, ms=4, label=f"COMA, mean of {seeds}", **coma.line())
            ax.fill_between(
                group.missions, mean - std, mean + std, color=coma.color, alpha=0.2, lw=0, label="±1 s.d. over seeds"
            )
            for k, name in enumerate(BASELINES):
                f1, entropy = group.levels[name]
                ax.plot(
                    group.missions,
                    np.full(n, f1 if metric == "f1" else entropy),
                    lw=1.2,
                    ms=5,
                    markevery=(k % max(n, 1), max(n // 3, 1)),  # markers staggered, not stacked
                    label=f"{name} (F1 {f1:.3f}, entropy {entropy:.3f})",
                    zorder=1 + k,
                    **styles[name].line(),
                )
            if group.teacher_missions:  # the clone's phase: the teacher labelled these, COMA did not learn
                ax.axvspan(
                    0, group.teacher_missions, color="0.85", lw=0, zorder=0, label="DAgger: teacher-labelled missions"
                )
            ax.set_xlim(left=0)
            ax.set_title(f"{group.name}: {title} ({group.validation.missions} missions)", fontsize=10)
            ax.set_xlabel("missions trained (teacher-labelled, then COMA's joint steps / budget)")
            ax.set_ylabel("F1-score (0-1)" if metric == "f1" else "entropy (bits per valuable cell)")
            ax.grid(alpha=0.3)
        row[1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0)
    fig.suptitle(
        "COMA: mean and ±1 s.d. (population) over seeds; flat lines: AG, AG look-ahead 3, the oracle "
        "(upper reference) and random on the same validation missions",
        fontsize=9,
    )
    return fig


def plot_groups(groups: Sequence[GroupCurve], path: str | Path) -> Path:
    """Write :func:`draw_groups`' figure as a PNG."""
    path = Path(path)
    fig = draw_groups(groups)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path


def _seeds(group: GroupCurve) -> str:
    """``"N (s0, s1, ...)"``: how many seeds and which (``?`` where a run recorded none)."""
    seeds = ", ".join("?" if r.seed is None else str(r.seed) for r in group.runs)
    return f"{len(group.runs)} ({seeds})"


def table_markdown(groups: Sequence[GroupCurve], digits: int = 3) -> str:
    """One line per group: final and best validation F1 / entropy, the baselines' levels."""
    head = (
        "| group | seeds | missions at last eval | final F1 ↑ | final entropy ↓ | best mean F1 (missions) "
        "| best mean entropy (missions) | " + " | ".join(f"{name} F1 / entropy" for name in BASELINES) + " |"
    )
    lines = [head, "| --- | --- | ---: | ---: | ---: | ---: | ---: |" + " ---: |" * len(BASELINES)]
    for g in groups:
        (f1, f1_sd), (ent, ent_sd) = g.mean_std("f1"), g.mean_std("entropy")
        bf, be = int(np.argmax(f1)), int(np.argmin(ent))
        cells = [
            g.name,
            _seeds(g),
            f"{g.missions[-1]:g}",
            f"{f1[-1]:.{digits}f} ± {f1_sd[-1]:.{digits}f}",
            f"{ent[-1]:.{digits}f} ± {ent_sd[-1]:.{digits}f}",
            f"{f1[bf]:.{digits}f} ({g.missions[bf]:g})",
            f"{ent[be]:.{digits}f} ({g.missions[be]:g})",
            *(f"{g.levels[name][0]:.{digits}f} / {g.levels[name][1]:.{digits}f}" for name in BASELINES),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    notes = [f"- {g.name}: {g.validation.describe()}" for g in groups]
    return (
        "\n".join(
            [
                *lines,
                "",
                "Validation F1 / entropy at the final step, mean over the validation missions; ± std over seeds.",
                "",
                *notes,
            ]
        )
        + "\n"
    )


# ------------------------------------------------------------------------------------ command line
def parse_groups(specs: Sequence[str]) -> list[tuple[str, list[Path]]]:
    """``GROUP=RUN_DIR[,RUN_DIR...]`` -> ``(group, run folders)``."""
    groups = []
    for spec in specs:
        name, sep, dirs = spec.partition("=")
        paths = [Path(d) for d in dirs.split(",") if d.strip()]
        if not sep or not name.strip() or not paths:
            raise RunDirError(f"{spec!r}: expected GROUP=RUN_DIR[,RUN_DIR...]")
        groups.append((name.strip(), paths))
    return groups


def main(argv: Sequence[str] | None = None) -> list[GroupCurve]:
    """Read every group's runs, fly the baselines' levels, draw the figure, print (and write) the table."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("groups", nargs="+", metavar="GROUP=RUN_DIR[,RUN_DIR...]")
    parser.add_argument("--out", default="docs/figures/learning_curves.png", help="figure file (PNG)")
    parser.add_argument("--table", default=None, help="also write the Markdown table to this file")
    parser.add_argument(
        "--eval-seed",
        type=seed_value,
        default=None,
        help="validation env seed (default: the run's --eval-seed, else 1000)",
    )
    args = parser.parse_args(argv)
    specs = parse_groups(args.groups)
    levels = baseline_levels_cache()
    groups = [build_group(name, [read_run(p, args.eval_seed) for p in paths], levels) for name, paths in specs]
    figure = plot_groups(groups, args.out)
    table = table_markdown(groups)
    print(table, end="")
    if args.table:
        out = Path(args.table)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(table, encoding="utf-8")
    print(f"figure: {figure}")
    return groups


if __name__ == "__main__":
    try:
        main()
    except RunDirError as exc:  # a bad run folder is the user's to fix: one line naming it, status 1
        sys.exit(f"learning_curves: {exc}")
