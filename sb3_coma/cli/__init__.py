"""The ``sb3-coma`` command line.

Each sub-command lives in its own module under :mod:`sb3_coma.cli.commands` and exposes
``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args) -> int``; modules are discovered
at start-up, so adding a command never touches this file. Errors that users can fix (bad options,
missing files) are printed as one line and exit with status 2, never as a traceback; a full disk
while saving is one line with status 1.

Building the parser imports the command modules, so they (and this file) import at module level
only what their options need: ``sb3-coma --help`` and ``sb3-coma VERB --help`` load neither
torch nor rl_zoo3, onnx or matplotlib (seconds of start-up), and each command imports its
implementation inside ``run`` (tests/test_cli_lazy.py).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import linecache
import pkgutil
import sys
from types import ModuleType
from typing import NoReturn

from sb3_coma.cli import commands


class UserError(Exception):
    """An error the user can fix; printed without a traceback."""


class _OneLineParser(argparse.ArgumentParser):
    """argparse, with a bad option or value as one stderr line (``sb3-coma demo: error: argument
    --seed: must be ...``, exit status 2), as every other user error of the command line, instead of
    the usage block first (``--help`` prints it)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _command_modules() -> list[ModuleType]:
    mods = []
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda i: i.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{commands.__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    return mods


def user_errors() -> tuple[type[BaseException], ...]:
    """Exception types that mean "the user gave a bad value": printed as one line, exit 2.

    A function, not a constant, because the classes live in modules that import torch: they are
    looked up only once a command has failed, never for ``--help``. A command whose front door
    reports every bad input as a plain ``ValueError`` names it in its module's ``USER_ERRORS``: the
    one handler here then prints it as one line, instead of each command re-wrapping it."""
    from sb3_coma.app.config import TrainingError
    from sb3_coma.app.outputs import OutputFolderError
    from sb3_coma.app.pretrained import PretrainedError
    from sb3_coma.common.checkpoints import CheckpointError
    from sb3_coma.common.shipped import ShippedFileError
    from sb3_coma.sendfuse import SenDFuseWeightsError
    from uav_ipp import ConfigError, MapError

    return (
        UserError,
        FileNotFoundError,
        FloatingPointError,
        ConfigError,
        MapError,
        TrainingError,
        CheckpointError,
        SenDFuseWeightsError,
        ShippedFileError,
        PretrainedError,
        OutputFolderError,
    )


def _raised_by_our_checks(exc: BaseException) -> bool:
    """Whether a plain ``ValueError`` / ``TypeError`` (a command's ``USER_ERRORS``) comes from a
    ``raise`` statement of ours (sb3_coma or uav_ipp code) rather than from inside a dependency or
    a C extension called by our code: the first is a message for the user (one line, exit 2), the
    second a failure whose traceback must be seen."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    if tb is None:
        return False
    module = str(tb.tb_frame.f_globals.get("__name__", ""))
    line = linecache.getline(tb.tb_frame.f_code.co_filename, tb.tb_lineno).strip()
    return module.split(".")[0] in ("sb3_coma", "uav_ipp") and line.startswith("raise ")


def set_threads(threads: int) -> None:
    """``--threads``: torch's CPU thread count for this command (must be >= 1)."""
    if not isinstance(threads, int) or threads < 1:
        raise UserError(f"--threads must be an integer >= 1, got {threads!r}")
    import torch  # here, not at module level: the parser alone must not load torch

    torch.set_num_threads(threads)


def build_parser() -> tuple[argparse.ArgumentParser, dict[str, ModuleType]]:
    parser = _OneLineParser(prog="sb3-coma", description="COMA + SenDFuse + CBAM for multi-UAV IPP")
    parser.add_argument("--version", action="version", version=f"%(prog)s {importlib.metadata.version('sb3-coma')}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    table = {}
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP))
        mod.add_arguments(p)
        table[mod.NAME] = mod
    return parser, table


def main(argv: list[str] | None = None) -> int:
    parser, table = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # a bad option or value (its line printed): 2; --help and --version go on
        if exc.code == 2:
            return 2
        raise
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return _run(table[args.command], args)
    except Exception as exc:  # the user-error classes are imported only now that one may be needed
        generic = getattr(table[args.command], "USER_ERRORS", ())
        if not (isinstance(exc, user_errors()) or (isinstance(exc, generic) and _raised_by_our_checks(exc))):
            raise
        print(f"sb3-coma {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sb3-coma {args.command}: interrupted", file=sys.stderr)
        return 130


def _run(command: ModuleType, args: argparse.Namespace) -> int:
    """Run one command inside its evaluation pool; a full disk is one line with exit status 1."""
    from sb3_coma.app.evaluation import parallel_evaluation
    from sb3_coma.common.checkpoints import DiskFullError

    try:
        with parallel_evaluation(getattr(args, "eval_workers", 1)):
            return int(command.run(args) or 0)
    except DiskFullError as exc:  # the machine, not the input: one line, exit 1
        print(f"sb3-coma {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    # Re-import under the package name so commands and this entry point share one UserError class.
    from sb3_coma.cli import main as _package_main

    sys.exit(_package_main())
