"""Reliability v3: bad input is one line (exit 2) naming the culprit, good input works.

Every case goes through a front door: ``sb3_coma.cli.main([...])`` with the captured stderr, the
config loader (``sb3_coma.app.config.load_config``) or ``sb3_coma.evaluate``; none through an
inner helper alone. The cases:

1. shipped SenDFuse weights and shipped models are verified whatever path leads to them;
2. a model flown with other observation options is refused, in another world warned about;
   ``export --fusion`` must match the model's;
3. training on ``split="test"`` needs ``--allow-test-split`` and is recorded;
4. numbers in exponent notation (``1e-4``, ``1e2``) work in YAML, ``--set`` and ``--timesteps``;
5. path options are checked before any work (a non-UTF-8 name, a file where a folder goes);
6. conflicting or ignored options (reward pair, maps or arms twice, one-mission verdicts).
"""

from __future__ import annotations

import os
import shutil
import sys
import warnings
from pathlib import Path

import pytest
import yaml

import uav_ipp
from sb3_coma import COMA, evaluate
from sb3_coma.app import evaluation as ev
from sb3_coma.app import pretrained
from sb3_coma.app.config import TrainingError, load_config, resolve_world
from sb3_coma.app.training import record_env_options
from sb3_coma.cli import main
from sb3_coma.common.checkpoints import atomic_save
from sb3_coma.sendfuse import SenDFuseConfig, SenDFuseNet, SenDFuseWeightsError, save_weights
from sb3_coma.sendfuse import weights as weights_mod
from uav_ipp import ConfigError

ENV_ID = "UavIpp-Env1-v0"
TINY = {
    ENV_ID: {
        "n_timesteps": 8,
        "n_envs": 1,
        "policy": "UavCnnPolicy",
        "policy_kwargs": {"features_extractor_kwargs": {"features_dim": 16}},
        "batch_size": 8,
        "env_kwargs": {"fusion": "mean", "n_uavs": 2, "budget": 4, "noise": "moderate"},
    }
}
#: A file name whose bytes are not valid UTF-8, as Python hands it over from the command line.
BAD_NAME = os.fsdecode(b"bad\xff")
SHIPPED = (pretrained.pretrained_dir() / pretrained.MANIFEST).is_file()
needs_shipped = pytest.mark.skipif(not SHIPPED, reason="no shipped models")


@pytest.fixture(scope="module")
def tiny_config(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("config") / "tiny.yml"
    path.write_text(yaml.safe_dump(TINY))
    return path


@pytest.fixture(scope="module")
def mean_zip(tmp_path_factory) -> Path:
    """A COMA zip that records its training env (env1, 2 UAVs, budget 4, mean fusion)."""
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", n_uavs=2, budget=4)
    model = COMA(
        "UavCnnPolicy", venv, batch_size=8, seed=0, policy_kwargs={"features_extractor_kwargs": {"features_dim": 16}}
    )
    record_env_options(model, resolve_world("UavIpp-Env1-v0", {"fusion": "mean", "n_uavs": 2, "budget": 4}, "test"))
    path = atomic_save(model, tmp_path_factory.mktemp("models") / "coma_mean.zip")
    venv.close()
    return path


def run_cli(argv: list[str], capsys) -> tuple[int, list[str]]:
    """``sb3-coma ARGV``: exit status and the stderr lines."""
    capsys.readouterr()
    rc = main(argv)
    return rc, capsys.readouterr().err.strip().splitlines()


def refused(argv: list[str], capsys, *needles: str) -> str:
    """``sb3-coma ARGV`` exits 2 with one stderr line naming every needle; returns that line."""
    rc, lines = run_cli(argv, capsys)
    assert rc == 2, (argv, lines)
    assert len(lines) == 1 and lines[0].startswith(f"sb3-coma {argv[0]}: error: "), lines
    assert "Traceback" not in lines[0]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# =========================================================================== 1. verified files
def test_replaced_shipped_weights_are_refused_whatever_the_path(tmp_path, monkeypatch, capsys):
    package = tmp_path / "package"
    package.mkdir()
    shutil.copyfile(weights_mod.default_weights_path(), package / "sendfuse_r44.safetensors")
    monkeypatch.setattr(weights_mod, "shipped_weights_dir", lambda: package.resolve())
    uav_ipp.make_vec_env("env1", fusion="sendfuse", n_uavs=2, budget=2).close()  # the intact copy is fine

    other = SenDFuseNet.from_config(SenDFuseConfig(grid_size=44, channels=(4, 4, 4)))
    save_weights(other, package / "sendfuse_r44.safetensors")  # a valid file, but not the shipped one
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "link.safetensors").symlink_to(package / "sendfuse_r44.safetensors")
    for fusion_kwargs in (
        None,  # the wrapper's default path
        {"weights": str(package / ".." / "package" / "sendfuse_r44.safetensors")},
        {"weights": str(tmp_path / "elsewhere" / "link.safetensors")},
    ):
        with pytest.raises(SenDFuseWeightsError, match="do not match their recorded SHA-256"):
            uav_ipp.make_vec_env("env1", fusion="sendfuse", n_uavs=2, budget=2, fusion_kwargs=fusion_kwargs)

    mine = tmp_path / "mine.safetensors"  # the user's own copy elsewhere is not the shipped file
    shutil.copyfile(package / "sendfuse_r44.safetensors", mine)
    uav_ipp.make_vec_env("env1", fusion="sendfuse", n_uavs=2, budget=2, fusion_kwargs={"weights": str(mine)}).close()

    if SHIPPED:  # evaluating a SenDFuse model builds such an env: one line, nothing flown
        argv = ["evaluate", "--methods", "", "--model", "env1", "--env", "env1", "--uavs", "2", "--budget", "2"]
        out = tmp_path / "results"
        refused([*argv, "--trials", "1", "--no-plots", "--out", str(out)], capsys, "sendfuse_r44", "SHA-256")
        assert not (out / "table.csv").exists()


@needs_shipped
def test_a_replaced_shipped_model_is_refused_by_its_path(tmp_path, monkeypatch, capsys):
    package = tmp_path / "pretrained"
    package.mkdir()
    shutil.copyfile(pretrained.pretrained_dir() / pretrained.MANIFEST, package / pretrained.MANIFEST)
    shutil.copyfile(pretrained.pretrained_dir() / "coma_env2.zip", package / "coma_env1.zip")  # replaced
    monkeypatch.setattr(pretrained, "pretrained_dir", lambda: package.resolve())
    zip_path = str(package / "coma_env1.zip")
    evaluate_argv = ["evaluate", "--methods", "", "--env", "env1", "--trials", "1", "--no-plots"]
    refused([*evaluate_argv, "--model", zip_path, "--out", str(tmp_path / "r")], capsys, "coma_env1.zip", "checksum")
    refused([*evaluate_argv, "--model", "env1", "--out", str(tmp_path / "r")], capsys, "checksum mismatch")
    refused(["export", "--model", zip_path, "--out", str(tmp_path / "onnx")], capsys, "coma_env1.zip", "checksum")
    refused(["train", "--resume", zip_path, "--run-dir", str(tmp_path / "run")], capsys, "coma_env1.zip", "checksum")
    assert not (tmp_path / "r").exists() and not (tmp_path / "onnx").exists() and not (tmp_path / "run").exists()

    mine = tmp_path / "mine" / "coma_env1.zip"  # the same bytes elsewhere: the user's own model
    mine.parent.mkdir()
    shutil.copyfile(package / "coma_env1.zip", mine)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # flown with 2 UAVs and budget 2: warned, legal
        result = evaluate(str(mine), env="env1", n_trials=1, n_uavs=2, budget=2)
    assert result.f1.shape == (1, 3)


# =========================================================================== 2. another world
def test_a_model_is_not_flown_with_another_observation(mean_zip, monkeypatch):
    def no_env(*args, **kwargs):
        raise AssertionError("an env was built before the options were checked")

    monkeypatch.setattr(ev.uav_ipp, "make_vec_env", no_env)
    with pytest.raises(ValueError, match=r"trained with lattice=11 but is asked to fly with lattice=9"):
        evaluate(str(mean_zip), env="env1", n_trials=1, n_uavs=2, lattice=9)
    with pytest.raises(ValueError, match=r"action_gain=True but is asked to fly with action_gain=False"):
        evaluate(str(mean_zip), env="env1", n_trials=1, n_uavs=2, action_gain=False)
    with pytest.raises(ValueError, match=r"altitudes=\[5.0, 10.0, 15.0\].*altitudes=\(5.0, 10.0\)"):
        evaluate(str(mean_zip), env="env1", n_trials=1, n_uavs=2, altitudes=(5.0, 10.0))


def test_a_model_flown_in_another_world_is_one_warning(mean_zip, tmp_path, capsys):
    argv = ["evaluate", "--methods", "", "--model", str(mean_zip), "--fusion", "mean", "--env", "env1"]
    argv += ["--uavs", "2", "--trials", "1", "--no-plots", "--out", str(tmp_path / "r")]
    with pytest.warns(ev.WorldMismatchWarning) as caught:
        rc, _ = run_cli([*argv, "--budget", "2", "--noise", "loud"], capsys)
    assert rc == 0
    (message,) = [str(w.message) for w in caught if issubclass(w.category, ev.WorldMismatchWarning)]
    assert "budget=2 (trained: 4)" in message and "noise='loud' (trained: 'moderate')" in message
    assert "\n" not in message
    with warnings.catch_warnings(record=True) as as_trained:
        warnings.simplefilter("always")
        assert run_cli([*argv, "--budget", "4"], capsys)[0] == 0  # flown as trained: nothing to say
    assert not [w for w in as_trained if issubclass(w.category, ev.WorldMismatchWarning)]


def test_export_refuses_a_fusion_the_model_was_not_trained_with(mean_zip, tmp_path, capsys):
    out = tmp_path / "onnx"
    argv = ["export", "--model", str(mean_zip), "--out", str(out), "--fusion", "sendfuse"]
    refused(argv, capsys, "--fusion sendfuse", "'mean'", "must not claim")
    refused(["export", "--model", str(mean_zip), "--out", str(out), "--opset", "99"], capsys, "--opset 99", "17 to")
    assert not out.exists()


@needs_shipped
def test_noise_sweep_refuses_another_map_family_repeated_arms_and_one_mission(tmp_path, capsys):
    out = str(tmp_path / "sweep")
    refused(["noise-sweep", "--quick", "--env", "env3", "--arms", "env1", "--out", out], capsys, "env1", "env3")
    refused(["noise-sweep", "--quick", "--env", "env1", "--arms", "ag,adaptive_gain", "--out", out], capsys, "twice")
    argv = ["noise-sweep", "--env", "env1", "--arms", "ag,env1", "--missions", "1", "--out", out]
    refused(argv, capsys, "n_missions=1", "at least 2")
    assert not Path(out).exists()


# =========================================================================== 3. the test split
def test_training_on_the_test_split_needs_the_flag_and_is_recorded(tiny_config, tmp_path, capsys):
    run = tmp_path / "run"
    train = ["train", "--env", "env1", "--config", str(tiny_config), "--no-progress", "-v", "0"]
    refused([*train, "--set", "env_kwargs.split=test", "--run-dir", str(run)], capsys, "split='test'", "--allow-test")
    refused([*train, "--allow-test-split", "--run-dir", str(run)], capsys, "is ignored", "split='paper'")
    assert not run.exists()
    entry = {**TINY[ENV_ID], "env_kwargs": {**TINY[ENV_ID]["env_kwargs"], "split": "test"}}
    config = tmp_path / "test_split.yml"
    config.write_text(yaml.safe_dump({ENV_ID: entry}))
    with pytest.raises(TrainingError, match="--allow-test-split"):
        load_config("env1", config)  # a config entry, not only --set
    assert load_config("env1", config, overrides={"env_kwargs.allow_test_split": True}).env_kwargs["split"] == "test"

    rc, lines = run_cli([*train, "--set", "env_kwargs.split=test", "--allow-test-split", "--run-dir", str(run)], capsys)
    assert rc == 0, lines
    recorded = yaml.safe_load((run / "config.yml").read_text())[ENV_ID]["env_kwargs"]
    assert recorded["split"] == "test" and recorded["allow_test_split"] is True
    refused(["train", "--resume", str(run), "--allow-test-split"], capsys, "--allow-test-split", "--resume")


# =========================================================================== 4. numbers
def test_numbers_in_exponent_notation_through_the_config_loader(tmp_path):
    config = tmp_path / "numbers.yml"
    config.write_text(
        f"{ENV_ID}:\n  n_timesteps: 1e2\n  n_steps: 8.0\n  learning_rate: 1e-4\n  critic_learning_rate: 1.0e3\n"
        "  policy: UavCnnPolicy\n  env_kwargs: {fusion: mean, n_uavs: 2e0, budget: 4, sigma: 1e-1}\n"
    )
    assert isinstance(yaml.safe_load(config.read_text())[ENV_ID]["learning_rate"], str)  # PyYAML's reading
    entry = load_config("env1", config).entry
    assert entry["learning_rate"] == 1e-4 and entry["critic_learning_rate"] == 1000.0
    assert entry["n_timesteps"] == 100 and isinstance(entry["n_timesteps"], int)
    assert entry["n_steps"] == 8 and isinstance(entry["n_steps"], int)
    assert entry["env_kwargs"]["sigma"] == 0.1 and entry["env_kwargs"]["n_uavs"] == 2
    with pytest.raises(TrainingError, match=r"n_timesteps must be a whole number, got 10.05"):
        load_config("env1", config, overrides={"n_timesteps": "1.005e1"})
    with pytest.raises(TrainingError, match=r"env_kwargs.budget must be a whole number, got 4.5"):
        load_config("env1", config, overrides={"env_kwargs.budget": "4.5e0"})
    assert load_config("env1", config, overrides={"advantage": "q"}).entry["advantage"] == "q"  # words stay words


def test_numbers_in_exponent_notation_through_the_cli(tiny_config, tmp_path, capsys):
    run = tmp_path / "run"
    train = ["train", "--env", "env1", "--config", str(tiny_config), "--no-progress", "-v", "0", "--run-dir", str(run)]
    refused([*train, "--set", "n_timesteps=1.005e1"], capsys, "n_timesteps must be a whole number, got 10.05")
    assert not run.exists()
    sets = ["learning_rate=1e-4", "env_kwargs.sigma=1e-1", "n_steps=8e0", "critic_learning_rate=1e-3"]
    rc, lines = run_cli([*train, "--timesteps", "1.6e1", *[a for s in sets for a in ("--set", s)]], capsys)
    assert rc == 0, lines
    entry = yaml.safe_load((run / "config.yml").read_text())[ENV_ID]
    assert entry["learning_rate"] == 1e-4 and entry["critic_learning_rate"] == 1e-3 and entry["n_steps"] == 8
    assert entry["n_timesteps"] == 16 and entry["env_kwargs"]["sigma"] == 0.1


# =========================================================================== 5. paths
@pytest.mark.skipif(sys.getfilesystemencoding().lower() not in ("utf-8", "utf8"), reason="a UTF-8 file system")
def test_path_options_are_checked_before_any_work(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    quick = ["--trials", "1", "--no-plots"]
    cases = [
        ["evaluate", "--methods", "random", *quick, "--out", BAD_NAME],
        ["evaluate", "--methods", "", "--model", BAD_NAME, *quick],
        ["train", "--env", "env1", "--run-dir", BAD_NAME],
        ["export", "--model", "env1", "--out", BAD_NAME],
        ["export", "--model", BAD_NAME, "--out", "onnx"],
        ["noise-sweep", "--quick", "--arms", "ag", "--out", BAD_NAME],
        ["reproduce", "--quick", "--out", BAD_NAME],
    ]
    for argv in cases:
        refused(argv, capsys, "bad\\udcff", "not valid utf-8 text")
    refused(["noise-sweep", "--quick", "--arms", "ag", "--out", "a_file"], capsys, "a_file is a file")
    refused(["reproduce", "--quick", "--out", "a_file/sub"], capsys, "its parent a_file is a file")
    refused(["reproduce", "--quick", "--docs", str(tmp_path)], capsys, "--docs", "is a folder, not a file")
    (tmp_path / "a_run").mkdir()
    refused(["evaluate", "--methods", "", "--model", "a_run", *quick], capsys, "'a_run' is a folder", "model.zip")
    assert sorted(os.listdir(tmp_path)) == ["a_file", "a_run"]  # nothing was made


# =========================================================================== 6. conflicts
def test_a_reward_option_the_reward_ignores_is_refused(tiny_config, capsys):
    with pytest.raises(ConfigError, match=r"reward_entropy='weighted': not with reward='metrics'"):
        uav_ipp.make_env("env1", reward="metrics", reward_entropy="weighted")
    uav_ipp.make_env("env1", reward="entropy", reward_entropy="weighted")  # the reward it shapes
    argv = ["train", "--env", "env1", "--config", str(tiny_config), "--set", "env_kwargs.reward=metrics"]
    refused([*argv, "--set", "env_kwargs.reward_entropy=weighted"], capsys, "reward_entropy='weighted'", "'metrics'")


def test_each_map_once_and_no_count_that_makes_every_verdict_nan(tmp_path, capsys):
    out = str(tmp_path / "r")
    evaluate_argv = ["evaluate", "--methods", "random", "--trials", "1", "--out", out]
    refused([*evaluate_argv, "--env", "env1,UavIpp-Env1-v0"], capsys, "'UavIpp-Env1-v0' twice")
    refused(["reproduce", "--quick", "--env", "env2,Env2", "--out", out], capsys, "'Env2' twice")
    for flag in ("--trials", "--unseen-missions", "--sweep-missions"):
        refused(["reproduce", "--quick", flag, "1", "--out", out], capsys, f"{flag} 1", "at least 2 missions")
    assert not Path(out).exists()
