"""TD(lambda) targets and COMA's counterfactual advantage on hand-made numbers."""

from __future__ import annotations

import pytest
import torch as th

from sb3_coma.coma.targets import counterfactual_advantage, counterfactual_baseline, td_lambda_targets

GAMMA = 0.9
REWARDS = th.tensor([1.0, 0.0, 2.0, -1.0, 3.0])
VALUES = th.tensor([0.5, 1.5, -2.0, 4.0, 10.0])  # v[t]: target Q after step t; v[4] = bootstrap


def mc_returns(rewards: th.Tensor, dones: th.Tensor, bootstrap: float, gamma: float) -> th.Tensor:
    """Discounted returns by the textbook definition, restarted after every episode end."""
    out, g = [], bootstrap
    for r, d in zip(reversed(rewards.tolist()), reversed(dones.tolist())):
        g = r + gamma * (0.0 if d else g)
        out.append(g)
    return th.tensor(out[::-1])


def test_lambda_zero_is_one_step() -> None:
    dones = th.zeros(5)
    got = td_lambda_targets(REWARDS, dones, VALUES, GAMMA, 0.0)
    assert th.allclose(got, REWARDS + GAMMA * VALUES)


def test_lambda_one_is_monte_carlo() -> None:
    dones = th.zeros(5)
    got = td_lambda_targets(REWARDS, dones, VALUES, GAMMA, 1.0)
    # 1 + .9*0 + .81*2 + .729*(-1) + .6561*3 + .59049*10 for t = 0, and so on.
    assert th.allclose(got, mc_returns(REWARDS, dones, 10.0, GAMMA))
    assert got[0].item() == pytest.approx(1 + 0.81 * 2 - 0.729 + 0.6561 * 3 + 0.59049 * 10)


def test_episode_ends_cut_the_return() -> None:
    dones = th.tensor([0.0, 1.0, 0.0, 0.0, 1.0])
    lam1 = td_lambda_targets(REWARDS, dones, VALUES, GAMMA, 1.0)
    assert th.allclose(lam1, mc_returns(REWARDS, dones, 0.0, GAMMA))
    assert lam1[1].item() == pytest.approx(0.0)  # last step of episode 1: its reward only
    assert lam1[4].item() == pytest.approx(3.0)  # bootstrap ignored after a terminal step
    lam0 = td_lambda_targets(REWARDS, dones, VALUES, GAMMA, 0.0)
    assert th.allclose(lam0, REWARDS + GAMMA * VALUES * (1 - dones))


def test_intermediate_lambda_by_hand() -> None:
    r, v, d = th.tensor([1.0, 2.0]), th.tensor([3.0, 5.0]), th.zeros(2)
    lam, g = 0.8, 0.5
    g1 = 2.0 + g * 5.0
    g0 = 1.0 + g * ((1 - lam) * 3.0 + lam * g1)
    assert th.allclose(td_lambda_targets(r, d, v, g, lam), th.tensor([g0, g1]))


def test_trailing_dims_are_independent() -> None:
    """(T, E, N) input equals running each (e, n) column on its own."""
    th.manual_seed(0)
    r, v = th.randn(7, 3, 2), th.randn(7, 3, 2)
    d = (th.rand(7, 3, 2) < 0.3).float()
    batched = td_lambda_targets(r, d, v, 0.99, 0.8)
    for e in range(3):
        for n in range(2):
            assert th.allclose(batched[:, e, n], td_lambda_targets(r[:, e, n], d[:, e, n], v[:, e, n], 0.99, 0.8))


def test_shape_mismatch_raises() -> None:
    with pytest.raises(ValueError, match="shape"):
        td_lambda_targets(th.zeros(3), th.zeros(4), th.zeros(3), 0.9, 0.8)


def test_baseline_is_policy_weighted_q_over_valid_actions() -> None:
    q = th.tensor([[1.0, 2.0, 3.0, 4.0, 5.0, 1e6]])  # huge Q on an invalid action
    probs = th.tensor([[0.1, 0.2, 0.3, 0.2, 0.2, 0.0]])
    assert counterfactual_baseline(q, probs).item() == pytest.approx(0.1 + 0.4 + 0.9 + 0.8 + 1.0)
    adv, base, q_taken = counterfactual_advantage(q, th.tensor([2]), probs)
    assert q_taken.item() == 3.0
    assert adv.item() == pytest.approx(3.0 - base.item())


def test_advantage_under_deterministic_policy_is_zero_for_its_action() -> None:
    q = th.randn(4, 6)
    probs = th.nn.functional.one_hot(th.tensor([0, 3, 5, 1]), 6).float()
    adv, _, _ = counterfactual_advantage(q, th.tensor([0, 3, 5, 1]), probs)
    assert th.allclose(adv, th.zeros(4))
