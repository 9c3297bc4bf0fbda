"""Step 1 of ``reproduce``: the models every later step flies, and how one of them is flown.

Each map gets its COMA model (shipped, or retrained with ``--train``), the env3 ablation gets
its four shipped arms, and every protocol gets one list of methods per map, so that every table
of the run compares the same methods.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch as th

from sb3_coma.app import evaluation as ev
from sb3_coma.app import pretrained as pt
from sb3_coma.app.methods import Method
from sb3_coma.app.pretrained import PretrainedError
from sb3_coma.app.rows import BASELINE_METHODS, LEARNED_BASELINES, outdated_note, shipped_methods
from sb3_coma.experiments.reproduce.options import (
    ABLATION_ARMS,
    ABLATION_ENV,
    ABLATION_FULL,
    Folders,
    ReproduceOptions,
    attempt,
)
from sb3_coma.experiments.reproduce.results import LoadedModels, ModelSource
from sb3_coma.experiments.reproduce.training import _train_model, manifest_value, sendfuse_available
from uav_ipp.maps.ground_truth import available_maps


def load_models(opts: ReproduceOptions, folders: Folders, say: Callable[[str], None]) -> LoadedModels:
    """Each env's COMA model (shipped or retrained), the ablation arms, and the methods of the
    protocols per env: that model, every other model shipped for the env, extra models, baselines."""
    skipped: dict[str, str] = {}
    sources: dict[str, ModelSource] = {}
    for env in opts.env_names:
        if opts.baselines_only:
            continue
        if opts.train:
            sources[env] = _retrained_model(opts, folders, env, say)
        else:
            src = _shipped_or_none(opts, env, skipped, say)
            if src is not None:
                sources[env] = src
    arms: dict[tuple[str, str], Any] = {}
    if opts.ablation and ABLATION_ENV in sources:
        arms = ablation_models(sources[ABLATION_ENV].model, say)
    loaded = {ABLATION_ARMS[v]: m for v, m in arms.items() if v in ABLATION_ARMS}
    methods: dict[str, list[Any]] = {}
    for env, src in sources.items():
        note = outdated_note(src.info) if src.source == "shipped" else ""
        own = Method("coma", src.model, kind="coma", fusion=src.fusion, deterministic=src.deterministic, note=note)
        what = f"other shipped models of {env}"
        others = attempt(skipped, say, what, shipped_methods, env, loaded=loaded, skip=(env,), log=say) or []
        extra = [Method(label, model, kind=_kind_of(label)) for label, model in opts.extra_models.get(env, {}).items()]
        methods[env] = [own, *others, *extra, *BASELINE_METHODS]
    for env in opts.env_names:
        methods.setdefault(env, list(BASELINE_METHODS))
    return LoadedModels(skipped=skipped, sources=sources, arms=arms, methods=methods)


def _shipped_or_none(
    opts: ReproduceOptions, env: str, skipped: dict[str, str], say: Callable[[str], None]
) -> ModelSource | None:
    """The shipped model of ``env``; ``None`` (baseline rows only, the reason under "Skipped") when
    this install has none for a built-in map; an unknown name is an error."""
    try:
        return _shipped_model(env, opts.deterministic)
    except PretrainedError as exc:
        if env not in available_maps():
            raise
        skipped[f"COMA on {env}"] = f"no shipped model ({exc}); baseline rows only"
        say(f"no shipped model for {env}: baseline rows only ({exc})")
        return None


def _kind_of(label: str) -> str:
    """The method kind an extra model's label names ("ippo..." / "mappo..."), else "coma"."""
    return next((k for k in LEARNED_BASELINES if label.lower().startswith(k)), "coma")


def _retrained_model(opts: ReproduceOptions, folders: Folders, env: str, say: Callable[[str], None]) -> ModelSource:
    """``--train``: the shipped model's settings retrained into the staging folder, named by the
    run folder where it will be once the run is in place."""
    fusion = opts.fusion or manifest_value(env, "fusion")
    if fusion in ("sendfuse", None):
        fusion = "sendfuse" if sendfuse_available() else "mean"
    deterministic = (
        opts.deterministic if opts.deterministic is not None else bool(manifest_value(env, "deterministic", True))
    )
    src = _train_model(env, fusion, folders.staging, opts.quick, opts.timesteps, say, deterministic)
    return dataclasses.replace(src, source=str(folders.final(Path(src.source))))


def _shipped_model(env: str, deterministic: bool | None = None) -> ModelSource:
    """The shipped model of ``env`` with what its manifest entry records about its training."""
    model = pt.load_pretrained(env)
    info = model.pretrained_info
    det = bool(info.get("deterministic", True)) if deterministic is None else deterministic
    return ModelSource(
        env,
        model,
        info.get("fusion", "sendfuse"),
        "shipped",
        info.get("command", ""),
        info.get("train_wall_s"),
        info.get("timesteps"),
        list(info.get("training_curve", [])),
        info,
        det,
    )


def ablation_models(full_model: Any, say: Callable[[str], None] = print) -> dict[tuple[str, str], Any]:
    """The four ablation arms: the shipped model of each (:data:`ABLATION_ARMS`); an arm whose
    shipped model cannot be loaded is left out with a message, except the full arm, which is then
    ``full_model`` (the env3 model in use)."""
    models: dict[tuple[str, str], Any] = {}
    for arm, name in ABLATION_ARMS.items():
        try:
            models[arm] = pt.load_pretrained(name)
        except PretrainedError as exc:
            if arm == ABLATION_FULL:
                models[arm] = full_model
            else:
                say(f"ablation: leaving out {arm[0]}_{arm[1]}: {exc}")
    return models


def evaluate_model(src: ModelSource, env: str, trials: int, seed: int, noise: str, label: str, **extra: Any) -> Any:
    """``evaluate`` a COMA model; sampled actions come from torch's generator, seeded here with
    ``seed``, so that a sampling model's numbers repeat from run to run."""
    th.manual_seed(seed)
    return ev.evaluate(
        src.model,
        env=env,
        n_trials=trials,
        seed=seed,
        fusion=src.fusion,
        label=label,
        deterministic=src.deterministic,
        noise=noise,
        record=0,
        **extra,
    )
