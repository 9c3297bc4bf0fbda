"""The zoo on third-party cooperative tasks: ``python -m sb3_coma.zoo train --algo coma|mappo|ippo
--env simple_spread`` (or a user's ``package.module:factory``), ``sb3-coma train --env <task>``, the
Optuna search, and their refusals; tiny budgets."""

from __future__ import annotations

from pathlib import Path

import optuna
import pytest
import yaml
from stable_baselines3 import PPO

from sb3_coma.app import zoo, zoo_sampler
from sb3_coma.app.marl_tasks import NAMED_TASKS, is_marl_task_id, resolve_task
from sb3_coma.app.zoo_marl import prune_refused_batch
from sb3_coma.cli import main as cli_main
from sb3_coma.coma import COMA
from sb3_coma.coma.validation import BatchLargerThanRollout

pytestmark = pytest.mark.usefixtures("tmp_cwd")

TASK = "simple_spread"
TINY = {"n_steps": 8, "batch_size": 16, "n_envs": 2, "n_timesteps": 64}
USER_MODULE = """
def make_team(**options):
    from mpe2 import simple_spread_v3
    return simple_spread_v3.parallel_env(**{"N": 2, "max_cycles": 10, **options})

NOT_A_FACTORY = 3
"""


def _config(tmp_path: Path, entries: dict[str, dict]) -> str:
    path = tmp_path / "conf.yml"
    path.write_text(yaml.safe_dump(entries))
    return str(path)


def _train(*extra: str) -> int:
    return zoo.main(["train", "--seed", "3", "--verbose", "0", *extra])


@pytest.mark.parametrize(
    ("algo", "policy", "steps_per_joint_step"),
    [("coma", "MlpPolicy", 1), ("mappo", "CentralValuePolicy", 3), ("ippo", "MlpPolicy", 3)],
)
def test_each_learner_trains_a_named_task_in_joint_steps(tmp_path, algo, policy, steps_per_joint_step):
    conf = _config(tmp_path, {TASK: {"policy": policy, **TINY}})
    assert _train("--algo", algo, "--env", TASK, "-conf", conf, "-f", "logs") == 0
    run = tmp_path / "logs" / algo / f"{TASK}_1"
    model = (COMA if algo == "coma" else PPO).load(run / f"{TASK}.zip", device="cpu")
    # one budget for every learner: SB3's PPO counts a step per agent row, COMA per joint step
    assert model.num_timesteps == 64 * steps_per_joint_step
    saved = yaml.load((run / TASK / "config.yml").read_text(), Loader=yaml.UnsafeLoader)
    assert dict(saved)["policy"] == policy
    if algo == "mappo":
        assert type(model.policy).__name__ == "CentralValuePolicy"


def test_an_entrys_linear_schedules_train_comas_two_learning_rates(tmp_path):
    """``lin_<x>`` for ``learning_rate`` (rl-zoo3's) and for COMA's ``critic_learning_rate`` alike."""
    entry = {"policy": "MlpPolicy", **TINY, "learning_rate": "lin_3e-4", "critic_learning_rate": "lin_1e-3"}
    assert _train("--algo", "coma", "--env", TASK, "-conf", _config(tmp_path, {TASK: entry}), "-f", "logs") == 0
    model = COMA.load(tmp_path / "logs" / "coma" / f"{TASK}_1" / f"{TASK}.zip", device="cpu")
    assert model.lr_schedule(0.5) == pytest.approx(1.5e-4) and model.critic_lr_schedule(0.5) == pytest.approx(5e-4)


def test_the_shipped_configs_train_every_named_task_by_default(tmp_path, capsys):
    """No -conf: zoo_configs/marl/<algo>.yml, the benchmark's entry (its budget cut by -n)."""
    rc = _train("--algo", "coma", "--env", TASK, "-n", "64", "-params", "n_steps:8", "n_envs:2", "batch_size:16")
    assert rc == 0
    saved = yaml.load((tmp_path / "logs" / "coma" / f"{TASK}_1" / TASK / "config.yml").read_text(), yaml.UnsafeLoader)
    assert dict(saved)["n_epochs"] == 10  # the shipped entry's, not COMA's default
    for algo in ("coma", "mappo", "ippo"):
        entries = yaml.safe_load((Path(__file__).parents[1] / "zoo_configs" / "marl" / f"{algo}.yml").read_text())
        assert set(NAMED_TASKS) <= set(entries), algo


def test_a_users_factory_trains_with_its_options(tmp_path, monkeypatch):
    (tmp_path / "team_env.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    env_id = "team_env:make_team"
    assert is_marl_task_id(env_id) and not is_marl_task_id("CartPole-v1")
    conf = _config(tmp_path, {env_id: {"policy": "MlpPolicy", **TINY, "env_kwargs": {"N": 3}}})
    assert _train("--algo", "coma", "--env", env_id, "-conf", conf, "-f", "logs") == 0
    model = COMA.load(tmp_path / "logs" / "coma" / "make_team_1" / "make_team.zip", device="cpu")
    assert model.n_agents == 3  # env_kwargs reached the factory (its default is 2)
    assert resolve_task(env_id).agents({}) == 2


def test_sb3_coma_train_takes_a_task(tmp_path, capsys):
    conf = _config(tmp_path, {TASK: {"policy": "MlpPolicy", **TINY}})
    argv = ["train", "--env", TASK, "--config", conf, "--seed", "2", "--run-dir", "runs", "--set", "batch_size=8"]
    rc = cli_main([*argv, "--timesteps", "32", "--no-progress", "-v", "0"])
    assert rc == 0
    model = COMA.load(tmp_path / "runs" / "coma" / f"{TASK}_1" / f"{TASK}.zip", device="cpu")
    assert model.num_timesteps == 32 and model.batch_size == 8 and model.seed == 2


def test_a_refused_batch_prunes_the_trial_instead_of_failing_it():
    def refused(trial: optuna.Trial) -> float:
        raise BatchLargerThanRollout("batch_size=1024 joint steps is larger than one rollout")

    study = optuna.create_study()
    trial = study.ask()
    with pytest.raises(optuna.TrialPruned, match="larger than one rollout"):
        prune_refused_batch(refused, trial)
    assert prune_refused_batch(lambda t: 1.5, trial) == 1.5
    with pytest.raises(ValueError, match="other"):  # any other error stays an error
        prune_refused_batch(lambda t: (_ for _ in ()).throw(ValueError("other")), trial)


def test_the_search_runs_on_a_task(tmp_path, monkeypatch):
    real = zoo_sampler.sample_coma_params

    def small(trial, n_actions, n_envs, additional_args):
        return real(trial, n_actions, n_envs, additional_args) | {"batch_size": 16, "n_epochs": 1}

    monkeypatch.setattr(zoo_sampler, "sample_coma_params", small)
    conf = _config(tmp_path, {TASK: {"policy": "MlpPolicy", **TINY}})
    storage = tmp_path / "study.log"
    rc = _train(
        *("--algo", "coma", "--env", TASK, "-conf", conf, "-f", "logs", "-optimize", "--n-trials", "2"),
        *("-n", "32", "--n-evaluations", "1", "--eval-episodes", "1", "--no-optim-plots"),
        *("--sampler", "random", "--pruner", "none", "--storage", str(storage), "--study-name", "task"),
    )
    assert rc == 0
    study = optuna.load_study(
        study_name="task",
        storage=optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(storage))),
    )
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 2
    assert {"n_epochs", "clip_range", "learning_rate"} <= set(study.trials[0].params)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--env", "no_such_module_xyz:make"], "cannot import 'no_such_module_xyz'"),
        (["--env", "team_env:NOT_A_FACTORY"], "team_env has no callable 'NOT_A_FACTORY'"),
        (["--env", TASK, "--variant", "cbam"], "variants are the UavIpp config's"),
        (["--env", TASK, "-conf", "CONF"], "no entry 'simple_spread'"),
        (["--env", "team_env:make_team", "--env-kwargs", "n_agents:4"], "env_kwargs {'n_agents': 4}"),
        (["--algo", "mappo", "--env", "UavIpp-Env1-v0"], "is a multi-agent env: train it with --algo coma"),
    ],
)
def test_bad_task_input_is_one_line(tmp_path, monkeypatch, capsys, argv, message):
    (tmp_path / "team_env.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    conf = _config(tmp_path, {"other_task": {"policy": "MlpPolicy"}})
    argv = [conf if a == "CONF" else a for a in argv]
    assert _train(*argv, "-n", "16", "-f", "logs") == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("extra", "flag"),
    [
        (["--resume", "runs/x"], "--resume"),
        (["--variant", "cbam"], "--variant"),
        (["--eval-missions", "4"], "--eval-missions"),
    ],
)
def test_sb3_coma_train_refuses_the_worlds_options_for_a_task(capsys, extra, flag):
    assert cli_main(["train", "--env", TASK, *extra]) == 2
    err = capsys.readouterr().err
    assert f"{flag} is an option of the UAV world's runs" in err and len(err.strip().splitlines()) == 1
