"""``COMA(normalize_q=True)``: the critic learns standardised Q, everything else reads Q in return units."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from pettingzoo import ParallelEnv

from sb3_coma import COMA, make_marl_vec_env

FAST = {"n_steps": 16, "batch_size": 16, "n_epochs": 1, "n_critic_epochs": 1}


def _spread(**kwargs: Any) -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False, **kwargs)


def _model(normalize_q: bool | str, seed: int = 0) -> COMA:
    return COMA(
        "MlpPolicy",
        make_marl_vec_env(_spread, n_envs=2, seed=seed),
        seed=seed,
        device="cpu",
        normalize_q=normalize_q,
        **FAST,
    )


def test_the_running_statistics_follow_the_targets() -> None:
    model = _model(True)
    targets = th.tensor([[-30.0, -31.0, -29.0], [-10.0, -12.0, -11.0]])
    fitted = model._critic_targets(targets)
    assert model.q_scale.mean == pytest.approx(float(targets.mean()), rel=1e-3)
    assert float(fitted.mean()) == pytest.approx(0.0, abs=1e-3) and float(fitted.std(unbiased=False)) == pytest.approx(
        1.0, rel=1e-3
    )
    assert th.allclose(model._q_units(fitted), targets, atol=1e-3)  # the critic's units back to returns


def test_without_it_the_critic_outputs_q_itself() -> None:
    model = _model(False)
    targets = th.tensor([[-30.0, -31.0]])
    assert th.equal(model._critic_targets(targets), targets) and th.equal(model._q_units(targets), targets)
    assert model.q_scale.count == pytest.approx(1e-4)  # untouched


def test_training_standardises_the_critic_and_logs_the_scale() -> None:
    model = _model(True)
    model.learn(96)
    assert model.q_scale.count > 1 and model.q_scale.mean < 0  # simple_spread's returns are negative
    values = model.logger.name_to_value
    assert values["train/q_target_std"] == pytest.approx(float(np.sqrt(model.q_scale.var)))
    # Q in return units is what the advantages and the logs read: near the targets' mean, not near 0
    assert abs(values["train/q_mean"] - model.q_scale.mean) < 3 * np.sqrt(model.q_scale.var)


def test_the_scale_is_saved_with_the_model(tmp_path: Path) -> None:
    model = _model(True)
    model.learn(64)
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", device="cpu")
    assert loaded.normalize_q is True
    assert loaded.q_scale.mean == model.q_scale.mean and loaded.q_scale.var == model.q_scale.var
    q = th.zeros(1, 3, 5)
    assert th.equal(loaded._q_units(q), model._q_units(q))


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_only_a_flag_is_a_flag(value: Any) -> None:
    with pytest.raises(ValueError, match=rf"normalize_q must be True, False or 'popart', got {value!r}"):
        COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=1, seed=0), normalize_q=value, **FAST)


def _critic_outputs(model: COMA) -> tuple[th.Tensor, th.Tensor]:
    """Q in return units of the critic and of its target on the last rollout's first joint steps."""
    data, idx = model.rollout_buffer.joint_steps(), th.arange(6)
    with th.no_grad():
        return model._q_units(model._q(data, idx)), model._q_units(model._q(data, idx, target=True))


@pytest.mark.parametrize("normalize_q", [True, "popart"])
def test_popart_keeps_the_critics_outputs_where_they_were_when_the_statistics_move(normalize_q: bool | str) -> None:
    model = _model(normalize_q)
    model.learn(64)
    before = _critic_outputs(model)
    scale = (model.q_scale.mean, model.q_scale.var)
    model._critic_targets(th.tensor([[-300.0, -310.0, -290.0], [-100.0, -120.0, -110.0]]))  # a scale 10x larger
    assert (model.q_scale.mean, model.q_scale.var) != scale
    after = _critic_outputs(model)
    preserved = all(th.allclose(a, b, rtol=1e-4, atol=1e-3) for a, b in zip(before, after))
    assert preserved is (normalize_q == "popart")  # plain running statistics read the same layer at the new scale


def test_popart_trains_and_is_saved_with_the_model(tmp_path: Path) -> None:
    model = _model("popart")
    model.learn(96)
    assert model.normalize_q == "popart" and model.q_scale.count > 1
    assert np.isfinite(model.logger.name_to_value["train/q_mean"])
    model.save(tmp_path / "m.zip")
    assert COMA.load(tmp_path / "m.zip", device="cpu").normalize_q == "popart"


def test_a_critic_without_a_linear_head_is_refused_in_one_line() -> None:
    model = _model("popart")
    model.policy.critic.head = th.nn.Sequential(th.nn.Linear(128, 5))
    with pytest.raises(TypeError, match="MlpPolicy: a critic's head is not one linear layer"):
        model.policy.critic_output_layers()
