"""Action masking for the shared actor: masked logits, behaviour probabilities, sampling.

Invalid actions get a large negative logit rather than ``-inf``: ``softmax`` then gives them a
probability of exactly 0 (``exp(-1e8)`` underflows to 0 in float32), so they are never sampled
nor chosen by ``argmax``, while ``log_softmax``, entropies and gradients stay finite (``-inf``
would turn ``0 * -inf`` into NaN in the entropy term).
"""

from __future__ import annotations

import torch as th

#: Logit given to invalid actions.
MASKED_LOGIT = -1.0e8


def valid_mask(mask: th.Tensor) -> th.Tensor:
    """Boolean validity from the env's float mask (1.0 valid, 0.0 invalid).

    A row with no valid action (which the env promises never happens) is treated as all-valid,
    so that a malformed mask degrades to the unmasked policy instead of producing NaNs.
    """
    valid = mask > 0.5
    none_valid = ~valid.any(dim=-1, keepdim=True)
    return valid | none_valid


def mask_logits(logits: th.Tensor, mask: th.Tensor) -> th.Tensor:
    """Replace the logits of invalid actions by :data:`MASKED_LOGIT`."""
    return th.where(valid_mask(mask), logits, th.full_like(logits, MASKED_LOGIT))


def behaviour_probs(masked_logits: th.Tensor, mask: th.Tensor, epsilon: float = 0.0) -> th.Tensor:
    """``(1 - eps) * pi + eps * uniform(valid actions)``: the distribution actions are drawn from.

    With ``epsilon == 0`` this is the policy itself (renormalised over valid actions).
    """
    probs = th.softmax(masked_logits, dim=-1)
    if epsilon > 0.0:
        valid = valid_mask(mask).to(probs.dtype)
        uniform = valid / valid.sum(dim=-1, keepdim=True)
        probs = (1.0 - epsilon) * probs + epsilon * uniform
    return probs


def sample_actions(probs: th.Tensor, deterministic: bool = False) -> th.Tensor:
    """One action per row: ``argmax`` when deterministic, else a draw from ``probs``.

    ``torch.multinomial`` never draws a zero-probability category, so masked actions cannot
    come out; the draw uses torch's global generator, which ``set_random_seed`` seeds.
    """
    if deterministic:
        return probs.argmax(dim=-1)
    return th.multinomial(probs, 1).squeeze(-1)
