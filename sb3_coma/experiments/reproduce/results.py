"""What the steps of ``reproduce`` hand each other: one frozen result per step.

A step takes the options and the earlier results it needs as arguments and returns one of
these; nothing is shared by mutation, so a step's inputs are in its signature and its outputs
in its return type. The orchestrator (``run.reproduce``) merges the :class:`StepOutput` parts
in step order, which is the order of ``summary.json``'s keys and of the "Skipped" list.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class ModelSource:
    """One map's COMA model and how it came to be (shipped, or the run folder that trained it)."""

    env: str
    model: Any
    fusion: str
    source: str  # "shipped" or the run folder
    command: str
    train_wall_s: float | None
    timesteps: int | None
    training_curve: list[float] = field(default_factory=list)
    info: dict[str, Any] = field(default_factory=dict)
    deterministic: bool = True  # argmax actions (True) or seeded draws from the policy (False)


@dataclass(frozen=True)
class StepOutput:
    """What a step adds to the run's outputs: ``summary.json`` keys (in the order it lists them),
    the report's sections (markdown by name) and what it skipped, with the reason."""

    summary: dict[str, Any] = field(default_factory=dict)
    sections: dict[str, str] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class LoadedModels(StepOutput):
    """Step 1: each map's model, the ablation arms (``(fusion, extractor) -> model``) and the
    methods every protocol flies per map (that model, the map's other shipped models, extra
    models, the baselines)."""

    sources: dict[str, ModelSource] = field(default_factory=dict)
    arms: dict[tuple[str, str], Any] = field(default_factory=dict)
    methods: dict[str, list[Any]] = field(default_factory=dict)


@dataclass(frozen=True)
class ProtocolStep(StepOutput):
    """A protocol's run (``protocols.run_protocol``'s result; ``None`` when it was skipped)."""

    protocol: Any = None

    @property
    def results(self) -> list[Any]:
        """The protocol's evaluation results, in table order."""
        return [row.result for row in self.protocol.rows()] if self.protocol is not None else []


@dataclass(frozen=True)
class AblationStep(StepOutput):
    """The ablation's result (``None`` without arms) and the arms it flew: the later steps use
    only these (an arm the ablation had to skip is left out of the paired check and the sweep)."""

    result: Any = None
    arms: dict[tuple[str, str], Any] = field(default_factory=dict)


@dataclass(frozen=True)
class SweepStep(StepOutput):
    """The noise sweep's result (``None`` when it was skipped)."""

    sweep: Any = None


@dataclass(frozen=True)
class RunRecord:
    """What ``sb3_coma.experiments.report`` reads of a finished run (``results_markdown``,
    ``readme_paragraph``): the summary, the sections, the protocols and the models."""

    summary: Mapping[str, Any]
    sections: Mapping[str, str]
    skipped: Mapping[str, str]
    paper: Any
    unseen: Any
    sweep: Any
    sources: Mapping[str, ModelSource]
    methods: Mapping[str, list[Any]]
