"""``advantage="v_return"``: the TD(lambda) return bootstrapped with a state value ``V_i(s)`` that
the critic's optimizer fits beside Q, minus the counterfactual baseline (docs/training.md, round 11)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch as th
from coma_fakes import collect_rollout
from pettingzoo import ParallelEnv

from sb3_coma import COMA, make_marl_vec_env
from sb3_coma.coma.policies import MlpPolicy

FAST = {"n_steps": 16, "batch_size": 8, "n_epochs": 1, "n_critic_epochs": 3}


def _spread() -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False)


def _model(**kwargs: Any) -> COMA:
    args = {"seed": 0, "device": "cpu", "advantage": "v_return", **FAST, **kwargs}
    return COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=2, seed=0), **args)


def test_only_v_return_builds_a_state_value() -> None:
    assert _model(advantage="return").policy.value_net is None
    model = _model()
    assert model.policy.value_net is not None
    critic_ids = {id(p) for p in model.policy.critic_parameters()}
    assert {id(p) for p in model.policy.value_net.parameters()} <= critic_ids  # the critic's optimizer trains it
    optimised = {id(p) for group in model.policy.critic_optimizer.param_groups for p in group["params"]}
    assert optimised == critic_ids


@pytest.mark.parametrize("normalize_q", [False, True])
def test_the_returns_bootstrap_with_the_state_value_of_collection_time(normalize_q: bool) -> None:
    """``G_t = r_t + gamma (1 - d_t) ((1 - lambda) V(s_t+1) + lambda G_t+1)``, ``V`` in units of
    return; the last row bootstraps with the rollout's bootstrap value: hand-rolled in numpy."""
    model = _model(td_lambda=0.8, gamma=0.9, n_steps=30, batch_size=20, normalize_q=normalize_q)
    if normalize_q:  # statistics away from (0, 1), so a missed conversion shows
        model.q_scale.update(np.array([-40.0, -20.0, -35.0]))
    collect_rollout(model)
    data = model.rollout_buffer.time_major()
    T, E, N = data["actions"].shape
    assert data["dones"].sum() > 0  # an episode end inside the rollout (25-step episodes)
    values, returns = model._state_value_returns()  # type: ignore[misc]
    flat = model.rollout_buffer.joint_steps()
    with th.no_grad():
        raw = model._v(flat, th.arange(T * E))
    scale = np.sqrt(model.q_scale.var + 1e-8) if normalize_q else 1.0
    shift = model.q_scale.mean if normalize_q else 0.0
    np.testing.assert_allclose(values.numpy(), raw.numpy() * scale + shift, rtol=1e-5, atol=1e-4)
    v = np.concatenate([values.view(T, E, N).numpy(), data["bootstrap"].numpy()[None]])
    r, d = data["rewards"].numpy(), data["dones"].numpy()
    expected, ahead = np.zeros((T, E, N)), v[T]
    for t in range(T - 1, -1, -1):
        blend = v[t + 1] if t == T - 1 else 0.2 * v[t + 1] + 0.8 * ahead
        ahead = r[t] + 0.9 * (1 - d[t]) * blend
        expected[t] = ahead
    np.testing.assert_allclose(returns.view(T, E, N).numpy(), expected, rtol=1e-4, atol=1e-3)


def test_the_advantage_is_that_return_minus_the_baseline(monkeypatch: pytest.MonkeyPatch) -> None:
    model = _model()
    collect_rollout(model)
    _values, expected = model._state_value_returns()  # type: ignore[misc]
    seen: list[th.Tensor] = []
    real = model._advantages

    def spy(data: dict[str, Any], q_all: th.Tensor, returns: th.Tensor) -> Any:
        seen.append(returns.clone())
        return real(data, q_all, returns)

    monkeypatch.setattr(model, "_advantages", spy)
    model.train()
    assert th.allclose(seen[0], expected)


def test_the_state_value_learns_its_returns() -> None:
    """Critic epochs on one rollout bring V toward the returns it is fitted to."""
    model = _model(n_critic_epochs=1, batch_size=32)
    collect_rollout(model)
    data = model.rollout_buffer.joint_steps()
    _values, returns = model._state_value_returns()  # type: ignore[misc]
    everything = th.arange(returns.shape[0])

    def error() -> float:
        with th.no_grad():
            return float(((model._v(data, everything) - returns) ** 2).mean())

    first = error()
    for _ in range(30):
        model._fit_critic(data, th.zeros_like(returns), returns, th.zeros(*returns.shape, 5))
    assert error() < 0.5 * first


def test_trains_logs_and_round_trips(tmp_path: Any) -> None:
    model = _model().learn(64)
    logged = model.logger.name_to_value
    assert np.isfinite(logged["train/value_explained_variance"]) and np.isfinite(logged["train/advantage_std"])
    model.save(tmp_path / "v.zip")
    loaded = COMA.load(tmp_path / "v.zip", device="cpu")
    assert loaded.advantage == "v_return" and loaded.policy.value_net is not None
    for name, tensor in model.policy.value_net.state_dict().items():
        assert th.equal(tensor, loaded.policy.value_net.state_dict()[name])


class _NoStateValue(MlpPolicy):
    supports_state_value = False


def test_a_policy_without_a_state_value_is_refused_in_one_line() -> None:
    from sb3_coma.uav.policies import UavCOMAPolicy

    assert UavCOMAPolicy.supports_state_value is False  # the UAV critic reads actions drawn in its image
    env = make_marl_vec_env(_spread, n_envs=2, seed=0)
    with pytest.raises(ValueError, match=r"advantage='v_return' needs a policy with a state value.*_NoStateValue"):
        COMA(_NoStateValue, env, advantage="v_return", device="cpu", **FAST)


def test_state_values_without_the_network_say_so() -> None:
    model = _model(advantage="return")
    with pytest.raises(RuntimeError, match="without a state value"):
        model.policy.state_values(None, th.zeros(2, 3, 4))


def test_it_bootstraps_with_the_state_value_wherever_it_bootstraps() -> None:
    """The rollout's last row and the time-limit cuts take ``V_i(s)`` (in units of return), not the
    target critic's expected Q: the returns bootstrap with V as MAPPO's do."""
    model = _model(normalize_q=True)
    model.q_scale.update(np.array([-40.0, -20.0, -35.0]))
    collect_rollout(model)
    joint, states = model._grouped(model._last_obs), model._last_states
    with th.no_grad():
        state = model._joint_state(joint, None if states is None else th.as_tensor(states))
        expected = model._q_units(model.policy.state_values(joint, state))
    got = model._expected_target_values(model._last_obs, model._masks(model._last_obs), states)
    assert th.allclose(got, expected, atol=1e-5)
    np.testing.assert_allclose(model.rollout_buffer.bootstrap, expected.numpy(), rtol=1e-5, atol=1e-4)
