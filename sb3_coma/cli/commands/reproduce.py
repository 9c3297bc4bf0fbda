"""``sb3-coma reproduce``: both evaluation protocols, ablation, noise sweep, costs -> results/ and docs/RESULTS.md.

Examples::

    sb3-coma reproduce                       # shipped models + baselines, env1-3 -> results/, docs/RESULTS.md
    sb3-coma reproduce --unseen-missions 30  # fewer unseen missions (the default is the protocol's 50)
    sb3-coma reproduce --train               # retrain each env through zoo_configs/coma.yml first
    sb3-coma reproduce --quick --out /tmp/r  # smoke run: 2 missions everywhere (and a tiny training with --train)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from sb3_coma.app.arguments import (
    add_env_argument,
    add_out_argument,
    add_seed_argument,
    add_threads_argument,
    add_workers_argument,
)
from sb3_coma.cli import UserError, set_threads
from uav_ipp.config import count_or_none_value, count_value

# The study and the config checks import torch, rl_zoo3 and matplotlib: the functions below import
# them, so that building the parser (``--help``) does not.

NAME = "reproduce"
#: ``reproduce()`` refuses a bad option (a count, an unknown or corrupt shipped model, env options,
#: an --out it cannot replace) with a ``ValueError`` before any work: this command's user errors.
USER_ERRORS = (ValueError,)
HELP = (
    "reproduce the paper protocol (Table I), the unseen protocol, the env3 ablation, the noise sweep and the "
    "deployment cost table (shipped models or --train) into results/ and docs/RESULTS.md"
)
DESCRIPTION = (
    "Evaluate the shipped COMA models (or retrain them with --train through zoo_configs/coma.yml) and every other "
    "shipped model against AG (the map's validated weighting), AG with look-ahead 2 and 3, lawnmower and random on "
    "env1-env3 under moderate noise: the paper protocol (split paper, 10 seeded trials, Table I at 33/67/100 % of "
    "the budget, mean +- std) and the unseen protocol (50 missions on split test, random starts), global and team "
    "metrics, paired verdicts; the SenDFuse x CBAM ablation on env3; the noise sweep; generalisation; the cost per "
    "UAV decision; figures and RESULTS.md. --out is written into a staging folder next to it and replaced as a "
    "whole when the run completes (files of other commands in it are kept): an interrupted run leaves it as it was."
)


def _repo_docs() -> Path | None:
    """docs/RESULTS.md of a source checkout, or None for an installed package."""
    root = Path(__file__).resolve().parents[3]
    docs = root / "docs"
    return docs / "RESULTS.md" if docs.is_dir() and (root / "zoo_configs").is_dir() else None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    _add_protocol_arguments(parser)
    _add_model_arguments(parser)
    _add_section_arguments(parser)


def _add_protocol_arguments(parser: argparse.ArgumentParser) -> None:
    """Threads, output folder, maps, mission counts, seed and noise."""
    add_workers_argument(parser)
    add_threads_argument(parser)
    add_out_argument(parser, "results")
    add_env_argument(parser, several=True)
    parser.add_argument(
        "--trials",
        type=count_value,
        default=10,
        help="missions per method of the paper protocol and the ablation (default 10; --quick: 2)",
    )
    parser.add_argument(
        "--unseen-missions",
        type=count_or_none_value,
        default=None,
        metavar="N",
        help="missions per method of the unseen protocol (default 50; 0 skips it; --quick: 2)",
    )
    parser.add_argument(
        "--sweep-missions",
        type=count_or_none_value,
        default=None,
        metavar="N",
        help="missions per setting of the noise sweep (default 50, the unseen protocol's missions; 0 skips "
        "it; --quick: 2)",
    )
    add_seed_argument(parser)
    parser.add_argument("--noise", default="moderate", help="channel noise: none, moderate, loud (default moderate)")


def _add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Which models fly and how: --train and its options, --quick, --ship, --record, sampled or argmax."""
    parser.add_argument("--train", action="store_true", help="retrain each env's model through the zoo config first")
    parser.add_argument(
        "--timesteps", type=count_value, default=None, help="with --train: joint steps (default: the config's)"
    )
    parser.add_argument(
        "--fusion",
        default=None,
        choices=("mean", "sendfuse"),
        help="with --train: fusion (default: the shipped model's; sendfuse needs its weights)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="smoke run (< 60 s): 2 trials, tiny training with --train; docs are not rewritten",
    )
    parser.add_argument(
        "--ship",
        action="store_true",
        help="with --train: replace the shipped zips and models.json with the retrained models",
    )
    parser.add_argument(
        "--record",
        action="store_true",
        help="store the measured metrics of the shipped models in sb3_coma/pretrained/models.json",
    )
    parser.add_argument(
        "--sampled",
        dest="deterministic",
        action="store_const",
        const=False,
        default=None,
        help="evaluate COMA with seeded draws from its policy (default: as recorded per model)",
    )
    parser.add_argument(
        "--argmax", dest="deterministic", action="store_const", const=True, help="evaluate COMA with argmax actions"
    )


def _add_section_arguments(parser: argparse.ArgumentParser) -> None:
    """RESULTS.md, the sections that can be skipped, --baselines-only and the paired check's missions."""
    parser.add_argument(
        "--docs",
        default=None,
        metavar="PATH",
        help="where to write RESULTS.md (default docs/RESULTS.md of a source checkout; not with --quick)",
    )
    parser.add_argument("--no-docs", action="store_true", help="do not rewrite docs/RESULTS.md")
    parser.add_argument("--no-plots", action="store_true", help="skip the figures")
    parser.add_argument(
        "--quiet", action="store_true", help="no progress lines (steps, warm-start rounds, training); errors still show"
    )
    parser.add_argument("--no-generalisation", action="store_true", help="skip the generalisation section")
    parser.add_argument(
        "--no-ablation", action="store_true", help="skip the env3 ablation (SenDFuse x CBAM arms at three noise levels)"
    )
    parser.add_argument("--no-costs", action="store_true", help="skip the deployment cost table")
    parser.add_argument(
        "--baselines-only",
        action="store_true",
        help="fly no learned model: every step with the baselines alone (maps without a shipped "
        "model get baseline rows anyway)",
    )
    parser.add_argument(
        "--wide-trials",
        type=count_or_none_value,
        default=None,
        metavar="N",
        help="missions of the paired check of the verdicts: COMA vs AG per env and the full "
        "model vs each ablation arm, same missions (default 50; 0 skips it)",
    )


def _env_names(args: argparse.Namespace) -> list[str]:
    """The maps of --env, each once."""
    from sb3_coma.app.config import map_list

    return map_list(args.env)


def _check_options(args: argparse.Namespace) -> None:
    """What only the command line adds to ``reproduce()``'s own rules (which it applies before any
    work: counts, seed, --ship and --baselines-only), checked before minutes of missions.

    Every verdict is a paired test on shared missions and needs at least 2 of them: a count of 1
    would fly everything and report "nan" everywhere, so it is refused, naming the option (0 skips
    the unseen and sweep steps; --quick caps each count at 2, never below what is given). --out
    and --docs are checked now rather than when the report is written."""
    from sb3_coma.app.config import output_file_problem, output_folder_problem

    paired = "the paired verdicts need at least 2 missions (with 1 every verdict is nan)"
    rules = [
        *(
            (flag, value, None if value != 1 else f"{paired}; use {flag} 2 or more{skip}")
            for flag, value, skip in (
                ("--trials", args.trials, ""),
                ("--unseen-missions", args.unseen_missions, " (0 skips it)"),
                ("--sweep-missions", args.sweep_missions, " (0 skips it)"),
            )
        ),
        ("--out", args.out, output_folder_problem(args.out)),
        ("--docs", args.docs, None if args.docs is None else output_file_problem(args.docs)),
    ]
    for flag, value, problem in rules:
        if problem is not None:
            raise UserError(f"{flag} {value!r}: {problem}")


def _docs_path(args: argparse.Namespace) -> Path | None:
    """Where RESULTS.md goes: --docs, else the checkout's docs/RESULTS.md (not with --quick), or nowhere."""
    if args.no_docs:
        return None
    if args.docs is not None:
        return Path(args.docs)
    if not args.quick:
        return _repo_docs()
    return None


def _given_counts(args: argparse.Namespace) -> dict[str, Any]:
    """The mission counts given on the command line (the others keep reproduce's defaults)."""
    return {
        name: value
        for name, value in (
            ("wide_trials", args.wide_trials),
            ("unseen_missions", args.unseen_missions),
            ("sweep_missions", args.sweep_missions),
        )
        if value is not None
    }


def run(args: argparse.Namespace) -> int:
    from sb3_coma.app.outputs import OutputInterrupted
    from sb3_coma.experiments.reproduce import reproduce

    set_threads(args.threads)
    envs = _env_names(args)
    _check_options(args)
    docs = _docs_path(args)
    counts = _given_counts(args)
    try:
        reproduce(
            out=args.out,
            env_names=envs,
            trials=args.trials,
            seed=args.seed,
            noise=args.noise,
            train=args.train,
            quick=args.quick,
            timesteps=args.timesteps,
            fusion=args.fusion,
            docs=docs,
            plots=not args.no_plots,
            ship=args.ship,
            generalisation=not args.no_generalisation,
            deterministic=args.deterministic,
            record=args.record and not args.quick,
            ablation=not args.no_ablation,
            costs=not args.no_costs,
            baselines_only=args.baselines_only,
            log=None if args.quiet else lambda line: print(line, flush=True),  # a log shows each step as it comes
            **counts,
        )
    except OutputInterrupted as exc:  # SIGTERM: the staged results were dropped, --out is as it was
        print(f"sb3-coma {NAME}: {exc}", file=sys.stderr)
        return 128 + exc.signum
    return 0
