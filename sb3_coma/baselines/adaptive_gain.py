"""``ag``: adaptive gain (Carbone et al. 2021, as ipp-marl adapted it to 3-D flight), with look-ahead.

Each UAV scores its moves by the expected information gain of the camera footprints they lead
to, at the footprint's altitude and flip probability, computed from its OWN per-cell local belief
M_i (what it measured plus what reached it through the noisy channel): the env keeps, per UAV,
the gain of one reading summed over every gain strip cell (``UavIppEnv.gain_strip_sums``), and
footprints are exact unions of strips, so a footprint's gain is exact and cheap.

UAVs decide in id order (the order the env resolves moves in). Cells covered by footprints that
earlier UAVs (or earlier steps of the same plan) are about to take lose ``discount`` of their
gain, and a column an earlier UAV moves into is not taken again (the env would turn that move
into a hover). With ``lookahead=k`` each UAV searches every sequence of k valid moves
(exhaustive, 6^k sequences) and takes the first move of the best sequence; ``k = 1`` is AG.
The search discounts a strip cell by ``discount`` each time a footprint of the plan covers it,
a first-order stand-in for the posterior after those readings, so planning cost grows as 6^k.
"""

from __future__ import annotations

import numba
import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from uav_ipp import kernels
from uav_ipp.config import is_real, is_whole
from uav_ipp.gain import WEIGHTINGS, check_weighting, gain_density
from uav_ipp.geometry import FieldGeometry
from uav_ipp.ipp_env import ACTION_DELTAS

from .base import Planner

#: Relative size of the random tie-break added to scores (never changes a strict order).
_JITTER = 1e-9
#: Deepest look-ahead accepted: 6^4 = 1296 sequences per UAV and decision is already ~10 ms.
MAX_LOOKAHEAD = 4

#: AG's entropy weighting per map family, chosen on validation missions (never on test missions)
#: by ``sb3_coma.experiments.ag_weighting.pick_ag_weighting`` (rule: lower global entropy at 100 % by a paired
#: test, else higher F1, else "class"). Used whenever "ag" is evaluated on that map and the caller
#: names no weighting. Measured by ``sb3-coma ag-weighting --env env1,env2,env3 --missions 60``
#: (15 s; split "train", env seeds 2000..2059, random starts, moderate noise, 4 UAVs, budget 15;
#: means at 100 %, paired differences plain - class ± standard error):
#:   env1 -> class: entropy class 0.3151 / plain 0.4208 (+0.1057 ± 0.0136), F1 0.8153 / 0.7642 (-0.0510 ± 0.0087)
#:   env2 -> class: entropy class 0.3956 / plain 0.4427 (+0.0471 ± 0.0152), F1 0.7392 / 0.7450 (+0.0058 ± 0.0103, tie)
#:   env3 -> plain: entropy class 0.4428 / plain 0.4528 (+0.0099 ± 0.0131, tie), F1 0.7274 / 0.7427 (+0.0153 ± 0.0072)
#: With 20 missions env2 and env3 were ties on both metrics (env3: entropy +0.0145 ± 0.0199, F1
#: +0.0148 ± 0.0101), so the rule fell back to "class"; 60 missions settle env2 on entropy and env3
#: on F1 (by 2.1 standard errors: the narrowest of the three choices).
WEIGHTING_BY_MAP: dict[str, str] = {"env1": "class", "env2": "class", "env3": "plain"}
#: The weighting of a map outside those families (a user's image): ipp-marl's.
FALLBACK_WEIGHTING = "class"


def default_weighting(map_name: str | None) -> str:
    """AG's default weighting on map family ``map_name`` (``"env1"``, a gymnasium id ...);
    :data:`FALLBACK_WEIGHTING` for a user's own image or an unknown name."""
    if map_name is None:
        return FALLBACK_WEIGHTING
    key = str(map_name).strip().lower()
    if key.startswith("uavipp-") and key.endswith("-v0"):
        key = key[len("uavipp-") : -len("-v0")]
    return WEIGHTING_BY_MAP.get(key, FALLBACK_WEIGHTING)


@numba.njit(cache=True)
def _footprint_gain(sums, keep, strips, x, y, z):
    """Discounted gain of the footprint at lattice (x, y) and level z: sum over its strip rectangle."""
    total = 0.0
    for gi in range(strips[y, z, 0], strips[y, z, 1]):
        for gj in range(strips[x, z, 0], strips[x, z, 1]):
            total += sums[z, gi, gj] * keep[gi, gj]
    return total


@numba.njit(cache=True)
def _claim(keep, strips, x, y, z, discount):
    for gi in range(strips[y, z, 0], strips[y, z, 1]):
        for gj in range(strips[x, z, 0], strips[x, z, 1]):
            keep[gi, gj] *= 1.0 - discount


@numba.njit(cache=True)
def _continuation(sums, start_keep, keep, moves, x0, y0, z0, no_fly, n_levels, deltas, strips, discount):
    """Best discounted gain of ``moves`` more valid moves from (x0, y0, z0), by enumerating every
    sequence (6^moves; ``start_keep`` already holds the claims so far and is left unchanged)."""
    if moves == 0:
        return 0.0
    lat = no_fly.shape[0]
    n_act = deltas.shape[0]
    best = 0.0
    found = False
    for code in range(n_act**moves):
        keep[:, :] = start_keep
        x, y, z = x0, y0, z0
        value = 0.0
        valid = True
        for _ in range(moves):
            a = code % n_act
            code //= n_act
            x, y, z = x + deltas[a, 0], y + deltas[a, 1], z + deltas[a, 2]
            if not (0 <= x < lat and 0 <= y < lat and 0 <= z < n_levels) or no_fly[y, x]:
                valid = False
                break
            value += _footprint_gain(sums, keep, strips, x, y, z)
            _claim(keep, strips, x, y, z, discount)
        if valid and (not found or value > best):
            best = value
            found = True
    return best


@numba.njit(cache=True)
def plan_team(sums, positions, allowed, no_fly, deltas, strips, discount, horizon, jitter, heard, scores, actions):
    """Sequential AG decision of one team (see module docstring).

    :param sums: (N, A, S, S) each UAV's gain strip sums for the chosen weighting
    :param positions: (N, 3) lattice (ix, iy, level)
    :param allowed: (N, 6) bool valid first moves (the env's mask)
    :param jitter: (N, 6) tie-break added to each first move's score
    :param heard: (N, N) bool: ``heard[u, v]`` when UAV u knows where UAV v is and what it chose this
        step (all true for "shared positions"; only UAVs within communication range for "comm only")
    :param scores: (N, 6) out: each first move's look-ahead value (``-inf`` where not allowed)
    :param actions: (N,) out: the chosen moves
    """
    n, n_levels = sums.shape[0], sums.shape[1]
    s = sums.shape[2]
    keep = np.ones((s, s))
    scratch = np.ones((s, s))
    team_keep = np.ones((s, s))
    lat = no_fly.shape[0]
    taken = np.zeros((lat, lat), dtype=np.bool_)
    targets = np.zeros((n, 3), dtype=np.int64)
    for u in range(n):
        # what UAV u knows of the earlier UAVs' choices: their footprints and columns, if heard
        team_keep[:, :] = 1.0
        taken[:, :] = False
        for v in range(u):
            if heard[u, v]:
                _claim(team_keep, strips, targets[v, 0], targets[v, 1], targets[v, 2], discount)
                taken[targets[v, 1], targets[v, 0]] = True
        best_a = -1
        for a in range(deltas.shape[0]):
            scores[u, a] = -np.inf
            nx, ny, nz = positions[u, 0] + deltas[a, 0], positions[u, 1] + deltas[a, 1], positions[u, 2] + deltas[a, 2]
            horizontal = deltas[a, 0] != 0 or deltas[a, 1] != 0
            if not allowed[u, a] or (horizontal and taken[ny, nx]):
                continue
            value = _footprint_gain(sums[u], team_keep, strips, nx, ny, nz)
            if horizon > 1:
                keep[:, :] = team_keep
                _claim(keep, strips, nx, ny, nz, discount)
                value += _continuation(
                    sums[u], keep, scratch, horizon - 1, nx, ny, nz, no_fly, n_levels, deltas, strips, discount
                )
            scores[u, a] = value + jitter[u, a]
            if best_a < 0 or scores[u, a] > scores[u, best_a]:
                best_a = a
        if best_a < 0:  # every move blocked by an earlier UAV's claim: take the best allowed one
            for a in range(deltas.shape[0]):
                if allowed[u, a]:
                    best_a = a
                    break
            best_a = max(best_a, 0)
        actions[u] = best_a
        tx, ty, tz = (
            positions[u, 0] + deltas[best_a, 0],
            positions[u, 1] + deltas[best_a, 1],
            positions[u, 2] + deltas[best_a, 2],
        )
        if not (0 <= tx < lat and 0 <= ty < lat and 0 <= tz < n_levels):
            tx, ty, tz = positions[u, 0], positions[u, 1], positions[u, 2]  # a hover
        targets[u, 0], targets[u, 1], targets[u, 2] = tx, ty, tz


#: What an AG UAV knows of its teammates (labels in tables: "AG, shared positions", ...):
#: ``shared``: every teammate's position and the moves lower ids chose this step (whatever the range);
#: ``comm``: only teammates within communication range (3-D distance <= ``comm_range``);
#: ``central``: one planner over the global belief (all readings, no channel noise): an upper
#: reference that no UAV on board can run, never a competitor.
KNOWLEDGE: tuple[str, ...] = ("shared", "comm", "central")


def strip_sums(density: np.ndarray, geometry: FieldGeometry) -> np.ndarray:
    """(S, S) sums of a per-cell density (grid, grid) over every gain-strip cell (rows = y strips)."""
    starts = np.flatnonzero(np.diff(geometry.strip_of_cell)) + 1
    starts = np.concatenate([[0], starts])
    return np.add.reduceat(np.add.reduceat(density, starts, axis=0), starts, axis=1)


def stored_probabilities() -> np.ndarray:
    """(TABLE_SIZE,) the probability ``global_belief`` reports for each stored log-odds value
    (row ``value + kernels.OFFSET``): a per-cell score of the belief is then one table lookup."""
    return kernels.probability(np.arange(kernels.TABLE_SIZE) - kernels.OFFSET)


def heard_matrix(positions_m: np.ndarray, comm_range: float) -> np.ndarray:
    """(N, N) bool: which teammates each UAV is within communication range of (itself included)."""
    gaps = np.linalg.norm(positions_m[:, None, :] - positions_m[None, :, :], axis=-1)
    return gaps <= comm_range


class AdaptiveGainPlanner(Planner):
    """Greedy (``lookahead=1``) or k-step expected-information-gain planner (module docstring).

    :param discount: share of a cell's gain lost once an earlier footprint of the team covers it (0..1)
    :param weighting: ``"class"`` (ipp-marl's class-weighted entropy) or ``"plain"`` (binary entropy);
        ``sb3_coma.evaluate`` passes the map family's :data:`WEIGHTING_BY_MAP` unless told otherwise
    :param lookahead: moves searched ahead per UAV (1 = AG, at most :data:`MAX_LOOKAHEAD`)
    :param knowledge: what a UAV knows of its teammates, one of :data:`KNOWLEDGE`
    """

    name = "ag"
    uses_env_state = True

    def __init__(
        self,
        venv: VecEnv,
        seed: int | None = None,
        discount: float = 0.5,
        weighting: str = "class",
        lookahead: int = 1,
        knowledge: str = "shared",
    ) -> None:
        super().__init__(venv, seed)
        # One row per option: (name, value, accepted, what is allowed); ``weighting`` is the
        # world's own rule (check_weighting, below).
        rules = (
            (
                "discount",
                discount,
                is_real(discount) and 0.0 <= discount <= 1.0,
                "must be a number in [0, 1]",
            ),
            (
                "lookahead",
                lookahead,
                is_whole(lookahead) and 1 <= lookahead <= MAX_LOOKAHEAD,
                f"an integer from 1 (greedy AG) to {MAX_LOOKAHEAD}",
            ),
            ("knowledge", knowledge, knowledge in KNOWLEDGE, f"choose one of {KNOWLEDGE}"),
        )
        for name, value, accepted, allowed in rules:
            if not accepted:
                raise ValueError(f"ag {name}={value!r}: {allowed}")
        self.discount = float(discount)
        self.weighting = check_weighting(weighting)
        self.lookahead = int(lookahead)
        self.knowledge = knowledge
        self.geometry: FieldGeometry = venv.get_attr("geometry", indices=[0])[0]
        self.config = venv.get_attr("config", indices=[0])[0]
        self._weighting_index = WEIGHTINGS.index(self.weighting)
        self._tables: np.ndarray | None = None
        #: Look-ahead scores of the last decision, (copies, N, 6), for inspection.
        self.last_scores: np.ndarray | None = None

    def _levels_flip(self) -> list[float]:
        return [float(self.config.flip_probability[a]) for a in self.config.altitudes]

    def _team_sums(self, copies: int) -> list[np.ndarray]:
        """Per copy, (N, A, S, S) the strip sums each UAV plans with."""
        if self.knowledge != "central":
            return [
                np.ascontiguousarray(s[:, self._weighting_index]) for s in self._per_copy("gain_strip_sums", copies)
            ]
        if self._tables is None:
            self._tables = self._density_tables()
        out = []
        for rows in self._table_rows(copies):
            levels = np.stack([strip_sums(table[rows], self.geometry) for table in self._tables])
            out.append(np.ascontiguousarray(np.broadcast_to(levels, (self.n_agents, *levels.shape))))
        return out

    def _density_tables(self) -> np.ndarray:
        """(A, TABLE_SIZE) the central planner's per-cell gain of each stored log-odds value, per
        altitude: the belief's cells take their value by lookup, not by logarithms per cell."""
        p = stored_probabilities()
        return np.stack([gain_density(p, q, self.weighting) for q in self._levels_flip()])

    def _table_rows(self, copies: int) -> list[np.ndarray]:
        """Per copy, (grid, grid) the row of :meth:`_density_tables` each cell of the global belief reads."""
        return [lo.astype(np.intp) + kernels.OFFSET for lo in self._per_copy("global_logodds", copies)]

    def _heard(self, copies: int) -> list[np.ndarray]:
        if self.knowledge != "comm":
            return [np.ones((self.n_agents, self.n_agents), dtype=bool)] * copies
        return [heard_matrix(p, float(self.config.comm_range)) for p in self._per_copy("positions_m", copies)]

    def _plan(self, observation: dict[str, np.ndarray], mask: np.ndarray, starts: np.ndarray) -> np.ndarray:
        copies = mask.shape[0]
        sums = self._team_sums(copies)
        heard = self._heard(copies)
        positions = self._per_copy("lattice_positions", copies)
        no_fly = self._per_copy("no_fly_columns", copies)
        actions = np.zeros((copies, self.n_agents), dtype=np.int64)
        scores = np.zeros((copies, self.n_agents, len(ACTION_DELTAS)))
        for c in range(copies):
            jitter = _JITTER * self.rng.random((self.n_agents, len(ACTION_DELTAS)))
            plan_team(
                sums[c],
                positions[c],
                mask[c],
                no_fly[c],
                ACTION_DELTAS,
                self.geometry.footprint_strips,
                self.discount,
                self.lookahead,
                jitter,
                heard[c],
                scores[c],
                actions[c],
            )
        self.last_scores = scores
        return actions
