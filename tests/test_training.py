"""Training API and ``sb3-coma train``: run folders, resume, bad input (tiny, fast settings)."""

from __future__ import annotations

import csv
import hashlib
import os
import signal
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml
from stable_baselines3.common.callbacks import BaseCallback
from tiny_runs import ENV, tiny_entry

import uav_ipp  # noqa: F401  (registers the gymnasium ids)
from sb3_coma import cli, training_options
from sb3_coma.app.config import TrainingError, default_config_path, list_variants, load_config
from sb3_coma.app.training import TrainingInterrupted, train
from sb3_coma.common.checkpoints import CheckpointError, find_checkpoints, validate_checkpoint

# 2 UAVs, 4-step missions, 8 joint steps per rollout (= 2 missions): every run is a few rollouts.
TINY = {
    ENV: tiny_entry(),
    "variants": {"cbam": {"policy": "CBAMPolicy"}, "loud": {"env_kwargs": {"noise": "loud"}}},
}


# Runs write run folders and logs into the working directory: keep them in tmp_path.
pytestmark = pytest.mark.usefixtures("tmp_cwd")


def write_config(folder: Path, data: dict | None = None, text: str | None = None) -> Path:
    path = folder / "tiny.yml"
    path.write_text(text if text is not None else yaml.safe_dump(data or TINY))
    return path


def quiet(**kwargs):
    kwargs.setdefault("progress_bar", False)
    kwargs.setdefault("verbose", 0)
    return kwargs


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def metric_rows(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / "metrics.csv").open(newline="") as handle:
        return list(csv.DictReader(handle))


class _Signal(BaseCallback):
    """Send a signal to this process once training has passed ``after`` joint steps."""

    def __init__(self, after: int, signum: int = signal.SIGTERM) -> None:
        super().__init__()
        self.after, self.signum, self.sent = after, signum, False

    def _on_step(self) -> bool:
        if not self.sent and self.num_timesteps >= self.after:
            self.sent = True
            os.kill(os.getpid(), self.signum)
        return True


class _Boom(BaseCallback):
    def _on_step(self) -> bool:
        if self.num_timesteps >= 12:
            raise RuntimeError("boom")
        return True


# ----------------------------------------------------------------------------- config files
def test_default_config_has_the_settings_that_learn_and_the_paper_variant():
    path = default_config_path()
    data = yaml.safe_load(path.read_text())
    for env_id in ("UavIpp-Env1-v0", "UavIpp-Env2-v0", "UavIpp-Env3-v0"):
        cfg = load_config(env_id, path)
        e = cfg.entry
        assert e["n_timesteps"] == 18000  # COMA's fine-tuning after the warm start
        assert e["policy"] == "CBAMPolicy" and e["n_envs"] == 8
        assert "batch_size" not in e  # COMA's defaults: the measured settings
        assert e["learning_rate"] == 3e-5 and e["kl_coef"] == 1.0 and e["kl_fraction"] == 1.0
        assert e["warm_start"] == {"teacher": "oracle", "rounds": 8, "missions": 128, "critic_warmup": 0.25}
        assert e["env_kwargs"] == {
            "fusion": "sendfuse",
            "n_uavs": 4,
            "budget": 15,
            "noise": "moderate",
            "split": "train",
            "reward": "metrics",
            "action_gain": True,
        }
        assert e["policy_kwargs"] == {"gain_inputs": True}  # the network reads the on-board gains
        assert data[env_id] == e
    paper = load_config("env3", path, "paper").entry
    assert paper["n_timesteps"] == 18000 and paper["learning_rate"] == 1e-5 and paper["critic_learning_rate"] == 1e-4
    assert paper["batch_size"] == 512 and paper["advantage"] == "q" and paper["clip_range"] is None
    assert paper["n_epochs"] == 1 and paper["env_kwargs"]["split"] == "paper"
    assert paper["warm_start"] is None and paper["kl_coef"] == 0.0  # the paper trains from scratch
    for name in ("paper", "paper-actor"):  # the paper's actor: 8 local channels, no gain inputs
        entry = load_config("env3", path, name).entry
        assert entry["policy_kwargs"] == {"gain_inputs": False} and entry["env_kwargs"]["action_gain"] is False
    variants = list_variants(path)
    assert {"paper", "paper-actor", "sendfuse-cbam", "sendfuse-cnn", "mean-cbam", "mean-cnn"} <= set(variants)
    base = load_config("env3", path, "mean-cnn").entry
    assert base["policy"] == "UavCnnPolicy" and base["env_kwargs"]["fusion"] == "mean"
    assert base["env_kwargs"]["noise"] == "moderate"  # merged key by key


def test_default_config_main_keys_load_in_rl_zoo(tmp_path):
    """rl-zoo3's own hyperparameter reading accepts the file for each main key."""
    import argparse

    from rl_zoo3.exp_manager import ExperimentManager

    for env_id in ("UavIpp-Env1-v0", "UavIpp-Env3-v0"):
        manager = ExperimentManager(
            argparse.Namespace(), "coma", env_id, str(tmp_path), config=str(default_config_path())
        )
        hyperparams, saved = manager.read_hyperparameters()
        assert hyperparams["n_envs"] == 8 and saved["env_kwargs"]["fusion"] == "sendfuse"


def test_overrides_and_variant(tmp_path):
    cfg = load_config("env1", write_config(tmp_path), "loud", {"env_kwargs.n_uavs": 3, "batch_size": 4})
    assert cfg.entry["env_kwargs"] == {"fusion": "mean", "n_uavs": 3, "budget": 4, "noise": "loud"}
    assert cfg.entry["batch_size"] == 4 and cfg.n_agents == 3


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(env="env9"), r"unknown env 'env9'"),
        (dict(env="env1", variant="nope"), r"unknown variant 'nope'.*variants: cbam, loud"),
        (
            dict(env="env1", overrides={"batch_sise": 8}),
            r"COMA does not take 'batch_sise' \(did you mean 'batch_size'\?\)",
        ),
        (dict(env="env1", overrides={"normalize": True}), r"'normalize' is not supported"),
        (dict(env="env1", overrides={"seed": 3}), r"'seed' cannot be set in a config"),
        (dict(env="env1", overrides={"env_kwargs.n_uav": 3}), r"env_kwargs: unknown environment option"),
        (dict(env="env1", overrides={"env_kwargs.fusion": "median"}), r"fusion must be one of"),
        (dict(env="env1", overrides={"learning_rate": "fast"}), r"learning_rate must be a number or 'lin_"),
        (dict(env="env1", overrides={"n_timesteps": 0}), r"n_timesteps must be a positive integer"),
        (dict(env="env1", overrides={"gamma": 2.0}), r"tiny.yml \[UavIpp-Env1-v0\].*gamma"),
    ],
)
def test_bad_config_input_is_named(tmp_path, kwargs, match):
    with pytest.raises(TrainingError, match=match):
        train(config=write_config(tmp_path), run_dir=tmp_path / "run", total_timesteps=8, **quiet(**kwargs))
    assert not (tmp_path / "run" / "model.zip").exists()


def test_malformed_yaml_names_file_and_line(tmp_path):
    path = write_config(tmp_path, text="UavIpp-Env1-v0:\n  n_timesteps: 40\n  batch_size: [8\n")
    with pytest.raises(TrainingError, match=r"tiny.yml is not valid YAML at line \d+, column \d+"):
        load_config("env1", path)
    with pytest.raises(TrainingError, match=r"config file .*missing.yml does not exist"):
        load_config("env1", tmp_path / "missing.yml")
    with pytest.raises(TrainingError, match=r"has no entry for UavIpp-Env2-v0"):
        load_config("env2", write_config(tmp_path))
    with pytest.raises(TrainingError, match=r"must be a mapping"):
        load_config("env1", write_config(tmp_path, text="- a\n- b\n"))


def test_resume_bad_paths(tmp_path):
    with pytest.raises(TrainingError, match=r"cannot resume from .*nowhere: no such file"):
        train(resume=tmp_path / "nowhere", **quiet())
    (tmp_path / "empty").mkdir()
    with pytest.raises(TrainingError, match=r"not a run folder \(no config.yml\)"):
        train(resume=tmp_path / "empty", **quiet())
    # Another algorithm's model.
    from stable_baselines3 import PPO

    ppo = tmp_path / "ppo.zip"
    PPO("MlpPolicy", "CartPole-v1", n_steps=16, batch_size=16).save(ppo)
    with pytest.raises(CheckpointError, match=r"ppo.zip is not a COMA checkpoint"):
        train(resume=ppo, config=write_config(tmp_path), env="env1", **quiet())
    # Not a zip at all.
    junk = tmp_path / "junk.zip"
    junk.write_text("not a zip")
    with pytest.raises(CheckpointError, match=r"junk.zip is unusable: it is not a zip archive"):
        train(resume=junk, **quiet())


# ----------------------------------------------------------------------------- runs
def test_run_folder_checkpoints_resume_and_no_overwrite(tmp_path):
    config = write_config(tmp_path)
    model, run = train(env="env1", config=config, seed=0, run_dir=tmp_path / "run", save_freq=16, **quiet())
    assert run == tmp_path / "run"
    assert model.num_timesteps == 40
    # config.yml: the resolved entry (valid zoo config) + run info
    saved = yaml.safe_load((run / "config.yml").read_text())
    assert saved[ENV]["env_kwargs"]["n_uavs"] == 2 and saved["run"]["seed"] == 0 and saved["run"]["env"] == ENV
    # final model and checkpoints at rollout boundaries (multiples of 8), atomically written
    assert validate_checkpoint(run / "model.zip").num_timesteps == 40
    # every saved model records the env it was trained on (sb3_coma.training_options)
    recorded = training_options(run / "model.zip")
    assert recorded == training_options(model) and recorded is not None
    assert recorded["map"] == "env1" and recorded["fusion"] == "mean" and recorded["noise"] == "moderate"
    assert (recorded["n_uavs"], recorded["budget"], recorded["split"]) == (2, 4, "paper")
    assert training_options(find_checkpoints(run / "checkpoints")[0][1]) == recorded
    steps = [s for s, _ in find_checkpoints(run / "checkpoints")]
    assert steps and all(s % 8 == 0 and s >= 16 for s in steps)
    assert not [p for p in run.rglob("*.tmp")]
    # metrics: one row per mission (40 joint steps / 4 per mission), values from the env
    rows = metric_rows(run)
    assert len(rows) == 10
    assert all(0.0 <= float(r["f1"]) <= 1.0 and 0.0 <= float(r["entropy"]) <= 1.0 for r in rows)
    assert [int(r["timesteps"]) for r in rows] == [4 * (i + 1) for i in range(10)]
    assert list((run / "tb").rglob("events.out.tfevents*"))

    # A second run asking for the same folder gets a suffix; a failing run writes no model.
    before = digest(run / "model.zip")
    with pytest.raises(RuntimeError, match="boom"):
        train(env="env1", config=config, seed=1, run_dir=tmp_path / "run", callbacks=[_Boom()], **quiet())
    assert (tmp_path / "run_2" / "config.yml").exists()
    assert not (tmp_path / "run_2" / "model.zip").exists()
    assert digest(run / "model.zip") == before

    # Extending the finished run resumes from model.zip (40) with optimiser state and continues counting.
    model2, run2 = train(resume=run, total_timesteps=56, **quiet())
    assert run2 == run and model2.num_timesteps == 56
    assert len(metric_rows(run)) == 14
    assert yaml.safe_load((run / "config.yml").read_text())[ENV]["n_timesteps"] == 56


def test_interrupt_saves_checkpoint_and_resume_reaches_same_count(tmp_path):
    config = write_config(tmp_path)
    handler = signal.getsignal(signal.SIGTERM)  # SIG_DFL, or Ray's if a Ray test ran in this worker first
    with pytest.raises(TrainingInterrupted) as info:
        train(env="env1", config=config, seed=0, run_dir=tmp_path / "run", callbacks=[_Signal(after=20)], **quiet())
    stop = info.value
    run = stop.run_dir
    assert stop.signum == signal.SIGTERM and stop.num_timesteps == 16  # the boundary before step 20
    assert stop.checkpoint == run / "checkpoints" / "rl_model_16_steps.zip"
    assert validate_checkpoint(stop.checkpoint).num_timesteps == 16
    assert not (run / "model.zip").exists()
    assert signal.getsignal(signal.SIGTERM) is handler  # handlers restored

    # The checkpoint holds both optimisers after 2 rollouts (one actor and one critic step each).
    from sb3_coma.coma import COMA

    with zipfile.ZipFile(stop.checkpoint) as archive:
        assert {"policy.optimizer.pth", "policy.critic_optimizer.pth"} <= set(archive.namelist())
    loaded = COMA.load(stop.checkpoint, device="cpu")
    for opt in (loaded.policy.optimizer, loaded.policy.critic_optimizer):
        steps = {int(s["step"]) for s in opt.state_dict()["state"].values()}
        assert steps == {2}

    model, run2 = train(resume=run, **quiet())
    assert run2 == run
    assert model.num_timesteps == 40  # the same count as the uninterrupted run above
    assert validate_checkpoint(run / "model.zip").num_timesteps == 40
    for opt in (model.policy.optimizer, model.policy.critic_optimizer):
        assert {int(s["step"]) for s in opt.state_dict()["state"].values()} == {5}
    stamps = [int(r["timesteps"]) for r in metric_rows(run)]
    assert stamps == sorted(stamps) and len(stamps) == 10  # missions after the checkpoint were flown again
    saved = yaml.safe_load((run / "config.yml").read_text())
    assert saved["run"]["resumes"][0]["at"] == 16


def test_truncated_checkpoint_is_refused_and_skipped(tmp_path):
    config = write_config(tmp_path)
    _, run = train(
        env="env1", config=config, seed=0, run_dir=tmp_path / "run", total_timesteps=24, save_freq=8, **quiet()
    )
    assert [s for s, _ in find_checkpoints(run / "checkpoints")] == [8, 16, 24]
    ckpt = run / "checkpoints" / "rl_model_24_steps.zip"
    ckpt.write_bytes(ckpt.read_bytes()[: ckpt.stat().st_size // 2])
    with pytest.raises(CheckpointError, match=r"rl_model_24_steps.zip is (truncated|corrupt|unusable)"):
        train(resume=ckpt, **quiet())
    (run / "model.zip").unlink()
    with pytest.warns(UserWarning, match="rl_model_24_steps.zip"):
        model, _ = train(resume=run, **quiet())
    assert model.num_timesteps == 24  # from the newest valid checkpoint (16) + 1 rollout
    assert validate_checkpoint(run / "model.zip").num_timesteps == 24


def test_resume_conflicts(tmp_path):
    config = write_config(tmp_path)
    _, run = train(env="env1", config=config, seed=0, run_dir=tmp_path / "run", total_timesteps=8, **quiet())
    with pytest.raises(TrainingError, match="drop --config/--variant"):
        train(resume=run, variant="cbam", **quiet())
    with pytest.raises(TrainingError, match="that run trains UavIpp-Env1-v0, not UavIpp-Env3-v0"):
        train(resume=run, env="env3", **quiet())
    before = (run / "config.yml").read_text()
    for change in ({"policy": "CBAMPolicy"}, {"env_kwargs.fusion": "sendfuse"}, {"learning_rate": 1e-3}):
        with pytest.raises(TrainingError, match="cannot apply to a resumed run"):
            train(resume=run, overrides=change, **quiet())
    assert (run / "config.yml").read_text() == before  # the run's record is not rewritten
    standalone = tmp_path / "standalone.zip"
    standalone.write_bytes((run / "model.zip").read_bytes())
    with pytest.raises(TrainingError, match="trained with 2 UAVs but the config has 3"):
        train(resume=standalone, env="env1", config=config, overrides={"env_kwargs.n_uavs": 3}, **quiet())


# ----------------------------------------------------------------------------- CLI
def test_cli_errors_are_one_line(tmp_path, capsys):
    config = str(write_config(tmp_path))
    cases = [
        (["train", "--env", "env9"], "unknown env 'env9'"),
        (["train", "--env", "env1", "--config", config, "--variant", "x"], "unknown variant 'x'"),
        (["train", "--env", "env1", "--config", config, "--set", "batch_sise=8"], "COMA does not take 'batch_sise'"),
        (["train", "--resume", str(tmp_path / "nope")], "no such file or folder"),
        (["train", "--env", "env1", "--timesteps", "0"], "--timesteps must be an integer >= 1, got 0"),
        (["train", "--env", "env1", "--eval-freq", "-5"], "--eval-freq must be an integer >= 0 (0: none)"),
    ]
    for argv, message in cases:
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("sb3-coma train: error:") and message in err and "\n" not in err


def test_cli_train_tiny_and_list_variants(tmp_path, capsys):
    config = str(write_config(tmp_path))
    assert cli.main(["train", "--config", config, "--list-variants"]) == 0
    assert "cbam:" in capsys.readouterr().out
    rc = cli.main(
        [
            "train",
            "--env",
            "env1",
            "--config",
            config,
            "--variant",
            "cbam",
            "--timesteps",
            "8",
            "--seed",
            "3",
            "--run-dir",
            str(tmp_path / "cli"),
            "--no-progress",
            "--set",
            "env_kwargs.budget=2",
        ]
    )
    assert rc == 0
    out = capsys.readouterr().out
    assert "Run folder:" in out and "model.zip" in out
    saved = yaml.safe_load((tmp_path / "cli" / "config.yml").read_text())
    assert saved[ENV]["policy"] == "CBAMPolicy" and saved[ENV]["env_kwargs"]["budget"] == 2
    assert saved["run"]["variant"] == "cbam" and saved["run"]["seed"] == 3
    assert len(metric_rows(tmp_path / "cli")) == 4


def test_cli_interrupt_exit_status(monkeypatch, tmp_path, capsys):
    import sb3_coma.app.training

    def interrupted(**kwargs):
        raise TrainingInterrupted(
            tmp_path / "run", tmp_path / "run" / "checkpoints" / "rl_model_8_steps.zip", 8, signal.SIGTERM
        )

    monkeypatch.setattr(sb3_coma.app.training, "train", interrupted)
    assert cli.main(["train", "--env", "env1", "-v", "0"]) == 128 + signal.SIGTERM
    assert "sb3-coma train --resume" in capsys.readouterr().err


def test_validation_picks_best_model_on_seeded_missions(tmp_path):
    """``eval_freq`` keeps ``best_model.zip``: the checkpoint with the best mean return on the
    same validation missions (env seed ``VALIDATION_SEED`` by default) at every evaluation."""
    from sb3_coma.app.training import VALIDATION_SEED

    config = write_config(tmp_path)
    _, run = train(
        env="env1", config=config, seed=0, run_dir=tmp_path / "run", eval_freq=16, eval_missions=2, **quiet()
    )
    data = np.load(run / "eval" / "evaluations.npz")
    assert list(data["timesteps"]) == [16, 32]
    assert data["results"].shape == (2, 2 * 2)  # 2 missions x 2 UAV rows per evaluation
    best = validate_checkpoint(run / "best_model.zip").num_timesteps
    assert best == int(data["timesteps"][int(np.argmax(data["results"].mean(axis=1)))])
    assert VALIDATION_SEED == 1000
    with pytest.raises(TrainingError, match="eval_missions must be an integer >= 1, got 0"):
        train(env="env1", config=config, seed=0, run_dir=tmp_path / "run2", eval_freq=16, eval_missions=0, **quiet())


def test_numbers_written_without_a_dot_are_numbers_and_inf_is_refused_up_front(tmp_path):
    """PyYAML reads `1e-4` as a string: the config format accepts it as the number people mean;
    an infinite learning rate is refused before anything is built, naming the value."""
    from sb3_coma.app.config import coma_kwargs

    kwargs = coma_kwargs({"learning_rate": "1e-4", "critic_learning_rate": "3E-3", "policy": "UavCnnPolicy"})
    assert kwargs["learning_rate"] == 1e-4 and kwargs["critic_learning_rate"] == 3e-3
    assert coma_kwargs({"policy": "UavCnnPolicy", "advantage": "q"})["advantage"] == "q"  # words stay words
    with pytest.raises((ValueError, TrainingError), match="learning_rate must be a finite positive number, got inf"):
        train(
            env="env1",
            config=write_config(tmp_path),
            overrides={"learning_rate": float("inf")},
            run_dir=tmp_path / "run",
            progress_bar=False,
            verbose=0,
        )
    assert not (tmp_path / "run").exists()  # refused before the run folder was made


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"eval_freq": -5}, "eval_freq must be an integer >= 0"),
        ({"save_freq": -1}, "save_freq must be an integer >= 0"),
        ({"eval_seed": -3}, "eval_seed must be an integer >= 0"),
    ],
)
def test_negative_frequencies_and_seeds_are_refused_before_anything_is_made(tmp_path, kwargs, match):
    with pytest.raises(TrainingError, match=match):
        train(
            env="env1", config=write_config(tmp_path), run_dir=tmp_path / "run", progress_bar=False, verbose=0, **kwargs
        )
    assert not (tmp_path / "run").exists()


# ----------------------------------------------------------------------------- resume: same world
def _edit_config(run: Path, edit) -> None:
    """Edit a run's config.yml by hand, as a user would."""
    data = yaml.safe_load((run / "config.yml").read_text())
    edit(data)
    (run / "config.yml").write_text(yaml.safe_dump(data, sort_keys=False))


def test_resume_refuses_a_change_of_world_unless_allowed_and_records_it(tmp_path):
    config = write_config(tmp_path)
    _, run = train(env="env1", config=config, seed=0, run_dir=tmp_path / "run", total_timesteps=8, **quiet())
    saved = yaml.safe_load((run / "config.yml").read_text())
    assert saved["run"]["settings"] == {k: v for k, v in saved[ENV].items() if k != "n_timesteps"}

    _edit_config(run, lambda d: d[ENV]["env_kwargs"].update(noise="loud"))  # by hand, after the start
    edited = (run / "config.yml").read_text()
    with pytest.raises(TrainingError) as info:
        train(resume=run, total_timesteps=16, **quiet())
    message = str(info.value)
    assert "env_kwargs.noise from 'moderate' to 'loud' (config.yml was edited after the run started)" in message
    assert "--allow-change" in message and "\n" not in message
    with pytest.raises(TrainingError, match=r"n_envs from 1 to 2 \(--n-envs\)"):
        train(resume=run, n_envs=2, total_timesteps=16, **quiet())
    assert (run / "config.yml").read_text() == edited
    assert validate_checkpoint(run / "model.zip").num_timesteps == 8  # nothing trained

    model, _ = train(resume=run, total_timesteps=16, allow_change=True, **quiet())
    assert model.num_timesteps == 16 and training_options(run / "model.zip")["noise"] == "loud"
    saved = yaml.safe_load((run / "config.yml").read_text())
    assert saved["run"]["resumes"][-1]["changes"] == {"env_kwargs.noise": {"from": "moderate", "to": "loud"}}
    assert saved["run"]["settings"]["env_kwargs"]["noise"] == "loud"  # the next resume compares with this
    model, _ = train(resume=run, total_timesteps=24, **quiet())  # no change now: no flag needed
    assert model.num_timesteps == 24
    assert "changes" not in yaml.safe_load((run / "config.yml").read_text())["run"]["resumes"][-1]


def test_resume_refuses_a_hand_edit_the_checkpoint_would_ignore(tmp_path, capsys):
    config = write_config(tmp_path)
    _, run = train(env="env1", config=config, seed=0, run_dir=tmp_path / "run", total_timesteps=8, **quiet())
    _edit_config(run, lambda d: d[ENV].update(learning_rate=1.0e-3))
    for allow in (False, True):  # the checkpoint keeps its own learning rate: --allow-change cannot help
        with pytest.raises(
            TrainingError, match=r"learning_rate from 0.0001 to 0.001 .*which the checkpoint keeps as it was saved"
        ):
            train(resume=run, allow_change=allow, **quiet())
    assert cli.main(["train", "--resume", str(run), "--allow-change"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sb3-coma train: error: --resume") and "learning_rate" in err and "\n" not in err


def test_resume_of_a_run_without_a_settings_copy_compares_with_the_checkpoint(tmp_path, capsys):
    """Runs started before the record kept a copy: the env options saved in the checkpoint tell."""
    config = write_config(tmp_path)
    _, run = train(env="env1", config=config, seed=0, run_dir=tmp_path / "run", total_timesteps=8, **quiet())

    def legacy_and_loud(data: dict) -> None:
        del data["run"]["settings"]
        data[ENV]["env_kwargs"]["noise"] = "loud"

    _edit_config(run, legacy_and_loud)
    assert cli.main(["train", "--resume", str(run), "--no-progress", "-v", "0"]) == 2
    err = capsys.readouterr().err.strip()
    assert "env_kwargs.noise from 'moderate' to 'loud' (the checkpoint recorded another env)" in err
    assert cli.main(["train", "--resume", str(run), "--allow-change", "--no-progress", "-v", "0"]) == 0


def test_save_freq_zero_means_no_checkpoints_by_one_rule(tmp_path):
    """``save_freq`` has one rule everywhere: an integer >= 0, 0 = no checkpoints."""
    run = tmp_path / "run0"
    train(ENV, config=write_config(tmp_path), run_dir=run, save_freq=0, seed=0, **quiet())
    assert (run / "model.zip").is_file() and not find_checkpoints(run / "checkpoints")
    with pytest.raises(TrainingError, match="save_freq must be an integer >= 0"):
        train(ENV, config=write_config(tmp_path), run_dir=tmp_path / "run1", save_freq=-1, **quiet())


def test_resume_from_an_older_checkpoint_is_refused_in_place_and_forks_with_fork(tmp_path):
    """Resuming in place from a checkpoint older than the run's newest would replace model.zip, cut
    metrics.csv and leave the next resume on the other branch: refused; --fork continues it in a new
    run folder that names its parent, and the parent is not touched."""
    config = write_config(tmp_path)
    _, run = train(env="env1", config=config, seed=0, run_dir=tmp_path / "run", save_freq=16, **quiet())
    older = find_checkpoints(run / "checkpoints")[0][1]
    parent_model, parent_rows = digest(run / "model.zip"), len(metric_rows(run))
    with pytest.raises(TrainingError, match=r"already reached 40 \(model\.zip\).*fork the run's history.*--fork"):
        train(resume=older, **quiet())
    assert digest(run / "model.zip") == parent_model and len(metric_rows(run)) == parent_rows
    forked, branch = train(resume=older, fork=True, run_dir=tmp_path / "branch", total_timesteps=32, **quiet())
    assert branch == tmp_path / "branch" and forked.num_timesteps == 32
    record = yaml.safe_load((branch / "config.yml").read_text())["run"]
    assert record["forked_from"] == str(run) and record["resumed_from"] == str(older)
    assert digest(run / "model.zip") == parent_model and len(metric_rows(run)) == parent_rows
    # the newest checkpoint itself is no fork: it resumes in place as before
    _, again = train(resume=run / "model.zip", total_timesteps=48, **quiet())
    assert again == run


def test_one_rule_per_count_for_train_and_the_cli(tmp_path, capsys):
    """``sb3-coma train --save-freq 0`` means what ``train(save_freq=0)`` means (no checkpoints),
    and a bad count is refused by the same rule, naming the flag or the argument."""
    config = str(write_config(tmp_path))
    argv = ["train", "--env", "env1", "--config", config, "--timesteps", "8", "--seed", "1", "--no-progress"]
    assert cli.main([*argv, "--save-freq", "0", "--run-dir", str(tmp_path / "cli")]) == 0
    assert not find_checkpoints(tmp_path / "cli" / "checkpoints")
    assert cli.main([*argv, "--save-freq", "-1", "--run-dir", str(tmp_path / "bad")]) == 2
    assert "--save-freq must be an integer >= 0 (0: none) in joint steps, got -1" in capsys.readouterr().err
    with pytest.raises(TrainingError, match=r"^save_freq must be an integer >= 0 \(0: none\) in joint steps, got -1$"):
        train(env="env1", config=config, seed=0, run_dir=tmp_path / "py", save_freq=-1, **quiet())
