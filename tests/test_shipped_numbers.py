"""The reported numbers are the shipped files' (#35): a shipped model flown today gives what its
models.json entry records, for the paper protocol and for its seed in the seed-spread table."""

from __future__ import annotations

import pytest

from sb3_coma.app.evaluation import evaluate
from sb3_coma.app.pretrained import read_manifest
from sb3_coma.experiments.ship_models import SCORED_FORM


def _finals(result) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    return round(float(result.f1[:, -1].mean()), 4), round(float(result.entropy[:, -1].mean()), 4)


@pytest.mark.slow
def test_the_shipped_env3_file_flies_its_recorded_numbers() -> None:
    entry = read_manifest()["models"]["env3"]
    paper = _finals(evaluate("env3", protocol="paper", record=0))
    assert paper == (entry["metrics"]["f1_100_mean"], entry["metrics"]["entropy_100_mean"])
    spread = entry["seeds_unseen"]
    scored = spread["scored"]  # how each seed was flown: the shipped seed from the shipped file
    assert scored == SCORED_FORM or scored[f"seed {entry['seed']}"] == "the shipped file"
    recorded = spread["metrics"][f"seed {entry['seed']}"]
    unseen = _finals(evaluate("env3", protocol="unseen", n_trials=spread["missions"], record=0))
    assert unseen == (recorded["f1"], recorded["entropy"])
