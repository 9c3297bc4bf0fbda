"""Rollout storage in joint steps: ``(T, E, N, ...)`` for T steps, E env copies, N agents.

SB3's ``RolloutBuffer`` flattens the vec-env axis and shuffles single agent transitions, which
would tear one joint step apart; COMA's critic needs every agent of a joint step together (agent
``i``'s input holds the other agents' actions). The vec env puts agent ``a`` of copy ``e`` at
index ``e * N + a``, so a plain reshape of each step's ``(E * N, ...)`` arrays into ``(E, N, ...)``
regroups them, and minibatches are drawn over whole joint steps.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import torch as th
from gymnasium import spaces

from uav_ipp import layout

__all__ = ["JointBatch", "JointRolloutBuffer"]

JointBatch = dict[str, th.Tensor]


class JointRolloutBuffer:
    """Fixed-size on-policy storage of ``n_steps`` joint steps for each of ``n_copies`` env copies.

    :param n_steps: steps per env copy per rollout (``T``)
    :param n_copies: env copies (``E``)
    :param n_agents: agents per copy (``N``)
    :param observation_space: the per-agent ``Dict`` space (``local``, ``state``, ``action_mask``)
    :param device: where :meth:`tensors` puts the data
    """

    def __init__(
        self,
        n_steps: int,
        n_copies: int,
        n_agents: int,
        observation_space: spaces.Dict,
        device: th.device | str = "cpu",
    ) -> None:
        self.n_steps = n_steps
        self.n_copies = n_copies
        self.n_agents = n_agents
        self.device = th.device(device)
        lead = (n_steps, n_copies, n_agents)

        def shape(key: str) -> tuple[int, ...]:
            return tuple(observation_space[key].shape or ())

        self.local = np.zeros(lead + shape(layout.KEY_LOCAL), dtype=np.float32)
        self.state = np.zeros(lead + shape(layout.KEY_STATE), dtype=np.float32)
        self.mask = np.zeros(lead + shape(layout.KEY_MASK), dtype=np.float32)
        #: The actor's prior (``action_gain``); zeros when the observation has none.
        prior = shape(layout.KEY_GAIN) if layout.KEY_GAIN in observation_space.spaces else (1, self.mask.shape[-1])
        self.prior = np.zeros(lead + prior, dtype=np.float32)
        self.actions = np.zeros(lead, dtype=np.int64)
        self.rewards = np.zeros(lead, dtype=np.float32)
        #: 1.0 where the episode ended with this step (termination or truncation).
        self.dones = np.zeros(lead, dtype=np.float32)
        #: Target critic's expected value after the last step, per copy and agent: ``(E, N)``.
        self.bootstrap = np.zeros((n_copies, n_agents), dtype=np.float32)
        self.pos = 0

    @property
    def full(self) -> bool:
        return self.pos == self.n_steps

    @property
    def n_joint_steps(self) -> int:
        """Joint steps stored so far (``pos * E``)."""
        return self.pos * self.n_copies

    def reset(self) -> None:
        self.pos = 0

    def _grouped(self, flat: np.ndarray) -> np.ndarray:
        """``(E * N, ...) -> (E, N, ...)`` (a view)."""
        return np.asarray(flat).reshape((self.n_copies, self.n_agents, *np.shape(flat)[1:]))

    def add(
        self,
        obs: dict[str, np.ndarray],
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
    ) -> None:
        """Store one vec-env step; every array has ``E * N`` rows in the vec env's order."""
        if self.full:
            raise RuntimeError("JointRolloutBuffer is full; call reset() before adding more steps")
        t = self.pos
        self.local[t] = self._grouped(obs[layout.KEY_LOCAL])
        self.state[t] = self._grouped(obs[layout.KEY_STATE])
        self.mask[t] = self._grouped(obs[layout.KEY_MASK])
        if layout.KEY_GAIN in obs:
            self.prior[t] = self._grouped(obs[layout.KEY_GAIN])
        self.actions[t] = self._grouped(actions)
        self.rewards[t] = self._grouped(rewards)
        self.dones[t] = self._grouped(dones)
        self.pos += 1

    def set_bootstrap(self, values: np.ndarray) -> None:
        """Value of what follows the last stored step, ``(E, N)`` or ``(E * N,)``."""
        self.bootstrap[...] = np.asarray(values, dtype=np.float32).reshape(self.n_copies, self.n_agents)

    def time_major(self) -> JointBatch:
        """The filled part as tensors shaped ``(T, E, N, ...)`` (no copy on CPU)."""
        t = self.pos
        to = lambda a: th.as_tensor(a[:t], device=self.device)  # noqa: E731
        return {
            "local": to(self.local),
            "state": to(self.state),
            "mask": to(self.mask),
            "prior": to(self.prior),
            "actions": to(self.actions),
            "rewards": to(self.rewards),
            "dones": to(self.dones),
            "bootstrap": th.as_tensor(self.bootstrap, device=self.device),
        }

    def joint_steps(self) -> JointBatch:
        """Per-step tensors flattened to joint steps, ``(T * E, N, ...)``; agents stay together."""
        data = self.time_major()
        data.pop("bootstrap")
        return {k: v.flatten(0, 1) for k, v in data.items()}

    @staticmethod
    def minibatch_indices(n_joint_steps: int, batch_size: int, shuffle: bool = True) -> Iterator[th.Tensor]:
        """Indices of whole joint steps, ``batch_size`` at a time (the last batch holds the rest)."""
        order = th.randperm(n_joint_steps) if shuffle else th.arange(n_joint_steps)
        yield from order.split(batch_size)
