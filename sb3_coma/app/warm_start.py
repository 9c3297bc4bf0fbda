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
clone and the DAgger record go into the run folder (``warm_start.zip``, ``warm_start.json``).

The warm start takes minutes, so it can be stopped and continued: after every round, DAgger's
progress goes into ``warm_start_state/`` (:class:`~sb3_coma.uav.imitation.DaggerCheckpoint`:
that round's labelled states, the actor and its optimiser, each file written atomically), and
``warm_start_state/progress.json`` says how far it got and whether a signal stopped it. With
``stop_on_signal``, SIGINT / SIGTERM drop the round in progress and raise
:class:`WarmStartInterrupted`; ``sb3-coma train --resume RUN`` continues after the last finished
round and gives the clone an unbroken warm start gives. The folder is removed once the clone is
saved. A run resumed from a checkpoint skips all of this: the checkpoint holds the trained actor.
"""

from __future__ import annotations

import json
import signal
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from sb3_coma.app.config import WARM_START_KEY, TrainConfig, check_warm_start, make_training_env
from sb3_coma.baselines import make_planner
from sb3_coma.coma import COMA
from sb3_coma.common.callbacks import SignalStopCallback
from sb3_coma.common.checkpoints import atomic_save, atomic_write_text
from sb3_coma.uav.imitation import DaggerCheckpoint, DaggerInterrupted, DaggerReport, clone_teacher

#: The clone (with its KL reference and the actor's hold): a COMA model at 0 joint steps.
WARM_START_MODEL = "warm_start.zip"
#: The DAgger record: the spec, seconds, agreement and every round's numbers.
WARM_START_RECORD = "warm_start.json"
#: DAgger's progress while the warm start runs (removed once the clone is saved).
WARM_START_STATE = "warm_start_state"
#: In :data:`WARM_START_STATE`: how far DAgger got, and whether a signal stopped it.
PROGRESS_FILE = "progress.json"


class WarmStartInterrupted(KeyboardInterrupt):
    """SIGINT / SIGTERM stopped the warm start; its finished rounds are in :attr:`state` (all of
    them, with the clone saved, when the signal came after the last round)."""

    def __init__(self, state: Path, rounds_done: int, rounds: int, signum: int) -> None:
        super().__init__(f"warm start stopped after round {rounds_done}/{rounds}; progress in {state}")
        self.state = state
        self.rounds_done = rounds_done
        self.rounds = rounds
        self.signum = signum


def warm_start_pending(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a warm start that was stopped before its clone was saved."""
    return (run_dir / WARM_START_STATE / PROGRESS_FILE).is_file()


def _read_progress(checkpoint: DaggerCheckpoint) -> dict[str, Any]:
    try:
        record = json.loads((checkpoint.folder / PROGRESS_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def _write_progress(
    checkpoint: DaggerCheckpoint, spec: Mapping[str, Any], done: int, seconds: float, stopped: int | None = None
) -> None:
    """``progress.json``: where the warm start is (or stopped), for a user and for ``--resume``."""
    record = {
        "teacher": spec["teacher"],
        "rounds": int(spec["rounds"]),
        "missions": int(spec["missions"]),
        "rounds_done": done,
        "seconds": round(seconds, 1),
        "stopped_by": signal.Signals(stopped).name if stopped is not None else None,
    }
    atomic_write_text(checkpoint.folder / PROGRESS_FILE, json.dumps(record, indent=2) + "\n")


def _run_dagger(
    model: COMA,
    spec: Mapping[str, Any],
    make_clone_env: Callable[[], VecEnv],
    seed: int,
    checkpoint: DaggerCheckpoint,
    say: Callable[[str], None],
    stopper: SignalStopCallback,
) -> tuple[DaggerReport, float]:
    """DAgger on ``make_clone_env()``, from the last round in ``checkpoint`` when it holds any;
    returns the report and the seconds spent (earlier sessions' included)."""
    rounds, first = int(spec["rounds"]), checkpoint.rounds_done()
    before = float(_read_progress(checkpoint).get("seconds") or 0.0) if first else 0.0
    _write_progress(checkpoint, spec, first, before)
    training_env = model.get_env()
    venv = make_clone_env()
    tic = time.perf_counter()
    try:
        model.set_env(venv)
        say(
            f"Warm start: DAgger from {spec['teacher']}, {rounds} rounds x {spec['missions']} missions"
            + (f"; continuing after round {first}/{rounds} ({checkpoint.folder})" if first else "")
        )
        teacher = make_planner(spec["teacher"], venv, seed=seed)

        def progress(record: dict[str, float]) -> None:
            done, elapsed = int(record["round"]) + 1, time.perf_counter() - tic
            _write_progress(checkpoint, spec, done, before + elapsed)
            say(
                f"  round {done}/{rounds}: {int(record['missions'])} missions, {int(record['states']):,} labelled "
                f"states, agreement {record['agreement']:.0%}, {elapsed:.0f} s elapsed, "
                f"about {elapsed / (done - first) * (rounds - done):.0f} s left (later rounds fit more data)"
            )

        report = clone_teacher(
            model,
            teacher,
            spec["missions"],
            rounds,
            seed=seed,
            on_round=progress,
            checkpoint=checkpoint,
            stop=lambda: stopper.received is not None,
        )
    except DaggerInterrupted as exc:
        signum = stopper.received if stopper.received is not None else int(signal.SIGINT)
        _write_progress(checkpoint, spec, exc.rounds_done, before + time.perf_counter() - tic, stopped=signum)
        raise WarmStartInterrupted(checkpoint.folder, exc.rounds_done, rounds, signum) from None
    finally:
        venv.close()
        if training_env is not None:
            model.set_env(training_env)
    return report, before + time.perf_counter() - tic


def _save_clone(
    model: COMA, spec: Mapping[str, Any], out_dir: Path, report: DaggerReport, seconds: float
) -> dict[str, Any]:
    """Set the KL reference and the actor's hold, save the clone and the record (atomically)."""
    model.set_reference_actor()
    model.hold_actor(float(spec["critic_warmup"]))
    atomic_save(model, out_dir / WARM_START_MODEL)
    record = {**spec, "seconds": round(seconds, 1), "agreement": report.agreement}
    record["rounds_record"] = report.rounds
    atomic_write_text(out_dir / WARM_START_RECORD, json.dumps(record, indent=2) + "\n")
    return record


def warm_start(
    model: COMA,
    spec: Mapping[str, Any],
    make_clone_env: Callable[[], VecEnv],
    seed: int,
    out_dir: Path,
    say: Callable[[str], None],
    *,
    resume: bool = False,
    stop_on_signal: bool = False,
) -> None:
    """Clone ``spec``'s teacher (checked by :func:`~sb3_coma.app.config.check_warm_start`) into
    ``model``'s actor on ``make_clone_env()`` (in-process copies of the training world), set the
    KL reference and the critic's warm-up, and write the record into ``out_dir``.

    :param resume: continue the DAgger progress in ``out_dir`` (else it starts afresh)
    :param stop_on_signal: SIGINT / SIGTERM stop the warm start cleanly (module docstring)
    :raises WarmStartInterrupted: stopped by a signal (``stop_on_signal``)
    """
    checkpoint = DaggerCheckpoint(out_dir / WARM_START_STATE)
    if not resume:
        checkpoint.clear()
    stopper = SignalStopCallback(verbose=0)
    if stop_on_signal:
        stopper.install()
    try:
        report, seconds = _run_dagger(model, spec, make_clone_env, seed, checkpoint, say, stopper)
        record = _save_clone(model, spec, out_dir, report, seconds)
        checkpoint.clear()
    finally:
        stopper.restore()
    say(
        f"Warm start done in {record['seconds']} s: the actor agrees with the teacher on {report.agreement:.0%} of states"
    )
    if stopper.received is not None:  # came after the last round: the clone is saved, COMA not started
        rounds = int(spec["rounds"])
        raise WarmStartInterrupted(out_dir / WARM_START_MODEL, rounds, rounds, stopper.received)


def warm_start_run(
    model: COMA,
    cfg: TrainConfig,
    seed: int,
    run_path: Path,
    say: Callable[[str], None],
    *,
    resume: bool = False,
    stop_on_signal: bool = False,
) -> None:
    """:func:`warm_start` of ``sb3-coma train``: the config entry's spec, copies of its world."""
    spec = check_warm_start(cfg.entry[WARM_START_KEY], cfg.where)
    warm_start(
        model,
        spec,
        lambda: make_training_env(cfg, seed=seed, workers=1),
        seed,
        run_path,
        say,
        resume=resume,
        stop_on_signal=stop_on_signal,
    )
