"""The multi-agent VecEnv contract as the algorithms read it (COMA, MAPPO's value function, the
mission callbacks): observation keys, agents per copy, state sources, joint tensors.

An observation is a tensor or a dict of tensors (SB3's ``PyTorchObs``). Rows are agents; COMA
regroups them into joint steps ``(B, N, ...)`` and back. Two keys of a ``Dict`` observation have a
meaning of their own: ``state`` (the global state, the critic's privileged input, never the actor's)
and ``action_mask`` (valid actions, applied to the logits, not an input either).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.preprocessing import get_flattened_obs_dim, preprocess_obs
from stable_baselines3.common.type_aliases import PyTorchObs
from stable_baselines3.common.vec_env import VecEnv

from sb3_coma.common.numbers import is_whole

#: Observation key of the global state an env provides to every agent (the critic's input).
KEY_STATE = "state"
#: Observation key of the valid-action mask (sb3-contrib's other convention is ``action_masks()``).
KEY_MASK = "action_mask"
#: Where the global state of a joint step comes from, in order of preference: a ``state`` key of
#: the observation, the env's ``get_state()`` (PettingZoo's ``state()``), or the concatenation of
#: all agents' observations of the joint step (EPyMARL's and BenchMARL's default).
STATE_SOURCES = ("obs", "env", "concat")
_PRIVILEGED = (KEY_STATE, KEY_MASK)


def map_obs(fn: Callable[[Any], Any], obs: Any) -> Any:
    """``fn`` applied to a tensor / array, or to every value of a dict of them."""
    if isinstance(obs, dict):
        return {key: fn(value) for key, value in obs.items()}
    return fn(obs)


def actor_observation_space(observation_space: spaces.Space) -> spaces.Space:
    """What the actor reads: the observation without its ``state`` and ``action_mask`` keys.

    A ``Dict`` left with a single key (PettingZoo's ``{"observation", "action_mask"}`` convention)
    becomes that key's space, so ``MlpPolicy`` and ``CnnPolicy`` fit such envs.
    """
    if not isinstance(observation_space, spaces.Dict):
        return observation_space
    kept = {key: space for key, space in observation_space.spaces.items() if key not in _PRIVILEGED}
    if not kept:
        raise ValueError(
            f"the observation has only {list(observation_space.spaces)}: nothing is left for the actor to read"
        )
    if len(kept) == 1:
        return next(iter(kept.values()))
    return spaces.Dict(kept)


def actor_view(obs: PyTorchObs, observation_space: spaces.Space) -> PyTorchObs:
    """The part of ``obs`` that :func:`actor_observation_space` describes."""
    if not isinstance(observation_space, spaces.Dict):
        return obs
    assert isinstance(obs, dict)
    kept = [key for key in observation_space.spaces if key not in _PRIVILEGED]
    if len(kept) == 1:
        return obs[kept[0]]
    return {key: obs[key] for key in kept}


def _flat_dim(space: spaces.Space) -> int:
    if isinstance(space, spaces.Dict):
        return sum(_flat_dim(sub) for sub in space.spaces.values())
    return int(get_flattened_obs_dim(space))


def concat_state_space(observation_space: spaces.Space, n_agents: int) -> spaces.Box:
    """The space of :func:`concat_state`: every agent's actor observation, flattened, side by side."""
    dim = n_agents * _flat_dim(actor_observation_space(observation_space))
    return spaces.Box(-np.inf, np.inf, (dim,), dtype=np.float32)


def _flatten(x: th.Tensor, space: spaces.Space, normalize_images: bool) -> th.Tensor:
    """``(B, N, ...)`` -> ``(B, N * D)``, each agent's part preprocessed as SB3 does for its actor."""
    batch, n_agents = x.shape[:2]
    rows = preprocess_obs(x.flatten(0, 1), space, normalize_images)
    assert isinstance(rows, th.Tensor)
    return rows.float().reshape(batch, n_agents, -1).flatten(1)


def concat_state(obs: PyTorchObs, observation_space: spaces.Space, normalize_images: bool = True) -> th.Tensor:
    """The state of a joint step from its agents' observations, ``(B, N * D)``.

    :param obs: joint observations ``(B, N, ...)`` (a tensor or a dict of them)
    """
    space = actor_observation_space(observation_space)
    view = actor_view(obs, observation_space)
    if isinstance(space, spaces.Dict):
        assert isinstance(view, dict)
        return th.cat([_flatten(view[key], sub, normalize_images) for key, sub in space.spaces.items()], dim=1)
    assert isinstance(view, th.Tensor)
    return _flatten(view, space, normalize_images)


def state_space_of(
    source: str, observation_space: spaces.Space, n_agents: int, env_state_space: spaces.Space | None = None
) -> spaces.Space:
    """The global state's space for a state source (``env_state_space``: the env's, for ``"env"``)."""
    if source == "obs":
        assert isinstance(observation_space, spaces.Dict)
        return observation_space[KEY_STATE]
    if source == "env":
        assert env_state_space is not None
        return env_state_space
    return concat_state_space(observation_space, n_agents)


def resolve_n_agents(env: VecEnv) -> int:
    """Agents per env copy, read from the vec env (wrappers forward the attribute).

    :raises TypeError: ``env`` is not an SB3 ``VecEnv``
    :raises ValueError: no usable ``n_agents``, or ``num_envs`` not a multiple of it
    """
    if not isinstance(env, VecEnv):
        raise TypeError(
            "COMA needs an SB3 VecEnv whose rows are agents (sb3_coma.make_marl_vec_env(parallel_env)), "
            f"got {type(env).__name__}"
        )
    n_agents: Any = getattr(env, "n_agents", None)
    if n_agents is None:
        try:
            values = env.get_attr("n_agents")
            n_agents = values[0] if values else None
        except Exception:  # any failure means "the env does not say"
            n_agents = None
    if not is_whole(n_agents) or n_agents < 1:
        raise ValueError(
            f"the vec env does not expose `n_agents` (agents per env copy) as a positive int (got {n_agents!r}); "
            "COMA cannot regroup its rows into joint steps. Build it with sb3_coma.make_marl_vec_env(parallel_env) "
            "or set `n_agents` on it."
        )
    if env.num_envs % n_agents != 0:
        raise ValueError(
            f"num_envs={env.num_envs} is not a multiple of n_agents={n_agents}: the vec env must hold "
            "whole env copies (agent a of copy e at index e * n_agents + a)"
        )
    return int(n_agents)


def resolve_state_source(env: VecEnv, n_agents: int) -> tuple[str, spaces.Space]:
    """Where the global state of a joint step comes from: the env's ``state_source`` attribute
    (``sb3_coma.make_marl_vec_env`` sets it), else a ``state`` observation key, else the env's
    ``get_state()`` with its ``state_space``, else the concatenation of the agents' observations.

    :return: the source and the state's space
    :raises ValueError: an unknown source, or ``"env"`` without ``state_space``
    """
    source = getattr(env, "state_source", None)
    state_space = getattr(env, "state_space", None)
    if source is None:
        has_key = isinstance(env.observation_space, spaces.Dict) and KEY_STATE in env.observation_space.spaces
        source = "obs" if has_key else "env" if state_space is not None and hasattr(env, "get_state") else "concat"
    # One rule: a known source whose input the env provides.
    provided = {
        "obs": isinstance(env.observation_space, spaces.Dict) and KEY_STATE in env.observation_space.spaces,
        "env": isinstance(state_space, spaces.Box),
        "concat": True,
    }
    if not provided.get(source, False):
        raise ValueError(
            f"the vec env's state_source {source!r} must be one of {STATE_SOURCES} with its input: 'obs' a "
            f"{KEY_STATE!r} key in the observation (got {env.observation_space}), 'env' a Box state_space "
            f"(got {state_space!r})"
        )
    return source, state_space_of(source, env.observation_space, n_agents, state_space)


#: The most joint steps one ``learn()`` may be asked for: 10^10 is weeks of the fastest collection
#: measured here; a larger number is a typo (``1e100``), and floats lose whole steps past 2^53.
