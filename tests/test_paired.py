"""Paired comparisons on shared missions (sb3_coma.stats.paired): differences, standard errors, verdicts."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from sb3_coma.stats.paired import NO_VERDICT, PairedDifference, paired_difference, paired_markdown


def _result(
    method: str, final_entropy: list[float], final_f1: list[float] | None = None, seed: int = 0, env: str = "env3"
) -> SimpleNamespace:
    n = len(final_entropy)
    entropy = np.ones((n, 4))
    entropy[:, -1] = final_entropy
    f1 = np.zeros((n, 4))
    f1[:, -1] = final_f1 if final_f1 is not None else 0.5
    return SimpleNamespace(method=method, env=env, seed=seed, n_trials=n, entropy=entropy, f1=f1)


def test_difference_and_standard_error_are_per_mission():
    a = _result("coma", [0.30, 0.40, 0.50, 0.60])
    b = _result("ag", [0.32, 0.43, 0.51, 0.64])  # a is lower by 0.02, 0.03, 0.01, 0.04
    d = paired_difference(a, b, "entropy")
    diffs = np.array([-0.02, -0.03, -0.01, -0.04])
    assert d.n == 4 and d.diff == pytest.approx(diffs.mean())
    assert d.se == pytest.approx(diffs.std(ddof=1) / 2.0)
    # The missions' own spread (std 0.13) would hide a 0.025 difference; pairing does not.
    assert d.verdict == "coma better"
    assert d.mean_a == pytest.approx(0.45) and d.mean_b == pytest.approx(0.475)


def test_verdicts_follow_the_metric_direction_and_call_small_differences_ties():
    a = _result("x", [0.5, 0.5, 0.5], final_f1=[0.8, 0.9, 0.7])
    b = _result("y", [0.5, 0.5, 0.5], final_f1=[0.7, 0.8, 0.6])
    assert paired_difference(a, b, "f1").verdict == "x better"  # higher F1 is better
    assert paired_difference(b, a, "f1").verdict == "x better"
    assert paired_difference(a, b, "entropy").verdict == "tie"  # identical: a tie, not a win
    noisy = _result("z", [0.48, 0.53, 0.50])
    assert paired_difference(noisy, b, "entropy").verdict == "tie"  # +0.003 +- 0.015
    one = paired_difference(_result("p", [0.1]), _result("q", [0.9]), "entropy")
    # One mission cannot tell: it is one scene, so the clustered test has no degrees of freedom and
    # says so (it used to read "tie"); no winner either way.
    assert np.isnan(one.se) and one.verdict == NO_VERDICT and one.winner is None


def test_refuses_different_missions_and_unknown_metrics():
    a = _result("a", [0.3, 0.4])
    with pytest.raises(ValueError, match="not the same missions: seed 0 vs 5"):
        paired_difference(a, _result("b", [0.3, 0.4], seed=5))
    with pytest.raises(ValueError, match="not the same missions: n_trials 2 vs 3"):
        paired_difference(a, _result("b", [0.3, 0.4, 0.5]))
    with pytest.raises(ValueError, match="metric must be 'f1', 'entropy', 'team_f1' or 'team_entropy', got 'return'"):
        paired_difference(a, a, "return")


def test_scene_labels_must_be_one_per_mission():
    """The label count is checked once (cluster_robust_mean); a result's own labels that fall
    short of the other's are still refused, mission by mission."""
    a, b = _result("a", [0.3, 0.4, 0.5]), _result("b", [0.3, 0.4, 0.5])
    with pytest.raises(ValueError, match="2 cluster labels for 3 values"):
        paired_difference(a, b, scenes=["s0", "s1"])
    a.scenes, b.scenes = ("s0", "s0", "s1"), ("s0", "s0")
    with pytest.raises(ValueError, match="not the same missions: scene of mission 2 's1' vs None"):
        paired_difference(a, b)
    b.scenes = ("s0", "s0")
    a.scenes = ("s0", "s0")
    with pytest.raises(ValueError, match="2 cluster labels for 3 values"):
        paired_difference(a, b)


def test_markdown_table_has_one_row_per_comparison():
    d = PairedDifference("coma", "ag", "entropy", 50, 0.31, 0.33, -0.02, 0.005)
    text = paired_markdown([d, d], ["env1", "env2"])
    lines = text.strip().splitlines()
    assert lines[0].startswith("| Env | a | b |") and len(lines) == 4
    assert "| env2 | coma | ag | entropy | 50 | 0.3100 | 0.3300 | -0.0200 ± 0.0050 | coma better |" in text
    assert d.as_dict()["verdict"] == "coma better"
