"""Budget sweep: where does learning pay?

    python -m sb3_coma.experiments.budget_sweep --env env3 --budgets 10,15,30 --missions 32
    python -m sb3_coma.experiments.budget_sweep --env env1 --budgets 15 --split test --missions 50 --noise loud

Flies the map's shipped COMA model, AG and AG with look-ahead 3 on the same missions at each
budget (``--split``: the validation missions by default; ``--split test`` flies the unseen test
scenes, for reporting only), and prints one Markdown table: final F1 and
entropy per method and budget, and the paired differences COMA - AG and COMA - AG-k3 with
scene-clustered standard errors and verdicts (Holm over the whole table, docs/statistics.md).
The shipped models were trained with a budget of 15: at 10 and 30 they fly a world they were not
trained for (the evaluation says so in a warning), which is the question this sweep asks.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from typing import Any

from sb3_coma.app.arguments import add_env_argument, add_missions_argument, add_seed_argument, add_workers_argument
from sb3_coma.app.evaluation import Method, Missions, fly, parallel_evaluation, resolve_method
from sb3_coma.app.roles import add_split_argument, protocol_for_split
from sb3_coma.common.evaluation import EvaluationResult
from sb3_coma.stats.paired import PairedDifference, holm_adjust, paired_difference

#: (label, method, planner options) of the methods flown at every budget, the learned one first.
BASELINES: tuple[tuple[str, str, dict[str, Any]], ...] = (("ag", "ag", {}), ("ag-k3", "ag", {"lookahead": 3}))


def sweep(
    env: str,
    budgets: list[int],
    missions: int | None,
    seed: int | None,
    noise: str = "moderate",
    protocol: str = "validation",
) -> dict[int, dict[str, EvaluationResult]]:
    """Every method at every budget on the same missions of ``protocol``."""
    out: dict[int, dict[str, EvaluationResult]] = {}
    coma = resolve_method(Method("coma", env))  # the map's shipped model, verified once
    baselines = [Method(label, method, planner_kwargs=options) for label, method, options in BASELINES]
    for budget in budgets:
        flights = Missions(
            env=env, protocol=protocol, count=missions, seed=seed, noise=noise, options={"budget": budget}
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the model flies another budget than it trained with: the point
            flown = {"coma": fly(coma, flights)}
        for method in baselines:
            flown[method.label] = fly(method, flights)
        out[budget] = flown
    return out


def table(results: dict[int, dict[str, EvaluationResult]]) -> str:
    """Markdown: per budget, the means and the paired verdicts of COMA against each baseline."""
    keys = [(b, label, m) for b in results for label, _, _ in BASELINES for m in ("f1", "entropy")]
    diffs: list[PairedDifference] = holm_adjust(
        [paired_difference(results[b]["coma"], results[b][label], m) for b, label, m in keys]
    )
    lines = [
        "| budget | metric | COMA | AG | AG-k3 | COMA - AG | COMA - AG-k3 |",
        "| ---: | --- | ---: | ---: | ---: | --- | --- |",
    ]
    for b in results:
        for m in ("f1", "entropy"):
            means = [float(getattr(results[b][k], m)[:, -1].mean()) for k in ("coma", "ag", "ag-k3")]
            cells = [
                f"{d.diff:+.4f} ± {d.se_clustered:.4f} ({d.verdict})"
                for (bb, _, mm), d in zip(keys, diffs)
                if bb == b and mm == m
            ]
            lines.append(f"| {b} | {m} | " + " | ".join(f"{x:.4f}" for x in means) + " | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Run the sweep and print its table."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_env_argument(parser)
    parser.add_argument("--budgets", default="10,15,30", help="comma-separated budgets (decisions per UAV)")
    add_missions_argument(parser, None, "method and budget")
    add_seed_argument(parser, default=None)
    add_split_argument(parser)
    parser.add_argument("--noise", default="moderate", help="channel noise of every mission (none, moderate, loud)")
    add_workers_argument(parser)
    args = parser.parse_args(argv)
    budgets = [int(b) for b in args.budgets.split(",")]
    with parallel_evaluation(args.eval_workers):
        protocol = protocol_for_split(args.split)
        print(table(sweep(args.env, budgets, args.missions, args.seed, args.noise, protocol)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
