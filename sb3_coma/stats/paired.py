"""Paired comparisons of two methods flown on the same seeded missions, clustered by scene.

Table I and the ablation report mean +- std over missions, and the spread between missions
(0.01-0.05 in entropy) is as large as many of the differences the tables rank. Because every
method flies the *same* missions (env seed k for trial k), the per-mission difference
``a_k - b_k`` cancels most of that spread. But missions are not independent draws: an unseen
mission is a scene (a map crop) under one of 8 flips / rotations, and several missions share a
scene, so a method that suits one scene wins all of that scene's missions at once. The standard
error is therefore clustered by scene. A verdict table has 8-9 scenes of unequal size, where the
usual CR1 cluster-robust error with ``scenes - 1`` degrees of freedom rejects too often, so the
error is CR2 (Bell and McCaffrey's bias-reduced linearisation) and the t test uses the
Bell-McCaffrey / Satterthwaite degrees of freedom (Pustejovsky and Tipton 2018; Imbens and
Kolesar 2016), a float between 1 and ``scenes - 1``. The p-values of one verdict table are
Holm-corrected together (docs/statistics.md has the formulas and the outside check). With a single scene (the
paper's protocol: one mission, 10 noise draws) no test is possible: the verdict says so
(:data:`NO_VERDICT`) and the mission-level numbers are labelled as what they are.

Every "A beats B" that ``sb3-coma reproduce`` writes comes from here. Metrics: the paper's
``f1`` / ``entropy`` of the global map and the team metrics ``team_f1`` / ``team_entropy`` on the
UAVs' own local beliefs (lower entropy is better either way).

Two results are only paired when they are the same missions flown under the same settings
(:func:`check_same_missions`): same env, seed, mission count and scenes, and the same value of
every env option except the few in :data:`MAY_DIFFER`, which change what a model reads or how
the run is executed but not the world the missions are flown in.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from uav_ipp import IppConfig

#: Two-sided level of every verdict: "a better" / "b better" only when the Holm-adjusted p < ALPHA.
ALPHA = 0.05
#: The verdict when all missions share one scene: the clustered test has no degrees of freedom.
NO_VERDICT = "one scene: no verdict"
#: What ``n`` counts when all missions share one scene (fixed starts, or random starts).
ONE_MISSION = "noise draws of one mission"
ONE_SCENE = "missions of one scene"
#: The cluster-robust standard error the verdicts use (CR2 with Bell-McCaffrey degrees of freedom).
SE_METHOD = "CR2"
#: What :func:`cluster_robust_mean` computes: CR2 (the verdicts'), CR1 (the old ``G / (G - 1)``
#: correction with ``G - 1`` degrees of freedom, kept for comparison) and CR0 (no correction).
CLUSTER_METHODS = ("CR2", "CR1", "CR0")
#: Metrics a paired difference can be taken of, and whether lower is better.
METRICS: dict[str, bool] = {"f1": False, "entropy": True, "team_f1": False, "team_entropy": True}
#: Env options that decide *which* missions are flown; a difference in one of them reads "not the
#: same missions", in any other option "not flown under the same settings".
MISSION_OPTIONS = ("split", "start", "map_seed", "map_path", "n_uavs", "budget")
#: Env options (``uav_ipp.IppConfig``) two paired results may differ in, and why that does not change
#: the missions. Every other option (noise, comm_range, decoder, comm_grid, lattice, grid,
#: altitudes, field_size, fov_deg, ...) changes the world or the channel and must match. Keys of
#: ``env_options`` that are not ``IppConfig`` options (how the vec env is built: fusion_kwargs,
#: monitor, workers) are not the world and are not compared; the fusion is the method's own.
MAY_DIFFER: dict[str, str] = {
    "action_gain": "adds an observation key (the expected gain of each move); the world is the same",
    "observation": "v3 adds what a UAV observes (fine view, intent) and the critic's inputs; the missions, "
    "readings, links and channel draws are the same",
    "render_mode": "display only",
    "reward": "the return paid to a learner; no paired metric reads it",
    "reward_entropy": "the return paid to a learner; no paired metric reads it",
    "alpha": "the return paid to a learner (reward scale); no paired metric reads it",
    "beta": "the return paid to a learner (reward offset); no paired metric reads it",
}


def _field_default(f: dataclasses.Field[Any]) -> Any:
    """The default of a dataclass field, from its ``default`` or its ``default_factory``."""
    if f.default is not dataclasses.MISSING:
        return f.default
    assert f.default_factory is not dataclasses.MISSING, f"{f.name} has no default"
    return f.default_factory()


#: ``uav_ipp.IppConfig``'s options and defaults: an option a result does not name was flown at its default.
_DEFAULTS: dict[str, Any] = {f.name: _field_default(f) for f in dataclasses.fields(IppConfig) if f.name != "map_name"}


# ---------------------------------------------------------------------------------------------
# Student's t distribution (no scipy dependency: the regularized incomplete beta function)
# ---------------------------------------------------------------------------------------------
def _beta_fraction(a: float, b: float, x: float) -> float:
    """Continued fraction of the incomplete beta function (modified Lentz; Numerical Recipes 6.4)."""
    tiny, eps = 1e-300, 1e-15

    def guard(v: float) -> float:
        return v if abs(v) > tiny else tiny

    c, d = 1.0, 1.0 / guard(1.0 - (a + b) * x / (a + 1.0))
    h = d
    for m in range(1, 1000):
        even = m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m))
        odd = -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1))
        for num in (even, odd):
            d = 1.0 / guard(1.0 + num * d)
            c = guard(1.0 + num / c)
            h *= d * c
        if abs(d * c - 1.0) < eps:
            break
    return h


def _betainc(a: float, b: float, x: float) -> float:
    """Regularized incomplete beta ``I_x(a, b)``, for ``0 <= x <= 1``."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    if x < (a + 1.0) / (a + b + 2.0):  # the fraction converges fast here; else use the symmetry
        return math.exp(log_front) * _beta_fraction(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_fraction(b, a, 1.0 - x) / b


def t_two_sided_p(t: float, df: float) -> float:
    """``P(|T| >= |t|)`` for Student's t with ``df`` degrees of freedom (NaN in, NaN out)."""
    if math.isnan(t) or math.isnan(df) or df <= 0:
        return float("nan")
    if math.isinf(t):
        return 0.0
    return min(1.0, _betainc(df / 2.0, 0.5, df / (df + t * t)))


def t_cdf(t: float, df: float) -> float:
    """``P(T <= t)`` for Student's t with ``df`` degrees of freedom."""
    p = t_two_sided_p(t, df)
    return p / 2.0 if t < 0 else 1.0 - p / 2.0


def t_ppf(q: float, df: float) -> float:
    """The ``q`` quantile of Student's t (``t_ppf(0.975, 9) = 2.262``), by bisection on :func:`t_cdf`."""
    if not 0.0 < q < 1.0 or not df > 0:
        raise ValueError(f"t_ppf needs 0 < q < 1 and df > 0, got q={q!r}, df={df!r}")
    if q < 0.5:
        return -t_ppf(1.0 - q, df)
    lo, hi = 0.0, 1.0
    while t_cdf(hi, df) < q:
        lo, hi = hi, hi * 2.0
    for _ in range(200):
        mid = (lo + hi) / 2.0
        lo, hi = (mid, hi) if t_cdf(mid, df) < q else (lo, mid)
        if hi - lo < 1e-12 * max(1.0, hi):
            break
    return (lo + hi) / 2.0


# ---------------------------------------------------------------------------------------------
# the estimator and the multiple-comparison correction
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ClusteredMean:
    """A mean with its cluster-robust standard error and the degrees of freedom of its t test."""

    mean: float
    se: float
    n_clusters: int
    #: Degrees of freedom of the t test: Bell-McCaffrey (CR2) or ``G - 1`` (CR1, CR0); ``G - 1``
    #: (0, or -1 without values) when there are fewer than 2 clusters and no test exists.
    df: float
    method: str


def _cluster_sums(d: np.ndarray, clusters: Sequence[str]) -> tuple[float, np.ndarray, np.ndarray]:
    """(mean, residual sum ``u_g``, size ``n_g``) per cluster, clusters in order of first appearance."""
    if len(clusters) != len(d):
        raise ValueError(f"{len(clusters)} cluster labels for {len(d)} values")
    keys = {c: k for k, c in enumerate(dict.fromkeys(clusters))}
    index = np.array([keys[c] for c in clusters], dtype=np.int64)
    mean = float(d.mean()) if len(d) else float("nan")
    sums = np.bincount(index, weights=d - mean, minlength=len(keys))
    return mean, sums, np.bincount(index, minlength=len(keys)).astype(np.float64)


def bell_mccaffrey_df(sizes: Sequence[int] | np.ndarray) -> float:
    """Bell-McCaffrey / Satterthwaite degrees of freedom of the CR2 t test of a mean, from the
    cluster sizes ``n_g`` alone (``G - 1`` below 2 clusters, where no test exists).

    Why a formula of the sizes only: the approximation matches the first two moments of the CR2
    variance under the working model of independent, equal-variance missions (Bell and McCaffrey
    2002; Pustejovsky and Tipton 2018 with the identity working model, clubSandwich's default for
    ``lm``). For the intercept-only model, with ``p_g = n_g / N`` and ``q_g = p_g^2 / (1 - p_g)``,
    the general ``(sum_g p_g'p_g)^2 / sum_{g,h} (p_g'p_h)^2`` reduces to
    ``1 / (sum_g p_g^2 + (sum_g q_g)^2 - sum_g q_g^2)``. It is ``G - 1`` for equal sizes (returned
    exactly), exactly 1 for any two clusters, and lies in ``[1, G - 1]`` (a Satterthwaite df is
    ``(tr B)^2 / tr(B^2) >= 1`` for a PSD ``B`` of rank at most ``G - 1``); the result is clipped to
    that range so that rounding never turns a test into "no verdict" (``df < 1``).
    """
    n = np.asarray(sizes, dtype=np.float64)
    g = len(n)
    if g < 2 or bool(np.all(n == n[0])):
        return float(g - 1)
    share = n / n.sum()
    q = share**2 / (1.0 - share)
    total = float(np.sum(share**2) + np.sum(q) ** 2 - np.sum(q**2))
    return min(float(g - 1), max(1.0, 1.0 / total))


def cluster_robust_mean(
    values: Sequence[float] | np.ndarray, clusters: Sequence[str], method: str = SE_METHOD
) -> ClusteredMean:
    """The mean of ``values`` with a standard error clustered by ``clusters`` and its t test's df.

    With ``u_g = sum_{i in g} (d_i - mean)``, ``n_g`` the cluster's size and ``p_g = n_g / N``:

    * ``"CR2"`` (the verdicts'): ``se^2 = sum_g u_g^2 / (1 - p_g) / N^2``, the bias-reduced
      linearisation of Bell and McCaffrey. For a regression on 1 the hat block is
      ``H_gg = J / N``, so ``A_g = (I - H_gg)^{-1/2} = I + (1 / sqrt(1 - p_g) - 1) J / n_g`` and
      ``1' A_g e_g = u_g / sqrt(1 - p_g)``. It is unbiased when the missions are independent with
      equal variance, and weights each cluster by its own share instead of CR1's blanket
      ``G / (G - 1)``, which undercorrects large clusters. df: :func:`bell_mccaffrey_df`.
    * ``"CR1"``: ``se^2 = G / (G - 1) * sum_g u_g^2 / N^2`` (Stata's ``vce(cluster)`` for a mean),
      df ``G - 1``: what the verdicts used before; liberal with few clusters of unequal size.
    * ``"CR0"``: ``sum_g u_g^2 / N^2``, no correction (CR2 is never below it).

    CR2 equals CR1 when the clusters have equal sizes (then the ordinary standard error of the G
    cluster means, with df ``G - 1``) or one value each (the ordinary ``sd / sqrt(N)``). One
    cluster: NaN standard error and df 0 (nothing to estimate the spread between clusters from).
    """
    if method not in CLUSTER_METHODS:
        raise ValueError(f"method must be one of {CLUSTER_METHODS}, got {method!r}")
    d = np.asarray(values, dtype=np.float64)
    mean, u, sizes = _cluster_sums(d, clusters)
    g, n = len(u), len(d)
    if g < 2:
        return ClusteredMean(mean, float("nan"), g, float(g - 1), method)
    if method == "CR2":
        variance = float(np.sum(u**2 / (1.0 - sizes / n))) / n**2
        return ClusteredMean(mean, math.sqrt(variance), g, bell_mccaffrey_df(sizes), method)
    factor = g / (g - 1) if method == "CR1" else 1.0
    return ClusteredMean(mean, math.sqrt(factor * float(np.sum(u**2)) / n**2), g, float(g - 1), method)


def clustered_mean_se(
    values: Sequence[float] | np.ndarray, clusters: Sequence[str], method: str = SE_METHOD
) -> tuple[float, float, int]:
    """(mean, standard error, number of clusters) of ``values`` grouped by ``clusters``: since
    issue #35 the CR2 standard error the verdicts use (``method="CR1"`` gives the old one);
    :func:`cluster_robust_mean` has the formulas and also returns the degrees of freedom."""
    r = cluster_robust_mean(values, clusters, method)
    return r.mean, r.se, r.n_clusters


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm's step-down adjusted p-values of one family (in the input order).

    Sorted ascending, the k-th smallest of m gets ``max_{j <= k} min(1, (m - j + 1) p_(j))``;
    rejecting where the adjusted p < alpha keeps the chance of any false "better" in the family
    below alpha. NaN entries (comparisons without a test) are left out of the family and stay NaN.
    """
    p = [float(v) for v in p_values]
    bad = [v for v in p if not math.isnan(v) and not 0.0 <= v <= 1.0]
    if bad:
        raise ValueError(f"p-values must be in [0, 1], got {bad}")
    order = sorted((i for i, v in enumerate(p) if not math.isnan(v)), key=lambda i: p[i])
    out = [float("nan")] * len(p)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(order) - rank) * p[i]))
        out[i] = running
    return out


# ---------------------------------------------------------------------------------------------
# one comparison
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SceneStat:
    """One scene of a comparison: its missions and both methods' means there."""

    scene: str
    n: int
    mean_a: float
    mean_b: float

    @property
    def diff(self) -> float:
        return self.mean_a - self.mean_b


@dataclass(frozen=True)
class PairedDifference:
    """``a - b`` of one metric at 100 % of the budget, over ``n`` shared missions in ``n_clusters`` scenes.

    ``se`` is the plain standard error over the missions (what the missions alone say; with one
    scene, over ``unit``); ``se_clustered`` the CR2 standard error over scenes and ``df_clustered``
    its Bell-McCaffrey degrees of freedom (:func:`cluster_robust_mean`), which the verdict uses.
    ``n_clusters`` / ``se_clustered`` left ``None`` mean "every mission its own scene";
    ``df_clustered`` left ``None`` means ``n_clusters - 1``, the df of equal-size scenes (true of
    one mission per scene).
    ``p_holm`` is set by :func:`holm_adjust` for the table the comparison sits in; ``None``: a
    family of one (``p_value``).
    """

    a: str
    b: str
    metric: str
    n: int
    mean_a: float
    mean_b: float
    diff: float
    se: float
    n_clusters: int | None = None
    se_clustered: float | None = None
    p_holm: float | None = None
    unit: str = "missions"
    per_scene: tuple[SceneStat, ...] = field(default=(), repr=False)
    df_clustered: float | None = None

    def __post_init__(self) -> None:
        n_clusters = self.n if self.n_clusters is None else self.n_clusters
        if self.n_clusters is None:
            object.__setattr__(self, "n_clusters", n_clusters)
        if self.se_clustered is None:
            object.__setattr__(self, "se_clustered", self.se if n_clusters >= 2 else float("nan"))
        if self.df_clustered is None:
            object.__setattr__(self, "df_clustered", float(n_clusters - 1))

    @property
    def lower_is_better(self) -> bool:
        return METRICS.get(self.metric, False)

    @property
    def df(self) -> float:
        """Degrees of freedom of the t test: Bell-McCaffrey's, a float in ``[1, scenes - 1]``;
        ``scenes - 1`` (0) with one scene, where there is no test (every ``df < 1`` check)."""
        n_clusters = int(self.n_clusters)  # type: ignore[arg-type]
        if n_clusters < 2:
            return float(n_clusters - 1)
        return float(self.df_clustered)  # type: ignore[arg-type]

    @property
    def t(self) -> float:
        """``diff / se_clustered`` (NaN with one scene; 0 for no difference at all)."""
        se = float(self.se_clustered)  # type: ignore[arg-type]
        if self.df < 1 or math.isnan(se) or math.isnan(self.diff):
            return float("nan")
        if se == 0.0:
            return 0.0 if self.diff == 0.0 else math.copysign(math.inf, self.diff)
        return self.diff / se

    @property
    def p_value(self) -> float:
        """Two-sided p of the t test, before any correction (NaN with one scene)."""
        return t_two_sided_p(self.t, self.df)

    @property
    def p_adjusted(self) -> float:
        """The p the verdict reads: ``p_holm`` when a table set it, else ``p_value``."""
        return self.p_value if self.p_holm is None else float(self.p_holm)

    @property
    def verdict(self) -> str:
        """``"a better"``, ``"b better"``, ``"tie"`` (adjusted p >= :data:`ALPHA`) or :data:`NO_VERDICT`."""
        if self.df < 1:
            return NO_VERDICT
        if not self.p_adjusted < ALPHA:  # also a tie: NaN values
            return "tie"
        a_better = self.diff < 0 if self.lower_is_better else self.diff > 0
        return f"{self.a} better" if a_better else f"{self.b} better"

    @property
    def winner(self) -> str | None:
        """The better method's label, ``None`` for a tie or no verdict."""
        v = self.verdict
        return v[: -len(" better")] if v.endswith(" better") else None

    def as_dict(self) -> dict[str, object]:
        return {
            "a": self.a,
            "b": self.b,
            "metric": self.metric,
            "n": self.n,
            "mean_a": self.mean_a,
            "mean_b": self.mean_b,
            "diff": self.diff,
            "se": self.se,
            "verdict": self.verdict,
            "unit": self.unit,
            "n_clusters": self.n_clusters,
            "se_clustered": self.se_clustered,
            "df": self.df,
            "t": self.t,
            "p_value": self.p_value,
            "p_holm": self.p_adjusted,
        }


def holm_adjust(diffs: Sequence[PairedDifference]) -> list[PairedDifference]:
    """The comparisons of one table with ``p_holm`` set by :func:`holm` over all of them (from
    their raw ``p_value``, so adjusting twice gives the same result)."""
    adjusted = holm([d.p_value for d in diffs])
    return [dataclasses.replace(d, p_holm=p) for d, p in zip(diffs, adjusted)]


# ---------------------------------------------------------------------------------------------
# pairing two results
# ---------------------------------------------------------------------------------------------
def _normal(value: Any) -> Any:
    """A comparable form of an option value: (5, 10, 15) == [5.0, 10.0, 15.0], numpy scalars as Python."""
    if isinstance(value, Mapping):
        return tuple(sorted((_normal(k), _normal(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_normal(v) for v in value)
    if isinstance(value, np.generic):
        return value.item()
    return value


def _effective_options(result: Any) -> dict[str, Any]:
    """The world options (``uav_ipp.IppConfig``'s) a result was flown with, defaults filled in,
    ``start`` as its rule (``None`` means "fixed" on split "paper", "random" elsewhere)."""
    given = getattr(result, "env_options", None) or {}
    options = {k: given.get(k, default) for k, default in _DEFAULTS.items()}
    if options.get("start") is None:  # uav_ipp.IppConfig.start_rule: the split decides
        options["start"] = "fixed" if options.get("split") == "paper" else "random"
    return options


def check_same_missions(a: Any, b: Any) -> tuple[str, ...] | None:
    """Refuse (``ValueError`` naming the option and both values) to pair two results that are not
    the same missions flown under the same settings; return their scene labels (``None`` when
    neither result has them)."""
    same, settings = "not the same missions", "not flown under the same settings"
    sa, sb = getattr(a, "scenes", None), getattr(b, "scenes", None)
    oa, ob = _effective_options(a), _effective_options(b)
    keys = list(MISSION_OPTIONS) + sorted(set(_DEFAULTS) - set(MISSION_OPTIONS) - set(MAY_DIFFER))
    # One rule: every (what, value in a, value in b) below is equal, checked in this order.
    compared = [(attr, getattr(a, attr), getattr(b, attr), same) for attr in ("env", "seed", "n_trials")]
    compared += [(key, oa.get(key), ob.get(key), same if key in MISSION_OPTIONS else settings) for key in keys]
    if sa is not None and sb is not None:
        compared += [(f"scene of mission {k}", x, y, same) for k, (x, y) in enumerate(itertools.zip_longest(sa, sb))]
    for name, va, vb, what in compared:
        if _normal(va) != _normal(vb):
            raise ValueError(
                f"{what}: {name} {va!r} vs {vb!r} ({getattr(a, 'method', 'a')} vs {getattr(b, 'method', 'b')})"
            )
    known = sa if sa is not None else sb
    return None if known is None else tuple(str(s) for s in known)


def _per_scene(va: np.ndarray, vb: np.ndarray, labels: Sequence[str]) -> tuple[SceneStat, ...]:
    out = []
    for scene in dict.fromkeys(labels):
        rows = np.array([label == scene for label in labels])
        out.append(SceneStat(scene, int(rows.sum()), float(va[rows].mean()), float(vb[rows].mean())))
    return tuple(out)


def paired_difference(
    a: Any, b: Any, metric: str = "entropy", *, scenes: Sequence[str] | None = None
) -> PairedDifference:
    """Per-mission ``a - b`` of ``metric`` at the last step for two ``EvaluationResult`` objects
    flown on the same missions under the same settings (:func:`check_same_missions`), with the
    standard error clustered by scene (CR2, Bell-McCaffrey df: :func:`cluster_robust_mean`).

    :param scenes: one scene label per mission; default: the results' own ``scenes``. Without
        labels every mission counts as its own scene (the caller vouches they are independent).
    """
    if metric not in METRICS:
        raise ValueError(f"metric must be 'f1', 'entropy', 'team_f1' or 'team_entropy', got {metric!r}")
    known = check_same_missions(a, b)
    labels = known if scenes is None else tuple(str(s) for s in scenes)
    va = np.asarray(getattr(a, metric))[:, -1].astype(np.float64)
    vb = np.asarray(getattr(b, metric))[:, -1].astype(np.float64)
    d = va - vb
    se = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else float("nan")
    clusters = labels if labels is not None else tuple(str(k) for k in range(len(d)))
    clustered = cluster_robust_mean(d, clusters)
    g = clustered.n_clusters
    fixed = _effective_options(a)["start"] == "fixed"
    return PairedDifference(
        a=str(a.method),
        b=str(b.method),
        metric=metric,
        n=len(d),
        mean_a=float(va.mean()),
        mean_b=float(vb.mean()),
        diff=float(d.mean()),
        se=se,
        n_clusters=g,
        se_clustered=clustered.se,
        df_clustered=clustered.df,
        unit="missions" if g >= 2 else (ONE_MISSION if fixed else ONE_SCENE),
        per_scene=() if labels is None else _per_scene(va, vb, labels),
    )


# ---------------------------------------------------------------------------------------------
# text
# ---------------------------------------------------------------------------------------------
def p_text(p: float) -> str:
    """A p-value for a table: ``"0.012"``, ``"<0.001"``, ``"n/a"`` (no test)."""
    if math.isnan(p):
        return "n/a"
    return "<0.001" if p < 0.001 else f"{p:.3f}"


def _spread(d: PairedDifference, digits: int = 4) -> str:
    """``"+0.0123 ± 0.0040"`` (clustered s.e.), or with one scene the plain s.e. and what it is over."""
    if d.df < 1:
        return f"{d.diff:+.{digits}f} ± {d.se:.{digits}f} over {d.unit}"
    return f"{d.diff:+.{digits}f} ± {d.se_clustered:.{digits}f}"


def _scenes_text(d: PairedDifference) -> str:
    """``"9 (df 4.3)"``: the scenes and the t test's Bell-McCaffrey df, which sets the p (below
    ``scenes - 1`` when the scenes have unequal sizes); just ``"1"`` with one scene (no test)."""
    return str(d.n_clusters) if d.df < 1 else f"{d.n_clusters} (df {d.df:.1f})"


def cell(d: PairedDifference, digits: int = 4) -> str:
    """``"+0.0123 ± 0.0040, p 0.012 (ag)"``: the difference, its clustered standard error, the
    (Holm-adjusted) p and who is better (or ``tie``, or :data:`NO_VERDICT` with one scene)."""
    if d.df < 1:
        return f"{_spread(d, digits)} ({NO_VERDICT})"
    return f"{_spread(d, digits)}, p {p_text(d.p_adjusted)} ({d.winner or 'tie'})"


def paired_markdown(
    rows: Sequence[PairedDifference],
    first_column: Sequence[str] | None = None,
    first_title: str = "Env",
    *,
    adjust: bool = True,
) -> str:
    """A Markdown table: one row per comparison (optionally led by a label column).

    The rows are one family: their p-values are Holm-adjusted together (``adjust=False`` keeps
    what the caller set, e.g. when the family is larger than this table).
    """
    rows = holm_adjust(rows) if adjust else list(rows)
    head = ([first_title] if first_column is not None else []) + [
        "a",
        "b",
        "metric @100%",
        "missions",
        "mean a",
        "mean b",
        "a - b (± s.e.)",
        "verdict",
        "scenes (df)",
        "p (Holm)",
    ]
    lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(["---"] * len(head)) + " |"]
    for i, r in enumerate(rows):
        cells = ([first_column[i]] if first_column is not None else []) + [
            r.a,
            r.b,
            r.metric,
            str(r.n),
            f"{r.mean_a:.4f}",
            f"{r.mean_b:.4f}",
            _spread(r),
            r.verdict,
            _scenes_text(r),
            p_text(r.p_adjusted),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def scene_markdown(d: PairedDifference, digits: int = 4) -> str:
    """Per scene of one comparison: missions, mean of ``a``, mean of ``b``, their difference.

    Shows which scenes carry a difference (the clustered test weighs scenes, not missions).
    """
    if not d.per_scene:
        return f"{d.a} vs {d.b} ({d.metric}): no scene labels.\n"
    head = ["scene", "missions", f"{d.a} {d.metric}", f"{d.b} {d.metric}", "a - b"]
    lines = ["| " + " | ".join(head) + " |", "| --- | ---: | ---: | ---: | ---: |"]
    for s in d.per_scene:
        lines.append(f"| {s.scene} | {s.n} | {s.mean_a:.{digits}f} | {s.mean_b:.{digits}f} | {s.diff:+.{digits}f} |")
    scenes = f"{d.n_clusters} scene" + ("" if d.n_clusters == 1 else "s")
    lines.append(f"| all ({scenes}) | {d.n} | {d.mean_a:.{digits}f} | {d.mean_b:.{digits}f} | {d.diff:+.{digits}f} |")
    return "\n".join(lines) + "\n"
