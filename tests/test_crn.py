"""Common random numbers: every random draw of the world is a counter-based hash of what is drawn.

Sensor flips are keyed on (mission seed, step, UAV, cell), channel noise on (mission seed, step,
sender, receiver, cell) and message drops on (mission seed, step, sender, receiver); the mission
seed is the reset seed. So two plans that take the same measurement get the same reading, the
same seed and actions replay bit for bit, and the draws still have the configured statistics.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import uav_ipp
from uav_ipp import kernels, layout

#: Two UAVs in opposite corners at 15 m: footprints never overlap, so each UAV's M_i holds its own
#: readings in its footprint and only the other's message in the other footprint.
CORNERS = [(0.0, 0.0, 15.0), (50.0, 50.0, 15.0)]


def _fly(env: uav_ipp.UavIppEnv, seed: int | None, plan: list[list[int]]) -> list[dict]:
    """Reset and fly ``plan`` (one action per UAV per step); record, per measurement, every UAV's
    readings, the change of every M_i and of the global map, the links, rewards and infos."""
    frames = []
    before_local = np.zeros_like(env.local_logodds())
    before_glob = np.zeros_like(env._logodds)
    obs, _ = env.reset(seed=seed)
    rewards: dict = {}
    infos: dict = {}
    for k in range(len(plan) + 1):
        local = env.local_logodds()
        frames.append(
            {
                "pos": env.lattice_positions(),
                "readings": [env.footprint_readings(u) for u in range(env.n_uavs)],
                "local_delta": local.astype(np.int32) - before_local,
                "glob_delta": env._logodds.astype(np.int32) - before_glob,
                "links": env._links_now.copy(),
                "obs": obs,
                "rewards": rewards,
                "infos": infos,
            }
        )
        before_local, before_glob = local, env._logodds.copy()
        if k < len(plan):
            obs, rewards, _, _, infos = env.step({a: plan[k][i] for i, a in enumerate(env.possible_agents)})
    return frames


def test_same_measurement_gets_the_same_reading_under_different_plans():
    """Two plans that differ on step 1 but meet at the same positions on steps 2 and 3: those
    measurements, the messages about them and their noise are identical, bit for bit."""
    options = dict(n_uavs=2, start_positions=[(10.0, 10.0, 15.0), (40.0, 40.0, 15.0)], budget=3)
    options.update(noise="loud", comm_range=float("inf"), drop_probability=0.3)
    # uav_0: +x then -x, or -x then +x; uav_1: +y then -y, or down then up; then both descend
    plan_a = [[4, 3], [1, 2], [5, 5]]
    plan_b = [[1, 5], [4, 0], [5, 5]]
    a = _fly(uav_ipp.make_env("env3", **options), 11, plan_a)
    b = _fly(uav_ipp.make_env("env3", **options), 11, plan_b)
    assert not np.array_equal(a[1]["pos"], b[1]["pos"])  # the plans really differ on step 1
    for k in (0, 2, 3):
        np.testing.assert_array_equal(a[k]["pos"], b[k]["pos"])
        for u in range(2):
            np.testing.assert_array_equal(a[k]["readings"][u], b[k]["readings"][u])
        np.testing.assert_array_equal(a[k]["links"], b[k]["links"])  # drops: keyed, not sequential
        # own readings and received messages change each M_i by the same amount (no clamp at 15/10 m)
        np.testing.assert_array_equal(a[k]["local_delta"], b[k]["local_delta"])
        np.testing.assert_array_equal(a[k]["glob_delta"], b[k]["glob_delta"])
    # not vacuous: uav_1 did receive uav_0's loud message on a compared step (its change is then
    # not +-increment everywhere), and the drops did lose some message on the way
    delivered = [k for k in (0, 2, 3) if a[k]["links"][1, 0]]
    assert any(len(np.unique(a[k]["local_delta"][1])) > 3 for k in delivered)
    assert not all(f["links"].all() for f in a)


def test_same_seed_and_actions_replay_bit_for_bit():
    options = dict(n_uavs=4, budget=6, noise="loud", drop_probability=0.3, split="train")
    plan = [[3, 4, 2, 5], [5, 1, 0, 3], [2, 2, 4, 1], [4, 5, 5, 0], [0, 3, 1, 2], [1, 0, 3, 4]]
    first = _fly(uav_ipp.make_env("env3", **options), 5, plan)
    env = uav_ipp.make_env("env3", **options)
    _fly(env, 6, plan)  # another mission in between: nothing carries over
    second = _fly(env, 5, plan)
    for fa, fb in zip(first, second):
        for key in ("pos", "local_delta", "glob_delta", "links"):
            np.testing.assert_array_equal(fa[key], fb[key], err_msg=key)
        for ra, rb in zip(fa["readings"], fb["readings"]):
            np.testing.assert_array_equal(ra, rb)
        assert fa["rewards"] == fb["rewards"] and fa["infos"] == fb["infos"]
        for agent in fa["obs"]:
            for key in fa["obs"][agent]:
                np.testing.assert_array_equal(fa["obs"][agent][key], fb["obs"][agent][key])


def test_different_seeds_draw_different_noise():
    options = dict(n_uavs=2, start_positions=CORNERS, budget=1, noise="loud", comm_range=float("inf"))
    a = _fly(uav_ipp.make_env("env3", **options), 0, [[0, 0]])
    b = _fly(uav_ipp.make_env("env3", **options), 1, [[0, 0]])
    for k in range(2):
        np.testing.assert_array_equal(a[k]["pos"], b[k]["pos"])  # same fixed mission, same positions
        assert not np.array_equal(a[k]["readings"][0], b[k]["readings"][0])
        assert not np.array_equal(a[k]["local_delta"][1], b[k]["local_delta"][1])
    # the same UAV over the same cells at the next step draws anew (hovering: new flips)
    assert not np.array_equal(a[0]["readings"][0], a[1]["readings"][0])


def test_unseeded_resets_vary_and_follow_the_env_generator():
    env = uav_ipp.make_env("env3", n_uavs=2, start_positions=CORNERS, budget=1)
    env.reset()
    first = env.footprint_readings(0)
    env.reset()
    assert not np.array_equal(first, env.footprint_readings(0))
    # an unseeded reset derives its mission seed from the env's generator: reproducible after a seed
    replay = []
    for _ in range(2):
        env.reset(seed=8)
        env.reset()
        replay.append(env.footprint_readings(0))
    np.testing.assert_array_equal(*replay)
    env.reset(seed=8)
    assert not np.array_equal(replay[0], env.footprint_readings(0))


def test_readings_and_messages_follow_the_documented_keys():
    """Readings are ``truth ^ (flip_draws(seed, step, uav, cells) < threshold)``; a threshold
    receiver's bit is ``a I + n > 0.5`` with ``(a, n) = channel_draws(seed, step, sender, receiver)``."""
    alpha_low, sigma = 0.1, 0.3  # a wide channel: many cells cross 0.5, so the keys are pinned down
    env = uav_ipp.make_env(
        "env3",
        n_uavs=2,
        start_positions=CORNERS,
        budget=1,
        decoder="threshold",
        alpha_low=alpha_low,
        sigma=sigma,
        comm_range=float("inf"),
    )
    seed, grid = 21, env.config.grid
    key = kernels.mission_seed(seed)
    env.reset(seed=seed)
    truth = env.ground_truth.valuable.astype(np.uint8)
    threshold = kernels.flip_threshold(env.config.flip_probability[15.0])
    increment = int(env._increments[2])
    before = np.zeros((2, grid, grid), np.int32)
    crossed = 0
    for step in range(2):
        local = env.local_logodds().astype(np.int32)
        fps = [env.geometry.footprint(int(x), int(y), int(z)) for x, y, z in env.lattice_positions()]
        for u, fp in enumerate(fps):
            draws = kernels.flip_draws(key, step, u, (fp.r0, fp.r1, fp.c0, fp.c1), grid)
            expected = truth[fp.r0 : fp.r1, fp.c0 : fp.c1] ^ (draws < threshold).astype(np.uint8)
            np.testing.assert_array_equal(env.footprint_readings(u), expected)
        for sender, receiver in ((0, 1), (1, 0)):
            fp = fps[sender]
            rect = (fp.r0, fp.r1, fp.c0, fp.c1)
            a, n = kernels.channel_draws(key, step, sender, receiver, rect, grid, alpha_low, sigma, env._normals)
            image = env.footprint_readings(sender)
            bits = a * image + n > 0.5
            crossed += int((bits != image.astype(bool)).sum())
            delta = (local - before)[receiver, fp.r0 : fp.r1, fp.c0 : fp.c1]
            np.testing.assert_array_equal(delta, np.where(bits, increment, -increment))
        before = local
        if step == 0:
            env.step({"uav_0": 0, "uav_1": 0})  # up is invalid at the top altitude: both hover
    assert crossed > 1000  # the check is not vacuous: the channel flipped many bits


@pytest.mark.parametrize("level,altitude", [(0, 5.0), (1, 10.0), (2, 15.0)])
def test_flip_frequency_matches_the_configured_probability(level, altitude):
    """At least ~100k readings per altitude, from the env itself, flip with the configured q."""
    q = uav_ipp.IppConfig().flip_probability[altitude]
    starts = [(10.0, 10.0 + 10.0 * k, altitude) for k in range(4)]
    steps = {0: 8, 1: 2, 2: 1}[level]
    env = uav_ipp.make_env("env1", n_uavs=4, start_positions=starts, budget=steps)
    env.reset(seed=100 + level)
    truth = env.ground_truth.valuable.astype(np.uint8)
    flips = cells = 0
    for k in range(steps + 1):
        for u, (x, y, z) in enumerate(env.lattice_positions()):
            assert z == level
            fp = env.geometry.footprint(int(x), int(y), int(z))
            flips += int((env.footprint_readings(u) != truth[fp.r0 : fp.r1, fp.c0 : fp.c1]).sum())
            cells += fp.shape[0] * fp.shape[1]
        if k < steps:
            move = 4 if k % 2 == 0 else 1  # +x, then back: the altitude never changes
            env.step({a: move for a in env.possible_agents})
    assert cells >= 100_000
    rate = flips / cells
    assert abs(rate - q) < 5 * math.sqrt(q * (1 - q) / cells), (rate, q, cells)


@pytest.mark.parametrize("preset", ["moderate", "loud"])
def test_channel_noise_has_the_preset_mean_and_spread(preset):
    """a ~ U(alpha_low, 1) and n ~ N(0, sigma^2) (quantile table, |n| < 3.7 sigma), over ~150k
    cells of one step's messages, and independent of each other."""
    alpha_low, sigma = uav_ipp.NOISE_PRESETS[preset]
    normals = kernels.normal_table()
    a_all, n_all = [], []
    for sender, receiver in ((0, 1), (1, 0), (2, 3), (3, 2), (0, 3)):
        rect = (0, 171, 0, 171)  # a whole 15 m footprint
        a, n = kernels.channel_draws(kernels.mission_seed(4), 7, sender, receiver, rect, 493, alpha_low, sigma, normals)
        a_all.append(a.ravel())
        n_all.append(n.ravel())
    a, n = np.concatenate(a_all), np.concatenate(n_all)
    count = a.size
    assert count >= 100_000
    spread = (1 - alpha_low) / math.sqrt(12)
    assert a.mean() == pytest.approx((1 + alpha_low) / 2, abs=5 * spread / math.sqrt(count) + 1e-5)
    assert a.std() == pytest.approx(spread, rel=0.01)
    assert a.min() >= alpha_low and a.max() < 1.0
    assert n.mean() == pytest.approx(0.0, abs=5 * sigma / math.sqrt(count))
    assert n.std() == pytest.approx(sigma, rel=0.01)
    assert np.abs(n).max() <= 3.7 * sigma  # the table's outermost quantiles are +-3.67
    assert abs(np.corrcoef(a, n)[0, 1]) < 5 / math.sqrt(count)
    # distinct links of the same step draw independent noise
    assert abs(np.corrcoef(n_all[0], n_all[1])[0, 1]) < 5 / math.sqrt(n_all[0].size)


def test_drop_rate_matches_drop_probability():
    p = 0.3
    draws = np.empty((4, 4))
    dropped = []
    for seed in range(40):
        for step in range(160):
            kernels.link_uniforms(kernels.mission_seed(seed), step, draws)
            dropped.append(draws < p)
    dropped_arr = np.array(dropped)
    count = dropped_arr.size
    assert count >= 100_000
    assert dropped_arr.mean() == pytest.approx(p, abs=5 * math.sqrt(p * (1 - p) / count))
    # each ordered pair (receiver, sender) drops at the same rate: no link is favoured
    per_link = dropped_arr.mean(axis=0)
    assert np.all(np.abs(per_link - p) < 5 * math.sqrt(p * (1 - p) / len(dropped_arr)))
    # and the env applies exactly these draws to the links in range
    env = uav_ipp.make_env("env1", n_uavs=4, budget=15, comm_range=float("inf"), drop_probability=p)
    env.reset(seed=3)
    lost = total = 0
    for step in range(16):
        kernels.link_uniforms(kernels.mission_seed(3), step, draws)
        expected = draws >= p
        np.fill_diagonal(expected, True)
        np.testing.assert_array_equal(env._links_now, expected)
        off = ~np.eye(4, dtype=bool)
        lost += int((~env._links_now[off]).sum())
        total += int(off.sum())
        if env.agents:
            masks = env.action_masks()
            env.step({a: int(np.flatnonzero(masks[i])[0]) for i, a in enumerate(env.possible_agents)})
    assert 0 < lost < total


def test_channel_settings_never_change_readings_or_drops():
    """Flips and drops have their own keys: the noise preset changes only the channel draws."""
    options = dict(n_uavs=3, budget=3, drop_probability=0.4)
    plan = [[3, 4, 5], [4, 5, 2], [5, 3, 1]]
    quiet = _fly(uav_ipp.make_env("env3", noise="none", **options), 9, plan)
    loud = _fly(uav_ipp.make_env("env3", noise="loud", **options), 9, plan)
    for fq, fl in zip(quiet, loud):
        np.testing.assert_array_equal(fq["links"], fl["links"])
        np.testing.assert_array_equal(fq["glob_delta"], fl["glob_delta"])
        for rq, rl in zip(fq["readings"], fl["readings"]):
            np.testing.assert_array_equal(rq, rl)
        np.testing.assert_array_equal(fq["obs"]["uav_0"][layout.KEY_STATE], fl["obs"]["uav_0"][layout.KEY_STATE])
