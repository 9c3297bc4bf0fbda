"""One writer per run folder: ``RUN/.lock`` (``flock``) is held by the training process for the
whole run and dropped by the OS when it dies.

The two-process test runs a real ``python -m sb3_coma.cli train`` subprocess (the tiny config of
``tests/tiny_runs.py``, slowed by a throttle callback so it is still training when the test acts)
and, from this process, a second ``train --resume`` and a second ``train --run-dir`` into the same
folder: both are refused with one line naming the first process, and the folder is not touched.
After a SIGKILL of the first the lock is free and the resume works.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from tiny_runs import ENV, tiny_entry

from sb3_coma import cli
from sb3_coma.app.outputs import LOCK_FILE, FolderInUseError, FolderLock, lock_holder
from sb3_coma.app.training import TrainingError, train
from sb3_coma.common.checkpoints import find_checkpoints, validate_checkpoint

REPO = Path(__file__).resolve().parent.parent
TOTAL = 64  # joint steps: 8 rollouts of 8
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


def _config(folder: Path, throttled: bool) -> Path:
    entry = {**tiny_entry(), "n_timesteps": TOTAL}
    if throttled:
        (folder / "throttle.py").write_text(THROTTLE)
        entry["callback"] = ["throttle.Throttle"]
    path = folder / "tiny.yml"
    path.write_text(yaml.safe_dump({ENV: entry}))
    return path


def _env(folder: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(folder), str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["OMP_NUM_THREADS"] = "1"
    env["MKL_NUM_THREADS"] = "1"
    env["SB3_COMA_TEST_THROTTLE"] = "0.1"
    return env


# ----------------------------------------------------------------------------- the lock itself
def test_a_folder_lock_is_exclusive_names_its_holder_and_is_released(tmp_path):
    assert lock_holder(tmp_path) is None and not (tmp_path / LOCK_FILE).exists()  # probing creates nothing
    first = FolderLock(tmp_path).acquire()
    holder = lock_holder(tmp_path)
    assert holder is not None and holder.pid == os.getpid() and holder.started
    with pytest.raises(FolderInUseError) as info:
        FolderLock(tmp_path).acquire()  # another open of the file: refused, even in this process
    assert f"is in use by pid {os.getpid()} (started {holder.started})" in str(info.value)
    first.release()
    assert lock_holder(tmp_path) is None
    with FolderLock(tmp_path) as again:
        assert again.held
    assert (tmp_path / LOCK_FILE).exists()  # the file stays: it names the last writer


def test_train_refuses_a_folder_that_another_writer_holds(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    config = _config(tmp_path, throttled=False)
    _, run = train(
        env="env1", config=config, seed=0, run_dir=tmp_path / "run", total_timesteps=8, verbose=0, progress_bar=False
    )
    assert lock_holder(run) is None  # released when train() returned
    with FolderLock(run):  # the "other writer"
        before = {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()}
        with pytest.raises(TrainingError, match=r"run folder .*run is in use by pid \d+ .*wait for it to finish"):
            train(resume=run, verbose=0)
        with pytest.raises(TrainingError, match=r"is in use by pid \d+ .*wait for it or pass another --run-dir"):
            train(env="env1", config=config, run_dir=run, total_timesteps=8, verbose=0)
        assert {p.name: p.read_bytes() for p in run.iterdir() if p.is_file()} == before
    assert not (tmp_path / "run_2").exists()


# ----------------------------------------------------------------------------- two real processes
def test_a_second_trainer_is_refused_while_the_first_runs_and_resume_works_after_sigkill(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))  # the config's throttle callback, a no-op here
    config = _config(tmp_path, throttled=True)
    run = tmp_path / "run"
    command = [sys.executable, "-m", "sb3_coma.cli", "train", "--env", "env1", "--config", str(config)]
    command += ["--seed", "0", "--run-dir", str(run), "--save-freq", "8", "--no-progress", "-v", "0"]
    log = (tmp_path / "first.log").open("wb")
    first = subprocess.Popen(command, cwd=tmp_path, env=_env(tmp_path), stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and first.poll() is None and not find_checkpoints(run / "checkpoints"):
            time.sleep(0.01)
        assert first.poll() is None, f"training ended too soon:\n{(tmp_path / 'first.log').read_text()}"
        config_before = (run / "config.yml").read_bytes()

        for argv in (["train", "--resume", str(run)], ["train", "--env", "env1", "--config", str(config)]):
            rc = cli.main([*argv, "--run-dir", str(run)] if "--config" in argv else argv)
            err = capsys.readouterr().err.strip().splitlines()
            assert rc == 2 and len(err) == 1, err
            assert err[0].startswith(f"sb3-coma train: error: run folder {run} is in use by pid {first.pid} (started ")
        assert first.poll() is None, "the first trainer must still be running"
        assert (run / "config.yml").read_bytes() == config_before  # nothing touched by the refused ones
        assert not (tmp_path / "run_2").exists()

        first.send_signal(signal.SIGKILL)
        first.wait(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
        log.close()
    assert first.returncode == -signal.SIGKILL
    assert lock_holder(run) is None  # the OS dropped the dead process's lock

    assert cli.main(["train", "--resume", str(run), "--no-progress", "-v", "0"]) == 0, capsys.readouterr().err
    assert validate_checkpoint(run / "model.zip").num_timesteps == TOTAL
