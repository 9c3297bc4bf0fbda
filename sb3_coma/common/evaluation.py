"""Evaluation of a predictor on seeded missions: per-step F1 and entropy (the paper's protocol).

:func:`evaluate_policy` takes objects, like SB3's ``evaluate_policy(model, env)``: a predictor (a
trained model, a planner, anything with SB3's ``predict``, or a factory that builds one on each
evaluation env) and a factory of unseeded vec envs. Turning names and paths into those objects is
the application's job (``sb3_coma.evaluate``, the front door, in :mod:`sb3_coma.app.evaluate`).
Trial ``k`` resets its env copy with seed ``seed + k``, so every method
faces the same maps, start positions and random streams. Metrics are read after the reset
measurement (step 0) and after each of the ``budget`` joint steps, giving arrays of shape
``(n_trials, budget + 1)``; the table reads them at 33 %, 67 % and 100 % of the budget
(steps ``round(f * budget)``: 5, 10, 15 for the default budget) as mean +- std over trials
(population std, ``ddof=0``).

Besides the paper's metrics on the global map (``f1``, ``entropy``), every result carries the
team metrics on each UAV's own local belief M_i, averaged over UAVs (``team_f1``,
``team_entropy``: what the team knows without a ground station), read at the same steps.

Three protocols (``protocol=``, :data:`PROTOCOLS`), one per role of the missions:

* ``"paper"``: the paper's Table I: ``split="paper"`` (the fixed map and start corners), 10
  seeded trials (reporting);
* ``"unseen"``: 50 missions on ``split="test"`` (scenes / stars never trained on, each with one of
  8 flips / rotations) with random starts (reporting only: no choice is made on them);
* ``"validation"``: the missions every choice is made on (checkpoints, seeds, recipes, observation
  versions, AG's weighting): train scenes with env seeds from :data:`VALIDATION_SEED` (apart from
  the training runs' seeds and the reporting protocols' 0..49), random starts, and
  ``mission_from_seed`` so that seed ``s`` flies mission ``s`` of the split: consecutive seeds
  visit every train scene in turn, :data:`MISSIONS_PER_SCENE` times each
  (:func:`validation_missions`).

Either way trial ``k`` uses env seed ``seed + k`` for every method, so two results of one protocol
are shared missions and ``sb3_coma.stats.paired`` compares them mission by mission.

AG's entropy weighting defaults to the one chosen per map family on validation missions
(``sb3_coma.baselines.adaptive_gain.WEIGHTING_BY_MAP``, measured by ``sb3-coma ag-weighting``)
unless ``planner_kwargs`` names one.

Planning time is the wall time of the ``predict`` call of each joint step divided by the
number of UAV decisions it produced (all trials of a batch decide in one call), measured after one
untimed warm-up decision (:func:`warm_up`: JIT compilation and first-call set-up excluded).
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch as th

from sb3_coma.baselines import Planner
from sb3_coma.common.memory import release_freed_memory
from sb3_coma.common.numbers import is_whole
from uav_ipp.maps import TRANSFORMS, split_scenes

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
    first_seed: int = 0
    mission_from_seed: bool = False

    def env_options(self) -> dict[str, Any]:
        options: dict[str, Any] = {"split": self.split}
        if self.start is not None:
            options["start"] = self.start
        if self.mission_from_seed:
            options["mission_from_seed"] = True
        return options

    def missions(self, env: str) -> int:
        """The protocol's default mission count on map ``env`` (validation: every train scene equally)."""
        return validation_missions(env) if self.name == "validation" else self.n_trials


#: First env seed of the validation missions: apart from the reporting protocols' seeds (0..49)
#: and from the seeds training runs reset their copies with (the run's seed plus the copy index).
VALIDATION_SEED = 1000
#: Validation missions per train scene (at least 4, so that no scene's luck decides a choice).
MISSIONS_PER_SCENE = 4


def validation_missions(env: str) -> int:
    """Validation missions of map family ``env``: :data:`MISSIONS_PER_SCENE` per train scene
    (env2: 9 scenes, 36 missions; env3: 12 scenes, 48); env1's stars are all distinct, 48 of them."""
    scenes = split_scenes(env, "train") if env in ("env2", "env3") else ()
    return MISSIONS_PER_SCENE * (len(scenes) or 12)


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
    "validation": Protocol(
        "validation",
        "train",
        "random",
        48,
        "validation missions: split `train`, env seeds from 1000, every train scene in turn (4 missions each), "
        "random starts",
        first_seed=VALIDATION_SEED,
        mission_from_seed=True,
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
    #: one scene label per trial (:func:`scene_label`): missions of one scene are not independent,
    #: so ``sb3_coma.stats.paired`` clusters its standard errors by them (``None``: unknown)
    scenes: tuple[str, ...] | None = None

    def step_of(self, fraction: float) -> int:
        """Step index at a fraction of the budget (0 = the reset measurement)."""
        if not 0.0 <= fraction <= 1.0:
            raise ValueError(f"fraction must be in [0, 1], got {fraction}")
        return round(float(fraction) * self.budget)

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


def scene_label(name: str) -> str:
    """The scene of a mission from its map's name: ``"env3/test/south1/rot90"`` -> ``"env3/test/south1"``.

    A split mission is a scene (a map crop) under one of the 8 flips / rotations of
    ``uav_ipp.maps.scenes.TRANSFORMS``; the missions of one scene share most of what makes a method
    do well or badly, so they are one cluster of the paired statistics. Names without a trailing
    transform (an env1 star ``"env1/test/star2000000007"``, a paper map ``"env3"``, a user map) are
    their own scene.
    """
    head, sep, last = str(name).rpartition("/")
    return head if sep and last in TRANSFORMS else str(name)


def _env_copies(venv: Any) -> list[Any] | None:
    copies = getattr(getattr(venv, "unwrapped", venv), "copies", None)
    return list(copies) if copies is not None else None


def warm_up(predictor: Any, obs: Any, deterministic: bool) -> None:
    """One untimed decision on the first observation, so that planning times exclude JIT
    compilation (numba kernels compiled on first call), oneDNN kernel selection and first-call
    set-up. The predictor's random streams (a planner's ``rng``, torch's generator) are restored
    afterwards, so the missions flown are exactly those flown without the warm-up."""
    rng = getattr(predictor, "rng", None)
    rng_state = rng.bit_generator.state if isinstance(rng, np.random.Generator) else None
    torch_state = th.get_rng_state()
    predictor.predict(obs, episode_start=np.ones(len(obs["action_mask"]), dtype=bool), deterministic=deterministic)
    th.set_rng_state(torch_state)
    if isinstance(rng, np.random.Generator) and rng_state is not None:
        rng.bit_generator.state = rng_state


def _run_batch(
    predictor: Any, venv: Any, seed: int, deterministic: bool, keep_beliefs: int, frames: bool
) -> dict[str, Any]:
    """Fly one mission in every copy of ``venv`` (already seeded with ``seed``) and collect the metrics."""
    n_agents = int(venv.n_agents)
    copies = venv.num_envs // n_agents
    rows = [c * n_agents for c in range(copies)]
    obs = venv.reset()
    # After the reset: split missions (and env1 without a map seed) draw their map there.
    truths = venv.get_attr("ground_truth", indices=rows)
    truth = truths[0]
    warm_up(predictor, obs, deterministic)
    if not deterministic:  # sampled actions: torch's stream starts at the batch's seed, as planners' do
        th.manual_seed(seed)
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
            if (dones != (t == budget)).any():  # one rule: every mission lasts exactly the budget
                raise RuntimeError(
                    f"every mission must last the budget of {budget} steps; at step {t}, {int(dones.sum())} of "
                    f"{len(dones)} rows ended"
                )
            if frames and t < budget:
                belief_frames.append(venv.env_method("global_belief", indices=[0])[0].astype(np.float16))
    finally:
        if snaps is not None:
            snaps.remove()
    seen = [] if snaps is None else [tr for tr in snaps.trajectory if tr is not None]
    if snaps is not None and len(seen) == len(snaps.trajectory):
        trajectories = np.stack(seen)
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
        "scenes": [scene_label(t.name) for t in truths],
        "plan_ms": plan_ms,
        "trajectories": trajectories,
        "final_beliefs": [b for b in final_beliefs if b is not None],
        "belief_frames": np.stack(belief_frames) if frames and len(belief_frames) == budget + 1 else None,
    }


def _check_int(name: str, value: Any, minimum: int) -> int:
    if not is_whole(value) or value < minimum:
        raise ValueError(f"{name}={value!r}: must be an integer >= {minimum}")
    return int(value)


#: Missions flown at once by default: enough to batch the networks' calls, few enough that 50
#: missions with SenDFuse stay within a few hundred MB (each env copy holds ~12 MB of maps).
EVAL_BATCH = 10

#: Builds the predictor for one evaluation env and that batch's first mission seed (planners are
#: rebuilt for every batch; models are built once).
PredictorFactory = Callable[[Any, int], Any]


def _result_of(parts: list[dict[str, Any]], config: Any, label: str, seed: int, record: int) -> EvaluationResult:
    """One :class:`EvaluationResult` from the batches of :func:`evaluate_policy`."""
    finals = [b for p in parts for b in p["final_beliefs"]][:record]
    truth = parts[0]["truth"]
    return EvaluationResult(
        method=label,
        env=str(config.map_name),
        seed=seed,
        n_trials=sum(len(p["returns"]) for p in parts),
        budget=int(config.budget),
        n_agents=int(config.n_uavs),
        fusion="",
        env_options={},
        f1=np.concatenate([p["f1"] for p in parts]),
        entropy=np.concatenate([p["entropy"] for p in parts]),
        team_f1=np.concatenate([p["team_f1"] for p in parts]),
        team_entropy=np.concatenate([p["team_entropy"] for p in parts]),
        returns=np.concatenate([p["returns"] for p in parts]),
        planning_time_ms=np.average(
            np.stack([p["plan_ms"] for p in parts]), axis=0, weights=[len(p["returns"]) for p in parts]
        ),
        trajectories=np.concatenate([p["trajectories"] for p in parts]),
        ground_truth=np.asarray(truth.valuable, dtype=bool),
        no_fly=np.asarray(truth.no_fly, dtype=bool),
        field_size=float(config.field_size),
        altitudes=tuple(float(a) for a in config.altitudes),
        final_beliefs=np.stack(finals) if finals else None,
        belief_frames=parts[0]["belief_frames"],
        scenes=tuple(s for p in parts for s in p["scenes"]),
    )


def evaluate_policy(
    predictor: Any,
    make_env: Callable[[int], Any],
    n_trials: int = DEFAULT_TRIALS,
    seed: int = 0,
    *,
    deterministic: bool = True,
    n_envs: int = EVAL_BATCH,
    record: int = 1,
    label: str = MODEL_LABEL,
) -> EvaluationResult:
    """Fly ``n_trials`` seeded missions with ``predictor`` and return their per-step metrics.

    :param predictor: an object with SB3's ``predict(obs, episode_start=..., deterministic=...)``
        (a model or a planner), or a :data:`PredictorFactory` ``(venv, seed) -> predictor``
    :param make_env: ``make_env(n)`` -> an unseeded vec env of ``n`` copies (``uav_ipp.make_vec_env``
        with the mission's options); it is closed after its batch
    :param n_trials: missions; trial ``k`` uses env seed ``seed + k``
    :param n_envs: env copies flown at once; results are reproducible for the same ``seed`` and ``n_envs``
    :param record: how many trials keep their final global belief (trial 0 also keeps a belief per
        step for the GIF when ``record >= 1``)
    """
    n_trials, seed = _check_int("n_trials", n_trials, 1), _check_int("seed", seed, 0)
    record, n_envs = _check_int("record", record, 0), min(n_trials, _check_int("n_envs", n_envs, 1))
    is_factory = not callable(getattr(predictor, "predict", None))
    flying: Any = None if is_factory else predictor
    parts: list[dict[str, Any]] = []
    config: Any = None
    for start in range(0, n_trials, n_envs):
        venv = make_env(min(n_envs, n_trials - start))
        try:
            config = venv.get_attr("config", indices=[0])[0]
            # Planners are rebuilt for every batch, seeded by its first trial, so a batch's missions do
            # not depend on the batches before it (parallel workers fly the same missions); a model
            # is built once (loading is the expensive part, and it predicts deterministically).
            if flying is None or (is_factory and isinstance(flying, Planner)):
                flying = predictor(venv, seed + start)
            # Seed after building the predictor: loading a model with env=venv re-seeds that env
            # with the model's training seed (SB3's set_random_seed).
            venv.seed(seed + start)
            keep = max(record - start, 0)
            parts.append(_run_batch(flying, venv, seed + start, deterministic, keep, record >= 1 and start == 0))
        finally:
            venv.close()
    release_freed_memory()
    return _result_of(parts, config, label, seed, record)


def _joined(parts: Sequence[np.ndarray | None]) -> np.ndarray | None:
    return None if any(p is None for p in parts) else np.concatenate(parts)  # type: ignore[arg-type]


def merge_results(parts: Sequence[EvaluationResult]) -> EvaluationResult:
    """One result from consecutive chunks of one evaluation (same method and world; chunk ``k+1``
    starts at the seed where chunk ``k`` ends), as flown by one call over all trials: per-trial
    arrays concatenated, planning times averaged by trials, the recorded beliefs and the GIF
    frames of the first chunks. Used to fly the chunks in parallel processes."""
    chunks = [(p.method, p.seed, p.seed + p.n_trials) for p in parts]
    if not chunks or any(q[0] != p[0] or q[1] != p[2] for p, q in itertools.pairwise(chunks)):
        raise ValueError(
            f"merge_results needs one or more consecutive chunks of one method's missions, got (method, first seed, "
            f"end seed) {chunks}"
        )
    first = parts[0]
    beliefs = [p.final_beliefs for p in parts if p.final_beliefs is not None and len(p.final_beliefs)]
    scenes = [p.scenes for p in parts]
    return dataclasses.replace(
        first,
        n_trials=sum(p.n_trials for p in parts),
        f1=np.concatenate([p.f1 for p in parts]),
        entropy=np.concatenate([p.entropy for p in parts]),
        team_f1=_joined([p.team_f1 for p in parts]),
        team_entropy=_joined([p.team_entropy for p in parts]),
        returns=np.concatenate([p.returns for p in parts]),
        planning_time_ms=np.average(
            np.stack([p.planning_time_ms for p in parts]), axis=0, weights=[p.n_trials for p in parts]
        ),
        trajectories=np.concatenate([p.trajectories for p in parts]),
        final_beliefs=np.concatenate(beliefs) if beliefs else None,
        scenes=None if any(s is None for s in scenes) else tuple(x for s in scenes for x in s),  # type: ignore[union-attr]
    )


def relabel(result: EvaluationResult, **changes: Any) -> EvaluationResult:
    """A copy of ``result`` with some fields replaced (the front door's names and options)."""
    return dataclasses.replace(result, **changes)
