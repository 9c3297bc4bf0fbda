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
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

LEARNERS = ("coma", "mappo", "ippo", "random")
#: PPO settings for IPPO and MAPPO (per row: 8 copies x N agents x 128 steps per rollout), close to
#: the MAPPO paper's MPE settings; COMA runs with the library's defaults.
PPO_KWARGS: dict[str, Any] = {"n_steps": 128, "batch_size": 256, "n_epochs": 10, "ent_coef": 0.01}
N_ENVS = 8
EVAL_EPISODES = 100
EVAL_SEED = 100_000


@dataclass(frozen=True)
class Task:
    """A cooperative env and how long each learner trains on it (joint steps)."""

    name: str
    joint_steps: int

    def make(self) -> Any:
        """A fresh PettingZoo ``ParallelEnv`` of this task."""
        if self.name == "simple_spread":
            from mpe2 import simple_spread_v3

            return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False)
        import gymnasium
        import lbforaging  # noqa: F401  (registers the Foraging ids)

        from sb3_coma.common.gymnasium_marl import GymnasiumMultiAgentToParallel

        return GymnasiumMultiAgentToParallel(gymnasium.make(self.name, disable_env_checker=True))


TASKS = {
    "simple_spread": Task("simple_spread", 300_000),
    "lbf": Task("Foraging-5x5-2p-1f-coop-v3", 200_000),
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


def _vec_env(task: Task, seed: int, learner: str) -> tuple[VecEnv, TeamReturns]:
    """The task's vec env for ``learner`` and the recorder inside it."""
    from sb3_coma import make_marl_vec_env
    from sb3_coma.mappo.central_value import CentralStateVecEnv

    base = make_marl_vec_env(task.make, n_envs=N_ENVS, seed=seed)
    recorder = TeamReturns(base, base.n_agents)  # type: ignore[attr-defined]
    return (CentralStateVecEnv(recorder) if learner == "mappo" else recorder), recorder


def _model(learner: str, venv: VecEnv, seed: int) -> Any:
    from stable_baselines3 import PPO

    from sb3_coma import COMA
    from sb3_coma.mappo.central_value import CentralValuePolicy

    if learner == "coma":
        return COMA("MlpPolicy", venv, seed=seed, device="cpu")
    policy = CentralValuePolicy if learner == "mappo" else "MlpPolicy"
    return PPO(policy, venv, seed=seed, device="cpu", **PPO_KWARGS)


def _act(model: Any) -> Callable[[Any, VecEnv], np.ndarray]:
    if model is None:
        return lambda obs, venv: np.array([venv.action_space.sample() for _ in range(venv.num_envs)])
    return lambda obs, venv: model.predict(obs, deterministic=True)[0]


def evaluate_team_return(task: Task, learner: str, model: Any, episodes: int = EVAL_EPISODES) -> list[float]:
    """Team returns of ``episodes`` evaluation episodes (seeds of their own)."""
    venv, recorder = _vec_env(task, EVAL_SEED, learner)
    venv.action_space.seed(EVAL_SEED)
    act = _act(model)
    obs = venv.reset()
    while len(recorder.episodes) < episodes:
        obs, *_ = venv.step(act(obs, venv))
    venv.close()
    return [ret for _, ret in recorder.episodes[:episodes]]


def _joint_to_learn(learner: str, task: Task, n_agents: int) -> int:
    """``learn()``'s argument for ``task.joint_steps`` joint steps (PPO counts agent steps)."""
    return task.joint_steps * (n_agents if learner in ("ippo", "mappo") else 1)


def run_one(task_key: str, learner: str, seed: int) -> dict[str, Any]:
    """Train one (task, learner, seed) and evaluate it; the record of :func:`main`'s table."""
    import torch as th

    th.set_num_threads(1)
    task = TASKS[task_key]
    start = time.perf_counter()
    model = None
    curve: list[tuple[int, float]] = []
    if learner != "random":
        venv, recorder = _vec_env(task, seed, learner)
        model = _model(learner, venv, seed)
        model.learn(_joint_to_learn(learner, task, recorder.n_agents))
        curve = recorder.episodes
        venv.close()
    returns = evaluate_team_return(task, learner, model)
    return {
        "task": task.name,
        "learner": learner,
        "seed": seed,
        "joint_steps": task.joint_steps if model is not None else 0,
        "final_return": float(np.mean(returns)),
        "curve": curve,
        "seconds": time.perf_counter() - start,
    }


def _write_json(path: Path, data: Any) -> None:
    """Write to a temporary file in the same folder, then move it into place (never half a file)."""
    handle, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(handle, "w") as f:
        json.dump(data, f)
    os.replace(tmp, path)


def _job(args: tuple[str, str, int, str]) -> str:
    task_key, learner, seed, folder = args
    target = Path(folder) / f"{task_key}-{learner}-{seed}.json"
    _write_json(target, run_one(task_key, learner, seed))
    return target.name


def train_phase(out: Path, tasks: list[str], seeds: list[int], workers: int) -> None:
    """Every missing (task, learner, seed) record, ``workers`` at a time."""
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    todo = [
        (task, learner, seed, str(runs))
        for task in tasks
        for learner in LEARNERS
        for seed in (seeds if learner != "random" else seeds[:1])
        if not (runs / f"{task}-{learner}-{seed}.json").exists()
    ]
    print(f"train: {len(todo)} runs to do", flush=True)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for name in pool.map(_job, todo):
            print(f"  done {name}", flush=True)


def _learn_rate(learner: str, joint_steps: int) -> float:
    """Joint steps per second of ``learn()`` on simple_spread (seed 0)."""
    import torch as th

    th.set_num_threads(1)
    task = Task("simple_spread", joint_steps)
    venv, recorder = _vec_env(task, 0, learner)
    model = _model(learner, venv, 0)
    start = time.perf_counter()
    model.learn(_joint_to_learn(learner, task, recorder.n_agents))
    return joint_steps / (time.perf_counter() - start)


def _import_seconds(module: str) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", f"import {module}"], check=True)
    return time.perf_counter() - start


def speed_phase(out: Path, joint_steps: int = 20_000, repeats: int = 3) -> dict[str, float]:
    """COMA against SB3's PPO (``learn()`` joint steps/s, same ``n_envs``) and ``import sb3_coma``
    against ``import stable_baselines3`` (process wall time), interleaved, medians of ``repeats``."""
    rates: dict[str, list[float]] = {"coma": [], "ippo": []}
    imports: dict[str, list[float]] = {"sb3_coma": [], "stable_baselines3": []}
    for _ in range(repeats):
        for learner in rates:
            rates[learner].append(_learn_rate(learner, joint_steps))
        for module in imports:
            imports[module].append(_import_seconds(module))
    speed = {
        "coma_joint_steps_per_s": float(np.median(rates["coma"])),
        "ppo_joint_steps_per_s": float(np.median(rates["ippo"])),
        "import_sb3_coma_s": float(np.median(imports["sb3_coma"])),
        "import_stable_baselines3_s": float(np.median(imports["stable_baselines3"])),
    }
    speed["learn_ratio_coma_over_ppo"] = speed["coma_joint_steps_per_s"] / speed["ppo_joint_steps_per_s"]
    speed["import_ratio_sb3_coma_over_sb3"] = speed["import_sb3_coma_s"] / speed["import_stable_baselines3_s"]
    _write_json(out / "speed.json", speed)
    print(json.dumps(speed, indent=1), flush=True)
    return speed


def _records(out: Path) -> list[dict[str, Any]]:
    return [json.loads(path.read_text()) for path in sorted((out / "runs").glob("*.json"))]


def _smoothed(curve: list[list[float]], grid: np.ndarray, window: int = 100) -> np.ndarray:
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
    fig, axes = plt.subplots(1, len(tasks), figsize=(6 * len(tasks), 4.2), squeeze=False)
    for ax, task in zip(axes[0], tasks):
        mine = [r for r in records if r["task"] == task]
        horizon = max((r["joint_steps"] for r in mine), default=1)
        grid = np.linspace(horizon / 50, horizon, 50)
        for learner in LEARNERS:
            runs = [r for r in mine if r["learner"] == learner]
            if learner == "random" and runs:
                ax.axhline(runs[0]["final_return"], color=colours[learner], ls="--", label="random")
                continue
            if not runs:
                continue
            curves = np.array([_smoothed(r["curve"], grid) for r in runs])
            ax.plot(grid, np.nanmean(curves, 0), color=colours[learner], label=f"{learner.upper()} ({len(runs)} seeds)")
            ax.fill_between(grid, np.nanmin(curves, 0), np.nanmax(curves, 0), color=colours[learner], alpha=0.2)
        ax.set(title=task, xlabel="joint env steps", ylabel="team return (last 100 training episodes)")
        ax.legend(loc="lower right", fontsize=8)
    fig.text(0.5, 0.005, "line: mean over seeds; band: min..max over seeds", ha="center", fontsize=8)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    handle, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".png")
    os.close(handle)
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, target)


def report_phase(out: Path) -> str:
    """``results.md`` and ``curves.png`` from the records in ``out`` (written, not typed)."""
    records = _records(out)
    lines = [
        "# COMA, MAPPO, IPPO and random on third-party cooperative envs",
        "",
        "Generated by `python -m sb3_coma.experiments.marl_benchmark` (do not edit). Final team return: mean",
        f"over {EVAL_EPISODES} evaluation episodes (their own seeds, most likely actions) of the final policy;",
        "mean and standard deviation over training seeds. Same joint env steps for every learner. Last 100",
        "training episodes: the team return of the sampled (exploring) policy at the end of training, mean over",
        "seeds. Train minutes: wall time of one run, two runs sharing the machine's two cores.",
        "",
        "| task | learner | seeds | joint steps | final team return | std over seeds | per seed | last 100 training episodes | train minutes |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for task in sorted({r["task"] for r in records}):
        for learner in LEARNERS:
            runs = [r for r in records if r["task"] == task and r["learner"] == learner]
            if not runs:
                continue
            finals = [r["final_return"] for r in runs]
            per_seed = ", ".join(f"{f:.2f}" for f in finals)
            late = [np.mean([ret for _, ret in r["curve"][-100:]]) for r in runs if r["curve"]]
            lines.append(
                f"| {task} | {learner.upper()} | {len(runs)} | {runs[0]['joint_steps']:,} | {np.mean(finals):.2f} | "
                f"{np.std(finals, ddof=1) if len(finals) > 1 else 0.0:.2f} | {per_seed} | "
                f"{f'{np.mean(late):.2f}' if late else '-'} | {np.mean([r['seconds'] for r in runs]) / 60:.1f} |"
            )
    speed_path = out / "speed.json"
    if speed_path.exists():
        speed = json.loads(speed_path.read_text())
        lines += [
            "",
            "## Speed (same run, same machine: compare the ratios)",
            "",
            f"- `learn()` on simple_spread, {N_ENVS} copies: COMA {speed['coma_joint_steps_per_s']:.0f} joint steps/s, "
            f"SB3 PPO {speed['ppo_joint_steps_per_s']:.0f}: ratio {speed['learn_ratio_coma_over_ppo']:.2f}",
            f"- `import sb3_coma` {speed['import_sb3_coma_s']:.2f} s, `import stable_baselines3` "
            f"{speed['import_stable_baselines3_s']:.2f} s: ratio {speed['import_ratio_sb3_coma_over_sb3']:.2f}",
        ]
    text = "\n".join(lines) + "\n"
    handle, tmp = tempfile.mkstemp(dir=out, prefix=".results.md.")
    with os.fdopen(handle, "w") as f:
        f.write(text)
    os.replace(tmp, out / "results.md")
    if records:
        _plot(records, out / "curves.png")
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m sb3_coma.experiments.marl_benchmark", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument(
        "--out", type=Path, default=Path("docs/marl_benchmark"), help="folder of records, table and figure"
    )
    parser.add_argument("--phases", default="train,speed,report", help="comma-separated: train, speed, report")
    parser.add_argument("--tasks", default=",".join(TASKS), help=f"comma-separated of {sorted(TASKS)}")
    parser.add_argument("--seeds", type=int, default=3, help="training seeds per learner (0..seeds-1)")
    parser.add_argument("--workers", type=int, default=2, help="runs trained side by side")
    args = parser.parse_args(argv)
    phases = args.phases.split(",")
    tasks = args.tasks.split(",")
    for name, given, known in (("phase", phases, ("train", "speed", "report")), ("task", tasks, tuple(TASKS))):
        bad = [g for g in given if g not in known]
        if bad:
            print(f"error: unknown {name} {bad[0]!r}; choose from {', '.join(known)}", file=sys.stderr)
            return 2
    if args.seeds < 1 or args.workers < 1:
        print(f"error: --seeds and --workers must be >= 1, got {args.seeds} and {args.workers}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    if "train" in phases:
        train_phase(args.out, tasks, list(range(args.seeds)), args.workers)
    if "speed" in phases:
        speed_phase(args.out)
    if "report" in phases:
        print(report_phase(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
