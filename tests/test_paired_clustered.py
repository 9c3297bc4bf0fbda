"""Clustered paired statistics (sb3_coma.stats.paired): scenes, CR2 (and the old CR1) standard
errors, the t test, Holm's correction, the one-scene case, refusals and the per-scene table, on
hand-made examples (tests/test_paired_cr2.py checks CR2 against an outside reference)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from result_fakes import fake_result

from sb3_coma.common.evaluation import PROTOCOLS, scene_label
from sb3_coma.experiments.protocols import Method, ProtocolResult
from sb3_coma.stats.paired import (
    NO_VERDICT,
    PairedDifference,
    cell,
    clustered_mean_se,
    holm,
    holm_adjust,
    paired_difference,
    paired_markdown,
    scene_markdown,
    t_cdf,
    t_ppf,
    t_two_sided_p,
)


def _one_scene_effect():
    """3 scenes x 10 missions; scene s1 carries the whole effect (a is 0.05 better there, equal elsewhere)."""
    jitter = np.tile([-0.004, -0.002, 0.0, 0.002, 0.004], 2)  # the same small spread in every scene
    d = np.concatenate([0.05 + jitter, jitter, -jitter])
    scenes = ["s1"] * 10 + ["s2"] * 10 + ["s3"] * 10
    base = np.linspace(0.5, 0.7, 30)
    return fake_result("a", base + d, scenes), fake_result("b", base, scenes), d, scenes


# ------------------------------------------------------------------ Student's t
def test_t_distribution_matches_the_tables():
    for df, quantile in ((1, 12.706), (9, 2.262), (30, 2.042)):
        assert t_ppf(0.975, df) == pytest.approx(quantile, abs=5e-4)
        assert t_cdf(quantile, df) == pytest.approx(0.975, abs=1e-4)
        assert t_two_sided_p(quantile, df) == pytest.approx(0.05, abs=2e-4)
    assert t_cdf(0.0, 5) == 0.5 and t_cdf(-2.0, 7) == pytest.approx(1 - t_cdf(2.0, 7))
    assert t_ppf(0.025, 9) == pytest.approx(-2.262, abs=5e-4)
    assert t_two_sided_p(math.inf, 3) == 0.0 and math.isnan(t_two_sided_p(1.0, 0))
    with pytest.raises(ValueError, match="t_ppf needs 0 < q < 1"):
        t_ppf(1.0, 3)


def test_t_distribution_agrees_with_scipy_where_installed():
    stats = pytest.importorskip("scipy.stats")
    for df in (1, 2, 3.5, 9, 49, 300):
        for t in (-7.0, -1.0, 0.3, 1.96, 4.0, 40.0):
            assert t_cdf(t, df) == pytest.approx(stats.t.cdf(t, df), abs=1e-12)
        assert t_ppf(0.975, df) == pytest.approx(stats.t.ppf(0.975, df), rel=1e-9)


# ------------------------------------------------------------------ Holm
def test_holm_on_a_known_vector():
    # sorted: 0.005 x 4 = 0.02, 0.01 x 3 = 0.03, 0.03 x 2 = 0.06, 0.04 x 1 = 0.04 -> kept monotone: 0.06
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([0.6, 0.7]) == [1.0, 1.0]  # capped at 1, monotone
    out = holm([0.02, float("nan"), 0.04])  # a comparison without a test is not in the family
    assert out[0] == pytest.approx(0.04) and math.isnan(out[1]) and out[2] == pytest.approx(0.04)
    assert holm([]) == []
    with pytest.raises(ValueError, match="p-values must be in"):
        holm([0.5, 1.5])


def test_holm_turns_two_lone_wins_into_ties_in_one_table():
    se = 0.01
    rows = [
        PairedDifference("a", "b", "f1", 10, 0.6, 0.5, t_ppf(1 - p / 2, 9) * se, se) for p in (0.03, 0.04)
    ]  # each alone p = 0.03 / 0.04 < 0.05
    assert [r.verdict for r in rows] == ["a better", "a better"]
    adjusted = holm_adjust(rows)
    assert [r.p_holm for r in adjusted] == pytest.approx([0.06, 0.06], abs=1e-6)
    assert [r.verdict for r in adjusted] == ["tie", "tie"] and holm_adjust(adjusted) == adjusted
    text = paired_markdown(rows)
    assert text.count("| tie |") == 2 and "a better" not in text and "| 0.060 |" in text


# ------------------------------------------------------------------ the clustered estimator
def test_cr1_standard_error_by_hand():
    # mean 4; cluster sums of residuals: x (1-4)+(2-4)+(3-4) = -6, y 10-4 = 6; G/(G-1) * 72 / 16 = 9
    assert clustered_mean_se([1.0, 2.0, 3.0, 10.0], ["x", "x", "x", "y"], method="CR1") == pytest.approx((4.0, 3.0, 2))
    # The default became CR2 (issue #35), which weighs each cluster by 1 / (1 - n_g / N) instead of
    # G / (G - 1): (36 / (1 - 3/4) + 36 / (1 - 1/4)) / 16 = (144 + 48) / 16 = 12, so the expected
    # 3.0 (CR1) is now sqrt(12) for these two unequal clusters.
    assert clustered_mean_se([1.0, 2.0, 3.0, 10.0], ["x", "x", "x", "y"]) == pytest.approx((4.0, math.sqrt(12.0), 2))
    d = np.array([0.1, 0.3, 0.2, 0.6, 0.5, 0.4])
    # equal cluster sizes: the ordinary standard error of the cluster means
    means = np.array([0.2, 0.4, 0.45])
    _, se, g = clustered_mean_se(d, ["p", "p", "q", "q", "r", "r"])
    assert g == 3 and se == pytest.approx(means.std(ddof=1) / math.sqrt(3))
    # one value per cluster: the ordinary standard error of the values
    assert clustered_mean_se(d, list("abcdef"))[1] == pytest.approx(d.std(ddof=1) / math.sqrt(6))
    mean, se, g = clustered_mean_se(d, ["one"] * 6)
    assert g == 1 and math.isnan(se) and mean == pytest.approx(d.mean())


def test_one_scene_carrying_the_effect_wins_naively_but_ties_clustered():
    a, b, d, _scenes = _one_scene_effect()
    naive = paired_difference(a, b, "f1", scenes=[str(k) for k in range(30)])  # missions as if independent
    clustered = paired_difference(a, b, "f1")
    assert naive.diff == clustered.diff == pytest.approx(d.mean())
    assert naive.n_clusters == 30 and naive.verdict == "a better" and naive.p_value < 0.001
    assert clustered.n_clusters == 3 and clustered.df == 2 and clustered.verdict == "tie"
    assert clustered.se == pytest.approx(d.std(ddof=1) / math.sqrt(30))  # the plain s.e. stays available
    means = np.array([d[:10].mean(), d[10:20].mean(), d[20:].mean()])
    assert clustered.se_clustered == pytest.approx(means.std(ddof=1) / math.sqrt(3))
    assert clustered.t == pytest.approx(1.0) and clustered.p_value == pytest.approx(t_two_sided_p(1.0, 2))
    row = clustered.as_dict()
    assert row["n_clusters"] == 3 and row["df"] == 2 and row["verdict"] == "tie" and row["p_holm"] == row["p_value"]
    # the entropy (lower is better) sees the same thing from the other side
    assert paired_difference(b, a, "entropy", scenes=[str(k) for k in range(30)]).verdict == "a better"


def test_one_scene_gives_no_verdict_and_labels_the_noise_draws():
    values = [0.60, 0.61, 0.62, 0.60, 0.61, 0.63, 0.60, 0.62, 0.61, 0.60]
    a = fake_result("coma", np.array(values) + 0.05, ["env3"] * 10, split="paper", start=None)
    b = fake_result("ag", values, ["env3"] * 10, split="paper", start=None)
    d = paired_difference(a, b, "f1")
    assert d.n == 10 and d.n_clusters == 1 and d.df == 0 and d.verdict == NO_VERDICT and d.winner is None
    assert d.unit == "noise draws of one mission" and d.se == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(d.p_value) and math.isnan(holm_adjust([d])[0].p_holm)
    assert NO_VERDICT in cell(d) and "over noise draws of one mission" in cell(d)
    text = paired_markdown([d])
    assert "| coma | ag | f1 | 10 |" in text and f"| {NO_VERDICT} | 1 | n/a |" in text
    # random starts on one scene are missions of that scene, still no verdict
    r = paired_difference(fake_result("x", [0.1, 0.2], ["s", "s"]), fake_result("y", [0.0, 0.1], ["s", "s"]), "f1")
    assert r.unit == "missions of one scene" and r.verdict == NO_VERDICT


# ------------------------------------------------------------------ refusals
def test_refuses_results_flown_under_different_settings():
    base = fake_result("a", [0.5, 0.6], ["s", "t"], noise="moderate")
    for option, mine, theirs in (
        ("noise", "moderate", "loud"),
        ("comm_range", 25.0, 10.0),
        ("decoder", "soft", "threshold"),
        ("drop_probability", 0.0, 0.3),
        ("sigma", None, 0.2),
        ("lattice", 11, 9),
        ("comm_grid", 44, 40),
    ):
        other = fake_result("b", [0.5, 0.6], ["s", "t"], **{**base.env_options, option: theirs})
        mine_r = fake_result("a", [0.5, 0.6], ["s", "t"], **{**base.env_options, option: mine})
        with pytest.raises(ValueError, match=f"not flown under the same settings: {option} {mine!r} vs {theirs!r}"):
            paired_difference(mine_r, other, "f1")
    with pytest.raises(ValueError, match="not the same missions: budget 15 vs 10"):
        paired_difference(base, fake_result("b", [0.5, 0.6], ["s", "t"], budget=10), "f1")
    with pytest.raises(ValueError, match="not the same missions: n_uavs 4 vs 3"):
        paired_difference(base, fake_result("b", [0.5, 0.6], ["s", "t"], n_uavs=3), "f1")
    with pytest.raises(ValueError, match="not the same missions: start 'random' vs 'fixed'"):
        paired_difference(base, fake_result("b", [0.5, 0.6], ["s", "t"], start="fixed"), "f1")
    with pytest.raises(ValueError, match="not the same missions: scene of mission 1 't' vs 'u'"):
        paired_difference(base, fake_result("b", [0.5, 0.6], ["s", "u"]), "f1")
    with pytest.raises(ValueError, match="not the same missions: seed 0 vs 1"):
        paired_difference(base, fake_result("b", [0.5, 0.6], ["s", "t"], seed=1), "f1")


def test_pairs_what_only_changes_a_models_observation_or_is_spelled_differently():
    a = fake_result("coma", [0.5, 0.7], ["s", "t"], noise="moderate", action_gain=False, altitudes=[5, 10, 15])
    b = fake_result("ag", [0.4, 0.6], ["s", "t"])  # defaults: moderate noise, action_gain True, (5.0, 10.0, 15.0)
    assert paired_difference(a, b, "f1").n == 2
    c = fake_result("c", [0.4, 0.6], ["s", "t"], start=None)  # split test: None means random starts
    assert paired_difference(a, c, "f1").n == 2
    unlabelled = fake_result("d", [0.4, 0.6])  # no scene labels: the other result's are used
    assert paired_difference(a, unlabelled, "f1").n_clusters == 2


# ------------------------------------------------------------------ per-scene table
def test_scene_table_shows_which_scene_carries_the_difference():
    a, b, d, _ = _one_scene_effect()
    diff = paired_difference(a, b, "f1")
    text = scene_markdown(diff)
    lines = text.strip().splitlines()
    assert lines[0] == "| scene | missions | a f1 | b f1 | a - b |" and len(lines) == 2 + 3 + 1
    assert lines[2].startswith("| s1 | 10 |") and lines[2].endswith(f"| {d[:10].mean():+.4f} |")
    assert lines[3].endswith(("| +0.0000 |", "| -0.0000 |")) and lines[-1].startswith("| all (3 scenes) | 30 |")
    assert "no scene labels" in scene_markdown(PairedDifference("a", "b", "f1", 3, 0.5, 0.4, 0.1, 0.01))

    stars = [f"env1/test/star{k}" for k in range(30)]
    result = ProtocolResult(
        PROTOCOLS["unseen"],
        30,
        0,
        "moderate",
        {"split": "test"},
        methods={
            "env3": [Method("a", "ag"), Method("b", "random")],
            "env1": [Method("a", "ag"), Method("b", "random")],
        },
        results={
            ("env3", "a"): a,
            ("env3", "b"): b,
            ("env1", "a"): fake_result("a", a.f1[:, -1], stars),
            ("env1", "b"): fake_result("b", b.f1[:, -1], stars),
        },
    )
    table = result.scene_table(
        metric="f1", comparisons=result.comparisons({"env3": [("a", "b")], "env1": [("a", "b")]})
    )
    assert "env3, a vs b, f1 @100%: tie" in table and "| s1 | 10 |" in table
    assert "env1, a vs b: every mission is its own scene (30 scenes)." in table


def test_protocol_verdict_tables_are_one_holm_family():
    a, b, _, _ = _one_scene_effect()
    a.method, b.method = "ag", "random"
    result = ProtocolResult(
        PROTOCOLS["unseen"],
        30,
        0,
        "moderate",
        {"split": "test"},
        methods={"env3": [Method("ag", "ag"), Method("random", "random")]},
        results={("env3", "ag"): a, ("env3", "random"): b},
    )
    (c,) = result.comparisons()  # default pairs: ag vs random, on all four metrics
    raw = [d.p_value for d in c.diffs.values()]
    assert len(raw) == 4 and [d.p_holm for d in c.diffs.values()] == pytest.approx(holm(raw))
    table = result.verdict_table()
    assert "(tie)" in table and ", p " in table and "ag better" not in table


# ------------------------------------------------------------------ scene labels of real missions
def test_scene_label_drops_only_a_trailing_transform():
    assert scene_label("env3/test/south1/rot90") == "env3/test/south1"
    assert scene_label("env2/train/north/anti-transpose") == "env2/train/north"
    assert scene_label("env1/test/star2000000007") == "env1/test/star2000000007"
    assert scene_label("env3") == "env3" and scene_label("orchard") == "orchard"


def test_evaluate_records_one_scene_per_mission():
    from sb3_coma.app.evaluation import evaluate

    r = evaluate("random", env="env3", n_trials=3, seed=0, record=0, budget=1, split="test", n_envs=2)
    assert r.scenes is not None and len(r.scenes) == 3
    assert all(s.startswith("env3/test/") and s.count("/") == 2 for s in r.scenes)
    again = evaluate("lawnmower", env="env3", n_trials=3, seed=0, record=0, budget=1, split="test", n_envs=3)
    assert again.scenes == r.scenes  # the same seeds are the same scenes, however they are batched
    paper = evaluate("random", env="env2", n_trials=2, seed=0, record=0, budget=1)
    assert paper.scenes == ("env2", "env2")
