"""The interface every planner shares with a trained COMA model.

Evaluation code calls ``predict(observation)`` on whatever it evaluates, exactly as it would on
an SB3 algorithm, so baselines and learned policies are run by one loop and face identical
missions. Observations are the vec env's batched dict (index ``copy * n_agents + agent``); the
planners that need more than the observation (AG reads each UAV's own local belief, the
lawnmower reads positions and the map's no-fly columns) query the vec env they were built with
through SB3's public ``env_method``/``get_attr``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np
from stable_baselines3.common.vec_env import VecEnv

from uav_ipp import layout
from uav_ipp.config import is_whole


class Planner(ABC):
    """A non-learned policy over the batched observation of an IPP vec env.

    :param venv: the vec env the planner acts in (``uav_ipp.make_vec_env``); planners that read
        env state need the same env whose observations they receive
    :param seed: seed of the planner's own random stream (tie-breaking, random actions), so a
        run is reproducible bit for bit
    """

    #: Registry name (``make_planner(name, ...)``) and label in tables.
    name: ClassVar[str] = "planner"
    #: Whether ``predict`` reads the env's state (then the batch must be the env's whole batch).
    uses_env_state: ClassVar[bool] = False

    def __init__(self, venv: VecEnv, seed: int | None = None) -> None:
        n_agents = getattr(venv, "n_agents", None)
        if not is_whole(n_agents) or n_agents < 1:
            raise TypeError(
                f"{type(self).__name__} needs an IPP vec env with an n_agents attribute "
                f"(uav_ipp.make_vec_env), got {type(venv).__name__}"
            )
        self.venv = venv
        self.n_agents = int(n_agents)
        self.seed = self._checked_seed(seed)
        self.rng = np.random.default_rng(self.seed)

    def _checked_seed(self, seed: Any) -> int | None:
        """``None`` or an integer >= 0 (a numpy integer as an ``int``); ``ValueError`` naming it."""
        if seed is not None and (not is_whole(seed) or seed < 0):
            raise ValueError(f"{self.name} seed={seed!r}: must be None or an integer >= 0")
        return None if seed is None else int(seed)

    def reset(self, seed: int | None = None) -> None:
        """Forget per-episode state; reseed the random stream when ``seed`` is given."""
        if seed is not None:
            self.seed = self._checked_seed(seed)
            self.rng = np.random.default_rng(self.seed)

    def predict(
        self,
        observation: dict[str, np.ndarray],
        state: Any = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """One action per vec-env row, honouring ``action_mask``; SB3's ``predict`` signature.

        ``state`` is ignored (planners keep their own per-episode memory) and ``deterministic``
        has no effect: every planner is a fixed function of the observation, the env state and
        its seeded random stream.
        """
        if not isinstance(observation, dict) or layout.KEY_MASK not in observation:
            raise TypeError(
                f"{type(self).__name__}.predict needs the vec env's observation dict with "
                f"'{layout.KEY_MASK}', got {type(observation).__name__}"
            )
        mask = np.asarray(observation[layout.KEY_MASK]).astype(bool)
        if mask.ndim != 2 or mask.shape[1] != layout.N_ACTIONS or mask.shape[0] % self.n_agents:
            raise ValueError(f"action_mask must be (copies * {self.n_agents}, {layout.N_ACTIONS}), got {mask.shape}")
        if self.uses_env_state and mask.shape[0] != self.venv.num_envs:
            raise ValueError(
                f"{type(self).__name__} reads the env's state: pass the observation of its whole "
                f"vec env ({self.venv.num_envs} rows), got {mask.shape[0]} rows"
            )
        copies = mask.shape[0] // self.n_agents
        mask = mask.reshape(copies, self.n_agents, layout.N_ACTIONS)
        # A row with nothing valid cannot happen with the env's masks; guard so argmax stays defined.
        mask[~mask.any(axis=-1), 0] = True
        starts = self._episode_starts(observation, episode_start, copies)
        actions = self._plan(observation, mask, starts)
        return np.asarray(actions, dtype=np.int64).reshape(-1), None

    def _episode_starts(
        self, observation: dict[str, np.ndarray], episode_start: np.ndarray | None, copies: int
    ) -> np.ndarray:
        """(copies,) bool: which copies are at their first decision.

        The remaining-budget channel is 1 only at the first decision, so this works whether or not
        the caller passes SB3's ``episode_start``.
        """
        budget = np.asarray(observation[layout.KEY_LOCAL])[:, layout.BUDGET, 0, 0]
        starts = budget.reshape(copies, self.n_agents)[:, 0] >= 1.0 - 1e-6
        if episode_start is not None:
            starts |= np.asarray(episode_start, dtype=bool).reshape(copies, self.n_agents).any(axis=1)
        return starts

    @abstractmethod
    def _plan(self, observation: dict[str, np.ndarray], mask: np.ndarray, starts: np.ndarray) -> np.ndarray:
        """(copies, n_agents) actions from the (copies, n_agents, 6) bool mask."""

    # ------------------------------------------------------------------ env access helpers
    def _first_rows(self, copies: int) -> list[int]:
        """Vec-env row of agent 0 of each copy: one ``env_method`` call per copy, not per agent."""
        return [c * self.n_agents for c in range(copies)]

    def _per_copy(self, method: str, copies: int) -> list[Any]:
        return self.venv.env_method(method, indices=self._first_rows(copies))

    def _attr_per_copy(self, attr: str, copies: int) -> list[Any]:
        return self.venv.get_attr(attr, indices=self._first_rows(copies))

    def __repr__(self) -> str:
        return f"{type(self).__name__}(n_agents={self.n_agents}, seed={self.seed})"
