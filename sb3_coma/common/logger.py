"""The logger of a ``learn()`` without TensorBoard, for every algorithm the package ships.

SB3's ``configure_logger`` gives a run without ``tensorboard_log`` (and without a logger of the
caller's) a stdout-only logger, but first makes an empty ``SB3-<timestamp>`` folder in the system
temp dir, at every ``learn()``, whatever ``verbose`` is. :func:`folderless_logger` is the same
logger without a folder: COMA builds it at every ``learn()`` (``COMA._setup_learn``), IPPO and
MAPPO (SB3's own ``PPO``) get it once from their factories (:func:`use_folderless_logger`).
"""

from __future__ import annotations

import sys
from typing import Any, TextIO, TypeVar, cast

from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import HumanOutputFormat, Logger

Algorithm = TypeVar("Algorithm", bound=BaseAlgorithm)


class _Stdout:
    """Whatever ``sys.stdout`` is when a line is written (a redirect or pytest's capture made
    after the logger was built included)."""

    def write(self, text: str) -> Any:
        return sys.stdout.write(text)

    def flush(self) -> None:
        sys.stdout.flush()


def folderless_logger(verbose: int) -> Logger:
    """SB3's logger for a run without TensorBoard: stdout at ``verbose >= 1``, else nothing; no folder."""
    return Logger(folder=None, output_formats=[HumanOutputFormat(cast(TextIO, _Stdout()))] if verbose >= 1 else [])


def use_folderless_logger(model: Algorithm) -> Algorithm:
    """``model`` (an SB3 algorithm without ``tensorboard_log``) with :func:`folderless_logger` as
    its logger, so that its ``learn()`` makes no ``SB3-<timestamp>`` folder; a model with
    TensorBoard keeps SB3's (its folder is the run's log). ``set_logger`` keeps it out of the saved
    zip, as SB3 does with every logger."""
    if model.tensorboard_log is None:
        model.set_logger(folderless_logger(model.verbose))
    return model
