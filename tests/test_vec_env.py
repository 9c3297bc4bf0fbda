"""The SB3 vec-env pipeline: SuperSuit + fusion + adapter + VecMonitor, and gymnasium ids."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

import uav_ipp
from uav_ipp import layout
from uav_ipp.config import ConfigError
from uav_ipp.fusion import mean_fusion


def valid_random_actions(obs, rng):
    mask = obs[layout.KEY_MASK]
    return np.array([rng.choice(np.flatnonzero(m)) for m in mask])


@pytest.fixture(scope="module")
def venv():
    return uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=0, budget=4)


def test_spaces_and_shapes(venv):
    assert isinstance(venv, VecMonitor) and isinstance(venv, VecEnv)
    assert venv.num_envs == 8 and venv.n_agents == 4
    assert venv.get_attr("n_agents") == [4] * 8
    space = venv.observation_space
    assert set(space.spaces) == {layout.KEY_LOCAL, layout.KEY_STATE, layout.KEY_MASK, layout.KEY_GAIN}
    assert space[layout.KEY_LOCAL].shape == (8, 11, 11)
    obs = venv.reset()
    assert obs[layout.KEY_LOCAL].shape == (8, 8, 11, 11)
    assert obs[layout.KEY_STATE].shape == (8, 3, 11, 11)
    assert obs[layout.KEY_MASK].shape == (8, 6)
    assert obs[layout.KEY_GAIN].shape == (8, 2, 6)
    for i in range(8):
        assert space.contains({k: v[i] for k, v in obs.items()})


def test_step_terminal_observation_and_infos(venv):
    rng = np.random.default_rng(0)
    obs = venv.reset()
    for _t in range(4):
        obs, rewards, dones, infos = venv.step(valid_random_actions(obs, rng))
        assert rewards.shape == (8,) and dones.shape == (8,)
        assert all("f1" in info and "entropy" in info for info in infos)
        # the team reward is shared by the agents of one copy
        assert np.all(rewards[:4] == rewards[0]) and np.all(rewards[4:] == rewards[4])
    assert dones.all()
    for info in infos:
        assert info["TimeLimit.truncated"] is False
        term = info["terminal_observation"]
        assert term[layout.KEY_LOCAL].shape == (8, 11, 11)
        assert term[layout.KEY_LOCAL][layout.BUDGET].max() == 0.0
        assert "episode" in info and {"r", "l", "f1", "entropy"} <= set(info["episode"])
        assert info["episode"]["l"] == 4
    # the auto-reset observation starts a fresh mission
    assert np.all(obs[layout.KEY_LOCAL][:, layout.BUDGET] == 1.0)


def test_seeding_per_copy_and_reproducible():
    def rollout(seed):
        v = uav_ipp.make_vec_env("env1", n_envs=2, seed=seed, budget=3)
        rng = np.random.default_rng(1)
        obs = v.reset()
        out = [obs[layout.KEY_LOCAL].copy()]
        for _ in range(3):
            obs, r, _d, _ = v.step(valid_random_actions(obs, rng))
            out.append(r.copy())
        return out

    a, b, c = rollout(5), rollout(5), rollout(6)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, c))
    # copies get different seeds: their rewards differ
    assert not np.array_equal(a[1][:4], a[1][4:])


def test_seed_method_and_env_method(venv):
    seeds = venv.seed(10)
    assert seeds[:4] == [10] * 4 and seeds[4:] == [11] * 4
    venv.reset()
    metrics = venv.env_method("metrics", indices=[0, 5])
    assert len(metrics) == 2 and "f1" in metrics[0]
    assert venv.get_attr("render_mode") == [None] * 8
    venv.set_attr("render_mode", "ansi", indices=[0])
    assert venv.get_attr("render_mode", indices=[0]) == ["ansi"]
    venv.set_attr("render_mode", None)


def test_mean_fusion_is_the_average_of_valid_slots():
    rng = np.random.default_rng(0)
    received = rng.random((3, 4, 44, 44)).astype(np.float32)
    valid = np.array([[1, 1, 0, 0], [1, 0, 0, 0], [1, 1, 1, 1]], np.float32)
    fused = mean_fusion(received, valid)
    np.testing.assert_allclose(fused[0], received[0, :2].mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(fused[1], received[1, 0], rtol=1e-6)
    np.testing.assert_allclose(fused[2], received[2].mean(axis=0), rtol=1e-6)


def test_fused_channel_matches_raw_received():
    raw = uav_ipp.make_vec_env("env1", n_envs=1, fusion="none", seed=3, budget=2, monitor=False)
    fused = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=3, budget=2, monitor=False)
    r, f = raw.reset(), fused.reset()
    np.testing.assert_array_equal(r[layout.KEY_LOCAL], f[layout.KEY_LOCAL][:, :7])
    geo = raw.copies[0].geometry
    expect = np.clip(geo.to_lattice(mean_fusion(r[layout.KEY_RECEIVED], r[layout.KEY_RECEIVED_VALID])), 0, 1)
    np.testing.assert_allclose(f[layout.KEY_LOCAL][:, layout.FUSED], expect, atol=1e-5)


def test_gymnasium_ids_registered():
    for env_id in ("UavIpp-Env1-v0", "UavIpp-Env2-v0", "UavIpp-Env3-v0"):
        assert env_id in gymnasium.registry
    vec = gymnasium.make_vec("UavIpp-Env1-v0", num_envs=2, budget=2)
    obs, _ = vec.reset(seed=0)
    assert obs[layout.KEY_LOCAL].shape == (8, 8, 11, 11)
    with pytest.raises(TypeError, match="multi-agent"):
        gymnasium.make("UavIpp-Env1-v0")


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"n_envs": 0}, "n_envs"),
        ({"n_envs": 1.5}, "n_envs"),
        ({"fusion": "median"}, "fusion"),
        ({"seed": "abc"}, "seed"),
        ({"budget": -2}, "budget"),
    ],
)
def test_bad_vec_env_arguments(kwargs, match):
    with pytest.raises((ConfigError, ValueError), match=match):
        uav_ipp.make_vec_env("env1", **kwargs)
