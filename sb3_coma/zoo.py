"""rl-zoo3 with COMA: ``python -m sb3_coma.zoo train|enjoy [rl-zoo3 arguments]``.

This runs rl-zoo3's own ``train`` and ``enjoy`` (its argument parser, log folder layout
``logs/coma/<env id>_<n>/``, saving, evaluation, Optuna search, ``-n``, ``--seed``, ``-tb``,
``--eval-freq``, ``--save-freq``, ``-params``, ``--env-kwargs`` ...) with four additions:

* ``ALGOS["coma"] = COMA`` and the COMA Optuna sampler are registered before rl-zoo3 builds its
  ``--algo`` choices;
* rl-zoo3's ``ExperimentManager`` is replaced, for the duration of the call, by
  :class:`ComaExperimentManager`, which builds envs with ``envs.make_vec_env`` (``gym.make``
  cannot return a multi-agent env), counts evaluation and checkpoint frequencies in joint steps
  and evaluations in missions, logs mission F1 / entropy / team reward, writes models and
  checkpoints atomically, validates the config with clear errors and understands
  ``--variant NAME`` (the config's ``variants`` mapping);
* rl-zoo3's ``create_test_env`` (used by ``enjoy``) gets the same env factory for UavIpp ids and
  reports F1 and entropy per mission;
* ``--algo coma``, ``--env UavIpp-Env3-v0`` and ``-conf zoo_configs/coma.yml`` are the defaults.

Other algorithms and envs pass through to rl-zoo3 unchanged.
"""
from __future__ import annotations

import difflib
import sys
from collections import OrderedDict
from contextlib import contextmanager
from pathlib import Path
from pprint import pprint
from typing import Any, Iterator

import gymnasium
import numpy as np
from rl_zoo3.exp_manager import ExperimentManager
from rl_zoo3.utils import ALGOS
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

import envs
from envs import ENV_IDS, ConfigError
from sb3_coma.checkpoints import CheckpointError, atomic_save, validate_checkpoint
from sb3_coma.training import (
    TrainingError,
    _schedule,
    _split_env_kwargs,
    config_entry,
    default_config_path,
    read_config_file,
    resolve_policy_kwargs,
    validate_entry,
)

__all__ = ["ComaExperimentManager", "MissionReportVecEnv", "create_test_env", "main", "register"]

ALGO = "coma"
DEFAULT_ENV = "UavIpp-Env3-v0"


def register() -> None:
    """Register COMA with rl-zoo3 (``ALGOS`` and the Optuna sampler / converter tables)."""
    from sb3_coma.coma import COMA
    from sb3_coma.zoo_sampler import register as register_sampler

    ALGOS[ALGO] = COMA
    register_sampler()


def _n_agents(env_kwargs: dict[str, Any] | None, env_id: str) -> int:
    _, _, options = _split_env_kwargs(env_kwargs or {})
    return envs.IppConfig.from_options(ENV_IDS[env_id], **options).n_uavs


def _build_vec_env(env_id: str, env_kwargs: dict[str, Any] | None, n_envs: int, seed: int | None) -> VecEnv:
    fusion, fusion_kwargs, options = _split_env_kwargs(env_kwargs or {})
    if options.get("render_mode") == "human":  # rl-zoo3's default for enjoy; maps render headless
        options.pop("render_mode")
    if fusion_kwargs:
        options["fusion_kwargs"] = fusion_kwargs
    try:
        return envs.make_vec_env(ENV_IDS[env_id], n_envs=n_envs, fusion=fusion, seed=seed, **options)
    except ValueError as exc:  # ConfigError is a ValueError too
        raise TrainingError(f"cannot build {env_id} with env_kwargs {env_kwargs}: {exc}") from exc


# =========================================================================== experiment manager
class ComaExperimentManager(ExperimentManager):
    """rl-zoo3's ``ExperimentManager`` for the multi-agent UavIpp envs (others: unchanged)."""

    #: ``--variant`` of the current call (set by :func:`main`).
    variant: str | None = None

    def __init__(self, args: Any, algo: str, env_id: str, *pos: Any, **kwargs: Any) -> None:
        super().__init__(args, algo, env_id, *pos, **kwargs)
        self._ours = env_id in ENV_IDS
        if self._ours and algo != ALGO:
            raise TrainingError(f"{env_id} is a multi-agent env: train it with --algo {ALGO}, not {algo!r}")
        if algo == ALGO and not self._ours:
            raise TrainingError(f"--algo {ALGO} trains the UavIpp envs ({', '.join(ENV_IDS)}), not {env_id!r}")
        if self._ours and args is not None:
            args.variant = self.variant  # recorded in args.yml

    # ------------------------------------------------------------------ hyperparameters
    def read_hyperparameters(self) -> tuple[dict[str, Any], dict[str, Any]]:
        if not self._ours or not self.config.endswith((".yml", ".yaml")):
            if self.variant is not None:
                raise TrainingError("--variant needs a YAML config (-conf FILE.yml)")
            return super().read_hyperparameters()
        env_id = self.env_name.gym_id
        print(f"Loading hyperparameters from: {self.config}" + (f" (variant {self.variant})" if self.variant else ""))
        data = read_config_file(self.config)
        hyperparams = config_entry(self.config, env_id, self.variant, data=data)
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
        where = f"{self.config} [{env_id}" + (f", variant {self.variant}" if self.variant else "") + "] with command-line overrides"
        validate_entry(hyperparams, where, ENV_IDS[env_id])
        saved_hyperparams = OrderedDict([(key, hyperparams[key]) for key in sorted(hyperparams)])
        print("Default hyperparameters for environment (ones being tuned will be overridden):")
        pprint(saved_hyperparams)
        return hyperparams, saved_hyperparams

    @staticmethod
    def _preprocess_schedules(hyperparams: dict[str, Any]) -> dict[str, Any]:
        critic = hyperparams.pop("critic_learning_rate", None)
        hyperparams = ExperimentManager._preprocess_schedules(hyperparams)
        if critic is not None:
            hyperparams["critic_learning_rate"] = _schedule(critic)
        return hyperparams

    def _preprocess_hyperparams(self, hyperparams: dict[str, Any]):
        if self._ours and "policy_kwargs" in hyperparams:
            # Evaluate here, with COMA's names (CBAMExtractor, CnnExtractor, dotted *_class paths).
            hyperparams["policy_kwargs"] = resolve_policy_kwargs(hyperparams["policy_kwargs"])
        return super()._preprocess_hyperparams(hyperparams)

    # ------------------------------------------------------------------ envs
    def _agents(self) -> int:
        return _n_agents(self.env_kwargs, self.env_name.gym_id)

    def create_envs(self, n_envs: int, eval_env: bool = False, no_log: bool = False) -> VecEnv:
        if not self._ours:
            return super().create_envs(n_envs, eval_env=eval_env, no_log=no_log)
        if self.vec_env_class is not DummyVecEnv and not getattr(self, "_told_vec_env", False):
            print("Note: --vec-env is ignored for UavIpp envs (env copies are vectorised by envs.make_vec_env)")
            self._told_vec_env = True
        # rl-zoo3 would give the eval env no env_kwargs when they come from the config only.
        kwargs = self.eval_env_kwargs if eval_env and self._eval_env_kwargs_args is not None else self.env_kwargs
        env = _build_vec_env(self.env_name.gym_id, kwargs, n_envs, self.seed)
        if self.vec_env_wrapper is not None:
            env = self.vec_env_wrapper(env)
        return env

    # ------------------------------------------------------------------ callbacks
    def create_callbacks(self) -> None:
        if not self._ours:
            return super().create_callbacks()
        from sb3_coma.callbacks import (
            EpisodeMetricsCallback,
            JointCheckpointCallback,
            MissionEvalCallback,
            SignalStopCallback,
        )
        from sb3_coma.coma.progress import JointStepProgressBar

        if self.show_progress:
            self.callbacks.insert(0, JointStepProgressBar())
        # Per-mission reward / F1 / entropy to TensorBoard and <save_path>/metrics.csv.
        self.callbacks.append(EpisodeMetricsCallback(csv_path=Path(self.save_path) / "metrics.csv"))
        if self.save_freq > 0:
            # In joint steps, at rollout boundaries, atomic; rl-zoo3's file names.
            self.callbacks.append(JointCheckpointCallback(self.save_freq, self.save_path, verbose=1))
        if self.eval_freq > 0 and not self.optimize_hyperparameters:
            if self.verbose > 0:
                print("Creating test environment")
            self.callbacks.append(
                MissionEvalCallback(
                    self.create_envs(self.n_eval_envs, eval_env=True),
                    eval_freq=self.eval_freq,
                    n_eval_missions=self.n_eval_episodes,
                    best_model_save_path=self.save_path,
                    log_path=self.save_path,
                    deterministic=self.deterministic_eval,
                    verbose=self.verbose,
                )
            )
        # SIGINT / SIGTERM stop training cleanly; rl-zoo3 then saves the model as on Ctrl-C.
        self.callbacks.append(SignalStopCallback(verbose=self.verbose))

    # ------------------------------------------------------------------ saving / loading
    def save_trained_model(self, model: Any) -> None:
        if not self._ours:
            return super().save_trained_model(model)
        print(f"Saving to {self.save_path}")
        atomic_save(model, Path(self.save_path) / f"{self.env_name}.zip")

    def _load_pretrained_agent(self, hyperparams: dict[str, Any], env: VecEnv):
        if self._ours:
            validate_checkpoint(self.trained_agent)
        return super()._load_pretrained_agent(hyperparams, env)

    # ------------------------------------------------------------------ optimisation
    def hyperparameters_optimization(self) -> None:
        if self._ours:
            # rl-zoo3's TrialEvalCallback counts agent-episodes; ask for whole missions.
            self.n_eval_episodes = int(self.n_eval_episodes) * self._agents()
        try:
            return super().hyperparameters_optimization()
        except ImportError as exc:
            # rl-zoo3 writes its report with study.trials_dataframe(), which needs pandas; the
            # search itself is finished by then (and kept in --storage when one is given).
            if "pandas" not in str(exc):
                raise
            print(f"Optuna report not written: {exc.__class__.__name__}: pandas is not installed "
                  "(pip install pandas); the trials are kept in the study storage")
            return None


# =========================================================================== enjoy
class _MissionDones(np.ndarray):
    """The ``dones`` of one step: truthy when every row's mission ended (rl-zoo3's ``if done``)."""

    def __bool__(self) -> bool:
        return bool(np.all(np.asarray(self)))


class MissionReportVecEnv(VecEnvWrapper):
    """Wrapper used by ``enjoy``: prints F1 / entropy per mission, makes ``if done`` mission-wise.

    rl-zoo3's ``enjoy`` was written for one row per env (``if done: ...``); here a step has one
    row per UAV, all ending together. Live rendering is not available (headless maps; use
    ``sb3-coma evaluate`` for plots), so ``render`` only explains that once.
    """

    def __init__(self, venv: VecEnv, render_requested: bool = False) -> None:
        super().__init__(venv)
        self.n_agents = int(getattr(venv, "n_agents", 1))
        self.render_requested = render_requested
        self._told = False
        self.missions: list[dict[str, float]] = []

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        for row in range(0, len(infos), self.n_agents):
            if dones[row]:
                info = infos[row]
                episode = info.get("episode", {})
                record = {
                    "reward": float(episode.get("r", np.nan)),
                    "f1": float(info.get("f1", np.nan)),
                    "entropy": float(info.get("entropy", np.nan)),
                }
                self.missions.append(record)
                print(
                    f"Mission {len(self.missions)} (copy {row // self.n_agents}): team reward {record['reward']:+.3f}, "
                    f"F1 {record['f1']:.3f}, entropy {record['entropy']:.3f}"
                )
        return obs, rewards, np.asarray(dones, dtype=bool).view(_MissionDones), infos

    def render(self, mode: str | None = None):  # type: ignore[override]
        if self.render_requested and not self._told:
            print("Live rendering is not available for UavIpp envs; pass --no-render (plots: sb3-coma evaluate)")
            self._told = True
        return None

    def close(self) -> None:
        if self.missions:
            f1 = np.nanmean([m["f1"] for m in self.missions])
            ent = np.nanmean([m["entropy"] for m in self.missions])
            print(f"{len(self.missions)} missions: mean final F1 {f1:.3f}, mean final entropy {ent:.3f}")
        self.venv.close()


_ORIGINAL_CREATE_TEST_ENV = None


def create_test_env(env_id: str, n_envs: int = 1, stats_path: str | None = None, seed: int = 0,
                    log_dir: str | None = None, should_render: bool = True, hyperparams: dict | None = None,
                    env_kwargs: dict | None = None, vec_env_cls: Any = None, vec_env_kwargs: dict | None = None) -> VecEnv:
    """rl-zoo3's ``create_test_env`` for UavIpp ids (``n_envs`` env copies); others pass through."""
    if env_id not in ENV_IDS:
        import rl_zoo3.utils

        original = _ORIGINAL_CREATE_TEST_ENV or rl_zoo3.utils.create_test_env
        return original(env_id, n_envs=n_envs, stats_path=stats_path, seed=seed, log_dir=log_dir,
                        should_render=should_render, hyperparams=hyperparams, env_kwargs=env_kwargs,
                        vec_env_cls=vec_env_cls, vec_env_kwargs=vec_env_kwargs)
    env = _build_vec_env(env_id, env_kwargs, n_envs, seed)
    wrapper = (hyperparams or {}).get("vec_env_wrapper")
    if wrapper is not None:
        from rl_zoo3.utils import get_wrapper_class

        wrap = get_wrapper_class(hyperparams or {}, "vec_env_wrapper")
        env = wrap(env) if wrap is not None else env
    return MissionReportVecEnv(env, render_requested=should_render)


# =========================================================================== entry point
@contextmanager
def _patched(variant: str | None) -> Iterator[None]:
    """Swap rl-zoo3's manager and test-env factory for ours during one call."""
    global _ORIGINAL_CREATE_TEST_ENV
    import rl_zoo3.enjoy as zoo_enjoy
    import rl_zoo3.train as zoo_train

    saved = (zoo_train.ExperimentManager, zoo_enjoy.create_test_env, ComaExperimentManager.variant)
    _ORIGINAL_CREATE_TEST_ENV = zoo_enjoy.create_test_env
    zoo_train.ExperimentManager = ComaExperimentManager
    zoo_enjoy.create_test_env = create_test_env
    ComaExperimentManager.variant = variant
    try:
        yield
    finally:
        zoo_train.ExperimentManager, zoo_enjoy.create_test_env, ComaExperimentManager.variant = saved
        _ORIGINAL_CREATE_TEST_ENV = None


def _pop_option(args: list[str], name: str) -> tuple[str | None, list[str]]:
    """Remove ``name VALUE`` / ``name=VALUE`` from ``args``; return ``(VALUE, rest)``."""
    out, value, i = [], None, 0
    while i < len(args):
        arg = args[i]
        if arg == name:
            if i + 1 >= len(args):
                raise TrainingError(f"{name} needs a value")
            value, i = args[i + 1], i + 2
            continue
        if arg.startswith(name + "="):
            value = arg.split("=", 1)[1]
        else:
            out.append(arg)
        i += 1
    return value, out


def _has_option(args: list[str], *names: str) -> bool:
    return any(a in names or any(a.startswith(n + "=") for n in names) for a in args)


def _option_value(args: list[str], *names: str) -> str | None:
    for i, a in enumerate(args):
        for n in names:
            if a == n and i + 1 < len(args):
                return args[i + 1]
            if a.startswith(n + "="):
                return a.split("=", 1)[1]
    return None


USAGE = """usage: python -m sb3_coma.zoo {train,enjoy} [rl-zoo3 arguments]

  train   rl-zoo3's train with COMA (--algo coma and -conf zoo_configs/coma.yml by default);
          extra option: --variant NAME (a key of the config's 'variants' mapping)
  enjoy   rl-zoo3's enjoy for a model trained with `train` (use --no-render)

Examples:
  python -m sb3_coma.zoo train --algo coma --env UavIpp-Env3-v0 -conf zoo_configs/coma.yml
  python -m sb3_coma.zoo train --env UavIpp-Env3-v0 --variant mean-cnn -n 36000 --seed 1 -tb runs/tb
  python -m sb3_coma.zoo train --env UavIpp-Env1-v0 -optimize --n-trials 50 --storage sqlite:///coma.db --study-name env1
  python -m sb3_coma.zoo enjoy --algo coma --env UavIpp-Env3-v0 -f logs --no-render -n 150
"""


def main(argv: list[str] | None = None) -> int:
    """Run rl-zoo3's ``train`` or ``enjoy`` with COMA registered; return an exit status."""
    args = list(sys.argv[1:] if argv is None else argv)
    if not args or args[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if args else 2
    command, rest = args[0], args[1:]
    if command not in ("train", "enjoy"):
        print(f"sb3_coma.zoo: error: unknown command {command!r} (train or enjoy)\n\n{USAGE}", file=sys.stderr)
        return 2
    try:
        variant, rest = _pop_option(rest, "--variant")
        if variant is not None and command != "train":
            raise TrainingError("--variant is a train option (enjoy reads the run's saved config)")
        if not _has_option(rest, "--algo"):
            rest = ["--algo", ALGO, *rest]
        algo = _option_value(rest, "--algo")
        if algo == ALGO and not _has_option(rest, "--env"):
            rest = [*rest, "--env", DEFAULT_ENV]
        env_id = _option_value(rest, "--env")
        if env_id is not None and env_id not in gymnasium.registry:
            close = difflib.get_close_matches(env_id, list(ENV_IDS) + list(gymnasium.registry), n=1)
            raise TrainingError(f"unknown env id {env_id!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        if command == "train" and algo == ALGO and not _has_option(rest, "-conf", "--conf-file"):
            rest = [*rest, "-conf", str(default_config_path())]
        register()
        from rl_zoo3.enjoy import enjoy as zoo_enjoy_main
        from rl_zoo3.train import train as zoo_train_main

        runner = {"train": zoo_train_main, "enjoy": zoo_enjoy_main}[command]
        saved_argv = sys.argv
        sys.argv = [f"{Path(sys.argv[0]).name if sys.argv else 'sb3_coma.zoo'} {command}", *rest]
        try:
            with _patched(variant):
                runner()
        finally:
            sys.argv = saved_argv
    except (TrainingError, CheckpointError, ConfigError) as exc:
        print(f"sb3_coma.zoo {command}: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
