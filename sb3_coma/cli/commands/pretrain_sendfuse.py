"""``sb3-coma pretrain-sendfuse``: pre-train SenDFuse on env-generated pairs and write its weights.

With the defaults this reproduces the weights shipped in ``sb3_coma/pretrained/`` (same seed and
thread count -> the same file, byte for byte): a few minutes on one CPU core.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
from pathlib import Path
from types import SimpleNamespace

from sb3_coma.app.arguments import add_threads_argument
from sb3_coma.cli import UserError
from uav_ipp.config import count_value, seed_value

NAME = "pretrain-sendfuse"
HELP = "pre-train the SenDFuse denoising autoencoder on env-generated data and save its weights"
DESCRIPTION = (
    "Fly random missions twice in lockstep (with and without channel noise) on random synthetic maps, "
    "train SenDFuse as a one-to-one denoising autoencoder (MSE + MAE + (1 - SSIM)), calibrate its "
    "fusion on pre-training maps, and write a safetensors file with the run's provenance. env2 and "
    "env3 are never used (they are held out for `sb3-coma eval-sendfuse`)."
)

#: ``sb3_coma.sendfuse.pretrain.PretrainConfig``'s defaults of the options below (the shipped
#: weights' run), written out because that module imports torch and ``--help`` must not;
#: tests/test_cli_lazy.py checks that they are the dataclass's own.
PRETRAIN_DEFAULTS = SimpleNamespace(samples=12_000, epochs=3, batch=32, lr=2e-3, seed=0, calibration_fusions=240)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    d = PRETRAIN_DEFAULTS
    parser.add_argument(
        "--samples", type=count_value, default=d.samples, help=f"training pairs to generate (default {d.samples})"
    )
    parser.add_argument(
        "--epochs", type=count_value, default=d.epochs, help=f"passes over the pairs (default {d.epochs})"
    )
    parser.add_argument("--batch", type=count_value, default=d.batch, help=f"batch size (default {d.batch})")
    parser.add_argument("--lr", type=float, default=d.lr, help=f"Adam learning rate, cosine-decayed (default {d.lr:g})")
    parser.add_argument(
        "--seed", type=seed_value, default=d.seed, help=f"seed of data, initialisation and batches (default {d.seed})"
    )
    add_threads_argument(parser)
    parser.add_argument("--no-calibrate", action="store_true", help="skip the fusion-scale calibration")
    parser.add_argument(
        "--calibration-fusions",
        type=count_value,
        default=d.calibration_fusions,
        help=f"fusions flown to calibrate the fusion scale (default {d.calibration_fusions})",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="output .safetensors (default: sendfuse_r44.safetensors in the current folder; "
        "never the package's shipped file)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def canonical_command(args: argparse.Namespace) -> str:
    """The command that reproduces the file (options that change the weights, not --out)."""
    parts = [
        "sb3-coma",
        NAME,
        f"--samples {args.samples}",
        f"--epochs {args.epochs}",
        f"--batch {args.batch}",
        f"--lr {args.lr:g}",
        f"--seed {args.seed}",
        f"--threads {args.threads}",
    ]
    if args.no_calibrate:
        parts.append("--no-calibrate")
    else:
        parts.append(f"--calibration-fusions {args.calibration_fusions}")
    return " ".join(parts)


def run(args: argparse.Namespace) -> int:
    # here, not at module level: the parser alone must not load torch
    import numpy as np
    import torch

    from sb3_coma.sendfuse.pretrain import PretrainConfig, pretrain
    from sb3_coma.sendfuse.weights import default_weights_path, save_weights

    try:
        config = PretrainConfig(
            samples=args.samples,
            epochs=args.epochs,
            batch=args.batch,
            lr=args.lr,
            seed=args.seed,
            threads=args.threads,
            calibrate=not args.no_calibrate,
            calibration_fusions=args.calibration_fusions,
        )
        config.validate()
    except ValueError as exc:
        raise UserError(str(exc)) from None
    out = Path(args.out) if args.out else Path(default_weights_path(config.grid_size).name)
    for refused, why in (  # one rule: a file of the user's, not a folder and not the shipped one
        (
            out.resolve().parent == default_weights_path(config.grid_size).resolve().parent,
            "is inside the installed package; write the weights elsewhere "
            "(shipped weights change only through a release, with their SHA-256 recorded)",
        ),
        (out.is_dir(), "is a directory; give a file name such as sendfuse.safetensors"),
    ):
        if refused:
            raise UserError(f"--out {str(out)!r} {why}")
    command = canonical_command(args)
    print(f"{command}\n-> {out}", flush=True)
    result = pretrain(config, progress=not args.quiet)
    final = result.history[-1]
    if not math.isfinite(final.total):
        raise UserError("training diverged (non-finite loss); try a smaller --lr")
    metadata = {
        "command": command,
        "seed": str(config.seed),
        "samples": str(config.samples),
        "epochs": str(config.epochs),
        "batch": str(config.batch),
        "lr": f"{config.lr:g}",
        "threads": str(config.threads),
        "data": result.data_summary,
        "final_loss": f"{final.total:.6g}",
        "final_loss_terms": f"mse {final.mse:.6g}, mae {final.mae:.6g}, 1-ssim {final.ssim:.6g}",
        "val_mse": f"{final.val_mse:.6g}",
        "val_identity_mse": f"{result.identity_val_mse:.6g}",
        "loss_curve": "; ".join(f"{h.epoch}: {h.total:.5g}" for h in result.history),
        "fusion_scale": f"{result.scale:g}",
        "torch": torch.__version__,
        "numpy": np.__version__,
        "python": platform.python_version(),
    }
    path = save_weights(result.model, out, metadata)  # sorted header: identical runs, identical bytes
    print(
        f"final loss {final.total:.4f} (mse {final.mse:.3g}, mae {final.mae:.3g}, 1-ssim {final.ssim:.3g}); "
        f"validation MSE {final.val_mse:.3g} vs noisy input {result.identity_val_mse:.3g}; "
        f"fusion scale {result.scale:g}"
    )
    print(
        f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB, {result.model.num_parameters()} parameters) "
        f"in {result.seconds:.0f}s",
        flush=True,
    )
    return 0


if __name__ == "__main__":  # pragma: no cover
    from sb3_coma.cli import main

    sys.exit(main([NAME, *sys.argv[1:]]))
