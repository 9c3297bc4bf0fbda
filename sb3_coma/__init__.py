"""sb3-coma: COMA for multi-UAV informative path planning, as a Stable-Baselines3 extension.

``from sb3_coma import COMA`` gives the algorithm; names are resolved lazily so that light
modules (``sb3_coma.sendfuse.network``, which the environment package imports for its wrapper)
do not pull in SB3 and the whole algorithm side.
"""
from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS: dict[str, str] = {
    "COMA": "sb3_coma.coma",
    "CBAMPolicy": "sb3_coma.coma",
    "CnnPolicy": "sb3_coma.coma",
    "COMAPolicy": "sb3_coma.coma",
    "CBAMExtractor": "sb3_coma.extractors",
    "CnnExtractor": "sb3_coma.extractors",
    "SenDFuseNet": "sb3_coma.sendfuse",
    "evaluate": "sb3_coma.evaluation",
    "load_pretrained": "sb3_coma.pretrained",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'sb3_coma' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
