"""sb3-coma: COMA for multi-UAV informative path planning, as a Stable-Baselines3 extension.

The library: ``COMA`` and its policies (``CBAMPolicy``, ``CnnPolicy``), the features extractors,
SenDFuse, ``evaluate`` (the paper's protocol for models and baselines), ``load_pretrained``
(the shipped models) and ``training_options`` (the env options a saved model was trained with).
"""

from __future__ import annotations

from sb3_coma.checkpoints import training_options
from sb3_coma.coma import COMA, CBAMPolicy, CnnPolicy, COMAPolicy
from sb3_coma.evaluation import evaluate
from sb3_coma.extractors import CBAMExtractor, CnnExtractor
from sb3_coma.pretrained import load_pretrained
from sb3_coma.sendfuse import SenDFuseNet

__version__ = "0.1.0"

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
