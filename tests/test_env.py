"""The IPP environment: API compliance, physics, bookkeeping, determinism and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

import uav_ipp
from uav_ipp import gain, kernels, layout
from uav_ipp.config import ConfigError
from uav_ipp.ipp_env import ACTION_DELTAS


def random_episode(env, seed: int, policy_seed: int = 0):
    """Run one mission with uniformly random valid actions; return per-step (reward, info)."""
    rng = np.random.default_rng(policy_seed)
    obs, _ = env.reset(seed=seed)
    history = []
    while env.agents:
        actions = {a: int(rng.choice(np.flatnonzero(obs[a][layout.KEY_MASK]))) for a in env.agents}
        obs, rewards, _, _, infos = env.step(actions)
        history.append((rewards["uav_0"], infos["uav_0"], obs))
    return history


@pytest.fixture(scope="module")
def env():
    return uav_ipp.make_env("env1", n_uavs=4, budget=15)


def test_pettingzoo_parallel_api():
    parallel_api_test(uav_ipp.make_env("env1", budget=5), num_cycles=12)


def test_observation_layout(env):
    obs, _ = env.reset(seed=0)
    assert set(obs) == set(env.possible_agents) == {f"uav_{i}" for i in range(4)}
    o = obs["uav_0"]
    assert o[layout.KEY_LOCAL].shape == (7, 11, 11)
    assert o[layout.KEY_RECEIVED].shape == (4, 44, 44)
    assert o[layout.KEY_RECEIVED_VALID].shape == (4,)
    assert o[layout.KEY_STATE].shape == (3, 11, 11)
    assert o[layout.KEY_MASK].shape == (6,)
    for agent in env.possible_agents:
        assert env.observation_space(agent).contains(obs[agent])
    # channels: budget ratio, id ratio, footprint 1 at own cell
    assert np.all(o[layout.KEY_LOCAL][layout.BUDGET] == 1.0)
    assert np.allclose(obs["uav_2"][layout.KEY_LOCAL][layout.AGENT_ID], 3 / 4)
    x, y = 2, 2  # default start (10 m, 10 m)
    assert o[layout.KEY_LOCAL][layout.FOOTPRINT][y, x] == 1.0
    assert o[layout.KEY_LOCAL][layout.ALTITUDE][y, x] == pytest.approx(1.0)
    assert o[layout.KEY_RECEIVED_VALID][0] == 1.0


def test_episode_length_budget_and_termination():
    env = uav_ipp.make_env("env1", budget=7)
    hist = random_episode(env, seed=1)
    assert len(hist) == 7
    assert env.agents == []
    assert hist[-1][1]["budget_left"] == 0
    with pytest.raises(RuntimeError, match="reset"):
        env.step({"uav_0": 0})


def test_same_seed_identical_episode():
    a = random_episode(uav_ipp.make_env("env1", budget=6), seed=3, policy_seed=5)
    b = random_episode(uav_ipp.make_env("env1", budget=6), seed=3, policy_seed=5)
    for (ra, ia, oa), (rb, ib, ob) in zip(a, b):
        assert ra == rb and ia == ib
        for agent in oa:
            for key in oa[agent]:
                np.testing.assert_array_equal(oa[agent][key], ob[agent][key])
    c = random_episode(uav_ipp.make_env("env1", budget=6), seed=4, policy_seed=5)
    assert [r for r, _, _ in a] != [r for r, _, _ in c]


@pytest.mark.parametrize("level,expected", [(0, 57), (1, 114), (2, 171)])
def test_footprint_side_per_altitude(level, expected):
    geo = uav_ipp.make_env("env1").geometry
    side_m = 2 * [5.0, 10.0, 15.0][level] * math.tan(math.radians(30))
    assert abs(geo.footprint_side_cells(level) - side_m / geo.cell) <= 1.0
    assert abs(geo.footprint_side_cells(level) - expected) <= 1


def test_footprint_clipped_at_field_border():
    geo = uav_ipp.make_env("env1").geometry
    fp = geo.footprint(0, 0, 2)
    assert fp.r0 == 0 and fp.c0 == 0
    assert fp.shape[0] == pytest.approx(171 / 2, abs=2)


def _sense_once(env, local_logodds, truth, level, threshold, seed=7):
    """Call the sensing kernel on the footprint of the field's centre at ``level`` with a chosen
    flip threshold; return (readings, comm_sum, comm_cnt, (rows, cols))."""
    geo = env.geometry
    r0, r1 = geo.footprint_ranges[5, level]
    tables = env._tables._replace(thresholds=np.full_like(env._thresholds, threshold))
    glob = kernels.GlobalMaps.blank(493, 11)._replace(truth=truth)
    loc = kernels.LocalMaps.blank(1, 493, 11, geo.n_strips, 44)._replace(logodds=local_logodds[None])
    comm = kernels.CommState.blank(1, geo.max_footprint, geo.comm_grid)
    key = np.uint64(
        kernels.stream_key(kernels.mission_seed(seed), kernels.DOMAIN_FLIP, 0, 0, 0)
    )  # numba returns an int
    kernels.sense(0, (r0, r1, r0, r1), level, key, tables, geo.kernel_geometry(), glob, loc, comm)
    readings = comm.readings[0, : r1 - r0, : r1 - r0]
    return readings, comm.comm_sum, comm.comm_cnt, (slice(r0, r1), slice(r0, r1))


def test_belief_update_matches_closed_form():
    """Readings without flips move log-odds by exactly +-log((1-q)/q) per reading."""
    env = uav_ipp.make_env("env1")
    level, q = 1, 0.265
    truth = (np.arange(493 * 493).reshape(493, 493) % 3 == 0).astype(np.uint8)
    logodds = np.zeros((493, 493), np.int16)
    for k in range(1, 4):
        _, _, _, box = _sense_once(env, logodds, truth, level, threshold=0)
        expected = np.where(truth[box] == 1, 1.0, -1.0) * k * math.log((1 - q) / q)
        p = 1 / (1 + np.exp(-logodds[box] / kernels.SCALE))
        np.testing.assert_allclose(p, 1 / (1 + np.exp(-expected)), atol=2e-3)
    outside = np.ones_like(logodds, bool)
    outside[box] = False
    assert np.all(logodds[outside] == 0)
    # always-flipping readings undo it
    for _ in range(3):
        _sense_once(env, logodds, truth, level, threshold=65536)
    assert np.all(logodds == 0)


def test_sensor_flip_rate_matches_altitude_table():
    env = uav_ipp.make_env("env1")
    truth = np.ones((493, 493), np.uint8)
    for level, q in enumerate((0.01, 0.265, 0.375)):
        readings, comm_sum, comm_cnt, _ = _sense_once(
            env, np.zeros((493, 493), np.int16), truth, level, kernels.flip_threshold(q), seed=11
        )
        count = readings.size
        assert comm_cnt.sum() == count and comm_sum.sum() == readings.sum()
        flips = 1 - readings.mean()
        assert abs(flips - q) < 4 * math.sqrt(q * (1 - q) / count) + 1e-4


def _received_image(env, image, alpha_low, sigma, soft, increment):
    """Decode a 0/1 image (the centre footprint at 15 m) through the receive kernel into a blank
    M_r with a large increment, and return the evidence each cell's log-odds change implies."""
    geo = env.geometry
    r0, r1 = geo.footprint_ranges[5, 2]
    comm = kernels.CommState.blank(2, geo.max_footprint, geo.comm_grid)
    comm.readings[1, : r1 - r0, : r1 - r0] = image  # sender 1 -> receiver 0
    loc = kernels.LocalMaps.blank(2, 493, 11, geo.n_strips, 44)
    tables = env._tables._replace(increments=np.full_like(env._increments, increment))
    channel = kernels.Channel(np.ones((2, 2), bool), np.full((2, 2), alpha_low), sigma, soft)
    glob = kernels.GlobalMaps.blank(493, 11)
    kernels.receive(0, 1, (r0, r1, r0, r1), 2, np.uint64(99), channel, tables, geo.kernel_geometry(), glob, loc, comm)
    return loc.logodds[0, r0:r1, r0:r1].astype(np.float64)


@pytest.mark.parametrize("preset", ["none", "moderate", "loud"])
def test_channel_noise_statistics(preset):
    """Each received cell is a I + n, a ~ U(alpha_low, 1), n ~ N(0, sigma^2); soft decoding adds
    increment x (2 clip(I_r, 0, 1) - 1), so the log-odds change reveals the evidence per cell."""
    env = uav_ipp.make_env("env1")
    lo, sigma = uav_ipp.NOISE_PRESETS[preset]
    inc = 1000
    side = env.geometry.footprint_ranges[5, 2, 1] - env.geometry.footprint_ranges[5, 2, 0]
    ones = np.ones((side, side), np.uint8)
    evidence = (_received_image(env, ones, lo, sigma, True, inc) / inc + 1) / 2
    rng = np.random.default_rng(0)
    model = np.clip(rng.uniform(lo, 1, 400_000) + rng.normal(0, sigma, 400_000), 0, 1)
    assert evidence.mean() == pytest.approx(model.mean(), abs=2e-3 + 4 * model.std() / side)
    assert evidence.std() == pytest.approx(model.std(), rel=0.1, abs=1e-3)
    zeros = (_received_image(env, 0 * ones, lo, sigma, True, inc) / inc + 1) / 2
    assert zeros.mean() == pytest.approx(np.clip(rng.normal(0, sigma, 400_000), 0, 1).mean(), abs=2e-3)
    # threshold decoding: a full +-increment, flipped only where the noise crosses 0.5
    hard = _received_image(env, ones, lo, sigma, False, inc)
    assert set(np.unique(hard)) <= {-inc, inc}
    assert (hard > 0).mean() == pytest.approx(
        (rng.uniform(lo, 1, 400_000) + rng.normal(0, sigma, 400_000) > 0.5).mean(), abs=3e-3
    )


def test_incremental_bookkeeping_matches_full_recompute():
    env = uav_ipp.make_env("env1", budget=10)
    hist = random_episode(env, seed=2)
    info, obs = hist[-1][1], hist[-1][2]
    truth = env.ground_truth.valuable
    p = env.global_belief().astype(np.float64)
    pred = p > 0.5
    tp = np.sum(pred & truth)
    f1 = 2 * tp / (pred.sum() + truth.sum())
    assert info["f1"] == pytest.approx(f1, abs=1e-9)
    assert info["entropy"] == pytest.approx(kernels.binary_entropy(p[truth]).mean(), abs=1e-4)
    assert info["reward_entropy"] == pytest.approx(kernels.binary_entropy(p).sum(), rel=1e-4)
    weighted = uav_ipp.make_env("env1", budget=10, reward_entropy="weighted")
    info_w = random_episode(weighted, seed=2)[-1][1]
    p_w = weighted.global_belief().astype(np.float64)
    assert info_w["reward_entropy"] == pytest.approx(kernels.weighted_entropy(p_w).sum(), rel=1e-4)
    geo = env.geometry
    state = obs["uav_0"][layout.KEY_STATE]
    blocks = np.zeros((11, 11))
    np.add.at(blocks, (geo.block_of_cell[:, None], geo.block_of_cell[None, :]), p)
    np.testing.assert_allclose(state[layout.GLOBAL_BELIEF], blocks / geo.block_area, atol=1e-4)
    # local 11x11 channels equal the block means of the per-cell M_i (and of the comm-grid sensor map)
    beliefs = env.local_beliefs().astype(np.float64)
    for u, agent in enumerate(env.possible_agents):
        local = obs[agent][layout.KEY_LOCAL]
        np.testing.assert_allclose(local[layout.BELIEF], _block_means(geo, beliefs[u]), atol=1e-4)
        np.testing.assert_allclose(
            local[layout.BELIEF_ENTROPY], _block_means(geo, kernels.binary_entropy(beliefs[u])), atol=1e-4
        )
        np.testing.assert_allclose(local[layout.SENSOR], np.clip(geo.to_lattice(env.sensor_maps()[u]), 0, 1), atol=1e-4)
    # team metrics: each UAV's own M_i scored like the global map, then averaged
    f1s = [2 * np.sum((b > 0.5) & truth) / ((b > 0.5).sum() + truth.sum()) for b in beliefs]
    ents = [kernels.binary_entropy(b[truth]).mean() for b in beliefs]
    assert info["team_f1"] == pytest.approx(np.mean(f1s), abs=1e-9)
    assert info["team_entropy"] == pytest.approx(np.mean(ents), abs=1e-4)


def _block_means(geo, cell_map):
    blocks = np.zeros((geo.lattice, geo.lattice))
    np.add.at(blocks, (geo.block_of_cell[:, None], geo.block_of_cell[None, :]), cell_map)
    return blocks / geo.block_area


def test_action_gain_is_the_exact_footprint_gain_of_own_belief():
    """action_gain = the expected entropy drop summed over each action's target footprint, from the
    UAV's own per-cell M_i (brute force over cells), normalised by the best valid action."""
    env = uav_ipp.make_env("env3", budget=6, comm_range=30.0)
    hist = random_episode(env, seed=4)
    obs = hist[-1][2]
    geo = env.geometry
    flips = [env.config.flip_probability[a] for a in env.config.altitudes]
    beliefs = env.local_beliefs().astype(np.float64)
    for u, agent in enumerate(env.possible_agents):
        mask = obs[agent][layout.KEY_MASK]
        for w, weighting in enumerate(gain.WEIGHTINGS):
            raw = np.zeros(6)
            for act in np.flatnonzero(mask):
                x, y, z = np.clip(env._pos[u] + ACTION_DELTAS[act], 0, [10, 10, 2])
                fp = geo.footprint(int(x), int(y), int(z))
                cells = beliefs[u, fp.r0 : fp.r1, fp.c0 : fp.c1]
                raw[act] = gain.gain_density(cells, flips[z], weighting).sum()
            expected = raw / np.abs(raw).max()
            np.testing.assert_allclose(obs[agent][layout.KEY_GAIN][w], expected, atol=2e-4)


def test_metrics_on_hand_made_map(tmp_path):
    """A left-half-valuable image: F1 and entropy computed from first principles."""
    import cv2

    img = np.zeros((100, 100), np.uint8)
    img[:, :50] = 255
    path = tmp_path / "half.png"
    cv2.imwrite(str(path), img)
    env = uav_ipp.make_env(
        "mine",
        map_path=str(path),
        valuable="threshold:0.5",
        n_uavs=1,
        flip_probability={5.0: 1e-9, 10.0: 1e-9, 15.0: 1e-9},
        budget=1,
    )
    env.reset(seed=0)
    truth = env.ground_truth.valuable
    assert truth[:, :240].all() and not truth[:, 260:].any()
    m = env.metrics()
    # start at (10, 10, 15): a perfect sensor sees 171x171 cells (clipped) all on the valuable side
    seen = env._measured.astype(bool)
    tp = np.sum(seen & truth)
    assert m["f1"] == pytest.approx(2 * tp / (tp + truth.sum()), abs=1e-9)
    assert m["entropy"] == pytest.approx(1.0 - tp / truth.sum(), abs=1e-3)


def test_reward_sign_and_scale():
    env = uav_ipp.make_env("env1", budget=3)
    env.reset(seed=0)
    h0 = env.metrics()["reward_entropy"]
    _, rewards, _, _, infos = env.step({a: 5 for a in env.agents})  # all descend: fresh cells
    h1 = infos["uav_0"]["reward_entropy"]
    expected = 10.0 * (h0 - h1) / h0 - 0.17
    assert all(r == pytest.approx(expected) for r in rewards.values())
    assert h1 < h0 and rewards["uav_0"] > -0.17
    # the relative reduction is a fraction of the map: one step's reward stays well inside alpha
    assert -1.0 < rewards["uav_0"] < 10.0


def test_masks_at_border_altitude_and_conflicts():
    env = uav_ipp.make_env("env1", n_uavs=2, start_positions=[(0, 0, 15), (5, 0, 5)], budget=3)
    env.reset(seed=0)
    m = env.action_masks()
    # uav_0 at the corner, top altitude: no up, no -x, no -y, no +x (uav_1 there); down and +y ok
    np.testing.assert_array_equal(m[0], [0, 0, 0, 1, 0, 1])
    # uav_1 at the bottom altitude: no down, no -y, no -x (uav_0 there)
    np.testing.assert_array_equal(m[1], [1, 0, 0, 1, 1, 0])


def test_invalid_action_hovers_and_bad_action_raises():
    env = uav_ipp.make_env("env1", n_uavs=2, start_positions=[(0, 0, 15), (5, 0, 5)], budget=3)
    env.reset(seed=0)
    before = env._pos.copy()
    env.step({"uav_0": 1, "uav_1": 5})  # -x off the field; down below the lowest altitude
    np.testing.assert_array_equal(env._pos, before)
    with pytest.raises(ValueError, match=r"0\.\.5"):
        env.step({"uav_0": 7, "uav_1": 0})
    with pytest.raises(ValueError, match=r"0\.\.5"):
        env.step({"uav_0": "up", "uav_1": 0})
    with pytest.raises(ValueError, match="missing"):
        env.step({"uav_0": 0})
    with pytest.raises(ValueError, match="unknown agent"):
        env.step({"uav_0": 0, "uav_1": 0, "uav_9": 0})


def test_simultaneous_moves_never_share_a_column():
    env = uav_ipp.make_env("env1", n_uavs=2, start_positions=[(0, 0, 15), (10, 0, 15)], budget=3)
    env.reset(seed=0)
    env.step({"uav_0": 4, "uav_1": 1})  # both aim at (5, 0)
    cols = {tuple(p[:2]) for p in env._pos}
    assert len(cols) == 2


def test_global_map_never_sees_channel_noise():
    quiet = random_episode(uav_ipp.make_env("env1", noise="none", budget=5), seed=9)
    loud = random_episode(uav_ipp.make_env("env1", noise="loud", budget=5), seed=9)
    # identical global metrics and state channels; only the received maps differ
    for (rq, iq, oq), (rl, il, ol) in zip(quiet, loud):
        assert iq["f1"] == il["f1"] and rq == rl
        np.testing.assert_array_equal(oq["uav_0"][layout.KEY_STATE], ol["uav_0"][layout.KEY_STATE])


def test_comm_range_zero_isolates_uavs():
    env = uav_ipp.make_env("env1", comm_range=0.0, budget=2)
    obs, _ = env.reset(seed=0)
    assert np.all(obs["uav_0"][layout.KEY_RECEIVED_VALID] == [1, 0, 0, 0])
    assert np.all(obs["uav_0"][layout.KEY_RECEIVED][1:] == 0.5)


def test_drop_probability_one_drops_everything():
    env = uav_ipp.make_env("env1", drop_probability=1.0, comm_range=1e9, budget=2)
    obs, _ = env.reset(seed=0)
    assert np.all(obs["uav_3"][layout.KEY_RECEIVED_VALID] == [1, 0, 0, 0])


def test_random_starts_are_seeded_and_distinct():
    env = uav_ipp.make_env("env1", start="random", n_uavs=6)
    env.reset(seed=5)
    a = env._pos.copy()
    env.reset(seed=5)
    np.testing.assert_array_equal(a, env._pos)
    assert len({tuple(p[:2]) for p in a}) == 6


def test_render_modes():
    env = uav_ipp.make_env("env1", render_mode="rgb_array", budget=2)
    env.reset(seed=0)
    img = env.render()
    assert img.shape == (493, 493, 3) and img.dtype == np.uint8
    text = uav_ipp.make_env("env1", render_mode="ansi")
    text.reset(seed=0)
    assert "f1=" in text.render()


BAD_OPTIONS = [
    ({"budget": -1}, "budget"),
    ({"budget": 0}, "budget"),
    ({"n_uavs": 0}, "n_uavs"),
    ({"n_uavs": 500}, "n_uavs"),
    ({"noise": "deafening"}, "noise"),
    ({"start_altitude": 12.0}, "start_altitude"),
    ({"altitudes": [5.0, 10.0]}, "start_altitude"),
    ({"flip_probability": {5.0: 0.6, 10.0: 0.2, 15.0: 0.3}}, "flip_probability"),
    ({"flip_probability": {5.0: 0.1}}, "flip_probability"),
    ({"comm_range": -3}, "comm_range"),
    ({"drop_probability": 1.5}, "drop_probability"),
    ({"comm_grid": 45}, "comm_grid"),
    ({"start": "anywhere"}, "start"),
    ({"start_positions": [(10, 10, 15)]}, "start_positions"),
    ({"n_uavs": 2, "start_positions": [(10, 10, 15), (10, 10, 5)]}, "start_positions"),
    ({"n_uavs": 1, "start_positions": [(12, 10, 15)]}, "start_positions"),
    ({"render_mode": "human"}, "render_mode"),
    ({"reward_entropy": "fancy"}, "reward_entropy"),
    ({"reward": "money"}, "reward"),
    ({"action_gain": "class"}, "action_gain"),
    ({"colour": "blue"}, "colour"),
    ({"lattice": 1}, "lattice"),
]


@pytest.mark.parametrize("options,option_name", BAD_OPTIONS)
def test_bad_options_raise_clear_errors(options, option_name):
    with pytest.raises(ConfigError, match=option_name):
        uav_ipp.make_env("env1", **options)


def test_unknown_map_is_clear_error():
    with pytest.raises(uav_ipp.MapError, match="env9"):
        uav_ipp.make_env("env9")


def test_action_deltas_match_documented_meaning():
    # 0 up(+z), 1 -x, 2 -y, 3 +y, 4 +x, 5 down(-z)
    np.testing.assert_array_equal(ACTION_DELTAS, [[0, 0, 1], [-1, 0, 0], [0, -1, 0], [0, 1, 0], [1, 0, 0], [0, 0, -1]])


def test_bad_worlds_fail_at_construction_with_the_value_named(tmp_path):
    with pytest.raises(ConfigError, match=r"n_uavs=120.*110 flyable"):
        uav_ipp.make_env("env3", n_uavs=120)
    with pytest.raises(ConfigError, match=r"start_positions.*no-fly"):
        uav_ipp.make_env("env3", n_uavs=1, start_positions=[(20, 20, 15)])
    with pytest.raises(ConfigError, match="field_size"):
        uav_ipp.make_env("env1", field_size=1e6)
    with pytest.raises(uav_ipp.MapError, match="NUL"):
        uav_ipp.make_env("mine", map_path="a\x00b.png", valuable="threshold:0.5")
    with pytest.raises(ConfigError, match="reset seed=-1"):
        uav_ipp.make_env("env1").reset(seed=-1)


def test_map_with_almost_no_valuable_cells_warns(tmp_path):
    import cv2

    img = np.full((100, 100), 255, np.uint8)
    img[50, 50] = 0
    path = tmp_path / "dot.png"
    cv2.imwrite(str(path), img)
    with pytest.warns(UserWarning, match="valuable cell"):
        uav_ipp.make_env("dot", map_path=str(path), valuable="dark:0.5")
