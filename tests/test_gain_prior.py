"""The per-action information-gain observation, the ``metrics`` reward and COMA's gain prior.

The env computes, for each UAV, the expected information gain of every action's footprint from
the UAV's own local belief (``obs["action_gain"]``, two entropy weightings); the actor can add a
learned mix of them to its logits (``policy_kwargs={"gain_prior": ...}``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

import uav_ipp
from sb3_coma import COMA
from sb3_coma.baselines.adaptive_gain import plan_team
from uav_ipp import layout
from uav_ipp.ipp_env import ACTION_DELTAS

SMALL = dict(n_uavs=2, budget=4)


def _positions(env) -> np.ndarray:
    return env._pos.copy()


def test_action_gain_is_normalised_masked_and_matches_ag():
    env = uav_ipp.make_env("env3")
    geometry = env.geometry
    rng = np.random.default_rng(3)
    obs, _ = env.reset(seed=3)
    for _ in range(5):
        obs, *_ = env.step({a: int(rng.choice(np.flatnonzero(obs[a][layout.KEY_MASK]))) for a in env.agents})
        masks = np.stack([obs[a][layout.KEY_MASK] for a in env.possible_agents]).astype(bool)
        gains = np.stack([obs[a][layout.KEY_GAIN] for a in env.possible_agents])  # (N, 2, 6)
        assert gains.shape == (4, 2, 6) and gains.dtype == np.float32
        assert np.all(np.abs(gains) <= 1.0)
        assert np.all(gains[~np.repeat(masks[:, None], 2, axis=1)] == 0.0)
        np.testing.assert_allclose(np.abs(np.where(masks[:, None], gains, 0)).max(-1), 1.0, rtol=1e-6)
        sums = env.gain_strip_sums()
        for row, _weighting in enumerate(layout.GAIN_WEIGHTINGS):
            scores, actions = np.zeros((4, 6)), np.zeros(4, np.int64)
            plan_team(
                np.ascontiguousarray(sums[:, row]),
                _positions(env),
                masks,
                env.no_fly_columns(),
                ACTION_DELTAS,
                geometry.footprint_strips,
                0.0,
                1,
                np.zeros((4, 6)),
                np.ones((4, 4), bool),
                scores,
                actions,
            )
            # UAV 0 decides first, so AG's scores, normalised, are exactly its own gains.
            own = scores[0][masks[0]]
            np.testing.assert_allclose(gains[0, row][masks[0]], own / np.abs(own).max(), rtol=1e-5, atol=1e-6)


def test_action_gain_can_be_switched_off():
    env = uav_ipp.make_env("env1", action_gain=False, **SMALL)
    obs, _ = env.reset(seed=0)
    assert layout.KEY_GAIN not in obs["uav_0"]
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", action_gain=False, **SMALL)
    assert layout.KEY_GAIN not in venv.observation_space.spaces
    venv.close()
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", **SMALL)
    assert venv.observation_space[layout.KEY_GAIN].shape == (2, 6)
    assert venv.reset()[layout.KEY_GAIN].shape == (2, 2, 6)
    venv.close()


def test_metrics_reward_pays_the_change_of_f1_and_entropy():
    env = uav_ipp.make_env("env2", reward="metrics", budget=6)
    rng = np.random.default_rng(1)
    obs, _ = env.reset(seed=1)
    m0 = env.metrics()
    total = 0.0
    for _ in range(6):
        acts = {a: int(rng.choice(np.flatnonzero(obs[a][layout.KEY_MASK]))) for a in env.agents}
        obs, rewards, _, _, infos = env.step(acts)
        assert len(set(rewards.values())) == 1
        total += rewards["uav_0"]
    final = infos["uav_0"]
    cfg = env.config
    expected = cfg.alpha * ((final["f1"] - final["entropy"]) - (m0["f1"] - m0["entropy"])) + 6 * cfg.beta
    assert total == pytest.approx(expected, rel=1e-9, abs=1e-9)


def _small_model(**policy_kwargs):
    venv = uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=0, **SMALL)
    kwargs = dict(features_extractor_kwargs={"features_dim": 16}, **policy_kwargs)
    return COMA("UavCnnPolicy", venv, n_steps=8, batch_size=8, seed=0, policy_kwargs=kwargs), venv


def test_gain_prior_starts_as_soft_greedy_planner():
    model, venv = _small_model(gain_prior=5.0)
    actor = model.policy.actor
    np.testing.assert_allclose(actor.prior_weights.detach().numpy(), [5.0, 5.0])
    obs = venv.reset()
    mask = th.as_tensor(obs[layout.KEY_MASK]).float()
    prior = th.as_tensor(obs[layout.KEY_GAIN])
    with th.no_grad():
        logits = model.policy.masked_logits({"local": th.as_tensor(obs[layout.KEY_LOCAL]), "action_gain": prior}, mask)
    expected = 5.0 * prior.sum(1)
    valid = mask.bool()
    # The network's own term starts near zero (output gain 0.01): the prior decides.
    assert th.allclose(logits[valid], expected[valid], atol=0.1)
    scores = th.where(valid, expected, th.tensor(-1e9))
    greedy = scores.argmax(-1).numpy()
    actions, _ = model.predict(obs, deterministic=True)
    # rows whose two best prior logits lie within the network's small term of each other are a
    # near-tie that the network may break either way; every other row follows the prior exactly
    top2 = scores.topk(2, dim=-1).values
    clear = (top2[:, 0] - top2[:, 1] > 0.1).numpy()
    assert clear.sum() >= len(clear) // 2
    np.testing.assert_array_equal(actions[clear], greedy[clear])
    venv.close()


def test_gain_prior_learns_saves_and_loads(tmp_path: Path):
    model, venv = _small_model(gain_prior=2.0, gain_prior_speed=50.0)
    before = model.policy.actor.prior_weights.detach().clone()
    model.learn(32)
    after = model.policy.actor.prior_weights.detach().clone()
    assert not th.allclose(before, after)  # the weights are trained
    assert np.any(model.rollout_buffer.obs[layout.KEY_GAIN] != 0)  # the buffer keeps what the actor acted on
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", env=venv)
    assert loaded.policy.gain_prior == 2.0 and loaded.policy.gain_prior_speed == 50.0
    assert th.allclose(loaded.policy.actor.prior_weights, after)
    obs = venv.reset()
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0])
    venv.close()


def test_no_prior_ignores_the_gain_key():
    model, venv = _small_model()
    assert model.policy.actor.prior_weights is None
    model.learn(16)
    venv.close()


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"gain_prior": -1.0}, "gain_prior=-1.0"),
        ({"gain_prior": float("nan")}, "gain_prior=nan"),
        ({"gain_prior": 1.0, "gain_prior_speed": 0.0}, "gain_prior_speed=0.0"),
        ({"gain_prior": "lots"}, "gain_prior='lots'"),
        ({"gain_prior": [1.0, 2.0, 3.0]}, r"one weight per 'action_gain' row, 2 \(class, plain\), got 3"),
        ({"gain_prior": [1.0, -2.0]}, r"gain_prior=\[1.0, -2.0\]: .*weights must be finite numbers >= 0"),
        ({"gain_prior": [1.0, "x"]}, r"gain_prior=\[1.0, 'x'\]: must be a number or a list of numbers"),
    ],
)
def test_bad_gain_prior_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        _small_model(**kwargs)


def test_untrained_prior_is_the_greedy_mix_the_training_starts_from():
    from sb3_coma.experiments.reproduce import untrained_prior

    model, venv = _small_model(gain_prior=3.0)
    model.learn(32)
    policy = untrained_prior(model)
    np.testing.assert_allclose(policy.actor.prior_weights.detach().numpy(), [3.0, 3.0], rtol=1e-6)
    assert not th.allclose(model.policy.actor.prior_weights, policy.actor.prior_weights)  # the model is untouched
    obs = venv.reset()
    actions, _ = policy.predict(obs, deterministic=True)
    greedy = np.where(obs[layout.KEY_MASK] > 0, obs[layout.KEY_GAIN].sum(1), -np.inf).argmax(-1)
    np.testing.assert_array_equal(actions, greedy)
    no_prior, venv2 = _small_model()
    assert untrained_prior(no_prior) is None
    venv.close()
    venv2.close()


def test_gain_prior_per_row_start_saves_and_loads(tmp_path: Path):
    """``gain_prior=[10, 0]`` starts from the class-weighted row alone (adaptive-gain's choice)."""
    model, venv = _small_model(gain_prior=[10.0, 0.0], gain_prior_speed=100.0)
    np.testing.assert_allclose(model.policy.actor.prior_weights.detach().numpy(), [10.0, 0.0])
    assert model.policy.gain_prior_init == (10.0, 0.0)
    obs = venv.reset()
    greedy = np.where(obs[layout.KEY_MASK] > 0, obs[layout.KEY_GAIN][:, 0], -np.inf).argmax(-1)
    np.testing.assert_array_equal(model.predict(obs, deterministic=True)[0], greedy)
    model.learn(16)
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", env=venv)
    assert loaded.policy.gain_prior == [10.0, 0.0] and loaded.policy.gain_prior_init == (10.0, 0.0)
    assert th.allclose(loaded.policy.actor.prior_weights, model.policy.actor.prior_weights)
    from sb3_coma.experiments.reproduce import untrained_prior

    np.testing.assert_allclose(untrained_prior(loaded).actor.prior_weights.detach().numpy(), [10.0, 0.0], rtol=1e-6)
    venv.close()


def test_all_zero_gain_prior_is_no_prior():
    model, venv = _small_model(gain_prior=[0.0, 0.0])
    assert model.policy.actor.prior_weights is None
    venv.close()


def test_correction_bound_caps_the_network_term_and_round_trips(tmp_path: Path):
    """``correction_bound=c``: the network's term is ``c * tanh(net / c)``, the prior's is untouched."""
    model, venv = _small_model(gain_prior=5.0, correction_bound=2.0)
    obs = venv.reset()
    local, mask, prior = (th.as_tensor(obs[k]).float() for k in (layout.KEY_LOCAL, layout.KEY_MASK, layout.KEY_GAIN))
    rows = {"local": local, "action_gain": prior}
    actor = model.policy.actor
    with th.no_grad():
        raw = actor.head(actor.features_extractor(local))
        th.testing.assert_close(actor.network_logits(local), 2.0 * th.tanh(raw / 2.0))
        actor.head.bias.copy_(th.tensor([50.0, -50.0, 0.0, 0.0, 0.0, 0.0]))  # a swamping correction
        net = actor.network_logits(local)
        assert net.abs().max() <= 2.0 and net[:, 0].min() > 1.99
        th.testing.assert_close(actor(local, prior) - net, actor.prior_logits(prior))
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", env=venv)
    assert loaded.policy.correction_bound == 2.0 and loaded.policy.actor.correction_bound == 2.0
    with th.no_grad():
        th.testing.assert_close(loaded.policy.masked_logits(rows, mask), model.policy.masked_logits(rows, mask))
    venv.close()


@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), "big", True])
def test_correction_bound_rejects_bad_values(bad):
    with pytest.raises(ValueError, match=r"correction_bound=.*must be null \(unbounded\) or a finite number > 0"):
        _small_model(correction_bound=bad)


# --------------------------------------------------------------------------- gain inputs
def test_gain_inputs_are_read_by_the_network_not_added_to_the_logits():
    """``gain_inputs``: the gains feed a learned encoder; the first policy is near-uniform (no
    hand-set weight makes it greedy) and changing only the gains changes the logits."""
    model, venv = _small_model(gain_inputs=True)
    actor = model.policy.actor
    assert actor.prior_weights is None and actor.gain_encoder is not None and actor.reads_gain
    obs = venv.reset()
    local, mask = th.as_tensor(obs[layout.KEY_LOCAL]), th.as_tensor(obs[layout.KEY_MASK]).float()
    gains = th.as_tensor(obs[layout.KEY_GAIN])
    with th.no_grad():
        probs = model.policy.action_probs({"local": local, "action_gain": gains}, mask)
        logits = model.policy.masked_logits({"local": local, "action_gain": gains}, mask)
        flipped = model.policy.masked_logits({"local": local, "action_gain": -gains}, mask)
    valid = mask.bool()
    uniform = mask / mask.sum(-1, keepdim=True)
    assert th.allclose(probs[valid], uniform[valid], atol=0.02)  # output gain 0.01: near-uniform start
    assert not th.allclose(logits[valid], flipped[valid])  # the gains are an input of the network
    with pytest.raises(ValueError, match=r"needs observation\['action_gain'\] \(reads it \(gain_inputs\)\)"):
        model.policy.masked_logits({"local": local}, mask)
    venv.close()


def test_gain_inputs_learn_save_and_load(tmp_path: Path):
    model, venv = _small_model(gain_inputs=True)
    before = [p.detach().clone() for p in model.policy.actor.gain_encoder.parameters()]
    model.learn(32)
    after = list(model.policy.actor.gain_encoder.parameters())
    assert any(not th.equal(b, a) for b, a in zip(before, after))  # the encoder is trained
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", env=venv)
    assert loaded.policy.gain_inputs is True and loaded.policy.gain_input_size == 12
    obs = venv.reset()
    with th.no_grad():
        local, mask, gains = (
            th.as_tensor(obs[k]).float() for k in (layout.KEY_LOCAL, layout.KEY_MASK, layout.KEY_GAIN)
        )
        rows = {"local": local, "action_gain": gains}
        th.testing.assert_close(model.policy.masked_logits(rows, mask), loaded.policy.masked_logits(rows, mask))
    venv.close()


@pytest.mark.parametrize("bad", ["yes", 1, None])
def test_gain_inputs_must_be_a_bool(bad):
    with pytest.raises(ValueError, match=rf"gain_inputs={bad!r}: must be true or false"):
        _small_model(gain_inputs=bad)


def test_gain_inputs_need_the_gain_observation():
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", action_gain=False, **SMALL)
    with pytest.raises(ValueError, match=r"gain_inputs=True needs observation\['action_gain'\]"):
        COMA("UavCnnPolicy", venv, n_steps=8, batch_size=8, seed=0, policy_kwargs={"gain_inputs": True})
    venv.close()
