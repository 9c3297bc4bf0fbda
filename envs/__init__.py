"""The world side of sb3-coma: the multi-UAV IPP PettingZoo environment and its vectorisation.

Public entry points (DESIGN section 7):

* :func:`make_env` -> PettingZoo ``ParallelEnv`` with raw observations;
* :func:`make_vec_env` -> SB3 ``VecEnv`` (SuperSuit + fusion wrapper + adapter + VecMonitor);
* gymnasium ids ``UavIpp-Env1-v0`` .. ``UavIpp-Env3-v0`` (vector entry points).
"""
from __future__ import annotations

from typing import Any

from .config import NOISE_PRESETS, WORLD_VERSION, ConfigError, IppConfig
from .ipp_env import UavIppEnv
from .maps import GroundTruth, MapError, available_maps, load_ground_truth
from .registration import ENV_IDS, map_name_of, register_envs
from .vec_env import IppVecEnv, make_vec_env as _make_vec_env


def make_env(name: str = "env3", **options: Any) -> UavIppEnv:
    """A PettingZoo ``ParallelEnv`` for the named map (``env1``/``env2``/``env3``, a gymnasium id,
    or any name with ``map_path=`` and ``valuable=``); options as in :class:`IppConfig`."""
    return UavIppEnv(IppConfig.from_options(map_name_of(name), **options))


def make_vec_env(name: str = "env3", n_envs: int = 1, fusion: str = "mean", seed: int | None = None,
                 **options: Any):
    """SB3 ``VecEnv`` of ``n_envs`` copies; agent ``a`` of copy ``e`` at index ``e * n_agents + a``."""
    return _make_vec_env(map_name_of(name), n_envs=n_envs, fusion=fusion, seed=seed, **options)


register_envs()

__all__ = [
    "ConfigError", "ENV_IDS", "WORLD_VERSION", "GroundTruth", "IppConfig", "IppVecEnv", "MapError", "NOISE_PRESETS",
    "UavIppEnv", "available_maps", "load_ground_truth", "make_env", "make_vec_env",
]
