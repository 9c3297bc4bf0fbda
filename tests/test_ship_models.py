"""ship_models: the shipped model is the best candidate on validation; every seed's unseen result
is recorded next to it; today's shipped model can compete without its run folder."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from tiny_runs import ENV, tiny_entry

from sb3_coma.app import pretrained as pt
from sb3_coma.app.training import train
from sb3_coma.app.validation_flights import validation_return
from sb3_coma.experiments import ship_models as sm


def _fake_run(folder: Path, seed: int, returns: list[float], warm_start: dict | None = None) -> Path:
    """A run folder as ``sb3-coma train --eval-freq`` leaves it, as far as selection reads it."""
    (folder / "eval").mkdir(parents=True)
    np.savez(
        folder / "eval" / "evaluations.npz",
        timesteps=np.arange(1, len(returns) + 1) * 3000,
        results=np.array(returns)[:, None].repeat(4, axis=1),
    )
    command = f"python sb3-coma train --env env3 --variant mean-cnn --seed {seed} --eval-freq 3000 --run-dir {folder}"
    run = {"command": command, "seed": seed, "env": "UavIpp-Env3-v0", "variant": "mean-cnn"}
    entry = {"n_timesteps": 3000 * len(returns), "warm_start": warm_start}
    (folder / "config.yml").write_text(yaml.safe_dump({"UavIpp-Env3-v0": entry, "run": run}))
    return folder


@pytest.fixture
def shipped_folder(tmp_path, monkeypatch):
    folder = tmp_path / "pretrained"
    folder.mkdir()
    entry = {
        "file": "coma_env3_mean_cnn.zip",
        "sha256": hashlib.sha256(b"zip").hexdigest(),
        "env": "env3",
        "fusion": "mean",
        "seed": 0,
        "selection": {"candidates": {"seed 0": {"best_validation_return": 7.1, "at_joint_steps": 30000}}},
    }
    (folder / pt.MANIFEST).write_text(json.dumps({"format": 1, "models": {"env3-mean-cnn": entry}}))
    (folder / entry["file"]).write_bytes(b"zip")
    monkeypatch.setattr(pt, "pretrained_dir", lambda: folder)
    spread_calls = []

    def fake_spread(models, env, fusion, missions=50):
        spread_calls.append((dict(models), env, fusion))
        return {"metrics": {label: {"f1": 0.7, "entropy": 0.4} for label in models}}

    def fake_entry(name, run):
        spread_calls.append("saved")  # after every candidate flew: saving replaces the shipped file
        return {"env": "env3", "fusion": "mean", "from": str(run)}

    monkeypatch.setattr(sm, "seed_spread", fake_spread)
    monkeypatch.setattr(sm, "_entry_of_run", fake_entry)
    monkeypatch.setattr(sm, "load_trained", lambda path: (path, {"map": "env3", "fusion": "mean"}))
    # flown today, not the recorded 7.1 (the fake "model" is its file)
    monkeypatch.setattr(sm, "model_validation_return", lambda model, options: 8.0)
    return folder, spread_calls


def test_the_shipped_model_stays_when_its_validation_score_flown_today_wins(tmp_path, shipped_folder):
    folder, spread_calls = shipped_folder
    runs = [_fake_run(tmp_path / "s1", 1, [7.0, 7.5]), _fake_run(tmp_path / "s2", 2, [6.0, 7.9])]
    entry = sm.ship("env3-mean-cnn", ["shipped", *map(str, runs)])
    assert entry["file"] == "coma_env3_mean_cnn.zip" and entry["seed"] == 0 and "from" not in entry
    assert entry["selection"]["candidates"] == {
        "seed 0": {"best_validation_return": 8.0, "at_joint_steps": 30000},
        "seed 1": {"best_validation_return": 7.5, "at_joint_steps": 6000},
        "seed 2": {"best_validation_return": 7.9, "at_joint_steps": 6000},
    }
    models, env, fusion = spread_calls[0]
    assert models == {"seed 0": folder / "coma_env3_mean_cnn.zip", "seed 1": runs[0] / "best_model.zip",
                      "seed 2": runs[1] / "best_model.zip"}  # fmt: skip
    assert (env, fusion) == ("env3", "mean")
    assert set(entry["seeds_unseen"]["metrics"]) == {"seed 0", "seed 1", "seed 2"}


def test_a_run_that_validates_higher_replaces_the_shipped_model(tmp_path, shipped_folder):
    runs = [_fake_run(tmp_path / "s1", 1, [8.5, 7.0]), _fake_run(tmp_path / "s2", 2, [6.0, 7.9])]
    entry = sm.ship("env3-mean-cnn", ["shipped", *map(str, runs)])
    assert entry["from"] == str(runs[0])
    assert shipped_folder[1][-1] == "saved" and len(shipped_folder[1]) == 2  # flown, then saved
    assert entry["selection"]["candidates"]["seed 1"]["best_validation_return"] == 8.5


def test_two_candidates_of_one_seed_are_refused(tmp_path, shipped_folder):
    runs = [_fake_run(tmp_path / "s0", 0, [7.0])]
    with pytest.raises(ValueError, match="two candidates of seed 0"):
        sm.ship("env3-mean-cnn", ["shipped", *map(str, runs)])


def test_a_warm_started_run_is_selected_on_its_evaluations_after_the_warm_up(tmp_path):
    spec = {"teacher": "oracle", "rounds": 8, "missions": 128, "critic_warmup": 0.25}
    run = _fake_run(tmp_path / "s1", 1, [9.0, 7.0, 8.0, 7.5], warm_start=spec)  # 12000 steps: warm-up 3000
    assert sm.validation_best(run) == (8.0, 9000)  # 9.0 at 3000 steps is the clone, held still


def test_a_checkpoint_flown_today_scores_what_its_run_recorded(tmp_path):
    """validation_return is MissionEvalCallback's score: a run's best_model.zip re-flown on the
    validation missions gives the run's best recorded evaluation, to the last digit."""
    config = tmp_path / "tiny.yml"
    config.write_text(yaml.safe_dump({ENV: tiny_entry()}))
    _, run = train(env="env1", config=config, seed=3, run_dir=tmp_path / "run", eval_freq=16, eval_missions=4,
                   progress_bar=False, verbose=0)  # fmt: skip
    recorded = np.load(run / "eval" / "evaluations.npz")["results"].mean(axis=1).max()
    assert validation_return(run / "best_model.zip", missions=4) == pytest.approx(float(recorded), abs=1e-6)


def test_a_bare_zip_competes_but_cannot_be_shipped(tmp_path, shipped_folder, monkeypatch):
    class Model:
        seed, num_timesteps = 5, 21000

        def __init__(self, path):
            self.path = path

    monkeypatch.setattr(sm, "load_trained", lambda path: (Model(path), {"map": "env3", "fusion": "mean"}))
    monkeypatch.setattr(sm, "model_validation_return", lambda m, o: 9.0 if str(m.path).endswith("old.zip") else 8.0)
    old = tmp_path / "old.zip"
    with pytest.raises(ValueError, match=r"old\.zip, has no run folder"):
        sm.ship("env3-mean-cnn", ["shipped", str(old)])
    monkeypatch.setattr(sm, "model_validation_return", lambda m, o: 6.0 if str(m.path).endswith("old.zip") else 8.0)
    entry = sm.ship("env3-mean-cnn", ["shipped", str(old)])
    assert entry["seed"] == 0 and entry["selection"]["candidates"]["seed 5"] == {
        "best_validation_return": 6.0, "at_joint_steps": 21000}  # fmt: skip


@pytest.mark.parametrize(
    "command, value",
    [("sb3-coma train --env env1 --timesteps 24000", "24000"), ("sb3-coma train --timesteps=48000 --seed 1", "48000"),
     ("sb3-coma train --env env2", None)],
)  # fmt: skip
def test_flag_value_reads_both_spellings(command, value):
    assert sm._flag_value(command, "--timesteps") == value


def _sb3_zip(policy_class: str, weights: bytes) -> bytes:
    import io
    import zipfile

    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        archive.writestr("data", json.dumps({"policy_class": {"__init__": policy_class}, "num_timesteps": 9}))
        archive.writestr("policy.pth", weights)
    return buffer.getvalue()


def test_a_reselection_that_keeps_the_model_keeps_its_bytes(tmp_path, monkeypatch):
    """SB3 writes memory addresses into ``data``: a second save of the same model must not add a
    new file to git history; a different model replaces the file."""
    monkeypatch.setattr(pt, "pretrained_dir", lambda: tmp_path)
    target = tmp_path / sm.shipped_file_name("env3-mean-cnn")
    old = _sb3_zip("<function at 0x1>", b"weights")
    target.write_bytes(old)

    def save(weights: bytes):
        def write():
            target.write_bytes(_sb3_zip("<function at 0x2>", weights))
            return {"file": target.name, "sha256": "new", "size_bytes": 0}

        return write

    entry = sm._keep_same_file("env3-mean-cnn", save(b"weights"))
    assert target.read_bytes() == old and entry["sha256"] == hashlib.sha256(old).hexdigest()
    assert entry["size_bytes"] == len(old)
    entry = sm._keep_same_file("env3-mean-cnn", save(b"other weights"))
    assert target.read_bytes() != old and entry["sha256"] == "new"
