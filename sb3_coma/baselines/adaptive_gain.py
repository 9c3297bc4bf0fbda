"""``ag``: adaptive gain (Carbone et al. 2021, as ipp-marl adapted it to 3-D flight).

Each UAV scores every valid move by the expected class-weighted information gain of the camera
footprint it would take there, at that altitude's flip probability, computed from its OWN local
belief (what it measured plus what reached it through the noisy channel). Scores are normalised
per UAV. UAVs decide in id order (the order the env resolves moves in); the footprints already
chosen by earlier UAVs discount the cells they cover for the later ones, and a column an earlier
UAV moves into is not taken again (the env would turn that move into a hover). Each UAV then takes
its best move: greedy, one step ahead.
"""
from __future__ import annotations

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from envs.geometry import FieldGeometry
from envs.ipp_env import ACTION_DELTAS

from .base import Planner
from .gain import WEIGHTINGS, axis_counts, footprint_fraction, footprint_gains, gain_density

#: Relative size of the random tie-break added to normalised scores (never changes a strict order).
_JITTER = 1e-9


def choose_actions(beliefs: np.ndarray, positions: np.ndarray, mask: np.ndarray, counts: np.ndarray,
                   cell_area: np.ndarray, flips: np.ndarray, discount: float = 0.5,
                   weighting: str = "class", rng: np.random.Generator | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Sequential greedy AG decision for a batch of env copies.

    :param beliefs: (C, N, R, R) each UAV's local belief on the comm grid
    :param positions: (C, N, 3) lattice indices (ix, iy, level)
    :param mask: (C, N, 6) bool valid actions
    :param counts: (A, L, R) footprint table (:func:`gain.axis_counts`)
    :param cell_area: (R, R) belief cells per comm cell
    :param flips: (A,) flip probability per altitude level
    :param discount: how much a cell covered by an earlier UAV's chosen footprint loses of its
        gain for later UAVs (0: ignore others, 1: a covered cell is worth nothing)
    :return: actions (C, N) and the normalised scores (C, N, 6) (``-inf`` where not allowed)
    """
    n_copies, n_uavs = positions.shape[:2]
    n_levels, lat = counts.shape[0], counts.shape[1]
    density = gain_density(beliefs, flips, weighting)  # (C, N, A, R, R)
    targets = positions[:, :, None, :] + ACTION_DELTAS[None, None]  # (C, N, 6, 3)
    inside = ((targets[..., :2] >= 0) & (targets[..., :2] < lat)).all(-1) & (targets[..., 2] >= 0) & (targets[..., 2] < n_levels)
    allowed = mask & inside
    targets = np.clip(targets, 0, [lat - 1, lat - 1, n_levels - 1])
    keep = np.ones((n_copies,) + cell_area.shape)  # gain kept per comm cell after earlier claims
    taken = np.zeros((n_copies, lat, lat), dtype=bool)  # columns earlier UAVs move into
    horizontal = (ACTION_DELTAS[:, :2] != 0).any(axis=1)
    rows = np.arange(n_copies)
    actions = np.zeros((n_copies, n_uavs), dtype=np.int64)
    scores = np.full((n_copies, n_uavs, len(ACTION_DELTAS)), -np.inf)
    for u in range(n_uavs):  # sequential by design: each UAV sees the earlier UAVs' choices
        t = targets[:, u]
        gains = footprint_gains(density[:, u] * keep[:, None], counts, t)
        ok = allowed[:, u] & ~(taken[rows[:, None], t[..., 1], t[..., 0]] & horizontal[None])
        ok = np.where(ok.any(axis=1, keepdims=True), ok, allowed[:, u] | ~allowed[:, u].any(axis=1, keepdims=True))
        scale = np.abs(np.where(ok, gains, 0.0)).max(axis=1, keepdims=True)
        norm = gains / np.where(scale > 0, scale, 1.0)
        if rng is not None:
            norm = norm + _JITTER * rng.random(norm.shape)
        norm = np.where(ok, norm, -np.inf)
        choice = norm.argmax(axis=1)
        actions[:, u] = choice
        scores[:, u] = norm
        chosen = t[rows, choice]  # (C, 3)
        keep *= 1.0 - discount * footprint_fraction(counts, cell_area, chosen)
        taken[rows, chosen[:, 1], chosen[:, 0]] = True
    return actions, scores


class AdaptiveGainPlanner(Planner):
    """Greedy expected-information-gain planner (see module docstring).

    :param discount: weight of the discount on cells claimed by earlier UAVs (0..1)
    :param weighting: ``"class"`` (ipp-marl's class-weighted entropy, default) or ``"none"``
    """

    name = "ag"
    uses_env_state = True

    def __init__(self, venv: VecEnv, seed: int | None = None, discount: float = 0.5,
                 weighting: str = "class") -> None:
        super().__init__(venv, seed)
        if not (0.0 <= float(discount) <= 1.0):
            raise ValueError(f"ag discount={discount!r}: must be in [0, 1]")
        if weighting not in WEIGHTINGS:
            raise ValueError(f"ag weighting={weighting!r}: choose one of {WEIGHTINGS}")
        self.discount = float(discount)
        self.weighting = weighting
        self.geometry: FieldGeometry = venv.get_attr("geometry", indices=[0])[0]
        config = self.geometry.config
        self.altitudes = np.asarray(config.altitudes, dtype=np.float64)
        self.flips = np.array([config.flip_probability[a] for a in config.altitudes], dtype=np.float64)
        self.counts = axis_counts(self.geometry)
        self.cell_area = np.asarray(self.geometry.comm_cell_area, dtype=np.float64)
        #: Normalised scores of the last decision, (copies, N, 6), for inspection.
        self.last_scores: np.ndarray | None = None

    def _plan(self, observation: dict[str, np.ndarray], mask: np.ndarray, starts: np.ndarray) -> np.ndarray:
        copies = mask.shape[0]
        beliefs = np.stack(self._per_copy("local_beliefs", copies)).astype(np.float64)
        pos_m = np.stack(self._per_copy("positions_m", copies))
        spacing = self.geometry.config.spacing
        positions = np.concatenate([np.rint(pos_m[..., :2] / spacing),
                                    np.searchsorted(self.altitudes, pos_m[..., 2])[..., None]], axis=-1).astype(np.int64)
        actions, self.last_scores = choose_actions(beliefs, positions, mask, self.counts, self.cell_area,
                                                   self.flips, self.discount, self.weighting, self.rng)
        return actions
