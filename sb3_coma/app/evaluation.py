"""``sb3_coma.evaluate`` and :func:`fly`: the front door that turns names into objects, then flies them.

``evaluate(policy_or_name, env="env3", n_trials=10, seed=0)`` flies ``n_trials`` missions with a
trained model (object, ``.zip`` path or shipped name) or a baseline (``"random"``,
``"lawnmower"``, ``"ag"``). The input is resolved once into a
:class:`~sb3_coma.app.methods.Method` (:func:`~sb3_coma.app.methods.resolve_method`: a shipped
name or a path to a verified model, a baseline name to a planner) and the missions into
:class:`Missions`; :func:`fly` takes both, turns a protocol into env options and the model's own
observation options into the env it flies in (like rl-zoo's ``get_model_path``); flying the
missions is the library's :func:`sb3_coma.common.evaluation.evaluate_policy`, which takes objects.
Every study flies its methods through :func:`fly`.

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
import tempfile
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import uav_ipp
from sb3_coma.app.methods import (
    Method,
    resolve_method,
)
from sb3_coma.baselines.adaptive_gain import default_weighting
from sb3_coma.coma import COMA
from sb3_coma.common.evaluation import (
    DEFAULT_TRIALS,
    EVAL_BATCH,
    EvaluationResult,
    _check_int,
    evaluate_policy,
    merge_results,
    protocol_of,
    relabel,
)
from sb3_coma.common.numbers import is_real, is_whole, plain
from uav_ipp import NOISE_PRESETS, IppConfig


def is_model(policy_or_name: Any) -> bool:
    """Whether this names/is a learned model (not a baseline): decides the default fusion. For
    callers that hold a name; a resolved :class:`Method` says it as ``learned``."""
    try:
        return resolve_method(policy_or_name).learned
    except (ValueError, TypeError, OSError):
        return True  # what cannot resolve is refused by the evaluation itself


def check_policy(policy_or_name: Any) -> None:
    """Fail early, before any env is built, on names and paths that cannot resolve."""
    resolve_method(policy_or_name)


def trained_options(policy_or_name: Any) -> dict[str, Any]:
    """The env options a model was trained with (``sb3_coma.training_options``, a shipped model's
    manifest ``env_options``); ``{}`` for baselines and for models that do not record them."""
    method = resolve_method(policy_or_name)
    return dict(method.trained) if method.learned else {}


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


def _same(a: Any, b: Any) -> bool:
    """Option values compared in one form: a recorded option comes from JSON (lists, string keys),
    a given one from Python (tuples, ints, float keys)."""
    return _comparable(a) == _comparable(b)


def _comparable(value: Any) -> Any:
    if isinstance(value, Mapping):
        return tuple(sorted((_comparable_key(k), _comparable(v)) for k, v in value.items()))
    if isinstance(value, (list, tuple)):
        return tuple(_comparable(v) for v in value)
    if is_real(value):
        return float(value)
    return value


def _comparable_key(key: Any) -> Any:
    try:
        return float(key)
    except (TypeError, ValueError):
        return str(key)


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


def _take_observation_options(method: Method, env_options: dict[str, Any]) -> None:
    """What the network's inputs are made of follows the model: a caller's other value is refused
    (:func:`check_observation_options`), an unset one is taken from the training (in place)."""
    check_observation_options(method.described, method.trained, env_options)
    for key in OBSERVATION_OPTIONS:
        if key in method.trained and key not in env_options:
            env_options[key] = method.trained[key]


def _warn_if_flown_differently(method: Method, config: IppConfig) -> None:
    """Warn (not refuse) when a model flies with another team size, fusion or world than it trained with.

    All are legal (the actor is per agent and the fusions take any number of maps, see
    docs/deployment.md), but the results then describe another method or world than the model's
    own, which is easy to do by accident with ``--uavs``, ``--fusion`` or ``--budget``. The
    method's ``fusion`` is the caller's (``None``: the model's own is used, nothing to warn about).
    """
    if not method.learned:
        return
    what, n_uavs, trained = method.described, int(config.n_uavs), method.trained
    own_n = trained.get("n_uavs")
    if own_n is None and method.source == "object":
        own_n = getattr(method.policy, "n_agents", None)  # a COMA object that records no options
    if is_whole(own_n) and int(own_n) != n_uavs:
        warnings.warn(
            f"{what} was trained with {int(own_n)} UAVs but flies with {n_uavs} (n_uavs={n_uavs}): allowed, its "
            f"actor is per agent, but the results are not those of its own team size",
            UserWarning,
            stacklevel=3,
        )
    own_fusion = trained.get("fusion") or method.shipped.get("fusion")
    if method.fusion is not None and own_fusion and method.fusion != own_fusion:
        warnings.warn(
            f"{what} was trained with fusion {own_fusion!r} but flies with fusion {method.fusion!r}: its actor "
            f"reads fused maps of another kind; pass fusion={own_fusion!r} (or leave it unset) to fly it as trained",
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


def planner_options(policy_or_name: Any, config: Any, planner_kwargs: Mapping[str, Any] | None) -> dict[str, Any]:
    """The options a baseline is built with: ``planner_kwargs`` plus, for AG on a known map family
    without a ``weighting`` of the caller's, the per-map weighting chosen on validation missions."""
    return _planner_options(resolve_method(policy_or_name, planner_kwargs=planner_kwargs), config)


def _planner_options(method: Method, config: Any) -> dict[str, Any]:
    """:func:`planner_options` of a resolved method."""
    options = dict(method.planner_kwargs)
    if method.source == "planner" and method.policy == "ag" and "weighting" not in options:
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


@dataclass(frozen=True)
class Missions:
    """Which missions a method flies: every study describes them with this one type and hands it
    to :func:`fly`, instead of rebuilding the same ten keywords of :func:`evaluate`.

    :param env: map name or gymnasium id
    :param protocol: ``"paper"``, ``"unseen"`` or ``"validation"`` (:data:`PROTOCOLS`): sets
        ``split`` / ``start`` and the default ``count`` and ``seed``; ``None``: the options as given
    :param count: missions; mission ``k`` is env seed ``seed + k`` (default: the protocol's, 10 without)
    :param seed: first env seed (default: the protocol's first seed, else 0)
    :param noise: channel noise preset (``None``: the env's default, or ``options["noise"]``)
    :param n_envs: env copies flown at once (default :data:`EVAL_BATCH`); results are
        reproducible for the same ``seed`` and ``n_envs``
    :param record: how many missions keep their final global belief (mission 0 also per step)
    :param workers: processes flying batches side by side (``"auto"``: every core; ``None``: the
        value set by :func:`parallel_evaluation`, else 1); the result does not depend on it
    :param options: further env options (``split``, ``budget``, ``n_uavs``, ``map_path`` ...)
    """

    env: str = "env3"
    protocol: str | None = None
    count: int | None = None
    seed: int | None = None
    noise: str | None = None
    n_envs: int | None = None
    record: int = 0
    workers: int | str | None = None
    options: Mapping[str, Any] = field(default_factory=dict)

    def env_options(self) -> dict[str, Any]:
        """The env options as given (the protocol's are added by :func:`fly`), numpy scalars as the
        Python numbers they hold (a result records them)."""
        options = {**self.options, **({} if self.noise is None else {"noise": self.noise})}
        return {key: plain(value) for key, value in options.items()}


def fly(method: Method | Any, missions: Missions) -> EvaluationResult:
    """Fly ``method`` (a :class:`Method`, or anything :func:`resolve_method` takes) on ``missions``.

    The one way every study and :func:`evaluate` fly: the method is resolved once (a resolved
    one is trusted as it is), the protocol applied, the batches flown here or on workers.
    """
    method = resolve_method(method)
    protocol, n_trials, seed, env_options = _protocol_options(
        missions.protocol, missions.count, missions.seed, missions.env, missions.env_options()
    )
    n_trials = _check_int("n_trials", n_trials, 1)
    n_envs = EVAL_BATCH if missions.n_envs is None else _check_int("n_envs", missions.n_envs, 1)
    workers = _DEFAULT_WORKERS[0] if missions.workers is None else missions.workers
    n_workers = evaluation_workers(workers, n_trials, n_envs)
    if n_workers > 1 and (method.source != "object" or isinstance(method.policy, COMA)):
        fixed = replace(missions, protocol=protocol, count=n_trials, seed=seed, n_envs=n_envs, workers=1)
        return _fly_on_workers(method, fixed, n_workers)
    return _fly_here(method, missions.env, protocol, n_trials, seed, n_envs, missions.record, env_options)


def _fly_here(
    method: Method,
    env: str,
    protocol: str | None,
    n_trials: int,
    seed: int,
    n_envs: int,
    record: int,
    env_options: dict[str, Any],
) -> EvaluationResult:
    """Fly every batch in this process and label the result with how it flew."""
    _take_observation_options(method, env_options)
    own_fusion = method.trained.get("fusion") or method.shipped.get("fusion")
    flown_fusion = method.fusion or own_fusion or ("sendfuse" if method.learned else "mean")
    deterministic = method.deterministic
    if deterministic is None:
        deterministic = bool(method.shipped.get("deterministic", True))
    flown_kwargs: dict[str, Any] = {}
    result = evaluate_policy(
        _predictor_maker(method, flown_kwargs),
        _env_maker(env, flown_fusion, own_fusion, env_options),
        n_trials,
        seed,
        deterministic=bool(deterministic),
        n_envs=n_envs,
        record=record,
        label=method.label,
    )
    return relabel(
        result,
        env=str(env),
        fusion=flown_fusion,
        env_options=dict(env_options),
        protocol=protocol,
        planner_kwargs=dict(flown_kwargs) if method.source == "planner" else {},
    )


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
        via ``sb3_coma.load_pretrained``); or any object with SB3's ``predict``; or a :class:`Method`
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
    method = resolve_method(policy_or_name, label, planner_kwargs)
    if fusion is not None or deterministic is not None:
        method = replace(
            method,
            fusion=method.fusion if fusion is None else fusion,
            deterministic=method.deterministic if deterministic is None else deterministic,
        )
    missions = Missions(
        env=env, protocol=protocol, count=n_trials, seed=seed, n_envs=n_envs, record=record, workers=workers,
        options=env_options,
    )  # fmt: skip
    return fly(method, missions)


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


def _fly_chunk(job: tuple[Method, Missions]) -> tuple[EvaluationResult, list[tuple[str, type[Warning]]]]:
    """One worker's part of :func:`_fly_on_workers` (a spawned process: one torch thread), with
    the warnings it raised: the caller re-raises them, so its filters and ``pytest.warns`` see what
    one process would have shown."""
    import torch as th

    th.set_num_threads(1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = fly(*job)
    return result, [(str(w.message), w.category) for w in caught]


def _fly_on_workers(method: Method, missions: Missions, n_workers: int) -> EvaluationResult:
    """Fly whole batches of missions in ``n_workers`` spawned processes and merge them in order.

    ``missions`` has its protocol, count, seed and batch size fixed. Every batch is seeded by its
    first mission and gets its own planner, and models predict deterministically, so the merged
    result equals one process's. The resolved method travels as it is (a model file is not
    verified again); a model object travels as a saved file (a process cannot share it).
    """
    assert missions.count is not None and missions.seed is not None and missions.n_envs is not None
    with tempfile.TemporaryDirectory(prefix="sb3-coma-eval-") as tmp:
        saved = Path(tmp) / "model.zip"
        travelling = method
        if method.source == "object":  # a COMA model (fly sends no other object to workers)
            method.policy.save(saved)
            travelling = replace(method, policy=str(saved), source="file", path=saved)
        jobs = [
            (
                travelling,
                replace(missions, seed=missions.seed + start, count=count, record=max(missions.record - start, 0)),
            )
            for start, count in _chunks(missions.count, missions.n_envs, n_workers)
        ]
        try:
            done = list(_pool(len(jobs)).map(_fly_chunk, jobs))
        except BrokenProcessPool:
            _close_pool()
            raise RuntimeError("an evaluation worker process died (out of memory?); rerun with workers=1") from None
    for message, category in dict.fromkeys(w for _, caught in done for w in caught):  # once each, in order
        if travelling is not method:  # name the model the caller gave, not its temporary copy
            message = message.replace(f"model {str(saved)!r}", f"model {method.label!r}")
        warnings.warn(message, category, stacklevel=3)
    return merge_results([result for result, _ in done])


#: The evaluation workers, kept between calls: starting a process and importing torch costs
#: seconds, and a protocol makes dozens of calls. Closed at exit.
_POOL: dict[int, ProcessPoolExecutor] = {}


def _pool(n_workers: int) -> ProcessPoolExecutor:
    if n_workers not in _POOL:
        from uav_ipp.workers import check_main_guard

        check_main_guard(f"evaluate(workers={n_workers})", "spawn")  # one line, not dead workers
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


def _predictor_maker(method: Method, flown_kwargs: dict[str, Any]) -> Callable[[Any, int], Any]:
    """``predictor_for(venv, batch_seed)`` of :func:`evaluate_policy`. At the first batch it fills
    ``flown_kwargs`` with the baseline's options for the flown map and warns once if the model
    flies otherwise than it trained; every batch gets its own predictor."""
    first_batch = [True]

    def predictor_for(venv: Any, batch_seed: int) -> Any:
        if first_batch.pop() if first_batch else False:
            config = venv.get_attr("config", indices=[0])[0]
            flown_kwargs.update(_planner_options(method, config))
            _warn_if_flown_differently(method, config)
        return replace(method, planner_kwargs=flown_kwargs).predictor(venv, batch_seed)

    return predictor_for
