"""The world side of sb3-coma, installed as ``uav_ipp``: the multi-UAV IPP PettingZoo environment
and its vectorisation.

Public entry points (docs/design.md, "Public names"):

* :func:`make_env` -> PettingZoo ``ParallelEnv`` with raw observations;
* :func:`make_vec_env` -> SB3 ``VecEnv`` (SuperSuit + fusion wrapper + adapter + VecMonitor), its
  copies in this process or, with ``workers=`` / ``backend=``, in worker processes or Ray actors;
* gymnasium ids ``UavIpp-Env1-v0`` .. ``UavIpp-Env3-v0`` (vector entry points), registered on import.

Importing the package is cheap (the ids and :mod:`uav_ipp.layout` only): the numba kernels, maps,
SuperSuit and SB3 load when a name below is first used (PEP 562), so a learner that only needs the
observation layout (``sb3_coma``'s UAV policy) does not pay for the whole world.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if __name__ != "uav_ipp":  # the source folder ``envs/`` imported under its folder name
    raise ImportError(
        f"the sb3-coma world installs as `uav_ipp`, not `{__name__}`: use `import uav_ipp` "
        "(pip install sb3-coma, or pip install -e . in a checkout)"
    )

from .registration import ENV_IDS, map_name_of, register_envs

if TYPE_CHECKING:
    from .api import make_env, make_vec_env
    from .config import DEFAULT_MAP, NOISE_PRESETS, WORLD_VERSION, ConfigError, IppConfig
    from .fusion import DEFAULT_FUSION, available_fusions
    from .ipp_env import UavIppEnv
    from .maps import GroundTruth, MapError, available_maps, load_ground_truth
    from .vec_env import IppVecEnv
    from .workers import BACKENDS, EnvWorkerError, WorkerVecEnv

#: Public name -> the submodule that defines it (imported on first use).
_LAZY = {
    "make_env": "api",
    "make_vec_env": "api",
    "NOISE_PRESETS": "config",
    "WORLD_VERSION": "config",
    "ConfigError": "config",
    "IppConfig": "config",
    "DEFAULT_FUSION": "fusion",
    "available_fusions": "fusion",
    "UavIppEnv": "ipp_env",
    "GroundTruth": "maps",
    "MapError": "maps",
    "available_maps": "maps",
    "load_ground_truth": "maps",
    "DEFAULT_MAP": "config",
    "IppVecEnv": "vec_env",
    "BACKENDS": "workers",
    "EnvWorkerError": "workers",
    "WorkerVecEnv": "workers",
}


def __getattr__(name: str) -> Any:
    """PEP 562: the heavy parts of the world load when one of their names is first used."""
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])


register_envs()

__all__ = [
    "BACKENDS",
    "DEFAULT_FUSION",
    "DEFAULT_MAP",
    "ENV_IDS",
    "NOISE_PRESETS",
    "WORLD_VERSION",
    "ConfigError",
    "EnvWorkerError",
    "GroundTruth",
    "IppConfig",
    "IppVecEnv",
    "MapError",
    "UavIppEnv",
    "WorkerVecEnv",
    "available_fusions",
    "available_maps",
    "load_ground_truth",
    "make_env",
    "make_vec_env",
    "map_name_of",
]
