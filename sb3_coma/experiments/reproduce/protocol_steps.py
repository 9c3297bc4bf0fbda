"""Steps 2 and 5 of ``reproduce``: the paper protocol (Table I) and the unseen protocol.

Both fly every method of every map on shared missions (``protocols.run_protocol``) and write
their tables and paired verdicts; the unseen protocol's verdicts are also the acceptance, so
that ``acceptance.md`` and ``unseen_verdicts.md`` say the same.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from sb3_coma.experiments import report
from sb3_coma.experiments.protocols import run_protocol
from sb3_coma.experiments.reproduce.acceptance import acceptance, competitors
from sb3_coma.experiments.reproduce.options import ReproduceOptions
from sb3_coma.experiments.reproduce.results import ProtocolStep
from sb3_coma.stats import tables


def paper_protocol(
    opts: ReproduceOptions, methods: Mapping[str, list[Any]], out: Path, say: Callable[[str], None]
) -> ProtocolStep:
    """Table I on split "paper": every method, global and team tables, paired verdicts."""
    paper = run_protocol("paper", methods, n_trials=opts.trials, seed=opts.seed, noise=opts.noise, log=say)
    paper.write(out, "paper")
    skipped = {f"paper protocol: {k}": v for k, v in paper.skipped.items()}
    rows = paper.rows()
    tables.write_table_csv(rows, out / "table.csv")
    tables.write_table_csv(rows, out / "team_table.csv", metrics="team")
    tables.write_per_step_csv(rows, out / "per_step.csv")
    tables.write_planning_time_csv(rows, out / "planning_time.csv")
    table = paper.table("global")
    (out / "table.md").write_text(table)
    (out / "team_table.md").write_text(paper.table("team"))
    summary = {"table": {f"{r.env}/{r.method}": r.summary() for r in (row.result for row in rows)}}
    summary["paper"] = paper.summary()
    return ProtocolStep(summary=summary, sections={"table": table}, skipped=skipped, protocol=paper)


def unseen_protocol(
    opts: ReproduceOptions, methods: Mapping[str, list[Any]], out: Path, say: Callable[[str], None]
) -> ProtocolStep:
    """Every method on ``unseen_missions`` missions of split "test" with random starts, and the
    acceptance taken from its verdict table."""
    if not opts.unseen_missions:
        return ProtocolStep()
    unseen = run_protocol("unseen", methods, n_trials=opts.unseen_missions, seed=opts.seed, noise=opts.noise, log=say)
    unseen.write(out, "unseen")
    skipped = {f"unseen protocol: {k}": v for k, v in unseen.skipped.items()}
    summary: dict[str, Any] = {"unseen": unseen.summary()}
    unseen_results = [row.result for row in unseen.rows()]
    table = {(c.env, c.b): c.diffs for c in unseen.comparisons() if c.a == "coma"}
    accept = acceptance(unseen_results, baselines=competitors(methods), verdicts=table)
    (out / "acceptance.md").write_text(report.acceptance_markdown(accept))
    summary["acceptance"] = accept
    return ProtocolStep(summary=summary, skipped=skipped, protocol=unseen)
