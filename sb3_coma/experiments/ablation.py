"""The paper's ablation: {mean, sendfuse} fusion x {cnn, cbam} extractor under three noise levels.

Models come as a mapping ``{(fusion, extractor) or "fusion_extractor": model or path}`` or as a
directory holding files named ``{fusion}_{extractor}.zip`` (e.g. ``mean_cnn.zip``,
``sendfuse_cbam.zip``). Each model is evaluated with the fusion it was trained with, on the same
seeded missions, at every noise level; the table has one group per noise level (rows = variants,
columns = F1 / entropy at 33/67/100 % of the budget). A variant whose fusion cannot be built yet
(``make_vec_env(fusion="sendfuse")`` raises) is skipped with a message saying why.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import uav_ipp
from sb3_coma.app.evaluation import Method, Missions, fly, resolve_method
from sb3_coma.app.pretrained import ABLATION_LABELS
from sb3_coma.common.evaluation import EvaluationResult
from sb3_coma.stats.tables import TableRow, table_markdown, table_text

FUSIONS: tuple[str, ...] = ("mean", "sendfuse")
EXTRACTORS: tuple[str, ...] = ("cnn", "cbam")
NOISES: tuple[str, ...] = ("none", "moderate", "loud")
#: Labels of the paper's figures ("Base" has neither SenDFuse nor CBAM).
LABELS = ABLATION_LABELS  # the arms' table names (sb3_coma.app.pretrained)
Variant = tuple[str, str]


def parse_variant(key: str | Sequence[str]) -> Variant:
    """``"sendfuse_cbam"`` or ``("sendfuse", "cbam")`` -> ``("sendfuse", "cbam")``, validated."""
    if isinstance(key, str):
        parts = key.strip().lower().replace("-", "_").split("_")
    else:
        parts = [str(p).strip().lower() for p in key]
    if len(parts) != 2 or parts[0] not in FUSIONS or parts[1] not in EXTRACTORS:  # one rule: a known pair
        raise ValueError(
            f"ablation variant {key!r}: expected FUSION_EXTRACTOR (e.g. 'sendfuse_cbam'): "
            f"fusion must be one of {FUSIONS} and extractor one of {EXTRACTORS}"
        )
    return parts[0], parts[1]


def find_models(source: Mapping[Any, Any] | str | os.PathLike) -> dict[Variant, Any]:
    """Variant -> model (object or path) from a mapping or a directory of ``{fusion}_{extractor}.zip``."""
    if isinstance(source, Mapping):
        models = {parse_variant(k): v for k, v in source.items()}
        missing = [
            f"model file for {f}_{e}: {os.fspath(m)!r}"
            for (f, e), m in models.items()
            if isinstance(m, (str, os.PathLike)) and not Path(m).is_file()
        ]
    else:
        folder = Path(source)
        missing = [] if folder.is_dir() else [f"models directory: {os.fspath(source)!r}"]
        found = ((f, e, folder / f"{f}_{e}.zip") for f in FUSIONS for e in EXTRACTORS)
        models = {(f, e): path for f, e, path in found if path.is_file()}
    if missing:  # one rule: every path given is there
        raise FileNotFoundError(f"not found: {', '.join(missing)}")
    if not models:
        names = ", ".join(f"{f}_{e}.zip" for f in FUSIONS for e in EXTRACTORS)
        raise ValueError(
            f"no ablation models found in {os.fspath(source) if not isinstance(source, Mapping) else 'the mapping'}; "
            f"expected files named {names}"
        )
    order = [(f, e) for f in FUSIONS for e in EXTRACTORS]
    return {v: models[v] for v in order if v in models}


def fusion_unavailable(env: str, fusion: str, **env_options: Any) -> str | None:
    """``None`` when ``make_vec_env(fusion=...)`` works here, else why it does not."""

    try:
        venv = uav_ipp.make_vec_env(env, n_envs=1, fusion=fusion, **env_options)
    except (ValueError, ImportError, FileNotFoundError, RuntimeError) as exc:
        return f"{type(exc).__name__}: {exc}"
    venv.close()
    return None


def find_training_logs(folder: str | os.PathLike) -> dict[str, Path]:
    """Variant label -> training log inside ``folder``: ``{fusion}_{extractor}`` as a run directory,
    ``.csv`` file or TensorBoard directory (Figure 3)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"training-logs directory not found: {os.fspath(folder)!r}")
    logs = {}
    for variant, label in LABELS.items():
        stem = f"{variant[0]}_{variant[1]}"
        for candidate in (folder / stem, folder / f"{stem}.csv"):
            if candidate.exists():
                logs[label] = candidate
                break
    if not logs:
        raise ValueError(f"no training logs named {{fusion}}_{{extractor}} (dir or .csv) in {os.fspath(folder)!r}")
    return logs


@dataclass
class AblationResult:
    """Results by (variant label, noise level), the variants skipped and why."""

    env: str
    noises: tuple[str, ...]
    results: dict[tuple[str, str], EvaluationResult] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)

    def rows(self) -> list[TableRow]:
        """Table rows grouped by noise level, variants in the paper's order."""
        labels = list(dict.fromkeys(label for label, _ in self.results))
        return [
            TableRow(noise, label, self.results[(label, noise)])
            for noise in self.noises
            for label in labels
            if (label, noise) in self.results
        ]

    def markdown(self) -> str:
        return table_markdown(self.rows(), group_title="Noise")

    def text(self) -> str:
        return table_text(self.rows(), group_title="Noise")

    def by_noise(self) -> dict[str, list[EvaluationResult]]:
        return {n: [r for (label, noise), r in self.results.items() if noise == n] for n in self.noises}


def run_ablation(
    models: Mapping[Any, Any] | str | os.PathLike,
    env: str = "env3",
    noises: Sequence[str] = NOISES,
    n_trials: int = 10,
    seed: int = 0,
    log: Callable[[str], None] | None = print,
    protocol: str | None = None,
    **env_options: Any,
) -> AblationResult:
    """Evaluate every available variant at every noise level on the same seeded missions
    (``protocol="unseen"``: the unseen protocol's missions, on which verdicts rest)."""
    noises = tuple(noises)
    if "noise" in env_options or not noises:  # one rule: the levels are noises=..., at least one
        raise ValueError(f"noises must be a non-empty list of noise levels (not noise=...), got {noises!r}")
    found = find_models(models)
    out = AblationResult(env=env, noises=noises)
    unavailable = {f: fusion_unavailable(env, f, noise=noises[0], **env_options) for f in {v[0] for v in found}}
    for variant, model in found.items():
        label = LABELS[variant]
        why = unavailable[variant[0]]
        if why is not None:
            out.skipped[label] = f"fusion {variant[0]!r} is not available: {why}"
            if log:
                log(f"skipping {label} ({variant[0]}_{variant[1]}): {out.skipped[label]}")
            continue
        method = resolve_method(Method(label, model, fusion=variant[0]))  # once: a shipped zip is hashed once
        for noise in noises:
            if log:
                log(f"evaluating {label} ({variant[0]}_{variant[1]}) on {env}, noise {noise} ...")
            missions = Missions(
                env=env, protocol=protocol, count=n_trials, seed=seed, noise=noise, record=1, options=env_options
            )
            out.results[(label, noise)] = fly(method, missions)
    return out
