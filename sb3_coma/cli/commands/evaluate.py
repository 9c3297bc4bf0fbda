"""``sb3-coma evaluate``: the paper's Table I, per-step curves, planning times and mission plots.

Example::

    sb3-coma evaluate --env env1,env2 --methods ag,lawnmower,random --model runs/env1/final.zip \
        --noise moderate --trials 10 --seed 0 --out results/

writes into ``--out``: ``table.md`` / ``table.csv`` (F1 and entropy at 33/67/100 % of the budget,
mean +- std over trials, best in bold), ``per_step.csv``, ``planning_time.md`` / ``.csv`` (mean
ms per UAV decision), ``curves_<env>.png`` (Figures 4/5), ``mission_<env>_<method>.png`` and
``.gif``, and ``training_reward.png`` (Figure 3) when ``--training-log`` is given. The files are
staged in a folder next to ``--out`` and moved into place together when all are written
(``sb3_coma.app.outputs``); files of other commands in ``--out`` are kept.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_coma.app.arguments import (
    add_out_argument,
    add_seed_argument,
    add_threads_argument,
    add_workers_argument,
    count_value,
)
from sb3_coma.cli import UserError, set_threads

if TYPE_CHECKING:
    from sb3_coma.app.methods import Method

# The evaluation, tables and figures are imported by the functions that use them, so that building
# the parser (``--help``) loads neither torch nor matplotlib (sb3_coma/cli/__init__.py).

NAME = "evaluate"
#: The evaluation front door (``resolve_method``, ``evaluate``) and the figures refuse a bad method,
#: option or log with a ``ValueError`` / ``TypeError``: this command's user errors, one line each.
USER_ERRORS = (ValueError, TypeError)
HELP = "evaluate trained models and baselines (AG, lawnmower, random) as in the paper's Table I"
DESCRIPTION = (
    "Fly N seeded missions per method (trial k uses env seed SEED+k, identical for every method), print "
    "F1 and entropy at 33/67/100 % of the budget as mean +- std, and write tables, per-step curves, "
    "planning times and plots to --out."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_workers_argument(parser)
    add_threads_argument(parser)
    parser.add_argument(
        "--env",
        default=None,
        help="map name(s), comma separated: env1, env2, env3 or gymnasium ids (default env3; "
        "with --map-path the image's name)",
    )
    parser.add_argument(
        "--methods",
        default="ag,lawnmower,random",
        help="comma-separated methods: baselines (ag, ag-k2, ag-k3, ag-comm, ag-central, lawnmower, oracle, "
        "random), a row of the generated tables naming a shipped model of the map (coma, coma[mean-cnn], "
        "coma[paper-actor] ...), shipped model names and/or model paths (default: ag,lawnmower,random; '' for "
        "models only)",
    )
    parser.add_argument(
        "--model",
        action="append",
        default=[],
        metavar="[LABEL=]PATH_OR_NAME",
        help="a trained COMA model: .zip path or shipped name (env1/env2/env3); repeatable; "
        "evaluated before the baselines, labelled LABEL (default 'coma')",
    )
    parser.add_argument(
        "--fusion",
        default=None,
        choices=("mean", "sendfuse"),
        help="fusion of received maps for models (default sendfuse; baselines always use mean)",
    )
    parser.add_argument("--noise", default="moderate", help="channel noise: none, moderate, loud (default moderate)")
    parser.add_argument(
        "--trials",
        type=count_value,
        default=None,
        help="missions per method (default 10; with --protocol the protocol's: paper 10, unseen 50, "
        "validation 4 per train scene)",
    )
    parser.add_argument(
        "--protocol",
        default=None,
        choices=("paper", "unseen", "validation"),
        help="the missions: 'paper' (split paper, Table I), 'unseen' (split test, random starts; reporting "
        "only) or 'validation' (train scenes, every scene equally, seeds from 1000: for choices); "
        "default: the env options as given (split paper)",
    )
    add_seed_argument(parser, default=None)
    parser.add_argument("--uavs", type=count_value, default=None, help="number of UAVs (env default 4)")
    parser.add_argument("--budget", type=count_value, default=None, help="decisions per UAV (env default 15)")
    parser.add_argument("--map-path", default=None, help="your own map image (with --valuable)")
    parser.add_argument("--valuable", default=None, help="rule that marks valuable pixels of --map-path")
    parser.add_argument("--n-envs", type=count_value, default=None, help="missions flown at once (default 10)")
    add_out_argument(parser, "results")
    parser.add_argument(
        "--training-log",
        action="append",
        default=[],
        metavar="[LABEL=]PATH",
        help="training log for the reward-vs-episode plot (metrics.csv, monitor CSV or TensorBoard dir); repeatable",
    )
    parser.add_argument(
        "--agents-per-episode",
        type=count_value,
        default=1,
        help="rows per mission in a VecMonitor CSV training log (n UAVs), averaged",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip all figures")
    parser.add_argument("--no-gif", action="store_true", help="skip the mission GIFs")


def _labelled(spec: str, default: str) -> tuple[str, str]:
    """``"label=path"`` -> (label, path); a bare path gets ``default`` (or its own name for baselines).
    A path that exists is a path, ``=`` and all (``app.methods.split_label``)."""
    from sb3_coma.app.methods import split_label

    label, value = split_label(spec)
    return label or default, value


def _methods(args: argparse.Namespace) -> list[tuple[str | None, str]]:
    """(label or None for the default, method) in table order: models first, then baselines."""

    out: list[tuple[str | None, str]] = []
    for k, spec in enumerate(args.model):
        label, value = _labelled(spec, "coma" if len(args.model) == 1 else f"coma{k + 1}")
        out.append((label, value))
    for name in [m.strip() for m in args.methods.split(",") if m.strip()]:
        out.append((None, name))
    labels = [lab or name for lab, name in out]
    if not out or len(set(labels)) != len(labels):  # one rule: at least one method, each label once
        problem = f"duplicate method labels {labels}" if out else "nothing to evaluate"
        raise UserError(f"{problem}: give --methods and/or --model, naming models with --model LABEL=PATH")
    return out


def _for_map(label: str | None, method: str, env_name: str) -> tuple[str | None, str]:
    """A row of the generated tables that names a shipped model of the map (``coma`` is the map's
    own model, ``coma[mean-cnn]`` its ``<map>-mean-cnn``: the labels ``reproduce`` gives them) ->
    (the row as label, that shipped model); any other method as given, so that every row of
    docs/RESULTS.md can be flown again by its name."""
    from sb3_coma.app.rows import shipped_name_of_label

    shipped = shipped_name_of_label(method, env_name)
    return (label or method, shipped) if shipped is not None else (label, method)


def _env_options(args: argparse.Namespace) -> dict[str, Any]:
    options: dict[str, Any] = {"noise": args.noise}
    if args.uavs is not None:
        options["n_uavs"] = args.uavs
    if args.budget is not None:
        options["budget"] = args.budget
    if args.map_path is not None:  # checked in _check_args: an image file
        options["map_path"] = args.map_path
    if args.valuable is not None:
        options["valuable"] = args.valuable
    return options


def _env_names(args: argparse.Namespace) -> list[str]:
    """The maps of --env, each once (default env3, or the --map-path image's name)."""
    from sb3_coma.app.config import map_list

    if args.env is None:
        return [Path(args.map_path).stem if args.map_path else "env3"]
    return map_list(args.env)


def _trials(args: argparse.Namespace, env_name: str) -> int:
    """Missions per method on ``env_name``: ``--trials``, else the protocol's count for that map."""
    from sb3_coma.common.evaluation import PROTOCOLS

    return int(args.trials) if args.trials is not None else PROTOCOLS[args.protocol].missions(env_name)


def _trials_text(args: argparse.Namespace, env_names: list[str]) -> str:
    counts = sorted({_trials(args, name) for name in env_names})
    return (
        f"{counts[0]} trials" if len(counts) == 1 else f"{'/'.join(map(str, counts))} trials ({', '.join(env_names)})"
    )


def _check_args(args: argparse.Namespace) -> None:
    """The counts, and the paths this command reads, prints and records, refused before any
    mission is flown (a name that is not valid text in the file system's encoding, a missing map
    image or training log), not in a traceback after them: one table, one raise."""
    from sb3_coma.app.config import path_name_problem

    rules: list[tuple[str, Any, str | None]] = [
        (flag, value, None if value >= low else f"must be >= {low}, got {value}")
        for flag, value, low in (
            ("--trials", 1 if args.trials is None else args.trials, 1),
            ("--seed", args.seed, 0),
            ("--agents-per-episode", args.agents_per_episode, 1),
            ("--n-envs", 1 if args.n_envs is None else args.n_envs, 1),
        )
    ]
    paths: list[tuple[str, Any, str, Callable[[Path], bool] | None]]
    paths = [("--map-path", args.map_path, "map image", Path.is_file)]
    paths += [("--model", _labelled(spec, "")[1], "", None) for spec in args.model]
    paths += [("--training-log", _labelled(spec, "")[1], "training log", Path.exists) for spec in args.training_log]
    for flag, value, what, exists in paths:
        problem = None if value is None else path_name_problem(value)
        if problem is None and value is not None and exists is not None and not exists(Path(value)):
            problem = f"{what} not found"
        rules.append((flag, value, problem))
    for flag, value, problem in rules:
        if problem is not None:
            raise UserError(f"{flag} {value!r}: {problem}" if isinstance(value, str) else f"{flag} {problem}")


#: What an evaluation writes into --out (``fnmatch`` patterns): how a folder written before
#: outputs carried a manifest tells this command's files from others' (those are kept).
OUTPUT_PATTERNS = ("table.*", "per_step.csv", "planning_time.*", "curves_*.png", "mission_*", "training_reward.png")
#: The files every evaluation writes into --out (the figures depend on the maps and methods).
OUTPUT_FILES = ("table.csv", "per_step.csv", "planning_time.csv", "table.md", "planning_time.md")


def _check_out(out: Path) -> None:
    """Refuse an --out the tables cannot be written into before any mission is flown, not after:
    a file (or a path below one), a read-only location, or a folder where a table file goes.
    Files already in --out are replaced, as every evaluation does."""
    from sb3_coma.app.config import output_folder_problem

    problem = output_folder_problem(out)  # its name, a file in its place, a read-only location
    if problem is None:
        problem = next((f"{out / name} is a folder" for name in OUTPUT_FILES if (out / name).is_dir()), None)
    if problem is not None:
        raise UserError(f"--out {str(out)!r} cannot take the results: {problem}")


def run(args: argparse.Namespace) -> int:
    from sb3_coma.app import evaluation as ev
    from sb3_coma.app.outputs import OutputInterrupted, staged_output
    from sb3_coma.common.evaluation import PROTOCOLS

    set_threads(args.threads)
    if args.seed is None:
        args.seed = PROTOCOLS[args.protocol].first_seed if args.protocol else 0
    if args.trials is None and not args.protocol:
        args.trials = ev.DEFAULT_TRIALS
    _check_args(args)
    methods = _methods(args)
    env_names = _env_names(args)
    options = _env_options(args)
    resolved: dict[str, ev.Method] = {}
    for env, (lab, name) in itertools.product(env_names, methods):  # fail on a typo before minutes of missions
        method = _for_map(lab, name, env)[1]
        resolved[method] = resolved.get(method) or ev.resolve_method(method)  # once: a shipped zip is hashed once
    logs = [_labelled(spec, Path(_labelled(spec, "")[1]).stem or "reward") for spec in args.training_log]
    target = Path(args.out)
    _check_out(target)
    try:  # everything goes into a staging folder that replaces --out once complete
        with staged_output(target, command=NAME, own=OUTPUT_PATTERNS) as out:
            written = _fly_and_write(args, methods, resolved, env_names, options, logs, out)
    except OutputInterrupted as exc:  # SIGTERM: nothing was moved into --out
        print(f"sb3-coma {NAME}: {exc}", file=sys.stderr)
        return 128 + exc.signum
    print("wrote " + ", ".join(str(target / p.relative_to(out)) for p in written))
    return 0


def _fly_and_write(
    args: argparse.Namespace,
    methods: list[tuple[str | None, str]],
    resolved: Mapping[str, Method],
    env_names: list[str],
    options: dict[str, Any],
    logs: list[tuple[str, str]],
    out: Path,
) -> list[Path]:
    """Fly every method on every map, write the tables and figures into ``out`` (the staging
    folder) and print the tables; the files written."""
    from sb3_coma.app import evaluation as ev
    from sb3_coma.stats import tables

    results: list[ev.EvaluationResult] = []
    for env_name in env_names:
        for label, method in (_for_map(lab, name, env_name) for lab, name in methods):
            print(
                f"evaluating {label or method} on {env_name} ({_trials(args, env_name)} trials, noise {args.noise}) ...",
                flush=True,
            )
            fusion = args.fusion if resolved[method].learned else None
            try:
                results.append(
                    ev.evaluate(
                        resolved[method],
                        env=env_name,
                        n_trials=_trials(args, env_name),
                        seed=args.seed,
                        fusion=fusion,
                        n_envs=args.n_envs,
                        label=label,
                        protocol=args.protocol,
                        **options,
                    )
                )
            except (ValueError, TypeError) as exc:
                raise UserError(f"{label or method} on {env_name}: {exc}") from None
    rows = tables.rows_for(results)
    written = [
        tables.write_table_csv(rows, out / "table.csv"),
        tables.write_per_step_csv(rows, out / "per_step.csv"),
        tables.write_planning_time_csv(rows, out / "planning_time.csv"),
    ]
    markdown = tables.table_markdown(rows)
    timing = tables.planning_time_markdown(rows)
    (out / "table.md").write_text(
        f"F1-score and entropy at 33/67/100 % of the budget, mean ± std over {_trials_text(args, env_names)} "
        f"(env seeds from {args.seed}), noise {args.noise}"
        f"{f', protocol {args.protocol}' if args.protocol else ''}; best in bold.\n\n{markdown}\n"
        f"Team metrics (each UAV's own map):\n\n{tables.table_markdown(rows, metrics='team')}"
    )
    (out / "planning_time.md").write_text(timing)
    written += [out / "table.md", out / "planning_time.md"]
    if not args.no_plots:
        written += _plots(results, env_names, logs, args, out)
    print()
    print(markdown)
    print("Planning time (wall time of predict per UAV decision):")
    print(timing)
    return written


def _plots(
    results: list[Any], env_names: list[str], logs: list[tuple[str, str]], args: argparse.Namespace, out: Path
) -> list[Path]:
    """The curves, mission pictures (and GIFs) of each map and the training-reward figure."""
    from sb3_coma.experiments import plots

    written = []
    for env_name in env_names:
        group = [r for r in results if r.env == env_name]
        written.append(plots.plot_metric_curves(group, out / f"curves_{env_name}.png"))
        for r in group:
            stem = f"mission_{env_name}_{_safe(r.method)}"
            written.append(plots.plot_mission(r, out / f"{stem}.png"))
            if not args.no_gif:
                written.append(plots.animate_mission(r, out / f"{stem}.gif"))
    if logs:  # a log without episodes is a ValueError: one line (USER_ERRORS)
        written.append(
            plots.plot_training_reward(
                dict(logs), out / "training_reward.png", agents_per_episode=args.agents_per_episode
            )
        )
    return written


def _safe(label: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label)
