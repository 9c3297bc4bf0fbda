"""Expected information gain of a reading, and the per-cell table the kernels sum it from.

A reading of a cell with prior ``p`` through a binary symmetric channel with flip probability
``q`` is 1 with probability ``P1 = p (1 - q) + (1 - p) q`` and moves the belief to
``p1 = p (1 - q) / P1`` or ``p0 = p q / (1 - P1)``. The expected gain of that reading is the
expected drop of the entropy the mission rewards: ipp-marl's class-weighted entropy
(``weighting="class"``) or plain binary entropy (``"plain"``, the mutual information).

The gain depends on the cell's log-odds only, so :func:`build_local_table` tabulates it for every
fixed-point log-odds value and every altitude level, next to the probability and entropy. The
kernels keep, per UAV, the sum of each gain column over every *gain strip* cell of its own local
map M_i (``uav_ipp.geometry``: footprints are exact unions of strips), so the gain of any candidate
footprint is a sum over a few hundred strip cells, exact, and never a pass over belief cells.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from uav_ipp import kernels

WEIGHTINGS = ("class", "plain")
#: Altitude levels the tables and kernels carry a gain column for (``kernels.GAIN_SLOTS`` / 2).
MAX_LEVELS = kernels.GAIN_SLOTS // len(WEIGHTINGS)


def check_weighting(weighting: str) -> str:
    """Return ``weighting`` if it is one of :data:`WEIGHTINGS`, else raise naming it."""
    if weighting not in WEIGHTINGS:
        raise ValueError(f"weighting={weighting!r}: choose one of {WEIGHTINGS}")
    return weighting


def _binary_entropy(p: np.ndarray) -> np.ndarray:
    """Binary entropy in bits; ``p`` must already be clipped away from 0 and 1."""
    return -(p * np.log2(p) + (1.0 - p) * np.log2(1.0 - p))


def _entropy_term(p: np.ndarray, weighting: str) -> np.ndarray:
    """The entropy the mission rewards: ipp-marl's class-weighted, clipped entropy or plain entropy."""
    if weighting == "class":
        clip = kernels.ENTROPY_CLIP
        return kernels.class_weight(p) * _binary_entropy(np.clip(p, clip, 1.0 - clip))
    return _binary_entropy(np.clip(p, 1e-12, 1.0 - 1e-12))


def gain_density(belief: np.ndarray, flip_probability: float, weighting: str = "class") -> np.ndarray:
    """Expected entropy drop (bits) of one reading with flip probability ``q``, per cell of ``belief``.

    With class weighting the drop can be negative for cells believed not valuable (weight 0): a
    reading may make them look valuable again, exactly what that reward would charge.
    """
    check_weighting(weighting)
    p = np.clip(np.asarray(belief, dtype=np.float64), 0.0, 1.0)
    q = float(flip_probability)
    p_one = p * (1.0 - q) + (1.0 - p) * q
    post_one = p * (1.0 - q) / np.maximum(p_one, 1e-300)
    post_zero = p * q / np.maximum(1.0 - p_one, 1e-300)
    after = p_one * _entropy_term(post_one, weighting) + (1.0 - p_one) * _entropy_term(post_zero, weighting)
    return _entropy_term(p, weighting) - after


def gain_column(weighting: str, level: int) -> int:
    """Gain column (0-based, after probability and entropy) of a weighting and altitude level."""
    return WEIGHTINGS.index(check_weighting(weighting)) * MAX_LEVELS + level


def build_local_table(flip_probabilities: Sequence[float]) -> np.ndarray:
    """(TABLE_SIZE, 2 + GAIN_SLOTS) float32 per fixed-point log-odds value: probability, entropy
    (bits), then the gain of a reading at each altitude level, class-weighted first, then plain
    (``MAX_LEVELS`` columns each; levels the config does not have stay 0)."""
    # IppConfig refuses more than 3 altitudes at the edge; the tables' width is the same limit
    assert len(flip_probabilities) <= MAX_LEVELS, flip_probabilities
    p = kernels.table_probabilities()
    table = np.zeros((len(p), kernels.L_GAIN0 + kernels.GAIN_SLOTS), dtype=np.float32)
    table[:, kernels.L_PROB] = p
    table[:, kernels.L_ENTROPY] = kernels.binary_entropy(p)
    for _w, weighting in enumerate(WEIGHTINGS):
        for level, q in enumerate(flip_probabilities):
            table[:, kernels.L_GAIN0 + gain_column(weighting, level)] = gain_density(p, q, weighting)
    return table
