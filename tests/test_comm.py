"""World v2: per-cell local beliefs M_i fed by cell-level messages through the paper's channel."""

from __future__ import annotations

import numpy as np
import pytest

import uav_ipp
from uav_ipp import layout
from uav_ipp.config import ConfigError

#: A fixed flight for every UAV (hover, sweep, descend), so channel settings can be compared.
PLAN = [3, 4, 3, 5, 4, 2, 1, 4]


def fly(plan=PLAN, seed=3, **options):
    env = uav_ipp.make_env("env3", budget=len(plan), **options)
    obs, _ = env.reset(seed=seed)
    infos = []
    for action in plan:
        obs, _, _, _, info = env.step({a: action for a in env.agents})
        infos.append(info["uav_0"])
    return env, obs, infos


def test_uav_out_of_range_holds_only_its_own_readings():
    # two UAVs in opposite corners at 15 m, hovering (up is invalid at the top): no overlap, no link
    corners = [(0.0, 0.0, 15.0), (50.0, 50.0, 15.0)]
    env, obs, _ = fly(plan=[0, 0, 0], n_uavs=2, start_positions=corners, comm_range=10.0)
    glob, local = env._logodds, env.local_logodds()
    geo = env.geometry
    for u, (ix, iy) in enumerate([(0, 0), (10, 10)]):
        fp = geo.footprint(ix, iy, 2)
        inside = np.zeros_like(glob, bool)
        inside[fp.r0 : fp.r1, fp.c0 : fp.c1] = True
        np.testing.assert_array_equal(local[u][inside], glob[inside])  # its own readings, exactly
        assert np.all(local[u][~inside] == 0)  # nothing else
        np.testing.assert_array_equal(obs[f"uav_{u}"][layout.KEY_RECEIVED_VALID], [1, 0])


def test_noiseless_message_gives_the_receiver_what_the_senders_readings_imply():
    """With no noise, unlimited range and no drops every M_i holds every reading: M_i = global map."""
    env, obs, infos = fly(noise="none", comm_range=float("inf"))
    for u in range(env.n_uavs):
        np.testing.assert_array_equal(env.local_logodds()[u], env._logodds)
    assert infos[-1]["team_f1"] == pytest.approx(infos[-1]["f1"], abs=1e-12)
    assert infos[-1]["team_entropy"] == pytest.approx(infos[-1]["entropy"], abs=1e-9)
    assert np.all(obs["uav_2"][layout.KEY_RECEIVED_VALID] == 1)


def test_threshold_decoder_without_noise_equals_soft():
    soft, _, _ = fly(noise="none", comm_range=float("inf"), decoder="soft")
    hard, _, _ = fly(noise="none", comm_range=float("inf"), decoder="threshold")
    np.testing.assert_array_equal(soft.local_logodds(), hard.local_logodds())


def test_loud_soft_channel_raises_team_entropy_threshold_much_less():
    def team_entropy(noise, decoder):
        return fly(noise=noise, decoder=decoder, comm_range=float("inf"))[2][-1]["team_entropy"]

    clean = team_entropy("none", "soft")
    soft_loud = team_entropy("loud", "soft")
    hard_loud = team_entropy("loud", "threshold")
    assert soft_loud > clean + 0.02
    assert abs(hard_loud - clean) < 0.2 * (soft_loud - clean)


@pytest.mark.parametrize(
    "channel",
    [
        {"noise": "loud"},
        {"noise": "loud", "decoder": "threshold"},
        {"attenuation": "distance"},
        {"drop_probability": 0.5},
        {"alpha_low": 0.1, "sigma": 0.3},
        {"comm_range": 0.0},
    ],
)
def test_global_map_and_paper_metrics_ignore_every_channel_setting(channel):
    base, base_obs, base_infos = fly(noise="none")
    other, other_obs, other_infos = fly(**channel)
    np.testing.assert_array_equal(base._logodds, other._logodds)
    for a, b in zip(base_infos, other_infos):
        assert (a["f1"], a["entropy"], a["reward_entropy"]) == (b["f1"], b["entropy"], b["reward_entropy"])
    np.testing.assert_array_equal(base_obs["uav_0"][layout.KEY_STATE], other_obs["uav_0"][layout.KEY_STATE])
    np.testing.assert_array_equal(base.sensor_maps(), other.sensor_maps())  # own data stays clean


def test_explicit_alpha_low_and_sigma_override_the_preset():
    assert uav_ipp.make_env("env1", noise="loud", sigma=0.0).config.noise_params == (0.6, 0.0)
    assert uav_ipp.make_env("env1", noise="none", alpha_low=0.5).config.noise_params == (0.5, 0.0)
    quiet = fly(noise="loud", alpha_low=1.0, sigma=0.0, comm_range=float("inf"))[0]
    none = fly(noise="none", comm_range=float("inf"))[0]
    np.testing.assert_array_equal(quiet.local_logodds(), none.local_logodds())


def test_distance_attenuation_is_milder_than_uniform_inside_the_range():
    uniform = fly(noise="loud", comm_range=float("inf"))[2][-1]["team_entropy"]
    distance = fly(noise="loud", comm_range=60.0, attenuation="distance")[2][-1]["team_entropy"]
    clean = fly(noise="none", comm_range=float("inf"))[2][-1]["team_entropy"]
    assert clean < distance < uniform


def test_received_map_is_the_comm_grid_average_of_the_noisy_image():
    env, obs, _ = fly(plan=[0], noise="none", comm_range=float("inf"))
    received = obs["uav_1"][layout.KEY_RECEIVED]
    # without noise the copy of uav_0's patch equals uav_0's own (clean) sensor map
    np.testing.assert_allclose(received[1], env.sensor_maps()[0], atol=1e-6)
    loud, loud_obs, _ = fly(plan=[0], noise="loud", comm_range=float("inf"))
    got = loud_obs["uav_1"][layout.KEY_RECEIVED][1]
    own = loud.sensor_maps()[0]
    seen = own != 0.5
    # E[a] = 0.8 for loud: valuable fractions shrink by ~0.8 on average
    assert got[seen].sum() == pytest.approx(0.8 * own[seen].sum(), rel=0.05)


@pytest.mark.parametrize(
    "options,name",
    [
        ({"alpha_low": 1.5}, "alpha_low"),
        ({"alpha_low": "x"}, "alpha_low"),
        ({"sigma": -0.1}, "sigma"),
        ({"sigma": float("nan")}, "sigma"),
        ({"attenuation": "cubic"}, "attenuation"),
        ({"decoder": "fuzzy"}, "decoder"),
        ({"split": "validation"}, "split"),
        ({"altitudes": [5.0, 10.0, 15.0, 20.0]}, "altitudes"),
        ({"fov_deg": 0.001}, "fov_deg"),
        ({"alpha": 1e300}, "alpha"),
    ],
)
def test_new_channel_options_are_validated(options, name):
    with pytest.raises(ConfigError, match=name):
        uav_ipp.make_env("env1", **options)
