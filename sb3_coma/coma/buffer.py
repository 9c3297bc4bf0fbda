"""Rollout storage in joint steps: ``(T, E, N, ...)`` for T steps, E env copies, N agents.

SB3's ``RolloutBuffer`` flattens the vec-env axis and shuffles single agent transitions, which
would tear one joint step apart; COMA's critic needs every agent of a joint step together (agent
``i``'s input holds the other agents' actions). The vec env puts agent ``a`` of copy ``e`` at
index ``e * N + a``, so a plain reshape of each step's ``(E * N, ...)`` arrays into ``(E, N, ...)``
regroups them, and minibatches are drawn over whole joint steps.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_coma.common.joint import map_obs

JointBatch = dict[str, Any]


def _storage(space: spaces.Space, lead: tuple[int, ...]) -> np.ndarray:
    """Zeros for ``lead`` + one observation of ``space``, in the space's own dtype (uint8 images
    stay small); a ``Discrete`` observation is stored as its index."""
    if isinstance(space, spaces.Discrete):
        return np.zeros(lead, dtype=np.int64)
    return np.zeros(lead + tuple(space.shape or ()), dtype=space.dtype)


class JointRolloutBuffer:
    """Fixed-size on-policy storage of ``n_steps`` joint steps for each of ``n_copies`` env copies.

    :param n_steps: steps per env copy per rollout (``T``)
    :param n_copies: env copies (``E``)
    :param n_agents: agents per copy (``N``)
    :param observation_space: one agent's observation space (a ``Dict`` is stored key by key)
    :param n_actions: actions per agent (the mask's width)
    :param state_shape: shape of the per-copy global state to store (``None``: the state is read
        from the observations, nothing extra is stored)
    :param time_left: store each copy's time left in its episode (``COMA(critic_time_feature=...)``)
    :param device: where :meth:`time_major` puts the data
    """

    def __init__(
        self,
        n_steps: int,
        n_copies: int,
        n_agents: int,
        observation_space: spaces.Space,
        n_actions: int,
        state_shape: tuple[int, ...] | None = None,
        time_left: bool = False,
        device: th.device | str = "cpu",
    ) -> None:
        self.n_steps = n_steps
        self.n_copies = n_copies
        self.n_agents = n_agents
        self.device = th.device(device)
        lead = (n_steps, n_copies, n_agents)
        self.obs: np.ndarray | dict[str, np.ndarray]
        if isinstance(observation_space, spaces.Dict):
            self.obs = {key: _storage(space, lead) for key, space in observation_space.spaces.items()}
        else:
            self.obs = _storage(observation_space, lead)
        #: The env's global state per copy (state source "env" only).
        self.states = None if state_shape is None else np.zeros((n_steps, n_copies, *state_shape), dtype=np.float32)
        #: The fraction of the time limit left in each copy's episode at each step (the critic's clock).
        self.time_left = np.zeros((n_steps, n_copies), dtype=np.float32) if time_left else None
        #: 1.0 for valid actions; read only once a step came with masks (:attr:`masked`).
        self.mask = np.ones((*lead, n_actions), dtype=np.float32)
        #: Whether the env gives masks: without them every action is valid and the rollout's
        #: ``"mask"`` is ``None``, so that training skips masking (``th.where`` over all-valid rows
        #: would return the logits unchanged, at a cost per minibatch).
        self.masked = False
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
        """Start a new rollout; whether it has masks is its own (a model may be given another env)."""
        self.pos = 0
        self.masked = False

    def _grouped(self, flat: Any) -> np.ndarray:
        """``(E * N, ...) -> (E, N, ...)`` (a view)."""
        return np.asarray(flat).reshape((self.n_copies, self.n_agents, *np.shape(flat)[1:]))

    def add(
        self,
        obs: np.ndarray | dict[str, np.ndarray],
        mask: np.ndarray | None,
        actions: np.ndarray,
        rewards: np.ndarray,
        dones: np.ndarray,
        states: np.ndarray | None = None,
        time_left: np.ndarray | None = None,
    ) -> None:
        """Store one vec-env step; every array has ``E * N`` rows in the vec env's order
        (``states`` and ``time_left``: one row per copy; ``mask``: ``None`` when the env gives none)."""
        if self.full:
            raise RuntimeError("JointRolloutBuffer is full; call reset() before adding more steps")
        t = self.pos
        if isinstance(self.obs, dict):
            assert isinstance(obs, dict)
            for key, store in self.obs.items():
                store[t] = self._grouped(obs[key])
        else:
            self.obs[t] = self._grouped(obs)
        if self.states is not None:
            assert states is not None
            self.states[t] = np.asarray(states, dtype=np.float32).reshape(self.states.shape[1:])
        if self.time_left is not None:
            assert time_left is not None
            self.time_left[t] = time_left
        if mask is not None:
            self.mask[t] = self._grouped(mask)
            self.masked = True
        self.actions[t] = self._grouped(actions)
        self.rewards[t] = self._grouped(rewards)
        self.dones[t] = self._grouped(dones)
        self.pos += 1

    def set_bootstrap(self, values: np.ndarray) -> None:
        """Value of what follows the last stored step, ``(E, N)`` or ``(E * N,)``."""
        self.bootstrap[...] = np.asarray(values, dtype=np.float32).reshape(self.n_copies, self.n_agents)

    def time_major(self) -> JointBatch:
        """The filled part as tensors shaped ``(T, E, N, ...)`` (``states``: ``(T, E, ...)``,
        ``time_left``: ``(T, E)``; no copy on CPU)."""
        t = self.pos
        to = lambda a: th.as_tensor(a[:t], device=self.device)  # noqa: E731
        return {
            "obs": map_obs(to, self.obs),
            "states": None if self.states is None else to(self.states),
            "time_left": None if self.time_left is None else to(self.time_left),
            "mask": to(self.mask) if self.masked else None,
            "actions": to(self.actions),
            "rewards": to(self.rewards),
            "dones": to(self.dones),
            "bootstrap": th.as_tensor(self.bootstrap, device=self.device),
        }

    def joint_steps(self) -> JointBatch:
        """Per-step tensors flattened to joint steps, ``(T * E, N, ...)``; agents stay together."""
        data = self.time_major()
        data.pop("bootstrap")
        flat = lambda v: v.flatten(0, 1)  # noqa: E731
        return {key: None if value is None else map_obs(flat, value) for key, value in data.items()}

    @staticmethod
    def minibatch_indices(n_joint_steps: int, batch_size: int, shuffle: bool = True) -> Iterator[th.Tensor]:
        """Indices of whole joint steps, ``batch_size`` at a time (the last batch holds the rest)."""
        order = th.randperm(n_joint_steps) if shuffle else th.arange(n_joint_steps)
        yield from order.split(batch_size)
