"""``lawnmower`` (the paper's NL): a non-adaptive boustrophedon sweep.

The field is split evenly into one strip per UAV along x; each strip holds one or more lanes
(lattice x positions), chosen together so that the lanes' footprints cover as much of the field's
width as the lattice allows. A UAV first flies to the nearest corner of its strip at the sweep
altitude, then sweeps its lanes along y, turning at the ends; when the route is done it sweeps it
back (ping-pong) until the budget ends. Nothing it measures changes the route: that is the point
of the baseline. Masks are honoured by taking the valid move that gets closest to the plan.
"""

from __future__ import annotations

import itertools

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from uav_ipp.config import is_real
from uav_ipp.geometry import FieldGeometry

from .base import Planner
from .navigation import DistanceCache, best_move, lattice_cell

Waypoint = tuple[int, int, int]  # (ix, iy, iz) lattice indices, iz = altitude level

#: Up to this many UAVs, strips are assigned to UAVs by trying every permutation.
_EXACT_ASSIGNMENT_MAX = 7


def axis_ranges(geometry: FieldGeometry, level: int) -> np.ndarray:
    """(L, 2) half-open belief-cell range a footprint at altitude ``level`` covers along one axis,
    for every lattice index (the field is square, so x and y share it)."""
    return np.array(
        [[geometry.footprint(k, 0, level).c0, geometry.footprint(k, 0, level).c1] for k in range(geometry.lattice)],
        dtype=np.int64,
    )


def union_length(ranges: np.ndarray, picks: np.ndarray | list[int]) -> int:
    """Number of belief cells along one axis covered by the footprints at lattice indices ``picks``."""
    if len(picks) == 0:
        return 0
    covered = np.zeros(int(ranges[:, 1].max()), dtype=bool)
    idx = np.arange(covered.size)
    r = ranges[np.asarray(picks)]
    covered |= ((idx[None, :] >= r[:, :1]) & (idx[None, :] < r[:, 1:])).any(axis=0)
    return int(covered.sum())


def best_lanes(ranges: np.ndarray, n_lanes: int) -> tuple[int, ...]:
    """The ``n_lanes`` lattice indices whose footprints cover the most of one axis (exact DP).

    Ranges start and end in lattice order, so a lane only overlaps the lane picked just before it
    (any earlier overlap is contained in that one): ``best[m, j] = len_j + max_i (best[m-1, i] -
    overlap(i, j))`` over ``i < j``. Ties go to the lexicographically first set.
    """
    lat = len(ranges)
    n_lanes = int(min(max(n_lanes, 1), lat))
    starts, ends = ranges[:, 0], ranges[:, 1]
    length = (ends - starts).astype(np.int64)
    overlap = np.clip(ends[:, None] - starts[None, :], 0, None)  # overlap[i, j] for i < j
    overlap = np.minimum(overlap, length[None, :])
    neg = np.iinfo(np.int64).min // 4
    best = np.full((n_lanes + 1, lat), neg, dtype=np.int64)
    back = np.full((n_lanes + 1, lat), -1, dtype=np.int64)
    best[1] = length
    earlier = np.tril(np.ones((lat, lat), dtype=bool), k=-1).T  # earlier[i, j]: i < j
    for m in range(2, n_lanes + 1):
        cand = np.where(earlier, best[m - 1][:, None] - overlap, neg)  # (i, j)
        back[m] = cand.argmax(axis=0)
        best[m] = np.where(cand.max(axis=0) > neg, cand.max(axis=0) + length, neg)
    j = int(np.argmax(best[n_lanes]))
    picks = [j]
    for m in range(n_lanes, 1, -1):
        j = int(back[m, j])
        picks.append(j)
    return tuple(sorted(picks))


def default_level(geometry: FieldGeometry, n_uavs: int) -> int:
    """The altitude level whose footprint side best fits one UAV's strip (10 m for 4 UAVs)."""
    width = geometry.config.field_size / n_uavs
    sides = 2.0 * geometry.half_side
    return int(np.argmin(np.abs(sides - width)))


def sweep_ends(ranges: np.ndarray, grid: int) -> tuple[int, int]:
    """First and last lattice index along a lane that still see the field's borders.

    Sweeping beyond them re-measures cells already seen, so the lane runs between them.
    """
    lows = np.flatnonzero(ranges[:, 0] <= 0)
    highs = np.flatnonzero(ranges[:, 1] >= grid)
    lo = int(lows.max()) if len(lows) else 0
    hi = int(highs.min()) if len(highs) else len(ranges) - 1
    return (lo, hi) if lo <= hi else (hi, lo)


def strip_routes(
    lanes: tuple[int, ...], n_uavs: int, y_ends: tuple[int, int], level: int
) -> list[list[list[Waypoint]]]:
    """For each strip (contiguous lanes of one UAV), its four candidate routes, one per entry
    corner: (from the left or right lane) x (from the low or high y end)."""
    per = len(lanes) // n_uavs
    strips = [lanes[k * per : (k + 1) * per] if k < n_uavs - 1 else lanes[k * per :] for k in range(n_uavs)]
    out = []
    for strip in strips:
        routes = []
        for xs in (list(strip), list(strip)[::-1]):
            for y0, y1 in (y_ends, y_ends[::-1]):
                route: list[Waypoint] = []
                for n, x in enumerate(xs):
                    a, b = (y0, y1) if n % 2 == 0 else (y1, y0)
                    route += [(x, a, level), (x, b, level)]
                routes.append(route)
        out.append(routes)
    return out


def _moves(a: Waypoint, b: Waypoint) -> int:
    return abs(a[0] - b[0]) + abs(a[1] - b[1]) + abs(a[2] - b[2])


def assign_strips(starts: list[Waypoint], routes: list[list[list[Waypoint]]]) -> list[list[Waypoint]]:
    """Give each UAV one strip and entry corner, minimising the longest (then total) transit."""
    n = len(starts)
    cost = np.array([[min(_moves(s, r[0]) for r in strip) for strip in routes] for s in starts])
    if n <= _EXACT_ASSIGNMENT_MAX:
        perms = np.array(list(itertools.permutations(range(n))))
        c = cost[np.arange(n)[None, :], perms]
        key = c.max(axis=1) * (c.sum(axis=1).max() + 1) + c.sum(axis=1)
        perm = perms[int(np.argmin(key))]
    else:  # greedy by start x: strips are ordered along x
        perm = np.argsort([s[0] * 1000 + s[1] for s in starts], kind="stable")
        perm = np.argsort(perm)
    chosen = []
    for u, s in enumerate(starts):
        options = routes[int(perm[u])]
        chosen.append(min(options, key=lambda r: _moves(s, r[0])))
    return chosen


def _free_route(route: list[Waypoint], no_fly: np.ndarray) -> list[Waypoint]:
    """Move waypoints out of no-fly columns along their lane (towards the lane's other end); drop
    lanes that are no-fly end to end, and repeated waypoints."""
    out: list[Waypoint] = []
    for k in range(0, len(route), 2):
        (x, a, z), (_, b, _) = route[k], route[k + 1]
        step = 1 if b >= a else -1
        ys = [y for y in range(a, b + step, step) if not no_fly[y, x]]
        if not ys:
            continue
        for w in ((x, ys[0], z), (x, ys[-1], z)):
            if not out or out[-1] != w:
                out.append(w)
    return out


class LawnmowerPlanner(Planner):
    """Non-adaptive strip sweep (see module docstring).

    :param altitude: sweep altitude in metres; ``None`` picks the altitude whose footprint side is
        closest to the strip width (field / UAVs), 10 m for the default 4 UAVs
    :param lanes_per_uav: lanes in each strip; ``None``: ``round(strip width / footprint side)``,
        at least 1
    """

    name = "lawnmower"
    uses_env_state = True

    def __init__(
        self, venv: VecEnv, seed: int | None = None, altitude: float | None = None, lanes_per_uav: int | None = None
    ) -> None:
        super().__init__(venv, seed)
        self.geometry: FieldGeometry = venv.get_attr("geometry", indices=[0])[0]
        config = self.geometry.config
        if altitude is None:
            self.level = default_level(self.geometry, self.n_agents)
        else:
            if not is_real(altitude) or float(altitude) not in config.altitudes:
                raise ValueError(
                    f"lawnmower altitude={altitude!r}: must be one of the env's altitudes {list(config.altitudes)}"
                )
            self.level = list(config.altitudes).index(float(altitude))
        self.altitude = float(config.altitudes[self.level])
        side = 2.0 * float(self.geometry.half_side[self.level])
        width = config.field_size / self.n_agents
        if lanes_per_uav is None:
            lanes_per_uav = max(1, round(width / side))
        if not (is_real(lanes_per_uav) and float(lanes_per_uav).is_integer() and lanes_per_uav >= 1):
            raise ValueError(f"lawnmower lanes_per_uav={lanes_per_uav!r}: must be an integer >= 1")
        self.lanes_per_uav = int(lanes_per_uav)
        self.ranges = axis_ranges(self.geometry, self.level)
        self.lanes = best_lanes(self.ranges, self.lanes_per_uav * self.n_agents)
        self.y_ends = sweep_ends(self.ranges, self.geometry.grid)
        self._strip_routes = strip_routes(self.lanes, self.n_agents, self.y_ends, self.level)
        self._distances = DistanceCache()
        self._routes: dict[int, list[list[Waypoint]]] = {}
        self._progress: dict[int, list[int]] = {}
        self._no_fly: dict[int, np.ndarray] = {}

    def reset(self, seed: int | None = None) -> None:
        super().reset(seed)
        self._routes.clear()
        self._progress.clear()

    def routes(self, copy: int = 0) -> list[list[Waypoint]]:
        """The current route (waypoints as lattice indices) of every UAV of one env copy."""
        return [list(r) for r in self._routes.get(copy, [])]

    def _lattice_positions(self, positions_m: np.ndarray) -> np.ndarray:
        config = self.geometry.config
        xy = np.rint(positions_m[:, :2] / config.spacing).astype(np.int64)
        z = np.searchsorted(np.asarray(config.altitudes), positions_m[:, 2])
        return np.column_stack([xy, z])

    def _make_plan(self, copy: int, positions: np.ndarray, no_fly: np.ndarray) -> None:
        starts = [lattice_cell(p) for p in positions]
        routes = assign_strips(starts, self._strip_routes)
        self._routes[copy] = [_free_route(r, no_fly) or [s] for r, s in zip(routes, starts)]
        self._progress[copy] = [0] * self.n_agents
        self._no_fly[copy] = no_fly

    def _plan(self, observation: dict[str, np.ndarray], mask: np.ndarray, starts: np.ndarray) -> np.ndarray:
        copies = mask.shape[0]
        positions = [self._lattice_positions(p) for p in self._per_copy("positions_m", copies)]
        need = [c for c in range(copies) if starts[c] or c not in self._routes]
        if need:
            truths = self.venv.get_attr("ground_truth", indices=[c * self.n_agents for c in need])
            for c, truth in zip(need, truths):
                self._make_plan(c, positions[c], np.asarray(truth.no_fly, dtype=bool))
        n_levels = len(self.geometry.config.altitudes)
        actions = np.zeros((copies, self.n_agents), dtype=np.int64)
        for c in range(copies):
            for u in range(self.n_agents):
                target = self._next_waypoint(c, u, lattice_cell(positions[c][u]))
                field = self._distances.get(self._no_fly[c], n_levels, target)
                actions[c, u] = best_move(positions[c][u], field, mask[c, u], target, self.rng)
        return actions

    def _next_waypoint(self, copy: int, uav: int, position: Waypoint) -> Waypoint:
        """Advance past reached waypoints; at the end of the route sweep it back (ping-pong)."""
        route = self._routes[copy][uav]
        k = self._progress[copy][uav]
        for _ in range(2 * len(route) + 1):
            if route[k] != position:
                break
            k += 1
            if k == len(route):
                route.reverse()
                self._routes[copy][uav] = route
                k = 1 if len(route) > 1 else 0
        self._progress[copy][uav] = k
        return route[k]
