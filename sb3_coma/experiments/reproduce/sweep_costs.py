"""Steps 8 and 9 of ``reproduce``: the noise sweep and the deployment cost table.

The sweep asks how each ablation arm holds up as the channel gets worse (against AG, which uses
no messages' content); the cost table what one UAV computes per decision on board.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from sb3_coma.app.evaluation import Method
from sb3_coma.app.pretrained import ABLATION_LABELS
from sb3_coma.common.timing import one_thread, time_call
from sb3_coma.common.timing import torch_fusion as _torch_fusion
from sb3_coma.experiments.costs import costs_markdown, decision_costs
from sb3_coma.experiments.noise_sweep import run_noise_sweep
from sb3_coma.experiments.reproduce.options import (
    ABLATION_ENV,
    COST_REPEATS,
    QUICK_REPEATS,
    ReproduceOptions,
)
from sb3_coma.experiments.reproduce.results import ModelSource, StepOutput, SweepStep


def sweep_arms(
    opts: ReproduceOptions, sources: Mapping[str, ModelSource], arms: Mapping[tuple[str, str], Any]
) -> tuple[str, list[Any]]:
    """(map, arms) of the noise sweep: AG and every trained ablation arm on env3 when it is
    evaluated, else AG and the first map's model."""
    env = ABLATION_ENV if ABLATION_ENV in sources else opts.env_names[0]
    methods = [Method("ag", "ag")]
    if env == ABLATION_ENV and arms:
        methods += [
            Method(ABLATION_LABELS[v], m, kind="coma", fusion=v[0], deterministic=True) for v, m in arms.items()
        ]
    elif env in sources:
        src = sources[env]
        methods.append(Method("coma", src.model, kind="coma", fusion=src.fusion, deterministic=src.deterministic))
    return env, methods


def noise_sweep_step(
    opts: ReproduceOptions,
    sources: Mapping[str, ModelSource],
    arms: Mapping[tuple[str, str], Any],
    out: Path,
    say: Callable[[str], None],
) -> SweepStep:
    """``sb3_coma.experiments.noise_sweep`` on the sweep arms, shared unseen missions; table, CSV."""
    if not opts.sweep_missions:
        return SweepStep()
    env, methods = sweep_arms(opts, sources, arms)
    sweep = run_noise_sweep(methods, env=env, n_missions=opts.sweep_missions, seed=opts.seed, quick=opts.quick, log=say)
    sweep.write_csv(out / "noise_sweep.csv")
    skipped = {f"noise sweep: {k}": v for k, v in sweep.skipped.items()}
    text = sweep.markdown()
    (out / "noise_sweep.md").write_text(text)
    return SweepStep(
        summary={"noise_sweep": sweep.summary()}, sections={"noise_sweep": text}, skipped=skipped, sweep=sweep
    )


def cost_models(
    sources: Mapping[str, ModelSource], arms: Mapping[tuple[str, str], Any]
) -> dict[str, tuple[Any, str, str]]:
    """One model per architecture in use (fusion x extractor), each timed on its own map: the maps'
    models, then the ablation arms of other architectures."""
    out: dict[str, tuple[Any, str, str]] = {}
    seen = set()
    candidates = [(f"COMA {src.env}", src.model, src.fusion, src.env) for src in sources.values()] + [
        (f"COMA {ABLATION_LABELS[v]}", m, v[0], ABLATION_ENV) for v, m in arms.items()
    ]
    for label, model, fusion, env in candidates:
        arch = (fusion, type(model.policy.actor.features_extractor).__name__)
        if arch not in seen:
            seen.add(arch)
            out[f"{label} ({fusion} + {'CBAM' if 'CBAM' in arch[1] else 'CNN'})"] = (model, fusion, env)
    return out


def cost_table(
    opts: ReproduceOptions,
    sources: Mapping[str, ModelSource],
    arms: Mapping[tuple[str, str], Any],
    out: Path,
    say: Callable[[str], None],
) -> StepOutput:
    """Decision time per UAV (batch of one, one thread): actor + fusion in PyTorch and ONNX Runtime,
    AG with look-ahead 1, 2, 3 (``sb3_coma.experiments.costs``)."""
    if not opts.costs:
        return StepOutput(summary={"latency": []})
    models = cost_models(sources, arms)
    if opts.quick:
        models = dict(list(models.items())[:1])
    rows = decision_costs(
        models,
        envs=list(opts.cost_envs or opts.env_names),
        repeats=QUICK_REPEATS if opts.quick else COST_REPEATS,
        log=say,
    )
    text = costs_markdown(rows)
    (out / "latency.md").write_text(text)
    return StepOutput(summary={"latency": [r.as_dict() for r in rows]}, sections={"latency": text})


def _time_fusion(fusion: str, n_agents: int, reps: int = 200) -> float | None:
    """ms per UAV decision of fusing the N received maps of one UAV (batch of one, PyTorch, with
    the projection to the lattice); ``None`` when the fusion cannot be built here."""
    try:
        fn = _torch_fusion(fusion, n_agents, 44, 11)
    except Exception:  # weights missing or unreadable: report n/a, not a crash
        return None
    with one_thread():
        return time_call(fn, reps, warmup=1)[0]
