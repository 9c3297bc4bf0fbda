"""A distributed Optuna sweep: two ``python -m sb3_coma.app.zoo train -optimize`` workers, one study.

What docs/deployment.md promises for several machines, on one machine: the workers share a
study through its storage (here rl-zoo3's journal file, ``--storage PATH.log``; on several
machines a PostgreSQL / MySQL URL), each runs its own trials, and the study ends up with every
trial of both, finished, numbered without gaps or duplicates.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import optuna
import pytest
import yaml

ENV = "UavIpp-Env1-v0"
STUDY = "sweep"
TRIALS_PER_WORKER = 2
#: A tiny arm: small CNN, 2 UAVs, 3 decisions each; a trial is a few seconds.
TINY = {
    ENV: {
        "n_timesteps": 200,
        "policy": "UavCnnPolicy",
        "policy_kwargs": {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}},
        "learning_rate": 1.0e-4,
        "critic_learning_rate": 1.0e-3,
        "batch_size": 64,
        "env_kwargs": {"fusion": "mean", "n_uavs": 2, "budget": 3},
    },
}
REPO = Path(__file__).resolve().parent.parent


def _worker(k: int, conf: Path, storage: Path, folder: Path) -> subprocess.Popen:
    """Worker ``k``: its own seed and log folder, the shared storage and study name."""
    argv = [
        sys.executable,
        "-m",
        "sb3_coma.app.zoo",
        "train",
        "--algo",
        "coma",
        "--env",
        ENV,
        "-conf",
        str(conf),
        "-optimize",
        "--n-trials",
        str(TRIALS_PER_WORKER),
        "--n-jobs",
        "1",
        "-n",
        "200",
        "--n-evaluations",
        "1",
        "--eval-episodes",
        "1",
        "--sampler",
        "random",
        "--pruner",
        "none",
        "--no-optim-plots",
        "--storage",
        str(storage),
        "--study-name",
        STUDY,
        "-f",
        str(folder / f"logs_{k}"),
        "--seed",
        str(k),
        "--verbose",
        "0",
    ]
    env = dict(
        os.environ,
        OMP_NUM_THREADS="1",
        MKL_NUM_THREADS="1",
        PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")])),
    )
    return subprocess.Popen(argv, cwd=folder, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_two_workers_fill_one_study(tmp_path):
    conf = tmp_path / "tiny.yml"
    conf.write_text(yaml.safe_dump(TINY))
    storage = tmp_path / "study.log"
    workers = [_worker(k, conf, storage, tmp_path) for k in range(2)]
    try:
        outputs = [w.communicate(timeout=150) for w in workers]
    finally:
        for w in workers:
            if w.poll() is None:
                w.kill()
                w.wait()
    for w, (_out, err) in zip(workers, outputs):
        assert w.returncode == 0, err[-3000:]

    study = optuna.load_study(
        study_name=STUDY,
        storage=optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(storage))),
    )
    trials = study.get_trials(deepcopy=False)
    finished = (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED)
    assert len(trials) == 2 * TRIALS_PER_WORKER, [t.state for t in trials]
    assert all(t.state in finished for t in trials), [t.state for t in trials]
    assert sorted(t.number for t in trials) == list(range(2 * TRIALS_PER_WORKER))
    assert all("learning_rate" in t.params for t in trials)
    # Each worker reports the trials it ran (Optuna logs "Trial N finished" / "Trial N pruned"):
    # both contributed, two each, none run twice.
    ran = [set(map(int, re.findall(r"Trial (\d+) (?:finished|pruned)", out + err))) for out, err in outputs]
    assert [len(r) for r in ran] == [TRIALS_PER_WORKER] * 2 and not ran[0] & ran[1], ran
    assert ran[0] | ran[1] == {t.number for t in trials}
