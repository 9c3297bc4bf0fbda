"""Table I style tables of :class:`~sb3_coma.common.evaluation.EvaluationResult` s: Markdown, text, CSV.

Cells are mean +- std over missions at 33 %, 67 % and 100 % of the budget; the best mean of each
group and column is bold.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from sb3_coma.common.evaluation import (
    ALL_METRICS,
    FRACTION_LABELS,
    FRACTIONS,
    METRICS,
    TEAM_METRICS,
    EvaluationResult,
)


@dataclass(frozen=True)
class TableRow:
    """One line of a Table-I style table: a group (env or noise level), a method and its result."""

    group: str
    method: str
    result: EvaluationResult


#: Which metrics a table shows: the paper's (global map) or the team's (the UAVs' own M_i).
METRIC_FAMILIES: dict[str, tuple[str, ...]] = {"global": tuple(METRICS), "team": tuple(TEAM_METRICS)}


def _metric_names(metrics: Sequence[str] | str) -> tuple[str, ...]:
    names = (
        METRIC_FAMILIES[metrics]
        if isinstance(metrics, str) and metrics in METRIC_FAMILIES
        else tuple([metrics] if isinstance(metrics, str) else metrics)
    )
    unknown = [m for m in names if m not in ALL_METRICS]
    if unknown or not names:
        raise ValueError(
            f"unknown metrics {unknown or names}; choose from {sorted(ALL_METRICS)} or {sorted(METRIC_FAMILIES)}"
        )
    return names


def _cell_values(result: EvaluationResult, metrics: Sequence[str] = tuple(METRICS)) -> list[tuple[float, float]]:
    return [result.mean_std(name, frac) for name in metrics for frac in FRACTIONS]


def _best_flags(rows: Sequence[TableRow], digits: int, metrics: Sequence[str] = tuple(METRICS)) -> list[list[bool]]:
    """Per row and column, whether the mean is the best of its group (ties share the bold)."""
    flags = [[False] * (len(metrics) * len(FRACTIONS)) for _ in rows]
    higher = [ALL_METRICS[name][1] for name in metrics for _ in FRACTIONS]
    groups: dict[str, list[int]] = {}
    for i, row in enumerate(rows):
        groups.setdefault(row.group, []).append(i)
    values = [_cell_values(r.result, metrics) for r in rows]
    for members in groups.values():
        if len(members) < 2:
            continue
        for col, up in enumerate(higher):
            means = [round(values[i][col][0], digits) for i in members]
            best = max(means) if up else min(means)
            for i, m in zip(members, means):
                flags[i][col] = m == best
    return flags


def table_markdown(
    rows: Sequence[TableRow], group_title: str = "Env", digits: int = 4, metrics: Sequence[str] | str = "global"
) -> str:
    """The paper's Table I as Markdown: mean +- std, best mean of each group in bold.

    :param metrics: ``"global"`` (the paper's F1 / entropy of the global map), ``"team"``
        (``team_f1`` / ``team_entropy``) or a list of metric names"""
    metrics = _metric_names(metrics)
    head = [group_title, "Method"] + [
        f"{ALL_METRICS[n][0]} {'↑' if ALL_METRICS[n][1] else '↓'} {lab}" for n in metrics for lab in FRACTION_LABELS
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join([" --- "] * 2 + [" ---: "] * (len(head) - 2)) + "|"]
    flags = _best_flags(rows, digits, metrics)
    previous = None
    for row, bold in zip(rows, flags):
        cells = []
        for (mean, std), b in zip(_cell_values(row.result, metrics), bold):
            m = f"{mean:.{digits}f}"
            cells.append(f"**{m}** ± {std:.{digits}f}" if b else f"{m} ± {std:.{digits}f}")
        group = row.group if row.group != previous else ""
        previous = row.group
        lines.append("| " + " | ".join([group, row.method, *cells]) + " |")
    return "\n".join(lines) + "\n"


def table_text(
    rows: Sequence[TableRow], group_title: str = "Env", digits: int = 4, metrics: Sequence[str] | str = "global"
) -> str:
    """Plain-text Table I for terminals: the best mean of each group marked with ``*``."""
    metrics = _metric_names(metrics)
    head = [group_title, "Method"] + [f"{n} {lab}" for n in metrics for lab in FRACTION_LABELS]
    flags = _best_flags(rows, digits, metrics)
    body = []
    for row, bold in zip(rows, flags):
        cells = [
            f"{'*' if b else ' '}{mean:.{digits}f}±{std:.{digits}f}"
            for (mean, std), b in zip(_cell_values(row.result, metrics), bold)
        ]
        body.append([row.group, row.method, *cells])
    widths = [max(len(str(r[i])) for r in [head, *body]) for i in range(len(head))]

    def fmt(r: list[str]) -> str:
        return "  ".join(str(c).ljust(w) if i < 2 else str(c).rjust(w) for i, (c, w) in enumerate(zip(r, widths)))

    return "\n".join([fmt(head), "  ".join("-" * w for w in widths)] + [fmt(r) for r in body]) + "\n"


def table_columns(metrics: Sequence[str] | str = "global") -> list[str]:
    return [
        f"{name}_{lab[:-1]}_{stat}"
        for name in _metric_names(metrics)
        for lab in FRACTION_LABELS
        for stat in ("mean", "std")
    ]


def write_table_csv(
    rows: Sequence[TableRow], path: str | os.PathLike, group_title: str = "env", metrics: Sequence[str] | str = "global"
) -> Path:
    """Wide CSV of Table I: one line per (group, method), ``f1_33_mean, f1_33_std, ...``
    (``metrics="team"`` or a list: other metric columns; ``"all"``-style lists work too)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = table_columns(metrics)
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(
            [
                group_title,
                "method",
                "n_trials",
                "budget",
                *columns,
                "return_mean",
                "return_std",
                "planning_ms_per_decision",
            ]
        )
        for row in rows:
            s = row.result.summary()
            writer.writerow(
                [row.group, row.method, row.result.n_trials, row.result.budget]
                + [f"{s[c]:.6f}" for c in columns]
                + [f"{s['return_mean']:.6f}", f"{s['return_std']:.6f}", f"{s['planning_ms_per_decision']:.6f}"]
            )
    return path


def write_per_step_csv(rows: Sequence[TableRow], path: str | os.PathLike, group_title: str = "env") -> Path:
    """Long CSV of the curves behind the plots: mean and std of both metrics at every step."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow([group_title, "method", "step"] + [f"{m}_{s}" for m in ALL_METRICS for s in ("mean", "std")])
        for row in rows:
            r = row.result
            for t in range(r.budget + 1):
                writer.writerow(
                    [row.group, row.method, t]
                    + [f"{v:.6f}" for m in ALL_METRICS for v in (r.metric(m)[:, t].mean(), r.metric(m)[:, t].std())]
                )
    return path


def planning_time_markdown(rows: Sequence[TableRow]) -> str:
    """Per-method planning time: mean and worst step, ms per UAV decision."""
    lines = ["| Env | Method | ms per UAV decision (mean) | slowest step (ms) |", "| --- | --- | ---: | ---: |"]
    for row in rows:
        t = row.result.planning_time_ms
        lines.append(f"| {row.group} | {row.method} | {t.mean():.4f} | {t.max():.4f} |")
    return "\n".join(lines) + "\n"


def write_planning_time_csv(rows: Sequence[TableRow], path: str | os.PathLike) -> Path:
    """Per-step planning time of each method (ms per UAV decision)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    budget = max(r.result.budget for r in rows) if rows else 0
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["env", "method", "mean_ms"] + [f"step_{t}" for t in range(1, budget + 1)])
        for row in rows:
            t = row.result.planning_time_ms
            writer.writerow([row.group, row.method, f"{t.mean():.6f}"] + [f"{v:.6f}" for v in t])
    return path


def rows_for(
    results: Iterable[EvaluationResult], group: Callable[[EvaluationResult], str] | None = None
) -> list[TableRow]:
    """Table rows grouped by env (or by ``group(result)``), in the given order."""
    return [TableRow(group(r) if group else r.env, r.method, r) for r in results]
