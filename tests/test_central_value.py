"""IPPO and MAPPO on any multi-agent VecEnv: the same route as COMA (``make_marl_vec_env``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pettingzoo import ParallelEnv
from stable_baselines3 import PPO

from sb3_coma import make_marl_vec_env
from sb3_coma.mappo.central_value import KEY_AGENT_ID, CentralStateVecEnv, CentralValuePolicy
from sb3_coma.mappo.mappo import make_ippo, make_mappo


def _spread() -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False)


@pytest.mark.parametrize(("state", "width"), [("env", 54), ("concat", 54)])
def test_central_state_rows_hold_the_state_and_a_one_hot_id(state: str, width: int) -> None:
    base = make_marl_vec_env(_spread, n_envs=2, seed=0, state=state)
    venv = CentralStateVecEnv(base)
    obs = venv.reset()
    assert obs["state"].shape == (6, width) and obs["obs"].shape == (6, 18)
    np.testing.assert_array_equal(obs[KEY_AGENT_ID], np.tile(np.eye(3), (2, 1)))
    assert np.array_equal(obs["state"][0], obs["state"][2]) and not np.array_equal(obs["state"][0], obs["state"][3])
    if state == "env":
        np.testing.assert_allclose(obs["state"][::3], base.get_state())  # type: ignore[attr-defined]
    else:  # every agent's observation of the copy, side by side
        np.testing.assert_allclose(obs["state"][0], obs["obs"][:3].reshape(-1))


def test_terminal_observations_become_dicts_with_the_terminal_state() -> None:
    """PPO bootstraps a time-limit end from the terminal observation through its value function."""
    venv = CentralStateVecEnv(make_marl_vec_env(_spread, n_envs=1, seed=0))
    venv.reset()
    for _ in range(25):
        _obs, _rewards, dones, infos = venv.step(np.zeros(3, dtype=np.int64))
    assert dones.all() and all(info["TimeLimit.truncated"] for info in infos)
    terminal = infos[1]["terminal_observation"]
    assert set(terminal) == {"obs", "state", KEY_AGENT_ID}
    np.testing.assert_array_equal(terminal[KEY_AGENT_ID], [0, 1, 0])
    np.testing.assert_allclose(terminal["state"], infos[0]["terminal_state"])


def test_ippo_and_mappo_train_save_and_load_on_a_third_party_env(tmp_path: Path) -> None:
    venv = make_marl_vec_env(_spread, n_envs=2, seed=0)
    ippo = make_ippo(venv, n_steps=16, batch_size=48, seed=0)
    mappo = make_mappo(venv, n_steps=16, batch_size=48, seed=0)
    assert type(ippo.policy).__name__ == "ActorCriticPolicy" and isinstance(mappo.policy, CentralValuePolicy)
    # MAPPO's value function reads state + id (54 + 3), its actor the agent's own observation (18)
    assert mappo.policy.vf_features_extractor.linear[0].in_features == 57
    assert mappo.policy.pi_features_extractor.linear[0].in_features == 18
    for name, model in (("ippo", ippo), ("mappo", mappo)):
        model.learn(96)
        model.save(tmp_path / f"{name}.zip")
        loaded = PPO.load(tmp_path / f"{name}.zip", env=model.get_env())
        obs = model.get_env().reset()
        np.testing.assert_array_equal(
            model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0]
        )
