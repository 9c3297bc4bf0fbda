"""rl-zoo3 with COMA: ``python -m sb3_coma.zoo train|enjoy [rl-zoo3 arguments]``.

With ``--algo coma`` (the default) on a UavIpp env:

* ``train`` takes rl-zoo3's own ``train`` arguments (same names and defaults: ``-n``,
  ``--seed``, ``-tb``, ``--eval-freq``, ``--save-freq``, ``-params``, ``--env-kwargs``,
  ``-optimize`` ...) plus ``--variant NAME`` (the config's ``variants`` mapping), and runs
  rl-zoo3's experiment lifecycle (``setup_experiment``, ``learn``, ``save_trained_model``,
  ``hyperparameters_optimization``: its log folder layout ``logs/coma/<env id>_<n>/``, saved
  config, Optuna search) with :class:`ComaExperimentManager`, a subclass of rl-zoo3's
  ``ExperimentManager`` that builds envs with ``uav_ipp.make_vec_env`` (``gym.make`` cannot return a
  multi-agent env), counts evaluation and checkpoint frequencies in joint steps and evaluations
  in missions, logs mission F1 / entropy / team reward, writes models and checkpoints atomically,
  records the env options in every saved model and validates the config with clear errors;
* ``enjoy`` takes rl-zoo3's ``enjoy`` arguments, loads the model from the same log folders
  (rl-zoo3's ``get_model_path``: ``--load-best``, ``--load-checkpoint N``,
  ``--load-last-checkpoint``, ``--exp-id``) and flies it, reporting F1 and entropy per mission.

The trainer core (callbacks, env options, envs) is the one ``sb3-coma train`` uses
(:mod:`sb3_coma.app.training`). rl-zoo3 is extended only where it offers it: the ``ALGOS`` and Optuna
sampler tables and ``ExperimentManager`` subclassing; none of its functions is replaced. Any other
``--algo`` runs rl-zoo3's own ``train`` / ``enjoy`` unchanged.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import os
import sys
import uuid
from collections import OrderedDict
from collections.abc import Callable, Mapping
from pathlib import Path
from pprint import pprint
from typing import Any, cast

import gymnasium
import numpy as np
import optuna
import rl_zoo3.enjoy
import rl_zoo3.train
import torch as th
import yaml
from huggingface_sb3 import EnvironmentName
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.utils import ALGOS, StoreDict, get_model_path, get_wrapper_class
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sb3_coma.app.config import (
    DEFAULT_ENV_ID,
    WARM_START_KEY,
    TrainingError,
    WorldSpec,
    check_warm_start,
    config_entry,
    default_config_path,
    make_vec_env_from_kwargs,
    make_world_vec_env,
    read_config_file,
    resolve_policy_kwargs,
    resolve_workers,
    resolve_world,
    validate_entry,
)
from sb3_coma.app.marl_tasks import MarlTask, is_marl_task_id, resolve_task
from sb3_coma.app.runs import load_checkpoint
from sb3_coma.app.training import check_device, mission_callbacks, record_env_options, selection_end
from sb3_coma.app.warm_start import warm_start
from sb3_coma.app.zoo_marl import (
    MARL_ALGOS,
    MarlExperimentManager,
    preprocess_schedules,
    prune_refused_batch,
    register_marl_algos,
    run_optimization,
)
from sb3_coma.app.zoo_sampler import register as register_sampler
from sb3_coma.coma import COMA
from sb3_coma.coma.progress import JointStepProgressBar
from sb3_coma.common.callbacks import finished_missions
from sb3_coma.common.checkpoints import (
    CheckpointError,
    DiskFullError,
    atomic_save,
    validate_checkpoint,
)
from uav_ipp import ENV_IDS, ConfigError
from uav_ipp.config import SEED_MAX, count_value, integer_type

ALGO = "coma"


def register() -> None:
    """Register COMA in rl-zoo3's tables (``ALGOS`` and the Optuna sampler / converter)."""
    ALGOS[ALGO] = COMA
    register_sampler()


# =========================================================================== experiment manager
def _kwargs_key(env_kwargs: Mapping[str, Any] | None) -> str:
    """A comparable key of an ``env_kwargs`` mapping (the zoo's world is resolved once per key)."""
    return repr(sorted((env_kwargs or {}).items()))


class ComaExperimentManager(ExperimentManager):
    """rl-zoo3's ``ExperimentManager`` for COMA on the multi-agent UavIpp envs.

    ``args.variant`` (``--variant``) names a variant of the config's ``variants`` mapping.
    """

    def __init__(self, args: argparse.Namespace, algo: str, env_id: str, *pos: Any, **kwargs: Any) -> None:
        assert env_id in ENV_IDS, env_id  # train() checked it at the edge (_start, _check_env)
        super().__init__(args, algo, env_id, *pos, **kwargs)
        self.variant: str | None = getattr(args, "variant", None)
        self.map_name = ENV_IDS[env_id]

    # ------------------------------------------------------------------ hyperparameters
    def setup_experiment(self) -> Any:
        try:
            return super().setup_experiment()
        except (TrainingError, ConfigError, CheckpointError):
            raise
        except (TypeError, ValueError) as exc:  # COMA's argument checks, e.g. -params batch_size:"'abc'"
            raise TrainingError(f"{self.config} [{self.env_name.gym_id}] with command-line overrides: {exc}") from exc

    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        if not self.config.endswith((".yml", ".yaml")):
            raise TrainingError(f"-conf {self.config}: COMA configs are YAML files (zoo_configs/coma.yml)")
        env_id = self.env_name.gym_id
        print(f"Loading hyperparameters from: {self.config}" + (f" (variant {self.variant})" if self.variant else ""))
        hyperparams = config_entry(self.config, env_id, self.variant, data=read_config_file(self.config))
        if self.storage and self.study_name and self.trial_id:
            print("Loading from Optuna study...")
            hyperparams.update(self.load_trial(self.storage, self.study_name, self.trial_id))
        if self.custom_hyperparams is not None:
            hyperparams.update(self.custom_hyperparams)
        if "env_kwargs" in hyperparams and self.env_kwargs:
            # rl-zoo3's rule: --env-kwargs replace the config's env_kwargs
            hyperparams["env_kwargs"] = self.env_kwargs
            if self._eval_env_kwargs_args is None:
                self.eval_env_kwargs = hyperparams["env_kwargs"]
        variant = f", variant {self.variant}" if self.variant else ""
        world = validate_entry(hyperparams, f"{self.config} [{env_id}{variant}] with command-line overrides", env_id)
        assert world is not None  # an env id was given
        # rl-zoo3 moves these env_kwargs to self.env_kwargs: the world resolved here serves them
        self._world_spec, self._world_key = world, _kwargs_key(hyperparams.get("env_kwargs"))
        saved_hyperparams = OrderedDict([(key, hyperparams[key]) for key in sorted(hyperparams)])
        print("Default hyperparameters for environment (ones being tuned will be overridden):")
        pprint(saved_hyperparams)
        return hyperparams, saved_hyperparams

    @staticmethod
    def _preprocess_schedules(hyperparams: dict[str, Any]) -> dict[str, Any]:
        return preprocess_schedules(hyperparams)

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]) -> Any:
        # where the training copies run: ours to read, not COMA's arguments
        self.workers = resolve_workers(hyperparams.pop("workers", 1), int(hyperparams.get("n_envs", 1)))
        self.backend = str(hyperparams.pop("backend", "subprocess"))
        spec = hyperparams.pop(WARM_START_KEY, None)
        self.warm_start = None if spec is None else check_warm_start(spec, f"{self.env_name.gym_id} hyperparameters")
        if "policy_kwargs" in hyperparams:
            # Evaluate here, with COMA's names (CBAMExtractor, CnnExtractor, dotted *_class paths).
            hyperparams["policy_kwargs"] = resolve_policy_kwargs(hyperparams["policy_kwargs"])
        return super()._preprocess_hyperparams(hyperparams)

    # ------------------------------------------------------------------ envs
    def _world(self) -> WorldSpec:
        """The training world of ``self.env_kwargs`` (rl-zoo3 settles them from the config and
        ``--env-kwargs`` after the hyperparameters are read), resolved once per distinct mapping."""
        key = _kwargs_key(self.env_kwargs)
        if getattr(self, "_world_key", None) != key:
            where = f"{self.config} [{self.env_name.gym_id}]"
            self._world_spec, self._world_key = resolve_world(self.env_name.gym_id, self.env_kwargs or {}, where), key
        return self._world_spec

    def _agents(self) -> int:
        return self._world().n_agents

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        if self.vec_env_class is not DummyVecEnv and not getattr(self, "_told_vec_env", False):
            print("Note: --vec-env is ignored for UavIpp envs (env copies are vectorised by uav_ipp.make_vec_env)")
            self._told_vec_env = True
        # rl-zoo3 would give the eval env no env_kwargs when they come from the config only.
        kwargs = self.eval_env_kwargs if eval_env and self._eval_env_kwargs_args is not None else self.env_kwargs
        workers = 1 if eval_env else getattr(self, "workers", 1)
        backend = getattr(self, "backend", "subprocess")
        if kwargs is self.env_kwargs:
            env = make_world_vec_env(self._world(), n_envs, self.seed, workers, backend)
        else:
            env = make_vec_env_from_kwargs(self.env_name.gym_id, kwargs, n_envs, self.seed, workers, backend)
        if self.vec_env_wrapper is not None:
            env = self.vec_env_wrapper(env)
        return env

    # ------------------------------------------------------------------ callbacks
    def create_callbacks(self) -> None:
        if self.show_progress:
            self.callbacks.insert(0, JointStepProgressBar())
        evaluate = self.eval_freq > 0 and not self.optimize_hyperparameters
        if evaluate and self.verbose > 0:
            print("Creating test environment")
        standard = mission_callbacks(
            Path(self.save_path),
            self.save_freq,
            checkpoint_dir=Path(self.save_path),
            eval_env=self.create_envs(self.n_eval_envs, eval_env=True) if evaluate else None,
            eval_freq=self.eval_freq,
            eval_missions=self.n_eval_episodes,
            deterministic=self.deterministic_eval,
            verbose=self.verbose,
            select_after=selection_end({WARM_START_KEY: getattr(self, "warm_start", None)}, self.n_timesteps),
        )
        # SIGINT / SIGTERM stop training cleanly; rl-zoo3 then saves the model as on Ctrl-C.
        self.callbacks.extend([*standard.as_list(), *([standard.stopper] if standard.stopper else [])])

    # ------------------------------------------------------------------ learning, saving, loading
    def learn(self, model: Any) -> None:
        record_env_options(model, self._world())  # saved in checkpoints and the final zip
        spec = getattr(self, "warm_start", None)
        if spec is not None and not self.trained_agent:
            Path(self.save_path).mkdir(parents=True, exist_ok=True)
            warm_start(model, spec, self._clone_env, self.seed, Path(self.save_path), print)
        super().learn(model)

    def _clone_env(self) -> VecEnv:
        """In-process copies of the training world for the warm start's teacher."""
        env = make_world_vec_env(self._world(), self.n_envs, self.seed, 1, "subprocess")
        return self.vec_env_wrapper(env) if self.vec_env_wrapper is not None else env

    def save_trained_model(self, model: Any) -> None:
        print(f"Saving to {self.save_path}")
        atomic_save(model, Path(self.save_path) / f"{self.env_name}.zip")

    def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: VecEnv) -> Any:
        validate_checkpoint(self.trained_agent)
        return super()._load_pretrained_agent(hyperparams, env)

    # ------------------------------------------------------------------ optimisation
    def hyperparameters_optimization(self) -> None:
        # rl-zoo3's TrialEvalCallback counts agent-episodes; ask for whole missions.
        self.n_eval_episodes = int(self.n_eval_episodes) * self._agents()
        run_optimization(super().hyperparameters_optimization)

    def objective(self, trial: optuna.Trial) -> float:
        return prune_refused_batch(super().objective, trial)


# =========================================================================== argument parsers
class _StoreDict(StoreDict):
    """rl-zoo3's ``StoreDict`` (``key:value``, the value evaluated as Python, as rl-zoo3 does), but
    a value that does not evaluate is a one-line :class:`TrainingError` naming the key and the
    value instead of a ``NameError`` traceback from inside ``eval``."""

    def __call__(self, parser: Any, namespace: Any, values: Any, option_string: Any = None) -> None:
        parsed = {}
        for argument in values:
            key, _, text = argument.partition(":")
            try:
                parsed[key] = eval(text)  # rl-zoo3's format: values are Python expressions
            except Exception as exc:  # NameError, SyntaxError, ...: whatever eval raises
                raise TrainingError(
                    f"{option_string} {argument}: the value {text!r} of {key!r} cannot be read as Python "
                    f"({exc}); as in rl-zoo3, write numbers as they are and quote text ({key}:\"'text'\")"
                ) from None
        setattr(namespace, self.dest, parsed)


#: rl-zoo3's integer options, each with the values its help documents (``-1``: rl-zoo3's "the
#: default" where it has one), as argparse types (:func:`sb3_coma.app.arguments.integer_type`).
_SEED = integer_type(0, SEED_MAX, sentinels={-1: "random"})
_THREADS = integer_type(1, sentinels={-1: "torch's default"})
_CONFIG_STEPS = integer_type(1, sentinels={-1: "the config's"})
_LOG_INTERVAL = integer_type(1, sentinels={-1: "default", -2: "off"})
#: ``<= 0: none``, as rl-zoo3: every integer is a documented value.
_FREQUENCY = integer_type(None)
_EXPERIMENT = integer_type(0, sentinels={-1: "no experiment folder"})


def _common_arguments(parser: argparse.ArgumentParser, seed: int, algos: tuple[str, ...] = (ALGO,)) -> None:
    parser.add_argument(
        "--algo", default=ALGO, choices=list(algos), help=f"RL algorithm ({', '.join(algos)}; default {ALGO})"
    )
    parser.add_argument("--env", default=DEFAULT_ENV_ID, help=f"environment id (default {DEFAULT_ENV_ID})")
    parser.add_argument("--seed", type=_SEED, default=seed, help=f"random generator seed (default {seed}; -1: random)")
    parser.add_argument("--device", default="auto", help="PyTorch device (auto, cpu, cuda ...)")
    parser.add_argument("--num-threads", type=_THREADS, default=-1, help="torch threads (-1: torch's default)")
    parser.add_argument("--verbose", type=integer_type(0), default=1, help="0: no output, 1: info")
    parser.add_argument("--gym-packages", nargs="+", default=[], help="extra modules to import (env registration)")
    parser.add_argument("--env-kwargs", nargs="+", action=_StoreDict, help="env options, e.g. noise:'loud'")
    parser.add_argument("-P", "--progress", action="store_true", help="show a progress bar")


def train_parser() -> argparse.ArgumentParser:
    """rl-zoo3 2.9's ``train`` arguments (same names, defaults and meaning) plus ``--variant``."""
    parser = argparse.ArgumentParser(
        prog="python -m sb3_coma.zoo train",
        description="rl-zoo3's train with COMA on a UavIpp env, or with COMA, MAPPO or IPPO on a third-party "
        "PettingZoo task (simple_spread, ..., or package.module:factory); steps are joint steps",
    )
    _common_arguments(parser, seed=-1, algos=tuple(MARL_ALGOS))
    add = parser.add_argument
    add("--variant", default=None, help="a key of the config's 'variants' mapping (e.g. mean-cnn)")
    add(
        "-conf",
        "--conf-file",
        default=None,
        help="YAML hyperparameters (default zoo_configs/coma.yml; a third-party task: zoo_configs/marl/<algo>.yml)",
    )
    add("-params", "--hyperparams", nargs="+", action=_StoreDict, help="override hyperparameters (batch_size:64)")
    add("--eval-env-kwargs", nargs="+", action=_StoreDict, help="env options of the evaluation env")
    add("-tb", "--tensorboard-log", default="", help="TensorBoard log folder")
    add("-i", "--trained-agent", default="", help="a model .zip to continue training")
    add("--truncate-last-trajectory", type=bool, default=True, help="(off-policy algorithms only)")
    add("-n", "--n-timesteps", type=_CONFIG_STEPS, default=-1, help="joint steps to train (-1: the config's)")
    add("--log-interval", type=_LOG_INTERVAL, default=-1, help="log every N rollouts (-1: default, -2: off)")
    add("--eval-freq", type=_FREQUENCY, default=25000, help="joint steps between evaluations (<= 0: none)")
    add("--optimization-log-path", default=None, help="folder for each trial's evaluations and best model")
    add("--eval-episodes", type=count_value, default=5, help="missions per evaluation")
    add("--n-eval-envs", type=count_value, default=1, help="env copies of the evaluation env")
    add("--save-freq", type=_FREQUENCY, default=-1, help="joint steps between checkpoints (<= 0: none)")
    add("--save-replay-buffer", action="store_true", help="(off-policy algorithms only)")
    add("-f", "--log-folder", default="logs", help="log folder")
    add("--vec-env", default="dummy", choices=["dummy", "subproc"], help="ignored (env copies are vectorised)")
    add("--n-trials", type=count_value, default=500, help="Optuna trials of this worker")
    add("--max-total-trials", type=count_value, default=None, help="Optuna trials of the whole study")
    add("-optimize", "--optimize-hyperparameters", action="store_true", help="run a hyperparameter search")
    add("--no-optim-plots", action="store_true", help="no Optuna plots")
    add("--n-jobs", type=count_value, default=1, help="parallel Optuna jobs")
    add("--sampler", default="tpe", choices=["random", "tpe", "auto"], help="Optuna sampler")
    add("--pruner", default="median", choices=["halving", "median", "none"], help="Optuna pruner")
    add("--n-startup-trials", type=integer_type(0), default=10, help="trials before the sampler is used")
    add("--n-evaluations", type=count_value, default=None, help="evaluations per trial")
    add("--storage", default=None, help="Optuna storage (sqlite:///coma.db, a .log journal file, ...)")
    add("--study-name", default=None, help="Optuna study name")
    add("--trial-id", type=integer_type(0), default=None, help="Optuna trial whose hyperparameters to train with")
    add("-uuid", "--uuid", action="store_true", help="a unique id in the log folder name")
    add("--track", action="store_true", help="Weights & Biases tracking (not supported with COMA: use -tb)")
    return parser


def enjoy_parser() -> argparse.ArgumentParser:
    """rl-zoo3 2.9's ``enjoy`` arguments for a COMA model (``--reward-log`` excluded)."""
    parser = argparse.ArgumentParser(
        prog="python -m sb3_coma.zoo enjoy", description="fly a COMA model from an rl-zoo3 log folder"
    )
    _common_arguments(parser, seed=0)
    add = parser.add_argument
    add("-f", "--folder", default="logs", help="log folder")
    add("-n", "--n-timesteps", type=count_value, default=1000, help="env steps to fly")
    add("--n-envs", type=count_value, default=1, help="env copies")
    add("--exp-id", type=_EXPERIMENT, default=0, help="experiment id (0: latest, -1: no experiment folder)")
    add("--no-render", action="store_true", help="do not render (rendering is not available: headless maps)")
    add("--deterministic", action="store_true", help="argmax actions (the default for COMA)")
    add("--stochastic", action="store_true", help="sample actions from the policy")
    add("--load-best", action="store_true", help="load best_model.zip")
    add("--load-checkpoint", type=count_value, default=None, help="load rl_model_<N>_steps.zip")
    add("--load-last-checkpoint", action="store_true", help="load the newest checkpoint")
    add("--norm-reward", action="store_true", help="ignored (no VecNormalize)")
    add("--custom-objects", action="store_true", help="ignored (COMA models load without them)")
    return parser


# =========================================================================== train and enjoy
def _check_env(env_id: str) -> None:
    """One rule: a UavIpp env id or a third-party task (another registered env is rl-zoo3's, not COMA's)."""
    if env_id in ENV_IDS or is_marl_task_id(env_id):
        return
    close = difflib.get_close_matches(env_id, list(ENV_IDS) + list(gymnasium.registry), n=1)
    raise TrainingError(
        f"--algo {ALGO} trains the UavIpp envs ({', '.join(ENV_IDS)}) and cooperative PettingZoo tasks "
        f"(simple_spread, ..., package.module:factory), not the single-agent {env_id!r}"
        if env_id in gymnasium.registry
        else f"unknown env id {env_id!r}" + (f" (did you mean {close[0]!r}?)" if close else "")
    )


def _start(args: argparse.Namespace) -> None:
    """What rl-zoo3's entry points do first: extra env packages, the seed, torch threads (and,
    unlike rl-zoo3, refuse a --device this machine lacks rather than run on the CPU)."""
    for module in args.gym_packages:
        importlib.import_module(module)
    _check_env(args.env)
    check_device(args.device)
    if args.seed < 0:
        args.seed = int(np.random.randint(2**32 - 1, dtype="int64"))
    set_random_seed(args.seed)
    if args.num_threads > 0:
        th.set_num_threads(args.num_threads)


def train(args: argparse.Namespace) -> None:
    """rl-zoo3's training lifecycle with :class:`ComaExperimentManager`."""
    refused = (  # (refused, why): the options rl-zoo3 takes that a COMA run cannot
        (args.track, "--track (Weights & Biases) is not supported with --algo coma; use -tb for TensorBoard"),
        (
            args.trained_agent and not (args.trained_agent.endswith(".zip") and os.path.isfile(args.trained_agent)),
            f"-i {args.trained_agent}: the trained agent must be an existing .zip file",
        ),
    )
    problem = next((why for bad, why in refused if bad), None)
    if problem is not None:
        raise TrainingError(problem)
    _start(args)
    marl = args.env not in ENV_IDS
    if marl and args.variant is not None:
        raise TrainingError(f"--variant {args.variant}: variants are the UavIpp config's; a task's entry has none")
    assert marl or args.algo == ALGO, args.algo  # main() sent another algo on a UavIpp env to its refusal
    register()
    register_marl_algos()
    print("=" * 10, args.env, "=" * 10)
    print(f"Seed: {args.seed}")
    manager_class: Callable[..., ExperimentManager] = MarlExperimentManager if marl else ComaExperimentManager
    target: MarlTask | str = resolve_task(args.env) if marl else args.env
    config = f"marl/{args.algo}.yml" if marl else "coma.yml"
    manager = manager_class(
        args,
        args.algo,
        target,
        args.log_folder,
        args.tensorboard_log,
        args.n_timesteps,
        args.eval_freq,
        args.eval_episodes,
        args.save_freq,
        args.hyperparams,
        args.env_kwargs,
        args.eval_env_kwargs,
        args.trained_agent,
        args.optimize_hyperparameters,
        args.storage,
        args.study_name,
        args.n_trials,
        args.max_total_trials,
        args.n_jobs,
        args.sampler,
        args.pruner,
        args.optimization_log_path,
        n_startup_trials=args.n_startup_trials,
        n_evaluations=args.n_evaluations,
        truncate_last_trajectory=args.truncate_last_trajectory,
        uuid_str=f"_{uuid.uuid4()}" if args.uuid else "",
        seed=args.seed,
        log_interval=args.log_interval,
        save_replay_buffer=args.save_replay_buffer,
        verbose=args.verbose,
        vec_env_type=args.vec_env,
        n_eval_envs=args.n_eval_envs,
        no_optim_plots=args.no_optim_plots,
        device=args.device,
        config=args.conf_file or str(default_config_path(config)),
        show_progress=args.progress,
        trial_id=args.trial_id,
    )
    results = manager.setup_experiment()
    if results is None:
        manager.hyperparameters_optimization()
        return
    model, _ = results
    manager.learn(model)
    manager.save_trained_model(model)


def train_marl_task(
    env_id: str,
    *,
    config: str | None,
    timesteps: int | None,
    seed: int | None,
    log_folder: str,
    hyperparams: dict[str, Any],
    eval_freq: int,
    save_freq: int | None,
    device: str,
    verbose: int,
    progress: bool,
) -> None:
    """``sb3-coma train --env <task>``: COMA on a third-party task through the zoo's own training
    (:class:`MarlExperimentManager`), so both front doors give the same run for the same options."""
    argv = ["--algo", ALGO, "--env", env_id, "-f", log_folder, "--seed", str(-1 if seed is None else seed)]
    argv += ["--eval-freq", str(eval_freq or -1), "--device", device, "--verbose", str(verbose)]
    argv += [] if config is None else ["-conf", config]
    argv += [] if timesteps is None else ["-n", str(timesteps)]
    argv += [] if save_freq is None else ["--save-freq", str(save_freq or -1)]
    argv += ["--progress"] if progress else []
    args = train_parser().parse_args(argv)
    args.hyperparams = dict(hyperparams) or None
    train(args)


class _ZooLogLoader(yaml.SafeLoader):
    """YAML as rl-zoo3 writes a log folder's ``config.yml`` / ``args.yml`` (``yaml.dump`` of an
    ``OrderedDict``), without the power to build any other Python object: rl-zoo3 itself reads
    them with ``yaml.UnsafeLoader``, so a shared log folder could run code from its YAML."""


def _ordered_dict(loader: yaml.SafeLoader, node: yaml.Node) -> OrderedDict:
    assert isinstance(node, yaml.SequenceNode)
    pairs = loader.construct_sequence(node, deep=True)
    return OrderedDict((key, value) for key, value in (pairs[0] if pairs and isinstance(pairs[0], list) else pairs))


_ZooLogLoader.add_constructor("tag:yaml.org,2002:python/object/apply:collections.OrderedDict", _ordered_dict)


def read_zoo_log_yaml(path: Path) -> Any:
    """A log folder's YAML, safely (:class:`_ZooLogLoader`); any other Python tag is one line."""
    try:
        return yaml.load(path.read_text(encoding="utf-8"), Loader=_ZooLogLoader)
    except yaml.YAMLError as exc:  # a Python tag (ConstructorError) or broken YAML: one line
        first = str(exc).splitlines()[0]
        raise TrainingError(
            f"{path}: {getattr(exc, 'problem', '') or first}; sb3-coma reads log-folder YAML as plain data (and "
            "rl-zoo3's OrderedDicts) only, never Python objects: fix or delete that entry"
            if isinstance(exc, yaml.constructor.ConstructorError)
            else f"{path}: not valid YAML ({first})"
        ) from None


def _saved_hyperparams(stats_path: str) -> dict[str, Any]:
    """rl-zoo3's ``get_saved_hyperparams`` for what ``enjoy`` uses (``env_kwargs``, the vec-env
    wrapper), with the safe loader."""
    config = Path(stats_path) / "config.yml"
    if not config.is_file():
        return {}
    loaded = read_zoo_log_yaml(config)
    return dict(loaded) if isinstance(loaded, dict) else {}


def _enjoy_env_kwargs(
    log_path: str, env_name: str, hyperparams: dict[str, Any], given: dict[str, Any] | None
) -> dict[str, Any]:
    """rl-zoo3's rule: the saved config's env_kwargs, replaced by those of the training command
    line (``args.yml``), updated by ``--env-kwargs``."""
    env_kwargs = dict(hyperparams.get("env_kwargs") or {})
    args_path = Path(log_path) / env_name / "args.yml"
    if args_path.is_file():
        saved = read_zoo_log_yaml(args_path) or {}
        if saved.get("env_kwargs") is not None:
            env_kwargs = dict(saved["env_kwargs"])
    env_kwargs.update(given or {})
    return env_kwargs


def enjoy(args: argparse.Namespace) -> None:
    """Fly a COMA model from rl-zoo3's log folders; one line per finished mission."""
    _start(args)
    env_name = EnvironmentName(args.env)
    try:
        _, model_path, log_path = get_model_path(
            args.exp_id, args.folder, ALGO, env_name, args.load_best, args.load_checkpoint, args.load_last_checkpoint
        )
    except (AssertionError, ValueError) as exc:
        raise TrainingError(str(exc)) from exc
    print(f"Loading {model_path}")
    hyperparams = _saved_hyperparams(os.path.join(log_path, env_name))
    env = make_vec_env_from_kwargs(
        args.env, _enjoy_env_kwargs(log_path, env_name, hyperparams, args.env_kwargs), args.n_envs, args.seed
    )
    # rl-zoo3 annotates get_wrapper_class for gym.Env wrappers; for "vec_env_wrapper" it returns VecEnv wrappers.
    wrapper = cast("Callable[[VecEnv], VecEnv] | None", get_wrapper_class(hyperparams, "vec_env_wrapper"))
    if wrapper is not None:
        env = wrapper(env)
    if not args.no_render:
        print("Live rendering is not available for UavIpp envs; pass --no-render (plots: sb3-coma evaluate)")
    try:
        _fly(
            load_checkpoint(model_path, env=env, device=args.device),
            env,
            args.n_timesteps,
            deterministic=not args.stochastic,
            verbose=args.verbose,
        )
    finally:
        env.close()


def _fly(model: COMA, env: VecEnv, steps: int, deterministic: bool, verbose: int) -> None:
    n_agents = int(model.n_agents or 1)
    missions: list[dict[str, float]] = []
    obs = env.reset()
    episode_start = np.ones(env.num_envs, dtype=bool)
    try:
        for _ in range(steps):
            assert isinstance(obs, dict)  # the vec envs of uav_ipp.make_vec_env have Dict observations
            actions, _ = model.predict(obs, episode_start=episode_start, deterministic=deterministic)
            obs, _, dones, infos = env.step(actions)
            episode_start = dones
            for copy, info in finished_missions(infos, dones, n_agents):
                episode = info.get("episode", {})
                record = {
                    "reward": float(episode.get("r", np.nan)),
                    "length": float(episode.get("l", np.nan)),
                    "f1": float(info.get("f1", np.nan)),
                    "entropy": float(info.get("entropy", np.nan)),
                }
                missions.append(record)
                if verbose > 0:
                    print(
                        f"Mission {len(missions)} (copy {copy}): team reward {record['reward']:+.3f}, "
                        f"F1 {record['f1']:.3f}, entropy {record['entropy']:.3f}"
                    )
                    print(f"Episode Reward: {record['reward']:.2f}")
                    print("Episode Length", int(record["length"]) if np.isfinite(record["length"]) else "?")
    except KeyboardInterrupt:
        pass
    if verbose > 0 and missions:
        rewards = [m["reward"] for m in missions]
        print(f"{len(missions)} Episodes")
        print(f"Mean reward: {np.mean(rewards):.2f} +/- {np.std(rewards):.2f}")
        print(
            f"{len(missions)} missions: mean final F1 {np.nanmean([m['f1'] for m in missions]):.3f}, "
            f"mean final entropy {np.nanmean([m['entropy'] for m in missions]):.3f}"
        )


# =========================================================================== entry point
USAGE = """usage: python -m sb3_coma.zoo {train,enjoy} [rl-zoo3 arguments]

  train   rl-zoo3's train with COMA (--algo coma and -conf zoo_configs/coma.yml by default);
          extra option: --variant NAME (a key of the config's 'variants' mapping)
  enjoy   fly a model trained with `train` from its log folder (use --no-render)

Examples:
  python -m sb3_coma.zoo train --algo coma --env UavIpp-Env3-v0 -conf zoo_configs/coma.yml
  python -m sb3_coma.zoo train --env UavIpp-Env3-v0 --variant mean-cnn -n 36000 --seed 1 -tb runs/tb
  python -m sb3_coma.zoo train --env UavIpp-Env1-v0 -optimize --n-trials 50 --storage sqlite:///coma.db --study-name env1
  python -m sb3_coma.zoo enjoy --algo coma --env UavIpp-Env3-v0 -f logs --no-render -n 150
"""
COMMANDS = {"train": (train_parser, train), "enjoy": (enjoy_parser, enjoy)}


def _option_value(args: list[str], *names: str) -> str | None:
    for i, a in enumerate(args):
        for n in names:
            if a == n and i + 1 < len(args):
                return args[i + 1]
            if a.startswith(n + "="):
                return a.split("=", 1)[1]
    return None


def _rl_zoo3(command: str, args: list[str]) -> None:
    """Another algorithm: rl-zoo3's own entry point, untouched (it reads ``sys.argv``)."""
    env_id = _option_value(args, "--env")
    if env_id in ENV_IDS:
        raise TrainingError(
            f"{env_id} is a multi-agent env: train it with --algo {ALGO}, not {_option_value(args, '--algo')!r}"
        )
    runner = {"train": rl_zoo3.train.train, "enjoy": rl_zoo3.enjoy.enjoy}[command]
    saved_argv = sys.argv
    sys.argv = [f"rl_zoo3 {command}", *args]
    try:
        runner()
    finally:
        sys.argv = saved_argv


def main(argv: list[str] | None = None) -> int:
    """Run ``train`` or ``enjoy``; return an exit status (2 for a user error, one line)."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if args else 2
    command, rest = args[0], args[1:]
    if command not in COMMANDS:
        print(f"sb3_coma.app.zoo: error: unknown command {command!r} (train or enjoy)\n\n{USAGE}", file=sys.stderr)
        return 2
    make_parser, run = COMMANDS[command]
    try:
        algo, env_id = _option_value(rest, "--algo"), _option_value(rest, "--env")
        marl_training = command == "train" and algo in MARL_ALGOS and env_id is not None and is_marl_task_id(env_id)
        if algo not in (None, ALGO) and not marl_training:
            _rl_zoo3(command, rest)
        else:
            run(make_parser().parse_args(rest))
    except SystemExit as exc:  # argparse: --help (0) or a bad option (2, usage printed)
        return int(exc.code or 0) if not isinstance(exc.code, str) else 2
    except (TrainingError, CheckpointError, ConfigError) as exc:
        print(f"sb3_coma.app.zoo {command}: error: {exc}", file=sys.stderr)
        return 2
    except DiskFullError as exc:  # the machine, not the input: one line, exit 1 (as sb3-coma)
        print(f"sb3_coma.app.zoo {command}: error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
