"""``COMA(advantage_before_critic_update=True)``: the counterfactual baseline is scored with the critic
as it was when the rollout was collected, not after this rollout's critic epochs."""

from __future__ import annotations

from typing import Any

import pytest
import torch as th
from pettingzoo import ParallelEnv

from sb3_coma import COMA, make_marl_vec_env

FAST = {"n_steps": 16, "batch_size": 8, "n_epochs": 1, "n_critic_epochs": 3}


def _spread(**kwargs: Any) -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False, **kwargs)


def _scored_q(before: bool, monkeypatch: pytest.MonkeyPatch) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """(Q the advantages read, the critic's Q of the rollout before train(), after train())."""
    model = COMA(
        "MlpPolicy",
        make_marl_vec_env(_spread, n_envs=2, seed=0),
        seed=0,
        device="cpu",
        advantage_before_critic_update=before,
        **FAST,
    )
    model.learn(32)  # one rollout collected and trained; the next one is scored below
    model._setup_learn(32, reset_num_timesteps=False)
    model.collect_rollouts(model.env, model._init_callback(None), model.rollout_buffer, model.n_steps)
    data = model.rollout_buffer.joint_steps()
    everything = th.arange(data["actions"].shape[0])
    with th.no_grad():
        q_before = model._q(data, everything).clone()
    seen: list[th.Tensor] = []
    real = model._advantages

    def spy(data: dict[str, Any], q_all: th.Tensor, targets: th.Tensor) -> Any:
        seen.append(q_all.clone())
        return real(data, q_all, targets)

    monkeypatch.setattr(model, "_advantages", spy)
    model.train()
    with th.no_grad():
        q_after = model._q(data, everything)
    return seen[0], q_before, q_after


def test_the_baseline_reads_the_critic_of_collection_time(monkeypatch: pytest.MonkeyPatch) -> None:
    scored, before, after = _scored_q(True, monkeypatch)
    assert th.allclose(scored, before, atol=1e-6)
    assert not th.allclose(scored, after, atol=1e-3)  # the critic did move in between


def test_by_default_it_reads_the_critic_of_the_last_epoch(monkeypatch: pytest.MonkeyPatch) -> None:
    scored, before, _after = _scored_q(False, monkeypatch)
    assert not th.allclose(scored, before, atol=1e-3)  # three critic epochs moved it


def test_the_option_is_a_flag() -> None:
    env = make_marl_vec_env(_spread, n_envs=2, seed=0)
    with pytest.raises(ValueError, match="advantage_before_critic_update must be True or False"):
        COMA("MlpPolicy", env, advantage_before_critic_update="yes", device="cpu")
