"""The paper's evaluation protocol: seeded missions, per-step F1 and entropy, Table I.

``evaluate(policy_or_name, env="env3", n_trials=10, seed=0)`` flies ``n_trials`` missions with a
trained model (object, ``.zip`` path or shipped name) or a baseline (``"random"``,
``"lawnmower"``, ``"ag"``). Trial ``k`` resets its env copy with seed ``seed + k``, so every method
faces the same maps, start positions and random streams. Metrics are read after the reset
measurement (step 0) and after each of the ``budget`` joint steps, giving arrays of shape
``(n_trials, budget + 1)``; the table reads them at 33 %, 67 % and 100 % of the budget
(steps ``round(f * budget)``: 5, 10, 15 for the default budget) as mean +- std over trials
(population std, ``ddof=0``).

Besides the paper's metrics on the global map (``f1``, ``entropy``), every result carries the
team metrics on each UAV's own local belief M_i, averaged over UAVs (``team_f1``,
``team_entropy``: what the team knows without a ground station), read at the same steps.

Two protocols (``protocol=``, :data:`PROTOCOLS`):

* ``"paper"``: the paper's Table I: ``split="paper"`` (the fixed map and start corners), 10
  seeded trials;
* ``"unseen"``: 50 missions on ``split="test"`` (scenes / stars never trained on, each with one of
  8 flips / rotations) with random starts.

Either way trial ``k`` uses env seed ``seed + k`` for every method, so two results of one protocol
are shared missions and ``sb3_coma.paired`` compares them mission by mission.

AG's entropy weighting defaults to the one chosen per map family on validation missions
(``sb3_coma.baselines.adaptive_gain.WEIGHTING_BY_MAP``, measured by ``sb3-coma ag-weighting``)
unless ``planner_kwargs`` names one.

Planning time is the wall time of the ``predict`` call of each joint step divided by the
number of UAV decisions it produced (all trials of a batch decide in one call).
"""

from __future__ import annotations

import csv
import functools
import os
import time
import warnings
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sb3_coma import pretrained
from sb3_coma.checkpoints import training_options
from sb3_coma.memory import release_freed_memory
from sb3_coma.pretrained import shipped_env_options

#: Budget fractions of the paper's Table I and their column labels.
FRACTIONS: tuple[float, ...] = (1 / 3, 2 / 3, 1.0)
FRACTION_LABELS: tuple[str, ...] = ("33%", "67%", "100%")
#: Metric -> (title, whether higher is better).
METRICS: dict[str, tuple[str, bool]] = {"f1": ("F1-Score", True), "entropy": ("Entropy", False)}
#: The same two on each UAV's own local belief M_i, averaged over UAVs (env infos ``team_f1`` ...).
TEAM_METRICS: dict[str, tuple[str, bool]] = {"team_f1": ("team F1", True), "team_entropy": ("team entropy", False)}
ALL_METRICS: dict[str, tuple[str, bool]] = {**METRICS, **TEAM_METRICS}


@dataclass(frozen=True)
class Protocol:
    """An evaluation protocol: which missions (split, start rule) and how many by default
    (``description`` says which missions, not how many)."""

    name: str
    split: str
    start: str | None
    n_trials: int
    description: str

    def env_options(self) -> dict[str, Any]:
        return {"split": self.split, **({} if self.start is None else {"start": self.start})}


#: ``evaluate(..., protocol=NAME)``: the paper's Table I and the unseen missions (module docstring).
PROTOCOLS: dict[str, Protocol] = {
    "paper": Protocol(
        "paper", "paper", None, 10, "the paper's Table I: split `paper` (the fixed map and start corners)"
    ),
    "unseen": Protocol(
        "unseen",
        "test",
        "random",
        50,
        "unseen missions: split `test` (held-out scenes / stars, each in one of 8 flips / rotations), random starts",
    ),
}
#: Missions when neither ``n_trials`` nor a protocol says otherwise (Table I's count).
DEFAULT_TRIALS = 10


def protocol_of(name: str) -> Protocol:
    """The :class:`Protocol` of a name; ``ValueError`` listing the choices otherwise."""
    key = str(name).strip().lower()
    if key not in PROTOCOLS:
        raise ValueError(f"unknown protocol {name!r}; choose one of {sorted(PROTOCOLS)}")
    return PROTOCOLS[key]


#: Label of a trained model in tables when the caller gives none (the paper's "Ours").
MODEL_LABEL = "coma"


# ---------------------------------------------------------------------------------------------
# results
# ---------------------------------------------------------------------------------------------
@dataclass
class EvaluationResult:
    """Per-step metrics of ``n_trials`` seeded missions of one method on one env setting.

    Arrays: ``f1`` and ``entropy`` (n_trials, budget + 1), step 0 = after the reset measurement
    (global map), ``team_f1`` / ``team_entropy`` the same on the UAVs' own M_i (NaN where an env
    does not report them);
    ``returns`` (n_trials,) team return; ``planning_time_ms`` (budget,) mean wall time per UAV
    decision at each step; ``trajectories`` (n_trials, budget + 1, n_agents, 3) positions in
    metres. For the first ``recorded`` trials the final global belief is kept (``final_beliefs``,
    (recorded, grid, grid)) and, for trial 0, the belief after every step (``belief_frames``,
    float16) for the mission GIF.
    """

    method: str
    env: str
    seed: int
    n_trials: int
    budget: int
    n_agents: int
    fusion: str
    env_options: dict[str, Any]
    f1: np.ndarray
    entropy: np.ndarray
    returns: np.ndarray
    planning_time_ms: np.ndarray
    trajectories: np.ndarray
    ground_truth: np.ndarray | None = None
    no_fly: np.ndarray | None = None
    field_size: float = 50.0
    altitudes: tuple[float, ...] = (5.0, 10.0, 15.0)
    final_beliefs: np.ndarray | None = None
    belief_frames: np.ndarray | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    team_f1: np.ndarray | None = None
    team_entropy: np.ndarray | None = None
    #: the protocol the missions came from (``None``: plain ``evaluate`` options)
    protocol: str | None = None
    #: the planner's options (AG: weighting, lookahead) as flown
    planner_kwargs: dict[str, Any] = field(default_factory=dict)

    def step_of(self, fraction: float) -> int:
        """Step index at a fraction of the budget (0 = the reset measurement)."""
        if not 0.0 <= fraction <= 1.0:
            raise ValueError(f"fraction must be in [0, 1], got {fraction}")
        return int(round(fraction * self.budget))

    def metric(self, name: str) -> np.ndarray:
        if name not in ALL_METRICS:
            raise ValueError(f"unknown metric {name!r}; choose one of {sorted(ALL_METRICS)}")
        values = getattr(self, name)
        if values is None:
            return np.full_like(self.f1, np.nan)
        return values

    def at(self, name: str, fraction: float) -> np.ndarray:
        """(n_trials,) values of a metric at a fraction of the budget."""
        return self.metric(name)[:, self.step_of(fraction)]

    def mean_std(self, name: str, fraction: float) -> tuple[float, float]:
        values = self.at(name, fraction)
        return float(values.mean()), float(values.std())

    def summary(self) -> dict[str, float]:
        """Flat dict of Table I's numbers, e.g. ``f1_100_mean`` (and ``team_f1_100_mean`` ...), plus
        return and planning time."""
        out: dict[str, float] = {}
        for name in ALL_METRICS:
            for frac, label in zip(FRACTIONS, FRACTION_LABELS):
                mean, std = self.mean_std(name, frac)
                out[f"{name}_{label[:-1]}_mean"] = mean
                out[f"{name}_{label[:-1]}_std"] = std
        out["return_mean"] = float(self.returns.mean())
        out["return_std"] = float(self.returns.std())
        out["planning_ms_per_decision"] = float(self.planning_time_ms.mean())
        return out

    def __repr__(self) -> str:
        f1, ent = self.mean_std("f1", 1.0), self.mean_std("entropy", 1.0)
        return (
            f"EvaluationResult(method={self.method!r}, env={self.env!r}, n_trials={self.n_trials}, "
            f"f1@100%={f1[0]:.4f}+-{f1[1]:.4f}, entropy@100%={ent[0]:.4f}+-{ent[1]:.4f})"
        )


# ---------------------------------------------------------------------------------------------
# resolving what to evaluate
# ---------------------------------------------------------------------------------------------
def baseline_names() -> list[str]:
    from sb3_coma.baselines import PLANNERS

    return sorted(PLANNERS)


def _is_baseline(name: str) -> bool:
    from sb3_coma.baselines import planner_class

    try:
        planner_class(name)
        return True
    except ValueError:
        return False


def _looks_like_path(name: str) -> bool:
    return name.endswith(".zip") or os.sep in name or "/" in name or name.startswith(".")


def _load_model_file(path: Path, venv: Any) -> Any:
    import pickle

    from sb3_coma import COMA
    from sb3_coma.checkpoints import validate_checkpoint

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
        return not (isinstance(policy_or_name, str) and _is_baseline(policy_or_name))
    from sb3_coma.baselines import Planner

    return not isinstance(policy_or_name, Planner)


def check_policy(policy_or_name: Any) -> None:
    """Fail early, before any env is built, on names and paths that cannot resolve."""
    if _is_shipped_name(policy_or_name) or (isinstance(policy_or_name, str) and _is_baseline(policy_or_name)):
        return
    if isinstance(policy_or_name, (str, os.PathLike)):
        text = os.fspath(policy_or_name)
        if not text.strip():
            raise ValueError("empty method name")
        if Path(text).is_file() or Path(text + ".zip").is_file():
            return
        if isinstance(policy_or_name, os.PathLike) or _looks_like_path(text):
            raise FileNotFoundError(f"model file not found: {text!r}")
        raise ValueError(
            f"unknown method {text!r}: not a baseline ({', '.join(baseline_names())}), not a model file, and not "
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
    from sb3_coma.baselines import Planner, make_planner, planner_class

    check_policy(policy_or_name)
    if isinstance(policy_or_name, str) and _is_baseline(policy_or_name):
        cls = planner_class(policy_or_name)
        return make_planner(cls.name, venv, seed=seed, **dict(planner_kwargs or {})), cls.name
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


# ---------------------------------------------------------------------------------------------
# running missions
# ---------------------------------------------------------------------------------------------
class _FinalSnapshots:
    """Keeps what the env forgets at SuperSuit's auto-reset: the finished mission's final state.

    SuperSuit resets a copy inside the step that ends its mission, so the final global belief and
    the last positions are gone when ``step`` returns. Shadowing ``reset`` on our own env copies
    (built by and private to this evaluation) snapshots them first.
    """

    def __init__(self, copies: Sequence[Any], keep_belief: Sequence[bool]) -> None:
        self.copies = list(copies)
        self.trajectory: list[np.ndarray | None] = [None] * len(self.copies)
        self.belief: list[np.ndarray | None] = [None] * len(self.copies)
        for c, env in enumerate(self.copies):
            env.reset = functools.partial(self._snapshot_then_reset, c, type(env).reset.__get__(env), keep_belief[c])

    def _snapshot_then_reset(
        self, c: int, reset: Callable[..., Any], keep_belief: bool, *args: Any, **kwargs: Any
    ) -> Any:
        env = self.copies[c]
        if self.trajectory[c] is None:
            self.trajectory[c] = env.trajectory()
            if keep_belief:
                self.belief[c] = env.global_belief()
        return reset(*args, **kwargs)

    def remove(self) -> None:
        for env in self.copies:
            env.__dict__.pop("reset", None)


def _env_copies(venv: Any) -> list[Any] | None:
    copies = getattr(getattr(venv, "unwrapped", venv), "copies", None)
    return list(copies) if copies is not None else None


def _run_batch(predictor: Any, venv: Any, deterministic: bool, keep_beliefs: int, frames: bool) -> dict[str, Any]:
    """Fly one mission in every copy of ``venv`` (already seeded) and collect the metrics."""
    n_agents = int(venv.n_agents)
    copies = venv.num_envs // n_agents
    rows = [c * n_agents for c in range(copies)]
    from sb3_coma.baselines import Planner

    obs = venv.reset()
    truth = venv.get_attr("ground_truth", indices=[0])[0]  # now: env1 without map seed redraws at reset
    if isinstance(predictor, Planner):
        predictor.reset()
    start = venv.env_method("metrics", indices=rows)
    budget = int(venv.get_attr("config", indices=[0])[0].budget)
    f1 = np.zeros((copies, budget + 1))
    ent = np.zeros((copies, budget + 1))
    team = {k: np.full((copies, budget + 1), np.nan) for k in TEAM_METRICS}
    f1[:, 0] = [m["f1"] for m in start]
    ent[:, 0] = [m["entropy"] for m in start]
    for k, arr in team.items():
        arr[:, 0] = [m.get(k, np.nan) for m in start]
    returns = np.zeros(copies)
    plan_ms = np.zeros(budget)
    env_copies = _env_copies(venv)
    snaps = _FinalSnapshots(env_copies, [c < keep_beliefs for c in range(copies)]) if env_copies else None
    belief_frames = [venv.env_method("global_belief", indices=[0])[0].astype(np.float16)] if frames else []
    episode_start = np.ones(venv.num_envs, dtype=bool)
    try:
        for t in range(1, budget + 1):
            tic = time.perf_counter()
            actions, _ = predictor.predict(obs, episode_start=episode_start, deterministic=deterministic)
            plan_ms[t - 1] = (time.perf_counter() - tic) * 1e3 / venv.num_envs
            episode_start[:] = False
            obs, rewards, dones, infos = venv.step(np.asarray(actions).reshape(-1))
            returns += rewards[rows]
            f1[:, t] = [infos[r]["f1"] for r in rows]
            ent[:, t] = [infos[r]["entropy"] for r in rows]
            for k, arr in team.items():
                arr[:, t] = [infos[r].get(k, np.nan) for r in rows]
            if t < budget:
                if dones.any():
                    raise RuntimeError(f"a mission ended after {t} of {budget} steps")
                if frames:
                    belief_frames.append(venv.env_method("global_belief", indices=[0])[0].astype(np.float16))
        if not dones.all():
            raise RuntimeError(f"missions did not end after the budget of {budget} steps")
    finally:
        if snaps is not None:
            snaps.remove()
    if snaps is not None and all(tr is not None for tr in snaps.trajectory):
        trajectories = np.stack(snaps.trajectory)
        final_beliefs = [b for b in snaps.belief[:keep_beliefs]]
    else:  # an env without our copies: the last positions are unknown, keep what was seen
        trajectories = np.full((copies, budget + 1, n_agents, 3), np.nan)
        final_beliefs = []
    if frames and final_beliefs and final_beliefs[0] is not None:
        belief_frames.append(final_beliefs[0].astype(np.float16))
    return {
        "f1": f1,
        "entropy": ent,
        **team,
        "returns": returns,
        "truth": truth,
        "plan_ms": plan_ms,
        "trajectories": trajectories,
        "final_beliefs": [b for b in final_beliefs if b is not None],
        "belief_frames": np.stack(belief_frames) if frames and len(belief_frames) == budget + 1 else None,
    }


def _check_int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"{name}={value!r}: must be an integer >= {minimum}")
    return int(value)


#: Missions flown at once by default: enough to batch the networks' calls, few enough that 50
#: missions with SenDFuse stay within a few hundred MB (each env copy holds ~12 MB of maps).
EVAL_BATCH = 10


#: Env options that shape a model's observation: ``evaluate`` takes them from the model's training
#: options unless the caller sets them. The mission (map, split, start, noise, team size) stays the
#: caller's choice.
OBSERVATION_OPTIONS = ("action_gain", "comm_grid", "lattice", "grid", "altitudes", "field_size", "fov_deg")


def _trained_options(policy_or_name: Any, shipped: dict[str, Any]) -> dict[str, Any]:
    """The env options a model was trained with (``sb3_coma.training_options``); ``{}`` for
    baselines and for models that do not record them."""
    if not is_model(policy_or_name):
        return {}
    if isinstance(policy_or_name, str) and not policy_or_name.endswith(".zip") and shipped:
        return shipped_env_options(policy_or_name) or {}
    return training_options(policy_or_name) or {}


def _warn_if_flown_differently(
    policy_or_name: Any, trained: dict[str, Any], shipped: dict[str, Any], fusion: str | None, n_uavs: int
) -> None:
    """Warn (not refuse) when a model flies with another team size or fusion than it trained with.

    Both are legal (the actor is per agent and the fusions take any number of maps, see
    docs/deployment.md), but the results then describe another method than the model's own,
    which is easy to do by accident with ``--uavs`` or ``--fusion``. ``fusion`` is the caller's
    (``None``: the model's own is used, nothing to warn about).
    """
    if not is_model(policy_or_name):
        return
    what = f"model {os.fspath(policy_or_name)!r}" if isinstance(policy_or_name, (str, os.PathLike)) else "the model"
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


def _shipped_info(policy_or_name: Any) -> dict[str, Any]:
    """Manifest entry of a shipped model (by name or loaded object); empty for anything else."""
    info = getattr(policy_or_name, "pretrained_info", None)
    if isinstance(info, dict):
        return info
    if isinstance(policy_or_name, str) and not policy_or_name.endswith(".zip"):
        try:
            from sb3_coma.pretrained import model_info

            return model_info(policy_or_name)
        except (ImportError, ValueError, KeyError, OSError):
            return {}
    return {}


def _is_ag(policy_or_name: Any) -> bool:
    if not isinstance(policy_or_name, str) or not _is_baseline(policy_or_name):
        return False
    from sb3_coma.baselines import planner_class

    return planner_class(policy_or_name).name == "ag"


def planner_options(policy_or_name: Any, config: Any, planner_kwargs: Mapping[str, Any] | None) -> dict[str, Any]:
    """The options a baseline is built with: ``planner_kwargs`` plus, for AG on a known map family
    without a ``weighting`` of the caller's, the per-map weighting chosen on validation missions."""
    options = dict(planner_kwargs or {})
    if _is_ag(policy_or_name) and "weighting" not in options:
        from sb3_coma.baselines.adaptive_gain import default_weighting

        options["weighting"] = default_weighting(None if getattr(config, "map_path", None) else config.map_name)
    return options


def _protocol_options(
    protocol: str | None, n_trials: int | None, env_options: dict[str, Any]
) -> tuple[str | None, int, dict[str, Any]]:
    """(protocol name, missions, env options) after applying a protocol's rules."""
    if protocol is None:
        return None, DEFAULT_TRIALS if n_trials is None else n_trials, env_options
    proto = protocol_of(protocol)
    fixed = proto.env_options()
    for key, value in fixed.items():
        if key in env_options and env_options[key] != value:
            raise ValueError(
                f"protocol {proto.name!r} flies {key}={value!r}; got {key}={env_options[key]!r} "
                f"(drop protocol= to choose the missions yourself)"
            )
    return proto.name, proto.n_trials if n_trials is None else n_trials, {**env_options, **fixed}


def evaluate(
    policy_or_name: Any,
    env: str = "env3",
    n_trials: int | None = None,
    seed: int = 0,
    fusion: str | None = None,
    deterministic: bool | None = None,
    n_envs: int | None = None,
    record: int = 1,
    label: str | None = None,
    planner_kwargs: Mapping[str, Any] | None = None,
    protocol: str | None = None,
    **env_options: Any,
) -> EvaluationResult:
    """Run a trained model or a baseline for ``n_trials`` seeded missions (see module docstring).

    :param policy_or_name: ``"random"``, ``"lawnmower"``, ``"ag"`` (or ``"nl"``); a COMA model
        object, a path to a saved ``.zip``, or a shipped model name (``"env1"`` ...,
        via ``sb3_coma.load_pretrained``); or any object with SB3's ``predict``
    :param env: map name or gymnasium id
    :param n_trials: missions; trial ``k`` uses env seed ``seed + k`` (default: the protocol's
        count, 10 without a protocol)
    :param seed: base seed (env and the planner's own random stream)
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
    :param protocol: ``"paper"`` or ``"unseen"`` (:data:`PROTOCOLS`): sets ``split`` / ``start`` and
        the default ``n_trials``; ``None``: the env options as given
    :param env_options: environment options (``noise``, ``n_uavs``, ``budget``, ``map_path``,
        ``valuable``, ...)
    """
    import envs

    protocol, n_trials, env_options = _protocol_options(protocol, n_trials, dict(env_options))
    n_trials = _check_int("n_trials", n_trials, 1)
    seed = _check_int("seed", seed, 0)
    record = _check_int("record", record, 0)
    n_envs = min(n_trials, EVAL_BATCH if n_envs is None else _check_int("n_envs", n_envs, 1))
    check_policy(policy_or_name)
    shipped = _shipped_info(policy_or_name)
    trained = _trained_options(policy_or_name, shipped)
    for key in OBSERVATION_OPTIONS:  # what the network's inputs are made of follows the model
        if key in trained and key not in env_options:
            env_options[key] = trained[key]
    asked_fusion = fusion
    if fusion is None:
        fusion = trained.get("fusion") or shipped.get("fusion") or ("sendfuse" if is_model(policy_or_name) else "mean")
    if deterministic is None:
        deterministic = bool(shipped.get("deterministic", True))
    predictor: Any = None
    name = label
    parts: list[dict[str, Any]] = []
    venv = None
    first_truth: Any = None
    config: Any = None
    flown_kwargs: dict[str, Any] = dict(planner_kwargs or {})
    for start in range(0, n_trials, n_envs):
        size = min(n_envs, n_trials - start)
        try:
            venv = envs.make_vec_env(env, n_envs=size, fusion=fusion, seed=None, **env_options)
        except ValueError as exc:
            if fusion == "sendfuse" and "sendfuse" in str(exc):
                raise ValueError(f"{exc}; evaluate a model trained without SenDFuse with fusion='mean'") from exc
            raise
        if config is None:
            config = venv.get_attr("config", indices=[0])[0]
            flown_kwargs = planner_options(policy_or_name, config, planner_kwargs)
            _warn_if_flown_differently(policy_or_name, trained, shipped, asked_fusion, int(config.n_uavs))
        if predictor is None or getattr(predictor, "uses_env_state", False):
            predictor, default_label = resolve_policy(policy_or_name, venv, seed + start, flown_kwargs)
            name = name or default_label
        # Seed after loading: loading a model with env=venv re-seeds that env with the model's
        # training seed (SB3's set_random_seed), which would replace these missions' seeds.
        venv.seed(seed + start)
        parts.append(_run_batch(predictor, venv, deterministic, max(record - start, 0), record >= 1 and start == 0))
        if first_truth is None:
            first_truth = parts[0]["truth"]
        venv.close()
    release_freed_memory()
    finals = [b for p in parts for b in p["final_beliefs"]][:record]
    return EvaluationResult(
        method=str(name),
        env=str(env),
        seed=seed,
        n_trials=n_trials,
        budget=int(config.budget),
        n_agents=int(config.n_uavs),
        fusion=fusion,
        env_options=dict(env_options),
        f1=np.concatenate([p["f1"] for p in parts]),
        entropy=np.concatenate([p["entropy"] for p in parts]),
        team_f1=np.concatenate([p["team_f1"] for p in parts]),
        team_entropy=np.concatenate([p["team_entropy"] for p in parts]),
        protocol=protocol,
        planner_kwargs=flown_kwargs if isinstance(policy_or_name, str) and _is_baseline(policy_or_name) else {},
        returns=np.concatenate([p["returns"] for p in parts]),
        planning_time_ms=np.average(
            np.stack([p["plan_ms"] for p in parts]), axis=0, weights=[len(p["returns"]) for p in parts]
        ),
        trajectories=np.concatenate([p["trajectories"] for p in parts]),
        ground_truth=np.asarray(first_truth.valuable, dtype=bool),
        no_fly=np.asarray(first_truth.no_fly, dtype=bool),
        field_size=float(config.field_size),
        altitudes=tuple(float(a) for a in config.altitudes),
        final_beliefs=np.stack(finals) if finals else None,
        belief_frames=parts[0]["belief_frames"],
    )


# ---------------------------------------------------------------------------------------------
# Table I
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TableRow:
    """One line of a Table-I style table: a group (env or noise level), a method and its result."""

    group: str
    method: str
    result: EvaluationResult


#: Which metrics a table shows: the paper's (global map) or the team's (the UAVs' own M_i).
METRIC_FAMILIES: dict[str, tuple[str, ...]] = {"global": tuple(METRICS), "team": tuple(TEAM_METRICS)}


def _metric_names(metrics: Sequence[str] | str) -> tuple[str, ...]:
    names = (
        METRIC_FAMILIES[metrics]
        if isinstance(metrics, str) and metrics in METRIC_FAMILIES
        else tuple([metrics] if isinstance(metrics, str) else metrics)
    )
    unknown = [m for m in names if m not in ALL_METRICS]
    if unknown or not names:
        raise ValueError(
            f"unknown metrics {unknown or names}; choose from {sorted(ALL_METRICS)} or {sorted(METRIC_FAMILIES)}"
        )
    return names


def _cell_values(result: EvaluationResult, metrics: Sequence[str] = tuple(METRICS)) -> list[tuple[float, float]]:
    return [result.mean_std(name, frac) for name in metrics for frac in FRACTIONS]


def _best_flags(rows: Sequence[TableRow], digits: int, metrics: Sequence[str] = tuple(METRICS)) -> list[list[bool]]:
    """Per row and column, whether the mean is the best of its group (ties share the bold)."""
    flags = [[False] * (len(metrics) * len(FRACTIONS)) for _ in rows]
    higher = [ALL_METRICS[name][1] for name in metrics for _ in FRACTIONS]
    groups: dict[str, list[int]] = {}
    for i, row in enumerate(rows):
        groups.setdefault(row.group, []).append(i)
    values = [_cell_values(r.result, metrics) for r in rows]
    for members in groups.values():
        if len(members) < 2:
            continue
        for col, up in enumerate(higher):
            means = [round(values[i][col][0], digits) for i in members]
            best = max(means) if up else min(means)
            for i, m in zip(members, means):
                flags[i][col] = m == best
    return flags


def table_markdown(
    rows: Sequence[TableRow], group_title: str = "Env", digits: int = 4, metrics: Sequence[str] | str = "global"
) -> str:
    """The paper's Table I as Markdown: mean +- std, best mean of each group in bold.

    :param metrics: ``"global"`` (the paper's F1 / entropy of the global map), ``"team"``
        (``team_f1`` / ``team_entropy``) or a list of metric names"""
    metrics = _metric_names(metrics)
    head = [group_title, "Method"] + [
        f"{ALL_METRICS[n][0]} {'↑' if ALL_METRICS[n][1] else '↓'} {lab}" for n in metrics for lab in FRACTION_LABELS
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join([" --- "] * 2 + [" ---: "] * (len(head) - 2)) + "|"]
    flags = _best_flags(rows, digits, metrics)
    previous = None
    for row, bold in zip(rows, flags):
        cells = []
        for (mean, std), b in zip(_cell_values(row.result, metrics), bold):
            m = f"{mean:.{digits}f}"
            cells.append(f"**{m}** ± {std:.{digits}f}" if b else f"{m} ± {std:.{digits}f}")
        group = row.group if row.group != previous else ""
        previous = row.group
        lines.append("| " + " | ".join([group, row.method] + cells) + " |")
    return "\n".join(lines) + "\n"


def table_text(
    rows: Sequence[TableRow], group_title: str = "Env", digits: int = 4, metrics: Sequence[str] | str = "global"
) -> str:
    """Plain-text Table I for terminals: the best mean of each group marked with ``*``."""
    metrics = _metric_names(metrics)
    head = [group_title, "Method"] + [f"{n} {lab}" for n in metrics for lab in FRACTION_LABELS]
    flags = _best_flags(rows, digits, metrics)
    body = []
    for row, bold in zip(rows, flags):
        cells = [
            f"{'*' if b else ' '}{mean:.{digits}f}±{std:.{digits}f}"
            for (mean, std), b in zip(_cell_values(row.result, metrics), bold)
        ]
        body.append([row.group, row.method] + cells)
    widths = [max(len(str(r[i])) for r in [head] + body) for i in range(len(head))]

    def fmt(r: list[str]) -> str:
        return "  ".join(str(c).ljust(w) if i < 2 else str(c).rjust(w) for i, (c, w) in enumerate(zip(r, widths)))

    return "\n".join([fmt(head), "  ".join("-" * w for w in widths)] + [fmt(r) for r in body]) + "\n"


def table_columns(metrics: Sequence[str] | str = "global") -> list[str]:
    return [
        f"{name}_{lab[:-1]}_{stat}"
        for name in _metric_names(metrics)
        for lab in FRACTION_LABELS
        for stat in ("mean", "std")
    ]


def write_table_csv(
    rows: Sequence[TableRow], path: str | os.PathLike, group_title: str = "env", metrics: Sequence[str] | str = "global"
) -> Path:
    """Wide CSV of Table I: one line per (group, method), ``f1_33_mean, f1_33_std, ...``
    (``metrics="team"`` or a list: other metric columns; ``"all"``-style lists work too)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    columns = table_columns(metrics)
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(
            [group_title, "method", "n_trials", "budget"]
            + columns
            + ["return_mean", "return_std", "planning_ms_per_decision"]
        )
        for row in rows:
            s = row.result.summary()
            writer.writerow(
                [row.group, row.method, row.result.n_trials, row.result.budget]
                + [f"{s[c]:.6f}" for c in columns]
                + [f"{s['return_mean']:.6f}", f"{s['return_std']:.6f}", f"{s['planning_ms_per_decision']:.6f}"]
            )
    return path


def write_per_step_csv(rows: Sequence[TableRow], path: str | os.PathLike, group_title: str = "env") -> Path:
    """Long CSV of the curves behind the plots: mean and std of both metrics at every step."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow([group_title, "method", "step"] + [f"{m}_{s}" for m in ALL_METRICS for s in ("mean", "std")])
        for row in rows:
            r = row.result
            for t in range(r.budget + 1):
                writer.writerow(
                    [row.group, row.method, t]
                    + [f"{v:.6f}" for m in ALL_METRICS for v in (r.metric(m)[:, t].mean(), r.metric(m)[:, t].std())]
                )
    return path


def planning_time_markdown(rows: Sequence[TableRow]) -> str:
    """Per-method planning time: mean and worst step, ms per UAV decision."""
    lines = ["| Env | Method | ms per UAV decision (mean) | slowest step (ms) |", "| --- | --- | ---: | ---: |"]
    for row in rows:
        t = row.result.planning_time_ms
        lines.append(f"| {row.group} | {row.method} | {t.mean():.4f} | {t.max():.4f} |")
    return "\n".join(lines) + "\n"


def write_planning_time_csv(rows: Sequence[TableRow], path: str | os.PathLike) -> Path:
    """Per-step planning time of each method (ms per UAV decision)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    budget = max(r.result.budget for r in rows) if rows else 0
    with path.open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["env", "method", "mean_ms"] + [f"step_{t}" for t in range(1, budget + 1)])
        for row in rows:
            t = row.result.planning_time_ms
            writer.writerow([row.group, row.method, f"{t.mean():.6f}"] + [f"{v:.6f}" for v in t])
    return path


def rows_for(
    results: Iterable[EvaluationResult], group: Callable[[EvaluationResult], str] | None = None
) -> list[TableRow]:
    """Table rows grouped by env (or by ``group(result)``), in the given order."""
    return [TableRow(group(r) if group else r.env, r.method, r) for r in results]
