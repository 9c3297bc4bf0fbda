"""Property tests (hypothesis): invariants of the environment for any options and actions."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import uav_ipp
from uav_ipp import layout

options = st.fixed_dictionaries(
    {
        "n_uavs": st.integers(1, 5),
        "budget": st.integers(1, 6),
        "noise": st.sampled_from(["none", "moderate", "loud"]),
        "comm_range": st.sampled_from([0.0, 10.0, 25.0, 1e9]),
        "drop_probability": st.sampled_from([0.0, 0.3]),
        "start": st.sampled_from(["fixed", "random"]),
    }
)
PROPERTY_SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _run(opts: dict, seed: int, actions: list[int], map_name: str = "env3"):
    env = uav_ipp.make_env(map_name, **opts)
    obs, _ = env.reset(seed=seed)
    frames = [(obs, env.metrics())]
    k = 0
    while env.agents:
        acts = {a: actions[(k + i) % len(actions)] for i, a in enumerate(env.agents)}
        k += len(env.agents)
        obs, rewards, _terms, _truncs, infos = env.step(acts)
        frames.append((obs, infos[env.possible_agents[0]], rewards))
        _check_state(env)
    return env, frames


def _check_state(env) -> None:
    cfg = env.config
    pos = env._pos
    assert np.all((pos[:, :2] >= 0) & (pos[:, :2] < cfg.lattice))
    assert np.all((pos[:, 2] >= 0) & (pos[:, 2] < len(cfg.altitudes)))
    assert len({(int(x), int(y)) for x, y, _ in pos}) == len(pos)  # one UAV per column
    assert not env.ground_truth.no_fly[pos[:, 1], pos[:, 0]].any()
    belief = env.global_belief()
    assert np.all(np.isfinite(belief)) and np.all((belief >= 0) & (belief <= 1))
    local = env.local_beliefs()
    assert np.all(np.isfinite(local)) and np.all((local >= 0) & (local <= 1))


@PROPERTY_SETTINGS
@given(opts=options, seed=st.integers(0, 2**16), actions=st.lists(st.integers(0, 5), min_size=1, max_size=12))
def test_any_actions_keep_the_world_consistent(opts, seed, actions):
    env, frames = _run(opts, seed, actions)
    space = env.observation_space(env.possible_agents[0])
    budgets = []
    for frame in frames:
        obs = frame[0]
        for agent in env.possible_agents:
            assert space.contains(obs[agent]), agent
            for value in obs[agent].values():
                assert not np.isnan(value).any()
        budgets.append(obs[env.possible_agents[0]][layout.KEY_LOCAL][layout.BUDGET, 0, 0])
    assert len(frames) == opts["budget"] + 1
    np.testing.assert_allclose(budgets, np.linspace(1.0, 0.0, opts["budget"] + 1), atol=1e-6)
    for _, info, rewards in frames[1:]:
        assert 0.0 <= info["f1"] <= 1.0 and 0.0 <= info["entropy"] <= 1.0 + 1e-9
        assert all(np.isfinite(r) for r in rewards.values())


@PROPERTY_SETTINGS
@given(opts=options, seed=st.integers(0, 2**16), actions=st.lists(st.integers(0, 5), min_size=1, max_size=8))
def test_channel_never_touches_own_data_or_the_global_map(opts, seed, actions):
    quiet_opts = {**opts, "noise": "none"}
    loud_opts = {**opts, "noise": "loud"}
    quiet, q_frames = _run(quiet_opts, seed, actions)
    loud, l_frames = _run(loud_opts, seed, actions)
    np.testing.assert_array_equal(quiet.global_belief(), loud.global_belief())
    np.testing.assert_array_equal(quiet.sensor_maps(), loud.sensor_maps())  # own slot: clean
    for (qo, *_), (lo, *_) in zip(q_frames, l_frames):
        for agent in quiet.possible_agents:
            np.testing.assert_array_equal(qo[agent][layout.KEY_STATE], lo[agent][layout.KEY_STATE])
            np.testing.assert_array_equal(qo[agent][layout.KEY_RECEIVED][0], lo[agent][layout.KEY_RECEIVED][0])
