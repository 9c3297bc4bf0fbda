"""make_marl_vec_env: the multi-agent VecEnv contract over PettingZoo envs (mpe2, LBF, tiny test envs)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from pettingzoo import ParallelEnv

from sb3_coma.common.gymnasium_marl import GymnasiumMultiAgentToParallel
from sb3_coma.common.marl_vec_env import make_marl_vec_env

N_ACTIONS = 4


class TinyEnv(ParallelEnv):
    """Two agents, a 3-step episode, Dict observations with an action mask in the obs or the infos.

    ``mask_in="obs"``: observation {"observation", "action_mask"}; ``"info"``: a Box observation and
    the mask in each agent's info. The mask of step ``t`` allows actions ``t % 4`` and 3 only.
    ``obs_sizes`` gives each agent its own observation size (for the space checks).
    """

    metadata: dict[str, Any] = {"name": "tiny"}  # noqa: RUF012 (PettingZoo's class attribute)

    def __init__(self, mask_in: str = "obs", obs_sizes: tuple[int, int] = (2, 2)) -> None:
        self.possible_agents = ["a", "b"]
        self.agents: list[str] = []
        self.mask_in = mask_in
        self.obs_sizes = dict(zip(self.possible_agents, obs_sizes))
        self.render_mode = None
        self.t = 0
        self.observation_spaces = {agent: self._space(size) for agent, size in self.obs_sizes.items()}
        self.action_spaces = {agent: spaces.Discrete(N_ACTIONS) for agent in self.possible_agents}

    def _space(self, size: int) -> spaces.Space:
        box = spaces.Box(-10.0, 10.0, (size,), np.float32)
        if self.mask_in == "info":
            return box
        return spaces.Dict({"observation": box, "action_mask": spaces.MultiBinary(N_ACTIONS)})

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[agent]

    def _mask(self) -> np.ndarray:
        mask = np.zeros(N_ACTIONS, dtype=np.int8)
        mask[[self.t % N_ACTIONS, 3]] = 1
        return mask

    def _observe(self) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        obs: dict[str, Any] = {}
        for i, agent in enumerate(self.possible_agents):
            box = np.full(self.obs_sizes[agent], self.t + i, dtype=np.float32)
            obs[agent] = box if self.mask_in == "info" else {"observation": box, "action_mask": self._mask()}
        infos = {agent: ({"action_mask": self._mask()} if self.mask_in == "info" else {}) for agent in obs}
        return obs, infos

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        self.agents = list(self.possible_agents)
        self.t = 0
        return self._observe()

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        self.t += 1
        obs, infos = self._observe()
        done = self.t >= 3
        if done:
            self.agents = []
        flags = dict.fromkeys(obs, done)
        return obs, dict.fromkeys(obs, 1.0), flags, dict.fromkeys(obs, False), infos


class NoStateEnv(TinyEnv):
    """Declares a state_space but leaves PettingZoo's state() unimplemented."""

    state_space = spaces.Box(-1.0, 1.0, (4,), np.float32)


class StaggeredEnv(TinyEnv):
    """Agent "a" terminates one step before agent "b" (SuperSuit cannot vectorise that)."""

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        obs, rewards, _, truncations, infos = super().step(actions)
        return obs, rewards, {"a": self.t >= 2, "b": self.t >= 3}, truncations, infos


def _spread(continuous: bool = False) -> ParallelEnv:
    simple_spread_v3 = pytest.importorskip("mpe2.simple_spread_v3")
    return simple_spread_v3.parallel_env(continuous_actions=continuous, max_cycles=25)


def _rollout(venv: Any, steps: int, seed: int = 0) -> np.ndarray:
    """Observations of ``steps`` steps under seeded random actions."""
    rng = np.random.default_rng(seed)
    frames = [venv.reset()]
    for _ in range(steps):
        frames.append(venv.step(rng.integers(0, venv.action_space.n, size=venv.num_envs))[0])
    return np.stack(frames)


# ---------------------------------------------------------------------- mpe2 simple_spread
def test_simple_spread_rows_state_and_truncation() -> None:
    """Rows follow possible_agents per copy (against reference envs seeded seed + e, same actions)."""
    venv = make_marl_vec_env(_spread, n_envs=2, seed=7)
    assert (venv.num_envs, venv.n_agents, venv.n_copies, venv.state_source) == (6, 3, 2, "env")
    refs = [_spread() for _ in range(2)]
    agents = refs[0].possible_agents
    ref_obs = [ref.reset(seed=7 + e)[0] for e, ref in enumerate(refs)]
    obs = venv.reset()
    rng = np.random.default_rng(0)
    for t in range(25):
        np.testing.assert_allclose(obs, [o[a] for o in ref_obs for a in agents], rtol=1e-6)
        states = venv.get_state()
        assert states.shape == (2, *venv.state_space.shape) and states.dtype == np.float32
        np.testing.assert_allclose(states, [ref.state() for ref in refs], rtol=1e-6)
        actions = rng.integers(0, 5, size=6)
        obs, _, dones, infos = venv.step(actions)
        ref_obs = [ref.step({a: actions[e * 3 + i] for i, a in enumerate(agents)})[0] for e, ref in enumerate(refs)]
        assert dones.tolist() == [t == 24] * 6
    for row, info in enumerate(infos):
        e, a = divmod(row, 3)
        assert info["TimeLimit.truncated"] is True
        np.testing.assert_allclose(info["terminal_observation"], ref_obs[e][agents[a]], rtol=1e-6)
        np.testing.assert_allclose(info["terminal_state"], refs[e].state(), rtol=1e-6)
    new_obs = [ref.reset()[0] for ref in refs]  # the copies auto-reset unseeded, continuing their generators
    np.testing.assert_allclose(obs, [o[a] for o in new_obs for a in agents], rtol=1e-6)
    np.testing.assert_allclose(venv.get_state(), [ref.state() for ref in refs], rtol=1e-6)
    assert len(venv.unwrapped.reset_infos) == 6


def test_simple_spread_seeding() -> None:
    first = _rollout(make_marl_vec_env(_spread, n_envs=2, seed=3), 30)
    np.testing.assert_array_equal(first, _rollout(make_marl_vec_env(_spread, n_envs=2, seed=3), 30))
    assert not np.allclose(first, _rollout(make_marl_vec_env(_spread, n_envs=2, seed=4), 30))
    reseeded = make_marl_vec_env(_spread, n_envs=2)
    assert list(reseeded.seed(3)) == [3, 3, 3, 4, 4, 4]
    np.testing.assert_array_equal(first, _rollout(reseeded, 30))
    unseeded = make_marl_vec_env(_spread, n_envs=2).reset()
    assert not np.allclose(unseeded[:3], unseeded[3:])  # copies are clones, yet play their own episodes


def test_forced_concat_has_no_state() -> None:
    venv = make_marl_vec_env(_spread(), state="concat", seed=0)
    venv.reset()
    assert venv.state_source == "concat" and venv.state_space is None
    with pytest.raises(RuntimeError, match=r"state_source 'env'.*'concat'"):
        venv.get_state()


# ---------------------------------------------------------------------- masks and attributes
@pytest.mark.parametrize("mask_in", ["obs", "info"])
def test_action_masks_follow_the_current_step(mask_in: str) -> None:
    venv = make_marl_vec_env(lambda: TinyEnv(mask_in), n_envs=2, seed=0)
    assert venv.state_source == "concat"
    venv.reset()
    for t in [0, 1, 2, 0]:  # the episode ends at step 3 and the copy resets to t = 0
        expected = np.zeros((4, N_ACTIONS), dtype=bool)
        expected[:, [t % N_ACTIONS, 3]] = True
        np.testing.assert_array_equal(venv.action_masks(), expected)
        per_row = venv.env_method("action_masks")
        assert len(per_row) == 4 and all(np.array_equal(m, expected[0]) for m in per_row)
        _, rewards, dones, _ = venv.step(np.full(4, 3))
    assert dones.tolist() == [False] * 4 and rewards.tolist() == [1.0] * 4


def test_terminal_infos_are_not_overwritten_by_reset_infos() -> None:
    venv = make_marl_vec_env(lambda: TinyEnv("info"), seed=0)
    venv.reset()
    for _ in range(3):
        _, _, dones, infos = venv.step(np.zeros(2, dtype=int))
    assert dones.all() and all(info["TimeLimit.truncated"] is False for info in infos)
    assert [info["action_mask"].tolist() for info in infos] == [[0, 0, 0, 1]] * 2  # step 3's, not the reset's
    assert [
        info["action_mask"].tolist() for info in venv.unwrapped.reset_infos
    ]  # VecMonitor has its own, unused copy == [[1, 0, 0, 1]] * 2
    np.testing.assert_array_equal(infos[1]["terminal_observation"], [4.0, 4.0])


def test_attributes() -> None:
    venv = make_marl_vec_env(_spread(), n_envs=2, seed=0)
    assert venv.get_attr("n_agents") == [3] * 6
    assert venv.get_attr("max_cycles", indices=[0, 5]) == [25, 25]
    assert venv.env_is_wrapped(object) == [False] * 6
    venv.set_attr("max_cycles", 10, indices=[3])
    assert venv.get_attr("max_cycles") == [25, 25, 25, 10, 10, 10]
    with pytest.raises(AttributeError, match="'no_such_thing'"):
        venv.get_attr("no_such_thing")
    with pytest.raises(AttributeError, match="'no_such_method'"):
        venv.env_method("no_such_method")


# ---------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize(
    ("env", "kwargs", "error", "match"),
    [
        (lambda: _spread(continuous=True), {}, ValueError, r"Discrete actions.*got Box\("),
        (lambda: TinyEnv(obs_sizes=(2, 3)), {}, ValueError, r"agents 'a' and 'b'.*pad_observations_v0"),
        (TinyEnv, {"state": "env"}, ValueError, "state='env'.*TinyEnv.*state_space"),
        (NoStateEnv, {"state": "env"}, ValueError, r"state='env'.*NoStateEnv does not implement state\(\)"),
        (TinyEnv, {"state": "obs"}, ValueError, "state='obs'.*'state' key"),
        (TinyEnv, {"state": "global"}, ValueError, "'global'"),
        (TinyEnv, {"n_envs": 0}, ValueError, "n_envs.*got 0"),
        (TinyEnv, {"seed": -1}, ValueError, "seed.*got -1"),
        ("simple_spread", {}, TypeError, "got str: 'simple_spread'"),
        (lambda: 42, {}, TypeError, "returned int"),
    ],
)
def test_bad_inputs_fail_with_one_clear_line(env: Any, kwargs: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match) as caught:
        make_marl_vec_env(env, **kwargs)
    assert "\n" not in str(caught.value)


def test_agents_must_finish_together() -> None:
    venv = make_marl_vec_env(StaggeredEnv, seed=0)
    venv.reset()
    venv.step(np.zeros(2, dtype=int))
    with pytest.raises(RuntimeError, match=r"agents \['a'\] finished before the others"):
        venv.step(np.zeros(2, dtype=int))


def test_aec_env_is_refused_with_the_conversion_hint() -> None:
    simple_spread_v3 = pytest.importorskip("mpe2.simple_spread_v3")
    with pytest.raises(TypeError, match="aec_to_parallel"):
        make_marl_vec_env(simple_spread_v3.env(continuous_actions=False))


# ---------------------------------------------------------------------- gymnasium multi-agent envs (LBF)
def _foraging() -> GymnasiumMultiAgentToParallel:
    pytest.importorskip("lbforaging")
    import gymnasium

    return GymnasiumMultiAgentToParallel(
        gymnasium.make("Foraging-8x8-2p-2f-coop-v3", disable_env_checker=True)
    )  # its checker expects one reward


def test_foraging_passes_the_parallel_api_test() -> None:
    from pettingzoo.test import parallel_api_test

    parallel_api_test(_foraging(), num_cycles=60)


def test_foraging_vectorises_with_concatenated_state() -> None:
    venv = make_marl_vec_env(_foraging, n_envs=2, seed=1)
    assert (venv.num_envs, venv.n_agents, venv.state_source, venv.state_space) == (4, 2, "concat", None)
    frames = _rollout(venv, 60)
    assert frames.shape == (61, 4, 12)
    np.testing.assert_array_equal(frames, _rollout(make_marl_vec_env(_foraging, n_envs=2, seed=1), 60))


def test_gymnasium_adapter_refuses_single_agent_spaces() -> None:
    import gymnasium

    with pytest.raises(TypeError, match=r"Tuple observation and action spaces.*Box\("):
        GymnasiumMultiAgentToParallel(gymnasium.make("CartPole-v1"))
