"""The verdicts' small-sample cluster-robust statistics (issue #35): CR2 with Bell-McCaffrey degrees
of freedom for the mean of paired differences (sb3_coma.stats.paired.cluster_robust_mean).

Three checks of the closed form the module uses for a regression on 1:
* against an independent general-matrix implementation written here (any design X; the
  adjustment ``A_g`` as ``scipy.linalg.sqrtm`` of ``(I - H_gg)^-1``, the Satterthwaite df from
  Pustejovsky and Tipton's ``(sum_g p_g'p_g)^2 / sum_{g,h} (p_g'p_h)^2``);
* against an outside reference, diff-diff's ``compute_robust_vcov(..., vcov_type="hc2_bm")``
  (its docs: Pustejovsky-Tipton CR2 Bell-McCaffrey, matching R's clubSandwich), and its CR1
  (``vcov_type="hc1"`` with clusters) for the old formula; the general form is checked against
  it too, on a design with a covariate;
* properties on seeded random data: CR2 >= CR0, 1 <= df <= G - 1, equal sizes give the ordinary
  standard error of the cluster means on G - 1 df, two clusters give df 1, CR1 and CR2 can each
  be the larger.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from result_fakes import fake_result

from sb3_coma.stats.paired import (
    NO_VERDICT,
    SE_METHOD,
    bell_mccaffrey_df,
    cluster_robust_mean,
    clustered_mean_se,
    paired_difference,
    paired_markdown,
    t_ppf,
    t_two_sided_p,
)

#: Cluster sizes of the checks: env3's 50 unseen missions (seeds 0-49 fall in its 9 test scenes
#: this way), env2's 8 scenes, very unequal ones, two clusters, singletons and equal sizes.
SIZES = (
    (2, 3, 4, 5, 5, 6, 7, 8, 10),
    (4, 5, 5, 6, 7, 7, 8, 8),
    (1, 1, 1, 10),
    (20, 1, 1),
    (2, 3),
    (1,) * 7,
    (4,) * 5,
)


def _clustered_data(sizes, seed, effect=0.01):
    """Differences with a scene effect and a mission effect; labels in a shuffled order."""
    rng = np.random.default_rng(seed)
    labels = np.repeat([f"s{k}" for k in range(len(sizes))], sizes)
    scene = dict(zip([f"s{k}" for k in range(len(sizes))], rng.normal(0.0, effect, len(sizes))))
    order = rng.permutation(len(labels))
    labels = labels[order]
    d = 0.005 + np.array([scene[s] for s in labels]) + rng.normal(0.0, effect, len(labels))
    return d, [str(s) for s in labels]


def _cr2_general(x, y, clusters, contrast):
    """CR2 estimate, standard error and Bell-McCaffrey / Satterthwaite df of ``contrast' beta`` in
    the OLS regression of ``y`` on ``x``, in the general matrix form (Bell and McCaffrey 2002;
    Pustejovsky and Tipton 2018, working model the identity), independent of the closed form."""
    scipy_linalg = pytest.importorskip("scipy.linalg")
    x, y, c = np.asarray(x, float), np.asarray(y, float), np.asarray(contrast, float)
    n = len(y)
    bread = np.linalg.inv(x.T @ x)
    beta = bread @ x.T @ y
    hat = x @ bread @ x.T
    residual_maker = np.eye(n) - hat
    e = residual_maker @ y
    labels = np.asarray(clusters)
    meat = np.zeros((x.shape[1], x.shape[1]))
    p_vectors = []
    for g in dict.fromkeys(clusters):
        rows = np.flatnonzero(labels == g)
        block = np.eye(len(rows)) - hat[np.ix_(rows, rows)]
        adjust = np.real(scipy_linalg.sqrtm(np.linalg.inv(block)))  # A_g = (I - H_gg)^{-1/2}
        score = x[rows].T @ adjust @ e[rows]
        meat += np.outer(score, score)
        # c' M X_g' A_g e_g = p_g' y with p_g = (I - H)_{g.}' A_g X_g M c
        p_vectors.append(residual_maker[rows].T @ adjust @ x[rows] @ bread @ c)
    variance = float(c @ bread @ meat @ bread @ c)
    gram = np.array(p_vectors) @ np.array(p_vectors).T
    df = float(np.trace(gram) ** 2 / np.sum(gram**2))
    return float(c @ beta), math.sqrt(variance), df


# ------------------------------------------------------------------ the closed form vs the matrix form
@pytest.mark.parametrize("sizes", SIZES)
def test_closed_form_matches_the_general_matrix_form(sizes):
    for seed in range(3):
        d, labels = _clustered_data(sizes, seed)
        r = cluster_robust_mean(d, labels)
        mean, se, df = _cr2_general(np.ones((len(d), 1)), d, labels, [1.0])
        assert r.method == SE_METHOD == "CR2" and r.n_clusters == len(sizes)
        assert r.mean == pytest.approx(mean, rel=1e-12)
        assert r.se == pytest.approx(se, rel=1e-9)
        assert r.df == pytest.approx(df, rel=1e-9)
        assert bell_mccaffrey_df(sizes) == pytest.approx(df, rel=1e-9)


# ------------------------------------------------------------------ the outside reference
def test_cr2_and_cr1_match_diff_diff():
    """diff-diff (PyPI ``diff-diff``, in the ``test`` extra) as the outside reference."""
    from diff_diff.linalg import compute_robust_vcov

    for sizes in SIZES:
        d, labels = _clustered_data(sizes, seed=7)
        ones = np.ones((len(d), 1))
        codes = np.unique(labels, return_inverse=True)[1]
        vcov, dof = compute_robust_vcov(ones, d - d.mean(), codes, vcov_type="hc2_bm", return_dof=True)
        r = cluster_robust_mean(d, labels)
        assert r.se == pytest.approx(math.sqrt(vcov[0, 0]), rel=1e-9), sizes
        assert r.df == pytest.approx(float(dof[0]), rel=1e-9), sizes
        # CR1: diff-diff's factor G/(G-1) (N-1)/(N-K) is G/(G-1) for K = 1 (only the vcov is compared:
        # its CR1 tail df is N - K, ours G - 1)
        vcov1 = compute_robust_vcov(ones, d - d.mean(), codes, vcov_type="hc1")
        assert cluster_robust_mean(d, labels, "CR1").se == pytest.approx(math.sqrt(vcov1[0, 0]), rel=1e-9)


def test_the_general_matrix_form_matches_diff_diff_with_a_covariate():
    """The matrix form above is checked itself, on a design that has no closed form."""
    from diff_diff.linalg import compute_robust_vcov

    d, labels = _clustered_data((2, 3, 4, 5, 5, 6, 7, 8, 10), seed=3)
    x = np.column_stack([np.ones(len(d)), np.random.default_rng(3).normal(size=len(d))])
    codes = np.unique(labels, return_inverse=True)[1]
    beta = np.linalg.lstsq(x, d, rcond=None)[0]
    vcov, dof = compute_robust_vcov(x, d - x @ beta, codes, vcov_type="hc2_bm", return_dof=True)
    for j in range(2):
        contrast = np.eye(2)[j]
        estimate, se, df = _cr2_general(x, d, labels, contrast)
        assert estimate == pytest.approx(beta[j], rel=1e-9)
        assert se == pytest.approx(math.sqrt(vcov[j, j]), rel=1e-9)
        assert df == pytest.approx(float(dof[j]), rel=1e-9)


# ------------------------------------------------------------------ properties
def test_properties_on_seeded_random_data():
    rng = np.random.default_rng(2026)
    for _ in range(300):
        g = int(rng.integers(2, 13))
        sizes = rng.integers(1, 16, size=g)
        d, labels = _clustered_data(sizes, seed=int(rng.integers(1 << 30)))
        cr0, cr1, cr2 = (cluster_robust_mean(d, labels, m) for m in ("CR0", "CR1", "CR2"))
        assert cr2.se >= cr0.se * (1 - 1e-12)  # every cluster's weight 1 / (1 - n_g / N) is >= 1
        assert cr1.se == pytest.approx(cr0.se * math.sqrt(g / (g - 1)))
        assert 1.0 <= cr2.df <= g - 1 and cr1.df == cr0.df == g - 1
        if g == 2:
            assert cr2.df == pytest.approx(1.0)  # any two clusters: df 1, however unequal
    for g, n in ((3, 10), (5, 4), (9, 1)):  # equal sizes: the ordinary s.e. of the cluster means
        d, labels = _clustered_data((n,) * g, seed=g)
        r = cluster_robust_mean(d, labels)
        means = np.array([d[np.array(labels) == s].mean() for s in dict.fromkeys(labels)])
        assert r.se == pytest.approx(means.std(ddof=1) / math.sqrt(g)) and r.df == g - 1  # exactly
        assert r.se == pytest.approx(cluster_robust_mean(d, labels, "CR1").se)


def test_neither_cr1_nor_cr2_is_always_the_larger():
    # the residual sits in the large cluster: CR2 weighs it 1 / (1 - 3/4) = 4 > CR1's 2
    big = [1.0, 2.0, 3.0, 10.0], ["x", "x", "x", "y"]
    assert clustered_mean_se(*big)[1] > clustered_mean_se(*big, method="CR1")[1]
    # ... in two small clusters of 1 beside one of 10: CR2 weighs them 1 / (1 - 1/12) < CR1's 3/2
    small = [0.0] * 10 + [1.0, -1.0], ["big"] * 10 + ["a", "b"]
    assert clustered_mean_se(*small)[1] == pytest.approx(math.sqrt(2 / (11 / 12)) / 12)
    assert clustered_mean_se(*small, method="CR1")[1] == pytest.approx(math.sqrt(1.5 * 2) / 12)
    # what makes CR1 liberal is mostly its df: G - 1 = 2 here, Bell-McCaffrey's 121 / 101 = 1.198
    # (shares 10/12, 1/12, 1/12; q = 25/6, 1/132, 1/132; 1 / (102/144 + 4 (25/6) / 132 + 2 / 132^2))
    assert bell_mccaffrey_df([10, 1, 1]) == pytest.approx(121 / 101)


def test_one_cluster_and_bad_methods():
    r = cluster_robust_mean([0.1, 0.2, 0.4], ["s"] * 3)
    assert r.n_clusters == 1 and math.isnan(r.se) and r.df == 0 and r.mean == pytest.approx(0.7 / 3)
    assert bell_mccaffrey_df([7]) == 0 and bell_mccaffrey_df([]) == -1
    with pytest.raises(ValueError, match="method must be one of"):
        cluster_robust_mean([0.1, 0.2], ["a", "b"], "CR3")
    with pytest.raises(ValueError, match="3 cluster labels for 2 values"):
        cluster_robust_mean([0.1, 0.2], ["a", "b", "c"])


def test_t_distribution_takes_a_float_df():
    stats = pytest.importorskip("scipy.stats")
    for df in (1.0, 1.03, 1.7, 4.26, 6.645):
        for t in (-5.0, 0.5, 2.0, 12.0):
            assert t_two_sided_p(t, df) == pytest.approx(2 * stats.t.sf(abs(t), df), abs=1e-12)
        assert t_ppf(0.975, df) == pytest.approx(stats.t.ppf(0.975, df), rel=1e-9)


# ------------------------------------------------------------------ the verdicts use it
def test_paired_difference_reads_cr2_and_the_bell_mccaffrey_df():
    d, labels = _clustered_data((2, 3, 4, 5, 5, 6, 7, 8, 10), seed=35)
    base = np.linspace(0.5, 0.7, len(d))
    diff = paired_difference(fake_result("a", base + d, labels), fake_result("b", base, labels), "f1")
    cr2, cr1 = cluster_robust_mean(d, labels), cluster_robust_mean(d, labels, "CR1")
    assert diff.se_clustered == pytest.approx(cr2.se) and diff.df == pytest.approx(cr2.df)
    assert diff.df == pytest.approx(bell_mccaffrey_df([2, 3, 4, 5, 5, 6, 7, 8, 10])) and 6 < diff.df < 7
    assert diff.p_value == pytest.approx(t_two_sided_p(diff.diff / cr2.se, cr2.df))
    assert diff.p_value > t_two_sided_p(diff.diff / cr1.se, 8)  # CR1 on 8 df claims more
    row = diff.as_dict()
    assert row["df"] == pytest.approx(cr2.df) and row["se_clustered"] == pytest.approx(cr2.se)
    assert f"| 9 (df {cr2.df:.1f}) |" in paired_markdown([diff])
    one = paired_difference(fake_result("a", [0.6, 0.7], ["s", "s"]), fake_result("b", [0.5, 0.6], ["s", "s"]), "f1")
    assert one.df == 0 and one.verdict == NO_VERDICT and "| 1 | n/a |" in paired_markdown([one])


def test_a_win_that_cr1_calls_is_a_tie_under_cr2():
    """Seeded example (50 missions, 9 unequal scenes) where the old CR1 test on G - 1 df says
    "a better" at p < 0.05 and CR2 with Bell-McCaffrey df says tie: tie stays tie."""
    rng = np.random.default_rng(107)
    sizes = rng.multinomial(50, [1 / 9] * 9)
    labels = [str(s) for s in np.repeat([f"s{k}" for k in range(9)], sizes)]
    d = 0.008 + np.repeat(rng.normal(0, 0.010, 9), sizes) + rng.normal(0, 0.01, 50)
    cr1 = cluster_robust_mean(d, labels, "CR1")
    assert t_two_sided_p(cr1.mean / cr1.se, cr1.df) < 0.05
    base = np.full(50, 0.5)
    diff = paired_difference(fake_result("a", base + d, labels), fake_result("b", base, labels), "f1")
    assert diff.verdict == "tie" and 0.05 <= diff.p_value < 0.06 and diff.df < 8


def test_protocol_tables_print_the_float_df_with_one_decimal(tmp_path):
    """The generated verdict files read the df from paired.py: one decimal in the CSV and the
    per-scene title, nothing recomputed there."""
    import csv

    from sb3_coma.common.evaluation import PROTOCOLS, EvaluationResult
    from sb3_coma.experiments.protocols import Method, ProtocolResult

    d, labels = _clustered_data((2, 3, 4, 5, 5, 6, 7, 8, 10), seed=35)
    base = np.linspace(0.5, 0.7, len(d))

    def result(method, f1):
        v = np.column_stack([np.zeros(len(f1)), f1])
        return EvaluationResult(
            method=method,
            env="env3",
            seed=0,
            n_trials=len(f1),
            budget=1,
            n_agents=4,
            fusion="mean",
            env_options={"split": "test", "start": "random"},
            f1=v,
            entropy=1 - v,
            returns=np.zeros(len(f1)),
            planning_time_ms=np.zeros(len(f1)),
            trajectories=np.zeros((len(f1), 4, 2, 3)),
            team_f1=v,
            team_entropy=1 - v,
            scenes=tuple(labels),
            protocol="unseen",
        )

    protocol = ProtocolResult(
        PROTOCOLS["unseen"],
        len(d),
        0,
        "moderate",
        {"split": "test"},
        methods={"env3": [Method("ag", "ag"), Method("random", "random")]},
        results={("env3", "ag"): result("ag", base + d), ("env3", "random"): result("random", base)},
    )
    df = f"{bell_mccaffrey_df([2, 3, 4, 5, 5, 6, 7, 8, 10]):.1f}"
    assert df == "6.6" and protocol.scene_table().splitlines()[0].endswith(f"Holm; df {df})")
    protocol.write(tmp_path)
    with (tmp_path / "unseen_verdicts.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 and {r["df"] for r in rows} == {df} and {r["scenes"] for r in rows} == {"9"}
    se = cluster_robust_mean(d, labels).se
    assert all(float(r["se_clustered"]) == pytest.approx(se, abs=1e-6) for r in rows)


def test_the_documented_example():
    """docs/statistics.md's table: CR0, CR1 and CR2 on env3's scene sizes, seed 0."""
    d, labels = _clustered_data((2, 3, 4, 5, 5, 6, 7, 8, 10), seed=0)
    assert round(float(d.mean()), 4) == 0.0082
    rows = {}
    for method in ("CR0", "CR1", "CR2"):
        r = cluster_robust_mean(d, labels, method)
        t = r.mean / r.se
        rows[method] = (round(r.se, 5), round(r.df, 2), round(t, 2), round(t_two_sided_p(t, r.df), 4))
    assert rows == {
        "CR0": (0.00247, 8.0, 3.33, 0.0104),
        "CR1": (0.00262, 8.0, 3.14, 0.0139),
        "CR2": (0.00269, 6.65, 3.06, 0.0195),
    }
