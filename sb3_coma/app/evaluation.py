"""``sb3_coma.evaluate``: the front door that turns names into objects, then flies them.

``evaluate(policy_or_name, env="env3", n_trials=10, seed=0)`` flies ``n_trials`` missions with a
trained model (object, ``.zip`` path or shipped name) or a baseline (``"random"``,
``"lawnmower"``, ``"ag"``). Resolving a shipped name or a path to a model, a baseline name to a
planner, a protocol to env options, and the model's own observation options to the env it flies
in is the application's job (like rl-zoo's ``get_model_path``); flying the missions is the
library's :func:`sb3_coma.common.evaluation.evaluate_policy`, which takes objects.

AG's entropy weighting defaults to the one chosen per map family on validation missions
(``sb3_coma.baselines.adaptive_gain.WEIGHTING_BY_MAP``, measured by ``sb3-coma ag-weighting``)
unless ``planner_kwargs`` names one. The baselines' rows of the generated tables are names too
(:data:`PLANNER_ALIASES`: ``"ag-k3"`` is AG with ``lookahead=3``), so every row can be flown again
by its name.
"""

from __future__ import annotations

import atexit
import contextlib
import itertools
import multiprocessing
import os
import pickle
import tempfile
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np

import uav_ipp
from sb3_coma.app import pretrained
from sb3_coma.app.pretrained import shipped_env_options
from sb3_coma.baselines import PLANNERS, Planner, make_planner, planner_class
from sb3_coma.baselines.adaptive_gain import default_weighting
from sb3_coma.coma import COMA
from sb3_coma.common.checkpoints import training_options, validate_checkpoint
from sb3_coma.common.evaluation import (
    DEFAULT_TRIALS,
    EVAL_BATCH,
    MODEL_LABEL,
    PROTOCOLS,
    EvaluationResult,
    _check_int,
    evaluate_policy,
    merge_results,
    protocol_of,
    relabel,
)
from uav_ipp import NOISE_PRESETS, IppConfig

__all__ = [
    "OBSERVATION_OPTIONS",
    "PLANNER_ALIASES",
    "PROTOCOLS",
    "WORLD_OPTIONS",
    "WorldMismatchWarning",
    "check_observation_options",
    "check_policy",
    "evaluate",
    "is_model",
    "parallel_evaluation",
    "planner_options",
    "resolve_policy",
    "trained_options",
    "world_differences",
]


#: The baseline rows of the generated tables (``sb3_coma.experiments.protocols.BASELINE_METHODS``)
#: that are a planner with options: ``evaluate("ag-k3")`` and ``sb3-coma evaluate --methods ag-k3``
#: fly the row ``ag-k3`` of docs/RESULTS.md, labelled so. ``planner_kwargs`` given with one of
#: them override its options.
PLANNER_ALIASES: dict[str, tuple[str, dict[str, Any]]] = {
    "ag-k2": ("ag", {"lookahead": 2}),
    "ag-k3": ("ag", {"lookahead": 3}),
    "ag-comm": ("ag", {"knowledge": "comm"}),
    "ag-central": ("ag", {"knowledge": "central"}),
}


def baseline_names() -> list[str]:
    """Every name of a baseline: the planners and the table rows of :data:`PLANNER_ALIASES`."""
    return sorted([*PLANNERS, *PLANNER_ALIASES])


def _alias(name: Any) -> str | None:
    """The :data:`PLANNER_ALIASES` key ``name`` spells (any case), or None."""
    key = name.strip().lower() if isinstance(name, str) else None
    return key if key in PLANNER_ALIASES else None


def _named_planner(
    policy_or_name: Any, planner_kwargs: Mapping[str, Any] | None, label: str | None
) -> tuple[Any, Mapping[str, Any] | None, str | None]:
    """A table row's name -> (its planner, its options under the caller's, the row's name as the
    default label); anything else unchanged. Done first, so the rest sees a plain planner."""
    alias = _alias(policy_or_name)
    if alias is None:
        return policy_or_name, planner_kwargs, label
    planner, options = PLANNER_ALIASES[alias]
    return planner, {**options, **dict(planner_kwargs or {})}, label or alias


def is_baseline(name: str) -> bool:
    """Whether ``name`` names a baseline planner or a table row of one (``ag-k3`` ...); the one
    test every front door (evaluate, export) uses."""
    if _alias(name) is not None:
        return True
    try:
        planner_class(name)
        return True
    except ValueError:
        return False


def looks_like_path(name: str) -> bool:
    """Whether a model name is spelt as a file path (a typo there is "not found", not "unknown")."""
    return name.endswith(".zip") or os.sep in name or "/" in name or name.startswith(".")


def _load_model_file(path: Path, venv: Any) -> Any:
    pretrained.verify_shipped_file(path)  # a shipped zip reached by its path is verified all the same
    validate_checkpoint(path)  # truncated / corrupt / another algorithm: CheckpointError naming the file
    try:
        return COMA.load(str(path), env=venv, device="cpu")
    except pickle.UnpicklingError as exc:  # torch's "Weights only load failed ..." on a damaged member
        raise ValueError(
            f"cannot load model {str(path)!r}: it is corrupt (a network or optimizer member is not "
            "a readable PyTorch file)"
        ) from exc
    except (ValueError, KeyError, AssertionError, RuntimeError, EOFError) as exc:
        raise ValueError(
            f"cannot load model {str(path)!r} for this environment: {exc} (was it trained with "
            f"another number of UAVs or observation layout?)"
        ) from exc


def _is_shipped_name(policy_or_name: Any) -> bool:
    """A shipped model's name (``"env1"``, ``"UavIpp-Env3-v0"``, ``"env3-mean-cnn"``): it always
    means the verified package file, never a file of that name in the current folder (an SB3 zip
    can run code when loaded, so a local file must be passed as an explicit path)."""
    return isinstance(policy_or_name, str) and pretrained.is_shipped(policy_or_name)


def _load_pretrained(name: str, venv: Any) -> Any:
    return pretrained.load_pretrained(name, env=venv)


def is_model(policy_or_name: Any) -> bool:
    """Whether this names/is a learned model (not a baseline): decides the default fusion."""
    if isinstance(policy_or_name, (str, os.PathLike)):
        return not (isinstance(policy_or_name, str) and is_baseline(policy_or_name))
    return not isinstance(policy_or_name, Planner)


def check_policy(policy_or_name: Any) -> None:
    """Fail early, before any env is built, on names and paths that cannot resolve."""
    if _is_shipped_name(policy_or_name) or (isinstance(policy_or_name, str) and is_baseline(policy_or_name)):
        return
    if isinstance(policy_or_name, (str, os.PathLike)):
        text = os.fspath(policy_or_name)
        if not text.strip():
            raise ValueError("empty method name")
        if Path(text).is_file() or Path(text + ".zip").is_file():
            # A shipped zip reached by its path is verified like the shipped name (PretrainedError).
            pretrained.verify_shipped_file(Path(text) if Path(text).is_file() else Path(text + ".zip"))
            return
        if Path(text).is_dir():
            raise ValueError(f"model {text!r} is a folder: pass the model .zip inside it (e.g. {text}/model.zip)")
        if isinstance(policy_or_name, os.PathLike) or looks_like_path(text):
            raise FileNotFoundError(f"model file not found: {text!r}")
        raise ValueError(
            f"unknown method {text!r}: not a baseline ({', '.join(sorted(PLANNERS))}; table rows: "
            f"{', '.join(sorted(PLANNER_ALIASES))}), not a model file, and not "
            f"a shipped model (available: {', '.join(pretrained.available()) or 'none'})"
        )
    if not callable(getattr(policy_or_name, "predict", None)):
        raise TypeError(
            f"cannot evaluate {type(policy_or_name).__name__}: pass a baseline name, a model path "
            f"or an object with SB3's predict(observation, deterministic=...)"
        )


def resolve_policy(
    policy_or_name: Any, venv: Any, seed: int | None, planner_kwargs: Mapping[str, Any] | None = None
) -> tuple[Any, str]:
    """(predictor with SB3's ``predict``, label) for a baseline name, model path/name or object."""
    policy_or_name, planner_kwargs, row = _named_planner(policy_or_name, planner_kwargs, None)
    check_policy(policy_or_name)
    if isinstance(policy_or_name, str) and is_baseline(policy_or_name):
        cls = planner_class(policy_or_name)
        return make_planner(cls.name, venv, seed=seed, **dict(planner_kwargs or {})), row or cls.name
    if _is_shipped_name(policy_or_name):
        return _load_pretrained(policy_or_name, venv), policy_or_name
    if isinstance(policy_or_name, (str, os.PathLike)):
        text = os.fspath(policy_or_name)
        path = Path(text) if Path(text).is_file() else Path(text + ".zip")
        return _load_model_file(path, venv), path.stem
    if isinstance(policy_or_name, Planner):
        if policy_or_name.uses_env_state and policy_or_name.venv is not venv:
            raise ValueError(
                f"a {policy_or_name.name!r} planner reads its own vec env's state: pass its name "
                f"({policy_or_name.name!r}) so that evaluate builds it on the evaluation env"
            )
        return policy_or_name, policy_or_name.name
    return policy_or_name, MODEL_LABEL


#: Env options that shape a model's observation: ``evaluate`` takes them from the model's training
#: options unless the caller sets them, and refuses a caller's value that differs
#: (:func:`check_observation_options`). The mission (map, split, start, noise, team size) stays the
#: caller's choice.
OBSERVATION_OPTIONS = (
    "action_gain",
    "observation",
    "comm_grid",
    "lattice",
    "grid",
    "altitudes",
    "field_size",
    "fov_deg",
)
#: Env options that change the world a model flies in, not its observation: flying a model with
#: other values is legal but the results then describe another world than its own, so it is a
#: :class:`WorldMismatchWarning` (team size and fusion have their own warnings).
WORLD_OPTIONS = (
    "budget",
    "noise",
    "alpha_low",
    "sigma",
    "attenuation",
    "decoder",
    "comm_range",
    "drop_probability",
    "flip_probability",
    "start_altitude",
)


class WorldMismatchWarning(UserWarning):
    """A model flies in another world than it trained in (budget, channel, decoder, flip table ...)."""


def trained_options(policy_or_name: Any, shipped: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The env options a model was trained with (``sb3_coma.training_options``, a shipped model's
    manifest ``env_options``); ``{}`` for baselines and for models that do not record them."""
    if not is_model(policy_or_name):
        return {}
    shipped = _shipped_info(policy_or_name) if shipped is None else shipped
    if isinstance(policy_or_name, str) and not policy_or_name.endswith(".zip") and shipped:
        return shipped_env_options(policy_or_name) or {}
    return training_options(policy_or_name) or {}


def _same(a: Any, b: Any) -> bool:
    """Option values compared in one form: a recorded option comes from JSON (lists, string keys),
    a given one from Python (tuples, ints, float keys)."""
    return _comparable(a) == _comparable(b)


def _comparable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return tuple(sorted((_comparable_key(k), _comparable(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_comparable(v) for v in value)
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_)):
        return float(value)
    return value


def _comparable_key(key: Any) -> Any:
    try:
        return float(key)
    except (TypeError, ValueError):
        return str(key)


def _described(policy_or_name: Any) -> str:
    if isinstance(policy_or_name, (str, os.PathLike)):
        return f"model {os.fspath(policy_or_name)!r}"
    return "the model"


def check_observation_options(what: str, trained: Mapping[str, Any], env_options: Mapping[str, Any]) -> None:
    """Refuse an option that shapes the observation, set by the caller to another value than the
    model trained with: SB3 would fail later with a bare "Observation spaces do not match" (or a
    layout of the same shape would be read as another one). ``ValueError`` naming both values."""
    for key in OBSERVATION_OPTIONS:
        if key in trained and key in env_options and not _same(trained[key], env_options[key]):
            raise ValueError(
                f"{what} was trained with {key}={trained[key]!r} but is asked to fly with {key}={env_options[key]!r}: "
                f"{key} changes the observation its network reads; drop {key}= to fly it with its own"
            )


def _take_observation_options(policy_or_name: Any, trained: Mapping[str, Any], env_options: dict[str, Any]) -> None:
    """What the network's inputs are made of follows the model: a caller's other value is refused
    (:func:`check_observation_options`), an unset one is taken from the training (in place)."""
    check_observation_options(_described(policy_or_name), trained, env_options)
    for key in OBSERVATION_OPTIONS:
        if key in trained and key not in env_options:
            env_options[key] = trained[key]


def _channel(options: Mapping[str, Any]) -> tuple[Any, Any]:
    """``(alpha_low, sigma)`` of recorded options, the noise preset's where they are ``None``."""
    low, sigma = NOISE_PRESETS.get(str(options.get("noise")), (None, None))
    given_low, given_sigma = options.get("alpha_low"), options.get("sigma")
    return (low if given_low is None else given_low, sigma if given_sigma is None else given_sigma)


def world_differences(trained: Mapping[str, Any], config: IppConfig, skip: Iterable[str] = ()) -> list[str]:
    """``"budget=2 (trained: 15)"`` for each of :data:`WORLD_OPTIONS` the flight (``config``) sets
    otherwise than the training did (``alpha_low`` / ``sigma`` compared as the channel really is,
    preset included), except those in ``skip`` (a sweep's own axes)."""
    out = []
    flown_channel, own_channel = dict(zip(("alpha_low", "sigma"), config.noise_params)), _channel(trained)
    for key in WORLD_OPTIONS:
        if key not in trained or key in skip:
            continue
        if key in ("alpha_low", "sigma"):
            if trained[key] is None and getattr(config, key) is None:
                continue  # both the preset's: "noise" tells the difference, if any
            flown, own = flown_channel[key], own_channel[("alpha_low", "sigma").index(key)]
        else:
            flown, own = getattr(config, key), trained[key]
        if not _same(flown, own):
            out.append(f"{key}={flown!r} (trained: {own!r})")
    return out


def _warn_if_flown_differently(
    policy_or_name: Any, trained: dict[str, Any], shipped: dict[str, Any], fusion: str | None, config: IppConfig
) -> None:
    """Warn (not refuse) when a model flies with another team size, fusion or world than it trained with.

    All are legal (the actor is per agent and the fusions take any number of maps, see
    docs/deployment.md), but the results then describe another method or world than the model's
    own, which is easy to do by accident with ``--uavs``, ``--fusion`` or ``--budget``. ``fusion``
    is the caller's (``None``: the model's own is used, nothing to warn about).
    """
    if not is_model(policy_or_name):
        return
    what, n_uavs = _described(policy_or_name), int(config.n_uavs)
    own_n = trained.get("n_uavs")
    if own_n is None and not isinstance(policy_or_name, (str, os.PathLike)):
        own_n = getattr(policy_or_name, "n_agents", None)  # a COMA object that records no options
    if isinstance(own_n, (int, np.integer)) and not isinstance(own_n, bool) and int(own_n) != n_uavs:
        warnings.warn(
            f"{what} was trained with {int(own_n)} UAVs but flies with {n_uavs} (n_uavs={n_uavs}): allowed, its "
            f"actor is per agent, but the results are not those of its own team size",
            UserWarning,
            stacklevel=3,
        )
    own_fusion = trained.get("fusion") or shipped.get("fusion")
    if fusion is not None and own_fusion and fusion != own_fusion:
        warnings.warn(
            f"{what} was trained with fusion {own_fusion!r} but flies with fusion {fusion!r}: its actor reads "
            f"fused maps of another kind; pass fusion={own_fusion!r} (or leave it unset) to fly it as trained",
            UserWarning,
            stacklevel=3,
        )
    differences = world_differences(trained, config)
    if differences:
        warnings.warn(
            f"{what} flies in another world than it trained in: {', '.join(differences)}; allowed, but the "
            f"results describe that world, not the model's own",
            WorldMismatchWarning,
            stacklevel=3,
        )


def _shipped_info(policy_or_name: Any) -> dict[str, Any]:
    """Manifest entry of a shipped model (by name or loaded object); empty for anything else."""
    info = getattr(policy_or_name, "pretrained_info", None)
    if isinstance(info, dict):
        return info
    if isinstance(policy_or_name, str) and not policy_or_name.endswith(".zip"):
        try:
            return pretrained.model_info(policy_or_name)
        except (ImportError, ValueError, KeyError, OSError):
            return {}
    return {}


def _is_ag(policy_or_name: Any) -> bool:
    if not isinstance(policy_or_name, str) or not is_baseline(policy_or_name):
        return False
    alias = _alias(policy_or_name)
    return planner_class(PLANNER_ALIASES[alias][0] if alias else policy_or_name).name == "ag"


def planner_options(policy_or_name: Any, config: Any, planner_kwargs: Mapping[str, Any] | None) -> dict[str, Any]:
    """The options a baseline is built with: ``planner_kwargs`` plus, for AG on a known map family
    without a ``weighting`` of the caller's, the per-map weighting chosen on validation missions."""
    options = dict(planner_kwargs or {})
    if _is_ag(policy_or_name) and "weighting" not in options:
        options["weighting"] = default_weighting(None if getattr(config, "map_path", None) else config.map_name)
    return options


def _protocol_options(
    protocol: str | None, n_trials: int | None, seed: int | None, env: Any, env_options: dict[str, Any]
) -> tuple[str | None, int, int, dict[str, Any]]:
    """(protocol name, missions, first seed, env options) after applying a protocol's rules."""
    if protocol is None:
        return None, DEFAULT_TRIALS if n_trials is None else n_trials, 0 if seed is None else seed, env_options
    proto = protocol_of(protocol)
    fixed = proto.env_options()
    for key, value in fixed.items():
        if key in env_options and env_options[key] != value:
            raise ValueError(
                f"protocol {proto.name!r} flies {key}={value!r}; got {key}={env_options[key]!r} "
                f"(drop protocol= to choose the missions yourself)"
            )
    missions = proto.missions(str(env)) if n_trials is None else n_trials
    return proto.name, missions, proto.first_seed if seed is None else seed, {**env_options, **fixed}


def evaluate(
    policy_or_name: Any,
    env: str = "env3",
    n_trials: int | None = None,
    seed: int | None = None,
    fusion: str | None = None,
    deterministic: bool | None = None,
    n_envs: int | None = None,
    record: int = 1,
    label: str | None = None,
    planner_kwargs: Mapping[str, Any] | None = None,
    protocol: str | None = None,
    workers: int | str | None = None,
    **env_options: Any,
) -> EvaluationResult:
    """Run a trained model or a baseline for ``n_trials`` seeded missions (see module docstring).

    :param policy_or_name: ``"random"``, ``"lawnmower"``, ``"ag"`` (or ``"nl"``), ``"oracle"``, a
        baseline row of the tables (:data:`PLANNER_ALIASES`: ``"ag-k3"``, ``"ag-comm"`` ...); a COMA model
        object, a path to a saved ``.zip``, or a shipped model name (``"env1"`` ...,
        via ``sb3_coma.load_pretrained``); or any object with SB3's ``predict``
    :param env: map name or gymnasium id
    :param n_trials: missions; trial ``k`` uses env seed ``seed + k`` (default: the protocol's
        count, 10 without a protocol)
    :param seed: base seed (env and the planner's own random stream; default: the protocol's
        first seed, :data:`~sb3_coma.common.evaluation.VALIDATION_SEED` for ``"validation"``, else 0)
    :param fusion: ``"mean"`` or ``"sendfuse"``; ``None``: ``"sendfuse"`` for models (the paper's
        method), ``"mean"`` for baselines (they do not read the fused channel)
    :param deterministic: passed to the model's ``predict``; ``None``: what a shipped model's
        manifest records (its results were measured that way), else ``True``
    :param n_envs: env copies flown at once (default :data:`EVAL_BATCH`); results are
        reproducible for the same ``seed`` and ``n_envs``
    :param record: how many trials keep their final global belief (trial 0 also keeps a belief
        per step for the GIF when ``record >= 1``)
    :param label: method name in tables (default: the baseline name, model file stem or "coma")
    :param planner_kwargs: options of the baseline (e.g. ``{"altitude": 5.0}`` for the lawnmower,
        ``{"lookahead": 2}`` for AG; AG's ``weighting`` defaults to the map family's, see module docstring)
    :param protocol: ``"paper"``, ``"unseen"`` or ``"validation"`` (:data:`PROTOCOLS`): sets
        ``split`` / ``start``, the default ``n_trials`` and ``seed``; ``None``: the env options as given
    :param env_options: environment options (``noise``, ``n_uavs``, ``budget``, ``map_path``,
        ``valuable``, ...)
    :param workers: processes that fly the batches of ``n_envs`` missions side by side (``"auto"``:
        every core; ``None``: the value set by :func:`parallel_evaluation`, else 1). The result
        is the one process's, planning times aside (measured on shared cores). Names, paths and
        COMA models fly on workers; other objects (a planner, a bare policy) in this process
    """
    policy_or_name, planner_kwargs, label = _named_planner(policy_or_name, planner_kwargs, label)
    given = dict(env_options)
    protocol, n_trials, seed, env_options = _protocol_options(protocol, n_trials, seed, env, dict(env_options))
    n_trials = _check_int("n_trials", n_trials, 1)
    check_policy(policy_or_name)
    n_envs = EVAL_BATCH if n_envs is None else _check_int("n_envs", n_envs, 1)
    n_workers = evaluation_workers(_DEFAULT_WORKERS[0] if workers is None else workers, n_trials, n_envs)
    if n_workers > 1 and isinstance(policy_or_name, (str, os.PathLike, COMA)):
        chunk = dict(
            policy_or_name=policy_or_name, env=env, seed=seed, fusion=fusion, deterministic=deterministic,
            n_envs=n_envs, record=record, label=label or policy_label(policy_or_name),
            planner_kwargs=planner_kwargs, protocol=protocol, **given,
        )  # fmt: skip
        return _evaluate_on_workers(chunk, n_trials, n_workers)
    shipped = _shipped_info(policy_or_name)
    trained = trained_options(policy_or_name, shipped)
    _take_observation_options(policy_or_name, trained, env_options)
    own_fusion = trained.get("fusion") or shipped.get("fusion")
    flown_fusion = fusion or own_fusion or ("sendfuse" if is_model(policy_or_name) else "mean")
    if deterministic is None:
        deterministic = bool(shipped.get("deterministic", True))
    flown_kwargs: dict[str, Any] = {}
    result = evaluate_policy(
        _predictor_maker(policy_or_name, trained, shipped, fusion, planner_kwargs, flown_kwargs),
        _env_maker(env, flown_fusion, own_fusion, env_options),
        n_trials,
        seed,
        deterministic=bool(deterministic),
        n_envs=n_envs,
        record=record,
        label=label or policy_label(policy_or_name),
    )
    baseline = isinstance(policy_or_name, str) and is_baseline(policy_or_name)
    return relabel(
        result,
        env=str(env),
        fusion=flown_fusion,
        env_options=dict(env_options),
        protocol=protocol,
        planner_kwargs=dict(flown_kwargs) if baseline else {},
    )


def evaluation_workers(workers: Any, n_trials: int, n_envs: int) -> int:
    """How many processes fly an evaluation: ``workers`` (``"auto"``: every core), at most one per
    batch of ``n_envs`` missions."""
    if workers == "auto":
        workers = os.cpu_count() or 1
    workers = _check_int("workers", workers, 1)
    return min(workers, -(-n_trials // n_envs))


#: The workers of ``evaluate(..., workers=None)``: set for a block of code by :func:`parallel_evaluation`.
_DEFAULT_WORKERS: list[int | str] = [1]


@contextlib.contextmanager
def parallel_evaluation(workers: int | str) -> Iterator[None]:
    """Within the block, every :func:`evaluate` that names no ``workers`` flies on ``workers``
    processes: a protocol, a sweep or ``reproduce`` is made of many calls, and they all take
    the command's ``--workers``."""
    evaluation_workers(workers, 1, 1)  # validate now, not at the first call
    before = _DEFAULT_WORKERS[0]
    _DEFAULT_WORKERS[0] = workers
    try:
        yield
    finally:
        _DEFAULT_WORKERS[0] = before


def _chunks(n_trials: int, n_envs: int, n_workers: int) -> list[tuple[int, int]]:
    """(first trial, trials) of each worker: whole batches, as even as they split, in order."""
    batches = -(-n_trials // n_envs)
    edges = [round(k * batches / n_workers) * n_envs for k in range(n_workers + 1)]
    return [(a, min(b, n_trials) - a) for a, b in itertools.pairwise(edges) if a < n_trials]


def _evaluate_chunk(kwargs: dict[str, Any]) -> tuple[EvaluationResult, list[tuple[str, type[Warning]]]]:
    """One worker's part of :func:`_evaluate_on_workers` (a spawned process: one torch thread),
    with the warnings it raised: the caller re-raises them, so its filters and ``pytest.warns``
    see what one process would have shown."""
    import torch as th

    th.set_num_threads(1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = evaluate(**kwargs)
    return result, [(str(w.message), w.category) for w in caught]


def _evaluate_on_workers(chunk: dict[str, Any], n_trials: int, n_workers: int) -> EvaluationResult:
    """Fly whole batches of missions in ``n_workers`` spawned processes and merge them in order.

    Every batch is seeded by its first trial and gets its own planner, and models predict
    deterministically, so the merged result equals one process's. A model object travels as a
    saved file (a process cannot share it); names, paths and planners travel as they are.
    """
    policy = chunk["policy_or_name"]
    with tempfile.TemporaryDirectory(prefix="sb3-coma-eval-") as tmp:
        if isinstance(policy, COMA):
            path = Path(tmp) / "model.zip"
            policy.save(path)
            chunk["policy_or_name"] = str(path)
        jobs = [
            {**chunk, "seed": chunk["seed"] + start, "n_trials": count, "record": max(chunk["record"] - start, 0)}
            for start, count in _chunks(n_trials, chunk["n_envs"], n_workers)
        ]
        try:
            done = list(_pool(len(jobs)).map(_evaluate_chunk, jobs))
        except BrokenProcessPool:
            _close_pool()
            raise RuntimeError("an evaluation worker process died (out of memory?); rerun with workers=1") from None
    for message, category in dict.fromkeys(w for _, caught in done for w in caught):  # once each, in order
        if isinstance(policy, COMA):  # name the model the caller gave, not its temporary copy
            message = message.replace(f"model {str(Path(tmp) / 'model.zip')!r}", f"model {chunk['label']!r}")
        warnings.warn(message, category, stacklevel=3)
    return merge_results([result for result, _ in done])


#: The evaluation workers, kept between calls: starting a process and importing torch costs
#: seconds, and a protocol makes dozens of calls. Closed at exit.
_POOL: dict[int, ProcessPoolExecutor] = {}


def _pool(n_workers: int) -> ProcessPoolExecutor:
    if n_workers not in _POOL:
        _close_pool()
        context = multiprocessing.get_context("spawn")  # torch and numba are not fork-safe
        _POOL[n_workers] = ProcessPoolExecutor(max_workers=n_workers, mp_context=context)
    return _POOL[n_workers]


@atexit.register
def _close_pool() -> None:
    while _POOL:
        _POOL.popitem()[1].shutdown(cancel_futures=True)


def _env_maker(
    env: str, flown_fusion: str, own_fusion: str | None, env_options: dict[str, Any]
) -> Callable[[int], Any]:
    """``make_env(n)`` of :func:`evaluate_policy`: ``n`` copies of the world the policy flies in."""

    def make_env(n: int) -> Any:
        try:
            return uav_ipp.make_vec_env(env, n_envs=n, fusion=flown_fusion, seed=None, **env_options)
        except ValueError as exc:
            if flown_fusion == "sendfuse" and own_fusion != "sendfuse" and "sendfuse" in str(exc):
                raise ValueError(f"{exc}; evaluate a model trained without SenDFuse with fusion='mean'") from exc
            raise

    return make_env


def _predictor_maker(
    policy_or_name: Any,
    trained: dict[str, Any],
    shipped: dict[str, Any],
    fusion: str | None,
    planner_kwargs: Mapping[str, Any] | None,
    flown_kwargs: dict[str, Any],
) -> Callable[[Any, int], Any]:
    """``predictor_for(venv, batch_seed)`` of :func:`evaluate_policy`. At the first batch it fills
    ``flown_kwargs`` with the baseline's options for the flown map and warns once if the model
    flies otherwise than it trained; every batch gets its own predictor."""
    first_batch = [True]

    def predictor_for(venv: Any, batch_seed: int) -> Any:
        config = venv.get_attr("config", indices=[0])[0]
        if first_batch.pop() if first_batch else False:
            flown_kwargs.update(planner_options(policy_or_name, config, planner_kwargs))
            _warn_if_flown_differently(policy_or_name, trained, shipped, fusion, config)
        return resolve_policy(policy_or_name, venv, batch_seed, flown_kwargs)[0]

    return predictor_for


def policy_label(policy_or_name: Any) -> str:
    """The name a method gets in tables: the baseline's name, the model file's stem, the shipped
    model's name, a planner's name, or :data:`MODEL_LABEL`."""
    if _alias(policy_or_name) is not None:
        return str(_alias(policy_or_name))
    if isinstance(policy_or_name, str) and is_baseline(policy_or_name):
        return planner_class(policy_or_name).name
    if _is_shipped_name(policy_or_name):
        return str(policy_or_name)
    if isinstance(policy_or_name, (str, os.PathLike)):
        text = os.fspath(policy_or_name)
        return (Path(text) if Path(text).is_file() else Path(text + ".zip")).stem
    if isinstance(policy_or_name, Planner):
        return policy_or_name.name
    return MODEL_LABEL
