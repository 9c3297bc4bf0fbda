"""MAPPO for any multi-agent VecEnv: SB3's ``PPO`` whose value function reads the global state.

IPPO needs nothing of ours: SB3's ``PPO("MlpPolicy", make_marl_vec_env(env))`` shares one set of
weights across the agent rows. MAPPO (Yu et al. 2022) differs only in its value function, which
reads the global state and the agent's id instead of the agent's observation. Two small parts do
that on SB3's own ``PPO``:

* :class:`CentralStateVecEnv` adds ``state`` (from the same source COMA reads: a ``state`` key,
  the env's ``get_state()`` or the concatenation of the agents' observations) and ``agent_id``
  (one-hot) to every row's observation, as a ``Dict``;
* :class:`CentralValuePolicy` keeps the actor on the agent's own keys and gives the value function
  its own extractor over ``state`` + ``agent_id`` (SB3's ``share_features_extractor=False``).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.preprocessing import get_flattened_obs_dim
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.type_aliases import Schedule
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from torch import nn

from sb3_coma.common.joint import KEY_MASK, KEY_STATE, concat_state, map_obs, resolve_n_agents, resolve_state_source

#: Observation key of the agent's one-hot id that :class:`CentralStateVecEnv` adds.
KEY_AGENT_ID = "agent_id"
#: Key of a non-``Dict`` observation once it sits in a ``Dict``.
KEY_OBS = "obs"


class CentralStateVecEnv(VecEnvWrapper):
    """Every row's observation as a ``Dict``: the agent's own keys (``obs`` for a ``Box``), the
    global ``state`` of its joint step and its one-hot ``agent_id``."""

    def __init__(self, venv: VecEnv) -> None:
        self.n_agents = resolve_n_agents(venv)
        self.state_source, state_space = resolve_state_source(venv, self.n_agents)
        space = venv.observation_space
        own = dict(space.spaces) if isinstance(space, spaces.Dict) else {KEY_OBS: space}
        own.pop(KEY_MASK, None)
        own.pop(KEY_STATE, None)
        self._source_space = space
        parts = {**own, KEY_STATE: state_space, KEY_AGENT_ID: spaces.Box(0.0, 1.0, (self.n_agents,), np.float32)}
        super().__init__(venv, observation_space=spaces.Dict(parts))
        self._ids = np.tile(np.eye(self.n_agents, dtype=np.float32), (venv.num_envs // self.n_agents, 1))

    def _with_state(self, obs: Any, env_states: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """Rows of whole copies (``obs``) with their state; ``env_states``: the env's, one per copy."""
        own = dict(obs) if isinstance(obs, dict) else {KEY_OBS: obs}
        own.pop(KEY_MASK, None)
        n = self.n_agents
        if self.state_source == "obs":
            state = own.pop(KEY_STATE)
        elif self.state_source == "env":
            assert env_states is not None
            state = np.repeat(np.asarray(env_states, dtype=np.float32), n, axis=0)
        else:
            joint = map_obs(lambda x: th.as_tensor(np.asarray(x)).view(-1, n, *np.shape(x)[1:]), obs)
            state = np.repeat(concat_state(joint, self._source_space).numpy(), n, axis=0)
        rows = len(state)
        return {**own, KEY_STATE: state, KEY_AGENT_ID: self._ids[:rows]}

    def _current_states(self) -> np.ndarray | None:
        return self.venv.get_state() if self.state_source == "env" else None  # type: ignore[attr-defined]

    def reset(self) -> dict[str, np.ndarray]:  # type: ignore[override]
        obs = self.venv.reset()
        return self._with_state(obs, self._current_states())

    def _terminal(self, infos: list[dict[str, Any]], copy: int) -> None:
        """Give the rows of a finished copy their terminal observation as a ``Dict`` too, so that
        PPO's value function can bootstrap a time-limit end from the terminal state."""
        n = self.n_agents
        rows = range(copy * n, copy * n + n)
        first = infos[rows[0]]["terminal_observation"]
        if isinstance(first, dict):
            stacked: Any = {key: np.stack([infos[r]["terminal_observation"][key] for r in rows]) for key in first}
        else:
            stacked = np.stack([infos[r]["terminal_observation"] for r in rows])
        env_state = infos[rows[0]].get("terminal_state") if self.state_source == "env" else None
        converted = self._with_state(stacked, None if env_state is None else np.asarray(env_state)[None])
        for i, row in enumerate(rows):
            infos[row]["terminal_observation"] = {key: value[i] for key, value in converted.items()}

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        n = self.n_agents
        for copy in sorted({row // n for row, info in enumerate(infos) if "terminal_observation" in info}):
            self._terminal(infos, copy)
        return self._with_state(obs, self._current_states()), rewards, dones, infos


class KeysExtractor(BaseFeaturesExtractor):
    """The named keys of a ``Dict`` observation, flattened side by side, then one layer to
    ``features_dim`` (so actor and value function hand SB3's ``MlpExtractor`` equal widths)."""

    def __init__(self, observation_space: spaces.Dict, keys: Sequence[str], features_dim: int = 64) -> None:
        super().__init__(observation_space, features_dim)
        self.keys = tuple(keys)
        width = sum(int(get_flattened_obs_dim(observation_space[key])) for key in self.keys)
        self.linear = nn.Sequential(nn.Linear(width, features_dim), nn.Tanh())

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:  # type: ignore[override]
        return self.linear(th.cat([observations[key].float().flatten(1) for key in self.keys], dim=1))


class CentralValuePolicy(ActorCriticPolicy):
    """PPO's actor on the agent's own keys, its value function on ``state`` + ``agent_id``."""

    def __init__(
        self, observation_space: spaces.Dict, action_space: spaces.Space, lr_schedule: Schedule, **kwargs: Any
    ) -> None:
        own = [key for key in observation_space.spaces if key not in (KEY_STATE, KEY_AGENT_ID)]
        kwargs.update(
            share_features_extractor=False,
            features_extractor_class=KeysExtractor,
            features_extractor_kwargs={"keys": own, **kwargs.get("features_extractor_kwargs", {})},
        )
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)
        dim = self.features_dim
        self.vf_features_extractor = KeysExtractor(observation_space, (KEY_STATE, KEY_AGENT_ID), dim)
        if self.ortho_init:
            self.vf_features_extractor.apply(partial(self.init_weights, gain=np.sqrt(2)))
        # The optimizer was built over the replaced extractor's parameters: build it again.
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]
