"""Steps 3 and 4 of ``reproduce``: the env3 ablation, and the paired check on more missions.

The ablation flies the four SenDFuse x CBAM arms at three noise levels; the paired check then
backs Table I's and the ablation's verdicts with ``wide_trials`` missions per pair (COMA vs AG
per map, the full arm vs every other arm at loud noise).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from sb3_coma.app import evaluation as ev
from sb3_coma.app.pretrained import ABLATION_LABELS
from sb3_coma.experiments import ablation as ab
from sb3_coma.experiments import report
from sb3_coma.experiments.reproduce.acceptance import ablation_acceptance
from sb3_coma.experiments.reproduce.models import evaluate_model
from sb3_coma.experiments.reproduce.options import (
    ABLATION_ARMS,
    ABLATION_CHECK_NOISE,
    ABLATION_ENV,
    ABLATION_FULL,
    ReproduceOptions,
)
from sb3_coma.experiments.reproduce.results import AblationStep, ModelSource, StepOutput
from sb3_coma.stats import tables
from sb3_coma.stats.paired import PairedDifference, holm_adjust, paired_difference, paired_markdown


def ablation_step(
    opts: ReproduceOptions, arms: Mapping[tuple[str, str], Any], out: Path, say: Callable[[str], None]
) -> AblationStep:
    """The env3 ablation: the four arms at three noise levels on the unseen missions; returns the
    arms it flew (the later steps use those only)."""
    if not arms:
        return AblationStep(arms=dict(arms))
    result = ab.run_ablation(
        dict(arms),
        env=ABLATION_ENV,
        n_trials=opts.unseen_missions or opts.trials,
        seed=opts.seed,
        log=say,
        protocol="unseen",
    )
    tables.write_table_csv(result.rows(), out / "ablation.csv", group_title="noise")
    sections = {"ablation": result.markdown()}
    (out / "ablation.md").write_text(sections["ablation"])
    full = ABLATION_LABELS[ABLATION_FULL]
    keys = [(noise, label) for (label, noise) in result.results if label != full and (full, noise) in result.results]
    adjusted = holm_adjust(
        [paired_difference(result.results[(full, n)], result.results[(lb, n)], "entropy") for n, lb in keys]
    )
    paired = [(noise, d) for (noise, _), d in zip(keys, adjusted)]
    sections["ablation_paired"] = report.paired_table(paired, "noise")
    flown = {v: m for v, m in arms.items() if ABLATION_LABELS[v] not in result.skipped}
    summary = {"ablation": {**ablation_acceptance(result), "paired": [{"noise": n, **d.as_dict()} for n, d in paired]}}
    return AblationStep(summary=summary, sections=sections, result=result, arms=flown)


def wide_paired_check(
    opts: ReproduceOptions,
    sources: Mapping[str, ModelSource],
    arms: Mapping[tuple[str, str], Any],
    out: Path,
    say: Callable[[str], None],
) -> StepOutput:
    """COMA vs AG per env and the full model vs every other ablation arm (loud noise), each pair on
    the same ``wide_trials`` missions."""
    if not opts.wide_trials or not (sources or arms):
        return StepOutput(summary={"paired": None})
    trials, seed, noise = opts.wide_trials, opts.seed, opts.noise
    table1 = _coma_vs_ag(sources, trials, seed, noise, say)
    runs = _fly_arms(arms, trials, seed, say)
    full = ABLATION_LABELS[ABLATION_FULL]
    diffs = holm_adjust(
        [paired_difference(runs[full], r, "entropy") for label, r in runs.items() if label != full and full in runs]
    )
    met = all(d.diff <= 0 for d in diffs) if len(diffs) == len(ABLATION_ARMS) - 1 else None
    table = _paired_text(table1, diffs, met, trials, seed, noise)
    (out / "paired.md").write_text(table)
    numbers = {
        "trials": trials,
        "seed": seed,
        "noise": noise,
        "table1": [{"env": env, **d.as_dict()} for env, d in table1],
        "ablation": [d.as_dict() for d in diffs],
        "ablation_noise": ABLATION_CHECK_NOISE,
        "ablation_met": met,
    }
    return StepOutput(summary={"paired": numbers}, sections={"paired": table})


def _coma_vs_ag(
    sources: Mapping[str, ModelSource], trials: int, seed: int, noise: str, say: Callable[[str], None]
) -> list[tuple[str, PairedDifference]]:
    """Per map, COMA - AG on F1 and entropy, Holm over the whole table."""
    table1 = []
    for env, src in sources.items():
        say(f"paired check: coma vs ag on {env} ({trials} missions) ...")
        coma = evaluate_model(src, env, trials, seed, noise, "coma", protocol="unseen")
        ag = ev.evaluate("ag", env=env, n_trials=trials, seed=seed, noise=noise, record=0, protocol="unseen")
        table1 += [(env, paired_difference(coma, ag, "f1")), (env, paired_difference(coma, ag, "entropy"))]
    return list(zip([env for env, _ in table1], holm_adjust([d for _, d in table1])))


def _fly_arms(
    arms: Mapping[tuple[str, str], Any], trials: int, seed: int, say: Callable[[str], None]
) -> dict[str, Any]:
    """Every ablation arm on the same missions at the check's noise, by arm label."""
    runs = {}
    for variant, model in arms.items():
        label = ABLATION_LABELS[variant]
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
    return runs


def _paired_text(
    table1: list[tuple[str, PairedDifference]],
    diffs: list[PairedDifference],
    met: bool | None,
    trials: int,
    seed: int,
    noise: str,
) -> str:
    """``paired.md``: the COMA vs AG table and, with arms, the full model vs each other arm."""
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
    return "\n".join(parts)
