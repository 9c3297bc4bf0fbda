"""Shortest moves on the decision lattice, around no-fly columns.

The lawnmower follows a fixed route of waypoints; between two waypoints it must still get around
no-fly columns (env3's buildings) and UAVs that block a column. A breadth-first distance field
per waypoint answers "which valid move gets closest to the plan" for any position in one lookup,
and is cached because routes revisit the same waypoints every episode.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np

from uav_ipp.ipp_env import ACTION_DELTAS

#: Action indices by kind (see ``uav_ipp.ipp_env.ACTION_DELTAS``).
ALTITUDE_MOVES = (5, 0)  # down first: reach the sweep altitude from the 15 m start early
X_MOVES = (1, 4)
Y_MOVES = (2, 3)


def lattice_cell(values: Iterable[Any]) -> tuple[int, int, int]:
    """``(ix, iy, iz)`` as plain ints, from any three numbers (a row of a positions array)."""
    ix, iy, iz = (int(v) for v in values)
    return ix, iy, iz


def distance_field(no_fly: np.ndarray, n_levels: int, target: tuple[int, int, int]) -> np.ndarray:
    """(n_levels, L, L) number of moves from every (z, y, x) to ``target`` = (ix, iy, iz).

    No-fly columns are blocked at every altitude; unreachable cells are ``inf``. Vectorised
    relaxation: each sweep extends the frontier by one move in all six directions at once.
    """
    no_fly = np.asarray(no_fly, dtype=bool)
    lat = no_fly.shape[0]
    ix, iy, iz = target
    dist = np.full((n_levels, lat, lat), np.inf)
    blocked = np.broadcast_to(no_fly, dist.shape)
    if blocked[iz, iy, ix]:
        return dist
    dist[iz, iy, ix] = 0.0
    while True:
        nxt = dist.copy()
        for axis in range(3):
            lo = [slice(None)] * 3
            hi = [slice(None)] * 3
            lo[axis], hi[axis] = slice(0, -1), slice(1, None)
            np.minimum(nxt[tuple(lo)], dist[tuple(hi)] + 1.0, out=nxt[tuple(lo)])
            np.minimum(nxt[tuple(hi)], dist[tuple(lo)] + 1.0, out=nxt[tuple(hi)])
        nxt[blocked] = np.inf
        if np.array_equal(nxt, dist):
            return dist
        dist = nxt


class DistanceCache:
    """Distance fields by (no-fly map, altitude levels, target), computed on first use."""

    def __init__(self) -> None:
        self._fields: dict[tuple[bytes, int, tuple[int, int, int]], np.ndarray] = {}

    def get(self, no_fly: np.ndarray, n_levels: int, target: tuple[int, int, int]) -> np.ndarray:
        key = (np.asarray(no_fly, dtype=bool).tobytes(), int(n_levels), lattice_cell(target))
        field = self._fields.get(key)
        if field is None:
            field = self._fields[key] = distance_field(no_fly, n_levels, key[2])
        return field


def move_costs(position: np.ndarray, field: np.ndarray) -> np.ndarray:
    """(6,) distance to the target after each action from ``position`` = (ix, iy, iz); ``inf``
    for moves that leave the lattice or enter a blocked column."""
    n_levels, lat, _ = field.shape
    new = np.asarray(position, dtype=np.int64)[None, :] + ACTION_DELTAS
    inside = (
        (new[:, 0] >= 0)
        & (new[:, 0] < lat)
        & (new[:, 1] >= 0)
        & (new[:, 1] < lat)
        & (new[:, 2] >= 0)
        & (new[:, 2] < n_levels)
    )
    costs = np.full(len(ACTION_DELTAS), np.inf)
    ok = new[inside]
    costs[inside] = field[ok[:, 2], ok[:, 1], ok[:, 0]]
    return costs


def preference(position: np.ndarray, target: tuple[int, int, int]) -> tuple[int, ...]:
    """Tie-break order among equally short moves: altitude first (measure at the sweep altitude
    from the first step), then along the axis with more left to go (so a UAV stays on its lane
    while sweeping and detours only where it must), then the other axis."""
    dx, dy = abs(target[0] - int(position[0])), abs(target[1] - int(position[1]))
    horizontal = Y_MOVES + X_MOVES if dy > dx else X_MOVES + Y_MOVES
    return ALTITUDE_MOVES + horizontal


def best_move(
    position: np.ndarray,
    field: np.ndarray,
    mask: np.ndarray,
    target: tuple[int, int, int] | None = None,
    rng: np.random.Generator | None = None,
) -> int:
    """The planned move if it is valid, else the valid move that gets closest to the plan.

    The planned move is the shortest-path move (ties by :func:`preference`). When it is masked,
    typically because another UAV occupies that column, the valid move that gets closest to the
    plan is taken. Two UAVs that block each other in a corridor would then wait for each other
    forever, both choosing the same "closest" move step after step; with ``rng`` a blocked UAV
    picks at random among the valid moves at most one move worse than the closest (waiting by an
    altitude change or stepping aside), which breaks the symmetry within a few steps and stays
    reproducible by seed. With no finite option the first valid move is taken, so the answer is
    always valid.
    """
    position = np.asarray(position, dtype=np.int64)
    costs = move_costs(position, field)
    mask = np.asarray(mask, dtype=bool)
    order = np.asarray(preference(position, target) if target is not None else ALTITUDE_MOVES + X_MOVES + Y_MOVES)
    planned = int(order[int(np.argmin(costs[order]))])
    if mask[planned] and np.isfinite(costs[planned]):
        return planned
    if not mask.any():
        return int(order[0])
    c = np.where(mask[order], costs[order], np.inf)
    if np.isinf(c).all():
        return int(order[np.flatnonzero(mask[order])[0]])
    if rng is None:
        return int(order[int(np.argmin(c))])
    pool = np.flatnonzero(c <= c.min() + 1.0)
    return int(order[pool[int(rng.integers(len(pool)))]])
