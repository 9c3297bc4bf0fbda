"""``policy_kwargs={"dueling_critic": True}``: Q as a value of the others' actions plus centred deviations."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import torch as th
from gymnasium import spaces
from pettingzoo import ParallelEnv
from stable_baselines3.common.torch_layers import FlattenExtractor

from sb3_coma import COMA, make_marl_vec_env
from sb3_coma.coma.policies import CriticNet
from sb3_coma.coma.targets import counterfactual_advantage

FAST = {"n_steps": 16, "batch_size": 16, "n_epochs": 1, "n_critic_epochs": 1}


def _spread(**kwargs: Any) -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False, **kwargs)


def _model(normalize_q: bool | str = False, dueling: bool = True) -> COMA:
    return COMA(
        "MlpPolicy",
        make_marl_vec_env(_spread, n_envs=2, seed=0),
        seed=0,
        device="cpu",
        normalize_q=normalize_q,
        policy_kwargs={"dueling_critic": dueling},
        **FAST,
    )


def _critic(dueling: bool) -> CriticNet:
    th.manual_seed(0)
    state = spaces.Box(-1.0, 1.0, (4,))
    return CriticNet(FlattenExtractor(state), None, 2, [8], th.nn.Tanh, 3, dueling=dueling)


def test_a_dueling_head_is_its_value_plus_the_centred_deviations() -> None:
    critic = _critic(dueling=True)
    state, extra = th.randn(5, 4), th.randn(5, 2)
    q = critic(state, None, extra)
    out = critic.head(critic.mlp(th.cat([critic.state_extractor(state), extra], dim=1)))
    assert critic.head.out_features == 4 and q.shape == (5, 3)
    assert th.allclose(q, out[:, :1] + out[:, 1:] - out[:, 1:].mean(dim=1, keepdim=True))
    # under the uniform policy the counterfactual baseline is the value itself, whatever the deviations
    _advantage, baseline, _taken = counterfactual_advantage(q, th.zeros(5, dtype=th.long), th.full((5, 3), 1 / 3))
    assert th.allclose(baseline, out[:, 0], atol=1e-6)


def test_a_plain_head_has_one_output_per_action() -> None:
    assert _critic(dueling=False).head.out_features == 3


def test_popart_keeps_a_dueling_critics_outputs_where_they_were() -> None:
    """PopArt rescales every output of the head; the centred deviations cancel the shift, so Q in return
    units is unchanged when the statistics move."""
    model = _model("popart")
    model.learn(64)
    data, idx = model.rollout_buffer.joint_steps(), th.arange(6)
    with th.no_grad():
        before = model._q_units(model._q(data, idx))
    model._critic_targets(th.tensor([[-300.0, -310.0, -290.0], [-100.0, -120.0, -110.0]]))
    with th.no_grad():
        after = model._q_units(model._q(data, idx))
    assert th.allclose(before, after, rtol=1e-4, atol=1e-3)


def test_a_dueling_critic_trains_and_is_saved_with_the_model(tmp_path: Path) -> None:
    model = _model()
    model.learn(96)
    assert model.policy.dueling_critic and model.policy.critic_target.dueling
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", device="cpu")
    assert loaded.policy.dueling_critic
    data, idx = model.rollout_buffer.joint_steps(), th.arange(4)
    with th.no_grad():
        assert th.allclose(model._q(data, idx), loaded.policy.q_values(*_critic_inputs(model, data, idx)))


def _critic_inputs(model: COMA, data: dict[str, Any], idx: th.Tensor) -> tuple[Any, th.Tensor, th.Tensor]:
    obs = model._take(data["obs"], idx)
    return obs, model._critic_state(data, obs, idx), data["actions"][idx]


def test_the_default_critic_is_not_dueling() -> None:
    model = _model(dueling=False)
    assert not model.policy.dueling_critic and model.policy.critic.head.out_features == model.policy.n_actions


def test_a_dueling_critic_that_is_not_a_flag_is_refused_by_name() -> None:
    """A config's ``"yes"`` or ``"no"`` would otherwise turn the head on either way."""
    with pytest.raises(ValueError, match=r"dueling_critic='yes': must be true or false"):
        COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=2, seed=0), policy_kwargs={"dueling_critic": "yes"}, **FAST)
    with pytest.raises(ValueError, match=r"critic_obs='no': must be true or false"):  # the same rule, its neighbour
        COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=2, seed=0), policy_kwargs={"critic_obs": "no"}, **FAST)
