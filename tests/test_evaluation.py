"""The evaluation protocol, Table I output, the ``evaluate`` / ``ablation`` commands and their errors."""

from __future__ import annotations

import csv
import importlib.util
import re
import shutil

import numpy as np
import pytest

import uav_ipp
from sb3_coma import evaluate as evaluate_export
from sb3_coma.app.evaluation import evaluate
from sb3_coma.cli import main
from sb3_coma.common.evaluation import FRACTIONS
from sb3_coma.experiments import ablation
from sb3_coma.stats.tables import rows_for, table_markdown, write_table_csv
from uav_ipp.config import ConfigError

SMALL = dict(env="env1", budget=3, noise="moderate")


@pytest.fixture(scope="module")
def results():
    return [evaluate(m, n_trials=3, seed=0, **SMALL) for m in ("ag", "lawnmower", "random")]


def test_exported_and_shapes(results):
    assert evaluate_export is evaluate
    for r in results:
        assert r.f1.shape == r.entropy.shape == (3, 4)
        assert r.returns.shape == (3,) and r.planning_time_ms.shape == (3,)
        assert r.trajectories.shape == (3, 4, 4, 3)
        assert np.all(r.planning_time_ms > 0)
        assert r.final_beliefs.shape == (1, 493, 493) and r.belief_frames.shape == (4, 493, 493)
        assert np.all((r.entropy > 0) & (r.entropy <= 1)) and np.all((r.f1 >= 0) & (r.f1 <= 1))
    assert results[0].trajectories[0, 0].tolist() == [[10, 10, 15], [40, 10, 15], [40, 40, 15], [10, 40, 15]]


def test_final_snapshot_matches_infos():
    """The final belief kept at SuperSuit's auto-reset is the mission's end state (its F1 is the
    F1 the env reported after the last step)."""
    r = evaluate("lawnmower", n_trials=2, seed=4, record=2, **SMALL)
    assert r.final_beliefs.shape[0] == 2
    for k in range(2):
        belief, truth = r.final_beliefs[k] > 0.5, r.ground_truth
        f1 = 2 * (belief & truth).sum() / (belief.sum() + truth.sum())
        assert np.isclose(f1, r.f1[k, -1], atol=1e-9)


def test_deterministic_by_seed_and_trial_seeds():
    a = evaluate("random", n_trials=2, seed=5, **SMALL)
    b = evaluate("random", n_trials=2, seed=5, **SMALL)
    assert np.array_equal(a.f1, b.f1) and np.array_equal(a.entropy, b.entropy)
    assert np.array_equal(a.returns, b.returns) and np.array_equal(a.trajectories, b.trajectories)
    c = evaluate("random", n_trials=2, seed=6, **SMALL)
    assert not np.array_equal(a.trajectories, c.trajectories)
    # trial k uses env seed seed + k: a deterministic planner gives the same mission either way
    both = evaluate("lawnmower", n_trials=2, seed=7, **SMALL)
    second = evaluate("lawnmower", n_trials=1, seed=8, **SMALL)
    assert np.array_equal(both.f1[1], second.f1[0]) and np.array_equal(both.entropy[1], second.entropy[0])
    one_by_one = evaluate("lawnmower", n_trials=2, seed=7, n_envs=1, **SMALL)
    assert np.array_equal(both.f1, one_by_one.f1)


def _numbers(cell: str) -> tuple[float, float]:
    mean, std = re.findall(r"[-\d.]+", cell.replace("**", ""))
    return float(mean), float(std)


def test_table_numbers_equal_mean_and_std(results, tmp_path):
    rows = rows_for(results)
    lines = table_markdown(rows).strip().splitlines()
    assert len(lines) == 2 + len(results)
    for line, r in zip(lines[2:], results):
        cells = [c.strip() for c in line.strip("|").split("|")]
        assert cells[1] == r.method
        values = [_numbers(c) for c in cells[2:]]
        expected = [
            (r.metric(m)[:, r.step_of(f)].mean(), r.metric(m)[:, r.step_of(f)].std())
            for m in ("f1", "entropy")
            for f in FRACTIONS
        ]
        assert np.allclose(values, expected, atol=5e-5)
    assert [r.step_of(f) for f in FRACTIONS] == [1, 2, 3]
    # bold = best mean per column: F1 highest, entropy lowest
    for col, (metric, frac) in enumerate([(m, f) for m in ("f1", "entropy") for f in FRACTIONS]):
        means = [round(r.mean_std(metric, frac)[0], 4) for r in results]
        best = max(means) if metric == "f1" else min(means)
        bold = ["**" in line.strip("|").split("|")[2 + col] for line in lines[2:]]
        assert bold == [m == best for m in means]
    path = write_table_csv(rows, tmp_path / "t.csv")
    with path.open() as fh:
        data = list(csv.DictReader(fh))
    for row, r in zip(data, results):
        assert row["method"] == r.method
        assert np.isclose(float(row["f1_100_mean"]), r.f1[:, -1].mean(), atol=1e-6)
        assert np.isclose(float(row["entropy_33_std"]), r.entropy[:, 1].std(), atol=1e-6)


def test_clear_errors():
    with pytest.raises(ValueError, match=r"unknown method 'greedy'.*ag, lawnmower, oracle, random|neither a baseline"):
        evaluate("greedy", n_trials=1, **SMALL)
    with pytest.raises(FileNotFoundError, match="model file not found"):
        evaluate("runs/missing.zip", n_trials=1, **SMALL)
    with pytest.raises(ConfigError, match="noise"):
        evaluate("random", n_trials=1, env="env1", noise="deafening")
    with pytest.raises(ConfigError, match="unknown environment option"):
        evaluate("random", n_trials=1, env="env1", wind=3)
    with pytest.raises(ValueError, match="n_trials"):
        evaluate("random", n_trials=0, env="env1")
    with pytest.raises(TypeError, match="predict"):
        evaluate(42, n_trials=1, **SMALL)


def test_cli_errors(capsys):
    assert main(["evaluate", "--env", "env1", "--methods", "ag,greedy", "--trials", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "greedy" in err[0]
    assert main(["evaluate", "--env", "env1", "--methods", "", "--model", "nowhere/x.zip"]) == 2
    assert "model file not found" in capsys.readouterr().err
    assert main(["evaluate", "--env", "env1", "--noise", "deafening", "--trials", "1", "--methods", "random"]) == 2
    assert "noise" in capsys.readouterr().err
    assert main(["evaluate", "--trials", "0"]) == 2


@pytest.mark.skipif(importlib.util.find_spec("sb3_coma.app.pretrained") is not None, reason="shipped models exist")
def test_pretrained_name_without_pretrained_module(capsys):
    assert main(["evaluate", "--env", "env1", "--methods", "", "--model", "env3"]) == 2
    assert "sb3_coma.app.pretrained" in capsys.readouterr().err


def test_cli_writes_table_and_plots(tmp_path, capsys):
    out = tmp_path / "res"
    code = main(
        [
            "evaluate",
            "--env",
            "env1",
            "--methods",
            "ag,nl",
            "--trials",
            "2",
            "--budget",
            "3",
            "--out",
            str(out),
            "--no-gif",
        ]
    )
    assert code == 0
    printed = capsys.readouterr().out
    assert "| env1 | ag |" in printed and "lawnmower" in printed and "ms per UAV decision" in printed
    for name in (
        "table.md",
        "table.csv",
        "per_step.csv",
        "planning_time.md",
        "planning_time.csv",
        "curves_env1.png",
        "mission_env1_ag.png",
        "mission_env1_lawnmower.png",
    ):
        assert (out / name).stat().st_size > 0
    assert "**" in (out / "table.md").read_text()


@pytest.fixture(scope="module")
def model_path(tmp_path_factory):
    """One small untrained COMA model saved once (building one costs seconds)."""
    coma = pytest.importorskip("sb3_coma.coma")
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", budget=3)
    path = tmp_path_factory.mktemp("models") / "model.zip"
    coma.COMA("UavCnnPolicy", venv, seed=0, device="cpu").save(str(path))
    return path


def test_evaluates_saved_model(model_path):
    r = evaluate(str(model_path), n_trials=2, seed=0, fusion="mean", **SMALL)
    assert r.method == "model" and r.f1.shape == (2, 4) and r.fusion == "mean"
    assert np.all(r.planning_time_ms > 0)


def test_model_by_path_flies_the_same_missions_as_the_object(tmp_path):
    """Loading a model with ``env=venv`` re-seeds that env with the model's training seed; the
    missions must still be the requested ones (regression: a path used to fly seed 7's missions)."""
    from sb3_coma.coma import COMA

    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", budget=3)
    model = COMA("UavCnnPolicy", venv, seed=7, device="cpu")
    model.save(tmp_path / "seed7.zip")
    venv.close()
    by_object = evaluate(model, n_trials=3, seed=0, fusion="mean", deterministic=True, **SMALL)
    by_path = evaluate(str(tmp_path / "seed7.zip"), n_trials=3, seed=0, fusion="mean", deterministic=True, **SMALL)
    np.testing.assert_array_equal(by_path.f1, by_object.f1)
    np.testing.assert_array_equal(by_path.entropy, by_object.entropy)


def test_ablation_finds_models_and_skips_missing_fusion(model_path, tmp_path, monkeypatch):
    for name in ("mean_cnn.zip", "sendfuse_cbam.zip"):
        shutil.copy(model_path, tmp_path / name)
    (tmp_path / "notes.txt").write_text("ignored")
    assert list(ablation.find_models(tmp_path)) == [("mean", "cnn"), ("sendfuse", "cbam")]
    with pytest.raises(ValueError, match="fusion must be one of"):
        ablation.find_models({"median_cnn": tmp_path / "mean_cnn.zip"})
    with pytest.raises(FileNotFoundError):
        ablation.find_models(tmp_path / "nope")
    real = ablation.fusion_unavailable
    monkeypatch.setattr(
        ablation,
        "fusion_unavailable",
        lambda env, fusion, **kw: "not built yet" if fusion == "sendfuse" else real(env, fusion, **kw),
    )
    messages = []
    result = ablation.run_ablation(
        tmp_path, env="env1", noises=("none", "loud"), n_trials=1, budget=2, log=messages.append
    )
    assert set(result.results) == {("Base", "none"), ("Base", "loud")}
    assert "SenDFuse+CBAM" in result.skipped and any("skipping SenDFuse+CBAM" in m for m in messages)
    md = result.markdown()
    assert "| none | Base |" in md and "| loud | Base |" in md


def test_evaluate_uses_the_models_observation_options():
    """A model trained without the action_gain key is evaluated without it, with no word from the
    caller: the network's inputs follow the model's recorded training options."""
    import uav_ipp
    from sb3_coma import COMA, evaluate

    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=0, n_uavs=2, budget=3, action_gain=False)
    model = COMA("UavCnnPolicy", venv, seed=0, n_steps=4, batch_size=4, device="cpu")
    model.env_options = {"map": "env1", "fusion": "mean", "action_gain": False}
    result = evaluate(model, env="env1", n_trials=2, n_uavs=2, budget=3)
    assert result.fusion == "mean" and result.env_options["action_gain"] is False
    assert result.f1.shape == (2, 4)


def test_a_local_file_never_shadows_a_shipped_model_name(tmp_path, monkeypatch):
    """`evaluate("env1")` means the verified shipped model even when ./env1.zip exists (an SB3 zip
    can run code when loaded); the local file is used only when passed as a path."""
    from sb3_coma import evaluate

    monkeypatch.chdir(tmp_path)
    (tmp_path / "env1.zip").write_bytes(b"not a model")
    result = evaluate("env1", env="env1", n_trials=1, budget=2)
    assert result.method == "env1" and result.f1.shape == (1, 3)
    with pytest.raises(Exception, match=r"env1\.zip"):
        evaluate("./env1.zip", env="env1", n_trials=1, budget=2)


def test_warm_up_decision_changes_no_mission(monkeypatch):
    """The untimed warm-up decision restores every random stream: the missions are the same."""
    from sb3_coma.common import evaluation as library

    kwargs = {"env": "env1", "n_trials": 2, "seed": 4, "record": 0, "split": "test", "start": "random"}
    warm = [evaluate(name, **kwargs) for name in ("ag", "random")]
    monkeypatch.setattr(library, "warm_up", lambda *args: None)
    cold = [evaluate(name, **kwargs) for name in ("ag", "random")]
    for a, b in zip(warm, cold):
        np.testing.assert_array_equal(a.f1, b.f1)
        np.testing.assert_array_equal(a.trajectories, b.trajectories)


# --------------------------------------------------------------------------- table rows by name (#34, #37)
def test_every_baseline_row_of_the_tables_resolves_by_its_name():
    """Each baseline row the protocols write (docs/RESULTS.md) is a name ``evaluate`` and
    ``sb3-coma evaluate --methods`` take, meaning the same planner and options as the row."""
    from sb3_coma.app import evaluation as ev
    from sb3_coma.app import methods
    from sb3_coma.app.rows import BASELINE_METHODS

    for method in BASELINE_METHODS:
        ev.check_policy(method.label)
        assert not ev.is_model(method.label)
        planner, options = methods.PLANNER_ALIASES.get(method.label, (method.label, {}))
        assert (planner, options) == (method.policy, dict(method.planner_kwargs)), method.label
    assert {"ag-k2", "ag-k3", "ag-comm", "ag-central", "oracle"} <= set(methods.baseline_names())


def test_a_row_name_flies_what_the_protocols_fly():
    """``evaluate("ag-k3")`` is ``evaluate("ag", planner_kwargs={"lookahead": 3})`` labelled ag-k3."""
    by_name = evaluate("ag-k3", n_trials=2, seed=0, n_uavs=2, **SMALL)
    by_options = evaluate("ag", n_trials=2, seed=0, n_uavs=2, planner_kwargs={"lookahead": 3}, **SMALL)
    assert by_name.method == "ag-k3" and by_options.method == "ag"
    assert np.array_equal(by_name.f1, by_options.f1) and np.array_equal(by_name.entropy, by_options.entropy)
    assert by_name.planner_kwargs == by_options.planner_kwargs


def test_every_shipped_model_row_resolves_by_its_name():
    """``coma``, ``coma[mean-cnn]``, ``coma[paper-actor]`` ...: the row label of a shipped model on
    its map leads back to that model."""
    from sb3_coma.app.pretrained import read_manifest
    from sb3_coma.app.rows import shipped_label, shipped_name_of_label

    models = read_manifest()["models"]
    assert models
    for name, info in models.items():
        assert shipped_name_of_label(shipped_label(name, info, info["env"]), info["env"]) == name
    assert shipped_name_of_label("coma", "env3") == "env3"
    assert shipped_name_of_label("coma[mean-cnn]", "env3") == "env3-mean-cnn"
    assert shipped_name_of_label("coma[mean-cnn]", "env1") is None and shipped_name_of_label("ag", "env1") is None


@pytest.mark.filterwarnings("ignore:model 'env1' flies in another world")  # budget 2 keeps it short
def test_cli_evaluates_table_rows_by_name(tmp_path, capsys):
    """``sb3-coma evaluate --methods`` with the rows' names; each comes back under its name."""
    out = tmp_path / "out"
    names = ["ag-k2", "ag-comm", "ag-central", "oracle", "coma"]
    argv = ["evaluate", "--env", "env1", "--methods", ",".join(names), "--trials", "1", "--budget", "2"]
    assert main([*argv, "--no-plots", "--out", str(out)]) == 0
    with open(out / "table.csv") as handle:
        rows = {row["method"] for row in csv.DictReader(handle)}
    assert set(names) <= rows, rows
    assert main(["evaluate", "--env", "env1", "--methods", "coma[mean-cnn]", "--out", str(out)]) == 2
    assert "unknown method 'coma[mean-cnn]'" in capsys.readouterr().err  # an env3 model only


def test_a_mission_must_last_exactly_the_budget():
    """One rule for both ways to break it: the env ends its missions before the budget the
    evaluation reads from its config, or lets them run past it."""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    from sb3_coma.baselines import make_planner
    from sb3_coma.common.evaluation import evaluate_policy

    class StatedBudget(VecEnvWrapper):  # reports a budget that is not the env's
        def __init__(self, venv, budget: int) -> None:
            super().__init__(venv)
            self.n_agents, self.stated = venv.n_agents, budget

        def reset(self):
            return self.venv.reset()

        def step_wait(self):
            return self.venv.step_wait()

        def get_attr(self, attr_name, indices=None):
            values = self.venv.get_attr(attr_name, indices)
            return [v.replace(budget=self.stated) for v in values] if attr_name == "config" else values

    config = uav_ipp.IppConfig.from_options("env1", n_uavs=2, budget=4)
    for stated, step in ((5, 4), (3, 3)):
        with pytest.raises(RuntimeError, match=rf"the budget of {stated} steps; at step {step}"):
            evaluate_policy(
                lambda venv, seed: make_planner("random", venv, seed=seed),
                lambda n, s=stated: StatedBudget(uav_ipp.make_vec_env(config, n_envs=n, fusion="mean"), s),
                n_trials=1,
                record=0,
            )
