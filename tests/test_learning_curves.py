"""``sb3_coma.experiments.learning_curves``: curves and table from two tiny run folders, AG's and random's
levels on exactly the validation missions, and clear errors naming a bad run folder."""

from __future__ import annotations

import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from tiny_runs import ENV, ENV_KWARGS, tiny_entry

import sb3_coma.experiments.learning_curves as lc
from sb3_coma import COMA, evaluate
from sb3_coma.app.training import train
from sb3_coma.common.checkpoints import validate_checkpoint

# tests/test_training.py's tiny runs: 2 UAVs, 4-step missions, 8 joint steps per rollout.
TINY = {ENV: tiny_entry()}
#: 6 validation missions: 3 eval env copies x 2 missions each, so the second mission of each copy
#: comes from auto-reset, not from a seed of its own (what evaluate's per-trial seeds would fly).
MISSIONS = 6


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> list[Path]:
    root = tmp_path_factory.mktemp("curves")
    config = root / "tiny.yml"
    config.write_text(yaml.safe_dump(TINY))
    out = []
    for seed in (0, 1):
        _, run = train(
            env="env1",
            config=config,
            seed=seed,
            run_dir=root / f"run_s{seed}",
            eval_freq=16,
            eval_missions=MISSIONS,
            progress_bar=False,
            verbose=0,
        )
        out.append(run)
    return out


def test_main_draws_the_curves_and_writes_the_table(runs, tmp_path, capsys):
    figure, table = tmp_path / "fig" / "curves.png", tmp_path / "curves.md"
    spec = "tiny=" + ",".join(str(r) for r in runs)
    groups = lc.main(["--out", str(figure), "--table", str(table), spec])
    assert figure.is_file() and figure.stat().st_size > 10_000
    text = table.read_text()
    assert text == capsys.readouterr().out.split("figure:")[0]  # printed and written alike
    assert "| tiny | 2 (0, 1) | 8 |" in text  # evaluations at 16 and 32 joint steps = 4 and 8 missions
    (group,) = groups
    assert group.f1.shape == group.entropy.shape == (2, 2)
    assert list(group.missions) == [4.0, 8.0]
    assert group.validation.missions == MISSIONS and group.validation.seed == 1000
    assert set(group.levels) == {"ag", "ag-k3", "oracle", "random"}
    for name in ("ag", "ag-k3", "oracle", "random"):
        f1, entropy = group.levels[name]
        assert math.isfinite(f1) and 0.0 <= f1 <= 1.0
        assert math.isfinite(entropy) and 0.0 <= entropy <= 1.0
        assert f"{f1:.3f} / {entropy:.3f}" in text
    assert group.levels["ag"][0] > group.levels["random"][0]
    assert group.levels["oracle"][1] <= group.levels["ag"][1]  # the clairvoyant reference ends less unsure


def test_levels_are_flown_on_the_validation_missions(runs):
    """The mechanism the levels use reproduces the callback's own evaluation: the best model flown
    through it gives the very returns and F1 the run recorded at its best step. evaluate()'s
    per-trial seeds share only each copy's first mission with it."""
    run = lc.read_run(runs[0])
    data = np.load(runs[0] / "eval" / "evaluations.npz")
    k = list(data["timesteps"]).index(validate_checkpoint(runs[0] / "best_model.zip").num_timesteps)
    model = COMA.load(runs[0] / "best_model.zip", device="cpu")
    flown = lc.fly_validation(run.validation, lambda venv: model)
    np.testing.assert_allclose(flown.returns, data["results"][k], rtol=1e-5)
    assert flown.f1.mean() == pytest.approx(run.f1[k], abs=1e-6)  # TensorBoard keeps float32
    assert flown.entropy.mean() == pytest.approx(run.entropy[k], abs=1e-6)

    # AG decides from the env state alone: on a shared mission it flies the same route either way.
    ag = lc.baseline_scores(run.validation, "ag")
    options = {key: value for key, value in ENV_KWARGS.items() if key != "fusion"}
    trials = evaluate("ag", env=ENV, n_trials=MISSIONS, seed=run.validation.seed, record=0, **options).f1[:, -1]
    copies = run.validation.copies
    assert copies == 3 and len(ag.f1) == MISSIONS
    # missions are read as they end, copy by copy: the first mission of copies 0..2, then their second
    np.testing.assert_allclose(ag.f1[:copies], trials[:copies])  # env seeds 1000..1002 in both
    assert not np.allclose(ag.f1[copies:], trials[copies:])  # auto-reset missions vs seeds 1003..1005
    assert lc.baseline_level(run.validation, "ag")[0] == pytest.approx(ag.f1.mean())


def test_a_bad_run_folder_is_named(runs, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(lc.RunDirError, match=re.escape(f"run folder {empty}: no config.yml")):
        lc.main(["--out", str(tmp_path / "x.png"), f"g={runs[0]},{empty}"])

    no_eval = tmp_path / "no_eval"
    shutil.copytree(runs[0], no_eval, ignore=shutil.ignore_patterns("*.zip"))
    (no_eval / "eval" / "evaluations.npz").unlink()
    with pytest.raises(lc.RunDirError, match=re.escape(f"run folder {no_eval}: no eval/evaluations.npz")):
        lc.read_run(no_eval)

    no_tb = tmp_path / "no_tb"
    shutil.copytree(runs[0], no_tb, ignore=shutil.ignore_patterns("*.zip", "tb"))
    with pytest.raises(lc.RunDirError, match=re.escape(f"run folder {no_tb}: no TensorBoard event file")):
        lc.read_run(no_tb)

    with pytest.raises(lc.RunDirError, match="expected GROUP=RUN_DIR"):
        lc.main(["--out", str(tmp_path / "x.png"), str(runs[0])])
    assert not (tmp_path / "x.png").exists()


def test_runs_as_a_module_and_names_a_bad_run_folder_in_one_line(tmp_path):
    """``python -m sb3_coma.experiments.learning_curves`` is the documented command: a bad run folder
    is one line naming it and a non-zero status, not a traceback (no run folder to train for this)."""
    missing = tmp_path / "missing"
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "sb3_coma.experiments.learning_curves",
            "--out",
            str(tmp_path / "x.png"),
            f"g={missing}",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 1, done.stderr
    assert "Traceback" not in done.stderr
    assert done.stderr.strip().splitlines()[-1] == f"learning_curves: run folder {missing}: not a folder"
    assert not (tmp_path / "x.png").exists()
