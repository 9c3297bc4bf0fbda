"""COMA next to IPPO, MAPPO and random on third-party cooperative envs, through the route any SB3
user takes (``make_marl_vec_env`` over a PettingZoo ``ParallelEnv``).

Phases (each resumable: a finished run's record is kept and skipped, every file is written to a
temporary name and moved into place):

* ``train``: every (task, learner, seed) for the same number of **joint** env steps (one step of
  every agent of one env copy; SB3's PPO counts agent steps, so it gets ``n_agents`` times more of
  its own), 3 seeds; the training curve is the team return (the agents' rewards summed over an
  episode) of the episodes finished so far; the final score is the mean team return of 100
  evaluation episodes (seeds of their own) with the final policy's most likely actions;
* ``speed``: joint steps per second of ``learn()`` for COMA and SB3's PPO on ``simple_spread`` with
  the same ``n_envs``, interleaved, and ``import sb3_coma`` against ``import stable_baselines3``,
  in the same run (ratios compare across machines; seconds do not);
* ``report``: ``results.md`` (table of final returns: mean and standard deviation over seeds) and
  ``curves.png`` in ``--out``.

``python -m sb3_coma.experiments.marl_benchmark --out docs/marl_benchmark`` runs all three.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import pickle
import subprocess
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from sb3_coma.app.marl_tasks import BENCHMARK_JOINT_STEPS, NAMED_TASKS
from sb3_coma.common.checkpoints import atomic_write, atomic_write_text, write_between_markers

LEARNERS = ("coma", "mappo", "ippo", "random")
#: The learned ones: each has its settings per task in ``zoo_configs/marl/<learner>.yml``.
TRAINED = LEARNERS[:3]
N_ENVS = 8
EVAL_EPISODES = 100
EVAL_SEED = 100_000
#: Points of a record's training curve.
CURVE_POINTS = 100
#: Where the learners' configs live below ``zoo_configs/`` (a checkout's, else the installed copy).
CONFIGS = "marl"


@dataclass(frozen=True)
class Task:
    """A cooperative env and how long each learner trains on it (joint steps).

    ``key`` names it in file names and ``--tasks``; ``name`` is the env's own id, as the tables
    show it; ``maker`` builds a fresh PettingZoo ``ParallelEnv`` (module-level, so a worker
    process can build it from the key alone)."""

    key: str
    name: str
    joint_steps: int
    maker: Callable[[], Any]

    def make(self) -> Any:
        """A fresh PettingZoo ``ParallelEnv`` of this task."""
        return self.maker()


#: The benchmark's tasks (their envs: ``sb3_coma.app.marl_tasks.NAMED_TASKS``, the ids the zoo trains);
#: each learner's settings for them are in ``zoo_configs/marl/<learner>.yml``.
TASKS = {
    key: Task(key, name, BENCHMARK_JOINT_STEPS[name], NAMED_TASKS[name])
    for key, name in (
        ("simple_spread", "simple_spread"),
        ("simple_reference", "simple_reference"),
        ("lbf", "Foraging-5x5-2p-1f-coop-v3"),
        ("lbf_8x8", "Foraging-8x8-2p-2f-coop-v3"),
        ("rware_tiny", "rware-tiny-2ag-v2"),
    )
}


class TeamReturns(VecEnvWrapper):
    """Records every finished episode's team return (rewards of all agents of a copy, summed)
    against the joint steps taken so far."""

    def __init__(self, venv: VecEnv, n_agents: int) -> None:
        super().__init__(venv)
        self.n_agents = n_agents
        self.copies = venv.num_envs // n_agents
        self.running = np.zeros(self.copies)
        self.joint_steps = 0
        self.episodes: list[tuple[int, float]] = []

    def reset(self) -> Any:
        self.running[:] = 0.0
        return self.venv.reset()

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        self.joint_steps += self.copies
        self.running += np.asarray(rewards, dtype=np.float64).reshape(self.copies, self.n_agents).sum(1)
        for copy in np.flatnonzero(np.asarray(dones).reshape(self.copies, self.n_agents)[:, 0]):
            self.episodes.append((self.joint_steps, float(self.running[copy])))
            self.running[copy] = 0.0
        return obs, rewards, dones, infos


def _vec_env(
    task: Task, seed: int, learner: str, normalize: dict[str, Any] | None = None
) -> tuple[VecEnv, TeamReturns]:
    """The task's vec env for ``learner`` and the recorder inside it (which sees the env's own
    rewards), under SB3's ``VecNormalize(**normalize)`` when an entry asks for it."""
    from stable_baselines3.common.vec_env import VecNormalize

    from sb3_coma import make_marl_vec_env
    from sb3_coma.mappo.central_value import CentralStateVecEnv

    base = make_marl_vec_env(task.make, n_envs=N_ENVS, seed=seed)
    recorder = TeamReturns(base, base.n_agents)  # type: ignore[attr-defined]
    venv: VecEnv = CentralStateVecEnv(recorder) if learner == "mappo" else recorder
    return (venv if normalize is None else VecNormalize(venv, **normalize)), recorder


def split_normalize(settings: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """An entry's constructor arguments and, apart, ``VecNormalize``'s keyword arguments from its
    ``normalize`` key (``None``: no normaliser), read by rl-zoo3's own ``_preprocess_normalization``
    (``true``, a dict, or a Python string such as ``"dict(norm_obs=False, norm_reward=True)"``; the
    entry's ``gamma`` is the normaliser's), so that an entry trains the same here as through the zoo."""
    from copy import deepcopy
    from types import SimpleNamespace

    from rl_zoo3.exp_manager import ExperimentManager

    reader = SimpleNamespace(normalize=False, normalize_kwargs={})  # ExperimentManager's initial state
    constructor = ExperimentManager._preprocess_normalization(reader, deepcopy(settings))  # type: ignore[arg-type]
    return constructor, (dict(reader.normalize_kwargs) if reader.normalize else None)


def learner_settings(learner: str, task: Task) -> dict[str, Any]:
    """``learner``'s constructor arguments for ``task``: its entry in ``zoo_configs/marl/<learner>.yml``
    (rl-zoo's layout: one file per algorithm, one entry per env id), ``policy`` included."""
    from sb3_coma.app.config import default_config_path, read_config_file

    path = default_config_path(f"{CONFIGS}/{learner}.yml")
    entries = read_config_file(path)
    if task.name not in entries:
        raise ValueError(f"{path} has no entry {task.name!r}; it has {sorted(entries)}")
    return dict(entries[task.name])


def _trainee(
    learner: str, task: Task, seed: int, settings: dict[str, Any] | None = None
) -> tuple[Any, VecEnv, TeamReturns]:
    """``learner``'s model on a fresh vec env of ``task``, with its benchmark entry or with ``settings``
    (an entry's keys: a study's variant) instead; and that env and its recorder."""
    constructor, normalize = split_normalize(learner_settings(learner, task) if settings is None else settings)
    venv, recorder = _vec_env(task, seed, learner, normalize)
    return _model(learner, venv, seed, constructor), venv, recorder


def _model(learner: str, venv: VecEnv, seed: int, settings: dict[str, Any]) -> Any:
    """``learner``'s model with ``settings`` (constructor arguments, policy included)."""
    from stable_baselines3 import PPO

    from sb3_coma import COMA
    from sb3_coma.app.zoo_marl import preprocess_schedules
    from sb3_coma.common.logger import use_folderless_logger
    from sb3_coma.mappo.central_value import CentralValuePolicy

    settings = preprocess_schedules(dict(settings))  # "lin_<x>" as the zoo reads it
    policy = settings.pop("policy")
    if learner == "coma":
        return COMA(policy, venv, seed=seed, device="cpu", **settings)
    ppo = PPO(
        CentralValuePolicy if policy == "CentralValuePolicy" else policy, venv, seed=seed, device="cpu", **settings
    )
    return use_folderless_logger(ppo)  # no SB3-<timestamp> folder in the temp dir


def _act(model: Any) -> Callable[[Any, VecEnv], np.ndarray]:
    if model is None:
        return lambda obs, venv: np.array([venv.action_space.sample() for _ in range(venv.num_envs)])
    return lambda obs, venv: model.predict(obs, deterministic=True)[0]


def evaluate_team_return(
    task: Task, learner: str, model: Any, episodes: int = EVAL_EPISODES, seed: int = EVAL_SEED
) -> list[float]:
    """Team returns of ``episodes`` evaluation episodes (env seeds from ``seed``: the benchmark's
    reported ones by default, a study's validation ones otherwise)."""
    venv, recorder = _vec_env(task, seed, learner)
    normalizer = None if model is None else model.get_vec_normalize_env()
    if normalizer is not None:  # the trained observation statistics, frozen; rewards as the env gives them
        frozen = pickle.loads(pickle.dumps(normalizer))  # VecNormalize pickles without its env (SB3's save)
        frozen.set_venv(venv)
        frozen.training, frozen.norm_reward = False, False
        venv = frozen
    venv.action_space.seed(seed)
    act = _act(model)
    obs = venv.reset()
    while len(recorder.episodes) < episodes:
        obs, *_ = venv.step(act(obs, venv))
    venv.close()
    return [ret for _, ret in recorder.episodes[:episodes]]


def _joint_to_learn(learner: str, task: Task, n_agents: int) -> int:
    """``learn()``'s argument for ``task.joint_steps`` joint steps (PPO counts agent steps)."""
    return task.joint_steps * (n_agents if learner in ("ippo", "mappo") else 1)


def run_one(task: Task, learner: str, seed: int, episodes: int = EVAL_EPISODES) -> dict[str, Any]:
    """Train one (task, learner, seed) and evaluate it; the record of :func:`main`'s table (a few
    kB: the training curve is kept as the mean of the last 100 episodes at :data:`CURVE_POINTS`
    points, not episode by episode)."""
    import torch as th

    th.set_num_threads(1)
    start = time.perf_counter()
    model = None
    curve: list[tuple[float, float]] = []
    late = None
    if learner != "random":
        model, venv, recorder = _trainee(learner, task, seed)
        model.learn(_joint_to_learn(learner, task, recorder.n_agents))
        grid = np.linspace(task.joint_steps / CURVE_POINTS, task.joint_steps, CURVE_POINTS)
        curve = [(float(x), float(y)) for x, y in zip(grid, _smoothed(recorder.episodes, grid))]
        late = float(np.mean([ret for _, ret in recorder.episodes[-100:]])) if recorder.episodes else None
        venv.close()
    returns = evaluate_team_return(task, learner, model, episodes)
    return {
        "task": task.name,
        "learner": learner,
        "seed": seed,
        "joint_steps": task.joint_steps if model is not None else 0,
        "settings": _recorded_settings(learner, task),
        "final_return": float(np.mean(returns)),
        "episode_returns": [round(r, 4) for r in returns],
        "late_training_return": late,
        "curve": curve,
        "seconds": time.perf_counter() - start,
    }


def _job(args: tuple[Task, str, int, int, str]) -> str:
    task, learner, seed, episodes, folder = args
    target = Path(folder) / f"{task.key}-{learner}-{seed}.json"
    atomic_write_text(target, json.dumps(run_one(task, learner, seed, episodes)))
    return target.name


def train_phase(
    out: Path,
    tasks: list[Task],
    seeds: list[int],
    workers: int,
    episodes: int = EVAL_EPISODES,
    learners: tuple[str, ...] = LEARNERS,
) -> None:
    """Every missing (task, learner, seed) record of ``learners``, ``workers`` at a time. A record
    already there is kept only if it was trained for this run's joint steps and evaluated on as
    many episodes (a ``--quick`` record never passes for a real one, nor the other way round)."""
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    check_kept_records(runs, tasks, episodes)
    todo = [
        (task, learner, seed, episodes, str(runs))
        for task in tasks
        for seed in seeds
        for learner in learners
        if (learner != "random" or seed == seeds[0]) and not (runs / f"{task.key}-{learner}-{seed}.json").exists()
    ]
    print(f"train: {len(todo)} runs to do", flush=True)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for name in pool.map(_job, todo):
            print(f"  done {name}", flush=True)


class RecordMismatch(ValueError):
    """A kept record of ``--out`` was made for another budget or evaluation than this run's."""


def _recorded_settings(learner: str, task: Task) -> dict[str, Any]:
    """What a record keeps of its learner's settings (``{}`` for random): a kept record is reused
    only while its config entry is unchanged."""
    return {} if learner == "random" else learner_settings(learner, task)


def check_kept_records(runs: Path, tasks: list[Task], episodes: int) -> None:
    """Refuse (one line naming the file) a record of these tasks made for other joint steps,
    another number of evaluation episodes or other settings than this run's config gives:
    resuming must not mix them."""
    for task in tasks:
        for path in sorted(runs.glob(f"{task.key}-*.json")):
            record = json.loads(path.read_text())
            wanted = _recorded_settings(record["learner"], task)
            if record.get("settings") != wanted:
                raise RecordMismatch(
                    f"{path} was trained with settings {record.get('settings')}, the config now gives {wanted}: "
                    "move that record away to retrain it, or restore the config it was made with"
                )
            steps = 0 if record["learner"] == "random" else task.joint_steps
            if record["joint_steps"] != steps or len(record["episode_returns"]) != episodes:
                raise RecordMismatch(
                    f"{path} holds a run of {record['joint_steps']:,} joint steps and "
                    f"{len(record['episode_returns'])} evaluation episodes, this run asks {steps:,} and {episodes}: "
                    "pass another --out (or --quick as that folder was made)"
                )


def _learn_rate(learner: str, task: Task) -> float:
    """Joint steps per second of ``learn()`` for ``task.joint_steps`` joint steps (seed 0)."""
    import torch as th

    th.set_num_threads(1)
    model, venv, recorder = _trainee(learner, task, 0)
    start = time.perf_counter()
    model.learn(_joint_to_learn(learner, task, recorder.n_agents))
    seconds = time.perf_counter() - start
    venv.close()
    return task.joint_steps / seconds


def _import_seconds(module: str) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", f"import {module}"], check=True)
    return time.perf_counter() - start


def speed_phase(out: Path, tasks: list[Task], joint_steps: int = 10_240, repeats: int = 3) -> dict[str, Any]:
    """Per task, COMA (its benchmark settings) against SB3's PPO (IPPO's settings) in ``learn()``
    joint steps/s, same ``n_envs``, interleaved, medians of ``repeats``; and ``import sb3_coma``
    against ``import stable_baselines3`` (process wall time). Ratios compare across machines."""
    speed: dict[str, Any] = {"joint_steps": joint_steps, "repeats": repeats, "tasks": {}}
    for task in tasks:
        short = dataclasses.replace(task, joint_steps=joint_steps)
        rates: dict[str, list[float]] = {"coma": [], "ippo": []}
        for _ in range(repeats):
            for learner in rates:
                rates[learner].append(_learn_rate(learner, short))
        coma, ppo = float(np.median(rates["coma"])), float(np.median(rates["ippo"]))
        speed["tasks"][task.name] = {"coma_joint_steps_per_s": coma, "ppo_joint_steps_per_s": ppo, "ratio": coma / ppo}
    imports = {
        module: float(np.median([_import_seconds(module) for _ in range(repeats)]))
        for module in ("sb3_coma", "stable_baselines3")
    }
    speed["import_sb3_coma_s"], speed["import_stable_baselines3_s"] = imports["sb3_coma"], imports["stable_baselines3"]
    speed["import_ratio"] = imports["sb3_coma"] / imports["stable_baselines3"]
    atomic_write_text(out / "speed.json", json.dumps(speed))
    print(json.dumps(speed, indent=1), flush=True)
    return speed


def _records(out: Path) -> list[dict[str, Any]]:
    return [json.loads(path.read_text()) for path in sorted((out / "runs").glob("*.json"))]


def _smoothed(curve: Sequence[Sequence[float]], grid: np.ndarray, window: int = 100) -> np.ndarray:
    """The mean team return of the last ``window`` episodes finished by each grid point."""
    steps = np.array([s for s, _ in curve])
    values = np.array([r for _, r in curve])
    out = np.full(len(grid), np.nan)
    for i, x in enumerate(grid):
        done = values[steps <= x][-window:]
        if done.size:
            out[i] = done.mean()
    return out


def _plot(records: list[dict[str, Any]], target: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = sorted({r["task"] for r in records})
    colours = {"coma": "tab:red", "mappo": "tab:blue", "ippo": "tab:green", "random": "tab:gray"}
    columns = min(3, len(tasks))
    rows = -(-len(tasks) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(5.5 * columns, 4.0 * rows), squeeze=False)
    for ax, task in zip(axes.flat, tasks):
        mine = [r for r in records if r["task"] == task]
        for learner in LEARNERS:
            runs = [r for r in mine if r["learner"] == learner]
            if learner == "random" and runs:
                ax.axhline(runs[0]["final_return"], color=colours[learner], ls="--", label="random")
                continue
            if not runs:
                continue
            grid = np.array([x for x, _ in runs[0]["curve"]])
            curves = np.array([[np.nan if y is None else y for _, y in r["curve"]] for r in runs])
            with warnings.catch_warnings():  # grid points before any episode ended are NaN in every seed
                warnings.simplefilter("ignore", RuntimeWarning)
                mean, low, high = np.nanmean(curves, 0), np.nanmin(curves, 0), np.nanmax(curves, 0)
            ax.plot(grid, mean, color=colours[learner], label=f"{learner.upper()} ({len(runs)} seeds)")
            ax.fill_between(grid, low, high, color=colours[learner], alpha=0.2)
        ax.set(title=task, xlabel="joint env steps", ylabel="team return (last 100 training episodes)")
        ax.legend(loc="lower right", fontsize=8)
    for ax in list(axes.flat)[len(tasks) :]:
        ax.set_visible(False)
    fig.text(0.5, 0.005, "line: mean over seeds; band: min..max over seeds", ha="center", fontsize=8)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    save_palette_png(fig, target, dpi=100)
    plt.close(fig)


def save_palette_png(fig: Any, target: Path, dpi: int) -> None:
    """``fig`` as a PNG of at most 128 colours, written atomically: line plots need no more, and the
    file is about a third of the full-colour one (these figures live in git)."""
    from PIL import Image

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    image = Image.open(buffer).convert("RGB").convert("P", palette=Image.Palette.ADAPTIVE, colors=128)
    atomic_write(target, lambda handle: image.save(handle, format="PNG", optimize=True))


def seed_paired_verdict(a: list[dict[str, Any]], b: list[dict[str, Any]]) -> str:
    """COMA minus MAPPO, paired by training seed (both flew the same evaluation episodes): the mean
    difference with its 95 % t interval over seeds (``seeds - 1`` degrees of freedom), and which
    learner it favours, or "tie" when the interval holds 0."""
    from sb3_coma.stats.paired import t_ppf

    by_seed = {r["seed"]: r["final_return"] for r in b}
    diffs = np.array([r["final_return"] - by_seed[r["seed"]] for r in a if r["seed"] in by_seed])
    if len(diffs) < 2:
        return "- (fewer than 2 shared seeds)"
    half = t_ppf(0.975, len(diffs) - 1) * diffs.std(ddof=1) / np.sqrt(len(diffs))
    low, high = diffs.mean() - half, diffs.mean() + half
    word = "COMA better" if low > 0 else "MAPPO better" if high < 0 else "tie"
    return f"{diffs.mean():+.2f} [{low:+.2f}, {high:+.2f}]: {word}"


def _within_spread(coma: list[float], mappo: list[float]) -> str:
    """The issue's bar: COMA's mean final return is at least MAPPO's mean minus MAPPO's seed std."""
    if len(mappo) < 2 or not coma:
        return "-"
    return "yes" if np.mean(coma) >= np.mean(mappo) - np.std(mappo, ddof=1) else "no"


def _table_rows(records: list[dict[str, Any]]) -> list[str]:
    lines = []
    for task in sorted({r["task"] for r in records}):
        for learner in LEARNERS:
            runs = sorted(
                (r for r in records if r["task"] == task and r["learner"] == learner), key=lambda r: r["seed"]
            )
            if not runs:
                continue
            finals = [r["final_return"] for r in runs]
            late = [r["late_training_return"] for r in runs if r.get("late_training_return") is not None]
            lines.append(
                f"| {task} | {learner.upper()} | {len(runs)} | {runs[0]['joint_steps']:,} | {np.mean(finals):.2f} | "
                f"{np.std(finals, ddof=1) if len(finals) > 1 else 0.0:.2f} | {', '.join(f'{f:.2f}' for f in finals)} | "
                f"{f'{np.mean(late):.2f}' if late else '-'} | {np.mean([r['seconds'] for r in runs]) / 60:.1f} |"
            )
    return lines


def _verdict_rows(records: list[dict[str, Any]]) -> list[str]:
    lines = []
    for task in sorted({r["task"] for r in records}):
        coma = [r for r in records if r["task"] == task and r["learner"] == "coma"]
        mappo = [r for r in records if r["task"] == task and r["learner"] == "mappo"]
        random = [r["final_return"] for r in records if r["task"] == task and r["learner"] == "random"]
        within = _within_spread([r["final_return"] for r in coma], [r["final_return"] for r in mappo])
        above = "-" if not (random and coma) else f"{np.mean([r['final_return'] for r in coma]) - random[0]:+.2f}"
        lines.append(f"| {task} | {seed_paired_verdict(coma, mappo)} | {within} | {above} |")
    return lines


#: README's paragraph on this benchmark lies between these markers; ``report`` writes it (``--readme``).
README_MARKERS = (
    "<!-- marl-benchmark:start (written by python -m sb3_coma.experiments.marl_benchmark) -->",
    "<!-- marl-benchmark:end -->",
)


def summary_paragraph(records: list[dict[str, Any]], speed: dict[str, Any] | None) -> str:
    """The benchmark in one paragraph, from the records (README quotes it; nobody types it)."""
    parts, within_tasks, above, bar_tasks = [], [], [], []
    for task in sorted({r["task"] for r in records}):
        finals = {
            learner: [r["final_return"] for r in records if r["task"] == task and r["learner"] == learner]
            for learner in LEARNERS
        }
        coma = [r for r in records if r["task"] == task and r["learner"] == "coma"]
        mappo = [r for r in records if r["task"] == task and r["learner"] == "mappo"]
        if not (coma and mappo):
            continue
        seeds = min(len(coma), len(mappo))
        verdict = seed_paired_verdict(coma, mappo)
        parts.append(
            f"{task} ({seeds} seed{'s' if seeds > 1 else ''}): COMA {np.mean(finals['coma']):.2f}, MAPPO {np.mean(finals['mappo']):.2f}, "
            f"COMA minus MAPPO {verdict}"
        )
        over_random = np.mean(finals["coma"]) - finals["random"][0] if finals["random"] else float("nan")
        if _within_spread(finals["coma"], finals["mappo"]) == "yes":
            within_tasks.append(task)
            if over_random > 0:
                bar_tasks.append(task)
        if finals["random"]:
            above.append(f"{task} {over_random:+.2f}")
    text = "COMA against MAPPO, paired by training seed (mean [95 % t interval]): " + "; ".join(parts) + ". "
    text += f"COMA's mean is within MAPPO's seed spread (or above) on {len(within_tasks)} of {len(parts)} tasks"
    text += f" ({', '.join(within_tasks)})" if within_tasks else ""
    text += f"; COMA minus random: {', '.join(above)}." if above else "."
    text += f" Both (within the spread and above random) on {len(bar_tasks)} of {len(parts)}" + (
        f" ({', '.join(bar_tasks)})." if bar_tasks else "."
    )
    if speed is not None:
        ratios = [row["ratio"] for row in speed["tasks"].values()]
        text += (
            f" `learn()` joint steps/s, COMA over SB3's PPO in the same run: {min(ratios):.2f} to {max(ratios):.2f}"
            f" on {len(ratios)} tasks."
        )
    return text


def write_readme_block(readme: Path, paragraph: str) -> None:
    """Replace the text between :data:`README_MARKERS` in ``readme`` (atomically) by ``paragraph``."""
    if not write_between_markers(readme, README_MARKERS, paragraph):
        raise ValueError(f"{readme} has no {README_MARKERS[0]} ... {README_MARKERS[1]} block to write")


def _speed(out: Path) -> dict[str, Any] | None:
    path = out / "speed.json"
    return json.loads(path.read_text()) if path.exists() else None


def _speed_lines(out: Path) -> list[str]:
    speed = _speed(out)
    if speed is None:
        return []
    lines = [
        "",
        "## Speed (same run, same machine: compare the ratios)",
        "",
        f"`learn()` for {speed['joint_steps']:,} joint steps, {N_ENVS} copies, one thread; COMA with its benchmark "
        f"settings, SB3's PPO with IPPO's; medians of {speed['repeats']}, interleaved.",
        "",
        "| task | COMA joint steps/s | SB3 PPO joint steps/s | ratio COMA / PPO |",
        "| --- | --- | --- | --- |",
    ]
    for task, row in speed["tasks"].items():
        lines.append(
            f"| {task} | {row['coma_joint_steps_per_s']:.0f} | {row['ppo_joint_steps_per_s']:.0f} | {row['ratio']:.2f} |"
        )
    lines += [
        "",
        f"`import sb3_coma` {speed['import_sb3_coma_s']:.2f} s, `import stable_baselines3` "
        f"{speed['import_stable_baselines3_s']:.2f} s: ratio {speed['import_ratio']:.2f}",
    ]
    return lines


HEADER = """# COMA, MAPPO, IPPO and random on third-party cooperative envs

Generated by `python -m sb3_coma.experiments.marl_benchmark` (do not edit); the per-run records are
in `runs/`. **Final team return**: the agents' rewards summed over every step of an episode and over
the agents, mean over {episodes} evaluation episodes (env seeds from {eval_seed}, the same episodes for
every learner and seed) of the final policy's most likely actions; then mean and standard deviation
over training seeds (0, 1, ...). Same joint env steps for every learner (one step of every agent of one
env copy). Last 100 training episodes: the team return of the sampled (exploring) policy at the end of
training. Train minutes: wall time of one run on the recording machine, shared with other runs (not a speed
figure: the speed table below is).

**Settings and tuning budget**: each learner's settings are its entry in `zoo_configs/marl/<learner>.yml`.
Actors: COMA's and IPPO's have two hidden layers of 64 tanh units, but COMA's on simple_spread and Foraging-5x5 have
three (their entries' `net_arch`, chosen by the study's round 21); MAPPO's (`CentralValuePolicy`) reads its keys
through one more than two (docs/design.md; the COMA study's rounds 15 and 21 measure what the third layer is worth).
{tuning}
"""


#: The study's rings fly an arm on three validation seeds, so a learner's budget fills three runs at a time:
#: counts fewer than this apart (every learner having some) are equal to within one arm.
ARM_RUNS = 3


def _budget_verdict(counts: dict[str, list[int]]) -> str:
    """Whether each task's validation runs (one count per learner) are equal, equal to within one arm, or
    not: the sentence the table prints, so a budget one arm apart is neither hidden nor called unequal."""
    equal = [task for task, runs in counts.items() if len(set(runs)) == 1]
    near = [
        task for task, runs in counts.items() if task not in equal and 0 < min(runs) <= max(runs) < min(runs) + ARM_RUNS
    ]
    unequal = [task for task in counts if task not in equal and task not in near]
    one_arm = f"to within one arm of {ARM_RUNS} validation seeds on {', '.join(near)}"
    if unequal:
        kept = [f"equal on {', '.join(equal)}"] * bool(equal) + [one_arm] * bool(near)
        return f"The budget is NOT equal across learners on {', '.join(unequal)}" + (
            f" ({'; '.join(kept)})" if kept else ""
        )
    if near:
        return f"The budget is equal across learners on every task, {one_arm}" + (
            f" (exactly on {', '.join(equal)})" if equal else ""
        )
    return "The budget is equal across learners on every task"


def tuning_paragraph(study: Path) -> str:
    """How many validation runs chose each learner's settings, per task, counted from the study's round
    tables in ``study`` (written, not typed), and whether that budget is equal across learners."""
    from sb3_coma.experiments.coma_study import tuning_runs

    runs = tuning_runs(study)
    tasks = sorted({task for _, task in runs})
    learners = [learner for learner in LEARNERS if learner != "random"]
    per_learner = []
    for learner in learners:
        counts = [f"{task} {runs[(learner, task)]}" for task in tasks if (learner, task) in runs]
        per_learner.append(f"{learner.upper()}: {', '.join(counts) or 'none'}")
    verdict = _budget_verdict({task: [runs.get((learner, task), 0) for learner in learners] for task in tasks})
    return (
        "Settings were chosen on validation seeds and episodes only (`python -m sb3_coma.experiments.coma_study`, "
        f"{study}/, one table a round). Tuning budget in validation runs per task (one variant on one seed, "
        f"counted from those tables): {'; '.join(per_learner)}. {verdict}; where a learner has "
        "no runs, its entry was not tuned on that task (each entry's comment in the config says where it "
        "comes from)."
    )


def report_phase(out: Path, episodes: int = EVAL_EPISODES, study: Path | None = None) -> str:
    """``results.md`` and ``curves.png`` from the records in ``out`` and the tuning budget from the study's
    tables in ``study`` (default: ``coma_study`` beside ``out``), written, not typed."""
    records = _records(out)
    tuning = tuning_paragraph(out.parent / "coma_study" if study is None else study)
    lines = [
        HEADER.format(episodes=episodes, eval_seed=EVAL_SEED, tuning=tuning),
        "| task | learner | seeds | joint steps | final team return | std over seeds | per seed | "
        "last 100 training episodes | train minutes |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
        *_table_rows(records),
        "",
        "## COMA against MAPPO",
        "",
        "Paired by training seed on the same evaluation episodes: COMA minus MAPPO, mean [95 % t interval over",
        "seeds]; a tie when the interval holds 0. Within spread: COMA's mean is at least MAPPO's mean minus",
        "MAPPO's standard deviation over seeds. Over random: COMA's mean minus random's.",
        "",
        "| task | COMA - MAPPO | within MAPPO's seed spread | COMA over random |",
        "| --- | --- | --- | --- |",
        *_verdict_rows(records),
        *_speed_lines(out),
        "",
        "## Summary",
        "",
        summary_paragraph(records, _speed(out)),
    ]
    text = "\n".join(lines) + "\n"
    atomic_write_text(out / "results.md", text)
    if records:
        _plot(records, out / "curves.png")
    return text


#: ``--quick``: every budget cut to this many joint steps, one seed, a few evaluation episodes (CI).
QUICK_STEPS, QUICK_EPISODES = 2_048, 4


def _parse(argv: list[str] | None) -> argparse.Namespace:
    from uav_ipp.config import count_value

    parser = argparse.ArgumentParser(
        prog="python -m sb3_coma.experiments.marl_benchmark", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--out", type=Path, default=Path("docs/marl_benchmark"), help="folder of records, table and figure"
    )
    parser.add_argument("--phases", default="train,speed,report", help="comma-separated: train, speed, report")
    parser.add_argument("--tasks", default=",".join(TASKS), help=f"comma-separated of {sorted(TASKS)}")
    parser.add_argument("--learners", default=",".join(LEARNERS), help=f"comma-separated of {', '.join(LEARNERS)}")
    parser.add_argument("--seeds", type=count_value, default=5, help="training seeds per learner (0..seeds-1)")
    parser.add_argument("--workers", type=count_value, default=2, help="runs trained side by side")
    parser.add_argument(
        "--readme",
        type=Path,
        default=None,
        help="with the report phase: write its summary between the benchmark's markers of this README",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=f"{QUICK_STEPS} joint steps per run, 1 seed, {QUICK_EPISODES} evaluation episodes (a check, not a result)",
    )
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = _parse(argv)
    phases = args.phases.split(",")
    keys, learners = args.tasks.split(","), tuple(args.learners.split(","))
    choices = (
        ("phase", phases, ("train", "speed", "report")),
        ("task", keys, tuple(TASKS)),
        ("learner", learners, LEARNERS),
    )
    for name, given, known in choices:
        bad = [g for g in given if g not in known]
        if bad:
            print(f"error: unknown {name} {bad[0]!r}; choose from {', '.join(known)}", file=sys.stderr)
            return 2
    tasks = [TASKS[key] for key in keys]
    seeds, episodes = list(range(args.seeds)), EVAL_EPISODES
    if args.quick:
        tasks = [dataclasses.replace(task, joint_steps=QUICK_STEPS) for task in tasks]
        seeds, episodes = [0], QUICK_EPISODES
    args.out.mkdir(parents=True, exist_ok=True)
    if "train" in phases:
        try:
            train_phase(args.out, tasks, seeds, args.workers, episodes, learners)
        except RecordMismatch as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    if "speed" in phases:
        speed_phase(args.out, tasks, joint_steps=QUICK_STEPS if args.quick else 10_240, repeats=1 if args.quick else 3)
    if "report" in phases:
        print(report_phase(args.out, episodes))
        if args.readme is not None:
            try:
                write_readme_block(args.readme, summary_paragraph(_records(args.out), _speed(args.out)))
            except (OSError, ValueError) as exc:
                print(f"error: --readme {args.readme}: {exc}", file=sys.stderr)
                return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
