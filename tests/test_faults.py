"""Faults: a training run killed with SIGKILL resumes from its last checkpoint; checkpoints are
written atomically (a crash mid-write never replaces a good file); truncated checkpoints are
refused; NaN in a loss stops training instead of saving a broken model.

The SIGKILL run is a real ``python -m sb3_coma.cli train`` subprocess on env1 with 2 UAVs,
budget 4, the config's ``mean-cnn`` variant (mean fusion) and a checkpoint every rollout
(8 joint steps). A throttle callback (active only while ``SB3_COMA_TEST_THROTTLE`` is set)
slows the first run down so that the kill always lands mid-run, whatever the machine's speed.
"""

from __future__ import annotations

import csv
import hashlib
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from sb3_coma import cli
from sb3_coma.common.checkpoints import (
    CheckpointError,
    atomic_save,
    find_checkpoints,
    last_checkpoint,
    validate_checkpoint,
)

REPO = Path(__file__).resolve().parent.parent
ENV_ID = "UavIpp-Env1-v0"
TOTAL = 96  # joint steps: 12 rollouts of 8, 24 missions of 4
SAVE_FREQ = 8  # one rollout (batch_size 8, one env copy -> n_steps 8)
SMALL_CNN = {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}}
CONFIG = {
    ENV_ID: {
        "n_timesteps": TOTAL,
        "n_envs": 1,
        "policy": "CBAMPolicy",
        "policy_kwargs": SMALL_CNN,
        "learning_rate": 1.0e-4,
        "critic_learning_rate": 1.0e-3,
        "batch_size": 8,
        "env_kwargs": {"fusion": "sendfuse", "n_uavs": 2, "budget": 4, "noise": "moderate"},
        "callback": ["throttle.Throttle"],
    },
    "variants": {"mean-cnn": {"policy": "UavCnnPolicy", "env_kwargs": {"fusion": "mean"}}},
}
THROTTLE = '''
import os
import time

from stable_baselines3.common.callbacks import BaseCallback


class Throttle(BaseCallback):
    """Sleep SB3_COMA_TEST_THROTTLE seconds per joint step (no-op when unset)."""

    def _on_step(self) -> bool:
        delay = float(os.environ.get("SB3_COMA_TEST_THROTTLE", "0") or 0)
        if delay:
            time.sleep(delay)
        return True
'''


def _env(tmp_path: Path, throttle: float | None) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["OMP_NUM_THREADS"] = "1"  # tiny networks: threads only add contention
    env["MKL_NUM_THREADS"] = "1"
    env.pop("SB3_COMA_TEST_THROTTLE", None)
    if throttle:
        env["SB3_COMA_TEST_THROTTLE"] = str(throttle)
    return env


def _steps(folder: Path) -> list[int]:
    return [s for s, _ in find_checkpoints(folder)]


def _metric_steps(run: Path) -> list[int]:
    with (run / "metrics.csv").open(newline="") as handle:
        return [int(r["timesteps"]) for r in csv.DictReader(handle)]


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def single_thread():
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# ----------------------------------------------------------------------------- SIGKILL + resume
def _kill_after_two_checkpoints(tmp_path: Path, run: Path, command: list[str]) -> int:
    """Start the throttled training, SIGKILL it once two checkpoints exist; its return code."""
    log = (tmp_path / "first.log").open("wb")
    proc = subprocess.Popen(
        command, cwd=tmp_path, env=_env(tmp_path, throttle=0.03), stdout=log, stderr=subprocess.STDOUT
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if [s for s in _steps(run / "checkpoints") if s >= 2 * SAVE_FREQ]:
                break
            time.sleep(0.005)
        assert proc.poll() is None, f"training ended before it could be killed:\n{(tmp_path / 'first.log').read_text()}"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
    return proc.returncode


def test_sigkill_mid_run_resumes_from_last_checkpoint(tmp_path):
    (tmp_path / "throttle.py").write_text(THROTTLE)
    config = tmp_path / "faults.yml"
    config.write_text(yaml.safe_dump(CONFIG, sort_keys=False))
    run = tmp_path / "run"
    command = [
        sys.executable,
        "-m",
        "sb3_coma.cli",
        "train",
        "--env",
        "env1",
        "--config",
        str(config),
        "--variant",
        "mean-cnn",
        "--seed",
        "0",
        "--run-dir",
        str(run),
        "--save-freq",
        str(SAVE_FREQ),
        "--no-progress",
        "-v",
        "0",
    ]
    assert _kill_after_two_checkpoints(tmp_path, run, command) == -signal.SIGKILL

    # What a hard kill leaves behind: no final model, only complete checkpoints under their
    # names (at worst a hidden .tmp file from a save in progress), progress past the last one.
    assert not (run / "model.zip").exists()
    steps = _steps(run / "checkpoints")
    for _, path in find_checkpoints(run / "checkpoints"):
        assert validate_checkpoint(path).num_timesteps == int(re.search(r"_(\d+)_steps", path.name).group(1))
    last = max(steps)
    assert 2 * SAVE_FREQ <= last < TOTAL and last % SAVE_FREQ == 0
    reached = max(_metric_steps(run))  # metrics.csv is flushed per mission
    assert reached - last <= SAVE_FREQ, f"killed at {reached} joint steps, last checkpoint {last}"

    # Resume: from the newest checkpoint, to exactly the requested total, same run folder.
    done = subprocess.run(
        [sys.executable, "-m", "sb3_coma.cli", "train", "--resume", str(run), "--no-progress", "-v", "1"],
        cwd=tmp_path,
        env=_env(tmp_path, throttle=None),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"at {last} joint steps" in done.stdout
    assert validate_checkpoint(run / "model.zip").num_timesteps == TOTAL
    saved = yaml.safe_load((run / "config.yml").read_text())
    assert saved["run"]["resumes"][0]["at"] == last
    assert saved[ENV_ID]["env_kwargs"]["fusion"] == "mean" and saved["run"]["variant"] == "mean-cnn"
    # Missions flown after the checkpoint were dropped and flown again: one row per mission.
    assert _metric_steps(run) == [4 * (k + 1) for k in range(TOTAL // 4)]
    assert max(_steps(run / "checkpoints")) == TOTAL

    # A truncated copy of a checkpoint of this run is refused with one line, no traceback.
    truncated = tmp_path / "truncated.zip"
    data = (run / "model.zip").read_bytes()
    truncated.write_bytes(data[: len(data) * 2 // 3])
    with pytest.raises(CheckpointError, match=r"truncated.zip is (unusable|truncated|corrupt)"):
        validate_checkpoint(truncated)
    assert cli.main(["train", "--resume", str(truncated)]) == 2


# ----------------------------------------------------------------------------- atomic writes
@pytest.fixture(scope="module")
def tiny_model():
    import torch

    import uav_ipp
    from sb3_coma import COMA

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", n_uavs=2, budget=4)
    model = COMA("UavCnnPolicy", venv, batch_size=8, seed=0, policy_kwargs=SMALL_CNN)
    yield model
    venv.close()
    torch.set_num_threads(threads)


def test_crash_mid_write_keeps_the_previous_checkpoint(tmp_path, tiny_model, monkeypatch):
    target = tmp_path / "checkpoints" / "rl_model_16_steps.zip"
    atomic_save(tiny_model, target)
    good = _digest(target)
    real_save = type(tiny_model).save

    def crash_half_way(self, path, *args, **kwargs):
        """Write the first half of a real checkpoint into the temporary file, then fail."""
        buffer = __import__("io").BytesIO()
        real_save(self, buffer, *args, **kwargs)
        path.write(buffer.getvalue()[: len(buffer.getvalue()) // 2])
        path.flush()
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(type(tiny_model), "save", crash_half_way)
    with pytest.raises(OSError, match=r"(?i)no space left"):
        atomic_save(tiny_model, target)
    assert _digest(target) == good and validate_checkpoint(target)
    assert sorted(p.name for p in target.parent.iterdir()) == [target.name]  # the partial temp file is gone

    # A hard crash (no cleanup: the process dies inside the write) leaves the partial temporary
    # file behind, never a partial file under the checkpoint's name; discovery and resume skip it.
    monkeypatch.setattr(Path, "unlink", lambda self, missing_ok=False: None)
    with pytest.raises(OSError):
        atomic_save(tiny_model, target)
    monkeypatch.undo()
    leftovers = [p for p in target.parent.iterdir() if p != target]
    assert len(leftovers) == 1 and leftovers[0].name.startswith(f".{target.name}.") and leftovers[0].suffix == ".tmp"
    assert _digest(target) == good
    assert find_checkpoints(target.parent) == [(16, target)]
    assert last_checkpoint(target.parent) == target


def test_crash_before_replace_keeps_the_final_model(tmp_path, tiny_model, monkeypatch):
    """The written temp file is complete and valid, but the process fails before ``os.replace``."""
    target = tmp_path / "model.zip"
    atomic_save(tiny_model, target)
    good = _digest(target)

    def no_replace(src, dst):
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "replace", no_replace)
    with pytest.raises(OSError, match="Input/output error"):
        atomic_save(tiny_model, target)
    monkeypatch.undo()
    assert _digest(target) == good
    assert [p.name for p in tmp_path.iterdir()] == ["model.zip"]


def test_truncated_checkpoint_is_refused_with_a_clear_error(tmp_path, tiny_model, capsys):
    from sb3_coma.app.runs import load_checkpoint

    path = atomic_save(tiny_model, tmp_path / "rl_model_8_steps.zip")
    data = path.read_bytes()
    for keep in (0, 100, len(data) // 2, len(data) - 50):
        broken = tmp_path / f"cut_{keep}.zip"
        broken.write_bytes(data[:keep])
        with pytest.raises(CheckpointError, match=rf"cut_{keep}.zip is (unusable|truncated|corrupt)"):
            load_checkpoint(broken)
        capsys.readouterr()
        assert cli.main(["train", "--resume", str(broken)]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("sb3-coma train: error: checkpoint ") and f"cut_{keep}.zip" in err
        assert len(err.splitlines()) == 1 and "Traceback" not in err


# ----------------------------------------------------------------------------- NaN in a loss
def test_nan_in_a_loss_stops_training_without_saving_a_model(tmp_path, single_thread, monkeypatch):
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_coma.app.training import train

    class PoisonCritic(BaseCallback):
        """Set one critic weight to NaN before the first update: the critic loss becomes NaN."""

        def _on_rollout_end(self) -> None:
            with torch.no_grad():
                next(self.model.policy.critic.parameters()).view(-1)[0] = math.nan

        def _on_step(self) -> bool:
            return True

    monkeypatch.chdir(tmp_path)
    config = tmp_path / "nan.yml"
    config.write_text(yaml.safe_dump({ENV_ID: {k: v for k, v in CONFIG[ENV_ID].items() if k != "callback"}}))
    run = tmp_path / "run"
    with pytest.raises(Exception, match=r"(?i)\bnan\b|non-finite|not finite") as info:
        train(
            env="env1",
            config=config,
            overrides={"env_kwargs.fusion": "mean", "policy": "UavCnnPolicy"},
            total_timesteps=SAVE_FREQ,
            seed=0,
            run_dir=run,
            save_freq=SAVE_FREQ,
            callbacks=[PoisonCritic()],
            progress_bar=False,
            verbose=0,
            handle_signals=False,
        )
    assert "loss" in str(info.value).lower()
    assert not (run / "model.zip").exists()
    assert not list((run / "checkpoints").glob("*.zip"))
