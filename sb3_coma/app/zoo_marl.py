"""rl-zoo3 on third-party cooperative tasks: ``python -m sb3_coma.zoo train --algo coma|mappo|ippo
--env simple_spread`` (or ``--env package.module:factory``, a user's PettingZoo env).

:class:`MarlExperimentManager` subclasses rl-zoo3's ``ExperimentManager`` for the tasks of
:mod:`sb3_coma.app.marl_tasks`; everything else is rl-zoo3's own lifecycle (log folder
``logs/<algo>/<env id>_<n>/``, ``config.yml``, ``-params``, ``-i``, ``--eval-freq``, ``-optimize``
with Optuna). What differs, and why:

* envs come from ``sb3_coma.make_marl_vec_env`` (a PettingZoo env cannot come from ``gym.make``):
  one vec-env row per agent, ``n_envs`` copies; MAPPO's rows also get the global state
  (:class:`sb3_coma.mappo.CentralStateVecEnv`); the evaluation env has seeds of its own;
* every step count (``n_timesteps``, ``-n``, ``--eval-freq``, ``--save-freq``) is in **joint**
  steps for every learner, so one config budget is one budget: SB3's PPO counts agent steps and is
  given ``n_agents`` times more of its own, as the learner benchmark does;
* ``--eval-episodes`` counts team episodes (SB3's evaluation counts one per agent row);
* the configs are ``zoo_configs/marl/<algo>.yml`` (``mappo`` and ``ippo`` are SB3's ``PPO``;
  MAPPO's ``policy: CentralValuePolicy``); an entry without ``n_envs`` / ``n_timesteps`` takes
  the benchmark's (8 copies, the task's budget) for a named task.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import Any

import optuna
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER
from rl_zoo3.utils import ALGOS
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecEnv

from sb3_coma.app.config import TrainingError, parse_schedule
from sb3_coma.app.marl_tasks import BENCHMARK_JOINT_STEPS, MarlTask
from sb3_coma.coma import COMA
from sb3_coma.coma.validation import BatchLargerThanRollout
from sb3_coma.common.marl_vec_env import make_marl_vec_env
from sb3_coma.mappo.central_value import CentralStateVecEnv, CentralValuePolicy

#: The learners this manager trains and the SB3 class each one is.
MARL_ALGOS: dict[str, type] = {"coma": COMA, "mappo": PPO, "ippo": PPO}
#: Copies of the env when a config entry does not say (the learner benchmark's).
DEFAULT_COPIES = 8
#: Seed offset of the evaluation env: its episodes are not the training copies' ones.
EVAL_SEED_OFFSET = 10_000


def preprocess_schedules(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """rl-zoo3's schedules (``"lin_<x>"`` strings and numbers, its own ``_preprocess_schedules`` for
    its keys) and COMA's ``critic_learning_rate`` read the same way, and ``clip_range: null`` left as
    COMA's plain policy gradient (rl-zoo3 refuses a ``None``), so an entry trains the same through
    every route (the zoo for the UAV world and for third-party tasks, the learner benchmark, the study)."""
    critic = hyperparams.pop("critic_learning_rate", None)
    unclipped = "clip_range" in hyperparams and hyperparams["clip_range"] is None  # COMA's plain gradient
    if unclipped:
        del hyperparams["clip_range"]
    hyperparams = ExperimentManager._preprocess_schedules(hyperparams)
    if critic is not None:
        hyperparams["critic_learning_rate"] = parse_schedule(critic)
    if unclipped:
        hyperparams["clip_range"] = None
    return hyperparams


def register_marl_algos() -> None:
    """Add ``coma``, ``mappo`` and ``ippo`` to rl-zoo3's ``ALGOS`` and its Optuna tables (the PPO
    learners use rl-zoo3's own PPO search space; COMA its own, :mod:`sb3_coma.app.zoo_sampler`)."""
    from sb3_coma.app.zoo_sampler import register as register_coma_sampler

    ALGOS.update(MARL_ALGOS)
    register_coma_sampler()
    for name in ("mappo", "ippo"):
        HYPERPARAMS_SAMPLER[name] = HYPERPARAMS_SAMPLER["ppo"]
        HYPERPARAMS_CONVERTER[name] = HYPERPARAMS_CONVERTER["ppo"]


class MarlExperimentManager(ExperimentManager):
    """rl-zoo3's ``ExperimentManager`` for COMA, MAPPO and IPPO on a PettingZoo task (joint steps)."""

    def __init__(self, args: argparse.Namespace, algo: str, task: MarlTask, *pos: Any, **kwargs: Any) -> None:
        assert algo in MARL_ALGOS, algo  # the caller resolved --algo at the edge
        super().__init__(args, algo, task.env_id, *pos, **kwargs)
        self.task = task
        self.n_agents = task.agents(self.env_kwargs)
        # SB3's evaluation counts one episode per agent row: ask for whole team episodes.
        self.n_eval_episodes = int(self.n_eval_episodes) * self.n_agents

    # rl-zoo3 asks gymnasium's registry what kind of env an id is; a task is none of those kinds.
    @staticmethod
    def is_atari(env_id: str) -> bool:
        return False

    @staticmethod
    def is_minigrid(env_id: str) -> bool:
        return False

    @staticmethod
    def is_bullet(env_id: str) -> bool:
        return False

    @staticmethod
    def is_robotics_env(env_id: str) -> bool:
        return False

    @staticmethod
    def is_panda_gym(env_id: str) -> bool:
        return False

    @property
    def _counts_agent_steps(self) -> bool:
        """SB3's PPO counts one step per agent row; COMA one per joint step."""
        return MARL_ALGOS[self.algo] is PPO

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        if not self.config.endswith((".yml", ".yaml")):
            raise TrainingError(f"-conf {self.config}: the configs are YAML files (zoo_configs/marl/{self.algo}.yml)")
        try:
            hyperparams, saved = super().read_hyperparameters()
        except ValueError as exc:  # rl-zoo3's "Hyperparameters not found for ..."
            raise TrainingError(f"{self.config}: no entry {self.task.env_id!r} ({exc})") from None
        defaults = {"n_envs": DEFAULT_COPIES}
        if self.task.env_id in BENCHMARK_JOINT_STEPS:
            defaults["n_timesteps"] = BENCHMARK_JOINT_STEPS[self.task.env_id]
        for key, value in defaults.items():
            if key not in hyperparams:
                hyperparams[key] = saved[key] = value
        if "n_timesteps" not in hyperparams and self.n_timesteps <= 0:
            raise TrainingError(f"{self.config} [{self.task.env_id}] has no n_timesteps: add it or pass -n")
        return hyperparams, saved

    @staticmethod
    def _preprocess_schedules(hyperparams: dict[str, Any]) -> dict[str, Any]:
        return preprocess_schedules(hyperparams)

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]) -> Any:
        if hyperparams.get("policy") == CentralValuePolicy.__name__:  # rl-zoo3 imports a dotted name
            hyperparams["policy"] = f"{CentralValuePolicy.__module__}.{CentralValuePolicy.__name__}"
        processed = super()._preprocess_hyperparams(hyperparams)
        if self._counts_agent_steps:
            # PPO's own count; rl-zoo3 spaces the search's evaluations as n_timesteps / n_evaluations
            # / n_envs vec steps, so a run of PPO still evaluates n_evaluations times (and the median
            # pruner's warm-up, n_evaluations // 3, counts those evaluations): n_evaluations stays.
            self.n_timesteps *= self.n_agents
        return processed

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        """``n_envs`` copies of the task, one row per agent (with the global state for MAPPO)."""
        seed = None if self.seed is None else int(self.seed) + (EVAL_SEED_OFFSET if eval_env else 0)
        options = self.eval_env_kwargs if eval_env else self.env_kwargs
        if eval_env and options != self.env_kwargs:
            self.task.agents(options)  # the evaluation's own options: refused in one line, as the training's
        env: VecEnv = make_marl_vec_env(self.task.with_options(options), n_envs=n_envs, seed=seed)
        if self.algo == "mappo":
            env = CentralStateVecEnv(env)
        if self.vec_env_wrapper is not None:
            env = self.vec_env_wrapper(env)
        return self._maybe_normalize(env, eval_env)

    def hyperparameters_optimization(self) -> None:
        run_optimization(super().hyperparameters_optimization)

    def objective(self, trial: optuna.Trial) -> float:
        return prune_refused_batch(super().objective, trial)


def prune_refused_batch(objective: Callable[[optuna.Trial], float], trial: optuna.Trial) -> float:
    """rl-zoo3's trial, pruned (not failed) when COMA refuses its sampled ``batch_size`` as larger
    than the rollout the config's ``n_steps`` gives: that point of the space is empty, not an error."""
    try:
        return objective(trial)
    except BatchLargerThanRollout as exc:
        raise optuna.TrialPruned(str(exc)) from None


def run_optimization(search: Callable[[], None]) -> None:
    """rl-zoo3's search; its closing report needs pandas (``study.trials_dataframe()``), which is
    optional: the search is finished by then (and kept in ``--storage`` when one is given)."""
    try:
        search()
    except ImportError as exc:
        if "pandas" not in str(exc):
            raise
        print(
            f"Optuna report not written: {exc.__class__.__name__}: pandas is not installed "
            "(pip install pandas); the trials are kept in the study storage"
        )
