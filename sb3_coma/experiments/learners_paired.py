"""Learned planners against each other (and AG, AG-k3) on the same missions, each the
validation's choice among its seeds: scene-clustered paired verdicts, Holm-corrected.

What it measures: whether one learner (e.g. COMA) beats another (IPPO, MAPPO) or the greedy
planners on shared missions, with every learner selected by the same rule, and how much its seeds
spread. It flies the validation missions by default (``--split validation``: a comparison that
may choose); the reported verdicts fly the test scenes with ``--split test`` (the ``"unseen"`` protocol:
random starts; the output says "test split: reporting only").

    python -m sb3_coma.experiments.learners_paired --env env3 --split test --missions 50 --fusion sendfuse \\
        --out docs/learners/shipped_env3.md \\
        coma=shipped:env3-sendfuse-cbam,runs/coma_s0,runs/coma_s2 \\
        ippo=runs/ippo_env3_s0,runs/ippo_env3_s1,runs/ippo_env3_s2 mappo=runs/mappo_env3_s0,...

Each ``label=CANDIDATES`` names one learner's seeds, comma-separated; a candidate is
* a run folder of ``sb3-coma train --eval-freq`` or of ``python -m sb3_coma.experiments.ippo_vs_ag``
  (its ``best_model.zip`` and ``eval/evaluations.npz``: the best validation return of the run),
* ``shipped:NAME``, a shipped model, scored by flying it on today's validation missions
  (``app.validation_flights.validation_return``, the rule ``ship_models`` applies to it),
* or a model zip (only as a learner's single candidate: it has no validation score).
The learner's row is the candidate with the highest validation return (split train, env seeds
1000+, never the test split): ``sb3_coma.experiments.ship_models``'s rule for every learner alike.
Every candidate is flown on the same unseen missions (trial k = env seed k) for the seed spread;
the selected one enters the paired table: the first learner minus every other learner, AG and
AG-k3, per metric, the standard error clustered by scene and the t verdict Holm-corrected over
the whole table (``sb3_coma.stats.paired``). A model's observation options (``action_gain``)
follow what it was trained with. ``--out`` writes the tables as Markdown (atomically).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
from stable_baselines3 import PPO

import sb3_coma.mappo.mappo  # noqa: F401  (the IPPO / MAPPO policy classes PPO.load needs)
from sb3_coma import COMA
from sb3_coma.app import pretrained as pt
from sb3_coma.app.arguments import add_env_argument, add_missions_argument
from sb3_coma.app.evaluation import Method, Missions, fly
from sb3_coma.app.roles import TEST_SPLIT_NOTE, add_split_argument, protocol_for_split
from sb3_coma.app.selection import run_command, validation_best
from sb3_coma.app.validation_flights import validation_return
from sb3_coma.common.checkpoints import atomic_write_text
from sb3_coma.stats.paired import PairedDifference, paired_difference, paired_markdown

#: Final metrics compared, in table order (global belief, then the UAVs' own beliefs).
METRICS = ("f1", "entropy", "team_f1", "team_entropy")
#: The greedy planners every learner is compared with (label, AG's options).
GREEDY: tuple[tuple[str, dict[str, Any]], ...] = (("ag", {}), ("ag-k3", {"lookahead": 3}))
#: Prefix of a shipped-model candidate.
SHIPPED_PREFIX = "shipped:"


def load(path: str | Path) -> Any:
    """A COMA zip, else an SB3 PPO zip (IPPO / MAPPO): the zip does not say which it holds."""
    try:
        return COMA.load(path, device="cpu")
    except (KeyError, ValueError, TypeError, AttributeError):
        return PPO.load(path, device="cpu")


@dataclass
class Candidate:
    """One seed of a learner: its model file, a seed label and its best validation return."""

    label: str
    path: Path
    validation: float | None


@dataclass
class Learner:
    """A learner's row: its candidates and, once flown, each one's unseen result."""

    label: str
    candidates: list[Candidate]
    results: dict[str, Any] = field(default_factory=dict)

    @property
    def selected(self) -> Candidate:
        """The candidate with the highest validation return (the first of equals)."""
        return select(self.candidates)


def validation_score(run: Path) -> float:
    """Best mean validation return of a run folder (its ``eval/evaluations.npz``). A COMA run uses
    ``ship_models``' rule (no warm-up evaluation); an IPPO / MAPPO run has no warm-up."""
    if (run / "config.yml").is_file():
        return validation_best(run)[0]
    with np.load(run / "eval" / "evaluations.npz") as data:
        return float(data["results"].mean(axis=1).max())


def _seed_label(run: Path, index: int) -> str:
    """``seed N`` as the run records it (``config.yml`` of ``sb3-coma train``, ``report.json`` of
    ``ippo_vs_ag``), else the candidate's position."""
    if (run / "config.yml").is_file():
        seed = run_command(run)[1].get("seed")
    elif (run / "report.json").is_file():
        seed = json.loads((run / "report.json").read_text()).get("args", {}).get("seed")
    else:
        seed = None
    return f"#{index}" if seed is None else f"seed {seed}"


def _candidate(spec: str, index: int) -> Candidate:
    """One candidate of a learner. One rule, one raise: a candidate is a known ``shipped:NAME``, a
    run folder with its ``best_model.zip``, or a model file; what ``spec`` is instead is named."""
    path = Path(spec)
    if spec.startswith(SHIPPED_PREFIX):
        name = spec[len(SHIPPED_PREFIX) :]
        models = pt.read_manifest()["models"]
        if name in models:
            path = pt.model_path(name)
            return Candidate(f"seed {models[name]['seed']}", path, validation_return(path))
        problem = f"no shipped model {name!r} (shipped: {', '.join(sorted(models))})"
    elif path.is_dir() and (path / "best_model.zip").is_file():
        return Candidate(_seed_label(path, index), path / "best_model.zip", validation_score(path))
    elif path.is_dir():
        problem = "a run folder without best_model.zip (train it with validation)"
    elif path.is_file():
        return Candidate(path.stem, path, None)
    else:
        problem = "neither a run folder, a model zip nor shipped:NAME"
    raise ValueError(f"{spec!r}: {problem}")


def parse_learner(spec: str) -> Learner:
    """``label=CANDIDATE[,CANDIDATE...]`` (module docstring) -> a :class:`Learner`.

    One rule, one raise: the spec's form, then that its candidates can be compared (every one
    scored on validation when there are several, each under a seed label of its own)."""
    label, sep, rest = spec.partition("=")
    candidates = [_candidate(part, i) for i, part in enumerate(rest.split(","))] if sep and label and rest else []
    needs = (
        (bool(candidates), "expected label=CANDIDATE[,CANDIDATE...]"),
        (
            len(candidates) == 1 or all(c.validation is not None for c in candidates),
            "a plain zip has no validation score: give it alone or as a run folder",
        ),
        (len({c.label for c in candidates}) == len(candidates), "two candidates with the same seed label"),
    )
    problem = next((message for ok, message in needs if not ok), None)
    if problem is not None:
        raise ValueError(f"{spec!r}: {problem}")
    return Learner(label, candidates)


def select(candidates: Sequence[Candidate]) -> Candidate:
    """The highest validation return wins; a single candidate is its own choice."""
    if len(candidates) == 1:
        return candidates[0]
    return max(candidates, key=lambda c: float(c.validation))  # type: ignore[arg-type]


def _fly(learner: Learner, missions: Missions, fusion: str) -> None:
    for cand in learner.candidates:
        model = load(cand.path)
        gain = model.observation_space.spaces.get("action_gain") is not None  # flown as it was trained
        method = Method(learner.label, model, fusion=fusion, deterministic=True)
        learner.results[cand.label] = fly(method, replace(missions, options={"action_gain": gain}))


def _final(result: Any, metric: str) -> float:
    return float(np.asarray(getattr(result, metric))[:, -1].mean())


def _learner_rows(learners: Sequence[Learner]) -> str:
    head = ["learner", "selected", "validation", *(f"{m} (selected)" for m in METRICS[:2]), "seeds"]
    head += [f"{m} over seeds" for m in METRICS[:2]]
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(["---"] * len(head)) + " |"]
    for lrn in learners:
        sel = lrn.selected
        val = "—" if sel.validation is None else f"{sel.validation:+.3f}"
        cells = [lrn.label, sel.label, val, *(f"{_final(lrn.results[sel.label], m):.4f}" for m in METRICS[:2])]
        cells.append(str(len(lrn.candidates)))
        for m in METRICS[:2]:
            per_seed = np.array([_final(r, m) for r in lrn.results.values()])
            cells.append(f"{per_seed.mean():.4f} ± {per_seed.std(ddof=1):.4f}" if len(per_seed) > 1 else "—")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _seed_rows(learners: Sequence[Learner]) -> str:
    lines = ["| learner | seed | validation | " + " | ".join(METRICS) + " |", "| --- " * (3 + len(METRICS)) + "|"]
    for lrn in learners:
        for cand in lrn.candidates:
            val = "—" if cand.validation is None else f"{cand.validation:+.3f}"
            mark = " (selected)" if cand is lrn.selected else ""
            finals = " | ".join(f"{_final(lrn.results[cand.label], m):.4f}" for m in METRICS)
            lines.append(f"| {lrn.label} | {cand.label}{mark} | {val} | {finals} |")
    return "\n".join(lines) + "\n"


def comparisons(learners: Sequence[Learner], greedy: dict[str, Any]) -> list[PairedDifference]:
    """The first learner's selected model minus every other selected learner and every greedy
    planner, per metric (not yet Holm-adjusted: the table is one family)."""
    first = learners[0].results[learners[0].selected.label]
    others = [lrn.results[lrn.selected.label] for lrn in learners[1:]] + list(greedy.values())
    return [paired_difference(first, other, m) for other in others for m in METRICS]


def report_markdown(
    env: str, missions: int, fusion: str, learners: Sequence[Learner], greedy: dict[str, Any], split: str = "test"
) -> str:
    """The three tables: learners (selected + seed spread), every seed, the paired verdicts."""
    flown = (
        "shared unseen missions (split test, random starts; " + TEST_SPLIT_NOTE + ")"
        if split == "test"
        else "shared validation missions (train scenes, env seeds 1000+, every scene equally, random starts)"
    )
    return (
        f"{env}, {missions} {flown}, moderate noise, fusion {fusion}, "
        "final step of the budget, argmax actions. Each learner's row is its best seed on the validation "
        "missions (split train, env seeds 1000+); the test missions chose nothing.\n\n"
        + _learner_rows(learners)
        + "\nEvery seed:\n\n"
        + _seed_rows(learners)
        + f"\nPaired ({learners[0].label}, selected, minus each): standard errors clustered by scene, "
        "t verdicts Holm-corrected over this table.\n\n" + paired_markdown(comparisons(learners, greedy))
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Select, fly every candidate and AG / AG-k3 on the same missions, print (and write) the tables."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument(
        "learners", nargs="+", help="label=CANDIDATE[,CANDIDATE...]; the first is compared with the rest"
    )
    add_env_argument(parser)
    add_missions_argument(parser, None, "learner and planner")
    parser.add_argument("--fusion", default="mean", choices=["mean", "sendfuse"])
    add_split_argument(parser)
    parser.add_argument("--out", help="also write the tables to this Markdown file")
    args = parser.parse_args(argv)
    try:
        learners = [parse_learner(spec) for spec in args.learners]
    except (ValueError, OSError, KeyError) as exc:
        print(f"learners_paired: {exc}", file=sys.stderr)
        return 2
    th.set_num_threads(1)
    protocol = protocol_for_split(args.split)
    flights = Missions(env=args.env, protocol=protocol, count=args.missions, record=1)
    for lrn in learners:
        _fly(lrn, flights, args.fusion)
    greedy = {label: fly(Method(label, "ag", fusion=args.fusion, planner_kwargs=kw), flights) for label, kw in GREEDY}
    missions = next(iter(greedy.values())).n_trials
    text = report_markdown(args.env, missions, args.fusion, learners, greedy, args.split)
    print(text)
    if args.out:
        command = "python -m sb3_coma.experiments.learners_paired " + " ".join(
            argv if argv is not None else sys.argv[1:]
        )
        atomic_write_text(Path(args.out), f"<!-- generated by: {command} -->\n\n{text}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
