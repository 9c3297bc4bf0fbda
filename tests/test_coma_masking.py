"""Invalid actions are never sampled nor chosen, with or without epsilon exploration."""

from __future__ import annotations

import torch as th

from sb3_coma.common.masking import MASKED_LOGIT, behaviour_probs, mask_logits, sample_actions


def random_masks(n: int, seed: int = 0) -> th.Tensor:
    g = th.Generator().manual_seed(seed)
    mask = (th.rand(n, 6, generator=g) < 0.4).float()
    mask[th.arange(n), th.randint(0, 6, (n,), generator=g)] = 1.0  # at least one valid
    return mask


def test_sampling_never_picks_invalid_actions() -> None:
    th.manual_seed(0)
    mask = random_masks(2000)
    logits = th.randn(2000, 6) * 5
    logits[mask == 0] += 50.0  # the network would love the invalid actions
    masked = mask_logits(logits, mask)
    for eps in (0.0, 0.3, 1.0):
        probs = behaviour_probs(masked, mask, eps)
        assert th.allclose(probs.sum(-1), th.ones(2000))
        assert (probs[mask == 0] == 0).all()
        for _ in range(20):
            actions = sample_actions(probs)
            assert (mask.gather(1, actions[:, None]) == 1).all()
    chosen = sample_actions(masked, deterministic=True)
    assert (mask.gather(1, chosen[:, None]) == 1).all()


def test_epsilon_one_is_uniform_over_valid() -> None:
    mask = th.tensor([[1.0, 0.0, 1.0, 0.0, 0.0, 1.0]])
    probs = behaviour_probs(mask_logits(th.tensor([[9.0, 0, 0, 0, 0, 0]]), mask), mask, 1.0)
    assert th.allclose(probs, mask / 3)


def test_masked_logits_keep_log_probs_finite() -> None:
    mask = th.tensor([[1.0, 1.0, 0.0, 0.0, 0.0, 0.0]])
    masked = mask_logits(th.zeros(1, 6, requires_grad=True), mask)
    log_probs = th.log_softmax(masked, -1)
    entropy = -(log_probs.exp() * log_probs).sum()
    entropy.backward()
    assert th.isfinite(entropy) and abs(entropy.item() - th.log(th.tensor(2.0)).item()) < 1e-6
    assert masked[0, 2].item() == MASKED_LOGIT


def test_row_without_valid_action_falls_back_to_all_valid() -> None:
    probs = behaviour_probs(mask_logits(th.zeros(1, 6), th.zeros(1, 6)), th.zeros(1, 6), 0.5)
    assert th.allclose(probs, th.full((1, 6), 1 / 6))
