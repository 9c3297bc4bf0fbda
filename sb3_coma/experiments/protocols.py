"""The two evaluation protocols over many methods, on shared missions, with paired verdicts.

``run_protocol("paper" | "unseen", methods)`` flies every method of every map on the protocol's
missions (``sb3_coma.common.evaluation.PROTOCOLS``: the paper's Table I on ``split="paper"``, or 50
unseen missions on ``split="test"`` with random starts); trial ``k`` is env seed ``seed + k`` for
every method, so the results are shared missions. :class:`ProtocolResult` holds them and writes:

* Table I style tables (mean ± std at 33 / 67 / 100 % of the budget) for the paper's metrics on the
  global map and for the team metrics on the UAVs' own beliefs (Markdown and CSV);
* a compact table at 100 % with the planning time per UAV decision;
* the verdicts: paired differences ``a - b`` at 100 % (± the CR2 standard error clustered by
  scene; a t test with Bell-McCaffrey degrees of freedom, at most scenes - 1, Holm-corrected over
  the whole verdict table; one scene gives no verdict: ``sb3_coma.stats.paired``,
  docs/statistics.md) for the comparisons of
  :func:`default_pairs`, on all four metrics;
* the per-scene breakdown of each map's first comparison (:meth:`ProtocolResult.scene_table`).

Methods (:class:`~sb3_coma.app.methods.Method`, the one type every front door resolves to): the baselines of :data:`sb3_coma.app.rows.BASELINE_METHODS` (AG with the map's weighting,
AG with look-ahead 2 and 3, AG with communication-only knowledge, lawnmower, random, and the
upper references centralised AG and the oracle) and whatever learned models exist: every shipped
COMA model trained on the map (:func:`sb3_coma.app.rows.shipped_methods`) and, as a hook for when they are
shipped, IPPO / MAPPO models (manifest entries with ``"algo": "ippo" | "mappo"``).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch as th

from sb3_coma.app.evaluation import Method, Missions, fly, resolve_method
from sb3_coma.common.evaluation import ALL_METRICS, EvaluationResult, Protocol, protocol_of
from sb3_coma.stats.paired import PairedDifference, cell, holm_adjust, p_text, paired_difference, scene_markdown
from sb3_coma.stats.tables import TableRow, table_markdown, write_per_step_csv, write_table_csv


# ---------------------------------------------------------------------------------------------
# comparisons
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Comparison:
    """``a - b`` on one map, on every metric (``sb3_coma.stats.paired.PairedDifference`` each)."""

    env: str
    a: str
    b: str
    diffs: dict[str, PairedDifference]

    def as_dict(self) -> dict[str, Any]:
        return {"env": self.env, "a": self.a, "b": self.b, **{m: d.as_dict() for m, d in self.diffs.items()}}


def holm_comparisons(comparisons: Sequence[Comparison]) -> list[Comparison]:
    """The comparisons with every metric's p-value Holm-adjusted over all of them: one verdict
    table is one family (``sb3_coma.stats.paired.holm``)."""
    flat = [(i, m, d) for i, c in enumerate(comparisons) for m, d in c.diffs.items()]
    adjusted = holm_adjust([d for _, _, d in flat])
    diffs: list[dict[str, PairedDifference]] = [{} for _ in comparisons]
    for (i, m, _), d in zip(flat, adjusted):
        diffs[i][m] = d
    return [Comparison(c.env, c.a, c.b, diffs[i]) for i, c in enumerate(comparisons)]


def default_pairs(methods: Sequence[Method]) -> list[tuple[str, str]]:
    """Which ``(a, b)`` a protocol's verdict table compares, in order:

    every learned model vs AG; the first learned model vs every other competitor; each AG variant
    vs AG; AG vs lawnmower and random; lawnmower vs random. References are shown, never compared."""
    labels = [m.label for m in methods]
    learned = [m.label for m in methods if m.learned]
    pairs: list[tuple[str, str]] = []

    def add(a: str, b: str) -> None:
        if a in labels and b in labels and a != b and (a, b) not in pairs and (b, a) not in pairs:
            pairs.append((a, b))

    for label in learned:
        add(label, "ag")
    competitors = [m.label for m in methods if m.kind != "reference"]
    if learned:
        for other in competitors:
            add(learned[0], other)
    for m in methods:
        if m.kind == "baseline" and m.label != "ag" and m.policy == "ag":
            add(m.label, "ag")
    for b in ("lawnmower", "random"):
        add("ag", b)
    add("lawnmower", "random")
    return pairs


# ---------------------------------------------------------------------------------------------
# the run
# ---------------------------------------------------------------------------------------------
@dataclass
class ProtocolResult:
    """Results of one protocol: ``results[(env, label)]``, the methods flown, what was skipped."""

    protocol: Protocol
    n_trials: int
    seed: int
    noise: str
    env_options: dict[str, Any]
    methods: dict[str, list[Method]] = field(default_factory=dict)
    results: dict[tuple[str, str], EvaluationResult] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)

    @property
    def envs(self) -> list[str]:
        return list(self.methods)

    def result(self, env: str, label: str) -> EvaluationResult:
        return self.results[(env, label)]

    def rows(self) -> list[TableRow]:
        return [
            TableRow(env, m.label, self.results[(env, m.label)])
            for env, ms in self.methods.items()
            for m in ms
            if (env, m.label) in self.results
        ]

    def comparisons(self, pairs: Mapping[str, Sequence[tuple[str, str]]] | None = None) -> list[Comparison]:
        """Paired differences on every metric for :func:`default_pairs` (or ``pairs[env]``), their
        p-values Holm-adjusted over all of them (the verdict table's family)."""
        out = []
        for env, ms in self.methods.items():
            flown = [m for m in ms if (env, m.label) in self.results]
            for a, b in (pairs or {}).get(env, default_pairs(flown)):
                ra, rb = self.results[(env, a)], self.results[(env, b)]
                out.append(Comparison(env, a, b, {m: paired_difference(ra, rb, m) for m in ALL_METRICS}))
        return holm_comparisons(out)

    def describe(self) -> str:
        """One sentence: which missions, how many, which noise."""
        return (
            f"{self.protocol.description}; {self.n_trials} missions per method (env seeds {self.seed}.."
            f"{self.seed + self.n_trials - 1}, the same for every method), channel noise `{self.noise}`"
        )

    # ---------------------------------------------------------------- markdown
    def table(self, family: str = "global") -> str:
        return table_markdown(self.rows(), metrics=family)

    def final_table(self) -> str:
        """At 100 % of the budget: the four metrics (mean ± std) and planning time per UAV decision."""
        head = (
            ["Env", "Method"]
            + [f"{ALL_METRICS[m][0]} {'↑' if ALL_METRICS[m][1] else '↓'}" for m in ALL_METRICS]
            + ["ms per UAV decision"]
        )
        lines = ["| " + " | ".join(head) + " |", "| --- | --- |" + " ---: |" * (len(head) - 2)]
        previous = None
        for row in self.rows():
            r = row.result
            cells = [f"{r.metric(m)[:, -1].mean():.4f} ± {r.metric(m)[:, -1].std():.4f}" for m in ALL_METRICS]
            lines.append(
                "| "
                + " | ".join(
                    [row.group if row.group != previous else "", row.method, *cells, f"{r.planning_time_ms.mean():.3f}"]
                )
                + " |"
            )
            previous = row.group
        return "\n".join(lines) + "\n"

    def verdict_table(self, comparisons: Sequence[Comparison] | None = None) -> str:
        """One row per comparison: ``a - b`` ± clustered s.e., Holm-adjusted p (who is better, tie,
        or no verdict with one scene) on each metric; the table's comparisons are one Holm family."""
        comparisons = self.comparisons() if comparisons is None else holm_comparisons(comparisons)
        head = ["Env", "a", "b"] + [f"{ALL_METRICS[m][0]} a − b" for m in ALL_METRICS]
        lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(["---"] * len(head)) + " |"]
        previous = None
        for c in comparisons:
            lines.append(
                "| "
                + " | ".join([c.env if c.env != previous else "", c.a, c.b] + [cell(c.diffs[m]) for m in ALL_METRICS])
                + " |"
            )
            previous = c.env
        return "\n".join(lines) + "\n"

    def scene_table(self, metric: str = "entropy", comparisons: Sequence[Comparison] | None = None) -> str:
        """Per map, its first comparison (a learned model vs AG when one flew) scene by scene:
        missions, both means and the difference, so a verdict carried by one scene shows. A map
        whose every mission is its own scene (env1's stars) gets one line instead of a table."""
        comparisons = self.comparisons() if comparisons is None else comparisons
        parts = []
        for env in dict.fromkeys(c.env for c in comparisons):
            c = next(c for c in comparisons if c.env == env)
            d = c.diffs[metric]
            if d.per_scene and all(s.n == 1 for s in d.per_scene):
                parts.append(f"{env}, {c.a} vs {c.b}: every mission is its own scene ({d.n_clusters} scenes).\n")
                continue
            p = "" if d.df < 1 else f" (p {p_text(d.p_adjusted)}, Holm; df {d.df:.1f})"
            title = f"{env}, {c.a} vs {c.b}, {metric} @100%: {d.verdict}{p}"
            parts.append(f"{title}\n\n{scene_markdown(d)}")
        return "\n".join(parts)

    # ---------------------------------------------------------------- files
    def write(self, out: str | os.PathLike, stem: str | None = None) -> list[Path]:
        """``{stem}_table.md/.csv`` (global), ``{stem}_team_table.md/.csv``, ``{stem}_per_step.csv``,
        ``{stem}_verdicts.md/.csv``, ``{stem}_scenes.md``; stem defaults to the protocol's name."""
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        stem = stem or self.protocol.name
        rows = self.rows()
        comparisons = self.comparisons()
        written = [
            write_table_csv(rows, out / f"{stem}_table.csv"),
            write_table_csv(rows, out / f"{stem}_team_table.csv", metrics="team"),
            write_per_step_csv(rows, out / f"{stem}_per_step.csv"),
        ]
        for name, text in (
            (f"{stem}_table.md", self.table("global")),
            (f"{stem}_team_table.md", self.table("team")),
            (f"{stem}_verdicts.md", self.verdict_table(comparisons)),
            (f"{stem}_scenes.md", self.scene_table(comparisons=comparisons)),
        ):
            (out / name).write_text(text)
            written.append(out / name)
        path = out / f"{stem}_verdicts.csv"
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(
                [
                    "env",
                    "a",
                    "b",
                    "metric",
                    "missions",
                    "mean_a",
                    "mean_b",
                    "diff",
                    "se",
                    "verdict",
                    "unit",
                    "scenes",
                    "se_clustered",
                    "df",
                    "p_value",
                    "p_holm",
                ]
            )
            for c in comparisons:
                for m, d in c.diffs.items():
                    writer.writerow(
                        [
                            c.env,
                            c.a,
                            c.b,
                            m,
                            d.n,
                            f"{d.mean_a:.6f}",
                            f"{d.mean_b:.6f}",
                            f"{d.diff:.6f}",
                            f"{d.se:.6f}",
                            d.verdict,
                            d.unit,
                            d.n_clusters,
                            f"{d.se_clustered:.6f}",
                            f"{d.df:.1f}",  # Bell-McCaffrey's, a float (0.0: one scene, no test)
                            f"{d.p_value:.6g}",
                            f"{d.p_adjusted:.6g}",
                        ]
                    )
        written.append(path)
        return written

    def summary(self) -> dict[str, Any]:
        """Numbers for summary.json: per (env, method) the 100 % means and stds, planning time;
        the comparisons; what was skipped."""
        table = {}
        for (env, label), r in self.results.items():
            s = r.summary()
            table[f"{env}/{label}"] = {
                k: v for k, v in s.items() if k.endswith(("_100_mean", "_100_std")) or k == "planning_ms_per_decision"
            }
        return {
            "protocol": self.protocol.name,
            "split": self.env_options.get("split"),
            "start": self.env_options.get("start"),
            "missions": self.n_trials,
            "seed": self.seed,
            "noise": self.noise,
            "table": table,
            "comparisons": [c.as_dict() for c in self.comparisons()],
            "skipped": dict(self.skipped),
            "methods": {
                env: [
                    {
                        "label": m.label,
                        "kind": m.kind,
                        "planner_kwargs": dict(self.results[(env, m.label)].planner_kwargs)
                        if (env, m.label) in self.results
                        else {},
                        "note": m.note,
                    }
                    for m in ms
                ]
                for env, ms in self.methods.items()
            },
        }


#: (policy name, planner options) already flown once in this process: numba compiled, caches warm.
_WARM: set[tuple[str, str]] = set()


def _warm_up(method: Method, env: str) -> None:
    """Fly a one-step mission of a baseline once per process so that ``evaluate``'s planning time
    does not include numba's compilation of the planner's kernels."""
    key = (str(method.policy), repr(sorted(dict(method.planner_kwargs).items())))
    if method.learned or key in _WARM:
        return
    fly(method, Missions(env=env, count=1, options={"budget": 1}))
    _WARM.add(key)


def _fly(method: Method, missions: Missions) -> EvaluationResult:
    method = resolve_method(method)
    _warm_up(method, missions.env)
    if method.learned:
        assert missions.seed is not None
        th.manual_seed(missions.seed)  # sampled actions (deterministic=False) come from torch's generator
    return fly(method, missions)


def run_protocol(
    protocol: str,
    methods: Mapping[str, Sequence[Method]],
    n_trials: int | None = None,
    seed: int = 0,
    noise: str = "moderate",
    log: Callable[[str], None] | None = print,
    **env_options: Any,
) -> ProtocolResult:
    """Fly ``methods[env]`` on every map of ``methods`` under ``protocol`` (module docstring).

    :param n_trials: missions per method (default: the protocol's, 10 or 50)
    :param env_options: further env options shared by every method (``budget``, ``n_uavs`` ...)

    A learned model that fails to run (e.g. its fusion's weights are missing) is skipped with a
    message in ``skipped``; a baseline that fails raises.
    """
    proto = protocol_of(protocol)
    n = proto.n_trials if n_trials is None else int(n_trials)
    out = ProtocolResult(proto, n, seed, noise, {**env_options, **proto.env_options()})
    for env, ms in methods.items():
        labels = [m.label for m in ms]
        # the rows come from app.rows, which labels every method of a map once: a repeat is our bug
        assert len(set(labels)) == len(labels), f"duplicate method labels on {env}: {labels}"
        out.methods[env] = list(ms)
        for m in ms:
            if log:
                log(f"{proto.name} protocol: {m.label} on {env} ({n} missions) ...")
            try:
                missions = Missions(env=env, protocol=proto.name, count=n, seed=seed, noise=noise, options=env_options)
                out.results[(env, m.label)] = _fly(m, missions)
            except (ValueError, RuntimeError, ImportError, FileNotFoundError) as exc:
                if not m.learned:
                    raise
                out.skipped[f"{env}/{m.label}"] = f"{type(exc).__name__}: {exc}"
                if log:
                    log(f"  skipped {m.label} on {env}: {exc}")
    return out
