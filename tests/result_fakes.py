"""A stand-in for an ``EvaluationResult`` in the statistics tests: final F1 per mission, entropy
``1 - F1``, the test split's options and, optionally, one scene label per mission."""

from __future__ import annotations

from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np


def fake_result(
    method: str, f1: Sequence[float], scenes: Sequence[str] | None = None, seed: int = 0, **env_options: Any
) -> SimpleNamespace:
    """Two steps per mission (0 at the reset, ``f1`` at the end); every metric derived from ``f1``."""
    final = np.asarray(f1, dtype=float)
    values = np.column_stack([np.zeros_like(final), final])
    return SimpleNamespace(
        method=method,
        env="env3",
        seed=seed,
        n_trials=len(final),
        env_options={"split": "test", "start": "random", **env_options},
        f1=values,
        entropy=1.0 - values,
        team_f1=values,
        team_entropy=1.0 - values,
        scenes=None if scenes is None else tuple(scenes),
    )
