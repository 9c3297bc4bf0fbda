"""Which evaluation of a training run may select its model, and the command that trained it.

Both the shipping tool (``sb3_coma.experiments.ship_models``) and the learners' comparison
(``sb3_coma.experiments.learners_paired``) score a run folder by its best selectable validation
return and name it by its recorded ``sb3-coma train`` command; the rule lives here, below the
studies, so that neither study imports the other for it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sb3_coma.app.training import selection_end
from sb3_coma.coma import COMA


def run_entry(run: Path) -> dict[str, Any]:
    """The config entry a run trained with (its ``config.yml``, without the ``run`` record)."""
    data = yaml.safe_load((run / "config.yml").read_text())
    return next(v for k, v in data.items() if k != "run")


def validation_best(run: Path) -> tuple[float, int]:
    """(best mean validation return, joint steps of that evaluation) of a run, over the
    evaluations that may select its model (:func:`sb3_coma.app.training.selection_end`: not
    while a warm-started actor is still the clone). Refuses a run whose ``best_model.zip`` is not
    that evaluation's checkpoint (trained before the rule, its best was a warm-up checkpoint)."""
    data = np.load(run / "eval" / "evaluations.npz")
    steps, means = data["timesteps"], data["results"].mean(axis=1)
    entry = run_entry(run)
    allowed = np.flatnonzero(steps > selection_end(entry, int(entry["n_timesteps"])))
    if not len(allowed):
        raise ValueError(f"{run}: no evaluation after the warm-up may select its model")
    best = int(allowed[np.argmax(means[allowed])])  # the first of equal bests, as EvalCallback keeps it
    saved = run / "best_model.zip"
    if saved.is_file() and COMA.load(saved, device="cpu").num_timesteps < steps[best]:
        raise ValueError(
            f"{run}: best_model.zip is an earlier checkpoint than its best selectable evaluation "
            f"({int(steps[best])} joint steps): retrain it with this version (same seed, same result)"
        )
    return float(means[best]), int(steps[best])


def run_command(run: Path) -> tuple[str, dict[str, Any]]:
    """The ``sb3-coma train`` command a run folder records (without its run-folder and display
    flags), and its ``run`` section."""
    info = yaml.safe_load((run / "config.yml").read_text())["run"]
    words = info["command"].split()
    words = words[words.index("train") :]
    kept, skip = [], False
    for word in words:
        if skip:
            skip = False
        elif word == "--run-dir":
            skip = True
        elif word != "--no-progress":
            kept.append(word)
    return "sb3-coma " + " ".join(kept), info
