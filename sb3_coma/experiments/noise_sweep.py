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
mission (``sb3_coma.common.paired``).
"""

from __future__ import annotations

import csv
import itertools
import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

from sb3_coma.app.evaluation import evaluate
from sb3_coma.common.evaluation import ALL_METRICS, EvaluationResult
from sb3_coma.common.paired import PairedDifference, cell, paired_difference
from sb3_coma.experiments.protocols import Method

__all__ = [
    "ALPHA_LOWS",
    "AXES",
    "CENTRE",
    "DECODERS",
    "DROP_PROBABILITIES",
    "QUICK_AXES",
    "SIGMAS",
    "NoiseSweepResult",
    "SweepPoint",
    "run_noise_sweep",
    "sweep_points",
]

SIGMAS: tuple[float, ...] = (0.0, 0.02, 0.06, 0.1, 0.2, 0.3)
ALPHA_LOWS: tuple[float, ...] = (1.0, 0.8, 0.6, 0.4)
DROP_PROBABILITIES: tuple[float, ...] = (0.0, 0.3)
DECODERS: tuple[str, ...] = ("soft", "threshold")
#: The swept axes (env option -> values) and the point they are swept around: the moderate preset.
AXES: dict[str, tuple[float, ...]] = {"sigma": SIGMAS, "alpha_low": ALPHA_LOWS, "drop_probability": DROP_PROBABILITIES}
CENTRE: dict[str, float] = {"sigma": 0.02, "alpha_low": 0.8, "drop_probability": 0.0}
#: ``quick=True``: two sigmas, one a_low, drops on, both decoders (tests and smoke runs).
QUICK_AXES: dict[str, tuple[float, ...]] = {"sigma": (0.02, 0.2), "alpha_low": (0.4,), "drop_probability": (0.3,)}
#: Titles of the axes in tables and figures.
AXIS_TITLES: dict[str, str] = {"sigma": "sigma", "alpha_low": "a_low", "drop_probability": "drop p"}


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
    seen: set[tuple[float, float, float, str]] = set()
    return [p for p in points if not (p.key() in seen or seen.add(p.key()))]


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
        if arm == self.reference or (self.reference, point) not in self.results:
            return None
        return paired_difference(self.results[(arm, point)], self.results[(self.reference, point)], metric)

    def rows(self) -> list[dict[str, Any]]:
        """One dict per (point, arm): the setting, the four metrics' mean and s.e. at 100 %, and the
        paired differences to the reference arm on both entropies."""
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
                    d = self.vs_reference(arm, point, m)
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
                paired = [self.vs_reference(arm, point, m) for m in ("entropy", "team_entropy")]
                lines.append(
                    "| " + " | ".join(setting + [arm] + values + ["" if d is None else cell(d) for d in paired]) + " |"
                )
                setting = [""] * 4
        return "\n".join(lines) + "\n"

    def write_csv(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        rows = self.rows()
        columns = (
            ["axis", "sigma", "alpha_low", "drop_probability", "decoder", "arm", "missions"]
            + [f"{m}_{s}" for m in ALL_METRICS for s in ("mean", "se")]
            + [f"{m}_vs_{self.reference}_{k}" for m in ("entropy", "team_entropy") for k in ("diff", "se", "verdict")]
        )
        with path.open("w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(columns)
            for row in rows:
                flat = dict(row)
                for m in ("entropy", "team_entropy"):
                    d = row[f"{m}_vs_{self.reference}"] or {}
                    for k in ("diff", "se", "verdict"):
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
    clash = sorted(set(env_options) & {"noise", "sigma", "alpha_low", "drop_probability", "decoder"})
    if clash:
        raise ValueError(f"the noise sweep sets {clash} itself; pass the settings with points=")
    if not arms:
        raise ValueError("no arms to sweep")
    if points is None:
        points = sweep_points(QUICK_AXES if quick else AXES, grid=grid)
    options = {"split": split, **({"start": "random"} if split != "paper" else {}), **env_options}
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
                out.results[(arm.label, point)] = evaluate(
                    arm.policy,
                    env=env,
                    n_trials=n_missions,
                    seed=seed,
                    fusion=arm.fusion,
                    deterministic=arm.deterministic,
                    label=arm.label,
                    record=0,
                    planner_kwargs=dict(arm.planner_kwargs) or None,
                    **options,
                    **point.env_options(),
                )
            except (ValueError, RuntimeError, ImportError, FileNotFoundError) as exc:
                if not arm.learned:
                    raise
                out.skipped[arm.label] = f"{type(exc).__name__}: {exc}"
                if log:
                    log(f"  skipped {arm.label}: {exc}")
                break
    out.arms = [a for a in out.arms if a not in out.skipped]
    return out
