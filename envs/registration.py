"""gymnasium ids ``UavIpp-Env{1,2,3}-v0``.

The environment is multi-agent, so ``gymnasium.make`` (single-agent) cannot return it: the ids
carry a *vector* entry point, so ``gymnasium.make_vec("UavIpp-Env3-v0", num_envs=4)`` returns the
fused gymnasium vector env (index = copy * n_agents + agent), and ``gymnasium.make`` explains
where to go instead. :data:`ENV_IDS` maps ids to map names for tools such as the rl-zoo entry point.
"""

from __future__ import annotations

from typing import Any

import gymnasium

ENV_IDS: dict[str, str] = {
    "UavIpp-Env1-v0": "env1",
    "UavIpp-Env2-v0": "env2",
    "UavIpp-Env3-v0": "env3",
}


def map_name_of(env_id_or_name: str) -> str:
    """``"UavIpp-Env3-v0"`` -> ``"env3"``; map names pass through unchanged."""
    return ENV_IDS.get(env_id_or_name, env_id_or_name)


def single_agent_entry_point(**kwargs: Any):
    raise TypeError(
        "UavIpp environments are multi-agent: use gymnasium.make_vec(id, num_envs=...), "
        "uav_ipp.make_env(name) (PettingZoo ParallelEnv) or uav_ipp.make_vec_env(name) (SB3 VecEnv)"
    )


def vector_entry_point(name: str, num_envs: int = 1, fusion: str | None = None, **options: Any):
    """gymnasium ``make_vec`` entry: the fused gymnasium vector env of ``num_envs`` copies
    (``fusion=None``: the world's default fusion). Imports the world when first called, so that
    registering the ids on ``import uav_ipp`` costs nothing."""
    from .config import IppConfig
    from .fusion import DEFAULT_FUSION
    from .vec_env import IppVecEnv, make_vec_env

    fusion_kwargs = options.pop("fusion_kwargs", None)
    config = IppConfig.from_options(name, **options)
    sb3_env = make_vec_env(
        config, num_envs, DEFAULT_FUSION if fusion is None else fusion, monitor=False, fusion_kwargs=fusion_kwargs
    )
    assert isinstance(sb3_env, IppVecEnv)
    return sb3_env.venv


def register_envs() -> None:
    for env_id, name in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="uav_ipp.registration:single_agent_entry_point",
                vector_entry_point="uav_ipp.registration:vector_entry_point",
                kwargs={"name": name},
            )
