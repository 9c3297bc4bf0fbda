"""Steps 6 and 7 of ``reproduce``: how far a model carries, and what its training adds.

Generalisation flies each map's model on the other maps, a fresh env1 layout and (full runs
only) the user-map images; the untrained-prior step flies the greedy mix a gain-prior model
starts from, so that the report can say what COMA's training adds to it.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import torch as th

from sb3_coma.app import evaluation as ev
from sb3_coma.experiments import report
from sb3_coma.experiments import user_maps as um
from sb3_coma.experiments.reproduce.acceptance import final_numbers
from sb3_coma.experiments.reproduce.models import evaluate_model
from sb3_coma.experiments.reproduce.options import (
    BASELINES,
    FRESH_ENV1_SEED,
    USER_MAP_MISSIONS,
    USER_MAP_MODEL,
    ReproduceOptions,
)
from sb3_coma.experiments.reproduce.results import ModelSource, StepOutput


def generalisation_step(
    opts: ReproduceOptions,
    sources: Mapping[str, ModelSource],
    paper_results: Sequence[Any],
    out: Path,
    say: Callable[[str], None],
) -> StepOutput:
    """Each env's model on the other paper maps and on a fresh env1 star (baselines there too),
    then, in a full run, the user-map images."""
    gen: list[dict[str, Any]] = []
    if opts.generalisation:
        gen += _other_maps(opts, sources, say)
    for r in paper_results:  # own-map numbers for reference
        if r.method == "coma":
            gen.append({"model": r.env, "target": r.env, **final_numbers(r)})
    (out / "generalisation.md").write_text(report.generalisation_markdown(gen))
    summary: dict[str, Any] = {"generalisation": gen}
    if opts.generalisation and not opts.quick and USER_MAP_MODEL in sources:
        user_maps = user_map_step(opts, sources[USER_MAP_MODEL], out, say)
        return StepOutput(summary={**summary, **user_maps.summary}, sections=user_maps.sections)
    return StepOutput(summary=summary)


def _other_maps(
    opts: ReproduceOptions, sources: Mapping[str, ModelSource], say: Callable[[str], None]
) -> list[dict[str, Any]]:
    """The generalisation rows: every model on every other target, then the baselines on the
    fresh layout (quick: only the fresh env1 layout; the cross-map runs are the same code path)."""
    rows: list[dict[str, Any]] = []
    targets: list[tuple[str, dict[str, Any]]] = ([] if opts.quick else [(e, {}) for e in opts.env_names]) + [
        (f"env1 (map_seed={FRESH_ENV1_SEED})", {"map_seed": FRESH_ENV1_SEED})
    ]
    fresh_label = targets[-1][0]
    for env, src in sources.items():
        for target, extra in targets:
            if target == env:
                continue  # in Table I
            say(f"generalisation: {env} model on {target} ...")
            r = evaluate_model(
                src, "env1" if extra else target, opts.trials, opts.seed, opts.noise, f"coma[{env}]", **extra
            )
            rows.append({"model": env, "target": target, **final_numbers(r)})
    for name in BASELINES:
        r = ev.evaluate(
            name, env="env1", n_trials=opts.trials, seed=opts.seed, noise=opts.noise, record=0, map_seed=FRESH_ENV1_SEED
        )
        rows.append({"model": name, "target": fresh_label, **final_numbers(r)})
    return rows


def user_map_step(opts: ReproduceOptions, src: ModelSource, out: Path, say: Callable[[str], None]) -> StepOutput:
    """A user's own map: the model on the user-map images (Landsat-8 colour crops no model trained
    on, ``sb3_coma.experiments.user_maps``) against AG and AG-k3, clustered by image."""
    say(f"user maps: {USER_MAP_MODEL} model, AG, AG-k3 and the oracle on {len(um.CROPS)} images ...")
    results = um.fly(src.model, um.images(), USER_MAP_MISSIONS, opts.noise)
    rows = um.verdicts(results)
    text = um.table_markdown(results, f"COMA {USER_MAP_MODEL}", USER_MAP_MISSIONS, opts.noise)
    (out / "user_maps.md").write_text(text + "\n")
    summary = {
        "user_maps": {
            "means": {label: final_numbers(res) for label, res in results.items()},
            "verdicts": [d.as_dict() for d in rows],
        }
    }
    return StepOutput(summary=summary, sections={"user_maps": text})


def untrained_prior(model: Any) -> Any:
    """The policy a gain-prior model starts from: its prior weights at their initial value and the
    network's contribution removed (output layer zeroed; at initialisation it is ~0.01 of the
    prior). ``None`` for a model without a gain prior. Evaluated with argmax actions, this is the
    greedy planner on the untrained mix of the two information gains, so comparing it with the
    trained model shows what COMA's training adds."""
    actor = model.policy.actor
    if getattr(actor, "prior_theta", None) is None:
        return None
    policy = copy.deepcopy(model.policy)
    with th.no_grad():
        policy.actor.head.weight.zero_()
        policy.actor.head.bias.zero_()
        policy.actor.prior_theta.copy_(th.tensor(policy.gain_prior_init) / policy.gain_prior_speed)
    return policy


def untrained_prior_step(
    opts: ReproduceOptions, sources: Mapping[str, ModelSource], paper: Any, say: Callable[[str], None]
) -> StepOutput:
    """The untrained gain prior of each model vs the trained model on the Table I missions."""
    rows: list[dict[str, Any]] = []
    for env, src in sources.items():
        policy = untrained_prior(src.model)
        if policy is None:
            continue
        say(f"evaluating the untrained gain prior of the {env} model ...")
        r = ev.evaluate(
            policy,
            env=env,
            n_trials=opts.trials,
            seed=opts.seed,
            fusion=src.fusion,
            deterministic=True,
            noise=opts.noise,
            label="prior",
            record=0,
        )
        rows.append(
            {
                "env": env,
                "prior": final_numbers(r),
                "trained": final_numbers(paper.result(env, "coma")),
                "weights_start": [float(w) for w in policy.gain_prior_init],
                "weights_trained": [round(float(w), 3) for w in src.model.policy.actor.prior_weights.detach()],
            }
        )
    return StepOutput(summary={"untrained_prior": rows})
