"""Paired comparisons of two methods flown on the same seeded missions.

Table I and the ablation report mean +- std over 10 missions, and the standard deviation between
missions (0.01-0.05 in entropy) is as large as many of the differences the tables rank. Because
every method flies the *same* missions (env seed k for trial k), the per-mission difference
``a_k - b_k`` cancels most of that spread: its mean and standard error say whether a difference
is more than mission-to-mission noise. Every "A beats B" that ``sb3-coma reproduce`` writes comes
from here: the paper and unseen protocols' verdict tables, the acceptance table, the noise sweep
and a check on more missions than Table I (``--wide-trials``, default 50).

Metrics: the paper's ``f1`` / ``entropy`` of the global map and the team metrics ``team_f1`` /
``team_entropy`` on the UAVs' own local beliefs (lower entropy is better either way).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["METRICS", "PairedDifference", "cell", "paired_difference", "paired_markdown"]

#: ``|difference| < TIE_SE * standard error`` is reported as a tie.
TIE_SE = 2.0
#: Metrics a paired difference can be taken of, and whether lower is better.
METRICS: dict[str, bool] = {"f1": False, "entropy": True, "team_f1": False, "team_entropy": True}
#: Env options that must agree for two results to be the same missions (besides env, seed, count).
MISSION_OPTIONS = ("split", "start", "map_seed", "map_path", "n_uavs", "budget")


@dataclass(frozen=True)
class PairedDifference:
    """``a - b`` of one metric at 100 % of the budget, over ``n`` shared missions."""

    a: str
    b: str
    metric: str
    n: int
    mean_a: float
    mean_b: float
    diff: float
    se: float

    @property
    def lower_is_better(self) -> bool:
        return METRICS.get(self.metric, False)

    @property
    def verdict(self) -> str:
        """``"a better"``, ``"b better"`` or ``"tie"`` (within ``TIE_SE`` standard errors)."""
        if not abs(self.diff) > TIE_SE * self.se:  # also a tie: no difference at all, or one mission (se NaN)
            return "tie"
        a_better = self.diff < 0 if self.lower_is_better else self.diff > 0
        return f"{self.a} better" if a_better else f"{self.b} better"

    @property
    def winner(self) -> str | None:
        """The better method's label, ``None`` for a tie."""
        v = self.verdict
        return None if v == "tie" else v[: -len(" better")]

    def as_dict(self) -> dict[str, object]:
        return {
            "a": self.a,
            "b": self.b,
            "metric": self.metric,
            "n": self.n,
            "mean_a": self.mean_a,
            "mean_b": self.mean_b,
            "diff": self.diff,
            "se": self.se,
            "verdict": self.verdict,
        }


def paired_difference(a: object, b: object, metric: str = "entropy") -> PairedDifference:
    """Per-mission ``a - b`` of ``metric`` at the last step, for two ``EvaluationResult`` objects
    flown on the same missions (same env, seed, trial count and mission options such as the
    split: checked)."""
    if metric not in METRICS:
        raise ValueError(f"metric must be 'f1', 'entropy', 'team_f1' or 'team_entropy', got {metric!r}")
    for attr in ("env", "seed", "n_trials"):
        if getattr(a, attr) != getattr(b, attr):
            raise ValueError(f"not the same missions: {attr} {getattr(a, attr)!r} vs {getattr(b, attr)!r}")
    oa, ob = getattr(a, "env_options", None) or {}, getattr(b, "env_options", None) or {}
    for key in MISSION_OPTIONS:
        if oa.get(key) != ob.get(key):
            raise ValueError(f"not the same missions: {key} {oa.get(key)!r} vs {ob.get(key)!r}")
    va = np.asarray(getattr(a, metric))[:, -1].astype(np.float64)
    vb = np.asarray(getattr(b, metric))[:, -1].astype(np.float64)
    d = va - vb
    se = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else float("nan")
    return PairedDifference(
        a=str(a.method),
        b=str(b.method),
        metric=metric,
        n=len(d),
        mean_a=float(va.mean()),
        mean_b=float(vb.mean()),
        diff=float(d.mean()),
        se=se,
    )


def paired_markdown(
    rows: Sequence[PairedDifference], first_column: Sequence[str] | None = None, first_title: str = "Env"
) -> str:
    """A Markdown table: one row per comparison (optionally led by a label column)."""
    head = ([first_title] if first_column is not None else []) + [
        "a",
        "b",
        "metric @100%",
        "missions",
        "mean a",
        "mean b",
        "a - b (± s.e.)",
        "verdict",
    ]
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(["---"] * len(head)) + " |"]
    for i, r in enumerate(rows):
        cells = ([first_column[i]] if first_column is not None else []) + [
            r.a,
            r.b,
            r.metric,
            str(r.n),
            f"{r.mean_a:.4f}",
            f"{r.mean_b:.4f}",
            f"{r.diff:+.4f} ± {r.se:.4f}",
            r.verdict,
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def cell(d: PairedDifference, digits: int = 4) -> str:
    """``"+0.0123 ± 0.0040 (ag)"``: the difference, its standard error and who is better (or tie)."""
    return f"{d.diff:+.{digits}f} ± {d.se:.{digits}f} ({d.winner or 'tie'})"
