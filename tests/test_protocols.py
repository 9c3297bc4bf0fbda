"""The two evaluation protocols, paired verdicts, AG's validated weighting, the noise sweep, costs.

Everything here runs with the baselines only, tiny budgets and a few missions, seeded.
"""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import numpy as np
import pytest

from sb3_coma.app.evaluation import evaluate
from sb3_coma.app.rows import BASELINE_METHODS
from sb3_coma.baselines.adaptive_gain import FALLBACK_WEIGHTING, WEIGHTING_BY_MAP, default_weighting
from sb3_coma.cli import main
from sb3_coma.common.evaluation import PROTOCOLS
from sb3_coma.experiments.ag_weighting import VALIDATION_SEED, pick_ag_weighting, validation_options
from sb3_coma.experiments.noise_sweep import QUICK_AXES, run_noise_sweep, sweep_points
from sb3_coma.experiments.protocols import Method, ProtocolResult, default_pairs, run_protocol
from sb3_coma.stats.paired import paired_difference

TINY = dict(budget=3)
METRIC_HEADS = ("F1-Score", "Entropy", "team F1", "team entropy")


@pytest.fixture(scope="module")
def unseen():
    return run_protocol("unseen", {"env1": list(BASELINE_METHODS)}, n_trials=3, seed=0, log=None, **TINY)


# ------------------------------------------------------------------ protocols
def test_protocols_fly_their_missions_end_to_end_with_baselines_only(unseen, tmp_path):
    paper = run_protocol("paper", {"env1": list(BASELINE_METHODS)}, n_trials=2, seed=0, log=None, **TINY)
    for result, split, start in ((paper, "paper", None), (unseen, "test", "random")):
        assert [m.label for m in result.methods["env1"]] == [
            "ag",
            "ag-k2",
            "ag-k3",
            "ag-comm",
            "lawnmower",
            "random",
            "ag-central",
            "oracle",
        ]
        for r in result.results.values():
            assert r.protocol == result.protocol.name and r.env_options["split"] == split
            assert r.env_options.get("start") == start
            assert r.team_f1.shape == r.team_entropy.shape == r.f1.shape == (result.n_trials, 4)
            assert np.all((r.team_entropy > 0) & (r.team_entropy <= 1)) and not np.isnan(r.team_f1).any()
    # paper: fixed corners; unseen: random starts, the same for every method
    assert paper.result("env1", "ag").trajectories[0, 0].tolist()[0] == [10, 10, 15]
    starts = {label: r.trajectories[:, 0].tolist() for (_, label), r in unseen.results.items()}
    assert (
        len({json.dumps(s) for s in starts.values()}) == 1
        and starts["ag"] != paper.result("env1", "ag").trajectories[:, 0].tolist()
    )
    final = unseen.final_table()
    assert all(h in final for h in METRIC_HEADS) and "ms per UAV decision" in final
    assert "team entropy ↓ 100%" in unseen.table("team") and "Entropy ↓ 100%" in unseen.table("global")
    verdicts = unseen.verdict_table()
    assert len(verdicts.strip().splitlines()) == 2 + len(default_pairs(unseen.methods["env1"]))
    written = unseen.write(tmp_path)
    assert {p.name for p in written} >= {"unseen_table.csv", "unseen_team_table.md", "unseen_verdicts.csv"}
    with (tmp_path / "unseen_verdicts.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {r["metric"] for r in rows} == {"f1", "entropy", "team_f1", "team_entropy"}
    summary = unseen.summary()
    assert summary["split"] == "test" and summary["table"]["env1/ag"]["team_entropy_100_mean"] > 0


def test_default_pairs_compare_models_with_ag_and_lookahead_with_ag():
    methods = [
        Method("coma", object(), kind="coma"),
        Method("coma[mean-cnn]", object(), kind="coma"),
        *BASELINE_METHODS,
    ]
    pairs = default_pairs(methods)
    assert pairs[:2] == [("coma", "ag"), ("coma[mean-cnn]", "ag")]
    assert {("coma", "lawnmower"), ("ag-k2", "ag"), ("ag-k3", "ag"), ("ag", "random"), ("lawnmower", "random")} <= set(
        pairs
    )
    assert len(pairs) == len(set(pairs))
    assert ("ag-comm", "ag") in pairs
    assert not any("oracle" in pair or "ag-central" in pair for pair in pairs)  # references: shown, not compared
    assert default_pairs(list(BASELINE_METHODS))[0] == ("ag-k2", "ag")


def _fake(method, final, n=4, team=None, split="test"):
    values = np.ones((n, 2))
    values[:, -1] = final
    tvalues = values.copy() if team is None else np.column_stack([np.ones(n), team])
    return SimpleNamespace(
        method=method,
        env="env1",
        seed=0,
        n_trials=n,
        env_options={"split": split},
        f1=1 - values,
        entropy=values,
        team_f1=1 - tvalues,
        team_entropy=tvalues,
    )


def test_verdicts_call_a_difference_within_the_standard_error_a_tie():
    a = _fake("a", [0.50, 0.52, 0.49, 0.51])
    b = _fake("b", [0.51, 0.50, 0.50, 0.50])  # a - b: -0.01 +0.02 -0.01 +0.01: mean 0.0025, se 0.0075
    d = paired_difference(a, b, "entropy")
    assert abs(d.diff) < d.se and d.verdict == "tie" and d.winner is None
    clear = _fake("c", [0.40, 0.42, 0.39, 0.41])
    assert paired_difference(clear, b, "entropy").winner == "c"
    result = ProtocolResult(
        PROTOCOLS["unseen"],
        4,
        0,
        "moderate",
        {"split": "test"},
        methods={"env1": [Method("a", "ag"), Method("b", "random")]},
        results={("env1", "a"): a, ("env1", "b"): b},
    )
    (c,) = result.comparisons({"env1": [("a", "b")]})
    assert c.diffs["entropy"].verdict == "tie" and c.diffs["team_entropy"].verdict == "tie"
    assert "(tie)" in result.verdict_table([c]) and "(a)" not in result.verdict_table([c])
    # and the acceptance table does not count a tie as a win
    from sb3_coma.experiments.reproduce import acceptance

    acc = acceptance([_fake("coma", [0.40, 0.42, 0.39, 0.41]), _fake("ag", [0.41, 0.40, 0.40, 0.40])])["env1"]
    assert not acc["beats_entropy"] and acc["paired"]["ag"]["entropy"]["verdict"] == "tie"
    with pytest.raises(ValueError, match="not the same missions: split 'test' vs 'paper'"):
        paired_difference(a, _fake("p", [0.5] * 4, split="paper"), "entropy")


def test_lookahead_one_is_ag_in_evaluate():
    plain = evaluate("ag", env="env1", n_trials=2, seed=3, record=0, split="test", **TINY)
    k1 = evaluate("ag", env="env1", n_trials=2, seed=3, record=0, split="test", planner_kwargs={"lookahead": 1}, **TINY)
    for name in ("f1", "entropy", "team_f1", "team_entropy", "trajectories", "returns"):
        np.testing.assert_array_equal(getattr(plain, name), getattr(k1, name), err_msg=name)
    assert plain.planner_kwargs == {"weighting": WEIGHTING_BY_MAP["env1"]}
    assert k1.planner_kwargs == {"lookahead": 1, "weighting": WEIGHTING_BY_MAP["env1"]}


def test_protocol_option_and_its_errors():
    r = evaluate("random", env="env1", budget=1, protocol="paper", record=0)
    assert r.n_trials == PROTOCOLS["paper"].n_trials == 10 and r.env_options["split"] == "paper"
    u = evaluate("random", env="env1", budget=1, protocol="unseen", n_trials=2, record=0)
    assert u.env_options["split"] == "test" and u.env_options["start"] == "random" and u.protocol == "unseen"
    with pytest.raises(ValueError, match="protocol 'unseen' flies split='test'; got split='paper'"):
        evaluate("random", env="env1", budget=1, protocol="unseen", split="paper")
    with pytest.raises(ValueError, match="unknown protocol 'holdout'"):
        evaluate("random", env="env1", budget=1, protocol="holdout")


# ------------------------------------------------------------------ AG's weighting
def test_ag_default_weighting_is_per_map_unless_given():
    assert default_weighting("UavIpp-Env3-v0") == WEIGHTING_BY_MAP["env3"]
    assert default_weighting(None) == default_weighting("my_field") == FALLBACK_WEIGHTING
    r = evaluate("ag", env="env3", n_trials=1, budget=1, record=0)
    assert r.planner_kwargs["weighting"] == WEIGHTING_BY_MAP["env3"]
    other = "class" if WEIGHTING_BY_MAP["env3"] == "plain" else "plain"
    assert (
        evaluate("ag", env="env3", n_trials=1, budget=1, record=0, planner_kwargs={"weighting": other}).planner_kwargs[
            "weighting"
        ]
        == other
    )
    assert evaluate("lawnmower", env="env3", n_trials=1, budget=1, record=0).planner_kwargs == {}


def test_ag_weighting_picker_never_touches_the_test_split():
    calls = []

    def recorder(method, **kwargs):
        calls.append(dict(kwargs))
        return evaluate(method, **kwargs)

    choice = pick_ag_weighting("env2", n_missions=2, budget=2, evaluate=recorder)
    assert len(calls) == 2 and {c["planner_kwargs"]["weighting"] for c in calls} == {"class", "plain"}
    for c in calls:
        assert c["split"] == "train" and c.get("protocol") is None and c["split"] != "test"
        assert c["seed"] >= VALIDATION_SEED and c["seed"] + c["n_trials"] - 1 < VALIDATION_SEED + 1000
    assert choice.env_options["split"] == "train" and choice.choice in ("class", "plain")
    assert set(choice.paired) == {"entropy", "f1"} and "split 'train'" in choice.comment()
    assert validation_options(budget=2) == {"budget": 2, "split": "train", "noise": "moderate"}
    for bad in ({"split": "test"}, {"split": "paper"}):
        with pytest.raises(ValueError, match="chooses on split='train'"):
            pick_ag_weighting("env1", n_missions=2, evaluate=recorder, **bad)
    with pytest.raises(ValueError, match="validation seeds start at"):
        pick_ag_weighting("env1", n_missions=2, seed=0, evaluate=recorder)
    assert len(calls) == 2  # the refused calls flew nothing


def test_ag_weighting_rule_prefers_entropy_then_f1_then_class():
    def fake(entropy, f1):
        def run(method, **kwargs):
            w = kwargs["planner_kwargs"]["weighting"]
            e, f = np.asarray(entropy[w]), np.asarray(f1[w])
            return SimpleNamespace(
                method=w,
                env="e",
                seed=kwargs["seed"],
                n_trials=len(e),
                env_options=kwargs,
                f1=np.column_stack([f, f]),
                entropy=np.column_stack([e, e]),
                team_f1=None,
                team_entropy=None,
            )

        return run

    lower = {"class": [0.5, 0.6, 0.55], "plain": [0.4, 0.52, 0.46]}
    same = {"class": [0.5, 0.6, 0.55], "plain": [0.5, 0.6, 0.55]}
    assert pick_ag_weighting("e", n_missions=3, evaluate=fake(lower, same)).choice == "plain"
    higher_f1 = {"class": [0.7, 0.8, 0.75], "plain": [0.6, 0.71, 0.66]}
    assert pick_ag_weighting("e", n_missions=3, evaluate=fake(same, higher_f1)).choice == "class"
    tie = pick_ag_weighting("e", n_missions=3, evaluate=fake(same, same))
    assert tie.choice == "class" and "tie" in tie.reason


# ------------------------------------------------------------------ noise sweep
def test_sweep_points_one_axis_at_a_time_and_grid():
    points = sweep_points()
    assert len(points) == 2 * (1 + 5 + 3 + 1)  # centre + the other values of each axis, per decoder
    assert {p.decoder for p in points} == {"soft", "threshold"}
    assert all(
        sum(getattr(p, a) != c for a, c in (("sigma", 0.02), ("alpha_low", 0.8), ("drop_probability", 0.0))) <= 1
        for p in points
    )
    assert len(sweep_points(grid=True)) == 2 * 6 * 4 * 2
    assert len(sweep_points(QUICK_AXES)) == 2 * 4
    with pytest.raises(ValueError, match="unknown noise-sweep axes"):
        sweep_points({"wind": (1,)})


def test_noise_sweep_quick_table_has_both_metric_families(tmp_path):
    arms = [Method("ag", "ag"), Method("random", "random")]
    result = run_noise_sweep(arms, env="env1", n_missions=2, quick=True, log=None, **TINY)
    assert len(result.results) == 2 * len(sweep_points(QUICK_AXES)) and result.reference == "ag"
    for (_arm, point), r in result.results.items():
        assert r.env_options["split"] == "test" and r.env_options["sigma"] == point.sigma
        assert r.env_options["decoder"] == point.decoder and r.env_options["drop_probability"] == point.drop_probability
    table = result.markdown()
    assert all(h in table.splitlines()[0] for h in METRIC_HEADS) and "team entropy − ag" in table
    assert len(table.strip().splitlines()) == 2 + len(result.results)
    rows = result.rows()
    assert all(r["team_entropy_mean"] > 0 and r["entropy_mean"] > 0 for r in rows)
    assert all((r["entropy_vs_ag"] is None) == (r["arm"] == "ag") for r in rows)
    with result.write_csv(tmp_path / "s.csv").open() as fh:
        header = next(csv.reader(fh))
    assert {"f1_mean", "entropy_mean", "team_f1_mean", "team_entropy_mean", "team_entropy_vs_ag_verdict"} <= set(header)
    from sb3_coma.experiments import plots

    assert plots.plot_noise_sweep(result, tmp_path / "s.png").stat().st_size > 0
    with pytest.raises(ValueError, match="sets \\['sigma'\\] itself"):
        run_noise_sweep(arms, env="env1", n_missions=2, sigma=0.1)


def test_noise_sweep_command_quick(tmp_path, capsys):
    out = tmp_path / "sweep"
    assert main(["noise-sweep", "--quick", "--arms", "ag", "--env", "env1", "--budget", "2", "--out", str(out)]) == 0
    assert (
        (out / "noise_sweep.md").is_file()
        and (out / "noise_sweep.csv").is_file()
        and (out / "noise_sweep.png").is_file()
    )
    assert "team entropy" in capsys.readouterr().out
    assert main(["noise-sweep", "--quick", "--arms", "", "--out", str(out)]) == 2


# ------------------------------------------------------------------ costs, reproduce with baselines only
def test_cost_table_times_ag_for_every_lookahead():
    from sb3_coma.experiments.costs import costs_markdown, decision_costs

    rows = decision_costs({}, envs=["env1"], lookaheads=(1, 2, 3), repeats=8, budget=3)
    w = WEIGHTING_BY_MAP["env1"]
    assert [r.what for r in rows] == [f"AG ({w})", f"AG, look-ahead k=2 ({w})", f"AG, look-ahead k=3 ({w})"]
    assert all(r.ms is not None and r.ms > 0 for r in rows)
    assert "AG, look-ahead k=3" in costs_markdown(rows)


def test_reproduce_quick_with_baselines_only(tmp_path):
    from sb3_coma.experiments.reproduce import reproduce

    out = tmp_path / "res"
    docs = tmp_path / "docs" / "RESULTS.md"
    summary = reproduce(out, env_names=["env1"], quick=True, baselines_only=True, docs=docs, log=None)
    assert summary["models"] == {} and summary["acceptance"] == {}
    assert set(summary["table"]) == {f"env1/{m.label}" for m in BASELINE_METHODS}
    assert summary["paper"]["split"] == "paper" and summary["unseen"]["split"] == "test"
    assert summary["unseen"]["missions"] == 2 and summary["noise_sweep"]["arms"] == ["ag"]
    assert {r["what"].split(" (")[0] for r in summary["latency"]} == {"AG", "AG, look-ahead k=2", "AG, look-ahead k=3"}
    for name in (
        "table.md",
        "team_table.md",
        "paper_verdicts.md",
        "unseen_table.md",
        "unseen_team_table.md",
        "unseen_verdicts.md",
        "noise_sweep.md",
        "latency.md",
        "summary.json",
        "RESULTS.md",
        "figures/noise_sweep.png",
        "figures/unseen_curves.png",
    ):
        assert (out / name).is_file(), name
    text = docs.read_text()
    for section in (
        "## Paragraph for README's results section",
        "## Table I (paper protocol)",
        "## Unseen protocol",
        "## Noise sweep",
        "## Deployment latency and cost",
        "team entropy",
    ):
        assert section in text, section
    assert (docs.parent / "figures" / "noise_sweep.png").is_file()


def test_ag_weighting_command(tmp_path, capsys):
    path = tmp_path / "w.json"
    assert main(["ag-weighting", "--env", "env1", "--missions", "2", "--budget", "2", "--json", str(path)]) == 0
    out = capsys.readouterr().out
    assert "#: env1:" in out and "split 'train', seeds 2000..2001" in out
    (entry,) = json.loads(path.read_text())
    assert entry["env_options"]["split"] == "train" and entry["choice"] in ("class", "plain")
    assert main(["ag-weighting", "--env", "env1", "--missions", "2", "--seed", "5"]) == 2
    assert "validation seeds start at 2000" in capsys.readouterr().err


def test_budget_sweep_flies_every_budget_on_shared_missions():
    from sb3_coma.experiments import budget_sweep

    results = budget_sweep.sweep("env1", [4, 6], missions=2, seed=0)
    assert set(results) == {4, 6}
    for budget, flown in results.items():
        assert set(flown) == {"coma", "ag", "ag-k3"}
        assert all(r.budget == budget and r.f1.shape == (2, budget + 1) for r in flown.values())
    text = budget_sweep.table(results)
    assert text.count("\n| 4 |") == 2 and "COMA - AG-k3" in text
