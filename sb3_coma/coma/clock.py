"""The critic's clock (``COMA(critic_time_feature=...)``): the time left in each env copy's episode.

Tasks like MPE end every episode at a fixed step and score the return up to it. A critic that
cannot see the clock either learns an infinite-horizon value carried in by the time-limit
bootstrap (whose scale grows for tens of thousands of steps while it is read) or, without that
bootstrap, cannot fit returns that depend on how many steps are left (docs/training.md, rounds 7
and 17). The centralised critic may read anything the trainer knows, and the trainer counts steps:
this module counts them per copy and appends ``1 - t / limit`` to the critic's state, as
sb3-contrib's ``TimeFeatureWrapper`` does for one agent's observation, without changing what the
actors see.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces


class EpisodeClock:
    """Steps since each env copy's episode began, as the fraction of a time limit still left.

    :param n_copies: env copies (every agent of a copy shares its clock)
    :param limit: the episodes' time limit in steps
    """

    def __init__(self, n_copies: int, limit: int) -> None:
        self.limit = int(limit)
        self.elapsed = np.zeros(n_copies, dtype=np.int64)

    def time_left(self, elapsed: np.ndarray | None = None) -> np.ndarray:
        """``max(0, 1 - t / limit)`` per copy (``elapsed``: other counts than the clock's own)."""
        steps = self.elapsed if elapsed is None else elapsed
        return np.clip(1.0 - steps / self.limit, 0.0, 1.0).astype(np.float32)

    def advance(self, copy_dones: Any) -> None:
        """One step of every copy; the copies whose episode ended start again at 0."""
        self.elapsed += 1
        self.elapsed[np.asarray(copy_dones, dtype=bool)] = 0


def with_time_left(space: spaces.Space) -> spaces.Box:
    """The state's space with the time left appended (a flat ``Box`` only).

    :raises ValueError: a state that is not a 1-D ``Box`` (an image has no place for one number)
    """
    if not isinstance(space, spaces.Box) or len(space.shape or ()) != 1:
        raise ValueError(
            f"critic_time_feature needs a flat state (a 1-D Box) to append the time left to; the state is {space}"
        )
    low = np.append(np.asarray(space.low, dtype=np.float32), 0.0).astype(np.float32)
    high = np.append(np.asarray(space.high, dtype=np.float32), 1.0).astype(np.float32)
    return spaces.Box(low, high, dtype=np.float32)


def append_time_left(state: th.Tensor, time_left: th.Tensor) -> th.Tensor:
    """``state`` ``(B, N, D)`` with each joint step's time left ``(B,)`` as feature ``D``."""
    clock = time_left.to(state.dtype).view(-1, 1, 1).expand(-1, state.shape[1], 1)
    return th.cat([state, clock], dim=-1)
