"""A tiny deterministic multi-UAV vec env with the real env's spaces, for testing COMA in seconds.

Each agent has a "good" action this step, told to it by its BELIEF channel (row ``g`` lit)
and to the critic by the global state (``(g_j + 1) / 6`` at agent ``j``'s cell).
The team reward is the number of agents that chose their good action, shared by all agents of
the copy, so a random valid policy earns about a quarter of the optimum and the counterfactual
Q-row of agent ``i`` differs between actions only through ``[u_i == g_i]``. Masks forbid moves
off the lattice and, at random, some other actions, but never the good one; an invalid action
given anyway means "hover" and is counted in ``invalid_actions``.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.logger import KVWriter, Logger
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from uav_ipp import layout

SIZE = layout.LATTICE
# (dx, dy, dz) per action: 0 up, 1 -x, 2 -y, 3 +y, 4 +x, 5 down.
MOVES = np.array([(0, 0, 1), (-1, 0, 0), (0, -1, 0), (0, 1, 0), (1, 0, 0), (0, 0, -1)])


def obs_space(
    local_shape: tuple[int, ...] = (layout.LOCAL_CHANNELS, SIZE, SIZE),
    state_shape: tuple[int, ...] = (layout.STATE_CHANNELS, SIZE, SIZE),
    drop_key: str | None = None,
) -> spaces.Dict:
    """The per-agent observation space of the fusion-wrapped env (optionally broken, for tests)."""
    parts = {
        layout.KEY_LOCAL: spaces.Box(0.0, 1.0, local_shape, dtype=np.float32),
        layout.KEY_STATE: spaces.Box(0.0, 1.0, state_shape, dtype=np.float32),
        layout.KEY_MASK: spaces.Box(0.0, 1.0, (layout.N_ACTIONS,), dtype=np.float32),
    }
    if drop_key is not None:
        parts.pop(drop_key)
    return spaces.Dict(parts)


class FakeUavVecEnv(VecEnv):
    """``n_envs`` copies x ``n_agents`` agents; row ``e * n_agents + a`` is agent ``a`` of copy ``e``.

    :param n_envs: env copies
    :param n_agents: agents per copy (``None`` hides the attribute, to test COMA's error)
    :param budget: steps per episode; every agent of a copy ends at the same step
    :param forbid_prob: chance that each non-good, geometrically valid action is masked anyway
    :param observation_space: override the spaces (to test validation)
    :param action_space: override the action space (to test validation)
    :param num_envs: override the row count (to test validation)
    :param truncate: end episodes by a time limit (``TimeLimit.truncated``) instead of termination
    """

    def __init__(
        self,
        n_envs: int = 2,
        n_agents: int | None = 2,
        budget: int = 6,
        forbid_prob: float = 0.3,
        observation_space: spaces.Space | None = None,
        action_space: spaces.Space | None = None,
        num_envs: int | None = None,
        truncate: bool = False,
    ) -> None:
        self._n_agents = n_agents or 1
        self.truncate = truncate
        if n_agents is not None:
            self.n_agents = n_agents
        self.n_copies = n_envs
        self.budget = budget
        self.forbid_prob = forbid_prob
        self.invalid_actions = 0
        self._rng = np.random.default_rng(0)
        super().__init__(
            num_envs if num_envs is not None else n_envs * self._n_agents,
            observation_space or obs_space(),
            action_space or spaces.Discrete(layout.N_ACTIONS),
        )
        E, N = self.n_copies, self._n_agents
        self.pos = np.zeros((E, N, 3), dtype=np.int64)  # x, y, altitude level
        self.visits = np.zeros((E, N, SIZE, SIZE), dtype=np.float32)
        self.good = np.zeros((E, N), dtype=np.int64)
        self.masks = np.ones((E, N, layout.N_ACTIONS), dtype=np.float32)
        self.t = np.zeros(E, dtype=np.int64)
        self.hits = np.zeros(E, dtype=np.float64)
        self._actions: np.ndarray | None = None

    # ------------------------------------------------------------ world
    def _reset_copy(self, e: int) -> None:
        N = self._n_agents
        cells = self._rng.choice(SIZE * SIZE, size=N, replace=False)
        self.pos[e, :, 0], self.pos[e, :, 1] = cells % SIZE, cells // SIZE
        self.pos[e, :, 2] = 2
        self.visits[e] = 0.0
        self.t[e] = 0
        self.hits[e] = 0.0
        self._draw_goals(e)

    def _draw_goals(self, e: int) -> None:
        for a in range(self._n_agents):
            x, y, z = self.pos[e, a]
            geo = np.array(
                [0 <= x + dx < SIZE and 0 <= y + dy < SIZE and 0 <= z + dz < 3 for dx, dy, dz in MOVES],
                dtype=bool,
            )
            valid = np.flatnonzero(geo)
            g = int(self._rng.choice(valid))
            forbid = self._rng.random(layout.N_ACTIONS) < self.forbid_prob
            forbid[g] = False
            self.good[e, a] = g
            self.masks[e, a] = (geo & ~forbid).astype(np.float32)

    def _copy_obs(self, e: int) -> dict[str, np.ndarray]:
        N = self._n_agents
        local = np.zeros((N, layout.LOCAL_CHANNELS, SIZE, SIZE), dtype=np.float32)
        state = np.zeros((N, layout.STATE_CHANNELS, SIZE, SIZE), dtype=np.float32)
        xs, ys, zs = self.pos[e, :, 0], self.pos[e, :, 1], self.pos[e, :, 2]
        altitude = np.zeros((SIZE, SIZE), dtype=np.float32)
        altitude[ys, xs] = (zs + 1) / 3.0
        goals = np.zeros((SIZE, SIZE), dtype=np.float32)
        goals[ys, xs] = (self.good[e] + 1) / layout.N_ACTIONS
        for a in range(N):
            local[a, layout.BUDGET] = 1.0 - self.t[e] / self.budget
            local[a, layout.AGENT_ID] = (a + 1) / N
            local[a, layout.ALTITUDE] = altitude
            footprint = np.where(self.visits[e, a] > 0, 0.5, 0.0).astype(np.float32)
            footprint[ys[a], xs[a]] = 1.0
            local[a, layout.FOOTPRINT] = footprint
            local[a, layout.BELIEF, self.good[e, a]] = 1.0  # row g lit: a linear read-out suffices
            local[a, layout.FUSED] = 0.5
            state[a, layout.GLOBAL_BELIEF] = goals
            state[a, layout.GLOBAL_COVERAGE] = (self.visits[e] > 0).any(axis=0)
        return {layout.KEY_LOCAL: local, layout.KEY_STATE: state, layout.KEY_MASK: self.masks[e].copy()}

    def _all_obs(self) -> dict[str, np.ndarray]:
        parts = [self._copy_obs(e) for e in range(self.n_copies)]
        return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}

    # ----------------------------------------------------------- VecEnv
    def reset(self) -> dict[str, np.ndarray]:
        if self._seeds[0] is not None:
            self._rng = np.random.default_rng(self._seeds[0])
        self._reset_seeds()
        for e in range(self.n_copies):
            self._reset_copy(e)
        return self._all_obs()

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.n_copies, self._n_agents)

    def step_wait(self) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, list[dict[str, Any]]]:
        assert self._actions is not None
        E, N = self.n_copies, self._n_agents
        rewards = np.zeros(E * N, dtype=np.float32)
        dones = np.zeros(E * N, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(E * N)]
        for e in range(E):
            acts = self._actions[e]
            valid = self.masks[e, np.arange(N), acts] > 0.5
            self.invalid_actions += int((~valid).sum())
            team = float((acts == self.good[e]).sum())
            for a in range(N):
                self.visits[e, a, self.pos[e, a, 1], self.pos[e, a, 0]] = 1.0
                if valid[a]:
                    self.pos[e, a] += MOVES[acts[a]]
            self.t[e] += 1
            self.hits[e] += team / N
            rewards[e * N : (e + 1) * N] = team
            f1 = self.hits[e] / self.t[e]
            for a in range(N):
                infos[e * N + a] = {"f1": f1, "entropy": 1.0 - f1}
            if self.t[e] >= self.budget:
                terminal = self._copy_obs(e)
                for a in range(N):
                    dones[e * N + a] = True
                    infos[e * N + a]["terminal_observation"] = {k: v[a] for k, v in terminal.items()}
                    infos[e * N + a]["TimeLimit.truncated"] = self.truncate
                self._reset_copy(e)
            else:
                self._draw_goals(e)
        return self._all_obs(), rewards, dones, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        if attr_name == "render_mode":
            return [None] * self.num_envs
        if not hasattr(self, attr_name):
            raise AttributeError(attr_name)
        return [getattr(self, attr_name)] * len(self._indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self, attr_name, value)

    def env_method(self, method_name: str, *args: Any, indices: Any = None, **kwargs: Any) -> list[Any]:
        return [getattr(self, method_name)(*args, **kwargs) for _ in self._indices(indices)]

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False] * len(self._indices(indices))

    def _indices(self, indices: Any) -> list[int]:
        if indices is None:
            return list(range(self.num_envs))
        return [indices] if isinstance(indices, int) else list(indices)


def make_fake_vec_env(
    n_envs: int = 2, n_agents: int = 2, budget: int = 6, seed: int | None = None, **kwargs: Any
) -> VecMonitor:
    """The fake env wrapped like ``uav_ipp.make_vec_env`` wraps the real one (``VecMonitor`` outside)."""
    venv = FakeUavVecEnv(n_envs=n_envs, n_agents=n_agents, budget=budget, **kwargs)
    if seed is not None:
        venv.seed(seed)
    return VecMonitor(venv, info_keywords=("f1", "entropy"))


def random_valid_return(venv: VecEnv, episodes: int, seed: int = 0) -> float:
    """Mean episode return of the uniform-random-valid policy (the baseline COMA must beat)."""
    rng = np.random.default_rng(seed)
    venv.seed(seed)
    obs = venv.reset()
    returns: list[float] = []
    n_agents = venv.n_agents
    while len(returns) < episodes:
        mask = obs[layout.KEY_MASK]
        actions = np.array([rng.choice(np.flatnonzero(m > 0.5)) for m in mask])
        obs, _, dones, infos = venv.step(actions)
        for row in range(0, venv.num_envs, n_agents):
            if dones[row] and "episode" in infos[row]:
                returns.append(float(infos[row]["episode"]["r"]))
    return float(np.mean(returns[:episodes]))


class CaptureWriter(KVWriter):
    """An SB3 logger output that keeps every dump in memory, for asserting on logged values."""

    def __init__(self) -> None:
        self.dumps: list[dict[str, Any]] = []

    def write(self, key_values: dict[str, Any], key_excluded: dict[str, Any], step: int = 0) -> None:
        self.dumps.append(dict(key_values, _step=step))

    def close(self) -> None:
        pass

    def series(self, key: str) -> list[Any]:
        return [d[key] for d in self.dumps if key in d]


def collect_rollout(model: Any, total_timesteps: int = 10_000, **setup: Any) -> None:
    """Set ``model`` up for ``learn(total_timesteps)`` (``setup``: more of ``_setup_learn``'s
    arguments) and fill its rollout buffer once, without training: what a test of one rollout's
    targets or advantages inspects."""
    model._setup_learn(total_timesteps, **setup)
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)


def capture_logger() -> tuple[Logger, CaptureWriter]:
    writer = CaptureWriter()
    return Logger(folder=None, output_formats=[writer]), writer


@pytest.fixture(autouse=True)
def one_torch_thread() -> Iterator[None]:
    """Import into a test module to run it on one torch thread (restored afterwards).

    The test networks are tiny; on a busy 2-core machine two OpenMP threads spin-wait on each
    other and run several times slower than one.
    """
    before = th.get_num_threads()
    th.set_num_threads(1)
    yield
    th.set_num_threads(before)
