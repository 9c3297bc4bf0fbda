"""sb3-coma: COMA for multi-UAV informative path planning, as a Stable-Baselines3 extension.

The library: ``COMA`` and its policies (``CBAMPolicy``, ``CnnPolicy``), the features extractors,
SenDFuse and ``training_options`` (the env options a saved model was trained with). Two front
doors of the application are reachable from here and load it only when first used, so that
``import sb3_coma`` imports neither rl_zoo3 nor the application: ``evaluate`` (a model, a shipped
name, a path or a baseline on seeded missions) and ``load_pretrained`` (a shipped trained model).
"""

from __future__ import annotations

import importlib
from typing import Any

from sb3_coma.coma import COMA, CBAMPolicy, CnnPolicy, COMAPolicy
from sb3_coma.common.checkpoints import training_options
from sb3_coma.common.extractors import CBAMExtractor, CnnExtractor
from sb3_coma.sendfuse import SenDFuseNet

__version__ = "0.2.0"

#: Names served lazily from the application (``name -> module``).
_FRONT_DOORS = {"evaluate": "sb3_coma.app.evaluation", "load_pretrained": "sb3_coma.app.pretrained"}


def __getattr__(name: str) -> Any:
    """PEP 562: ``sb3_coma.evaluate`` / ``sb3_coma.load_pretrained`` import the application on first use."""
    if name in _FRONT_DOORS:
        return getattr(importlib.import_module(_FRONT_DOORS[name]), name)
    raise AttributeError(f"module 'sb3_coma' has no attribute {name!r}")


__all__ = [
    "COMA",
    "CBAMExtractor",
    "CBAMPolicy",
    "COMAPolicy",
    "CnnExtractor",
    "CnnPolicy",
    "SenDFuseNet",
    "__version__",
    "evaluate",
    "load_pretrained",
    "training_options",
]
