"""``random``: every UAV picks uniformly among its valid actions (the paper's lower bound)."""

from __future__ import annotations

import numpy as np

from .base import Planner


class RandomPlanner(Planner):
    """Uniform over valid actions, drawn from the planner's seeded stream."""

    name = "random"

    def _plan(self, observation: dict[str, np.ndarray], mask: np.ndarray, starts: np.ndarray) -> np.ndarray:
        # The argmax of i.i.d. uniform keys over the valid actions is a uniform valid action;
        # one draw for the whole batch keeps it vectorised and reproducible.
        keys = self.rng.random(mask.shape)
        keys[~mask] = -1.0
        return keys.argmax(axis=-1)
