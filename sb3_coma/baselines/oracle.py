"""``oracle``: a clairvoyant greedy planner, the upper reference of every table (never a competitor).

It knows the ground truth and plans from the global belief (every UAV's readings, no channel
noise). Each move is scored by the expected drop of the binary entropy that its reading brings,
given the TRUE class of every cell: a reading of a cell of true class ``t`` agrees with ``t`` with
probability ``1 - q``; the drop counts in full on truly valuable cells (the entropy the mission
reports) and a quarter on the others (they decide the F1's precision). UAVs then decide in id order
with AG's footprint claims (:func:`~sb3_coma.baselines.adaptive_gain.plan_team`), so the only
difference from centralised AG is what the oracle knows. It measures the headroom left to a
planner that could guess where the valuable ground is; a DAgger teacher for the learner uses the
same scores.
"""

from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from uav_ipp import kernels

from .adaptive_gain import AdaptiveGainPlanner, stored_probabilities

#: Weight of the entropy drop on cells that are truly not valuable.
OTHER_WEIGHT = 0.25


def _entropy(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-12, 1.0 - 1e-12)
    return -(p * np.log2(p) + (1.0 - p) * np.log2(1.0 - p))


def clairvoyant_density(belief: np.ndarray, truth: np.ndarray, flip_probability: float) -> np.ndarray:
    """(grid, grid) expected entropy drop of one reading given the true class (module docstring)."""
    p = np.clip(np.asarray(belief, dtype=np.float64), 0.0, 1.0)
    q = float(flip_probability)
    post_one = p * (1.0 - q) / np.maximum(p * (1.0 - q) + (1.0 - p) * q, 1e-300)
    post_zero = p * q / np.maximum(p * q + (1.0 - p) * (1.0 - q), 1e-300)
    says_one = np.where(truth, 1.0 - q, q)  # probability that the reading is 1, given the truth
    drop = _entropy(p) - (says_one * _entropy(post_one) + (1.0 - says_one) * _entropy(post_zero))
    return np.where(truth, drop, OTHER_WEIGHT * drop)


class OraclePlanner(AdaptiveGainPlanner):
    """Clairvoyant greedy planner (module docstring); ``lookahead`` and ``discount`` as AG's."""

    name = "oracle"

    def __init__(self, venv: VecEnv, seed: int | None = None, discount: float = 0.5, lookahead: int = 1) -> None:
        super().__init__(venv, seed, discount=discount, weighting="plain", lookahead=lookahead, knowledge="central")

    def _density_tables(self) -> np.ndarray:
        """(A, 2 * TABLE_SIZE) :func:`clairvoyant_density` of every stored log-odds value, per
        altitude: the first half for truly not-valuable cells, the second for valuable ones."""
        p = stored_probabilities()
        halves = (np.zeros(p.shape, dtype=bool), np.ones(p.shape, dtype=bool))
        return np.stack(
            [np.concatenate([clairvoyant_density(p, truth, q) for truth in halves]) for q in self._levels_flip()]
        )

    def _table_rows(self, copies: int) -> list[np.ndarray]:
        truths = self._attr_per_copy("ground_truth", copies)
        return [
            rows + kernels.TABLE_SIZE * np.asarray(truth.valuable, dtype=np.intp)
            for rows, truth in zip(super()._table_rows(copies), truths)
        ]
