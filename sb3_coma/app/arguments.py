"""The options that many commands and studies share, each defined once.

``--threads``, ``--workers``, ``--missions``, ``--env``, ``--seed`` and ``--out`` mean the same
thing in ``sb3-coma evaluate``, ``reproduce``, ``noise-sweep``, ``ablation``, ``ag-weighting`` and
the studies' own ``main()``: one flag, one help text, one rule for the default, written here so
that a change (a clearer help, a new check) reaches every parser at once. It lives in the
application layer because both the command line (layer 4) and the studies (layer 3) build
parsers; it imports only ``argparse``, ``yaml`` (``--set`` values), the integer types of ``uav_ipp.config`` (the world's rules for a user's numbers)
and the world's default map name, none of which loads Stable-Baselines3 or torch, so
``sb3-coma --help`` stays quick (tests/test_cli_lazy.py).
"""

from __future__ import annotations

import argparse

import yaml

from uav_ipp.config import count_value, seed_value


def set_value(text: str) -> tuple[str, object]:
    """argparse type of ``--set KEY=VALUE``: the value read as YAML (``10``, ``true``, ``[1, 2]``),
    kept as text where it is not YAML, so a config key and a constructor argument take one spelling."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        parsed = yaml.safe_load(value) if value.strip() else None
    except yaml.YAMLError:
        parsed = value
    return key.strip(), parsed


#: ``--env`` of the commands that fly several maps: all three families, comma separated.
ALL_MAPS = "env1,env2,env3"


def default_map() -> str:
    """The world's default map (``uav_ipp.DEFAULT_MAP``), for the options' defaults and help; it
    lives in ``uav_ipp.config``, which imports neither Stable-Baselines3 nor torch, so ``--help``
    stays quick (tests/test_cli_lazy.py)."""
    from uav_ipp import DEFAULT_MAP

    return DEFAULT_MAP


def add_threads_argument(parser: argparse.ArgumentParser) -> None:
    """``--threads``: torch's CPU threads, 1 unless asked (checked by ``sb3_coma.cli.set_threads``)."""
    parser.add_argument(
        "--threads",
        type=count_value,
        default=1,
        help="torch CPU threads (default 1: as fast as 2 for these small networks; float reductions differ "
        "with the thread count, so results are reproducible for a fixed count)",
    )


def workers_value(text: str) -> int | str:
    """``--workers``: ``auto`` or an integer >= 1 (argparse turns the error into one line)."""
    if text == "auto":
        return text
    try:
        return count_value(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"must be auto or an integer >= 1, got {text!r}") from None


def add_workers_argument(parser: argparse.ArgumentParser) -> None:
    """``--workers`` of every command that flies evaluations (``sb3_coma.app.evaluation.parallel_evaluation``)."""
    parser.add_argument(
        "--workers",
        dest="eval_workers",
        type=workers_value,
        default="auto",
        help="processes that fly the evaluation missions (default auto: one per core); results do not depend on it",
    )


def add_env_argument(parser: argparse.ArgumentParser, several: bool = False) -> None:
    """``--env``: one map (default the world's default map) or, for a command that flies
    ``several``, comma-separated maps (default :data:`ALL_MAPS`)."""
    if several:
        parser.add_argument("--env", default=ALL_MAPS, help=f"comma-separated maps (default {ALL_MAPS})")
        return
    parser.add_argument(
        "--env",
        default=default_map(),
        help=f"map: env1, env2, env3 or a gymnasium id (default {default_map()})",
    )


def add_missions_argument(
    parser: argparse.ArgumentParser, default: int | None, per: str, default_text: str | None = None
) -> None:
    """``--missions``: how many missions each ``per`` flies; ``default`` ``None`` means the
    protocol's count (or ``default_text``, where the command decides it otherwise)."""
    shown = default_text or ("the protocol's" if default is None else str(default))
    parser.add_argument("--missions", type=count_value, default=default, help=f"missions per {per} (default {shown})")


def add_seed_argument(parser: argparse.ArgumentParser, default: int | None = 0, note: str = "") -> None:
    """``--seed``: the first env seed of the missions (mission k flies env seed SEED+k, the same for
    every method); ``default`` ``None`` means the protocol's first seed."""
    shown = "the protocol's: 0, validation 1000" if default is None else str(default)
    parser.add_argument(
        "--seed",
        type=seed_value,
        default=default,
        help=f"first env seed: mission k flies env seed SEED+k, the same for every method (default {shown}{note})",
    )


def add_out_argument(parser: argparse.ArgumentParser, default: str) -> None:
    """``--out``: the output folder (written through ``sb3_coma.app.outputs.staged_output`` by the
    commands: replaced once complete, other commands' files kept)."""
    parser.add_argument("--out", default=default, help=f"output folder (default {default})")
