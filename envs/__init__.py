"""The world side of sb3-coma: the multi-UAV IPP PettingZoo environment and its vectorisation.

Public entry points (DESIGN section 7):

* :func:`make_env` -> PettingZoo ``ParallelEnv`` with raw observations;
* :func:`make_vec_env` -> SB3 ``VecEnv`` (SuperSuit + fusion wrapper + adapter + VecMonitor);
* gymnasium ids ``UavIpp-Env1-v0`` .. ``UavIpp-Env3-v0`` (vector entry points).
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from .config import NOISE_PRESETS, WORLD_VERSION, ConfigError, IppConfig
from .fusion import DEFAULT_FUSION, available_fusions
from .ipp_env import UavIppEnv
from .maps import GroundTruth, MapError, available_maps, load_ground_truth
from .registration import ENV_IDS, map_name_of, register_envs
from .vec_env import DEFAULT_MAP, IppVecEnv
from .vec_env import make_vec_env as _make_vec_env


def make_env(name: str = DEFAULT_MAP, **options: Any) -> UavIppEnv:
    """A PettingZoo ``ParallelEnv`` for the named map (``env1``/``env2``/``env3``, a gymnasium id,
    or any name with ``map_path=`` and ``valuable=``); options as in :class:`IppConfig`."""
    return UavIppEnv(IppConfig.from_options(map_name_of(name), **options))


def make_vec_env(
    name: str = DEFAULT_MAP, n_envs: int = 1, fusion: str = DEFAULT_FUSION, seed: int | None = None, **options: Any
) -> VecEnv:
    """SB3 ``VecEnv`` of ``n_envs`` copies; agent ``a`` of copy ``e`` at index ``e * n_agents + a``.

    ``fusion``: ``"sendfuse"`` (default), ``"mean"``, ``"none"`` or any name in
    :func:`available_fusions`; ``options``: :class:`IppConfig` options, ``fusion_kwargs``, ``monitor``."""
    return _make_vec_env(map_name_of(name), n_envs=n_envs, fusion=fusion, seed=seed, **options)


register_envs()

__all__ = [
    "DEFAULT_FUSION",
    "DEFAULT_MAP",
    "ENV_IDS",
    "NOISE_PRESETS",
    "WORLD_VERSION",
    "ConfigError",
    "GroundTruth",
    "IppConfig",
    "IppVecEnv",
    "MapError",
    "UavIppEnv",
    "available_fusions",
    "available_maps",
    "load_ground_truth",
    "make_env",
    "make_vec_env",
]
