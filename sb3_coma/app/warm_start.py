"""The ``warm_start`` key of a config entry: DAgger from a teacher planner, then COMA.

    UavIpp-Env3-v0:
      kl_coef: 1.0              # COMA's pull toward the clone, falling to 0 over kl_fraction
      warm_start:
        teacher: oracle         # a planner that reads the env (the clairvoyant oracle)
        rounds: 8               # DAgger rounds
        missions: 128           # missions flown per round
        critic_warmup: 0.2      # first fraction of learn() in which only the critic learns

Before ``learn()``, a new run clones the teacher into the actor
(:func:`sb3_coma.uav.imitation.clone_teacher`) on copies of its own training world kept in this
process (the oracle reads each copy's ground truth and global belief at every step), stores the
clone as the KL reference (``COMA.set_reference_actor``), and holds the actor's learning rate at
0 for the first ``critic_warmup`` of training (``COMA.hold_actor``): the critic is new to this
policy, and advantages from an untrained critic would undo the clone before the pull can hold it.
Both are saved with the model (every checkpoint), so a resumed run keeps the same recipe. The
clone and the DAgger record go into the run folder (``warm_start.zip``, ``warm_start.json``). A
resumed run skips all of this: its checkpoint already holds the trained actor.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from sb3_coma.app.config import WARM_START_KEY, TrainConfig, check_warm_start, make_training_env
from sb3_coma.baselines import make_planner
from sb3_coma.coma import COMA
from sb3_coma.coma.coma import actor_frozen_then
from sb3_coma.uav.imitation import clone_teacher

__all__ = ["WARM_START_MODEL", "actor_frozen_then", "warm_start", "warm_start_run"]

#: The clone (with its KL reference and the actor's hold): a COMA model at 0 joint steps.
WARM_START_MODEL = "warm_start.zip"


def warm_start(
    model: COMA,
    spec: Mapping[str, Any],
    make_clone_env: Callable[[], VecEnv],
    seed: int,
    out_dir: Path,
    say: Callable[[str], None],
) -> None:
    """Clone ``spec``'s teacher (checked by :func:`~sb3_coma.app.config.check_warm_start`) into
    ``model``'s actor on ``make_clone_env()`` (in-process copies of the training world), set the
    KL reference and the critic's warm-up, and write the record into ``out_dir``."""
    training_env = model.get_env()
    venv = make_clone_env()
    tic = time.perf_counter()
    try:
        model.set_env(venv)
        say(f"Warm start: DAgger from {spec['teacher']}, {spec['rounds']} rounds x {spec['missions']} missions")
        teacher = make_planner(spec["teacher"], venv, seed=seed)

        def progress(record: dict[str, float]) -> None:
            done, rounds = int(record["round"]) + 1, int(spec["rounds"])
            elapsed = time.perf_counter() - tic
            say(
                f"  round {done}/{rounds}: {int(record['missions'])} missions, {int(record['states']):,} labelled "
                f"states, agreement {record['agreement']:.0%}, {elapsed:.0f} s elapsed, "
                f"about {elapsed / done * (rounds - done):.0f} s left (later rounds fit more data)"
            )

        report = clone_teacher(model, teacher, spec["missions"], spec["rounds"], seed=seed, on_round=progress)
    finally:
        venv.close()
        if training_env is not None:
            model.set_env(training_env)
    model.set_reference_actor()
    model.hold_actor(float(spec["critic_warmup"]))
    model.save(out_dir / WARM_START_MODEL)
    record = {**spec, "seconds": round(time.perf_counter() - tic, 1), "agreement": report.agreement}
    record["rounds_record"] = report.rounds
    (out_dir / "warm_start.json").write_text(json.dumps(record, indent=2) + "\n")
    say(
        f"Warm start done in {record['seconds']} s: the actor agrees with the teacher on {report.agreement:.0%} of states"
    )


def warm_start_run(model: COMA, cfg: TrainConfig, seed: int, run_path: Path, say: Callable[[str], None]) -> None:
    """:func:`warm_start` of ``sb3-coma train``: the config entry's spec, copies of its world."""
    spec = check_warm_start(cfg.entry[WARM_START_KEY], cfg.where)
    warm_start(model, spec, lambda: make_training_env(cfg, seed=seed, workers=1), seed, run_path, say)
