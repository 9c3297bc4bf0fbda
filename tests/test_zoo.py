"""rl-zoo3 route: ``python -m sb3_coma.app.zoo train|enjoy`` with COMA, tiny settings."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import optuna
import pytest
import yaml

import uav_ipp  # noqa: F401  (registers the gymnasium ids)
from sb3_coma import training_options
from sb3_coma.app import zoo, zoo_sampler
from sb3_coma.app.config import coma_parameter_names
from sb3_coma.common.checkpoints import validate_checkpoint

ENV = "UavIpp-Env1-v0"
TINY = {
    ENV: {
        "n_timesteps": 16,
        "policy": "UavCnnPolicy",
        "policy_kwargs": {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}},
        "learning_rate": 1.0e-4,
        "critic_learning_rate": "lin_1e-3",
        "batch_size": 8,
        "n_steps": 8,
        "env_kwargs": {"fusion": "mean", "n_uavs": 2, "budget": 4},
    },
    "variants": {"cbam": {"policy": "CBAMPolicy"}},
}


# Runs write run folders and logs into the working directory: keep them in tmp_path.
pytestmark = pytest.mark.usefixtures("tmp_cwd")


@pytest.fixture
def conf(tmp_path: Path) -> str:
    path = tmp_path / "tiny.yml"
    path.write_text(yaml.safe_dump(TINY))
    return str(path)


def test_zoo_train_enjoy_round_trip(tmp_path, conf, capsys):
    import rl_zoo3.enjoy
    import rl_zoo3.train
    from rl_zoo3.exp_manager import ExperimentManager

    logs = tmp_path / "logs"
    rc = zoo.main(
        [
            "train",
            "--algo",
            "coma",
            "--env",
            ENV,
            "-conf",
            conf,
            "--variant",
            "cbam",
            "-n",
            "16",
            "--seed",
            "1",
            "-f",
            str(logs),
            "--eval-freq",
            "8",
            "--eval-episodes",
            "2",
            "--save-freq",
            "8",
            "-tb",
            str(tmp_path / "tb"),
            "--verbose",
            "0",
        ]
    )
    assert rc == 0
    assert rl_zoo3.train.ExperimentManager is ExperimentManager  # un-patched afterwards
    run = logs / "coma" / f"{ENV}_1"
    assert validate_checkpoint(run / f"{ENV}.zip").num_timesteps == 16
    recorded = training_options(run / f"{ENV}.zip")  # the same record as sb3-coma train's
    assert recorded is not None and recorded["map"] == "env1" and recorded["fusion"] == "mean"
    assert recorded["n_uavs"] == 2 and training_options(run / "rl_model_8_steps.zip") == recorded
    assert validate_checkpoint(run / "rl_model_8_steps.zip").num_timesteps == 8
    assert validate_checkpoint(run / "rl_model_16_steps.zip").num_timesteps == 16
    assert validate_checkpoint(run / "best_model.zip")
    evaluations = np.load(run / "evaluations.npz")
    assert list(evaluations["timesteps"]) == [8, 16] and evaluations["results"].shape[1] == 2 * 2  # missions x UAVs
    saved = yaml.load((run / ENV / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert saved["policy"] == "CBAMPolicy" and saved["env_kwargs"]["fusion"] == "mean"
    args = yaml.load((run / ENV / "args.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert args["algo"] == "coma" and args["variant"] == "cbam" and args["seed"] == 1
    assert len((run / "metrics.csv").read_text().strip().splitlines()) == 1 + 4  # header + 16 / 4 missions
    assert list((tmp_path / "tb" / ENV).rglob("events.out.tfevents*"))
    capsys.readouterr()

    rc = zoo.main(["enjoy", "--algo", "coma", "--env", ENV, "-f", str(logs), "--no-render", "-n", "8"])
    assert rc == 0
    out = capsys.readouterr().out
    assert out.count("Mission ") >= 2 and "Episode Reward" in out and "mean final F1" in out
    assert rl_zoo3.enjoy.create_test_env is rl_zoo3.utils.create_test_env

    rc = zoo.main(["enjoy", "--env", ENV, "-f", str(logs), "--no-render", "-n", "4", "--load-last-checkpoint"])
    assert rc == 0 and "rl_model_16_steps.zip" in capsys.readouterr().out
    rc = zoo.main(["enjoy", "--env", ENV, "-f", str(logs), "--no-render", "-n", "4", "--load-checkpoint", "8"])
    assert rc == 0 and "rl_model_8_steps.zip" in capsys.readouterr().out


def test_zoo_bad_input(tmp_path, conf, capsys):
    logs = str(tmp_path / "logs")
    cases = [
        (["--variant", "nope"], "unknown variant 'nope'"),
        (["-params", "batch_sise:8"], "COMA does not take 'batch_sise'"),
        (["--env-kwargs", "n_uav:2"], "unknown environment option"),
        (["--algo", "ppo"], "multi-agent env: train it with --algo coma"),
    ]
    for extra, message in cases:
        rc = zoo.main(["train", "--env", ENV, "-conf", conf, "-f", logs, *extra])
        assert rc == 2, extra
        assert message in capsys.readouterr().err
    assert zoo.main(["fly"]) == 2
    assert zoo.main(["train", "--env", "UavIpp-Env9-v0"]) == 2
    assert "unknown env id 'UavIpp-Env9-v0'" in capsys.readouterr().err


def test_sampler_gives_coma_arguments():
    study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=0))
    allowed = set(coma_parameter_names())
    for _ in range(5):
        trial = study.ask()
        params = zoo_sampler.sample_coma_params(trial, 6, 1, {})
        assert set(params) <= allowed
        assert params == zoo_sampler.convert_coma_params(trial.params)
        assert 64 <= params["batch_size"] <= 1024 and 0.9 <= params["gamma"] < 1 and 0.5 <= params["td_lambda"] < 1


def test_zoo_optimize_with_shared_storage(tmp_path, conf, monkeypatch):
    real = zoo_sampler.sample_coma_params

    def small(trial, n_actions, n_envs, additional_args):
        params = real(trial, n_actions, n_envs, additional_args)
        params["batch_size"] = 8  # keep the test fast; the space is exercised above
        return params

    monkeypatch.setattr(zoo_sampler, "sample_coma_params", small)
    storage = tmp_path / "study.log"
    rc = zoo.main(
        [
            "train",
            "--env",
            ENV,
            "-conf",
            conf,
            "-optimize",
            "--n-trials",
            "1",
            "-n",
            "8",
            "--n-evaluations",
            "1",
            "--eval-episodes",
            "1",
            "--no-optim-plots",
            "--sampler",
            "random",
            "--pruner",
            "none",
            "--storage",
            str(storage),
            "--study-name",
            "tiny",
            "-f",
            str(tmp_path / "logs"),
            "--seed",
            "0",
            "--verbose",
            "0",
        ]
    )
    assert rc == 0
    study = optuna.load_study(
        study_name="tiny",
        storage=optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(storage))),
    )
    assert len(study.trials) == 1 and study.trials[0].state == optuna.trial.TrialState.COMPLETE
    assert "learning_rate" in study.trials[0].params


def test_python_dash_m_entry_point(tmp_path):
    result = subprocess.run(
        [sys.executable, "-m", "sb3_coma.zoo", "--help"],
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parent.parent,
        timeout=60,
    )
    assert result.returncode == 0 and "python -m sb3_coma.zoo" in result.stdout


def test_zoo_train_runs_the_warm_start(tmp_path):
    config = {ENV: {**TINY[ENV], "kl_coef": 1.0, "warm_start": {"rounds": 1, "missions": 2}}}
    path = tmp_path / "warm.yml"
    path.write_text(yaml.safe_dump(config))
    logs = tmp_path / "logs"
    args = ["train", "--algo", "coma", "--env", ENV, "-conf", str(path), "-n", "8", "--seed", "1", "-f", str(logs)]
    assert zoo.main([*args, "--verbose", "0"]) == 0
    run = logs / "coma" / f"{ENV}_1"
    record = yaml.safe_load((run / "warm_start.json").read_text())
    assert record["teacher"] == "oracle" and record["rounds"] == 1 and (run / "warm_start.zip").is_file()
    assert validate_checkpoint(run / f"{ENV}.zip").num_timesteps == 8
