"""The multi-UAV informative-path-planning world as a PettingZoo ``ParallelEnv``.

One instance is one mission: ``n_uavs`` UAVs on an 11 x 11 lattice at three altitudes sample a
binary ground truth with an altitude-dependent noisy camera, exchange their sensor maps over a
noisy channel, and are rewarded together for reducing the class-weighted entropy of the global
map (docs/design.md, "The world"). All per-step work is bounded by the footprints' areas: the global belief
and everything derived from it are updated incrementally by :mod:`uav_ipp.kernels`.

Semantics worth knowing (also in ``docs/environment.md``):

* The budget counts decisions; each UAV also measures once at reset, so a mission has
  ``budget + 1`` measurements per UAV. The episode *terminates* (not truncates) after ``budget``
  steps: the remaining budget is part of the observation, so the end is a true terminal state.
* Actions are resolved in UAV order; a move that is invalid when executed (off the lattice, into
  a no-fly column, into a column another UAV occupies) means "hover". ``action_mask`` in the
  observation is computed from the current positions, so a masked policy never picks one.
* Every UAV keeps its own local belief M_i on the belief grid (the same fixed-point log-odds as
  the global map). Its own readings update M_i exactly as they update the global map. A message
  (id, position, altitude, the 0/1 image of this step's footprint) reaches every UAV within
  ``comm_range`` through the paper's channel, cell by cell ``I_r = a I + n``, and the receiver's
  ``decoder`` folds it into M_i. Own data is never noised; the global map sees only true
  measurements. ``received`` holds each sender's latest patch as the comm-grid average of I_r.
* ``infos`` carry the paper's metrics on the global map (``f1``, ``entropy``) and the team metrics
  on the M_i (``team_f1``, ``team_entropy``) at every step.
* Randomness is counter-based (common random numbers, ``kernels.stream_key``): a sensor flip is a
  hash of (mission seed, step, UAV, cell), channel noise of (seed, step, sender, receiver, cell),
  a message drop of (seed, step, sender, receiver); the mission seed is the reset seed. Two plans
  that take the same measurement on the same seeded mission get the same reading, bit for bit.
"""

from __future__ import annotations

import functools
import math
import warnings
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from . import gain, kernels, layout
from .config import ConfigError, IppConfig, invalid_option, is_whole
from .gain import WEIGHTINGS
from .geometry import FieldGeometry
from .maps import GroundTruth, load_ground_truth
from .maps.ground_truth import check_grid

#: (dx, dy, dz) of each action in lattice steps: 0 up(+z), 1 -x, 2 -y, 3 +y, 4 +x, 5 down(-z).
ACTION_DELTAS = np.array([(0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 1, 0), (1, 0, 0), (0, 0, -1)], dtype=np.int64)
#: Below this many valuable cells the mission metrics are warned about (a few cells decide F1).
MIN_VALUABLE_CELLS = 100
#: Received values are clipped to this range so the observation stays inside a bounded Box;
#: the clip is 8 sigma beyond the loudest preset and never binds in practice.
RECEIVED_RANGE = (-0.5, 1.5)


class UavIppEnv(ParallelEnv):
    """Parameter-sharing multi-UAV IPP environment (see module docstring)."""

    metadata: ClassVar[dict[str, Any]] = {
        "name": "uav_ipp_v0",
        "render_modes": ["rgb_array", "ansi"],
        "is_parallelizable": True,
    }

    def __init__(self, config: IppConfig | None = None) -> None:
        self.config = config if config is not None else IppConfig()  # valid by construction
        cfg = self.config
        check_grid(cfg.grid, cfg.lattice)  # before the maps are allocated: a huge grid is one clear line
        self.render_mode = cfg.render_mode
        self.n_uavs = cfg.n_uavs
        self.possible_agents = [f"uav_{i}" for i in range(cfg.n_uavs)]
        self.agents: list[str] = []
        self.geometry = FieldGeometry(cfg)
        flips = [cfg.flip_probability[a] for a in cfg.altitudes]
        self._gtab = _global_table(cfg.reward_entropy)
        self._ltab = _local_table(tuple(flips))
        self._normals = _normals()
        self._alt_levels = len(cfg.altitudes)
        self._increments = np.array([kernels.fixed_point_increment(q) for q in flips], dtype=np.int64)
        self._gstep = kernels.step_table(self._gtab, self._increments)
        self._lstep = kernels.step_table(self._ltab, self._increments)
        self._thresholds = np.array([kernels.flip_threshold(q) for q in flips], dtype=np.int64)
        self._alpha_low, self._sigma = cfg.noise_params
        n = cfg.n_uavs
        self._allocate(n)  # before any map: the truth is copied into the kernels' buffer
        self._redraw_map = cfg.map_path is None and (cfg.split != "paper" or cfg.map_seed is None)
        self._rng = np.random.default_rng()
        self._truth: GroundTruth | None = None
        if not self._redraw_map:
            self._set_truth(self._load_truth(cfg.map_seed if cfg.map_seed is not None else 0))
            self._start_positions()  # a fixed map: bad starts fail at construction, not at the first reset
        # Mission seed of the counter-based draws (sensor flips, channel noise, drops; kernels.stream_key):
        # the reset seed, so every draw is a function of (seed, step, ids, cell) and never of the plan.
        self._seed = kernels.mission_seed(0)
        # mission_from_seed: the last reset seed, and how far an unseeded reset (a vec env's
        # auto-reset) moves on from it: the vec env sets its copy count, so copy e of n flies
        # missions s + e, s + e + n, ... and n copies fly the consecutive missions s, s + 1, ...
        self._mission: int | None = None
        self.mission_stride = 1
        self._build_spaces(n, cfg.comm_grid)
        self._steps = 0

    def _allocate(self, n: int) -> None:
        """Arrays that live as long as the env; :meth:`reset` only refills them.

        The kernels see the state as a few named tuples of arrays (``kernels.GlobalMaps``, ...),
        built here once; the env keeps short names for the same arrays (no copies).
        """
        cfg, geo = self.config, self.geometry
        G, L = cfg.grid, cfg.lattice
        self._tables = kernels.Tables(
            self._gstep, self._lstep, self._ltab, self._normals, self._increments, self._thresholds
        )
        self._kernel_geometry = geo.kernel_geometry()
        self._comm_area = self._kernel_geometry.comm_area
        self._global_maps = kernels.GlobalMaps.blank(G, L)
        self._truth_u8, self._logodds, self._measured, self._g_block, self._g_scal = self._global_maps
        self._local_maps = kernels.LocalMaps.blank(n, G, L, geo.n_strips, cfg.comm_grid)
        self._local_logodds, self._l_block, self._l_fine, self._l_strip, self._l_scal = self._local_maps
        self._comm = kernels.CommState.blank(n, geo.max_footprint, cfg.comm_grid)
        self._readings, self._received, self._received_valid, self._comm_sum, self._comm_cnt, self._slots = self._comm
        links, bound = np.zeros((n, n), dtype=np.bool_), np.ones((n, n), dtype=np.float64)
        self._channel = kernels.Channel(links, bound, float(self._sigma), cfg.decoder == "soft")
        self._masks = np.zeros((n, layout.N_ACTIONS), dtype=np.int8)
        self._gains = np.zeros((n, len(layout.GAIN_WEIGHTINGS), layout.N_ACTIONS), dtype=np.float64)
        self._visits = np.zeros((n, L, L), dtype=np.float32)
        self._moves = np.zeros(n, dtype=np.int64)  # each UAV's executed move this step (intent, v3)
        self._uav_index = np.arange(n)
        self._id_ratio = ((np.arange(n) + 1) / n).astype(np.float32)[:, None, None]
        self._alt_ratio = (np.asarray(cfg.altitudes) / max(cfg.altitudes)).astype(np.float32)
        prior = self._ltab[kernels.OFFSET].astype(np.float64)
        self._strip_prior = prior[kernels.L_GAIN0 :, None, None] * np.outer(geo.strip_cells, geo.strip_cells)[None]

    # ------------------------------------------------------------------ spaces
    def _build_spaces(self, n: int, r: int) -> None:
        L = self.config.lattice
        v3 = self.config.observation == "v3"
        local_channels = layout.RAW_LOCAL_CHANNELS + (layout.V3_LOCAL_EXTRA if v3 else 0)
        state_channels = layout.STATE_CHANNELS + (layout.V3_STATE_EXTRA if v3 else 0)
        entries: dict[str, spaces.Space] = {
            layout.KEY_LOCAL: spaces.Box(0.0, 1.0, (local_channels, L, L), np.float32),
            layout.KEY_RECEIVED: spaces.Box(*RECEIVED_RANGE, (n, r, r), np.float32),
            layout.KEY_RECEIVED_VALID: spaces.Box(0.0, 1.0, (n,), np.float32),
            layout.KEY_STATE: spaces.Box(0.0, 1.0, (state_channels, L, L), np.float32),
            layout.KEY_MASK: spaces.Box(0, 1, (layout.N_ACTIONS,), np.int8),
        }
        if self.config.action_gain:
            entries[layout.KEY_GAIN] = spaces.Box(
                -1.0, 1.0, (len(layout.GAIN_WEIGHTINGS), layout.N_ACTIONS), np.float32
            )
        self._observation_space = spaces.Dict(entries)
        self._action_space = spaces.Discrete(layout.N_ACTIONS)

    def observation_space(self, agent: str) -> spaces.Dict:
        """The same Dict space for every agent (parameter sharing); the object itself, never a copy."""
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Discrete:
        return self._action_space

    # ------------------------------------------------------------------ maps
    def _load_truth(self, seed: int) -> GroundTruth:
        cfg = self.config
        return load_ground_truth(
            cfg.map_name,
            seed=seed,
            map_path=cfg.map_path,
            valuable=cfg.valuable,
            grid=cfg.grid,
            lattice=cfg.lattice,
            split=cfg.split,
        )

    def _set_truth(self, truth: GroundTruth) -> None:
        # _load_truth asks for the config's grid, so the shapes agree by construction
        assert truth.valuable.shape == self._truth_u8.shape, (truth.name, truth.valuable.shape)
        self._truth = truth
        np.copyto(self._truth_u8, truth.valuable, casting="unsafe")
        self._n_valuable = int(self._truth_u8.sum())
        self._truth_blocks = self.geometry.block_sums(self._truth_u8)  # valuable cells per block
        if self._n_valuable < MIN_VALUABLE_CELLS:
            warnings.warn(
                f"map {truth.name!r} has only {self._n_valuable} valuable cell(s): F1 and the entropy over "
                f"valuable cells measure almost nothing on it (fewer than {MIN_VALUABLE_CELLS})",
                stacklevel=3,
            )
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
            pos = np.array(
                [
                    (round(x / cfg.spacing), round(y / cfg.spacing), cfg.altitudes.index(z))
                    for x, y, z in cfg.start_positions
                ],
                dtype=np.int64,
            )
            bad = [
                tuple(p)
                for p in cfg.start_positions
                if self._no_fly[round(p[1] / cfg.spacing), round(p[0] / cfg.spacing)]
            ]
            if bad:
                invalid_option("start_positions", bad, f"these columns are no-fly on map {self.ground_truth.name!r}")
            return pos
        free = self._default_columns()
        if len(free) < n:
            invalid_option("n_uavs", n, f"map {self.ground_truth.name!r} has only {len(free)} flyable columns")
        if cfg.start_rule == "random":
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
        np.copyto(self._moves, np.where(executed, actions, 0))  # a hover counts as "up": no heading
        return executed

    # ------------------------------------------------------------------ reset / step
    def reset(self, seed: int | None = None, options: dict | None = None):
        cfg, geo = self.config, self.geometry
        if seed is None and cfg.mission_from_seed and self._mission is not None:
            seed = self._mission + self.mission_stride  # the next mission of this copy's sequence
        if seed is not None:
            if not is_whole(seed) or seed < 0:
                raise ConfigError(f"invalid reset seed={seed!r}: an integer >= 0 or None")
            self._rng = np.random.default_rng(seed)
            self._mission = int(seed)
        if self._redraw_map:
            drawn = int(self._rng.integers(0, 2**31 - 1))  # drawn either way: start positions stay as they were
            # mission_from_seed: the reset seed names the split's mission itself (scenes.pick), so
            # consecutive seeds visit every scene equally (the validation protocol); else a drawn one.
            self._set_truth(self._load_truth(seed if cfg.mission_from_seed and seed is not None else drawn))
        # Two draws as in the sequential-stream world, so maps and start positions of every seed are
        # unchanged; the first seeds the noise of a reset without seed (unseeded runs still vary).
        derived = int(self._rng.integers(1, 2**63 - 1))
        self._rng.integers(1, 2**63 - 1)
        self._seed = kernels.mission_seed(seed if seed is not None else derived)
        self.agents = list(self.possible_agents)
        self._budget_left = cfg.budget
        self._steps = 0
        self._pos = self._start_positions()
        self._logodds.fill(0)
        self._measured.fill(0)
        self._local_logodds.fill(0)
        self._g_block[0] = 0.5 * geo.block_area
        self._g_block[1] = geo.block_area
        self._g_block[2] = 0.0
        self._g_block[3] = 0.5 * self._truth_blocks
        g0 = self._gtab[kernels.OFFSET]
        self._g_scal[:] = (float(g0[kernels.G_REWARD]) * cfg.grid**2, float(self._n_valuable), 0.0, 0.0)
        self._l_block[:, 0] = 0.5 * geo.block_area
        self._l_block[:, 1] = geo.block_area
        self._l_fine[:, 0] = 0.5 * self._comm_area
        self._l_fine[:, 1] = self._comm_area
        self._moves.fill(0)  # "up" at a reset: intent marks where each teammate is
        self._l_strip[:] = self._strip_prior
        self._l_scal[:] = (float(self._n_valuable), 0.0, 0.0)
        self._received.fill(0.5)
        self._received_valid.fill(0.0)
        self._received_valid[:, 0] = 1.0
        self._visits.fill(0.0)
        self._trajectory: list[np.ndarray] = []
        self._measure_all()
        self._mark_visits()
        observations = self._observations()
        infos: dict[str, dict[str, Any]] = {agent: {} for agent in self.agents}
        return observations, infos

    def step(self, actions: dict[str, Any]):
        if not self.agents:
            raise RuntimeError("step() called on a finished mission: call reset() first")
        acts = self._parse_actions(actions)
        cfg = self.config
        h_before = self._g_scal[kernels.S_REWARD]
        score_before = _score(self._global_metrics()) if cfg.reward == "metrics" else 0.0
        self._apply_actions(acts)
        self._budget_left -= 1
        self._steps += 1
        self._measure_all()
        self._mark_visits()
        metrics = self.metrics()
        if cfg.reward == "metrics":
            reward = cfg.alpha * (_score(metrics) - score_before) + cfg.beta
        else:
            h_after = self._g_scal[kernels.S_REWARD]
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
        missing = [a for a in self.agents if a not in actions]
        if unknown or missing:  # one rule: the actions name exactly the live agents
            wrong = "; ".join(
                part for part in (unknown and f"unknown agent(s) {unknown}", missing and f"missing {missing}") if part
            )
            raise ValueError(
                f"{wrong} in actions: every live agent must act, and the agents are {self.possible_agents}"
            )
        acts = np.zeros(self.n_uavs, dtype=np.int64)
        for i, agent in enumerate(self.possible_agents):
            value = actions[agent]
            if type(value) is int and 0 <= value < layout.N_ACTIONS:  # the common case, no numpy
                acts[i] = value
                continue
            try:
                a = int(np.asarray(value).item())
                valid = a == np.asarray(value).item() and 0 <= a < layout.N_ACTIONS
            except (TypeError, ValueError, OverflowError):  # OverflowError: an infinite float
                valid = False
            if not valid:
                raise ValueError(f"action for {agent} must be an integer in 0..5, got {value!r}")
            acts[i] = a
        return acts

    # ------------------------------------------------------------------ measurement + comms
    def _links(self, pos_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which messages arrive this step, ``links[r, s]``, and each link's attenuation bound.

        Single hop, positions after the move, 3-D distance within ``comm_range``; each message is
        lost whole with ``drop_probability``. ``attenuation="distance"`` lowers the bound of
        ``a ~ U(bound, 1)`` linearly from 1 at distance 0 to ``alpha_low`` at the range.
        """
        cfg, n = self.config, self.n_uavs
        dist = np.linalg.norm(pos_m[:, None, :] - pos_m[None, :, :], axis=-1)
        links = dist <= cfg.comm_range
        if cfg.drop_probability > 0:
            # keyed on (seed, step, sender, receiver): a message's fate does not depend on the plan
            draws = np.empty((n, n), dtype=np.float64)
            kernels.link_uniforms(self._seed, self._steps, draws)
            links &= draws >= cfg.drop_probability
        np.fill_diagonal(links, True)
        if cfg.attenuation == "distance" and 0.0 < cfg.comm_range < math.inf:
            frac = np.minimum(dist / cfg.comm_range, 1.0)
            bound = 1.0 - (1.0 - self._alpha_low) * frac
        else:
            bound = np.full((n, n), self._alpha_low)
        return links, bound

    def _measure_all(self) -> None:
        """Every UAV measures; every message in range is delivered and decoded (one kernel call)."""
        pos_m = self.positions_m()
        self._trajectory.append(pos_m)  # one position read per measurement serves both
        links, bound = self._links(pos_m)
        self._links_now = links  # links[r, s]: r received s's message this step
        np.copyto(self._channel.links, links)
        np.copyto(self._channel.bound, bound)
        kernels.measure_and_communicate(
            self._seed,
            self._steps,
            self._pos,
            self._channel,
            self._tables,
            self._kernel_geometry,
            self._global_maps,
            self._local_maps,
            self._comm,
        )

    def _mark_visits(self) -> None:
        np.minimum(self._visits, 0.5, out=self._visits)
        self._visits[self._uav_index, self._pos[:, 1], self._pos[:, 0]] = 1.0

    # ------------------------------------------------------------------ observations / metrics
    def _observations(self) -> dict[str, dict[str, np.ndarray]]:
        cfg, geo = self.config, self.geometry
        n, L = self.n_uavs, cfg.lattice
        area = geo.block_area
        local = np.empty((n, layout.RAW_LOCAL_CHANNELS, L, L), dtype=np.float32)
        local[:, layout.BUDGET] = self._budget_left / cfg.budget
        local[:, layout.AGENT_ID] = self._id_ratio
        local[:, layout.ALTITUDE] = 0.0
        alt_ratio = self._alt_ratio[self._pos[:, 2]]
        r_idx, s_idx = np.nonzero(self._links_now)
        local[r_idx, layout.ALTITUDE, self._pos[s_idx, 1], self._pos[s_idx, 0]] = alt_ratio[s_idx]
        local[:, layout.FOOTPRINT] = self._visits
        local[:, layout.SENSOR] = geo.to_lattice(self._received[:, 0])
        local[:, layout.BELIEF : layout.BELIEF_ENTROPY + 1] = self._l_block / area
        np.clip(local[:, layout.SENSOR :], 0.0, 1.0, out=local[:, layout.SENSOR :])
        state = (self._g_block[: layout.STATE_CHANNELS] / area).astype(np.float32)
        if cfg.observation == "v3":
            local = np.concatenate([local, self._intent(), self._fine_view()], axis=1)
            state = np.concatenate([state, self._privileged_state()], axis=0)
        np.clip(state, 0.0, 1.0, out=state)
        masks = self._masks
        kernels.action_masks(self._pos, self._no_fly, self._alt_levels, ACTION_DELTAS, masks)
        received = self._received.copy()
        valid = self._received_valid.copy()
        observations = {
            agent: {
                layout.KEY_LOCAL: local[i],
                layout.KEY_RECEIVED: received[i],
                layout.KEY_RECEIVED_VALID: valid[i],
                layout.KEY_STATE: state,
                layout.KEY_MASK: masks[i].copy(),
            }
            for i, agent in enumerate(self.possible_agents)
        }
        if cfg.action_gain:
            kernels.action_gains(
                self._pos, masks, ACTION_DELTAS, geo.footprint_strips, self._l_strip, self._alt_levels, self._gains
            )
            gains = self._gains.astype(np.float32)
            for i, agent in enumerate(self.possible_agents):
                observations[agent][layout.KEY_GAIN] = gains[i]
        return observations

    def _intent(self) -> np.ndarray:
        """(N, 1, L, L) observation v3's intent channel: each message carries the move its sender
        made this step; a receiver marks the column that sender reaches if it repeats the move
        (its own column for a vertical move or a hover). Moves are simultaneous, so the move a
        teammate will choose next is not known when it sends: its heading is the intent it can share."""
        L = self.config.lattice
        heading = ACTION_DELTAS[self._moves, :2]
        target = np.clip(self._pos[:, :2] + heading, 0, L - 1)
        intent = np.zeros((self.n_uavs, 1, L, L), dtype=np.float32)
        r_idx, s_idx = np.nonzero(self._links_now)
        teammate = r_idx != s_idx
        r_idx, s_idx = r_idx[teammate], s_idx[teammate]
        intent[r_idx, 0, target[s_idx, 1], target[s_idx, 0]] = 1.0
        return intent

    def _fine_view(self) -> np.ndarray:
        """(N, 32, L, L) observation v3's fine view of each M_i: mean belief and entropy on the comm
        grid (R = 4 L), space-to-depth onto the lattice so the actor's first convolution sees
        every sub-cell of a column in that column's channels."""
        n, L, f = self.n_uavs, self.config.lattice, layout.FINE_FACTOR
        fine = (self._l_fine / self._comm_area).astype(np.float32)  # (N, 2, R, R)
        blocks = fine.reshape(n, 2, L, f, L, f).transpose(0, 1, 3, 5, 2, 4)
        return blocks.reshape(n, layout.FINE_CHANNELS, L, L)

    def _privileged_state(self) -> np.ndarray:
        """(2, L, L) observation v3's ground-truth critic channels: the fraction of truly valuable
        cells per block and the global belief's mean per-cell error |p - truth| per block
        (sum p + sum truth - 2 sum p on valuable cells, all kept by the kernels)."""
        area = self.geometry.block_area
        g = self._g_block
        error = (g[0] + self._truth_blocks - 2.0 * g[3]) / area
        return np.stack([self._truth_blocks / area, error]).astype(np.float32)

    def _global_metrics(self) -> dict[str, float]:
        tp, pp = self._g_scal[kernels.S_TP], self._g_scal[kernels.S_PP]
        return {
            "f1": _f1(tp, pp, self._n_valuable),
            "entropy": _mean_entropy(self._g_scal[kernels.S_ENT_TRUE], self._n_valuable),
        }

    def metrics(self) -> dict[str, float]:
        """The paper's metrics on the global belief (``f1``, ``entropy`` over valuable cells) and the
        team metrics on each UAV's own M_i, averaged over UAVs (``team_f1``, ``team_entropy``)."""
        out = self._global_metrics()
        n_val, n = self._n_valuable, self.n_uavs
        per_uav = self._l_scal.tolist()  # rows: (entropy over valuable cells, tp, pp)
        out["team_f1"] = sum(_f1(tp, pp, n_val) for _, tp, pp in per_uav) / n
        out["team_entropy"] = sum(_mean_entropy(ent, n_val) for ent, _, _ in per_uav) / n
        out["reward_entropy"] = float(self._g_scal[kernels.S_REWARD])
        out["coverage"] = float(self._g_block[2].sum() / self.config.grid**2)
        out["budget_left"] = int(self._budget_left)
        return out

    # ------------------------------------------------------------------ inspection helpers
    def global_belief(self) -> np.ndarray:
        """(grid, grid) probability that each cell is valuable (float32)."""
        return kernels.probability(self._logodds)

    def global_logodds(self) -> np.ndarray:
        """(grid, grid) the global belief as stored: int16 log-odds in 1/``kernels.SCALE`` units
        (a quarter of ``global_belief``'s bytes; planners look their per-cell scores up by it)."""
        return self._logodds.copy()

    def local_beliefs(self) -> np.ndarray:
        """(N, grid, grid) each UAV's own local belief M_i, per belief cell (float32)."""
        return kernels.probability(self._local_logodds)

    def local_logodds(self) -> np.ndarray:
        """(N, grid, grid) each UAV's M_i as stored: int16 log-odds in 1/``kernels.SCALE`` units."""
        return self._local_logodds.copy()

    def sensor_maps(self) -> np.ndarray:
        """(N, R, R) each UAV's own clean sensor map on the comm grid (0.5 where never observed)."""
        return self._received[:, 0].copy()

    def footprint_readings(self, uav: int) -> np.ndarray:
        """(rows, cols) uint8 0/1 readings of UAV ``uav``'s latest measurement, over the footprint of
        its current position (``geometry.footprint``): what it measured and sent this step. Tests
        use it to check that a measurement's noise depends on the measurement only (CRN)."""
        ix, iy, level = (int(v) for v in self._pos[uav])
        fp = self.geometry.footprint(ix, iy, level)
        return self._readings[uav, : fp.r1 - fp.r0, : fp.c1 - fp.c0].copy()

    def gain_strip_sums(self) -> np.ndarray:
        """(N, W, A, S, S) per UAV, weighting (``uav_ipp.gain.WEIGHTINGS``), altitude level and gain strip
        cell: the summed expected gain of one reading, from the UAV's own M_i (what AG plans with)."""
        n, s = self.n_uavs, self.geometry.n_strips
        sums = self._l_strip.reshape(n, len(WEIGHTINGS), gain.MAX_LEVELS, s, s)
        return sums[:, :, : self._alt_levels].copy()

    def lattice_positions(self) -> np.ndarray:
        """(N, 3) int64 lattice indices (ix, iy, altitude level) of the UAVs."""
        return self._pos.copy()

    def no_fly_columns(self) -> np.ndarray:
        """(lattice, lattice) bool no-fly mask of the current map, indexed [y, x]."""
        return self._no_fly

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


def _f1(tp: float, pp: float, n_valuable: int) -> float:
    """F1 of "believed valuable" (log-odds > 0) from true and predicted positive counts."""
    denom = pp + n_valuable
    return float(2.0 * tp / denom) if denom > 0 else 0.0


def _mean_entropy(total: float, n_valuable: int) -> float:
    """Mean entropy (bits) over the valuable cells from its running total."""
    return float(max(total / n_valuable, 0.0)) if n_valuable > 0 else 0.0


def _score(metrics: dict[str, float]) -> float:
    """F1 minus the entropy over valuable cells: ``reward="metrics"`` pays its change, so a
    mission's return is ``alpha`` times the gain in both Table I metrics."""
    return metrics["f1"] - metrics["entropy"]


@functools.lru_cache(maxsize=2)
def _global_table(kind: str) -> np.ndarray:
    return kernels.build_global_table(kind)


@functools.lru_cache(maxsize=4)
def _local_table(flips: tuple[float, ...]) -> np.ndarray:
    return gain.build_local_table(flips)


@functools.lru_cache(maxsize=1)
def _normals() -> np.ndarray:
    return kernels.normal_table()
