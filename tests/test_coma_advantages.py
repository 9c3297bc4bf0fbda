"""COMA's advantage options: ``advantage_before_critic_update=True`` scores the counterfactual
baseline with the critic as it was when the rollout was collected, not after this rollout's critic
epochs; ``advantage="gae"`` is GAE(lambda) with that baseline as the value."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch as th
from coma_fakes import collect_rollout
from pettingzoo import ParallelEnv

from sb3_coma import COMA, make_marl_vec_env

FAST = {"n_steps": 16, "batch_size": 8, "n_epochs": 1, "n_critic_epochs": 3}


def _spread(**kwargs: Any) -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False, **kwargs)


def _fast_coma(**kwargs: Any) -> COMA:
    """COMA with the fast settings on two copies of simple_spread, seed 0."""
    return COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=2, seed=0), seed=0, device="cpu", **FAST, **kwargs)


def _scored_q(
    before: bool, monkeypatch: pytest.MonkeyPatch, normalize_q: bool = False
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """(Q the advantages read, the critic's Q of the rollout before train(), after train()), all in
    units of return (``normalize_q``: each with the running statistics of its own time)."""
    model = _fast_coma(advantage_before_critic_update=before, normalize_q=normalize_q)
    model.learn(32)  # one rollout collected and trained; the next one is scored below
    collect_rollout(model, 32, reset_num_timesteps=False)
    data = model.rollout_buffer.joint_steps()
    everything = th.arange(data["actions"].shape[0])
    with th.no_grad():
        q_before = model._q_units(model._q(data, everything)).clone()
    seen: list[th.Tensor] = []
    real = model._advantages

    def spy(data: dict[str, Any], q_all: th.Tensor, targets: th.Tensor) -> Any:
        seen.append(q_all.clone())
        return real(data, q_all, targets)

    monkeypatch.setattr(model, "_advantages", spy)
    model.train()
    with th.no_grad():
        q_after = model._q_units(model._q(data, everything))
    return seen[0], q_before, q_after


def test_the_baseline_reads_the_critic_of_collection_time(monkeypatch: pytest.MonkeyPatch) -> None:
    scored, before, after = _scored_q(True, monkeypatch)
    assert th.allclose(scored, before, atol=1e-6)
    assert not th.allclose(scored, after, atol=1e-3)  # the critic did move in between


def test_a_standardised_critic_is_read_in_the_units_it_was_trained_in(monkeypatch: pytest.MonkeyPatch) -> None:
    """With ``normalize_q`` the critic of collection time learnt Q in units of the statistics before
    this rollout's targets moved them: its baseline is scored with those, not the updated ones."""
    scored, before, _after = _scored_q(True, monkeypatch, normalize_q=True)
    assert th.allclose(scored, before, atol=1e-5)


def test_by_default_it_reads_the_critic_of_the_last_epoch(monkeypatch: pytest.MonkeyPatch) -> None:
    scored, before, _after = _scored_q(False, monkeypatch)
    assert not th.allclose(scored, before, atol=1e-3)  # three critic epochs moved it


def test_the_option_is_a_flag() -> None:
    env = make_marl_vec_env(_spread, n_envs=2, seed=0)
    with pytest.raises(ValueError, match="advantage_before_critic_update must be True or False"):
        COMA("MlpPolicy", env, advantage_before_critic_update="yes", device="cpu")


def test_gae_over_the_baseline_is_the_textbook_recursion() -> None:
    """``A_t = delta_t + gamma lambda (1 - d_t) A_t+1``, ``delta_t = r_t + gamma (1 - d_t) b_t+1 - b_t``,
    ``b_T`` the rollout's bootstrap: hand-rolled in numpy against the model's tensors."""
    model = COMA(
        "MlpPolicy",
        make_marl_vec_env(_spread, n_envs=2, seed=1),
        seed=1,
        device="cpu",
        advantage="gae",
        td_lambda=0.9,
        gamma=0.95,
        n_steps=30,
        batch_size=20,
    )
    collect_rollout(model, 60)
    data = model.rollout_buffer.time_major()
    T, E, N = data["actions"].shape
    assert data["dones"].sum() > 0  # the rollout holds an episode end (25-step episodes, 30 steps)
    baseline = th.randn(T * E, N, generator=th.Generator().manual_seed(0))
    got = model._gae_over_baseline(baseline).view(T, E, N).numpy()
    r, d = data["rewards"].numpy(), data["dones"].numpy()
    v = np.concatenate([baseline.view(T, E, N).numpy(), data["bootstrap"].numpy()[None]])
    expected, ahead = np.zeros((T, E, N)), np.zeros((E, N))
    for t in range(T - 1, -1, -1):
        delta = r[t] + 0.95 * (1 - d[t]) * v[t + 1] - v[t]
        ahead = delta + 0.95 * 0.9 * (1 - d[t]) * ahead
        expected[t] = ahead
    np.testing.assert_allclose(got, expected, rtol=1e-4, atol=1e-4)


def test_gae_trains() -> None:
    model = _fast_coma(advantage="gae").learn(64)
    assert model.num_timesteps == 64 and np.isfinite(model.logger.name_to_value["train/advantage_std"])


def _baseline_explained_variance(advantage: str, silent_critic: bool) -> float | None:
    # the critic as built, for one rollout
    model = _fast_coma(advantage=advantage, advantage_before_critic_update=True, critic_learning_rate=1e-12)
    if silent_critic:  # Q = 0 everywhere: the baseline is 0 and explains none of the return
        with th.no_grad():
            model.policy.critic.head.weight.zero_()
            model.policy.critic.head.bias.zero_()
    model.learn(32)
    return model.logger.name_to_value.get("train/baseline_explained_variance")


def test_the_baseline_explained_variance_is_what_the_baseline_removes_of_the_returns_variance() -> None:
    """Logged as 1 - Var(X - b) / Var(X), X the advantage's first term: 0 for a baseline of zeros,
    something else for the critic as built; not logged for GAE, whose first term is no single return."""
    assert _baseline_explained_variance("return", silent_critic=True) == pytest.approx(0.0, abs=1e-6)
    built = _baseline_explained_variance("return", silent_critic=False)
    assert built is not None and abs(built) > 1e-3
    assert _baseline_explained_variance("q", silent_critic=False) is not None
    assert _baseline_explained_variance("gae", silent_critic=False) is None
