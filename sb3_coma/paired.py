"""Paired comparisons of two methods flown on the same seeded missions.

Table I and the ablation report mean +- std over 10 missions, and the standard deviation between
missions (0.01-0.05 in entropy) is as large as many of the differences the tables rank. Because
every method flies the *same* missions (env seed k for trial k), the per-mission difference
``a_k - b_k`` cancels most of that spread: its mean and standard error say whether a difference
is more than mission-to-mission noise. ``sb3-coma reproduce`` uses this on more missions than
Table I (``--wide-trials``, default 50) as a check of its verdicts.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["PairedDifference", "paired_difference", "paired_markdown"]

#: ``|difference| < TIE_SE * standard error`` is reported as a tie.
TIE_SE = 2.0


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
        return self.metric == "entropy"

    @property
    def verdict(self) -> str:
        """``"a better"``, ``"b better"`` or ``"tie"`` (within ``TIE_SE`` standard errors)."""
        if not abs(self.diff) > TIE_SE * self.se:  # also a tie: no difference at all, or one mission (se NaN)
            return "tie"
        a_better = self.diff < 0 if self.lower_is_better else self.diff > 0
        return f"{self.a} better" if a_better else f"{self.b} better"

    def as_dict(self) -> dict[str, object]:
        return {"a": self.a, "b": self.b, "metric": self.metric, "n": self.n, "mean_a": self.mean_a,
                "mean_b": self.mean_b, "diff": self.diff, "se": self.se, "verdict": self.verdict}


def paired_difference(a: object, b: object, metric: str = "entropy") -> PairedDifference:
    """Per-mission ``a - b`` of ``metric`` at the last step, for two ``EvaluationResult`` objects
    flown on the same missions (same env, seed and trial count: checked)."""
    if metric not in ("f1", "entropy"):
        raise ValueError(f"metric must be 'f1' or 'entropy', got {metric!r}")
    for attr in ("env", "seed", "n_trials"):
        if getattr(a, attr) != getattr(b, attr):
            raise ValueError(f"not the same missions: {attr} {getattr(a, attr)!r} vs {getattr(b, attr)!r}")
    va = np.asarray(getattr(a, metric))[:, -1].astype(np.float64)
    vb = np.asarray(getattr(b, metric))[:, -1].astype(np.float64)
    d = va - vb
    se = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else float("nan")
    return PairedDifference(a=str(a.method), b=str(b.method), metric=metric, n=len(d), mean_a=float(va.mean()),
                            mean_b=float(vb.mean()), diff=float(d.mean()), se=se)


def paired_markdown(rows: Sequence[PairedDifference], first_column: Sequence[str] | None = None,
                    first_title: str = "Env") -> str:
    """A Markdown table: one row per comparison (optionally led by a label column)."""
    head = ([first_title] if first_column is not None else []) + \
        ["a", "b", "metric @100%", "missions", "mean a", "mean b", "a - b (± s.e.)", "verdict"]
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(["---"] * len(head)) + " |"]
    for i, r in enumerate(rows):
        cells = ([first_column[i]] if first_column is not None else []) + [
            r.a, r.b, r.metric, str(r.n), f"{r.mean_a:.4f}", f"{r.mean_b:.4f}", f"{r.diff:+.4f} ± {r.se:.4f}",
            r.verdict]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
