"""``sb3-coma eval-sendfuse``: fused-map quality of SenDFuse vs the naive mean on held-out maps."""

from __future__ import annotations

import argparse
import sys

from sb3_coma.app.arguments import add_missions_argument, add_seed_argument, default_map
from sb3_coma.cli import UserError
from uav_ipp.config import count_value

NAME = "eval-sendfuse"
HELP = "compare SenDFuse with the naive mean fusion (MSE vs the noise-free fused map) on held-out maps"
DESCRIPTION = (
    "Fly random missions in lockstep with and without channel noise and report, per noise preset, the "
    "mean squared error of the fused map against the clean fused map (the average of the noise-free "
    "received maps) for the naive mean and for SenDFuse, on the comm grid and on the 11 x 11 lattice "
    "the actor sees. env2 and env3 are never used in pre-training."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--env", default=default_map(), help=f"map (default {default_map()}), or a label with --map-path"
    )
    parser.add_argument("--map-path", default=None, help="your own image as the ground truth (with --valuable)")
    parser.add_argument(
        "--valuable", default=None, help="rule that marks valuable pixels of --map-path (e.g. hottest:0.3)"
    )
    add_missions_argument(parser, 20, "noise preset")
    add_seed_argument(parser)
    parser.add_argument("--uavs", type=count_value, default=4, help="number of UAVs (default 4)")
    parser.add_argument("--budget", type=count_value, default=15, help="decisions per UAV (default 15)")
    parser.add_argument(
        "--noise",
        nargs="+",
        default=None,
        metavar="PRESET",
        help="noise presets to score (default: none moderate loud)",
    )
    parser.add_argument("--weights", default=None, help="SenDFuse weights (default: the shipped file)")
    parser.add_argument("--markdown", action="store_true", help="print the table as Markdown")


def run(args: argparse.Namespace) -> int:
    # here, not at module level: the parser alone must not load torch
    import torch
    from tqdm.auto import tqdm

    from sb3_coma.sendfuse.data import NOISE_PRESETS
    from sb3_coma.sendfuse.quality import evaluate_quality, format_table
    from sb3_coma.sendfuse.weights import load_weights

    presets = tuple(args.noise) if args.noise else NOISE_PRESETS
    bad = [p for p in presets if p not in NOISE_PRESETS]
    rules = (  # one table, one raise: (flag, what was given, allowed)
        ("--missions", args.missions, args.missions >= 1, ">= 1"),
        ("--noise", " ".join(bad), not bad, f"each one of {' '.join(NOISE_PRESETS)}"),
        (
            "--valuable",
            args.valuable,
            args.valuable is None or args.map_path is not None,
            "given with --map-path (the built-in maps have their own rules)",
        ),
    )
    for flag, given, ok, allowed in rules:
        if not ok:
            raise UserError(f"{flag} {given}: must be {allowed}")
    options = {}
    if args.map_path is not None:
        options = {"map_path": args.map_path, "valuable": args.valuable}
    network = load_weights(args.weights)
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    label = args.map_path or args.env
    with tqdm(
        total=args.missions * len(presets),
        desc=f"eval {label}",
        unit="mission",
        file=sys.stderr,
        leave=False,
        dynamic_ncols=True,
    ) as bar:
        rows = evaluate_quality(
            network,
            args.env,
            missions=args.missions,
            seed=args.seed,
            presets=presets,
            n_uavs=args.uavs,
            budget=args.budget,
            progress=bar.update,
            **options,
        )
    source = args.weights or "shipped weights"
    print(
        f"SenDFuse fused-map quality on {label}: {args.uavs} UAVs, budget {args.budget}, {args.missions} "
        f"missions per preset, seed {args.seed}, {source}"
    )
    print("MSE against the clean fused map (mean of the noise-free received maps); ratio < 1: SenDFuse better")
    print(format_table(rows, markdown=args.markdown))
    return 0


if __name__ == "__main__":  # pragma: no cover
    from sb3_coma.cli import main

    sys.exit(main([NAME, *sys.argv[1:]]))
