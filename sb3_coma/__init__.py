"""sb3-coma: COMA (counterfactual multi-agent policy gradients) for Stable-Baselines3, with a
multi-UAV informative path planning world (SenDFuse, CBAM) as its first user.

The library: ``COMA`` and its policies for any env (``MlpPolicy``, ``CnnPolicy``,
``MultiInputPolicy``), ``make_marl_vec_env`` (any PettingZoo ``ParallelEnv`` -> the multi-agent
VecEnv COMA reads), the features extractors, SenDFuse and ``training_options`` (the env options a
saved model was trained with). Served lazily, so that ``import sb3_coma`` loads neither the UAV
world nor rl_zoo3 nor the application: the UAV world's policies (``CBAMPolicy``,
``UavCnnPolicy``) and two front doors of the application, ``evaluate`` (a model, a shipped name, a
path or a baseline on seeded missions) and ``load_pretrained`` (a shipped trained model).
"""

from __future__ import annotations

import importlib
from typing import Any

from sb3_coma.coma import COMA, CnnPolicy, COMAPolicy, MlpPolicy, MultiInputPolicy
from sb3_coma.common.checkpoints import training_options
from sb3_coma.common.extractors import CBAMExtractor, CnnExtractor
from sb3_coma.common.marl_vec_env import make_marl_vec_env
from sb3_coma.sendfuse import SenDFuseNet

__version__ = "0.3.0"

#: Names served lazily (``name -> module``): the application's front doors and the UAV policies.
_LAZY = {
    "evaluate": "sb3_coma.app.evaluation",
    "load_pretrained": "sb3_coma.app.pretrained",
    "CBAMPolicy": "sb3_coma.uav.policies",
    "UavCnnPolicy": "sb3_coma.uav.policies",
}


def __getattr__(name: str) -> Any:
    """PEP 562: the front doors import the application, the UAV policies the world, on first use."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'sb3_coma' has no attribute {name!r}")


__all__ = [
    "COMA",
    "CBAMExtractor",
    "CBAMPolicy",
    "COMAPolicy",
    "CnnExtractor",
    "CnnPolicy",
    "MlpPolicy",
    "MultiInputPolicy",
    "SenDFuseNet",
    "UavCnnPolicy",
    "__version__",
    "evaluate",
    "load_pretrained",
    "make_marl_vec_env",
    "training_options",
]
