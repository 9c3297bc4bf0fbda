"""Training as users run it: configs, run folders, checkpoints, resume.

:func:`train` is the Python API behind ``sb3-coma train`` (and the ``reproduce`` command)::

    from sb3_coma.training import train
    model, run_dir = train(env="env3", variant="mean-cnn", total_timesteps=18_000, seed=0)

A run folder holds everything about one training run::

    runs/UavIpp-Env3-v0_1/
        config.yml         the resolved config (itself a valid rl-zoo3 config file) + run info
        tb/COMA_1/         TensorBoard logs (SB3's values, mission/* per mission)
        checkpoints/       rl_model_<joint steps>_steps.zip, written atomically
        metrics.csv        one row per mission: reward, length, final F1 and entropy
        model.zip          the final model, written atomically when training completes

The config format is rl-zoo3's (one entry per gymnasium id, COMA's constructor arguments plus
``n_timesteps``, ``n_envs``, ``policy``, ``policy_kwargs``, ``env_kwargs``, ``callback``,
``vec_env_wrapper``), with one addition rl-zoo3 ignores: a top-level ``variants`` mapping of
named overrides (the ablation arms) merged into the env's entry. See ``docs/training.md``.
"""
from __future__ import annotations

import copy
import datetime as _dt
import difflib
import importlib
import inspect
import math
import os
import re
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping

import yaml

from sb3_coma.checkpoints import (
    CheckpointError,
    atomic_save,
    atomic_write_text,
    find_checkpoints,
    load_checkpoint,
    validate_checkpoint,
)

__all__ = [
    "TrainingError",
    "TrainingInterrupted",
    "TrainConfig",
    "CONFIG_FILE",
    "MODEL_FILE",
    "METRICS_FILE",
    "coma_kwargs",
    "default_config_path",
    "list_variants",
    "load_config",
    "make_training_env",
    "new_run_dir",
    "read_config_file",
    "resolve_env_id",
    "resolve_resume",
    "train",
    "validate_entry",
]

CONFIG_FILE = "config.yml"
MODEL_FILE = "model.zip"
METRICS_FILE = "metrics.csv"
CHECKPOINT_DIR = "checkpoints"
TENSORBOARD_DIR = "tb"
TB_LOG_NAME = "COMA"
#: Env seed of the validation missions that ``--eval-freq`` flies (seeds 1000, 1001, ...): far
#: from the seeds 0..n-1 that ``evaluate`` and ``reproduce`` report, so picking the best
#: checkpoint never looks at the test missions.
VALIDATION_SEED = 1000

#: Top-level keys of a config file that are not gymnasium ids.
VARIANTS_KEY = "variants"
RUN_KEY = "run"
#: rl-zoo3 keys that :func:`train` and ``python -m sb3_coma.zoo`` understand besides COMA's arguments.
ZOO_KEYS = ("n_timesteps", "n_envs", "policy", "policy_kwargs", "env_kwargs", "callback", "vec_env_wrapper")
#: Arguments set by the trainer, not by a config.
RESERVED_KEYS = {
    "seed": "pass --seed (sb3-coma train / rl-zoo3) or seed= (Python)",
    "verbose": "pass --verbose",
    "device": "pass --device",
    "tensorboard_log": "TensorBoard logs go to the run folder (rl-zoo3: -tb)",
    "env": "the env comes from the config key / --env",
}
#: rl-zoo3 keys that make no sense for a multi-agent Dict-observation vec env.
UNSUPPORTED_KEYS = {
    "normalize": "VecNormalize is not used: all observation maps are already in [0, 1]",
    "frame_stack": "frame stacking is not supported for the multi-agent vec env",
    "env_wrapper": "gymnasium wrappers cannot wrap the PettingZoo env; use vec_env_wrapper",
    "monitor_kwargs": "the vec env is always wrapped in VecMonitor with f1 and entropy",
    "noise_type": "action noise is for continuous actions; COMA explores with exploration_*_eps",
    "noise_std": "action noise is for continuous actions; COMA explores with exploration_*_eps",
    "replay_buffer_class": "COMA is on-policy (no replay buffer)",
    "replay_buffer_kwargs": "COMA is on-policy (no replay buffer)",
}
FUSIONS = ("mean", "sendfuse")
_SCHEDULE_KEYS = ("learning_rate", "critic_learning_rate")
_SCHEDULE_RE = re.compile(r"^lin_(?P<value>[-+0-9.eE]+)$")


class TrainingError(ValueError):
    """A training input the user can fix (env id, variant, config file, key, resume path)."""


class TrainingInterrupted(KeyboardInterrupt):
    """Training stopped on SIGINT/SIGTERM after saving a checkpoint; resume from :attr:`run_dir`."""

    def __init__(self, run_dir: Path, checkpoint: Path, num_timesteps: int, signum: int) -> None:
        super().__init__(f"interrupted at {num_timesteps} joint steps; checkpoint {checkpoint}")
        self.run_dir = run_dir
        self.checkpoint = checkpoint
        self.num_timesteps = num_timesteps
        self.signum = signum


# =========================================================================== env ids and files
def resolve_env_id(env: str) -> str:
    """``"env3"`` / ``"Env3"`` / ``"UavIpp-Env3-v0"`` -> ``"UavIpp-Env3-v0"``.

    :raises TrainingError: not one of the registered maps
    """
    from envs import ENV_IDS

    if isinstance(env, str):
        if env in ENV_IDS:
            return env
        for env_id, name in ENV_IDS.items():
            if env.lower() == name.lower():
                return env_id
    choices = sorted(ENV_IDS.values()) + sorted(ENV_IDS)
    hint = difflib.get_close_matches(str(env), choices, n=1)
    raise TrainingError(
        f"unknown env {env!r}: use one of {', '.join(choices)}" + (f" (did you mean {hint[0]!r}?)" if hint else "")
    )


def default_config_path() -> Path:
    """``zoo_configs/coma.yml`` of a source checkout, else the copy installed under ``sys.prefix``."""
    candidates = [
        Path(__file__).resolve().parent.parent / "zoo_configs" / "coma.yml",
        Path(sys.prefix) / "zoo_configs" / "coma.yml",
    ]
    for path in candidates:
        if path.is_file():
            return path
    raise TrainingError(
        "no default config found (looked for " + ", ".join(str(p) for p in candidates) + "); pass --config PATH"
    )


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Parse a YAML config file into a mapping.

    :raises TrainingError: missing file, invalid YAML (with line and column), not a mapping
    """
    p = Path(path)
    if not p.exists():
        raise TrainingError(f"config file {p} does not exist")
    if p.is_dir():
        raise TrainingError(f"config file {p} is a folder")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise TrainingError(f"config file {p} cannot be read: {exc}") from exc
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        where = ""
        mark = getattr(exc, "problem_mark", None)
        if mark is not None:
            where = f" at line {mark.line + 1}, column {mark.column + 1}"
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise TrainingError(f"config file {p} is not valid YAML{where}: {problem}") from exc
    if not isinstance(data, dict):
        raise TrainingError(f"config file {p} must be a mapping of env ids to hyperparameters, got {type(data).__name__}")
    return data


def list_variants(path: str | os.PathLike[str] | None = None) -> dict[str, dict[str, Any]]:
    """The ``variants`` mapping of a config file (name -> overrides)."""
    p = Path(path) if path is not None else default_config_path()
    data = read_config_file(p)
    variants = data.get(VARIANTS_KEY) or {}
    if not isinstance(variants, dict):
        raise TrainingError(f"config file {p}: '{VARIANTS_KEY}' must be a mapping of names to overrides")
    return variants


# =========================================================================== validation
def coma_parameter_names() -> list[str]:
    """COMA's constructor arguments a config may set (its signature, less the trainer's own)."""
    from sb3_coma.coma import COMA

    skip = {"self", "policy", "env", "_init_setup_model", *RESERVED_KEYS}
    return [n for n in inspect.signature(COMA.__init__).parameters if n not in skip]


def _fail(where: str, message: str) -> None:
    raise TrainingError(f"{where}: {message}")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _positive_int(where: str, key: str, value: Any) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not _is_int(value) or value < 1:
        _fail(where, f"{key} must be a positive integer, got {value!r}")
    return int(value)


def _split_env_kwargs(env_kwargs: Mapping[str, Any]) -> tuple[str, dict[str, Any], dict[str, Any]]:
    """``(fusion, fusion_kwargs, env options)`` from an ``env_kwargs`` mapping."""
    options = dict(env_kwargs)
    fusion = options.pop("fusion", "mean")
    fusion_kwargs = options.pop("fusion_kwargs", None) or {}
    return fusion, fusion_kwargs, options


def validate_entry(entry: Mapping[str, Any], where: str, map_name: str | None = None) -> None:
    """Check one resolved config entry; raise :class:`TrainingError` naming ``where`` and the key.

    Checks key names (COMA's arguments + rl-zoo3's keys), the zoo keys' values, schedule
    strings, and the environment options (through ``envs.IppConfig``). COMA's own value checks
    (ranges, batch vs rollout) run when the model is built.
    """
    from envs import ConfigError, IppConfig

    allowed = set(coma_parameter_names()) | set(ZOO_KEYS)
    for key in entry:
        if key in RESERVED_KEYS:
            _fail(where, f"{key!r} cannot be set in a config: {RESERVED_KEYS[key]}")
        if key in UNSUPPORTED_KEYS:
            _fail(where, f"rl-zoo3 key {key!r} is not supported with COMA: {UNSUPPORTED_KEYS[key]}")
        if key not in allowed:
            hint = difflib.get_close_matches(str(key), sorted(allowed), n=1)
            _fail(
                where,
                f"COMA does not take {key!r}" + (f" (did you mean {hint[0]!r}?)" if hint else "")
                + f"; allowed keys: {', '.join(sorted(allowed))}",
            )
    if "n_timesteps" not in entry:
        _fail(where, "n_timesteps (joint steps to train) is missing")
    _positive_int(where, "n_timesteps", entry["n_timesteps"])
    if "n_envs" in entry:
        _positive_int(where, "n_envs", entry["n_envs"])
    if "policy" in entry and not isinstance(entry["policy"], str):
        _fail(where, f"policy must be an alias (CBAMPolicy, CnnPolicy) or a dotted class path, got {entry['policy']!r}")
    if "policy_kwargs" in entry and not isinstance(entry["policy_kwargs"], (dict, str)):
        _fail(where, f"policy_kwargs must be a mapping or a Python expression string, got {entry['policy_kwargs']!r}")
    for key in _SCHEDULE_KEYS:
        value = entry.get(key)
        if isinstance(value, str) and not _SCHEDULE_RE.match(value):
            _fail(where, f"{key} must be a number or 'lin_<initial value>', got {value!r}")
    env_kwargs = entry.get("env_kwargs", {}) or {}
    if not isinstance(env_kwargs, dict):
        _fail(where, f"env_kwargs must be a mapping of environment options, got {env_kwargs!r}")
    fusion, fusion_kwargs, options = _split_env_kwargs(env_kwargs)
    if fusion not in FUSIONS:
        _fail(where, f"env_kwargs.fusion must be one of {FUSIONS}, got {fusion!r}")
    if not isinstance(fusion_kwargs, dict):
        _fail(where, f"env_kwargs.fusion_kwargs must be a mapping, got {fusion_kwargs!r}")
    if map_name is not None:
        try:
            IppConfig.from_options(map_name, **options)
        except ConfigError as exc:
            _fail(where, f"env_kwargs: {exc}")
        except TypeError as exc:
            _fail(where, f"env_kwargs: {exc}")


def _merge(base: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``overrides``; ``env_kwargs`` and mapping ``policy_kwargs`` merge key by key."""
    out = copy.deepcopy(base)
    for key, value in overrides.items():
        if key in ("env_kwargs", "policy_kwargs") and isinstance(value, dict) and isinstance(out.get(key), dict):
            merged = dict(out[key])
            merged.update(copy.deepcopy(value))
            out[key] = merged
        else:
            out[key] = copy.deepcopy(value)
    return out


def _apply_overrides(entry: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Apply ``{"key": v, "env_kwargs.noise": v}`` style overrides (dots reach into mappings)."""
    out = copy.deepcopy(entry)
    for key, value in overrides.items():
        parts = str(key).split(".")
        target = out
        for part in parts[:-1]:
            nxt = target.get(part)
            if nxt is None:
                nxt = target[part] = {}
            if not isinstance(nxt, dict):
                raise TrainingError(f"override {key}={value!r}: {part!r} is not a mapping")
            target = nxt
        target[parts[-1]] = copy.deepcopy(value)
    return out


def config_entry(
    path: str | os.PathLike[str],
    env_id: str,
    variant: str | None = None,
    overrides: Mapping[str, Any] | None = None,
    data: dict[str, Any] | None = None,
    validate: bool = True,
) -> dict[str, Any]:
    """The env's entry of a config file, with a variant and overrides merged in, validated."""
    from envs import ENV_IDS

    p = Path(path)
    data = read_config_file(p) if data is None else data
    entry = data.get(env_id)
    if entry is None:
        present = [k for k in data if k in ENV_IDS] or [k for k in data if k not in (VARIANTS_KEY, RUN_KEY)]
        raise TrainingError(f"config file {p} has no entry for {env_id} (it has: {', '.join(map(str, present)) or 'none'})")
    if not isinstance(entry, dict):
        raise TrainingError(f"config file {p}: the entry for {env_id} must be a mapping, got {type(entry).__name__}")
    where = f"config {p} [{env_id}]"
    if variant is not None:
        variants = data.get(VARIANTS_KEY) or {}
        if not isinstance(variants, dict):
            raise TrainingError(f"config file {p}: '{VARIANTS_KEY}' must be a mapping of names to overrides")
        if variant not in variants:
            known = ", ".join(sorted(map(str, variants))) or "none defined"
            raise TrainingError(f"unknown variant {variant!r} in config file {p} (variants: {known})")
        extra = variants[variant] or {}
        if not isinstance(extra, dict):
            raise TrainingError(f"config file {p}: variant {variant!r} must be a mapping of overrides")
        entry = _merge(entry, extra)
        where = f"config {p} [{env_id}, variant {variant}]"
    if overrides:
        entry = _apply_overrides(entry, overrides)
        where += " with overrides"
    if validate:
        validate_entry(entry, where, ENV_IDS[env_id])
    return entry


@dataclass
class TrainConfig:
    """A resolved training config: where it came from and the entry to train with."""

    env_id: str
    entry: dict[str, Any]
    source: Path | None = None
    variant: str | None = None
    run: dict[str, Any] = field(default_factory=dict)

    @property
    def map_name(self) -> str:
        from envs import ENV_IDS

        return ENV_IDS[self.env_id]

    @property
    def n_timesteps(self) -> int:
        return int(self.entry["n_timesteps"])

    @property
    def n_envs(self) -> int:
        return int(self.entry.get("n_envs", 1))

    @property
    def env_kwargs(self) -> dict[str, Any]:
        return dict(self.entry.get("env_kwargs") or {})

    @property
    def n_agents(self) -> int:
        from envs import IppConfig

        _, _, options = _split_env_kwargs(self.env_kwargs)
        return IppConfig.from_options(self.map_name, **options).n_uavs


def load_config(
    env: str | None = None,
    config: str | os.PathLike[str] | None = None,
    variant: str | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> TrainConfig:
    """Resolve env id, config file (default :func:`default_config_path`) and variant into a :class:`TrainConfig`."""
    env_id = resolve_env_id(env if env is not None else "env3")
    path = Path(config) if config is not None else default_config_path()
    entry = config_entry(path, env_id, variant, overrides)
    return TrainConfig(env_id=env_id, entry=entry, source=path, variant=variant)


# =========================================================================== building
def _import_dotted(name: str, what: str) -> Any:
    module_name, _, attr = name.rpartition(".")
    if not module_name:
        raise TrainingError(f"{what} {name!r} is neither a known alias nor a dotted path (module.Class)")
    try:
        return getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError) as exc:
        raise TrainingError(f"{what} {name!r} cannot be imported: {exc}") from exc


def _policy_kwargs_namespace() -> dict[str, Any]:
    import torch as th
    from torch import nn

    from sb3_coma.extractors import CBAMExtractor, CnnExtractor

    return {"nn": nn, "th": th, "CBAMExtractor": CBAMExtractor, "CnnExtractor": CnnExtractor}


def resolve_policy_kwargs(value: Any) -> dict[str, Any]:
    """``policy_kwargs`` from a mapping or an rl-zoo3 style expression string; ``*_class`` strings
    (aliases ``CBAMExtractor``/``CnnExtractor`` or dotted paths) become classes."""
    namespace = _policy_kwargs_namespace()
    if value is None:
        return {}
    if isinstance(value, str):
        try:
            value = eval(value, namespace)  # noqa: S307 - rl-zoo3's documented format
        except Exception as exc:  # noqa: BLE001 - any error in the user's expression
            raise TrainingError(f"policy_kwargs {value!r} is not a valid Python expression: {exc}") from exc
    if not isinstance(value, dict):
        raise TrainingError(f"policy_kwargs must be a mapping, got {value!r}")
    out = dict(value)
    for key, item in list(out.items()):
        if key.endswith("_class") and isinstance(item, str):
            out[key] = namespace[item] if item in namespace else _import_dotted(item, f"policy_kwargs.{key}")
    return out


def _schedule(value: Any) -> Any:
    if isinstance(value, str):
        match = _SCHEDULE_RE.match(value)
        if match:
            from rl_zoo3.utils import SimpleLinearSchedule

            return SimpleLinearSchedule(float(match.group("value")))
    return value


def coma_kwargs(entry: Mapping[str, Any]) -> dict[str, Any]:
    """COMA constructor arguments from a config entry (zoo keys removed, strings resolved)."""
    from sb3_coma.coma import COMA

    kwargs = {k: v for k, v in entry.items() if k not in ZOO_KEYS}
    for key in _SCHEDULE_KEYS:
        if key in kwargs:
            kwargs[key] = _schedule(kwargs[key])
    policy = entry.get("policy", "CBAMPolicy")
    if isinstance(policy, str) and policy not in COMA.policy_aliases:
        policy = _import_dotted(policy, "policy")
    kwargs["policy"] = policy
    if "policy_kwargs" in entry:
        kwargs["policy_kwargs"] = resolve_policy_kwargs(entry["policy_kwargs"])
    return kwargs


def _named_objects(spec: Any, what: str) -> list[tuple[Any, dict[str, Any]]]:
    """rl-zoo3's ``callback`` / ``vec_env_wrapper`` format: a name, a ``{name: kwargs}``, or a list."""
    if spec is None:
        return []
    items = spec if isinstance(spec, list) else [spec]
    out = []
    for item in items:
        kwargs: dict[str, Any] = {}
        if isinstance(item, dict):
            if len(item) != 1:
                raise TrainingError(f"{what} entry {item!r} must map exactly one class name to its arguments")
            item, kwargs = next(iter(item.items()))
            kwargs = dict(kwargs or {})
        target = _import_dotted(item, what) if isinstance(item, str) else item
        out.append((target, kwargs))
    return out


def _eval_copies(missions: int) -> int:
    """Env copies for an evaluation of ``missions`` missions: a divisor of it (every copy flies the
    same number), at most 5, so one forward pass acts for several missions."""
    return next(c for c in (5, 4, 3, 2, 1) if missions % c == 0)


def make_training_env(cfg: TrainConfig, n_envs: int | None = None, seed: int | None = None):
    """The SB3 vec env of a config (``envs.make_vec_env`` + the config's ``vec_env_wrapper``)."""
    import envs

    fusion, fusion_kwargs, options = _split_env_kwargs(cfg.env_kwargs)
    kwargs: dict[str, Any] = dict(options)
    if fusion_kwargs:
        kwargs["fusion_kwargs"] = fusion_kwargs
    try:
        env = envs.make_vec_env(cfg.map_name, n_envs=n_envs or cfg.n_envs, fusion=fusion, seed=seed, **kwargs)
    except ValueError as exc:  # envs.ConfigError, an unavailable fusion, ...
        raise TrainingError(f"cannot build {cfg.env_id} (fusion={fusion!r}, options {options}): {exc}") from exc
    try:
        for wrapper, wkwargs in _named_objects(cfg.entry.get("vec_env_wrapper"), "vec_env_wrapper"):
            env = _construct(wrapper, wkwargs, "vec_env_wrapper", env)
    except BaseException:
        env.close()
        raise
    return env


def _construct(target: Any, kwargs: dict[str, Any], what: str, *args: Any) -> Any:
    """``target(*args, **kwargs)`` for a config's ``callback`` / ``vec_env_wrapper``; bad arguments
    become a :class:`TrainingError` naming the class and its arguments."""
    try:
        return target(*args, **kwargs)
    except (TypeError, ValueError) as exc:
        name = getattr(target, "__qualname__", repr(target))
        raise TrainingError(f"{what} {name} with arguments {kwargs!r}: {exc}") from exc


def _check_device(device: Any) -> None:
    """Refuse a device string torch cannot parse before anything is built."""
    import torch as th

    if device == "auto":
        return
    try:
        th.device(device)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise TrainingError(f"device {device!r} is not a torch device: use auto, cpu, cuda or cuda:<index>") from exc


def _assertion_site(exc: BaseException) -> str:
    """``"AssertionError in <file>:<line>"`` for a bare ``assert`` without a message."""
    import traceback

    text = str(exc).strip()
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" in {Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else ""
    return f"AssertionError{where}" + (f": {text}" if text else "")


# =========================================================================== run folders
def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "run"


def new_run_dir(run_dir: str | os.PathLike[str] | None, env_id: str, variant: str | None = None,
                root: str | os.PathLike[str] = "runs") -> Path:
    """Create and return a fresh run folder; never reuses a folder that holds anything.

    ``run_dir=None``: ``<root>/<env id>[-<variant>]_<n>`` with the next free ``n`` (rl-zoo3's
    scheme). An explicit ``run_dir`` is used when it does not exist or is empty, else
    ``<run_dir>_2``, ``<run_dir>_3``, ... Folders are created with ``mkdir`` (atomic), so two runs
    started together never share one.
    """
    if run_dir is None:
        base = Path(root) / _slug(env_id + (f"-{variant}" if variant else ""))
        candidates = (Path(f"{base}_{n}") for n in range(1, 1_000_000))
    else:
        base = Path(run_dir)
        if base.is_dir() and not any(base.iterdir()):
            return base
        if base.exists() and not base.is_dir():
            raise TrainingError(f"run folder {base} exists and is a file")
        candidates = (base if n == 1 else Path(f"{base}_{n}") for n in range(1, 1_000_000))
    for candidate in candidates:
        candidate.parent.mkdir(parents=True, exist_ok=True)
        try:
            candidate.mkdir()
        except FileExistsError:
            continue
        return candidate
    raise TrainingError(f"no free run folder name next to {base}")  # pragma: no cover


def _plain(value: Any) -> Any:
    """YAML-safe copy: classes become dotted paths, tuples lists, schedules their string form."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, type):
        return f"{value.__module__}.{value.__qualname__}"
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    initial = getattr(value, "initial_value", None)
    if initial is not None:
        return f"lin_{initial}"
    return str(value)


def _write_run_config(run_dir: Path, cfg: TrainConfig) -> Path:
    header = (
        "# sb3-coma run config: the entry below is what this run trained with (a valid rl-zoo3 config);\n"
        "# 'run' records where it came from. Resume with: sb3-coma train --resume " + str(run_dir) + "\n"
    )
    body = {cfg.env_id: _plain(cfg.entry), RUN_KEY: _plain(cfg.run)}
    return atomic_write_text(run_dir / CONFIG_FILE, header + yaml.safe_dump(body, sort_keys=False))


def _read_run_config(run_dir: Path) -> TrainConfig:
    path = run_dir / CONFIG_FILE
    data = read_config_file(path)
    run = data.get(RUN_KEY)
    if not isinstance(run, dict) or "env" not in run:
        raise TrainingError(f"{path} is not an sb3-coma run config (no '{RUN_KEY}.env')")
    env_id = resolve_env_id(run["env"])
    entry = config_entry(path, env_id, data=data)
    return TrainConfig(env_id=env_id, entry=entry, source=path, variant=run.get("variant"), run=dict(run))


def _newest_model(run_dir: Path) -> Path | None:
    """Newest valid checkpoint or final model of a run folder (by joint steps)."""
    candidates = [p for _, p in find_checkpoints(run_dir / CHECKPOINT_DIR)]
    if (run_dir / MODEL_FILE).is_file():
        candidates.append(run_dir / MODEL_FILE)
    best: tuple[int, Path] | None = None
    for path in candidates:
        try:
            info = validate_checkpoint(path)
        except CheckpointError as exc:
            warnings.warn(f"skipping {exc}", stacklevel=3)
            continue
        if best is None or info.num_timesteps > best[0]:
            best = (info.num_timesteps, path)
    return best[1] if best else None


def resolve_resume(resume: str | os.PathLike[str]) -> tuple[Path | None, Path]:
    """``(run folder or None, model zip)`` for ``--resume PATH``.

    ``PATH`` is a run folder (its newest checkpoint or final model), a checkpoint or model zip
    inside a run folder, or any COMA model zip (then a new run folder is made).

    :raises TrainingError: the path does not exist, is a folder but not a run folder, or a run
        folder without a usable checkpoint
    :raises CheckpointError: the zip is truncated/corrupt or not a COMA model
    """
    p = Path(resume)
    if not p.exists():
        raise TrainingError(f"cannot resume from {p}: no such file or folder")
    if p.is_dir():
        if not (p / CONFIG_FILE).is_file():
            raise TrainingError(
                f"cannot resume from {p}: not a run folder (no {CONFIG_FILE}); pass a run folder or a checkpoint .zip"
            )
        model = _newest_model(p)
        if model is None:
            raise TrainingError(f"cannot resume from {p}: the run folder has no valid checkpoint or {MODEL_FILE}")
        return p, model
    validate_checkpoint(p)
    if (p.parent / CONFIG_FILE).is_file():
        return p.parent, p
    if p.parent.name == CHECKPOINT_DIR and (p.parent.parent / CONFIG_FILE).is_file():
        return p.parent.parent, p
    return None, p


# =========================================================================== training
def _progress_bar_available() -> bool:
    try:
        from stable_baselines3.common.callbacks import tqdm  # type: ignore[attr-defined]
    except ImportError:  # pragma: no cover
        return False
    return tqdm is not None


def _summary(history: list[dict[str, Any]], last: int = 20) -> str:
    if not history:
        return "no mission finished"
    recent = history[-last:]

    def mean(key: str) -> float:
        values = [r[key] for r in recent if not math.isnan(r[key])]
        return float(sum(values) / len(values)) if values else math.nan

    return (
        f"last {len(recent)} missions: team reward {mean('reward'):+.3f}, "
        f"F1 {mean('f1'):.3f}, entropy {mean('entropy'):.3f}"
    )


def train(
    env: str | None = None,
    config: str | os.PathLike[str] | None = None,
    variant: str | None = None,
    total_timesteps: int | None = None,
    seed: int | None = None,
    run_dir: str | os.PathLike[str] | None = None,
    resume: str | os.PathLike[str] | None = None,
    overrides: Mapping[str, Any] | None = None,
    n_envs: int | None = None,
    save_freq: int | None = None,
    eval_freq: int = 0,
    eval_missions: int = 5,
    eval_seed: int | None = None,
    callbacks: list | None = None,
    progress_bar: bool = True,
    device: str = "auto",
    verbose: int = 1,
    handle_signals: bool = True,
    runs_root: str | os.PathLike[str] = "runs",
    log: Callable[[str], None] | None = None,
):
    """Train COMA and return ``(model, run_dir)``.

    The returned model's training env is closed (``model.env``); give it a new one
    (``envs.make_vec_env``) to predict or evaluate, or load ``run_dir / "model.zip"``.

    :param env: ``"env1"``/``"env2"``/``"env3"`` or a gymnasium id (default ``"env3"``; with
        ``resume`` of a run folder, the run's own env)
    :param config: rl-zoo3 style YAML (default ``zoo_configs/coma.yml``)
    :param variant: a name from the config's ``variants`` mapping (ablation arm)
    :param total_timesteps: joint steps to reach in total (default: the config's ``n_timesteps``);
        when resuming, the total to reach, counting the steps already done
    :param seed: seed of model and env (default: random, recorded in ``config.yml``; when
        resuming, the run's seed plus the joint steps done)
    :param run_dir: run folder (default ``runs/<env id>[-<variant>]_<n>``; a folder that holds
        anything gets a ``_<n>`` suffix instead of being reused)
    :param resume: a run folder or checkpoint zip to continue from (same timestep count,
        optimiser states restored, ``reset_num_timesteps=False``)
    :param overrides: config keys to change, dots reach into mappings (``{"env_kwargs.noise": "loud"}``)
    :param n_envs: env copies (default: the config's ``n_envs``)
    :param save_freq: joint steps between checkpoints (default: a tenth of the run)
    :param eval_freq: joint steps between evaluations (0: none); best model -> ``best_model.zip``
    :param eval_missions: missions per evaluation
    :param eval_seed: env seed of the validation missions, the same at every evaluation (default
        :data:`VALIDATION_SEED`, disjoint from the seeds ``evaluate`` and ``reproduce`` test on)
    :param callbacks: extra SB3 callbacks
    :param progress_bar: show SB3's progress bar (joint steps)
    :param device: torch device
    :param verbose: 0 silent, 1 run information, 2 also SB3's training tables
    :param handle_signals: on SIGINT/SIGTERM save a checkpoint and raise :class:`TrainingInterrupted`
    :param runs_root: parent of default run folders
    :param log: where information lines go (default ``print`` when ``verbose >= 1``)
    :raises TrainingError: bad env id, variant, config file or key, resume path
    :raises CheckpointError: a resume zip that is truncated or not a COMA model
    :raises TrainingInterrupted: stopped by a signal (after saving a checkpoint)
    """
    import numpy as np

    from sb3_coma.callbacks import (
        EpisodeMetricsCallback,
        JointCheckpointCallback,
        MissionEvalCallback,
        SignalStopCallback,
        truncate_metrics_csv,
    )
    from sb3_coma.coma import COMA

    say = log or (print if verbose >= 1 else (lambda _msg: None))
    model_verbose = max(int(verbose) - 1, 0)
    if total_timesteps is not None:
        total_timesteps = _positive_int("train()", "total_timesteps", total_timesteps)
    if n_envs is not None:
        n_envs = _positive_int("train()", "n_envs", n_envs)
    if seed is not None and not _is_int(seed):
        raise TrainingError(f"seed must be an integer, got {seed!r}")
    _check_device(device)

    # ----------------------------------------------------------- config and run folder
    resume_model: Path | None = None
    resumed_in_place = False
    if resume is not None:
        resume_run, resume_model = resolve_resume(resume)
        if resume_run is not None:
            if config is not None or variant is not None:
                raise TrainingError(
                    f"--resume {resume} continues run {resume_run} with its own config; drop --config/--variant"
                )
            cfg = _read_run_config(resume_run)
            if env is not None and resolve_env_id(env) != cfg.env_id:
                raise TrainingError(f"--resume {resume}: that run trains {cfg.env_id}, not {resolve_env_id(env)}")
            if overrides:
                cfg.entry = config_entry(cfg.source or resume_run / CONFIG_FILE, cfg.env_id, overrides=overrides,
                                         data={cfg.env_id: cfg.entry})
            run_path: Path | None = resume_run
            resumed_in_place = True
        else:
            cfg = load_config(env, config, variant, overrides)
            run_path = None
    else:
        cfg = load_config(env, config, variant, overrides)
        run_path = None

    if n_envs is not None:
        cfg.entry["n_envs"] = n_envs
    if total_timesteps is not None:
        cfg.entry["n_timesteps"] = total_timesteps
    total = cfg.n_timesteps

    info = validate_checkpoint(resume_model) if resume_model is not None else None
    if info is not None and info.n_agents is not None and info.n_agents != cfg.n_agents:
        raise TrainingError(
            f"checkpoint {resume_model} was trained with {info.n_agents} UAVs but the config has {cfg.n_agents}"
        )
    done_steps = info.num_timesteps if info is not None else 0
    if seed is None:
        base_seed = cfg.run.get("seed") if resumed_in_place else None
        seed = int(base_seed) + done_steps if _is_int(base_seed) else int(np.random.randint(0, 2**31 - 1))

    # ----------------------------------------------------------- env and model (before any folder is made)
    venv = make_training_env(cfg, seed=seed)
    try:
        if resume_model is not None:
            model = load_checkpoint(resume_model, env=venv, device=device, tensorboard_log=None,
                                    verbose=model_verbose, seed=seed)
        else:
            try:
                model = COMA(env=venv, tensorboard_log=None, seed=seed, verbose=model_verbose, device=device,
                             **coma_kwargs(cfg.entry))
            except (TypeError, ValueError, AssertionError) as exc:
                if isinstance(exc, TrainingError):
                    raise
                where = f"config {cfg.source} [{cfg.env_id}" + (f", variant {cfg.variant}]" if cfg.variant else "]")
                if isinstance(exc, AssertionError):  # e.g. SB3's bare `assert features_dim > 0`
                    raise TrainingError(f"{where}: COMA rejected a setting ({_assertion_site(exc)}); check "
                                        f"policy_kwargs={cfg.entry.get('policy_kwargs')!r}") from exc
                raise TrainingError(f"{where}: {exc}") from exc
        if run_path is None:
            run_path = new_run_dir(run_dir, cfg.env_id, cfg.variant, runs_root)
    except BaseException:
        venv.close()
        raise
    tb_dir = str(run_path / TENSORBOARD_DIR)
    model.tensorboard_log = tb_dir  # read when learn() sets up its logger

    # ----------------------------------------------------------- run config
    if not resumed_in_place:
        cfg.run = {
            "env": cfg.env_id,
            "variant": cfg.variant,
            "seed": seed,
            "config": str(Path(cfg.source).resolve()) if cfg.source is not None else None,
            "created": _dt.datetime.now().isoformat(timespec="seconds"),
            "sb3_coma": _version(),
            "command": " ".join(getattr(sys, "orig_argv", sys.argv)),
        }
        if resume_model is not None:
            cfg.run["resumed_from"] = str(resume_model)
    else:
        cfg.run["resumes"] = list(cfg.run.get("resumes") or []) + [
            {"from": str(resume_model), "at": done_steps, "seed": seed,
             "when": _dt.datetime.now().isoformat(timespec="seconds")}
        ]
    _write_run_config(run_path, cfg)
    say(f"Run folder: {run_path}")
    if resume_model is not None:
        say(f"Resuming from {resume_model} at {done_steps} joint steps")

    # ----------------------------------------------------------- callbacks
    if resumed_in_place:
        truncate_metrics_csv(run_path / METRICS_FILE, done_steps)
    metrics = EpisodeMetricsCallback(csv_path=run_path / METRICS_FILE)
    every = save_freq if save_freq is not None else max(total // 10, 1)
    checkpoints = JointCheckpointCallback(every, run_path / CHECKPOINT_DIR, verbose=model_verbose)
    stopper = SignalStopCallback(verbose=verbose)
    cb_list: list = [metrics, checkpoints]
    for cls, kwargs in _named_objects(cfg.entry.get("callback"), "callback"):
        cb_list.append(_construct(cls, kwargs, "callback") if isinstance(cls, type) else cls)
    eval_env = None
    if eval_freq and eval_freq > 0:
        eval_missions = _positive_int("train()", "eval_missions", eval_missions)
        if eval_seed is None:
            eval_seed = VALIDATION_SEED
        elif not _is_int(eval_seed):
            raise TrainingError(f"eval_seed must be an integer, got {eval_seed!r}")
        eval_env = make_training_env(cfg, n_envs=_eval_copies(eval_missions), seed=int(eval_seed))
        cb_list.append(MissionEvalCallback(eval_env, eval_freq=eval_freq, n_eval_missions=eval_missions,
                                           best_model_save_path=run_path, log_path=run_path / "eval",
                                           verbose=model_verbose, eval_seed=int(eval_seed)))
    cb_list.extend(callbacks or [])
    if handle_signals:
        cb_list.append(stopper)

    # ----------------------------------------------------------- learn
    remaining = total - int(model.num_timesteps)
    try:
        if remaining > 0:
            say(f"Training {cfg.env_id}" + (f" ({cfg.variant})" if cfg.variant else "")
                + f" for {remaining} joint steps (to {total}); TensorBoard: tensorboard --logdir {tb_dir}")
            model.learn(
                total_timesteps=remaining,
                callback=cb_list,
                tb_log_name=TB_LOG_NAME,
                reset_num_timesteps=resume_model is None,
                progress_bar=bool(progress_bar) and _progress_bar_available(),
            )
        else:
            say(f"Nothing to train: the model is at {model.num_timesteps} >= {total} joint steps")
    finally:
        stopper.restore()
        metrics.close()
        if eval_env is not None:
            eval_env.close()
        venv.close()

    if stopper.received is not None and model.num_timesteps < total:
        at = stopper.boundary_timesteps
        reached = int(model.num_timesteps)
        model.num_timesteps = at
        try:
            path = checkpoints.save_now(at)
        finally:
            model.num_timesteps = reached
        say(f"Interrupted: checkpoint {path} ({at} joint steps); resume with: sb3-coma train --resume {run_path}")
        raise TrainingInterrupted(run_path, path, at, stopper.received)

    final = atomic_save(model, run_path / MODEL_FILE)
    say(f"Saved {final} ({model.num_timesteps} joint steps); {_summary(metrics.history)}")
    return model, run_path


def _version() -> str:
    try:
        from sb3_coma import __version__

        return str(__version__)
    except ImportError:  # pragma: no cover
        return "unknown"
