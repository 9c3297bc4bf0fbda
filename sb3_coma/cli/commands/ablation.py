"""``sb3-coma ablation``: {mean, sendfuse} x {cnn, cbam} under none / moderate / loud noise.

Example::

    sb3-coma ablation --models runs/ablation/ --env env3 --trials 10 --out results/ablation

``--models`` is a directory with ``{fusion}_{extractor}.zip`` files (``mean_cnn.zip``,
``mean_cbam.zip``, ``sendfuse_cnn.zip``, ``sendfuse_cbam.zip``; missing ones are left out), or
give them one by one with ``--model sendfuse_cbam=PATH``. Writes ``ablation.md`` / ``.csv``,
``ablation_curves.png`` (metrics vs step per noise level, Figure 4), ``ablation_bars.png`` and,
with ``--training-logs``, ``training_reward.png`` (Figure 3).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sb3_coma.app.arguments import (
    add_env_argument,
    add_out_argument,
    add_seed_argument,
    add_threads_argument,
    add_workers_argument,
    count_value,
)
from sb3_coma.cli import UserError, set_threads

NAME = "ablation"
#: The ablation refuses a bad variant, model set, log folder or noise list with a ``ValueError``:
#: this command's user errors, one line each.
USER_ERRORS = (ValueError,)
HELP = "evaluate the SenDFuse / CBAM ablation models at three noise levels"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_workers_argument(parser)
    add_threads_argument(parser)
    parser.add_argument("--models", default=None, help="directory with {fusion}_{extractor}.zip models")
    parser.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="FUSION_EXTRACTOR=PATH",
        help="one model, e.g. sendfuse_cbam=runs/x/final.zip; repeatable",
    )
    add_env_argument(parser)
    parser.add_argument("--noises", default="none,moderate,loud", help="comma-separated noise levels")
    parser.add_argument(
        "--trials", type=count_value, default=10, help="missions per model and noise level (default 10)"
    )
    add_seed_argument(parser)
    parser.add_argument("--uavs", type=count_value, default=None, help="number of UAVs (env default 4)")
    parser.add_argument("--budget", type=count_value, default=None, help="decisions per UAV (env default 15)")
    add_out_argument(parser, "results/ablation")
    parser.add_argument(
        "--training-logs", default=None, help="directory with {fusion}_{extractor} run dirs or CSVs for the reward plot"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the figures")


def run(args: argparse.Namespace) -> int:
    # here, not at module level: the parser alone must load neither torch nor matplotlib
    from sb3_coma.app.methods import split_label
    from sb3_coma.experiments import ablation, plots
    from sb3_coma.stats.tables import write_per_step_csv, write_table_csv

    set_threads(args.threads)
    pairs = [split_label(spec) for spec in args.model]  # an existing path is a path, "=" and all
    bad = [spec for spec, (label, _) in zip(args.model, pairs) if label is None]
    rules = (  # one table, one raise: (flag, what was given, allowed)
        ("--trials", args.trials, args.trials >= 1, ">= 1"),
        ("--seed", args.seed, args.seed >= 0, ">= 0"),
        ("--models/--model", args.models or args.model, bool(args.models) != bool(args.model), "one of the two"),
        ("--model", bad[0] if bad else None, not bad, "FUSION_EXTRACTOR=PATH"),
    )
    for flag, given, ok, allowed in rules:
        if not ok:
            raise UserError(f"{flag} must be {allowed}, got {given!r}")
    source: dict[str, str] | str = {str(k): v for k, v in pairs} if args.model else args.models
    noises = [n.strip() for n in args.noises.split(",") if n.strip()]
    options = {k: v for k, v in (("n_uavs", args.uavs), ("budget", args.budget)) if v is not None}
    logs = ablation.find_training_logs(args.training_logs) if args.training_logs else None
    result = ablation.run_ablation(source, env=args.env, noises=noises, n_trials=args.trials, seed=args.seed, **options)
    out = Path(args.out)
    written = []
    if result.results:
        rows = result.rows()
        (out).mkdir(parents=True, exist_ok=True)
        (out / "ablation.md").write_text(
            f"{args.env}: F1-score and entropy at 33/67/100 % of the budget, mean ± std over {args.trials} trials; "
            f"best of each noise level in bold.\n\n{result.markdown()}"
        )
        written += [
            out / "ablation.md",
            write_table_csv(rows, out / "ablation.csv", group_title="noise"),
            write_per_step_csv(rows, out / "ablation_per_step.csv", group_title="noise"),
        ]
        if not args.no_plots:
            written.append(
                plots.plot_metric_grid(
                    result.by_noise(),
                    out / "ablation_curves.png",
                    title=f"{args.env}: F1 and entropy vs step per noise level",
                )
            )
            written.append(
                plots.plot_ablation(
                    {k: v for k, v in result.results.items()},
                    out / "ablation_bars.png",
                    title=f"{args.env}: ablation at 100 % of the budget",
                )
            )
    if logs and not args.no_plots:
        written.append(plots.plot_training_reward(logs, out / "training_reward.png"))
    print()
    if result.results:
        print(result.markdown())
    for label, why in result.skipped.items():
        print(f"skipped {label}: {why}")
    if written:
        print("wrote " + ", ".join(str(p) for p in written))
    return 0 if result.results else 1
