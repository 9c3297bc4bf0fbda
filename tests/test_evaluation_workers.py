"""Evaluation on worker processes: the same missions and numbers as one process."""

from __future__ import annotations

import numpy as np
import pytest

import uav_ipp
from sb3_coma import COMA
from sb3_coma.app.config import resolve_world
from sb3_coma.app.evaluation import WorldMismatchWarning, _chunks, evaluate, evaluation_workers, parallel_evaluation
from sb3_coma.app.training import record_env_options
from sb3_coma.cli import main as cli_main
from sb3_coma.common.evaluation import merge_results

SMALL = {"env": "env1", "n_trials": 5, "n_envs": 2, "protocol": "unseen", "n_uavs": 2, "budget": 4}
FIELDS = ("f1", "entropy", "team_f1", "team_entropy", "returns", "trajectories", "final_beliefs", "belief_frames")


def _assert_same(a, b) -> None:
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert (a.scenes, a.n_trials, a.seed, a.method, a.env_options) == (
        b.scenes,
        b.n_trials,
        b.seed,
        b.method,
        b.env_options,
    )
    assert a.planning_time_ms.shape == b.planning_time_ms.shape


@pytest.mark.parametrize("method", ["ag", "random"])
def test_planners_on_two_workers_fly_the_same_missions(method):
    one = evaluate(method, record=3, workers=1, **SMALL)
    two = evaluate(method, record=3, workers=2, **SMALL)
    _assert_same(one, two)


def test_model_object_on_two_workers_and_through_the_context():
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=0, n_uavs=2, budget=4)
    model = COMA(
        "UavCnnPolicy",
        venv,
        n_steps=8,
        batch_size=8,
        seed=0,
        policy_kwargs={"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}},
    )
    one = evaluate(model, fusion="mean", record=0, workers=1, **SMALL)
    with parallel_evaluation(2):
        two = evaluate(model, fusion="mean", record=0, **SMALL)
    _assert_same(one, two)
    venv.close()


def test_chunks_are_whole_batches_in_order():
    assert _chunks(64, 10, 2) == [(0, 40), (40, 24)]
    assert _chunks(5, 2, 2) == [(0, 4), (4, 1)]
    assert _chunks(30, 10, 3) == [(0, 10), (10, 10), (20, 10)]
    assert evaluation_workers(8, 5, 10) == 1  # one batch: no worker to spare
    assert evaluation_workers("auto", 100, 10) >= 1


def test_bad_workers_are_refused():
    with pytest.raises(ValueError, match="workers"):
        evaluation_workers(0, 10, 10)
    with pytest.raises(ValueError, match="workers"), parallel_evaluation("many"):
        pass


def test_merge_refuses_chunks_that_are_not_consecutive():
    a = evaluate("random", record=0, workers=1, **{**SMALL, "n_trials": 2})
    b = evaluate("random", record=0, workers=1, seed=5, **{**SMALL, "n_trials": 2})
    with pytest.raises(ValueError, match="consecutive"):
        merge_results([a, b])
    with pytest.raises(ValueError, match="consecutive"):
        merge_results([])


def test_cli_workers_zero_is_one_line(capsys):
    assert cli_main(["evaluate", "--workers", "0"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "--workers" in line and "'0'" in line


def test_worker_warnings_reach_the_caller_once():
    """A model flown in another world than it trained in warns in the caller, as in one process."""
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=0, n_uavs=2, budget=4)
    kwargs = {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}}
    model = COMA("UavCnnPolicy", venv, n_steps=8, batch_size=8, seed=0, policy_kwargs=kwargs)
    record_env_options(model, resolve_world("UavIpp-Env1-v0", {"fusion": "mean", "n_uavs": 2, "budget": 4}, "test"))
    with pytest.warns(WorldMismatchWarning) as caught:
        evaluate(model, fusion="mean", record=0, workers=2, label="my-arm", **{**SMALL, "noise": "loud"})
    mismatches = [str(w.message) for w in caught if issubclass(w.category, WorldMismatchWarning)]
    assert len(mismatches) == 1
    assert "model 'my-arm'" in mismatches[0] and "sb3-coma-eval" not in mismatches[0]  # the arm, not a temp copy
    venv.close()
