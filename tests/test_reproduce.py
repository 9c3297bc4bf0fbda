"""``sb3-coma reproduce --quick`` end to end into a temporary folder."""

from __future__ import annotations

import json

import pytest

from sb3_coma.app import pretrained as pt
from sb3_coma.cli import main
from sb3_coma.experiments.reproduce import ablation_acceptance, acceptance

pytestmark = pytest.mark.skipif(not (pt.pretrained_dir() / pt.MANIFEST).is_file(), reason="no shipped models")


def test_reproduce_quick_end_to_end(tmp_path, capsys):
    out = tmp_path / "res"
    docs = tmp_path / "docs" / "RESULTS.md"
    assert main(["reproduce", "--quick", "--env", "env1", "--out", str(out), "--docs", str(docs)]) == 0
    for name in (
        "table.md",
        "table.csv",
        "acceptance.md",
        "generalisation.md",
        "latency.md",
        "summary.json",
        "RESULTS.md",
        "figures/table1_curves.png",
        "figures/training_reward.png",
    ):
        assert (out / name).is_file(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["trials"] == 2 and summary["models"]["env1"]["source"] == "shipped"
    assert set(summary["table"]) == {
        "env1/coma",
        "env1/coma[paper-actor]",  # every model shipped for the map gets its row
        "env1/ag",
        "env1/ag-k2",
        "env1/ag-k3",
        "env1/ag-comm",
        "env1/lawnmower",
        "env1/random",
        "env1/ag-central",  # upper references: rows, never in a verdict
        "env1/oracle",
    }
    assert not any("oracle" in k or "ag-central" in k for k in summary["acceptance"]["env1"]["paired"])
    assert {g["target"] for g in summary["generalisation"] if g["model"] == "env1"} >= {"env1 (map_seed=7)"}
    text = docs.read_text()
    assert "## Table I" in text and "## Generalisation" in text and "## Deployment latency" in text
    assert (
        "![table1_curves](figures/table1_curves.png)" in text
        and (docs.parent / "figures" / "table1_curves.png").is_file()
    )
    assert "sb3-coma reproduce --quick" in text
    said = capsys.readouterr().out
    assert "[1/12] load models (0 s elapsed)" in said and "[12/12] write results (" in said  # a line per step


def test_reproduce_refuses_bad_input(tmp_path, capsys):
    assert main(["reproduce", "--quick", "--ship", "--out", str(tmp_path)]) == 2
    assert "ship must be used with train=True" in capsys.readouterr().err
    assert main(["reproduce", "--quick", "--env", "env9", "--out", str(tmp_path), "--no-docs"]) == 2
    assert "unknown shipped model 'env9'" in capsys.readouterr().err
    assert main(["reproduce", "--quick", "--wide-trials", "1", "--out", str(tmp_path), "--no-docs"]) == 2
    assert "wide_trials must be 0 (skip) or an integer >= 2, got 1" in capsys.readouterr().err


def test_acceptance_logic():
    """Verdicts are paired on shared missions: per-mission values around the means below."""
    import numpy as np

    class R:
        def __init__(self, env, method, f1, ent):
            jitter = np.array([-0.01, 0.0, 0.01, 0.005])  # the same missions for every method
            self.env, self.method, self.seed, self.n_trials, self.env_options = env, method, 0, 4, {}
            self.f1 = np.column_stack([np.zeros(4), f1 + jitter])
            self.entropy = np.column_stack([np.ones(4), ent + jitter])

    acc = acceptance([R("e", "coma", 0.8, 0.3), R("e", "ag", 0.7, 0.2), R("e", "random", 0.5, 0.7)])["e"]
    assert acc["beats_f1"] and not acc["beats_entropy"] and not acc["beats_all"]
    assert acc["best_entropy_baseline"] == "ag" and acc["best_f1_baseline"] == "ag"
    assert (
        acc["paired"]["ag"]["entropy"]["verdict"] == "ag better"
        and acc["paired"]["random"]["f1"]["verdict"] == "coma better"
    )


def test_reproduce_quick_train(tmp_path):
    out = tmp_path / "res"
    assert (
        main(
            [
                "reproduce",
                "--quick",
                "--train",
                "--env",
                "env1",
                "--out",
                str(out),
                "--no-docs",
                "--no-plots",
                "--no-generalisation",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    model = summary["models"]["env1"]
    assert model["source"] == str(out / "runs" / "env1") and model["timesteps"] >= 32
    from sb3_coma.experiments.reproduce import shipped_seed

    seed = shipped_seed("env1")  # --train retrains the shipped model's seed
    assert model["command"].startswith(f"sb3-coma train --env env1 --seed {seed} --timesteps 32")  # the map's entry
    assert "--eval-freq" not in model["command"]  # the tiny training does not validate
    assert (out / "runs" / "env1" / "model.zip").is_file() and summary[
        "command"
    ] == "sb3-coma reproduce --train --quick"


def test_reproduce_training_says_how_far_it_is(tmp_path):
    """--train runs quiet (verbose 0, no bar): its training still says, every tenth of the run,
    the joint steps done, the time elapsed and an estimate of the time left, then when it ends."""
    from sb3_coma.experiments.reproduce import QUICK_TIMESTEPS, _train_model

    lines: list[str] = []
    _train_model("env1", "mean", tmp_path, True, None, lines.append)
    progress = [line for line in lines if line.startswith("  training env1: ")]
    assert len(progress) >= 5 and any(line.startswith("  Run folder: ") for line in lines), lines
    assert all("elapsed, about" in line and "left" in line for line in progress[:-1]), progress
    assert progress[-1].startswith(f"  training env1: done at {QUICK_TIMESTEPS}/{QUICK_TIMESTEPS} joint steps after")


def test_fusion_latency_is_measured_for_both_fusions():
    from sb3_coma.experiments.reproduce import _time_fusion

    for fusion in ("mean", "sendfuse"):
        ms = _time_fusion(fusion, 4, reps=3)
        assert ms is not None and 0 < ms < 1000


def test_reproduce_quick_ablation(tmp_path):
    """env3 brings the ablation: the env3 model plus the three shipped arms at three noise levels."""
    out = tmp_path / "res"
    assert (
        main(
            [
                "reproduce",
                "--quick",
                "--env",
                "env3",
                "--out",
                str(out),
                "--no-docs",
                "--no-plots",
                "--no-generalisation",
            ]
        )
        == 0
    )
    summary = json.loads((out / "summary.json").read_text())
    ablation = summary["ablation"]
    assert ablation["noise"] == "loud" and ablation["full"] == "SenDFuse+CBAM"
    assert set(ablation["entropy"]) == {"Base", "CBAM", "SenDFuse", "SenDFuse+CBAM"}
    assert ablation["met"] == all(ablation["entropy"]["SenDFuse+CBAM"] <= v for v in ablation["entropy"].values())
    table = (out / "ablation.md").read_text()
    assert all(f"| {noise} |" in table for noise in ("none", "moderate", "loud"))
    assert "## Ablation" in (out / "RESULTS.md").read_text()
    # The paired check (quick: as many missions as the table): coma vs ag, and the full model vs each arm.
    paired = summary["paired"]
    assert paired["trials"] == 2 and [r["metric"] for r in paired["table1"]] == ["f1", "entropy"]
    assert {r["b"] for r in paired["ablation"]} == {"Base", "CBAM", "SenDFuse"}
    assert all(r["a"] == "SenDFuse+CBAM" and r["n"] == 2 for r in paired["ablation"])
    assert paired["ablation_met"] == all(r["diff"] <= 0 for r in paired["ablation"])
    assert "| loud | SenDFuse+CBAM | SenDFuse | entropy | 2 |" in (out / "paired.md").read_text()
    assert "## A paired check on more missions" in (out / "RESULTS.md").read_text()


def test_ablation_acceptance_logic():
    class R:
        def __init__(self, ent):
            self.ent = ent

        def mean_std(self, name, frac):
            assert name == "entropy" and frac == 1.0
            return self.ent, 0.0

    class Result:
        def __init__(self, full, cnn):
            self.results = {
                ("SenDFuse+CBAM", "loud"): R(full),
                ("SenDFuse", "loud"): R(cnn),
                ("CBAM", "loud"): R(0.5),
                ("Base", "loud"): R(0.6),
                ("SenDFuse+CBAM", "none"): R(0.9),
            }

    assert ablation_acceptance(Result(0.40, 0.41))["met"] is True
    assert ablation_acceptance(Result(0.42, 0.41))["met"] is False
    partial = Result(0.40, 0.41)
    del partial.results[("Base", "loud")]
    assert ablation_acceptance(partial)["met"] is None


def test_retraining_uses_the_shipped_run_length(monkeypatch):
    """A shipped model trained with --timesteps records train_timesteps; --train retrains as long."""
    from sb3_coma.app import pretrained
    from sb3_coma.experiments import reproduce

    monkeypatch.setattr(
        pretrained, "model_info", lambda env: {"seed": 1, "train_timesteps": 18000} if env == "envL" else {"seed": 2}
    )
    assert reproduce.shipped_timesteps("envL") == 18000 and reproduce.shipped_seed("envL") == 1
    assert reproduce.shipped_timesteps("envS") is None  # the config's n_timesteps


def test_readme_block_is_written_between_its_markers_only(tmp_path):
    from sb3_coma.experiments.reproduce import README_MARKERS, write_readme_block

    readme = tmp_path / "README.md"
    readme.write_text(f"# title\n\n{README_MARKERS[0]}\nold words\n{README_MARKERS[1]}\n\n## after\n")
    assert write_readme_block(readme, "COMA ties AG on env3 (scene-clustered, Holm).")
    text = readme.read_text()
    assert "old words" not in text and "COMA ties AG on env3" in text
    assert text.startswith("# title\n") and text.endswith("\n## after\n")
    plain = tmp_path / "PLAIN.md"
    plain.write_text("no markers here\n")
    assert not write_readme_block(plain, "x") and plain.read_text() == "no markers here\n"


def test_acceptance_takes_the_verdict_tables_decisions():
    """With the protocol's Holm-adjusted verdicts the acceptance says exactly what that table says."""
    from types import SimpleNamespace

    import numpy as np

    from sb3_coma.experiments.reproduce import acceptance

    def result(method, f1, entropy):
        return SimpleNamespace(
            env="env1", method=method, n_trials=3, f1=np.full((3, 2), f1), entropy=np.full((3, 2), entropy)
        )

    def diff(winner):
        return SimpleNamespace(winner=winner, as_dict=lambda: {"winner": winner})

    results = [result("coma", 0.9, 0.2), result("ag", 0.8, 0.3), result("random", 0.5, 0.7)]
    verdicts = {
        ("env1", "ag"): {"f1": diff(None), "entropy": diff("coma")},
        ("env1", "random"): {"f1": diff("coma"), "entropy": diff("coma")},
    }
    row = acceptance(results, baselines=["ag", "random"], verdicts=verdicts)["env1"]
    assert row["beats_f1"] is False and row["beats_entropy"] is True and row["beats_all"] is False
    assert row["paired"]["ag"]["f1"] == {"winner": None}


def test_seed_spread_table_gives_the_shipped_seed_and_the_sample_std_over_seeds():
    from sb3_coma.experiments.report import seeds_markdown

    rows = [
        {
            "model": "env3",
            "shipped": "seed 1",
            "candidates": ["seed 0", "seed 1", "seed 2"],
            "missions": 50,
            "metrics": {
                "seed 0": {"f1": 0.70, "entropy": 0.40},
                "seed 1": {"f1": 0.80, "entropy": 0.30},
                "seed 2": {"f1": 0.90, "entropy": 0.50},
            },
        },
        {"model": "env1", "shipped": "seed 0", "candidates": ["seed 0"], "missions": None, "metrics": {}},
    ]
    table = seeds_markdown(rows).splitlines()
    assert table[2] == "| env3 | 3 (0, 1, 2) | seed 1 | 0.8000 | 0.8000 ± 0.1000 | 0.3000 | 0.4000 ± 0.1000 |"
    assert table[3] == "| env1 | 1 (0) | seed 0 | not recorded | not recorded | not recorded | not recorded |"


def test_seed_spread_rows_list_every_shipped_model_with_its_candidates():
    from sb3_coma.experiments.reproduce import seed_spread_rows

    rows = {r["model"]: r for r in seed_spread_rows()}
    assert set(rows) == set(pt.read_manifest()["models"])
    for name, entry in pt.read_manifest()["models"].items():
        assert rows[name]["shipped"] == f"seed {entry['seed']}"
        assert rows[name]["shipped"] in rows[name]["candidates"]


def test_recorded_metrics_go_to_the_model_a_row_flew():
    from sb3_coma.experiments.reproduce import _manifest_name

    assert _manifest_name("env3", "coma") == "env3"
    assert _manifest_name("env1", "coma[paper-actor]") == "env1-paper-actor"
    assert _manifest_name("env3", "coma[sendfuse-cnn]") == "env3-sendfuse-cnn"
    assert _manifest_name("env3", "ag-k3") is None


def test_quiet_turns_the_progress_lines_off(monkeypatch, tmp_path, capsys):
    """``reproduce --quiet`` passes no log (no step, round or training lines); without it every line is flushed."""
    import sb3_coma.experiments.reproduce as rep

    seen = []
    monkeypatch.setattr(rep, "reproduce", lambda **kwargs: seen.append(kwargs["log"]))
    assert main(["reproduce", "--quick", "--env", "env1", "--out", str(tmp_path / "a"), "--no-docs", "--quiet"]) == 0
    assert main(["reproduce", "--quick", "--env", "env1", "--out", str(tmp_path / "b"), "--no-docs"]) == 0
    assert seen[0] is None and callable(seen[1])
    assert capsys.readouterr().out == ""
