"""The orchestrator of ``sb3-coma reproduce``: the twelve named steps, in order, into one staged output.

Each step gets what it needs as arguments and returns its result; this module alone knows the
order, prints the progress line of each step ("[k/12] name (t s elapsed)"), times it, and
assembles the summary, the report's sections and the "Skipped" list from the steps' results.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from sb3_coma.app.outputs import staged_output
from sb3_coma.experiments.reproduce.ablation_steps import ablation_step, wide_paired_check
from sb3_coma.experiments.reproduce.generalisation import generalisation_step, untrained_prior_step
from sb3_coma.experiments.reproduce.models import load_models
from sb3_coma.experiments.reproduce.options import OUTPUT_PATTERNS, Folders, ReproduceOptions
from sb3_coma.experiments.reproduce.protocol_steps import paper_protocol, unseen_protocol
from sb3_coma.experiments.reproduce.results import RunRecord, StepOutput
from sb3_coma.experiments.reproduce.shipping import ship_or_record
from sb3_coma.experiments.reproduce.sweep_costs import cost_table, noise_sweep_step
from sb3_coma.experiments.reproduce.writing import figures_step, write_results

T = TypeVar("T")

#: The named steps of :func:`reproduce`, in order (their names are the progress lines' and
#: ``summary.json``'s ``step_seconds`` keys).
STEPS: tuple[Callable[..., Any], ...] = (
    load_models,
    paper_protocol,
    ablation_step,
    wide_paired_check,
    unseen_protocol,
    generalisation_step,
    untrained_prior_step,
    noise_sweep_step,
    cost_table,
    ship_or_record,
    figures_step,
    write_results,
)


class _Clock:
    """Says and times each step as it starts, so that a long run shows where it is; the steps
    must come in the order of :data:`STEPS`."""

    def __init__(self, say: Callable[[str], None]) -> None:
        self.say = say
        self.start = time.perf_counter()
        self.timings: dict[str, float] = {}

    def run(self, step: Callable[..., T], *args: Any) -> T:
        """``step(*args)``, after its progress line; its seconds go into :attr:`timings`."""
        number = len(self.timings) + 1
        assert STEPS[number - 1] is step, f"step {number} is {STEPS[number - 1].__name__}, not {step.__name__}"
        tic = time.perf_counter()
        self.say(f"[{number}/{len(STEPS)}] {step.__name__.replace('_', ' ')} ({tic - self.start:.0f} s elapsed)")
        result = step(*args)
        self.timings[step.__name__] = round(time.perf_counter() - tic, 1)
        return result


def reproduce(
    out: str | Path = "results", *, log: Callable[[str], None] | None = print, **options: Any
) -> dict[str, Any]:
    """Run the reproduction (see the package docstring) and return the summary dict.

    ``options`` are the fields of :class:`ReproduceOptions` (``env_names``, ``trials``,
    ``unseen_missions``, ``train``, ``quick``, ``docs`` ...).
    """
    unknown = sorted(set(options) - {f.name for f in dataclasses.fields(ReproduceOptions)})
    if unknown:
        raise TypeError(f"reproduce() got unknown options {unknown}")
    opts = ReproduceOptions(**options).checked()
    say = log or (lambda _m: None)
    with staged_output(out, command="reproduce", own=OUTPUT_PATTERNS, say=say) as staging:
        return _run_steps(opts, Folders(staging, Path(out)), say)


def _run_steps(opts: ReproduceOptions, folders: Folders, say: Callable[[str], None]) -> dict[str, Any]:
    """The twelve steps into ``folders.staging``; each step's outputs merged in step order."""
    started = time.perf_counter()
    clock = _Clock(say)
    out = folders.staging
    loaded = clock.run(load_models, opts, folders, say)
    paper = clock.run(paper_protocol, opts, loaded.methods, out, say)
    ablation = clock.run(ablation_step, opts, loaded.arms, out, say)
    arms = ablation.arms  # the arms the ablation flew
    paired = clock.run(wide_paired_check, opts, loaded.sources, arms, out, say)
    unseen = clock.run(unseen_protocol, opts, loaded.methods, out, say)
    general = clock.run(generalisation_step, opts, loaded.sources, paper.results, out, say)
    prior = clock.run(untrained_prior_step, opts, loaded.sources, paper.protocol, say)
    sweep = clock.run(noise_sweep_step, opts, loaded.sources, arms, out, say)
    costs = clock.run(cost_table, opts, loaded.sources, arms, out, say)
    clock.run(ship_or_record, opts, loaded.sources, paper.results, say)
    protocols = (paper.protocol, unseen.protocol)
    figures = clock.run(figures_step, opts, loaded, protocols, ablation.result, sweep.sweep, out)
    parts: list[StepOutput] = [loaded, paper, ablation, paired, unseen, general, prior, sweep, costs]
    record = RunRecord(
        summary={k: v for part in parts for k, v in part.summary.items()},
        sections={k: v for part in parts for k, v in part.sections.items()},
        skipped={k: v for part in parts for k, v in part.skipped.items()},
        paper=paper.protocol,
        unseen=unseen.protocol,
        sweep=sweep.sweep,
        sources=loaded.sources,
        methods=loaded.methods,
    )
    return clock.run(write_results, opts, folders, record, figures, dict(clock.timings), started, say)
