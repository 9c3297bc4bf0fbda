"""``sb3-coma export``: a trained model's actor and fusion network as ONNX files, for on-board use."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from sb3_coma.cli import UserError
from uav_ipp.config import count_value

if TYPE_CHECKING:  # the export imports torch and onnx: run() imports it, --help never does
    from sb3_coma.app.export import ModelSource
    from sb3_coma.coma import COMA

NAME = "export"
#: Every bad input of the export is a ``ValueError`` subclass (``ExportError``, ``PretrainedError``,
#: ``CheckpointError``, ``OutputFolderError``), whose module loads onnx: this command's user errors.
USER_ERRORS = (ValueError,)
HELP = "export a trained model's actor and its fusion network to ONNX (+ a JSON of inputs and env options)"
DESCRIPTION = (
    "Write actor.onnx (features extractor + action head + gain prior, masked logits and the argmax action), "
    "fusion.onnx (SenDFuse or the mean, ending in the 8th local channel the actor reads) and export.json "
    "(input and output names, shapes, dtypes, and the env options the model was trained with) into --out. "
    "Both files are checked against PyTorch with onnxruntime before the command returns. See docs/deployment.md."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model",
        required=True,
        metavar="NAME_OR_PATH",
        help="a shipped model name (env1, env2, env3, ...) or the path of a COMA model .zip",
    )
    parser.add_argument(
        "--out",
        required=True,
        metavar="DIR",
        help="folder to write the files into (created; replaced as a whole once all files are written and "
        "checked, other files in it kept)",
    )
    parser.add_argument(
        "--fusion",
        default=None,
        choices=("sendfuse", "mean"),
        help="fusion to export (default: the one the model was trained with, from models.json or "
        "the run folder's config.yml; needed for a bare .zip)",
    )
    parser.add_argument(
        "--opset",
        type=count_value,
        default=None,
        help="ONNX opset (default 17; from 17 to the newest onnx and torch write)",
    )
    parser.add_argument(
        "--no-verify", action="store_true", help="skip the onnxruntime-vs-PyTorch check of the written files"
    )


def _load(source: ModelSource) -> COMA:
    """Load the model the source names: a shipped one after its checksum, a zip after validation."""
    from sb3_coma.app.pretrained import load_pretrained
    from sb3_coma.app.runs import load_checkpoint

    # corrupt, truncated, another algorithm: a PretrainedError / CheckpointError, one line (USER_ERRORS)
    if source.shipped is not None:
        return load_pretrained(source.given)
    return load_checkpoint(source.path, env=None, device="cpu")


def run(args: argparse.Namespace) -> int:
    from sb3_coma.app.export import (
        ACTOR_FILE,
        FUSION_FILE,
        METADATA_FILE,
        OPSET,
        check_fusion_matches,
        check_opset,
        check_out_dir,
        export_onnx,
        resolve_model_source,
        settings_of_source,
    )
    from sb3_coma.app.outputs import OutputInterrupted, staged_output
    from sb3_coma.common.checkpoints import validate_checkpoint

    # Every check that needs no model comes first: a bad --opset, --model or --out costs nothing.
    opset = check_opset(OPSET if args.opset is None else args.opset, f"--opset {args.opset}")
    source = resolve_model_source(args.model)
    out = check_out_dir(args.out)
    validate_checkpoint(source.path)  # CheckpointError (a user error): empty, truncated, not COMA
    settings = settings_of_source(source)
    check_fusion_matches(args.fusion, settings, f"--fusion {args.fusion}")
    fusion = args.fusion or (settings or {}).get("fusion")
    if fusion is None:
        raise UserError(
            f"cannot tell which fusion model {args.model!r} was trained with (no models.json entry, no "
            f"run config.yml next to it): pass --fusion sendfuse or --fusion mean"
        )
    model = _load(source)
    try:  # the files go into a staging folder that replaces --out once all are written and checked
        with staged_output(out, command=NAME, own=(ACTOR_FILE, FUSION_FILE, METADATA_FILE)) as staging:
            paths = export_onnx(
                model, staging, fusion=fusion, settings=settings, source=source, opset=opset, verify=not args.no_verify
            )
    except OutputInterrupted as exc:  # SIGTERM: nothing was moved into --out
        print(f"sb3-coma {NAME}: {exc}", file=sys.stderr)
        return 128 + exc.signum
    _report({key: out / path.relative_to(staging) for key, path in paths.items()}, fusion)
    return 0


def _report(paths: dict[str, Path], fusion: str) -> None:
    """What was written, what the actor reads, what the model was trained on, how well it matched."""
    meta = json.loads(paths["metadata"].read_text())
    actor_inputs = ", ".join(f"{i['name']} {i['shape']}" for i in meta["actor"]["inputs"])
    fusion_inputs = ", ".join(f"{i['name']} {i['shape']}" for i in meta["fusion"]["inputs"])
    print(f"actor:  {paths['actor']}  ({actor_inputs} -> logits, action)")
    print(f"fusion: {paths['fusion']}  ({fusion}; {fusion_inputs} -> fused, fused_channel)")
    print(f"json:   {paths['metadata']}")
    env = meta["env"]
    options = ", ".join(f"{k}={v}" for k, v in env["options"].items()) or "defaults"
    print(f"trained on {env['name']} with {options} (from {env['from']})")
    check = meta["check"]
    if check.get("done"):
        print(
            f"checked with onnxruntime: max |ONNX - PyTorch| actor {check['actor_max_abs_diff']:.2g}, "
            f"fusion {check['fusion_max_abs_diff']:.2g}"
        )


if __name__ == "__main__":  # pragma: no cover
    from sb3_coma.cli import main  # the package's CLI (this file runs as __main__)

    sys.exit(main([NAME, *sys.argv[1:]]))
