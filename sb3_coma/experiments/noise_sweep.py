"""Noise sweep: how the channel's noise moves each method's map, global and team.

The channel (docs/design.md §3) corrupts every received cell as ``I_r = a I + n`` with
``a ~ U(alpha_low, 1)`` and ``n ~ N(0, sigma^2)``, drops whole messages with
``drop_probability``, and the receiver folds ``I_r`` into its own map with a ``decoder``
(``"soft"`` or ``"threshold"``). The sweep flies AG and each trained ablation arm on the same
missions at each setting and reports, at 100 % of the budget, the paper's F1 / entropy of the
global map (which never passes through the channel: it moves only through the decisions) and the
team metrics on the UAVs' own maps (which the channel feeds directly).

Settings (:func:`sweep_points`): one axis at a time around the ``moderate`` preset (sigma 0.02,
alpha_low 0.8, no drops), each under both decoders: :data:`SIGMAS`, :data:`ALPHA_LOWS`,
:data:`DROP_PROBABILITIES`; ``grid=True`` flies the full product instead (96 settings).
Every setting flies the same missions (env seeds ``seed .. seed + n - 1`` of ``split``, default
the unseen protocol's ``"test"`` with random starts), so each arm is compared with AG mission by
mission (``sb3_coma.stats.paired``: standard errors clustered by scene, and the p-values of the
whole table Holm-adjusted together, :meth:`NoiseSweepResult.paired`).
"""

from __future__ import annotations

import csv
import itertools
import os
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_coma.app.config import map_key
from sb3_coma.app.evaluation import (
    Method,
    Missions,
    WorldMismatchWarning,
    check_observation_options,
    fly,
    resolve_method,
    world_differences,
)
from sb3_coma.common.evaluation import ALL_METRICS, EvaluationResult
from sb3_coma.stats.paired import PairedDifference, cell, holm_adjust, paired_difference
from uav_ipp import ENV_IDS, IppConfig

SIGMAS: tuple[float, ...] = (0.0, 0.02, 0.06, 0.1, 0.2, 0.3)
ALPHA_LOWS: tuple[float, ...] = (1.0, 0.8, 0.6, 0.4)
DROP_PROBABILITIES: tuple[float, ...] = (0.0, 0.3)
DECODERS: tuple[str, ...] = ("soft", "threshold")
#: The swept axes (env option -> values) and the point they are swept around: the moderate preset.
AXES: dict[str, tuple[float, ...]] = {"sigma": SIGMAS, "alpha_low": ALPHA_LOWS, "drop_probability": DROP_PROBABILITIES}
CENTRE: dict[str, float] = {"sigma": 0.02, "alpha_low": 0.8, "drop_probability": 0.0}
#: ``quick=True``: two sigmas, one a_low, drops on, both decoders (tests and smoke runs).
QUICK_AXES: dict[str, tuple[float, ...]] = {"sigma": (0.02, 0.2), "alpha_low": (0.4,), "drop_probability": (0.3,)}


@dataclass(frozen=True)
class SweepPoint:
    """One channel setting: the three axis values and the decoder; ``axis`` names the one that
    differs from :data:`CENTRE` (``"centre"`` for the moderate point itself, ``"grid"`` in a grid)."""

    sigma: float
    alpha_low: float
    drop_probability: float
    decoder: str
    axis: str = "centre"

    def env_options(self) -> dict[str, Any]:
        return {
            "noise": "moderate",
            "sigma": float(self.sigma),
            "alpha_low": float(self.alpha_low),
            "drop_probability": float(self.drop_probability),
            "decoder": self.decoder,
        }

    def value(self, axis: str) -> float:
        return float(getattr(self, axis))

    def key(self) -> tuple[float, float, float, str]:
        return (self.sigma, self.alpha_low, self.drop_probability, self.decoder)

    def label(self) -> str:
        return f"sigma={self.sigma:g}, a_low={self.alpha_low:g}, drop={self.drop_probability:g}, {self.decoder}"


def sweep_points(
    axes: Mapping[str, Sequence[float]] = AXES,
    decoders: Sequence[str] = DECODERS,
    grid: bool = False,
    centre: Mapping[str, float] = CENTRE,
) -> list[SweepPoint]:
    """The settings to fly: per decoder, the centre and each axis value with the others at the
    centre (one axis at a time), or with ``grid`` every combination."""
    unknown = sorted(set(axes) - set(CENTRE))
    if unknown:
        raise ValueError(f"unknown noise-sweep axes {unknown}; choose from {sorted(CENTRE)}")
    full = {a: tuple(axes.get(a, (centre[a],))) for a in CENTRE}
    points: list[SweepPoint] = []
    for decoder in decoders:
        if grid:
            points += [SweepPoint(s, a, d, decoder, "grid") for s, a, d in itertools.product(*full.values())]
            continue
        points.append(SweepPoint(centre["sigma"], centre["alpha_low"], centre["drop_probability"], decoder))
        for axis, values in full.items():
            for v in values:
                if float(v) == float(centre[axis]):
                    continue
                points.append(SweepPoint(**{**centre, axis: float(v)}, decoder=decoder, axis=axis))
    first: dict[tuple[float, float, float, str], SweepPoint] = {}  # the first point of each setting, in order
    for p in points:
        first.setdefault(p.key(), p)
    return list(first.values())


@dataclass
class NoiseSweepResult:
    """``results[(arm label, point)]`` of one map, the reference arm (AG) and the settings."""

    env: str
    n_missions: int
    seed: int
    env_options: dict[str, Any]
    points: list[SweepPoint]
    arms: list[str]
    reference: str = "ag"
    results: dict[tuple[str, SweepPoint], EvaluationResult] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)

    def final(self, arm: str, point: SweepPoint, metric: str) -> np.ndarray:
        return self.results[(arm, point)].metric(metric)[:, -1]

    def vs_reference(self, arm: str, point: SweepPoint, metric: str) -> PairedDifference | None:
        """One arm minus the reference at one setting, on its own (a family of one: not
        Holm-adjusted; the table's verdicts come from :meth:`paired`)."""
        if arm == self.reference or (self.reference, point) not in self.results:
            return None
        return paired_difference(self.results[(arm, point)], self.results[(self.reference, point)], metric)

    def paired(self) -> dict[tuple[str, SweepPoint, str], PairedDifference]:
        """Every arm minus the reference at every setting on both entropies, keyed ``(arm, point,
        metric)``, Holm-adjusted together: the sweep's table is one family of verdicts."""
        keys = [
            (arm, point, m)
            for point in self.points
            for arm in self.arms
            if (arm, point) in self.results
            for m in ("entropy", "team_entropy")
        ]
        found = [(k, self.vs_reference(*k)) for k in keys]
        present = [(k, d) for k, d in found if d is not None]
        return dict(zip([k for k, _ in present], holm_adjust([d for _, d in present])))

    def rows(self) -> list[dict[str, Any]]:
        """One dict per (point, arm): the setting, the four metrics' mean and s.e. at 100 %, and the
        paired differences to the reference arm on both entropies (Holm-adjusted, :meth:`paired`)."""
        paired = self.paired()
        out = []
        for point in self.points:
            for arm in self.arms:
                if (arm, point) not in self.results:
                    continue
                row: dict[str, Any] = {
                    "axis": point.axis,
                    "sigma": point.sigma,
                    "alpha_low": point.alpha_low,
                    "drop_probability": point.drop_probability,
                    "decoder": point.decoder,
                    "arm": arm,
                    "missions": self.n_missions,
                }
                for m in ALL_METRICS:
                    v = self.final(arm, point, m)
                    row[f"{m}_mean"] = float(v.mean())
                    row[f"{m}_se"] = float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else float("nan")
                for m in ("entropy", "team_entropy"):
                    d = paired.get((arm, point, m))
                    row[f"{m}_vs_{self.reference}"] = None if d is None else d.as_dict()
                out.append(row)
        return out

    def markdown(self) -> str:
        """The table: one line per setting and arm (mean ± s.e. over the missions at 100 %)."""
        head = (
            ["sigma", "a_low", "drop p", "decoder", "arm"]
            + [ALL_METRICS[m][0] for m in ALL_METRICS]
            + [f"entropy − {self.reference}", f"team entropy − {self.reference}"]
        )
        lines = ["| " + " | ".join(head) + " |", "| " + " | ".join(["---:"] * 3 + ["---"] * 2 + ["---:"] * 6) + " |"]
        diffs = self.paired()
        for point in self.points:
            setting = [f"{point.sigma:g}", f"{point.alpha_low:g}", f"{point.drop_probability:g}", point.decoder]
            for arm in self.arms:
                if (arm, point) not in self.results:
                    continue
                values = []
                for m in ALL_METRICS:
                    v = self.final(arm, point, m)
                    se = v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else float("nan")
                    values.append(f"{v.mean():.4f} ± {se:.4f}")
                paired = [diffs.get((arm, point, m)) for m in ("entropy", "team_entropy")]
                lines.append(
                    "| " + " | ".join(setting + [arm] + values + ["" if d is None else cell(d) for d in paired]) + " |"
                )
                setting = [""] * 4
        return "\n".join(lines) + "\n"

    #: Columns of each paired difference in the CSV (``se``: over missions; the verdict uses ``se_clustered``).
    PAIRED_COLUMNS = ("diff", "se", "se_clustered", "p_holm", "verdict")

    def write_csv(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        rows = self.rows()
        columns = (
            ["axis", "sigma", "alpha_low", "drop_probability", "decoder", "arm", "missions"]
            + [f"{m}_{s}" for m in ALL_METRICS for s in ("mean", "se")]
            + [f"{m}_vs_{self.reference}_{k}" for m in ("entropy", "team_entropy") for k in self.PAIRED_COLUMNS]
        )
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(columns)
            for row in rows:
                flat = dict(row)
                for m in ("entropy", "team_entropy"):
                    d = row[f"{m}_vs_{self.reference}"] or {}
                    for k in self.PAIRED_COLUMNS:
                        flat[f"{m}_vs_{self.reference}_{k}"] = d.get(k, "")
                writer.writerow([f"{flat[c]:.6f}" if isinstance(flat[c], float) else flat[c] for c in columns])
        return path

    def curves(self, axis: str, arm: str, decoder: str, metric: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(axis values, means, standard errors) of one arm along one axis (the centre included)."""
        points = sorted(
            (
                p
                for p in self.points
                if p.decoder == decoder and p.axis in (axis, "centre") and (arm, p) in self.results
            ),
            key=lambda p: p.value(axis),
        )
        x = np.array([p.value(axis) for p in points])
        vals = [self.final(arm, p, metric) for p in points]
        mean = np.array([v.mean() for v in vals])
        se = np.array([v.std(ddof=1) / np.sqrt(len(v)) if len(v) > 1 else np.nan for v in vals])
        return x, mean, se

    def summary(self) -> dict[str, Any]:
        return {
            "env": self.env,
            "missions": self.n_missions,
            "seed": self.seed,
            "env_options": self.env_options,
            "arms": self.arms,
            "reference": self.reference,
            "points": len(self.points),
            "rows": self.rows(),
            "skipped": dict(self.skipped),
        }


#: Env options each setting sets itself: the arms' training values of these are not warned about.
SWEPT_OPTIONS = ("noise", "sigma", "alpha_low", "drop_probability", "decoder")


def _check_arms(arms: Sequence[Method], env: str, n_missions: int, options: Mapping[str, Any]) -> None:
    """Everything about the arms and options that would waste the sweep, refused before any mission
    is flown: an env option the settings set themselves (``points=`` says those), two arms under
    one label (their results would overwrite each other), too few missions for the paired columns
    (one mission makes every verdict nan), a model of another map family, or a model whose
    observation options differ from the sweep's. Other world differences of a model (budget ...)
    are one warning here; the swept settings differ on purpose (no warning)."""
    builtin = set(ENV_IDS.values())
    trained = {a.label: dict(a.trained) for a in arms if a.learned}
    elsewhere = [
        f"arm {label!r} is a model of {own_map} but the sweep flies {env}: sweep it on {own_map}, or pass a model of {env}"
        for label, own_map in ((label, str(own.get("map", ""))) for label, own in trained.items())
        if map_key(own_map) in builtin and map_key(env) in builtin and map_key(own_map) != map_key(env)
    ]
    labels = [a.label for a in arms]
    twice = sorted({label for label in labels if labels.count(label) > 1})
    clash = sorted(set(options) & set(SWEPT_OPTIONS))
    problems = [  # one table, one raise: the first that applies
        *([f"the noise sweep sets {clash} itself; pass the settings with points="] if clash else []),
        *(["no arms to sweep"] if not arms else []),
        *(
            [
                f"n_missions={n_missions}: each arm minus the reference is a paired test on shared missions and "
                "needs at least 2 (with 1 every verdict is nan)"
            ]
            if len(arms) > 1 and n_missions < 2
            else []
        ),
        *elsewhere,
        *([f"arm(s) {twice} given twice: give each arm once"] if twice else []),
    ]
    if problems:
        raise ValueError(problems[0])
    fields = {f for f in IppConfig.__dataclass_fields__ if f != "map_name"}
    fixed = {k: v for k, v in options.items() if k in fields}
    for label, own in trained.items():
        check_observation_options(f"arm {label!r}", own, fixed)
        differences = world_differences(own, IppConfig.from_options(str(env), **fixed), skip=SWEPT_OPTIONS)
        if differences:
            warnings.warn(
                f"arm {label!r} flies in another world than it trained in: {', '.join(differences)}",
                WorldMismatchWarning,
                stacklevel=3,
            )


def _fly(arm: Method, missions: Missions) -> EvaluationResult:
    """:func:`fly` without its :class:`WorldMismatchWarning`: every setting changes the
    channel on purpose, and the rest was checked once by :func:`_check_arms`."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", WorldMismatchWarning)
        return fly(arm, missions)


def run_noise_sweep(
    arms: Sequence[Method],
    env: str = "env3",
    n_missions: int = 20,
    seed: int = 0,
    points: Sequence[SweepPoint] | None = None,
    quick: bool = False,
    grid: bool = False,
    split: str = "test",
    log: Callable[[str], None] | None = print,
    **env_options: Any,
) -> NoiseSweepResult:
    """Fly every arm at every setting on the same missions (module docstring).

    :param arms: the methods (``sb3_coma.experiments.protocols.Method``); the first baseline AG among them is
        the reference of the paired columns
    :param points: the settings (default :func:`sweep_points`, ``quick``: :data:`QUICK_AXES`)
    :param split: where the missions come from (default the unseen protocol's ``"test"``; random
        starts unless ``start=`` says otherwise)
    :param env_options: more env options (``budget``, ``n_uavs`` ...); not the swept ones
    """
    if points is None:
        points = sweep_points(QUICK_AXES if quick else AXES, grid=grid)
    options = {"split": split, **({"start": "random"} if split != "paper" else {}), **env_options}
    arms = [resolve_method(a) for a in arms]  # once: every setting flies the same resolved arm
    _check_arms(arms, env, n_missions, options)
    reference = next(
        (
            a.label
            for a in arms
            if not a.learned and a.policy == "ag" and not dict(a.planner_kwargs).get("lookahead", 1) > 1
        ),
        arms[0].label,
    )
    out = NoiseSweepResult(env, n_missions, seed, options, list(points), [a.label for a in arms], reference)
    for arm in arms:
        for k, point in enumerate(points):
            if log and k == 0:
                log(f"noise sweep: {arm.label} on {env}, {len(points)} settings x {n_missions} missions ...")
            if arm.learned:
                th.manual_seed(seed)
            try:
                missions = Missions(env=env, count=n_missions, seed=seed, options={**options, **point.env_options()})
                out.results[(arm.label, point)] = _fly(arm, missions)
            except (ValueError, RuntimeError, ImportError, FileNotFoundError) as exc:
                if not arm.learned:
                    raise
                out.skipped[arm.label] = f"{type(exc).__name__}: {exc}"
                if log:
                    log(f"  skipped {arm.label}: {exc}")
                break
    out.arms = [a for a in out.arms if a not in out.skipped]
    return out
