"""The multi-UAV informative-path-planning world as a PettingZoo ``ParallelEnv``.

One instance is one mission: ``n_uavs`` UAVs on an 11 x 11 lattice at three altitudes sample a
binary ground truth with an altitude-dependent noisy camera, exchange their sensor maps over a
noisy channel, and are rewarded together for reducing the class-weighted entropy of the global
map (DESIGN section 3). All per-step work is bounded by the footprints' areas: the global belief
and everything derived from it are updated incrementally by :mod:`envs.kernels`.

Semantics worth knowing (also in ``docs/environment.md``):

* The budget counts decisions; each UAV also measures once at reset, so a mission has
  ``budget + 1`` measurements per UAV. The episode *terminates* (not truncates) after ``budget``
  steps: the remaining budget is part of the observation, so the end is a true terminal state.
* Actions are resolved in UAV order; a move that is invalid when executed (off the lattice, into
  a no-fly column, into a column another UAV occupies) means "hover". ``action_mask`` in the
  observation is computed from the current positions, so a masked policy never picks one.
* Sensor maps are exchanged on the communication grid (``comm_grid`` x ``comm_grid``, default
  44 x 44, about 1.14 m cells). A message carries the sender's id, position, altitude and its
  fresh footprint patch (fraction of cells read valuable per comm cell). The receiver writes the
  patch, as received through the noisy channel, into its copy of the sender's map and folds it
  into its local belief as soft evidence. Own data is never noised; the global map sees only
  true measurements.
"""
from __future__ import annotations

import functools
from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from . import gain, kernels, layout
from .config import ConfigError, IppConfig
from .geometry import FieldGeometry
from .maps import GroundTruth, load_ground_truth

#: (dx, dy, dz) of each action in lattice steps: 0 up(+z), 1 -x, 2 -y, 3 +y, 4 +x, 5 down(-z).
ACTION_DELTAS = np.array([(0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 1, 0), (1, 0, 0), (0, 0, -1)], dtype=np.int64)
#: Received values are clipped to this range so the observation stays inside a bounded Box;
#: the clip is 8 sigma beyond the loudest preset and never binds in practice.
RECEIVED_RANGE = (-0.5, 1.5)


class UavIppEnv(ParallelEnv):
    """Parameter-sharing multi-UAV IPP environment (see module docstring)."""

    metadata = {"name": "uav_ipp_v0", "render_modes": ["rgb_array", "ansi"], "is_parallelizable": True}

    def __init__(self, config: IppConfig | None = None) -> None:
        self.config = config if config is not None else IppConfig()
        self.config.validate()
        cfg = self.config
        self.render_mode = cfg.render_mode
        self.n_uavs = cfg.n_uavs
        self.possible_agents = [f"uav_{i}" for i in range(cfg.n_uavs)]
        self.agents: list[str] = []
        self.geometry = FieldGeometry(cfg)
        self._lut = _table(cfg.reward_entropy)
        self._alt_levels = len(cfg.altitudes)
        self._increments = np.array([kernels.fixed_point_increment(cfg.flip_probability[a]) for a in cfg.altitudes])
        self._local_increments = self._increments / kernels.SCALE
        self._thresholds = np.array([kernels.flip_threshold(cfg.flip_probability[a]) for a in cfg.altitudes])
        self._noise_low, self._noise_sigma = cfg.noise_params
        n, r = cfg.n_uavs, cfg.comm_grid
        self._slots = np.array([[s + 1 if s < i else s for s in range(n)] for i in range(n)], dtype=np.int64)
        for i in range(n):
            self._slots[i, i] = 0
        self._truth: GroundTruth | None = None
        if cfg.map_seed is not None or cfg.map_path is not None or cfg.map_name != "env1":
            self._set_truth(self._load_truth(cfg.map_seed if cfg.map_seed is not None else 0))
        self._rng = np.random.default_rng()
        self._state = np.ones(1, dtype=np.uint64)       # sensor flips
        self._comm_state = np.ones(1, dtype=np.uint64)  # channel noise: its own stream, so the
        # noise preset never changes which cells flip (the global map must not see the channel)
        if cfg.action_gain:
            self._gain_counts = gain.axis_counts(self.geometry)
            self._gain_flips = np.array([cfg.flip_probability[a] for a in cfg.altitudes], dtype=np.float64)
        self._build_spaces(n, r)
        self._steps = 0

    # ------------------------------------------------------------------ spaces
    def _build_spaces(self, n: int, r: int) -> None:
        L = self.config.lattice
        entries = {
            layout.KEY_LOCAL: spaces.Box(0.0, 1.0, (layout.RAW_LOCAL_CHANNELS, L, L), np.float32),
            layout.KEY_RECEIVED: spaces.Box(*RECEIVED_RANGE, (n, r, r), np.float32),
            layout.KEY_RECEIVED_VALID: spaces.Box(0.0, 1.0, (n,), np.float32),
            layout.KEY_STATE: spaces.Box(0.0, 1.0, (layout.STATE_CHANNELS, L, L), np.float32),
            layout.KEY_MASK: spaces.Box(0, 1, (layout.N_ACTIONS,), np.int8),
        }
        if self.config.action_gain:
            entries[layout.KEY_GAIN] = spaces.Box(-1.0, 1.0, (len(layout.GAIN_WEIGHTINGS), layout.N_ACTIONS), np.float32)
        self._observation_space = spaces.Dict(entries)
        self._action_space = spaces.Discrete(layout.N_ACTIONS)

    @functools.lru_cache(maxsize=None)
    def observation_space(self, agent: str) -> spaces.Dict:
        return self._observation_space

    @functools.lru_cache(maxsize=None)
    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_space

    # ------------------------------------------------------------------ maps
    def _load_truth(self, seed: int) -> GroundTruth:
        cfg = self.config
        return load_ground_truth(cfg.map_name, seed=seed, map_path=cfg.map_path, valuable=cfg.valuable,
                                 grid=cfg.grid, lattice=cfg.lattice)

    def _set_truth(self, truth: GroundTruth) -> None:
        self._truth = truth
        self._truth_u8 = np.ascontiguousarray(truth.valuable, dtype=np.uint8)
        self._n_valuable = int(self._truth_u8.sum())
        self._no_fly = np.ascontiguousarray(truth.no_fly, dtype=np.bool_)

    @property
    def ground_truth(self) -> GroundTruth:
        if self._truth is None:
            raise RuntimeError("call reset() first: this env draws a new map at every reset (map_seed=None)")
        return self._truth

    # ------------------------------------------------------------------ positions
    def _default_columns(self) -> list[tuple[int, int]]:
        """Well-spread start columns: the configured corners first, then centre, edges, the rest."""
        L = self.config.lattice
        lo, hi, mid = round(0.2 * (L - 1)), round(0.8 * (L - 1)), (L - 1) // 2
        preferred = [(lo, lo), (hi, lo), (hi, hi), (lo, hi), (mid, mid), (mid, lo), (hi, mid), (mid, hi), (lo, mid)]
        preferred += [(x, y) for y in range(L) for x in range(L)]
        seen: set[tuple[int, int]] = set()
        columns = []
        for c in preferred:
            if c in seen or self._no_fly[c[1], c[0]]:
                continue
            seen.add(c)
            columns.append(c)
        return columns

    def _start_positions(self) -> np.ndarray:
        cfg, n = self.config, self.config.n_uavs
        start_level = cfg.altitudes.index(cfg.start_altitude)
        if cfg.start_positions is not None:
            pos = np.array([(round(x / cfg.spacing), round(y / cfg.spacing), cfg.altitudes.index(z))
                            for x, y, z in cfg.start_positions], dtype=np.int64)
            bad = [tuple(p) for p in cfg.start_positions if self._no_fly[round(p[1] / cfg.spacing), round(p[0] / cfg.spacing)]]
            if bad:
                raise ConfigError(f"invalid option start_positions={bad!r}: these columns are no-fly on map {self.ground_truth.name!r}")
            return pos
        free = self._default_columns()
        if len(free) < n:
            raise ConfigError(f"invalid option n_uavs={n}: map {self.ground_truth.name!r} has only {len(free)} flyable columns")
        if cfg.start == "random":
            pick = self._rng.choice(len(free), size=n, replace=False)
            cols = [free[k] for k in pick]
        else:
            cols = free[:n]
        return np.array([(x, y, start_level) for x, y in cols], dtype=np.int64)

    def positions_m(self) -> np.ndarray:
        """(N, 3) UAV positions in metres (x, y, z)."""
        s = self.config.spacing
        alts = np.asarray(self.config.altitudes)
        return np.column_stack([self._pos[:, 0] * s, self._pos[:, 1] * s, alts[self._pos[:, 2]]])

    def action_masks(self) -> np.ndarray:
        """(N, 6) int8 validity of every action from the current positions (1 = valid).

        int8 because gymnasium's ``Discrete.sample(mask=...)`` (and PettingZoo's API test) take
        exactly that dtype.

        Invalid: off the lattice or the altitude range, into a no-fly column, or horizontally into
        a column another UAV occupies now. If nothing is valid (boxed in with a single altitude)
        action 0 is marked valid and acts as a hover, so a masked distribution always exists.
        """
        out = np.empty((self.n_uavs, layout.N_ACTIONS), dtype=np.int8)
        kernels.action_masks(self._pos, self._no_fly, self._alt_levels, ACTION_DELTAS, out)
        return out

    def _apply_actions(self, actions: np.ndarray) -> np.ndarray:
        """Move the UAVs in id order; an invalid move hovers. Returns which moves were executed."""
        executed = np.zeros(self.n_uavs, dtype=np.bool_)
        kernels.apply_actions(self._pos, actions, self._no_fly, self._alt_levels, ACTION_DELTAS, executed)
        return executed

    # ------------------------------------------------------------------ reset / step
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        cfg = self.config
        if self._truth is None or (cfg.map_seed is None and cfg.map_path is None and cfg.map_name == "env1"):
            self._set_truth(self._load_truth(int(self._rng.integers(0, 2**31 - 1))))
        self._state[0] = np.uint64(int(self._rng.integers(1, 2**63 - 1)))
        self._comm_state[0] = np.uint64(int(self._rng.integers(1, 2**63 - 1)))
        n, R, G, L = self.n_uavs, cfg.comm_grid, cfg.grid, cfg.lattice
        geo = self.geometry
        self.agents = list(self.possible_agents)
        self._budget_left = cfg.budget
        self._steps = 0
        self._pos = self._start_positions()
        self._logodds = np.zeros((G, G), dtype=np.int16)
        self._measured = np.zeros((G, G), dtype=np.uint8)
        self._block_prob = 0.5 * geo.block_area
        self._block_ent = geo.block_area.copy()
        self._block_cov = np.zeros((L, L), dtype=np.float64)
        self._went_total = float(kernels.reward_entropy(np.array(0.5), cfg.reward_entropy)) * G * G
        self._ent_true = float(self._n_valuable)
        self._tp = 0
        self._pp = 0
        self._local_logodds = np.zeros((n, R, R), dtype=np.float32)
        self._local_prob = np.full((n, R, R), 0.5, dtype=np.float32)
        self._local_ent = np.ones((n, R, R), dtype=np.float32)
        self._local_agg = np.empty((n, 3, L, L), dtype=np.float64)
        self._local_agg[:, 0:2] = 0.5
        self._local_agg[:, 2] = 1.0
        self._received = np.full((n, n, R, R), 0.5, dtype=np.float32)
        self._received_valid = np.zeros((n, n), dtype=np.float32)
        self._received_valid[:, 0] = 1.0
        self._visits = np.zeros((n, L, L), dtype=np.float32)
        self._links = np.eye(n, dtype=bool)
        self._trajectory: list[np.ndarray] = []
        self._measure_all()
        self._mark_visits()
        observations = self._observations()
        infos = {agent: {} for agent in self.agents}
        return observations, infos

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called on a finished mission: call reset() first")
        acts = self._parse_actions(actions)
        h_before = self._went_total
        score_before = _score(self.metrics()) if self.config.reward == "metrics" else 0.0
        self._apply_actions(acts)
        self._budget_left -= 1
        self._steps += 1
        self._measure_all()
        self._mark_visits()
        cfg = self.config
        h_after = self._went_total
        metrics = self.metrics()
        if cfg.reward == "metrics":
            reward = cfg.alpha * (_score(metrics) - score_before) + cfg.beta
        else:
            reward = cfg.alpha * (h_before - h_after) / h_before + cfg.beta if h_before > 0 else cfg.beta
        done = self._budget_left <= 0
        observations = self._observations()
        rewards = {a: float(reward) for a in self.agents}
        terminations = {a: done for a in self.agents}
        truncations = {a: False for a in self.agents}
        infos = {a: dict(metrics) for a in self.agents}
        if done:
            self.agents = []
        return observations, rewards, terminations, truncations, infos

    def _parse_actions(self, actions: dict[str, Any]) -> np.ndarray:
        if not isinstance(actions, dict):
            raise TypeError(f"actions must be a dict agent -> action, got {type(actions).__name__}")
        unknown = sorted(set(actions) - set(self.possible_agents))
        if unknown:
            raise ValueError(f"unknown agent(s) {unknown} in actions; agents are {self.possible_agents}")
        acts = np.zeros(self.n_uavs, dtype=np.int64)  # a missing agent moves "up" unless masked -> hovers
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"missing action(s) for {missing}; every live agent must act")
        for i, agent in enumerate(self.possible_agents):
            value = actions[agent]
            try:
                a = int(np.asarray(value).item())
            except (TypeError, ValueError, OverflowError):  # OverflowError: an infinite float
                raise ValueError(f"action for {agent} must be an integer in 0..5, got {value!r}") from None
            if a != np.asarray(value).item() or not 0 <= a < layout.N_ACTIONS:
                raise ValueError(f"action for {agent} must be an integer in 0..5, got {value!r}")
            acts[i] = a
        return acts

    # ------------------------------------------------------------------ measurement + comms
    def _measure_all(self) -> None:
        cfg, geo = self.config, self.geometry
        n, R = self.n_uavs, cfg.comm_grid
        comm_sum = np.zeros((n, R, R), dtype=np.float32)
        comm_cnt = np.zeros((n, R, R), dtype=np.float32)
        boxes = []
        for i in range(n):
            ix, iy, lev = (int(v) for v in self._pos[i])
            fp = geo.footprint(ix, iy, lev)
            d_went, d_ent, d_tp, d_pp = kernels.measure_global(
                self._logodds, self._truth_u8, self._measured, fp.r0, fp.r1, fp.c0, fp.c1,
                int(self._increments[lev]), int(self._thresholds[lev]), self._state,
                self._lut, geo.block_of_cell, geo.comm_of_cell,
                self._block_prob, self._block_ent, self._block_cov, comm_sum[i], comm_cnt[i])
            self._went_total += d_went
            self._ent_true += d_ent
            self._tp += d_tp
            self._pp += d_pp
            boxes.append((geo.comm_of_cell[fp.r0], geo.comm_of_cell[fp.r1 - 1] + 1,
                          geo.comm_of_cell[fp.c0], geo.comm_of_cell[fp.c1 - 1] + 1))
        fresh_mask = comm_cnt >= 0.5 * geo.comm_cell_area[None]
        fresh = comm_sum / np.maximum(comm_cnt, 1.0)
        pos_m = self.positions_m()
        self._trajectory.append(pos_m)  # one position read per measurement serves both
        dist = np.linalg.norm(pos_m[:, None, :] - pos_m[None, :, :], axis=-1)
        links = dist <= cfg.comm_range
        if cfg.drop_probability > 0:
            links &= self._rng.random((n, n)) >= cfg.drop_probability
        np.fill_diagonal(links, True)
        self._links = links  # links[r, s]: r received s's message this step
        for s in range(n):
            cr0, cr1, cc0, cc1 = boxes[s]
            kernels.communicate(s, fresh[s], fresh_mask[s], cr0, cr1, cc0, cc1,
                                float(self._local_increments[self._pos[s, 2]]), links[:, s], dist[:, s],
                                float(cfg.comm_range), self._noise_low, self._noise_sigma, self._slots,
                                self._received, self._received_valid, self._local_logodds,
                                self._local_prob, self._local_ent, self._local_agg,
                                geo.comm_blocks, geo.comm_weights, self._comm_state)

    def _mark_visits(self) -> None:
        cur = self._visits == 1.0
        self._visits[cur] = 0.5
        self._visits[np.arange(self.n_uavs), self._pos[:, 1], self._pos[:, 0]] = 1.0

    # ------------------------------------------------------------------ observations / metrics
    def _observations(self) -> dict[str, dict[str, np.ndarray]]:
        cfg, geo = self.config, self.geometry
        n, L = self.n_uavs, cfg.lattice
        local = np.zeros((n, layout.RAW_LOCAL_CHANNELS, L, L), dtype=np.float32)
        local[:, layout.BUDGET] = self._budget_left / cfg.budget
        local[:, layout.AGENT_ID] = ((np.arange(n) + 1) / n)[:, None, None]
        alt_ratio = np.asarray(cfg.altitudes, dtype=np.float32)[self._pos[:, 2]] / max(cfg.altitudes)
        r_idx, s_idx = np.nonzero(self._links)
        local[r_idx, layout.ALTITUDE, self._pos[s_idx, 1], self._pos[s_idx, 0]] = alt_ratio[s_idx]
        local[:, layout.FOOTPRINT] = self._visits
        local[:, layout.SENSOR:layout.BELIEF_ENTROPY + 1] = self._local_agg
        np.clip(local[:, layout.SENSOR:], 0.0, 1.0, out=local[:, layout.SENSOR:])
        area = geo.block_area
        state = np.stack([self._block_prob / area, self._block_ent / area, self._block_cov / area]).astype(np.float32)
        np.clip(state, 0.0, 1.0, out=state)
        masks = self.action_masks()
        received = self._received.copy()
        valid = self._received_valid.copy()
        observations = {
            agent: {
                layout.KEY_LOCAL: local[i],
                layout.KEY_RECEIVED: received[i],
                layout.KEY_RECEIVED_VALID: valid[i],
                layout.KEY_STATE: state,
                layout.KEY_MASK: masks[i],
            }
            for i, agent in enumerate(self.possible_agents)
        }
        if cfg.action_gain:
            gains = gain.action_gains(self._local_prob, self._pos, masks, self._gain_counts, self._gain_flips,
                                      ACTION_DELTAS, layout.GAIN_WEIGHTINGS)  # (N, 2, 6)
            for i, agent in enumerate(self.possible_agents):
                observations[agent][layout.KEY_GAIN] = gains[i]
        return observations

    def metrics(self) -> dict[str, float]:
        """F1 of (global belief > 0.5) vs truth, mean entropy (bits) over valuable cells, and more."""
        denom = self._pp + self._n_valuable
        f1 = 2.0 * self._tp / denom if denom > 0 else 0.0
        entropy = self._ent_true / self._n_valuable if self._n_valuable > 0 else 0.0
        return {
            "f1": float(f1),
            "entropy": float(max(entropy, 0.0)),
            "reward_entropy": float(self._went_total),
            "coverage": float(self._block_cov.sum() / self.config.grid ** 2),
            "budget_left": int(self._budget_left),
        }

    # ------------------------------------------------------------------ inspection helpers
    def global_belief(self) -> np.ndarray:
        """(grid, grid) probability that each cell is valuable (float32)."""
        return (1.0 / (1.0 + np.exp(-self._logodds.astype(np.float32) / kernels.SCALE))).astype(np.float32)

    def local_beliefs(self) -> np.ndarray:
        """(N, R, R) each UAV's local belief on the communication grid."""
        return self._local_prob.copy()

    def sensor_maps(self) -> np.ndarray:
        """(N, R, R) each UAV's own clean sensor map (0.5 where never observed)."""
        return self._received[:, 0].copy()

    def trajectory(self) -> np.ndarray:
        """(steps + 1, N, 3) positions in metres since the last reset."""
        return np.stack(self._trajectory)

    # ------------------------------------------------------------------ render / close
    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called with render_mode=None; pass render_mode='rgb_array' to make_env")
            return None
        if self.render_mode == "ansi":
            m = self.metrics()
            pos = ", ".join(f"({x:g},{y:g},{z:g})" for x, y, z in self.positions_m())
            return f"step {self._steps}/{self.config.budget} f1={m['f1']:.3f} entropy={m['entropy']:.3f} uavs={pos}"
        from .render import render_rgb
        return render_rgb(self)

    def close(self) -> None:
        pass


def _score(metrics: dict[str, float]) -> float:
    """F1 minus the entropy over valuable cells: ``reward="metrics"`` pays its change, so a
    mission's return is ``alpha`` times the gain in both Table I metrics."""
    return metrics["f1"] - metrics["entropy"]


@functools.lru_cache(maxsize=2)
def _table(kind: str) -> np.ndarray:
    return kernels.build_table(kind)
