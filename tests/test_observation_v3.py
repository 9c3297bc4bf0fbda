"""Observation v3: the fine view of M_i, teammates' intent, and the critic's ground-truth channels.

Each channel is checked against a brute-force computation from the env's own maps, and v3 must
leave every v2 channel exactly as it was (v3 only appends).
"""

from __future__ import annotations

import numpy as np
import pytest

import uav_ipp
from uav_ipp import kernels, layout
from uav_ipp.config import ConfigError
from uav_ipp.ipp_env import ACTION_DELTAS

OPTIONS = {"split": "train", "start": "random"}


def _first_valid(obs, agents, prefer: int = 4) -> dict[str, int]:
    """Each UAV's move: ``prefer`` (+x) when valid, else its first valid move."""
    out = {}
    for a in agents:
        mask = obs[a][layout.KEY_MASK]
        out[a] = prefer if mask[prefer] else int(np.flatnonzero(mask)[0])
    return out


def _fly(env, seed: int, steps: int):
    obs, _ = env.reset(seed=seed)
    for _ in range(steps):
        obs, *_ = env.step(_first_valid(obs, env.agents))
    return obs


def _block_means(env, grid_map: np.ndarray, index: np.ndarray, size: int) -> np.ndarray:
    sums = np.zeros((size, size))
    np.add.at(sums, (index[:, None], index[None, :]), grid_map)
    counts = np.bincount(index, minlength=size)
    return sums / np.outer(counts, counts)


def test_v3_spaces_and_v2_channels_unchanged():
    v2, v3 = uav_ipp.make_env("env3", **OPTIONS), uav_ipp.make_env("env3", observation="v3", **OPTIONS)
    assert v3.observation_space("uav_0")[layout.KEY_LOCAL].shape == (7 + layout.V3_LOCAL_EXTRA, 11, 11)
    assert v3.observation_space("uav_0")[layout.KEY_STATE].shape == (5, 11, 11)
    o2, o3 = _fly(v2, 5, 4), _fly(v3, 5, 4)
    for agent in v2.possible_agents:
        np.testing.assert_array_equal(o3[agent][layout.KEY_LOCAL][:7], o2[agent][layout.KEY_LOCAL])
        np.testing.assert_array_equal(o3[agent][layout.KEY_STATE][:3], o2[agent][layout.KEY_STATE])
        assert v3.observation_space(agent).contains(o3[agent])


def test_fine_view_is_the_comm_grid_mean_of_the_own_belief():
    env = uav_ipp.make_env("env3", observation="v3", **OPTIONS)
    obs = _fly(env, 11, 6)
    geo, f = env.geometry, layout.FINE_FACTOR
    for i, agent in enumerate(env.possible_agents):
        rows = env._ltab[env._local_logodds[i].astype(np.int64) + kernels.OFFSET]
        belief = _block_means(env, rows[..., kernels.L_PROB], geo.comm_of_cell, 44)
        entropy = _block_means(env, rows[..., kernels.L_ENTROPY], geo.comm_of_cell, 44)
        fine = obs[agent][layout.KEY_LOCAL][layout.FINE_VIEW - 1 :]  # raw env: no FUSED channel yet
        half = f * f
        for a in range(f):
            for b in range(f):
                np.testing.assert_allclose(fine[a * f + b], belief[a::f, b::f], atol=1e-5)
                np.testing.assert_allclose(fine[half + a * f + b], entropy[a::f, b::f], atol=1e-5)


def test_privileged_state_is_truth_and_belief_error():
    env = uav_ipp.make_env("env3", observation="v3", **OPTIONS)
    obs = _fly(env, 2, 5)
    geo = env.geometry
    truth = env._truth_u8.astype(np.float64)
    p = env._gtab[env._logodds.astype(np.int64) + kernels.OFFSET][..., kernels.G_PROB]
    state = obs["uav_0"][layout.KEY_STATE]
    np.testing.assert_allclose(
        state[layout.VALUABLE_FRACTION], _block_means(env, truth, geo.block_of_cell, 11), atol=1e-5
    )
    np.testing.assert_allclose(
        state[layout.BELIEF_ERROR], _block_means(env, np.abs(p - truth), geo.block_of_cell, 11), atol=1e-4
    )


def test_intent_marks_where_received_teammates_head():
    env = uav_ipp.make_env("env3", observation="v3", comm_range=1000.0, **OPTIONS)
    obs, _ = env.reset(seed=4)
    moves = _first_valid(obs, env.agents)
    obs, *_ = env.step(moves)
    pos = env.lattice_positions()
    for i, agent in enumerate(env.possible_agents):
        intent = obs[agent][layout.KEY_LOCAL][layout.INTENT - 1]  # raw env: INTENT sits one lower
        expect = np.zeros((11, 11), dtype=np.float32)
        for j in range(len(env.possible_agents)):
            if j != i:
                dx, dy = ACTION_DELTAS[env._moves[j], :2]
                expect[np.clip(pos[j, 1] + dy, 0, 10), np.clip(pos[j, 0] + dx, 0, 10)] = 1.0
        np.testing.assert_array_equal(intent, expect)
    assert any(ACTION_DELTAS[m, 0] == 1 for m in env._moves)  # some UAV really moved +x


def test_no_message_no_intent():
    env = uav_ipp.make_env("env3", observation="v3", drop_probability=1.0, **OPTIONS)
    obs = _fly(env, 1, 3)
    for agent in env.possible_agents:
        assert not obs[agent][layout.KEY_LOCAL][layout.INTENT - 1].any()


def test_fused_v3_keeps_fused_channel_at_its_index():
    v2 = uav_ipp.make_vec_env("env3", n_envs=1, fusion="mean", seed=3, **OPTIONS)
    v3 = uav_ipp.make_vec_env("env3", n_envs=1, fusion="mean", seed=3, observation="v3", **OPTIONS)
    o2, o3 = v2.reset(), v3.reset()
    assert o3[layout.KEY_LOCAL].shape[1] == layout.LOCAL_CHANNELS + layout.V3_LOCAL_EXTRA
    np.testing.assert_array_equal(o3[layout.KEY_LOCAL][:, : layout.LOCAL_CHANNELS], o2[layout.KEY_LOCAL])
    v2.close()
    v3.close()


def test_bad_observation_option_is_one_clear_error():
    with pytest.raises(ConfigError, match="observation"):
        uav_ipp.make_env("env3", observation="v4")
