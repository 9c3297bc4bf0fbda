"""COMA's learning targets: TD(lambda) returns for the critic, counterfactual advantages for the actor.

Both are standalone functions on tensors so they can be tested on hand-made numbers.
"""

from __future__ import annotations

import torch as th


def td_lambda_targets(
    rewards: th.Tensor,
    dones: th.Tensor,
    next_values: th.Tensor,
    gamma: float,
    td_lambda: float,
) -> th.Tensor:
    """TD(lambda) returns over a rollout, cut at episode ends, bootstrapped at its end.

    With time on the first axis (any trailing shape, e.g. ``(T, E, N)``)::

        G[T-1] = r[T-1] + gamma * (1 - d[T-1]) * v[T-1]
        G[t]   = r[t]   + gamma * (1 - d[t])   * ((1 - lambda) * v[t] + lambda * G[t+1])

    :param rewards: ``r[t]``, the reward received after step ``t``
    :param dones: ``d[t]`` = 1 where the episode ended with step ``t`` (nothing after it is
        counted; the next row already belongs to a new episode)
    :param next_values: ``v[t]``, the target critic's value of what follows step ``t``: its
        ``Q(s[t+1], u[t+1])`` at the joint action taken there, and for the last row the rollout's
        bootstrap value
    :param gamma: discount in [0, 1]
    :param td_lambda: trace decay in [0, 1]; 0 gives one-step targets ``r + gamma * v``,
        1 gives Monte-Carlo returns (bootstrapped by ``v[T-1]`` only if the rollout ends mid-episode)
    :return: ``G`` with the shape of ``rewards``
    """
    if not (rewards.shape == dones.shape == next_values.shape):
        raise ValueError(
            f"rewards, dones and next_values must share one shape, got "
            f"{tuple(rewards.shape)}, {tuple(dones.shape)}, {tuple(next_values.shape)}"
        )
    not_done = 1.0 - dones.to(rewards.dtype)
    targets = th.empty_like(rewards)
    # Beyond the rollout the lambda-return collapses to the bootstrap value itself.
    ahead = next_values[-1]
    for t in range(rewards.shape[0] - 1, -1, -1):
        blend = ahead if t == rewards.shape[0] - 1 else (1.0 - td_lambda) * next_values[t] + td_lambda * ahead
        targets[t] = rewards[t] + gamma * not_done[t] * blend
        ahead = targets[t]
    return targets


def counterfactual_baseline(q_values: th.Tensor, probs: th.Tensor) -> th.Tensor:
    """``b_i = sum_u' pi(u'|o_i) Q(s, (u_-i, u'))``.

    ``probs`` must be the masked policy (zero on invalid actions, renormalised over the valid
    ones), so the sum runs over valid actions only.
    """
    return (probs * q_values).sum(dim=-1)


def counterfactual_advantage(
    q_values: th.Tensor, actions: th.Tensor, probs: th.Tensor
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """COMA's advantage ``A_i = Q(s, u)[u_i] - b_i`` (Foerster et al. 2018, eq. of the paper).

    :param q_values: ``Q(s, u_-i, .)`` for every own action, shape ``(..., A)``
    :param actions: the taken own actions ``u_i``, shape ``(...)``
    :param probs: masked policy probabilities, shape ``(..., A)``
    :return: ``(advantage, baseline, q_taken)``, each of shape ``(...)``
    """
    q_taken = q_values.gather(-1, actions.long().unsqueeze(-1)).squeeze(-1)
    baseline = counterfactual_baseline(q_values, probs)
    return q_taken - baseline, baseline, q_taken
