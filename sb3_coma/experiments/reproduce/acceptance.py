"""The run's verdicts: does COMA beat every baseline, does the full model beat every ablation arm.

Kept apart from the steps that fly the missions so that the rules (paired tests on shared
missions, Holm within a family, a tie is not a win) can be tested on made-up results.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from sb3_coma.app.pretrained import ABLATION_LABELS as LABELS
from sb3_coma.experiments.reproduce.options import ABLATION_CHECK_NOISE, ABLATION_FULL
from sb3_coma.stats.paired import holm_adjust, paired_difference


def competitors(methods: Mapping[str, Sequence[Any]]) -> list[str]:
    """The methods a COMA model must beat: every baseline, never the upper references."""
    return list(dict.fromkeys(m.label for ms in methods.values() for m in ms if m.kind in ("baseline",)))


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
        out[env] = _acceptance_row(model_label, mine, others, diffs)
    return out


def _acceptance_row(
    model_label: str, mine: Any, others: Mapping[str, Any], diffs: Mapping[str, Mapping[str, Any]]
) -> dict[str, Any]:
    """One env's acceptance: the model's final numbers, the best baseline per metric, the paired
    verdicts and whether every one of them is a win."""
    finals = {k: final_numbers(v) for k, v in others.items()}
    best_f1 = max(finals.items(), key=lambda kv: kv[1]["f1"]) if finals else None
    best_en = min(finals.items(), key=lambda kv: kv[1]["entropy"]) if finals else None
    beats = {m: all(d[m].winner == model_label for d in diffs.values()) for m in ("f1", "entropy")}
    return {
        "coma": final_numbers(mine),
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


def _holm_nested(diffs: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Holm over every comparison of one acceptance row (all baselines x both metrics)."""
    keys = [(k, m) for k, per in diffs.items() for m in per]
    adjusted = holm_adjust([diffs[k][m] for k, m in keys])
    out: dict[str, dict[str, Any]] = {k: {} for k in diffs}
    for (k, m), d in zip(keys, adjusted):
        out[k][m] = d
    return out


def final_numbers(result: Any) -> dict[str, float]:
    """Mean and std (over the missions) of F1 and entropy at 100 % of the budget."""
    f1, en = np.asarray(result.f1)[:, -1], np.asarray(result.entropy)[:, -1]
    return {
        "f1": float(f1.mean()),
        "f1_std": float(f1.std()),
        "entropy": float(en.mean()),
        "entropy_std": float(en.std()),
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
