"""``sb3-coma noise-sweep``: AG and each trained ablation arm over the channel's noise settings.

Examples::

    sb3-coma noise-sweep                              # env3, AG + the shipped ablation arms, 20 missions/setting
    sb3-coma noise-sweep --arms ag --missions 50      # AG alone, more missions
    sb3-coma noise-sweep --quick --out /tmp/sweep     # smoke run: 4 settings x 2 decoders, 2 missions

Sweeps sigma {0, 0.02, 0.06, 0.1, 0.2, 0.3}, a_low {1, 0.8, 0.6, 0.4} and the drop probability
{0, 0.3} one axis at a time around the moderate preset (``--grid``: every combination), each
under the soft and the threshold decoder, on the same missions (split ``test``, random starts by
default). Writes ``noise_sweep.md`` / ``.csv`` (global and team F1 / entropy at 100 %, mean ±
standard error, and each arm minus AG on both entropies, paired) and ``noise_sweep.png``
(entropy vs each axis per arm).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_coma.app.arguments import (
    add_env_argument,
    add_missions_argument,
    add_out_argument,
    add_seed_argument,
    add_threads_argument,
    add_workers_argument,
    count_value,
)
from sb3_coma.cli import UserError, set_threads

if TYPE_CHECKING:  # the sweep imports torch and matplotlib: the functions import it, --help never does
    from sb3_coma.app.methods import Method

NAME = "noise-sweep"
#: The sweep refuses a bad arm (unknown, of another map, given twice) or option with a
#: ``ValueError``: this command's user errors, one line each.
USER_ERRORS = (ValueError,)
HELP = "AG and the trained ablation arms over sigma, a_low, drop probability and both decoders (shared missions)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_workers_argument(parser)
    add_threads_argument(parser)
    add_env_argument(parser)
    parser.add_argument(
        "--arms",
        default=None,
        help="comma-separated arms: 'ag' and/or shipped model names (default: ag and every shipped "
        "model of the map that is an ablation arm or the map's own model)",
    )
    add_missions_argument(parser, None, "setting", default_text="20; --quick: 2")
    add_seed_argument(parser)
    parser.add_argument(
        "--split",
        default="test",
        choices=("paper", "train", "test"),
        help="where the missions come from (default test, with random starts)",
    )
    parser.add_argument("--budget", type=count_value, default=None, help="decisions per UAV (env default 15)")
    parser.add_argument("--grid", action="store_true", help="the full grid (96 settings) instead of one axis at a time")
    parser.add_argument("--quick", action="store_true", help="smoke run: a few settings, 2 missions")
    add_out_argument(parser, "results/noise_sweep")
    parser.add_argument("--no-plots", action="store_true", help="skip the figure")


def default_arms(env: str) -> list[str]:
    """AG plus the shipped models of ``env`` that are ablation arms or the map's own model."""
    from sb3_coma.app.pretrained import read_manifest

    try:
        models = read_manifest()["models"]
    except (ImportError, ValueError):
        return ["ag"]
    return ["ag"] + [
        name
        for name, info in models.items()
        if info.get("env") == env
        and str(info.get("algo", "coma")) == "coma"
        and ("ablation_arm" in info or name == env)
    ]


def _arm(name: str, env: str) -> Method:
    """The arm ``name`` names: AG, or a shipped model labelled as its ablation arm."""
    from sb3_coma.app.methods import Method
    from sb3_coma.app.pretrained import load_pretrained
    from sb3_coma.experiments import ablation as ab

    if name.strip().lower() in ("ag", "adaptive_gain", "adaptive-gain"):
        return Method("ag", "ag")
    model = load_pretrained(name)
    info = model.pretrained_info
    variant = tuple(info.get("ablation_arm") or (info.get("fusion", "sendfuse"), info.get("extractor", "cbam")))
    label = ab.LABELS.get(variant, name)
    return Method(label, model, kind="coma", fusion=info.get("fusion"), deterministic=info.get("deterministic", True))


def _check_options(args: argparse.Namespace, missions: int) -> None:
    """The counts, and an --out the table cannot be written into, refused before the sweep, not
    after it (the arms themselves are the sweep's own rules: ``run_noise_sweep``)."""
    from sb3_coma.app.config import output_folder_problem

    rules = (
        ("--missions", missions, None if missions >= 1 else "must be >= 1"),
        ("--seed", args.seed, None if args.seed >= 0 else "must be >= 0"),
        ("--out", args.out, output_folder_problem(args.out)),
    )
    for flag, value, problem in rules:
        if problem is not None:
            raise UserError(f"{flag} {value!r}: {problem}")


def run(args: argparse.Namespace) -> int:
    from sb3_coma.app.outputs import OutputInterrupted, staged_output
    from sb3_coma.experiments.report import sweep_sentence

    set_threads(args.threads)
    missions = args.missions if args.missions is not None else (2 if args.quick else 20)
    _check_options(args, missions)
    names = [a.strip() for a in args.arms.split(",") if a.strip()] if args.arms is not None else default_arms(args.env)
    arms = [_arm(n, args.env) for n in names]  # none: the sweep's own "no arms to sweep"
    options = {} if args.budget is None else {"budget": args.budget}
    target = Path(args.out)
    try:  # the sweep writes into a staging folder that replaces --out once complete
        with staged_output(target, command=NAME, own=OUTPUT_PATTERNS) as out:
            result, written = _sweep(args, arms, missions, options, out)
    except OutputInterrupted as exc:  # SIGTERM: nothing was moved into --out
        print(f"sb3-coma {NAME}: {exc}", file=sys.stderr)
        return 128 + exc.signum
    print()
    print(result.markdown())
    print(sweep_sentence(result))
    for label, why in result.skipped.items():
        print(f"skipped {label}: {why}")
    print("wrote " + ", ".join(str(target / p.relative_to(out)) for p in written))
    return 0


#: What the sweep writes into --out (``fnmatch`` patterns), for a folder written before outputs
#: carried a manifest.
OUTPUT_PATTERNS = ("noise_sweep.*",)


def _sweep(
    args: argparse.Namespace, arms: list[Method], missions: int, options: dict[str, Any], out: Path
) -> tuple[Any, list[Path]]:
    """Fly the sweep and write its table, CSV and figure into ``out`` (the staging folder)."""
    from sb3_coma.experiments import plots
    from sb3_coma.experiments.noise_sweep import run_noise_sweep
    from sb3_coma.experiments.report import sweep_sentence

    result = run_noise_sweep(
        arms,
        env=args.env,
        n_missions=missions,
        seed=args.seed,
        quick=args.quick,
        grid=args.grid,
        split=args.split,
        log=lambda m: print(m, flush=True),
        **options,
    )
    (out / "noise_sweep.md").write_text(f"{sweep_sentence(result)}\n\n{result.markdown()}")
    written = [out / "noise_sweep.md", result.write_csv(out / "noise_sweep.csv")]
    if not args.no_plots and result.results:
        written.append(plots.plot_noise_sweep(result, out / "noise_sweep.png"))
    return result, written
