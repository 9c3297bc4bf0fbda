"""The training config format: rl-zoo3 hyperparameter files with variants.

One entry per gymnasium id (``zoo_configs/coma.yml``), keys are COMA's constructor arguments plus
rl-zoo3's ``n_timesteps``, ``n_envs``, ``policy``, ``policy_kwargs``, ``env_kwargs``, ``callback``
and ``vec_env_wrapper``; one addition rl-zoo3 ignores: a top-level ``variants`` mapping of named
overrides (the ablation arms) merged into the env's entry. See ``docs/modules/cli.md``.

This module reads and checks such files and turns an entry into what the library needs: COMA's
keyword arguments (:func:`coma_kwargs`), the training vec env (:func:`make_training_env`) and the
record of the env a model trains on (:func:`env_options_of`). Both trainers (``sb3-coma train``
and ``python -m sb3_coma.zoo``) and ``sb3-coma export`` read configs through it.
"""

from __future__ import annotations

import copy
import dataclasses
import difflib
import importlib
import importlib.metadata
import inspect
import os
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, NoReturn, TypeGuard

import torch as th
import yaml
from rl_zoo3.utils import SimpleLinearSchedule
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

import uav_ipp
from sb3_coma.baselines import PLANNERS
from sb3_coma.coma import COMA
from sb3_coma.coma.plugins import plugin_policies
from sb3_coma.coma.validation import check_total_timesteps
from sb3_coma.common.checkpoints import folder_write_problem
from sb3_coma.common.evaluation import PROTOCOLS
from sb3_coma.common.extractors import CBAMExtractor, CnnExtractor
from sb3_coma.common.numbers import is_real, is_whole
from sb3_coma.common.numbers import plain as plain_number
from uav_ipp import DEFAULT_FUSION, DEFAULT_MAP, ENV_IDS, ConfigError, IppConfig

#: Top-level keys of a config file that are not gymnasium ids.
VARIANTS_KEY = "variants"
RUN_KEY = "run"
#: rl-zoo3 keys that both trainers understand besides COMA's arguments.
ZOO_KEYS = ("n_timesteps", "n_envs", "policy", "policy_kwargs", "env_kwargs", "callback", "vec_env_wrapper")
#: Keys that say where the env copies run (``uav_ipp.make_vec_env``'s ``workers`` / ``backend``), not
#: what they are: ``workers`` is an integer >= 1 or ``"auto"`` (every core, at most one per copy).
LAYOUT_KEYS = ("workers", "backend")
#: ``warm_start``: DAgger from a teacher planner before COMA trains (``sb3_coma.app.warm_start``).
WARM_START_KEY = "warm_start"
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
#: ``env_kwargs`` key that says "train on split 'test', on purpose" (``sb3-coma train --allow-test-split``).
#: It sits next to ``split`` so that the run's ``config.yml`` records it with the split it allows, and
#: both trainers read it through :func:`split_env_kwargs`, which takes it out before the env is built.
ALLOW_TEST_SPLIT = "allow_test_split"
#: The gymnasium id of ``uav_ipp.DEFAULT_MAP``: what ``sb3-coma train`` trains without ``--env``.
DEFAULT_ENV_ID = next(env_id for env_id, name in ENV_IDS.items() if name == DEFAULT_MAP)
_SCHEDULE_KEYS = ("learning_rate", "critic_learning_rate")
#: Every env option's default: an error message lists only the options a config changed.
_DEFAULT_OPTIONS = {f.name: getattr(IppConfig(), f.name) for f in fields(IppConfig) if f.name != "map_name"}
_SCHEDULE_RE = re.compile(r"^lin_(?P<value>[-+0-9.eE]+)$")
#: Names a ``policy_kwargs`` expression string may use (rl-zoo3 evaluates such strings too).
_POLICY_KWARGS_NAMES: dict[str, Any] = {
    "nn": nn,
    "th": th,
    "CBAMExtractor": CBAMExtractor,
    "CnnExtractor": CnnExtractor,
}


class TrainingError(ValueError):
    """A training input the user can fix (env id, variant, config file, key, resume path)."""


# =========================================================================== env ids and files
def resolve_env_id(env: str) -> str:
    """``"env3"`` / ``"Env3"`` / ``"UavIpp-Env3-v0"`` -> ``"UavIpp-Env3-v0"``.

    :raises TrainingError: not one of the registered maps
    """
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


def default_config_path(name: str = "coma.yml") -> Path:
    """``zoo_configs/<name>`` of a source checkout (``coma.yml``: the UAV world's; ``marl/coma.yml``
    and its neighbours: the learner benchmark's), else the copy the installed distribution carries
    (setup.cfg ``data_files``: it lands under the install prefix, found through the distribution's
    own file list so that venv, ``--user`` and ``--prefix`` installs all work)."""
    candidates = [Path(__file__).resolve().parents[2] / "zoo_configs" / name]
    try:
        files = importlib.metadata.distribution("sb3-coma").files or []
    except importlib.metadata.PackageNotFoundError:
        files = []
    candidates += [Path(str(f.locate())).resolve() for f in files if f.as_posix().endswith(f"zoo_configs/{name}")]
    candidates.append(Path(sys.prefix) / "zoo_configs" / name)
    for path in candidates:
        if path.is_file():
            return path
    raise TrainingError(
        "no default config found (looked for " + ", ".join(str(p) for p in candidates) + "); pass --config PATH"
    )


class _UniqueKeyLoader(yaml.SafeLoader):
    """Safe YAML that refuses a key written twice in one mapping: PyYAML keeps the last value without
    a word, so a pasted ``learning_rate`` below an earlier one would silently win. Merge keys
    (``<<: *base``) still merge and may be overridden, as YAML says."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, int] = {}
        for key_node, _value in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                continue
            key = self.construct_object(key_node, deep=deep)  # type: ignore[no-untyped-call]
            try:
                first = seen.setdefault(key, key_node.start_mark.line + 1)
            except TypeError:  # an unhashable key: the base class reports it
                continue
            if first != key_node.start_mark.line + 1:
                raise yaml.constructor.ConstructorError(
                    None,
                    None,
                    f"key {key!r} is written twice (lines {first} and {key_node.start_mark.line + 1})",
                    key_node.start_mark,
                )
        return super().construct_mapping(node, deep=deep)


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Parse a YAML config file into a mapping.

    :raises TrainingError: missing file, invalid YAML (with line and column), not a mapping
    """
    p = Path(path)
    data: Any = None
    try:
        data = yaml.load(p.read_text(encoding="utf-8"), Loader=_UniqueKeyLoader)  # a SafeLoader subclass
        problem = (
            None
            if isinstance(data, dict)
            else f"must be a mapping of env ids to hyperparameters, got {type(data).__name__}"
        )
    except FileNotFoundError:
        problem = "does not exist"
    except IsADirectoryError:
        problem = "is a folder"
    except (OSError, UnicodeDecodeError) as exc:
        problem = f"cannot be read: {exc}"
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = "" if mark is None else f" at line {mark.line + 1}, column {mark.column + 1}"
        problem = f"is not valid YAML{where}: {getattr(exc, 'problem', None) or str(exc).splitlines()[0]}"
    if problem is not None:  # one rule: the file is a readable YAML mapping
        raise TrainingError(f"config file {p} {problem}")
    return dict(data)


def list_variants(path: str | os.PathLike[str] | None = None) -> dict[str, dict[str, Any]]:
    """The ``variants`` mapping of a config file (name -> overrides)."""
    p = Path(path) if path is not None else default_config_path()
    return _variants(read_config_file(p), p)


def _variants(data: Mapping[str, Any], path: Path) -> dict[str, dict[str, Any]]:
    """A config file's ``variants``: a mapping of names to mappings of overrides (``null``: none)."""
    variants = data.get(VARIANTS_KEY) or {}
    bad = [] if isinstance(variants, dict) else [VARIANTS_KEY]
    bad += [
        f"variant {name!r}"
        for name, extra in (variants.items() if not bad else ())
        if not isinstance(extra or {}, dict)
    ]
    if bad:
        raise TrainingError(
            f"config file {path}: {bad[0]} must be a mapping of overrides (variants: name -> overrides)"
        )
    return {name: dict(extra or {}) for name, extra in variants.items()}


# =========================================================================== validation
def coma_parameter_names() -> list[str]:
    """COMA's constructor arguments a config may set (its signature, less the trainer's own)."""
    skip = {"self", "policy", "env", "_init_setup_model", *RESERVED_KEYS}
    return [n for n in inspect.signature(COMA.__init__).parameters if n not in skip]


def _fail(where: str, message: str) -> NoReturn:
    raise TrainingError(f"{where}: {message}")


def is_int(value: Any) -> TypeGuard[int]:
    """An integer that is not a flag (:func:`sb3_coma.common.numbers.is_whole`: numpy's included)."""
    return is_whole(value)


def _whole_at_least(value: Any, minimum: int) -> int | None:
    """``value`` as an int >= ``minimum`` (``2.0`` passes), ``None`` when it is not one: the one
    test behind :func:`positive_int` (config entries) and :func:`checked_count` (a run's counts)."""
    if is_real(value) and not is_whole(value) and float(value).is_integer():
        value = int(value)
    return int(value) if is_int(value) and value >= minimum else None


def positive_int(where: str, key: str, value: Any) -> int:
    """``value`` as an int >= 1 (``2.0`` passes); :class:`TrainingError` naming ``where`` and ``key``."""
    number = _whole_at_least(value, 1)
    if number is None:
        _fail(where, f"{key} must be a positive integer, got {value!r}")
    return number


#: The least value each count of a run takes (the frequencies: 0 means none). One rule per count,
#: which ``train()`` applies to its arguments and ``sb3-coma train`` to its flags.
COUNT_MINIMUMS: dict[str, int] = {"total_timesteps": 1, "n_envs": 1, "eval_missions": 1, "save_freq": 0, "eval_freq": 0}


def checked_count(key: str, value: Any, label: str | None = None) -> int:
    """``value`` as the count ``key`` of :data:`COUNT_MINIMUMS` (``2.0`` passes); a
    :class:`TrainingError` naming ``label`` (default: the key) and the value otherwise."""
    minimum = COUNT_MINIMUMS[key]
    number = _whole_at_least(value, minimum)
    if number is None:
        rule = f"an integer >= {minimum}" + (" (0: none) in joint steps" if minimum == 0 else "")
        raise TrainingError(f"{label or key} must be {rule}, got {value!r}")
    return number


def split_env_kwargs(env_kwargs: Mapping[str, Any]) -> tuple[str, dict[str, Any], dict[str, Any]]:
    """``(fusion, fusion_kwargs, env options)`` from an ``env_kwargs`` mapping (fusion default:
    ``uav_ipp.DEFAULT_FUSION``, the same as ``uav_ipp.make_vec_env``'s)."""
    options = dict(env_kwargs)
    fusion = options.pop("fusion", DEFAULT_FUSION)
    fusion_kwargs = options.pop("fusion_kwargs", None) or {}
    options.pop(ALLOW_TEST_SPLIT, None)  # a permission of the run, not an env option
    return fusion, fusion_kwargs, options


@dataclass(frozen=True)
class WorldSpec:
    """The world one config entry trains in, resolved once from its ``env_kwargs``.

    The raw mapping is what a user writes and what a run's ``config.yml`` records; this typed
    object is what travels below the config edge (the env builders, the model's record of its
    world, the validation env), so the options are split and checked once per entry, not again in
    every layer they pass through.
    """

    env_id: str
    config: IppConfig
    fusion: str = DEFAULT_FUSION
    fusion_kwargs: Mapping[str, Any] = field(default_factory=dict)

    @property
    def n_agents(self) -> int:
        return self.config.n_uavs

    def with_options(self, **changes: Any) -> WorldSpec:
        """The same world with some env options changed (the validation protocol's missions)."""
        return dataclasses.replace(self, config=self.config.replace(**changes))

    def record(self) -> dict[str, Any]:
        """The record of this world as ``COMA.env_options`` keeps it (saved in the zip).

        ``{"map": map_name, "fusion": ..., "fusion_kwargs": {...}}`` plus every
        :class:`uav_ipp.IppConfig` option resolved (defaults included, so the record survives a
        later change of a default); ``uav_ipp.make_vec_env(opts.pop("map"), **opts)`` rebuilds it.
        """
        resolved = {f.name: getattr(self.config, f.name) for f in fields(self.config) if f.name != "map_name"}
        return {
            "map": self.config.map_name,
            "fusion": self.fusion,
            "fusion_kwargs": plain(dict(self.fusion_kwargs)),
            **plain(resolved),
        }


def resolve_world(env_id: str, env_kwargs: Mapping[str, Any], where: str) -> WorldSpec:
    """The one place an ``env_kwargs`` mapping becomes a :class:`WorldSpec`; a bad option is a
    :class:`TrainingError` naming ``where``. rl-zoo3's ``render_mode="human"`` (its default for
    ``enjoy``) is dropped: the maps render headless."""
    fusion, fusion_kwargs, options = split_env_kwargs(env_kwargs)
    if options.get("render_mode") == "human":
        options.pop("render_mode")
    try:
        config = IppConfig.from_options(ENV_IDS[env_id], **options)
    except (ConfigError, TypeError) as exc:
        raise TrainingError(f"{where}: env_kwargs: {exc}") from exc
    return WorldSpec(env_id, config, fusion, dict(fusion_kwargs))


def _trainable_fusions() -> list[str]:
    """Fusions a COMA model can train on: every available one but the raw observation."""
    return [name for name in uav_ipp.available_fusions() if name != "none"]


def _check_keys(entry: Mapping[str, Any], where: str) -> None:
    allowed = set(coma_parameter_names()) | set(ZOO_KEYS) | set(LAYOUT_KEYS) | {WARM_START_KEY}
    for key in entry:
        if key in RESERVED_KEYS:
            _fail(where, f"{key!r} cannot be set in a config: {RESERVED_KEYS[key]}")
        if key in UNSUPPORTED_KEYS:
            _fail(where, f"rl-zoo3 key {key!r} is not supported with COMA: {UNSUPPORTED_KEYS[key]}")
        if key not in allowed:
            hint = difflib.get_close_matches(str(key), sorted(allowed), n=1)
            _fail(
                where,
                f"COMA does not take {key!r}"
                + (f" (did you mean {hint[0]!r}?)" if hint else "")
                + f"; allowed keys: {', '.join(sorted(allowed))}",
            )


def _check_zoo_values(entry: Mapping[str, Any], where: str) -> None:
    if "n_timesteps" not in entry:
        _fail(where, "n_timesteps (joint steps to train) is missing")
    positive_int(where, "n_timesteps", entry["n_timesteps"])
    try:
        check_total_timesteps(entry["n_timesteps"], "n_timesteps")
    except ValueError as exc:
        _fail(where, str(exc))
    if "n_envs" in entry:
        positive_int(where, "n_envs", entry["n_envs"])
    if entry.get("workers", "auto") != "auto":
        positive_int(where, "workers", entry["workers"])
    if entry.get("backend", "subprocess") not in uav_ipp.BACKENDS:
        _fail(where, f"backend must be one of {tuple(uav_ipp.BACKENDS)}, got {entry['backend']!r}")
    if "policy" in entry and not isinstance(entry["policy"], str):
        _fail(
            where,
            f"policy must be an alias (CBAMPolicy, UavCnnPolicy, MlpPolicy, ...) or a dotted class path, "
            f"got {entry['policy']!r}",
        )
    if "policy_kwargs" in entry and not isinstance(entry["policy_kwargs"], (dict, str)):
        _fail(where, f"policy_kwargs must be a mapping or a Python expression string, got {entry['policy_kwargs']!r}")
    for key in _SCHEDULE_KEYS:
        value = entry.get(key)
        if isinstance(value, str) and not _SCHEDULE_RE.match(value):
            _fail(where, f"{key} must be a number or 'lin_<initial value>', got {value!r}")


def _check_env_kwargs(entry: Mapping[str, Any], where: str, env_id: str | None) -> WorldSpec | None:
    """The entry's ``env_kwargs`` checked (fusion, the test-split permission) and, with the env id
    known, resolved into the :class:`WorldSpec` everything below the config edge trusts."""
    env_kwargs = entry.get("env_kwargs", {}) or {}
    if not isinstance(env_kwargs, dict):
        _fail(where, f"env_kwargs must be a mapping of environment options, got {env_kwargs!r}")
    fusion = env_kwargs.get("fusion", DEFAULT_FUSION)
    if fusion not in _trainable_fusions():
        _fail(where, f"env_kwargs.fusion must be one of {tuple(_trainable_fusions())}, got {fusion!r}")
    if not isinstance(env_kwargs.get("fusion_kwargs") or {}, dict):
        _fail(where, f"env_kwargs.fusion_kwargs must be a mapping, got {env_kwargs['fusion_kwargs']!r}")
    _check_test_split(env_kwargs, where)
    return None if env_id is None else resolve_world(env_id, env_kwargs, where)


def _check_test_split(env_kwargs: Mapping[str, Any], where: str) -> None:
    """Training on ``split="test"`` needs :data:`ALLOW_TEST_SPLIT`; the permission alone is refused.

    The test scenes are the unseen protocol's missions, on which every verdict rests: a model
    that trained on them is no longer measured on unseen missions, which is easy to do by
    accident with one ``--set``. The permission without the split would be silently ignored.
    """
    allowed = env_kwargs.get(ALLOW_TEST_SPLIT, False)
    if not isinstance(allowed, bool):
        _fail(where, f"env_kwargs.{ALLOW_TEST_SPLIT} must be true or false, got {allowed!r}")
    split = env_kwargs.get("split", "paper")
    if split == "test" and not allowed:
        _fail(
            where,
            "env_kwargs.split='test' trains on the unseen protocol's test missions, on which every verdict is "
            f"measured; pass --allow-test-split (a config: env_kwargs.{ALLOW_TEST_SPLIT}: true) to do it on purpose",
        )
    if allowed and split != "test":
        _fail(
            where,
            f"env_kwargs.{ALLOW_TEST_SPLIT}=True (--allow-test-split) is ignored: the entry trains on "
            f"split={split!r}, not 'test'; drop it",
        )


def validate_entry(entry: Mapping[str, Any], where: str, env_id: str | None = None) -> WorldSpec | None:
    """Check one resolved config entry; raise :class:`TrainingError` naming ``where`` and the key.

    Checks key names (COMA's arguments + rl-zoo3's keys), the zoo keys' values, schedule
    strings, and the environment options, which with ``env_id`` become the entry's
    :class:`WorldSpec` (returned: the one time they are resolved). COMA's own value checks
    (ranges, batch vs rollout) run when the model is built.
    """
    _check_keys(entry, where)
    _check_zoo_values(entry, where)
    if entry.get(WARM_START_KEY) is not None:  # null: none (a variant's way to drop the map entry's)
        check_warm_start(entry[WARM_START_KEY], where)
    return _check_env_kwargs(entry, where, env_id)


_WARM_START_DEFAULTS: dict[str, Any] = {"teacher": "oracle", "rounds": 8, "missions": 128, "critic_warmup": 0.2}


def check_warm_start(spec: Any, where: str) -> dict[str, Any]:
    """The ``warm_start`` mapping with its defaults, or a :class:`TrainingError` naming the bad value.

    One table of (setting, value, rule, what is allowed) and one raise: the mapping itself, its
    keys and each value are one kind of check."""
    is_map = isinstance(spec, Mapping)
    out = {**_WARM_START_DEFAULTS, **(spec if is_map else {})}
    teachers = sorted(name for name, cls in PLANNERS.items() if cls.uses_env_state)
    unknown = sorted(set(spec) - set(_WARM_START_DEFAULTS)) if is_map else []

    table: list[tuple[str, Any, bool, str]] = [
        ("", spec, is_map, "a mapping (teacher, rounds, missions, critic_warmup)"),
        (" keys", unknown, not unknown, f"each one of {sorted(_WARM_START_DEFAULTS)}"),
        (" teacher", out["teacher"], out["teacher"] in teachers, f"one of {teachers}"),
        (" rounds", out["rounds"], is_int(out["rounds"]) and out["rounds"] >= 1, "an integer >= 1"),
        (" missions", out["missions"], is_int(out["missions"]) and out["missions"] >= 1, "an integer >= 1"),
        (
            " critic_warmup",
            out["critic_warmup"],
            is_real(out["critic_warmup"]) and 0.0 <= out["critic_warmup"] < 1.0,
            "a number in [0, 1)",
        ),
    ]
    for name, value, ok, allowed in table:
        if not ok:
            raise TrainingError(f"{where}: warm_start{name}={value!r}: {allowed}")
    return out


# =========================================================================== numbers
#: A number in exponent notation. PyYAML (YAML 1.1) reads it as a string unless it has both a dot
#: and a signed exponent: ``1e-4``, ``1e2`` and ``1.0e5`` are strings to it, ``1.0e-5`` is a float.
_EXPONENT_RE = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)[eE][+-]?\d+")


def written_number(value: Any) -> Any:
    """``"1e-4"`` -> ``0.0001``: a string in exponent notation is the number people mean by it;
    anything else stays as it is (words stay words)."""
    if isinstance(value, str) and _EXPONENT_RE.fullmatch(value.strip()):
        return float(value)
    return value


def _numbers_in(value: Any) -> Any:
    """:func:`written_number` through mappings and lists (``env_kwargs``, ``policy_kwargs`` ...)."""
    if isinstance(value, Mapping):
        return {k: _numbers_in(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_numbers_in(v) for v in value]
    return written_number(value)


def _is_int_annotation(annotation: Any) -> bool:
    return str(annotation) in ("int", "int | None")


def _integer_settings() -> tuple[set[str], set[str]]:
    """``(entry keys, env options)`` that take whole numbers: rl-zoo3's counts, COMA's ``int``
    arguments and ``uav_ipp.IppConfig``'s ``int`` fields, read from their signatures so that a new
    argument is covered without a list to keep in step."""
    params = inspect.signature(COMA.__init__).parameters
    coma = {name for name, p in params.items() if _is_int_annotation(p.annotation) and name not in RESERVED_KEYS}
    env = {f.name for f in fields(IppConfig) if _is_int_annotation(f.type)}
    return {"n_timesteps", "n_envs"} | coma, env


def whole_number(where: str, key: str, value: Any) -> Any:
    """An integer-valued float (``1e2``, ``8.0``) as the int it is, so a count written in exponent
    notation works; a float with a fraction is refused naming ``key``; anything else is left to the
    checks that follow."""
    if isinstance(value, float):
        if value.is_integer():
            return int(value)
        _fail(where, f"{key} must be a whole number, got {value!r}")
    return value


def read_numbers(entry: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The entry with written numbers read (:func:`written_number`) and whole-number settings as
    ints (:func:`whole_number`), at any depth.

    The config loader runs this before any check, so every check sees the number the user meant
    (``learning_rate: 1e-4`` in YAML, ``--set n_timesteps=1e2``, ``env_kwargs.sigma=1e-1``) and the
    run's ``config.yml`` records it as a number.
    """
    out = _numbers_in(entry)
    top, env = _integer_settings()
    for key in sorted(top & set(out)):
        out[key] = whole_number(where, key, out[key])
    env_kwargs = out.get("env_kwargs")
    if isinstance(env_kwargs, dict):
        for key in sorted(env & set(env_kwargs)):
            env_kwargs[key] = whole_number(where, f"env_kwargs.{key}", env_kwargs[key])
    return out


# =========================================================================== paths and names
def path_name_problem(path: str | os.PathLike[str]) -> str | None:
    """Why a path's name cannot be used as text, or ``None``.

    A name whose bytes are not valid in the file system's encoding (``os.fsdecode(b"bad\xff")``,
    which is what Python makes of such a command-line argument) can be opened, but neither
    printed nor written into ``config.yml`` or ``export.json``: the command would end in a
    traceback after its work. Commands check it before any work instead.
    """
    text = os.fsdecode(os.fspath(path))
    if not text.strip():
        return "the path is empty"
    encoding = sys.getfilesystemencoding()
    try:
        text.encode(encoding)
    except UnicodeEncodeError as exc:
        bad = text[exc.start : exc.end]
        try:
            shown = repr(os.fsencode(bad))
        except UnicodeEncodeError:
            shown = ascii(bad)
        return f"its name is not valid {encoding} text ({shown} at position {exc.start}); rename it"
    return None


def output_folder_problem(path: str | os.PathLike[str]) -> str | None:
    """Why files cannot be written into the folder ``path`` (made when missing), or ``None``: its
    name (:func:`path_name_problem`), a file in its place or a parent's, a read-only location."""
    return path_name_problem(path) or folder_write_problem(path)


def output_file_problem(path: str | os.PathLike[str]) -> str | None:
    """Why the file ``path`` cannot be written, or ``None``: its name, a folder in its place, or a
    parent folder that cannot be made or written."""
    problem = path_name_problem(path)
    if problem is None and Path(path).is_dir():
        problem = f"{os.fsdecode(os.fspath(path))} is a folder, not a file"
    return problem or folder_write_problem(Path(path).parent)


def map_key(name: str) -> str:
    """The map a name means, to spot one map listed twice: ``"env1"``, ``"Env1"`` and
    ``"UavIpp-Env1-v0"`` are one map; any other name (an image's stem) means itself."""
    try:
        return ENV_IDS[resolve_env_id(name)]
    except TrainingError:
        return str(name).strip()


def repeated(names: Sequence[str], key: Callable[[str], str]) -> list[str]:
    """The names that mean (``key``) the same as an earlier one in ``names``, in order."""
    seen: set[str] = set()
    out = []
    for name in names:
        meaning = key(name)
        if meaning in seen:
            out.append(name)
        seen.add(meaning)
    return out


def map_list(text: str, flag: str = "--env") -> list[str]:
    """The maps of a comma-separated option, each once: one line naming the option when it is
    empty or names one map twice (``env1`` and ``UavIpp-Env1-v0`` are one map)."""
    names = [e.strip() for e in text.split(",") if e.strip()]
    twice = repeated(names, map_key)
    if not names or twice:  # one rule: each map once, at least one
        listed = f"lists the map {twice[0]!r} twice" if twice else "names no map"
        raise TrainingError(f"{flag} {text!r} {listed}: give each map once")
    return names


# =========================================================================== entries and variants
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


def _variant_overrides(data: Mapping[str, Any], path: Path, variant: str) -> dict[str, Any]:
    variants = _variants(data, path)
    if variant not in variants:
        known = ", ".join(sorted(map(str, variants))) or "none defined"
        raise TrainingError(f"unknown variant {variant!r} in config file {path} (variants: {known})")
    return variants[variant]


def _entry_and_where(
    p: Path, env_id: str, variant: str | None, overrides: Mapping[str, Any] | None, data: dict[str, Any]
) -> tuple[dict[str, Any], str]:
    """The env's entry of a config file with a variant and overrides merged in, and how error
    messages name it."""
    entry = data.get(env_id)
    if not isinstance(entry, dict):  # one rule: the file has a mapping for the env
        present = [k for k in data if k in ENV_IDS] or [k for k in data if k not in (VARIANTS_KEY, RUN_KEY)]
        has = f"it has: {', '.join(map(str, present)) or 'none'}"
        got = "no entry" if entry is None else f"a {type(entry).__name__}, not a mapping,"
        raise TrainingError(f"config file {p} has {got} for {env_id} ({has})")
    where = f"config {p} [{env_id}]"
    if variant is not None:
        entry = _merge(entry, _variant_overrides(data, p, variant))
        where = f"config {p} [{env_id}, variant {variant}]"
    if overrides:
        entry = _apply_overrides(entry, overrides)
        where += " with overrides"
    return read_numbers(entry, where), where


def config_entry(
    path: str | os.PathLike[str],
    env_id: str,
    variant: str | None = None,
    overrides: Mapping[str, Any] | None = None,
    data: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The env's entry of a config file, with a variant and overrides merged in, validated (its
    env options resolved only by :func:`train_config`, the one that keeps them)."""
    p = Path(path)
    entry, where = _entry_and_where(p, env_id, variant, overrides, read_config_file(p) if data is None else data)
    validate_entry(entry, where)
    return entry


def train_config(
    path: str | os.PathLike[str],
    env_id: str,
    variant: str | None = None,
    overrides: Mapping[str, Any] | None = None,
    data: dict[str, Any] | None = None,
    run: Mapping[str, Any] | None = None,
) -> TrainConfig:
    """A config file's entry for ``env_id`` as a :class:`TrainConfig`: validated, its world resolved
    once into a :class:`WorldSpec`."""
    p = Path(path)
    entry, where = _entry_and_where(p, env_id, variant, overrides, read_config_file(p) if data is None else data)
    world = validate_entry(entry, where, env_id)
    assert world is not None  # an env id was given
    return TrainConfig(env_id=env_id, entry=entry, world=world, source=p, variant=variant, run=dict(run or {}))


@dataclass
class TrainConfig:
    """A resolved training config: where it came from, the entry to train with and its world.

    ``entry["env_kwargs"]`` is the record (what ``config.yml`` keeps); ``world`` is the same
    options resolved, which is what builds envs. A change of the env options means a new
    :class:`TrainConfig` (:func:`train_config`), never an edit of ``entry["env_kwargs"]``.
    """

    env_id: str
    entry: dict[str, Any]
    world: WorldSpec
    source: Path | None = None
    variant: str | None = None
    run: dict[str, Any] = field(default_factory=dict)

    @property
    def map_name(self) -> str:
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
    def workers(self) -> int:
        """Worker processes the training copies run in (``"auto"``: every core, at most one per copy)."""
        return resolve_workers(self.entry.get("workers", 1), self.n_envs)

    @property
    def backend(self) -> str:
        return str(self.entry.get("backend", "subprocess"))

    @property
    def n_agents(self) -> int:
        return self.world.n_agents

    @property
    def where(self) -> str:
        """``config <file> [<env id>, variant <v>]``: how error messages name this entry."""
        return f"config {self.source} [{self.env_id}" + (f", variant {self.variant}]" if self.variant else "]")


def load_config(
    env: str | None = None,
    config: str | os.PathLike[str] | None = None,
    variant: str | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> TrainConfig:
    """Resolve env id (default :data:`DEFAULT_ENV_ID`), config file (default
    :func:`default_config_path`) and variant into a :class:`TrainConfig`."""
    env_id = resolve_env_id(env if env is not None else DEFAULT_ENV_ID)
    path = Path(config) if config is not None else default_config_path()
    return train_config(path, env_id, variant, overrides)


# =========================================================================== building
def import_dotted(name: str, what: str) -> Any:
    """``module.attr`` imported; :class:`TrainingError` naming ``what`` when it cannot be."""
    module_name, _, attr = name.rpartition(".")
    try:
        return getattr(importlib.import_module(module_name), attr)
    except (ImportError, AttributeError, ValueError) as exc:  # ValueError: no module part at all
        why = exc if module_name else "it is neither a known alias nor a dotted path (module.Class)"
        raise TrainingError(f"{what} {name!r} cannot be imported: {why}") from exc


def resolve_policy_kwargs(value: Any) -> dict[str, Any]:
    """``policy_kwargs`` from a mapping or an rl-zoo3 style expression string; ``*_class`` strings
    (aliases ``CBAMExtractor``/``CnnExtractor`` or dotted paths) become classes."""
    if value is None:
        return {}
    problem, text = None, value
    if isinstance(value, str):
        try:
            value = eval(value, dict(_POLICY_KWARGS_NAMES))  # rl-zoo3's documented format
        except Exception as exc:  # any error in the user's expression
            problem = f"is not a valid Python expression: {exc}"
    if problem is None and not isinstance(value, dict):
        problem = f"must be a mapping, got {value!r}"
    if problem is not None:  # one rule: a mapping, or an expression that makes one
        raise TrainingError(f"policy_kwargs {text!r} {problem}")
    out = dict(value)
    for key, item in list(out.items()):
        if key.endswith("_class") and isinstance(item, str):
            out[key] = _POLICY_KWARGS_NAMES.get(item) or import_dotted(item, f"policy_kwargs.{key}")
    return out


def parse_schedule(value: Any) -> Any:
    """``"lin_<x>"`` -> rl-zoo3's linear schedule from ``x`` to 0; anything else as it is."""
    if isinstance(value, str):
        match = _SCHEDULE_RE.match(value)
        if match:
            return SimpleLinearSchedule(float(match.group("value")))
    return value


#: A number as people write it: PyYAML (YAML 1.1) reads ``1e-4`` (no dot) as a string.
_NUMBER_RE = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def _number_or_value(value: Any) -> Any:
    """``"1e-4"`` -> ``0.0001``; anything that is not a written number stays as it is."""
    if isinstance(value, str) and _NUMBER_RE.fullmatch(value.strip()):
        return float(value)
    return value


def coma_kwargs(entry: Mapping[str, Any]) -> dict[str, Any]:
    """COMA constructor arguments from a config entry (zoo keys removed, strings resolved)."""
    trainer_keys = (*ZOO_KEYS, *LAYOUT_KEYS, WARM_START_KEY)
    kwargs = {k: _number_or_value(v) for k, v in entry.items() if k not in trainer_keys}
    for key in _SCHEDULE_KEYS:
        if key in kwargs:
            kwargs[key] = parse_schedule(kwargs[key])
    policy = entry.get("policy", "CBAMPolicy")
    if isinstance(policy, str) and policy not in COMA.policy_aliases and policy not in plugin_policies():
        policy = import_dotted(policy, "policy")
    kwargs["policy"] = policy
    if "policy_kwargs" in entry:
        kwargs["policy_kwargs"] = resolve_policy_kwargs(entry["policy_kwargs"])
    return kwargs


def named_objects(spec: Any, what: str) -> list[tuple[Any, dict[str, Any]]]:
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
        target = import_dotted(item, what) if isinstance(item, str) else item
        out.append((target, kwargs))
    return out


def construct(target: Any, kwargs: dict[str, Any], what: str, *args: Any) -> Any:
    """``target(*args, **kwargs)`` for a config's ``callback`` / ``vec_env_wrapper``; bad arguments
    become a :class:`TrainingError` naming the class and its arguments."""
    try:
        return target(*args, **kwargs)
    except (TypeError, ValueError) as exc:
        name = getattr(target, "__qualname__", repr(target))
        raise TrainingError(f"{what} {name} with arguments {kwargs!r}: {exc}") from exc


def resolve_workers(value: Any, n_envs: int) -> int:
    """An entry's ``workers``: the number itself, or for ``"auto"`` every core (at most one per copy)."""
    if value == "auto":
        return max(1, min(os.cpu_count() or 1, int(n_envs)))
    return int(value)


def make_world_vec_env(
    world: WorldSpec, n_envs: int, seed: int | None, workers: int = 1, backend: str = "subprocess"
) -> VecEnv:
    """``uav_ipp.make_vec_env`` of a resolved world on ``workers`` processes; what the world
    refuses at build time (an unavailable fusion, fusion options it does not take) becomes a
    :class:`TrainingError` naming the env and its options."""
    try:
        return uav_ipp.make_vec_env(
            world.config,
            n_envs=n_envs,
            fusion=world.fusion,
            seed=seed,
            fusion_kwargs=dict(world.fusion_kwargs) or None,
            workers=min(workers, n_envs),
            backend=backend,
        )
    except ValueError as exc:  # uav_ipp.ConfigError, an unavailable fusion, ...
        options = {k: v for k, v in world.record().items() if k not in ("map", "fusion", "fusion_kwargs")}
        defaults = plain(_DEFAULT_OPTIONS)
        changed = {k: v for k, v in options.items() if v != defaults.get(k, v)}
        raise TrainingError(f"cannot build {world.env_id} (fusion={world.fusion!r}, options {changed}): {exc}") from exc


def make_vec_env_from_kwargs(
    env_id: str,
    env_kwargs: Mapping[str, Any] | None,
    n_envs: int,
    seed: int | None,
    workers: int = 1,
    backend: str = "subprocess",
) -> VecEnv:
    """:func:`make_world_vec_env` of a raw ``env_kwargs`` mapping (rl-zoo3's ``--env-kwargs``, a
    run's recorded options): resolved here, at the edge, once."""
    return make_world_vec_env(
        resolve_world(env_id, env_kwargs or {}, f"cannot build {env_id}"), n_envs, seed, workers, backend
    )


def make_training_env(
    cfg: TrainConfig, n_envs: int | None = None, seed: int | None = None, workers: int | None = None
) -> VecEnv:
    """The SB3 vec env of a config (``uav_ipp.make_vec_env`` + the config's ``vec_env_wrapper``), its
    copies on the config's ``workers`` (or ``workers``) processes."""
    copies = n_envs or cfg.n_envs
    layout = resolve_workers(cfg.entry.get("workers", 1), copies) if workers is None else workers
    return _wrapped_vec_env(cfg, cfg.world, copies, seed, layout)


def _wrapped_vec_env(cfg: TrainConfig, world: WorldSpec, copies: int, seed: int | None, workers: int) -> VecEnv:
    """``uav_ipp.make_vec_env`` of ``world`` inside the config's ``vec_env_wrapper`` entries."""
    env = make_world_vec_env(world, copies, seed, workers, cfg.backend)
    try:
        for wrapper, wkwargs in named_objects(cfg.entry.get("vec_env_wrapper"), "vec_env_wrapper"):
            env = construct(wrapper, wkwargs, "vec_env_wrapper", env)
    except BaseException:
        env.close()
        raise
    return env


def validation_world(world: WorldSpec) -> WorldSpec:
    """The world a run's checkpoints are validated in: ``world`` flying the validation protocol's
    missions (``sb3_coma.common.evaluation``: mission ``seed + k`` of the train split, every train
    scene in turn); a world on the paper's fixed mission (a user's map) has no scenes to visit and
    flies as it is, with the validation seeds."""
    if world.config.split != "train":
        return world
    return world.with_options(**PROTOCOLS["validation"].env_options())


def make_validation_env(cfg: TrainConfig, missions: int, seed: int) -> VecEnv:
    """The vec env a run's checkpoints are validated on (:func:`validation_world`), in one process."""
    return _wrapped_vec_env(cfg, validation_world(cfg.world), eval_copies(missions), seed, 1)


def eval_copies(missions: int) -> int:
    """Env copies for an evaluation of ``missions`` missions: a divisor of it (every copy flies the
    same number), at most 5, so one forward pass acts for several missions."""
    return next(c for c in (5, 4, 3, 2, 1) if missions % c == 0)


def plain(value: Any) -> Any:
    """JSON/YAML-safe copy: tuples become lists, classes dotted paths, schedules ``lin_<x>``,
    paths and other objects strings; a numpy scalar the Python number it holds."""
    value = plain_number(value)
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, type):
        return f"{value.__module__}.{value.__qualname__}"
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    initial = getattr(value, "initial_value", None)
    if initial is not None:
        return f"lin_{initial}"
    return str(value)


def env_options_of(env_id: str, env_kwargs: Mapping[str, Any]) -> dict[str, Any]:
    """:meth:`WorldSpec.record` of a raw ``env_kwargs`` mapping (a run's recorded settings)."""
    return resolve_world(env_id, env_kwargs, f"env_kwargs of {env_id}").record()
