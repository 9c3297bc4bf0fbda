"""Sub-commands of ``sb3-coma``: one module each (``NAME``, ``HELP``, ``add_arguments``, ``run``)."""

from __future__ import annotations

import argparse


def default_map() -> str:
    """The world's default map (``uav_ipp.DEFAULT_MAP``), for the options' defaults and help; it
    lives in ``uav_ipp.config``, which imports neither Stable-Baselines3 nor torch, so ``--help``
    stays quick (tests/test_cli_lazy.py)."""
    from uav_ipp import DEFAULT_MAP

    return DEFAULT_MAP


def workers_value(text: str) -> int | str:
    """``--workers``: ``auto`` or an integer >= 1 (argparse turns the ValueError into one line)."""
    if text == "auto":
        return text
    value = int(text)
    if value < 1:
        raise ValueError(text)
    return value


def add_workers_argument(parser: argparse.ArgumentParser) -> None:
    """``--workers`` of every command that flies evaluations (``sb3_coma.app.evaluation.parallel_evaluation``)."""
    parser.add_argument(
        "--workers",
        dest="eval_workers",
        type=workers_value,
        default="auto",
        help="processes that fly the evaluation missions (default auto: one per core); results do not depend on it",
    )
