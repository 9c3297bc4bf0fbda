"""End-to-end on the real environment: COMA trains, logs, saves and loads on uav_ipp.make_vec_env."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th
from coma_fakes import capture_logger, one_torch_thread  # noqa: F401 (autouse fixture)

from sb3_coma.coma import COMA

uav_ipp = pytest.importorskip("uav_ipp")

SMALL = dict(features_extractor_kwargs=dict(channels=(8, 16, 16), features_dim=32))


def make_env(seed: int = 0):
    return uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", n_uavs=2, budget=6, seed=seed)


def test_learn_log_save_load_on_env1(tmp_path: Path) -> None:
    venv = make_env()
    assert getattr(venv, "n_agents", None) == 2 and venv.num_envs == 4
    model = COMA("CBAMPolicy", venv, batch_size=24, n_steps=12, seed=0, policy_kwargs=SMALL)
    logger, out = capture_logger()
    model.set_logger(logger)
    model.learn(48)  # two rollouts of 12 steps x 2 copies = 8 missions of 6 steps
    assert model.num_timesteps == 48
    last = out.dumps[-1]
    assert last["rollout/ep_len_mean"] == 6
    assert 0.0 <= last["rollout/ep_f1"] <= 1.0 and 0.0 <= last["rollout/ep_entropy"] <= 1.0
    assert np.isfinite(last["train/critic_loss"])

    obs = venv.reset()
    for _ in range(6):  # one mission: every chosen action is valid under the env's own mask
        actions, _ = model.predict(obs, deterministic=False)
        assert (obs["action_mask"][np.arange(4), actions] == 1).all()
        obs, _, _, _ = venv.step(actions)

    model.save(tmp_path / "coma_env1.zip")
    loaded = COMA.load(tmp_path / "coma_env1.zip", env=make_env(seed=1))
    obs = loaded.env.reset()
    assert np.array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    joint = model._grouped(obs)
    state = model._joint_state(joint, None)
    actions = th.zeros(2, 2, dtype=th.long)
    with th.no_grad():
        assert th.equal(model.policy.q_values(joint, state, actions), loaded.policy.q_values(joint, state, actions))
    loaded.learn(24, reset_num_timesteps=False)
    assert loaded.num_timesteps == 72
