"""Expected information gain of a camera footprint on a UAV's own local belief.

The local belief lives on the communication grid (R x R comm cells, each standing for the many
belief cells inside it). A reading of a cell with prior ``p`` through a binary symmetric channel
with flip probability ``q`` is 1 with probability ``P1 = p (1 - q) + (1 - p) q`` and moves the
belief to ``p1 = p (1 - q) / P1`` or ``p0 = p q / (1 - P1)``. The expected gain of that reading
is the expected drop of the entropy the mission rewards: ipp-marl's class-weighted entropy
(``weighting="class"``) or plain binary entropy (``"none"``, the mutual information).

A footprint at lattice column (ix, iy) and altitude level ``a`` covers ``n_a[iy, r] * n_a[ix, c]``
belief cells of comm cell (r, c), where ``n_a[k, r]`` counts the covered belief-cell rows of comm
row ``r`` along one axis. So the gain of every footprint is a bilinear form ``n_a[iy] @ D_a @
n_a[ix]`` of the per-cell gain density ``D_a``: the footprint table is two small (A, L, R)
arrays, precomputed once, and never a per-cell loop.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from envs import kernels
from envs.geometry import FieldGeometry

WEIGHTINGS = ("class", "none")


def axis_counts(geometry: FieldGeometry) -> np.ndarray:
    """(A, L, R) belief cells along one axis that a footprint at altitude level ``a`` and lattice
    index ``k`` covers inside comm cell ``r`` (the field is square: x and y share the table)."""
    n_alt, lat, grid = len(geometry.altitudes), geometry.lattice, geometry.grid
    ranges = np.array([[(geometry.footprint(k, 0, a).c0, geometry.footprint(k, 0, a).c1) for k in range(lat)]
                       for a in range(n_alt)], dtype=np.int64)  # (A, L, 2)
    cells = np.arange(grid)
    covered = (cells >= ranges[..., :1]) & (cells < ranges[..., 1:])  # (A, L, G)
    onehot = np.zeros((grid, geometry.comm_grid), dtype=np.float64)
    onehot[cells, geometry.comm_of_cell] = 1.0
    return covered.astype(np.float64) @ onehot


def _binary_entropy(p: np.ndarray) -> np.ndarray:
    """Binary entropy in bits; ``p`` must already be clipped away from 0 and 1."""
    return -(p * np.log2(p) + (1.0 - p) * np.log2(1.0 - p))


def _entropy_term(p: np.ndarray, weighting: str) -> np.ndarray:
    """The entropy the mission rewards: ipp-marl's class-weighted, clipped entropy (the env's
    reward, ``envs.kernels.weighted_entropy``) or plain binary entropy."""
    if weighting == "class":
        weight = np.where(p > kernels.WEIGHT_HIGH, 1.0, np.where(p < kernels.WEIGHT_LOW, 0.0, 0.5))
        clip = kernels.ENTROPY_CLIP
        return weight * _binary_entropy(np.clip(p, clip, 1.0 - clip))
    return _binary_entropy(np.clip(p, 1e-12, 1.0 - 1e-12))


def gain_density(belief: np.ndarray, flip_probability: float | Sequence[float], weighting: str = "class") -> np.ndarray:
    """Expected entropy drop per belief cell from one reading with flip probability ``q``.

    ``belief`` is any array of probabilities (comm cells). A scalar ``q`` gives the belief's shape;
    a sequence of ``A`` flip probabilities gives ``belief.shape[:-2] + (A,) + belief.shape[-2:]``
    (one map per altitude level), sharing the prior's entropy. With class weighting the drop can
    be negative for cells believed not valuable (weight 0): a reading may make them look valuable
    again, exactly what the reward would charge.
    """
    return gain_densities(belief, flip_probability, (weighting,))[0]


def gain_densities(belief: np.ndarray, flip_probability: float | Sequence[float],
                   weightings: Sequence[str]) -> list[np.ndarray]:
    """:func:`gain_density` for several weightings, computing the reading's posteriors once."""
    bad = [w for w in weightings if w not in WEIGHTINGS]
    if bad:
        raise ValueError(f"weighting={bad[0]!r}: choose one of {WEIGHTINGS}")
    p = np.clip(np.asarray(belief, dtype=np.float64), 0.0, 1.0)
    scalar = np.ndim(flip_probability) == 0
    qs = np.atleast_1d(np.asarray(flip_probability, dtype=np.float64))
    priors = [_entropy_term(p, w) for w in weightings]
    out: list[list[np.ndarray]] = [[] for _ in weightings]
    for q in qs:  # one pass per altitude level (3), each vectorised over every cell
        p_one = p * (1.0 - q) + (1.0 - p) * q
        post_one = p * (1.0 - q) / np.maximum(p_one, 1e-300)
        post_zero = p * q / np.maximum(1.0 - p_one, 1e-300)
        for k, w in enumerate(weightings):
            after = p_one * _entropy_term(post_one, w) + (1.0 - p_one) * _entropy_term(post_zero, w)
            out[k].append(priors[k] - after)
    return [levels[0] if scalar else np.stack(levels, axis=-3) for levels in out]


def footprint_gains(density: np.ndarray, counts: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Gain of each candidate footprint.

    :param density: (B, A, R, R) gain density per altitude level for each of B beliefs
    :param counts: (A, L, R) from :func:`axis_counts`
    :param targets: (B, K, 3) candidate (ix, iy, level) lattice indices (in range)
    :return: (B, K) expected gain in belief cells x bits
    """
    b = np.arange(density.shape[0])[:, None]
    level, iy, ix = targets[..., 2], targets[..., 1], targets[..., 0]
    rows = counts[level, iy]  # (B, K, R)
    cols = counts[level, ix]  # (B, K, R)
    dens = density[b, level]  # (B, K, R, R)
    return (np.matmul(rows[:, :, None, :], dens)[:, :, 0] * cols).sum(axis=-1)


def footprint_fraction(counts: np.ndarray, cell_area: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(B, R, R) fraction of each comm cell that the footprints at ``target`` (B, 3) cover."""
    rows = counts[target[:, 2], target[:, 1]]
    cols = counts[target[:, 2], target[:, 0]]
    return rows[:, :, None] * cols[:, None, :] / cell_area[None]


def action_gains(beliefs: np.ndarray, positions: np.ndarray, mask: np.ndarray, counts: np.ndarray,
                 flips: np.ndarray, deltas: np.ndarray, weightings: Sequence[str] = ("class",)) -> np.ndarray:
    """Each UAV's normalised expected gain of every action, from its OWN local belief.

    This is the one-step look-ahead a UAV can compute on board (no other UAV's data beyond what
    reached it): the gain of the footprint each action leads to, divided by the largest absolute
    gain over the valid actions, so the best valid action scores 1. Invalid actions score 0 (the
    action mask removes them anyway).

    :param beliefs: (N, R, R) local beliefs on the comm grid
    :param positions: (N, 3) lattice indices (ix, iy, level)
    :param mask: (N, 6) validity (nonzero = valid)
    :param counts: (A, L, R) from :func:`axis_counts`
    :param flips: (A,) flip probability per altitude level
    :param deltas: (6, 3) lattice move of each action
    :param weightings: the entropy weightings, one output row each (posteriors computed once)
    :return: (N, K, 6) float32 in [-1, 1], K = ``len(weightings)``
    """
    n_levels, lat = counts.shape[0], counts.shape[1]
    targets = np.clip(positions[:, None, :] + deltas[None], 0, [lat - 1, lat - 1, n_levels - 1])  # (N, 6, 3)
    valid = np.asarray(mask) != 0
    rows = []
    for density in gain_densities(beliefs, flips, weightings):  # each (N, A, R, R)
        gains = np.where(valid, footprint_gains(density, counts, targets), 0.0)
        scale = np.abs(gains).max(axis=1, keepdims=True)
        rows.append(gains / np.where(scale > 0, scale, 1.0))
    return np.stack(rows, axis=1).astype(np.float32)

