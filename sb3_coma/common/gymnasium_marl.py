"""A PettingZoo ``ParallelEnv`` over a gymnasium env that plays all its agents in one ``step``.

Several multi-agent benchmarks (Level-Based Foraging's ``Foraging-*`` ids, ma-gym and the like)
are gymnasium envs whose observation and action spaces are ``Tuple``s with one entry per agent:
``step`` takes a tuple of actions and returns a tuple of observations, a list of per-agent rewards
(or one team reward) and a single done flag (or one per agent). :class:`GymnasiumMultiAgentToParallel`
presents such an env as a ParallelEnv (agents ``"agent_0"`` .. ``"agent_{n-1}"``) so that
:func:`sb3_coma.common.marl_vec_env.make_marl_vec_env` can vectorise it like any other.

Rewards are passed on as the env gives them: per-agent rewards stay per agent (LBF's
cooperative variants pay each agent its share; a learner that wants a team reward sums them
itself), a single reward goes to every agent. Such envs have no global state, so ``state()``
is not provided (``make_marl_vec_env`` then uses ``state_source="concat"``). The env's one info
dict is given to every agent (as a copy). Make such envs with
``gymnasium.make(id, disable_env_checker=True)``: gymnasium's checker expects one scalar reward and
warns about the list.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv


def _per_agent(value: Any, n_agents: int, what: str) -> list[Any]:
    """``value`` as one entry per agent: a scalar is shared, a sequence must have one per agent."""
    if not isinstance(value, (list, tuple, np.ndarray)) or np.ndim(value) == 0:
        return [value] * n_agents
    values = list(value)
    if len(values) != n_agents:
        raise ValueError(f"the env returned {len(values)} {what} for {n_agents} agents: {value!r}")
    return values


class GymnasiumMultiAgentToParallel(ParallelEnv[str, Any, Any]):
    """PettingZoo ParallelEnv over a gymnasium env with ``Tuple`` observation and action spaces.

    An agent whose own done flag is set leaves ``agents`` as PettingZoo requires; because the
    wrapped env still takes a full tuple of actions, it is sent that agent's last action until the
    episode ends (such envs ignore the actions of agents that are done).
    """

    def __init__(self, env: gymnasium.Env) -> None:
        obs_space, act_space = env.observation_space, env.action_space
        if not (isinstance(obs_space, spaces.Tuple) and isinstance(act_space, spaces.Tuple)) or (
            len(obs_space.spaces) != len(act_space.spaces) or not obs_space.spaces
        ):
            raise TypeError(
                "GymnasiumMultiAgentToParallel needs Tuple observation and action spaces with one entry per agent, "
                f"got {obs_space} and {act_space}"
            )
        self.env = env
        self.possible_agents = [f"agent_{i}" for i in range(len(obs_space.spaces))]
        self.agents: list[str] = []
        self.observation_spaces = dict(zip(self.possible_agents, obs_space.spaces))
        self.action_spaces = dict(zip(self.possible_agents, act_space.spaces))
        self.metadata = dict(env.metadata)
        self.render_mode = env.render_mode
        self._last_actions: dict[str, Any] = {}

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[agent]

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
        observations, info = self.env.reset(seed=seed, options=options)
        self.agents = list(self.possible_agents)
        self._last_actions = {}
        obs = _per_agent(observations, len(self.possible_agents), "observations")
        return dict(zip(self.possible_agents, obs)), {agent: dict(info) for agent in self.possible_agents}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[dict[str, Any], dict[str, float], dict[str, bool], dict[str, bool], dict[str, dict[str, Any]]]:
        missing = [agent for agent in self.agents if agent not in actions]
        if missing:
            raise ValueError(f"no action for the live agents {missing}")
        live = list(self.agents)
        self._last_actions.update({agent: actions[agent] for agent in live})
        joint = tuple(self._last_actions[agent] for agent in self.possible_agents)
        observations, rewards, terminated, truncated, info = self.env.step(joint)
        n = len(self.possible_agents)
        obs = _per_agent(observations, n, "observations")
        rew = _per_agent(rewards, n, "rewards")
        term = _per_agent(terminated, n, "terminated flags")
        trunc = _per_agent(truncated, n, "truncated flags")
        index = {agent: i for i, agent in enumerate(self.possible_agents) if agent in live}
        self.agents = [agent for agent in live if not (term[index[agent]] or trunc[index[agent]])]
        return (
            {agent: obs[i] for agent, i in index.items()},
            {agent: float(rew[i]) for agent, i in index.items()},
            {agent: bool(term[i]) for agent, i in index.items()},
            {agent: bool(trunc[i]) for agent, i in index.items()},
            {agent: dict(info) for agent in index},
        )

    def render(self) -> Any:
        return self.env.render()

    def close(self) -> None:
        self.env.close()
