"""The validation missions of a training run, flown the way its ``MissionEvalCallback`` flew them.

A run's checkpoints are chosen on these missions (``sb3-coma train --eval-freq``); three studies
need them again without the run's process: the learning curves (the baselines' levels on the same
missions), ``ship_models`` (a candidate scored today, without its run folder) and
``learners_paired`` (the same score for every learner). They live here, below the studies, so
that no study imports another for them. ``sb3_coma.experiments.learning_curves`` explains why the
flight goes through SB3's ``evaluate_policy`` on the training-time eval env rather than
``sb3_coma.evaluate``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.vec_env import VecEnv

from sb3_coma import COMA, training_options
from sb3_coma.app.config import eval_copies, make_vec_env_from_kwargs, resolve_env_id
from sb3_coma.app.training import VALIDATION_SEED
from sb3_coma.common.evaluation import PROTOCOLS, validation_missions


@dataclass(frozen=True)
class Validation:
    """The validation missions of a run: what its ``MissionEvalCallback`` flew at every evaluation."""

    env_id: str
    #: ``env_kwargs`` without the fusion, as sorted JSON (hashable: runs that share it share missions)
    options_json: str
    missions: int
    seed: int
    n_agents: int

    @property
    def copies(self) -> int:
        """Eval env copies, chosen as training chose them (so each copy flies the same missions)."""
        return eval_copies(self.missions)

    @property
    def options(self) -> dict[str, Any]:
        """The env options of the validation missions (without the fusion)."""
        return json.loads(self.options_json)

    def describe(self) -> str:
        """One line for the table's notes: which missions, how many copies, which seeds."""
        per_copy = self.missions // self.copies
        return (
            f"{self.missions} missions of {self.env_id} ({self.copies} env copies x {per_copy}, "
            f"copy c from env seed {self.seed} + c), {self.n_agents} UAVs"
        )


@dataclass
class MissionScores:
    """Per-mission final F1, entropy and team return of one flight of the validation missions."""

    f1: np.ndarray
    entropy: np.ndarray
    returns: np.ndarray


def fly_validation(
    validation: Validation,
    predictor_for: Callable[[VecEnv], Any],
    fusion: str = "mean",
    fusion_kwargs: dict[str, Any] | None = None,
) -> MissionScores:
    """Fly the validation missions as ``MissionEvalCallback`` does (module docstring), with the
    predictor ``predictor_for(venv)`` builds on the eval env (``returns``: SB3's per-row returns)."""
    env_kwargs = {**validation.options, "fusion": fusion, **({"fusion_kwargs": fusion_kwargs} if fusion_kwargs else {})}
    venv = make_vec_env_from_kwargs(validation.env_id, env_kwargs, n_envs=validation.copies, seed=validation.seed)
    f1: list[float] = []
    entropy: list[float] = []

    def read_infos(locals_: dict[str, Any], _globals: dict[str, Any]) -> None:
        # MissionEvalCallback._log_success_callback: a mission ends on every row of its copy; read it once.
        if locals_["done"] and locals_["i"] % validation.n_agents == 0:
            f1.append(float(locals_["info"]["f1"]))
            entropy.append(float(locals_["info"]["entropy"]))

    try:
        predictor = predictor_for(venv)
        venv.seed(validation.seed)  # MissionEvalCallback._on_step: applies to evaluate_policy's reset
        returns, _ = evaluate_policy(
            predictor,
            venv,
            n_eval_episodes=validation.missions * validation.n_agents,
            deterministic=True,
            return_episode_rewards=True,
            warn=False,
            callback=read_infos,
        )
    finally:
        venv.close()
    return MissionScores(np.array(f1), np.array(entropy), np.asarray(returns, dtype=np.float64))


def load_trained(model_file: Path) -> tuple[COMA, dict[str, Any]]:
    """A model zip and the env options it records (map, fusion, ...)."""
    model = COMA.load(model_file, device="cpu")
    options = training_options(model)
    if options is None:
        raise ValueError(f"{model_file} records no env options: not a model of a training run")
    return model, options


def validation_return(model_file: Path, missions: int | None = None) -> float:
    """Mean validation return of a model flown today, as ``MissionEvalCallback`` scores a checkpoint
    (:func:`fly_validation`: split train, env seeds from ``VALIDATION_SEED``, argmax):
    the score of a candidate without its run folder. A recorded score can be stale (the env's
    random streams changed since), a re-flown one cannot."""
    return model_validation_return(*load_trained(model_file), missions)


def model_validation_return(model: COMA, options: dict[str, Any], missions: int | None = None) -> float:
    """Today's validation missions: the validation protocol's (every train scene equally) where the
    model trained on the train split, else its own env; ``missions`` default: the protocol's count."""
    world = {k: v for k, v in options.items() if k not in ("map", "fusion", "fusion_kwargs")}
    if world.get("split", "paper") == "train":
        world.update(PROTOCOLS["validation"].env_options())
    validation = Validation(
        resolve_env_id(options["map"]),
        json.dumps(world, sort_keys=True),
        validation_missions(str(options["map"])) if missions is None else missions,
        VALIDATION_SEED,
        int(model.n_agents or 1),
    )
    scores = fly_validation(validation, lambda _venv: model, options["fusion"], options.get("fusion_kwargs") or None)
    return float(scores.returns.mean())
