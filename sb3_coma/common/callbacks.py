"""SB3 callbacks for multi-UAV training: mission metrics, checkpoints, stop-on-target, signals.

All of them think in **missions** (one per env copy) and **joint steps** (one per env copy per
step), not in vec-env rows: the vec env holds ``n_agents`` rows per env copy (agent ``a`` of copy
``e`` at row ``e * n_agents + a``), all agents of a copy share the team reward and finish together,
so a mission is read once, from the row of its first agent.

* :class:`EpisodeMetricsCallback` - team reward, F1 and entropy of every finished mission, to
  TensorBoard (one point per mission, plus means over a window in SB3's logger) and to a CSV file;
* :class:`JointCheckpointCallback` - a checkpoint every N joint steps, written atomically, at
  rollout boundaries (so a resumed run counts exactly the same timesteps as an uninterrupted one);
* :class:`StopOnTargetCallback` - stop when the windowed mean of a mission metric crosses a target
  (e.g. final entropy below 0.25);
* :class:`SignalStopCallback` - turn SIGINT / SIGTERM into a clean stop at the next step;
* :class:`ProgressLinesCallback` - a plain line every tenth of the run (joint steps, elapsed,
  estimate left), for runs without a progress bar whose output goes to a log;
* :class:`MissionEvalCallback` - SB3's ``EvalCallback`` counting missions, logging F1 and entropy.
"""

from __future__ import annotations

import contextlib
import csv
import io
import math
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
from stable_baselines3.common.logger import TensorBoardOutputFormat

from sb3_coma.common.checkpoints import (
    CHECKPOINT_PREFIX,
    atomic_save,
    atomic_write_text,
    checkpoint_name,
    find_checkpoints,
)
from sb3_coma.common.joint import resolve_n_agents
from sb3_coma.common.numbers import is_real, is_whole

#: Columns of the per-mission metrics CSV.
METRIC_COLUMNS = ("episode", "timesteps", "env_copy", "reward", "length", "f1", "entropy", "wall_time")


# --------------------------------------------------------------------------- helpers
def _agents_per_copy(model: Any, env: Any = None) -> int:
    """Agents per env copy: COMA's ``n_agents``, else the vec env's attribute, else 1."""
    n = getattr(model, "n_agents", None)
    if is_whole(n) and n > 0:
        return int(n)
    if env is not None:
        n = getattr(env, "n_agents", None)
        if is_whole(n) and n > 0:
            return int(n)
    return 1


def finished_missions(
    infos: Sequence[dict[str, Any]], dones: np.ndarray, n_agents: int
) -> list[tuple[int, dict[str, Any]]]:
    """``(env copy, info of its first agent)`` for every copy whose mission ended this step."""
    out = []
    for row in range(0, len(infos), max(n_agents, 1)):
        if bool(dones[row]):
            out.append((row // max(n_agents, 1), infos[row]))
    return out


def truncate_metrics_csv(path: str | os.PathLike[str], max_timesteps: int) -> int:
    """Drop rows recorded after ``max_timesteps`` (a resumed run redoes them) and rows a crash
    left half-written (missing columns); return rows kept.

    The file is rewritten atomically; a missing file keeps 0 rows.
    """
    p = Path(path)
    if not p.exists():
        return 0
    with p.open(newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    kept = [r for r in rows if _complete(r) and _as_int(r.get("timesteps")) <= max_timesteps]
    if len(kept) != len(rows):
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, fieldnames=list(METRIC_COLUMNS), extrasaction="ignore")
        writer.writeheader()
        writer.writerows(kept)
        atomic_write_text(p, buffer.getvalue())
    return len(kept)


def _check_counts(optional: Sequence[str] = (), **counts: Any) -> None:
    """The one rule of the callbacks' counts (windows, frequencies, missions): an integer >= 1,
    or ``None`` for the names in ``optional``; the error names the first bad one and its value."""
    for name, value in counts.items():
        if value is None and name in optional:
            continue
        if not is_whole(value) or value < 1:
            allowed = "an integer >= 1" + (" or None" if name in optional else "")
            raise ValueError(f"{name} must be {allowed}, got {value!r}")


def _complete(row: dict[str, Any]) -> bool:
    """Every column of the row is there: a partial last line (a crash mid-write) is not."""
    return all(row.get(column) not in (None, "") for column in METRIC_COLUMNS)


def _as_int(value: Any) -> int:
    try:
        return int(float(value))
    except (TypeError, ValueError):
        return 0


class _MissionTracker:
    """Team return and length of the running mission of each env copy, from the step rewards.

    Used where the vec env carries no ``VecMonitor`` (``info["episode"]`` missing).
    """

    def __init__(self) -> None:
        self.returns: np.ndarray | None = None
        self.lengths: np.ndarray | None = None

    def update(self, rewards: np.ndarray | None, n_agents: int) -> None:
        if rewards is None:
            return
        team = np.asarray(rewards, dtype=np.float64)[:: max(n_agents, 1)]
        if self.returns is None or self.returns.shape != team.shape:
            self.returns = np.zeros_like(team)
            self.lengths = np.zeros(team.shape, dtype=np.int64)
        self.returns += team
        assert self.lengths is not None
        self.lengths += 1

    def pop(self, copy: int) -> tuple[float, int]:
        if self.returns is None or self.lengths is None or copy >= len(self.returns):
            return math.nan, 0
        r, n = float(self.returns[copy]), int(self.lengths[copy])
        self.returns[copy] = 0.0
        self.lengths[copy] = 0
        return r, n


def _mission_record(copy: int, info: dict[str, Any], tracker: _MissionTracker) -> dict[str, Any]:
    """Reward, length, final F1 and entropy of a finished mission, from its first agent's info."""
    own_return, own_length = tracker.pop(copy)
    episode = info.get("episode")
    if isinstance(episode, dict) and "r" in episode:
        reward, length = float(episode["r"]), int(episode["l"])
    else:
        reward, length = own_return, own_length
    return {
        "env_copy": copy,
        "reward": reward,
        "length": length,
        "f1": float(info["f1"]) if "f1" in info else math.nan,
        "entropy": float(info["entropy"]) if "entropy" in info else math.nan,
    }


# --------------------------------------------------------------------------- metrics
class EpisodeMetricsCallback(BaseCallback):
    """Log team reward, final F1 and final entropy of every finished mission.

    For each mission (one per env copy, read from its first agent's info):

    * TensorBoard: ``<prefix>/reward``, ``<prefix>/f1``, ``<prefix>/entropy`` one point per
      mission at the current joint step (written straight to the TensorBoard writer of the
      model's logger, when it has one);
    * SB3's logger (all formats, dumped with SB3's other values at the end of each rollout):
      ``<prefix>/reward_mean``, ``<prefix>/f1_mean``, ``<prefix>/entropy_mean`` over the last
      ``window`` missions, the last mission's values, and ``<prefix>/missions`` (count);
    * ``csv_path`` (optional): one row per mission with :data:`METRIC_COLUMNS`, appended and
      flushed as missions end, so the file is useful while training runs.

    The reward is VecMonitor's episode return (``info["episode"]["r"]``) when present, else the
    sum of the team rewards this callback saw. ``history`` keeps every record (dicts).

    :param csv_path: per-mission CSV file (appended to when it exists)
    :param window: missions averaged in the ``*_mean`` values
    :param prefix: logger key prefix
    :param tensorboard_per_mission: write one TensorBoard point per mission
    """

    def __init__(
        self,
        csv_path: str | os.PathLike[str] | None = None,
        window: int = 100,
        prefix: str = "mission",
        tensorboard_per_mission: bool = True,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        _check_counts(window=window)
        self.csv_path = Path(csv_path) if csv_path is not None else None
        self.window = int(window)
        self.prefix = prefix
        self.tensorboard_per_mission = tensorboard_per_mission
        self.history: list[dict[str, Any]] = []
        self._recent: dict[str, deque] = {k: deque(maxlen=self.window) for k in ("reward", "f1", "entropy")}
        self._tracker = _MissionTracker()
        self._handle: TextIO | None = None
        self._writer: csv.DictWriter | None = None
        self._episode = 0

    # ------------------------------------------------------------------ life cycle
    def _on_training_start(self) -> None:
        self._n_agents = _agents_per_copy(self.model, self.training_env)
        if self.csv_path is not None and self._handle is None:
            self.csv_path.parent.mkdir(parents=True, exist_ok=True)
            fresh = not self.csv_path.exists() or self.csv_path.stat().st_size == 0
            if not fresh:
                with self.csv_path.open(newline="", encoding="utf-8") as handle:
                    episodes = [_as_int(r.get("episode")) for r in csv.DictReader(handle)]
                self._episode = max(episodes, default=0)
            self._handle = self.csv_path.open("a", newline="", encoding="utf-8")
            self._writer = csv.DictWriter(self._handle, fieldnames=list(METRIC_COLUMNS), extrasaction="ignore")
            if fresh:
                self._writer.writeheader()
                self._handle.flush()

    def _on_training_end(self) -> None:
        self.close()

    def close(self) -> None:
        """Close the CSV file (idempotent: rl-zoo3 calls ``on_training_end`` twice)."""
        if self._handle is not None:
            self._handle.close()
            self._handle = None
            self._writer = None

    # ------------------------------------------------------------------ per step
    def _tensorboard_writer(self):
        for fmt in getattr(self.logger, "output_formats", []):
            if isinstance(fmt, TensorBoardOutputFormat):
                return fmt.writer
        return None

    def _on_step(self) -> bool:
        infos = self.locals.get("infos")
        dones = self.locals.get("dones")
        if infos is None or dones is None:
            return True
        self._tracker.update(self.locals.get("rewards"), self._n_agents)
        finished = finished_missions(infos, dones, self._n_agents)
        if not finished:
            return True
        writer = self._tensorboard_writer() if self.tensorboard_per_mission else None
        for copy, info in finished:
            record = _mission_record(copy, info, self._tracker)
            self._episode += 1
            record.update(episode=self._episode, timesteps=int(self.num_timesteps), wall_time=round(time.time(), 3))
            self.history.append(record)
            for key in ("reward", "f1", "entropy"):
                if not math.isnan(record[key]):
                    self._recent[key].append(record[key])
                    self.logger.record(f"{self.prefix}/{key}_last", record[key])
                    if writer is not None:
                        writer.add_scalar(f"{self.prefix}/{key}", record[key], self.num_timesteps)
            if self._writer is not None:
                self._writer.writerow(record)
        if writer is not None:
            writer.flush()
        if self._handle is not None:
            self._handle.flush()
        for key, values in self._recent.items():
            if values:
                self.logger.record(f"{self.prefix}/{key}_mean", float(np.mean(values)))
        self.logger.record(f"{self.prefix}/missions", self._episode)
        return True


# --------------------------------------------------------------------------- checkpoints
class JointCheckpointCallback(BaseCallback):
    """Save the model every ``save_freq`` joint steps, atomically, at rollout boundaries.

    A checkpoint is written at the start of the first rollout after ``save_freq`` more joint
    steps were collected (or at the end of training, after a complete rollout), i.e. right after
    the model trained on everything it counts: its
    ``num_timesteps`` is a whole number of rollouts, its optimisers hold their state after that
    update, and resuming from it (``reset_num_timesteps=False``) reaches the very same final
    timestep count as a run that was never stopped. The effective period is therefore
    ``save_freq`` rounded up to whole rollouts.

    Files are ``<save_path>/<name_prefix>_<joint steps>_steps.zip`` (rl-zoo3's naming).

    :param save_freq: joint steps between checkpoints (> 0)
    :param save_path: folder
    :param name_prefix: file prefix
    :param keep_last: keep only the newest ``keep_last`` checkpoints (``None``: keep all)
    """

    def __init__(
        self,
        save_freq: int,
        save_path: str | os.PathLike[str],
        name_prefix: str = CHECKPOINT_PREFIX,
        keep_last: int | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        _check_counts(("keep_last",), save_freq=save_freq, keep_last=keep_last)
        self.save_freq = int(save_freq)
        self.save_path = Path(save_path)
        self.name_prefix = name_prefix
        self.keep_last = None if keep_last is None else int(keep_last)
        self.saved: list[Path] = []
        self._last_saved = 0

    def _init_callback(self) -> None:
        self.save_path.mkdir(parents=True, exist_ok=True)

    def _on_training_start(self) -> None:
        self._last_saved = int(self.model.num_timesteps)

    def _on_rollout_start(self) -> None:
        steps = int(self.model.num_timesteps)
        if steps - self._last_saved >= self.save_freq:
            self.save_now()

    def _on_training_end(self) -> None:
        # The end of a complete rollout + update is a boundary too; a stop mid-rollout is not.
        buffer = getattr(self.model, "rollout_buffer", None)
        steps = int(self.model.num_timesteps)
        full = getattr(buffer, "full", False)
        if bool(full() if callable(full) else full) and steps - self._last_saved >= self.save_freq:
            self.save_now()

    def _on_step(self) -> bool:
        return True

    def save_now(self, num_timesteps: int | None = None) -> Path:
        """Write a checkpoint now (named after ``num_timesteps``, default the model's count)."""
        steps = int(self.model.num_timesteps if num_timesteps is None else num_timesteps)
        path = atomic_save(self.model, self.save_path / checkpoint_name(steps, self.name_prefix))
        self._last_saved = steps
        self.saved.append(path)
        if self.verbose >= 1:
            print(f"Saving model checkpoint to {path}")
        if self.keep_last is not None:
            for _, old in find_checkpoints(self.save_path, self.name_prefix)[: -self.keep_last]:
                old.unlink(missing_ok=True)
        return path


# --------------------------------------------------------------------------- stop on target
class StopOnTargetCallback(BaseCallback):
    """Stop training when the mean of a mission metric over the last ``window`` missions hits a target.

    Example: ``StopOnTargetCallback("entropy", 0.25)`` stops once the mean final entropy of the
    last 20 missions is at or below 0.25; ``StopOnTargetCallback("f1", 0.8, mode="above")``.
    In an rl-zoo3 config::

        callback:
          - sb3_coma.common.callbacks.StopOnTargetCallback: {metric: entropy, threshold: 0.25}

    :param metric: ``"entropy"``, ``"f1"`` or ``"reward"`` (team return)
    :param threshold: the target
    :param mode: ``"below"`` (stop when mean <= threshold; default for entropy) or ``"above"``
        (mean >= threshold; default for f1 and reward)
    :param window: missions averaged
    :param min_missions: missions needed before the test applies (default: ``window``)
    """

    METRICS = ("entropy", "f1", "reward")

    def __init__(
        self,
        metric: str = "entropy",
        threshold: float = 0.25,
        mode: str | None = None,
        window: int = 20,
        min_missions: int | None = None,
        verbose: int = 1,
    ) -> None:
        super().__init__(verbose)
        mode = mode or ("below" if metric == "entropy" else "above")
        for name, value, allowed in (("metric", metric, self.METRICS), ("mode", mode, ("below", "above"))):
            if value not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
        _check_counts(("min_missions",), window=window, min_missions=min_missions)
        if not is_real(threshold):
            raise ValueError(f"threshold must be a number, got {threshold!r}")
        self.metric = metric
        self.threshold = float(threshold)
        self.mode = mode
        self.window = int(window)
        self.min_missions = int(min_missions if min_missions is not None else window)
        self.values: deque[float] = deque(maxlen=self.window)
        self.reached = False
        self.reached_at: int | None = None
        self._tracker = _MissionTracker()

    def _on_training_start(self) -> None:
        self._n_agents = _agents_per_copy(self.model, self.training_env)

    def _on_step(self) -> bool:
        infos, dones = self.locals.get("infos"), self.locals.get("dones")
        if infos is None or dones is None:
            return True
        self._tracker.update(self.locals.get("rewards"), self._n_agents)
        for copy, info in finished_missions(infos, dones, self._n_agents):
            value = _mission_record(copy, info, self._tracker)[self.metric]
            if not math.isnan(value):
                self.values.append(value)
        if len(self.values) < max(self.min_missions, 1):
            return True
        mean = float(np.mean(self.values))
        hit = mean <= self.threshold if self.mode == "below" else mean >= self.threshold
        if hit:
            self.reached, self.reached_at = True, int(self.num_timesteps)
            if self.verbose >= 1:
                print(
                    f"Stopping training: mean {self.metric} of the last {len(self.values)} missions is "
                    f"{mean:.4f} ({self.mode} {self.threshold}) at {self.num_timesteps} joint steps"
                )
            return False
        return True


# --------------------------------------------------------------------------- signals
class SignalStopCallback(BaseCallback):
    """Turn SIGINT / SIGTERM into a clean stop at the next environment step.

    While training runs, the first signal sets :attr:`received` and makes ``on_step`` return
    ``False`` (SB3 then leaves ``learn`` normally); a second SIGINT raises ``KeyboardInterrupt``
    at once. :attr:`boundary_timesteps` is the joint-step count at the start of the current
    rollout: the model's parameters and optimisers have not changed since, so a checkpoint saved
    under that count is an exact rollout-boundary state. Handlers are only installed from the main
    thread and are restored by :meth:`restore` (also called at the end of training).
    """

    def __init__(self, signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM), verbose: int = 0) -> None:
        super().__init__(verbose)
        self.signals = tuple(signals)
        self.received: int | None = None
        self.boundary_timesteps = 0
        self._previous: dict[int, Any] = {}

    def install(self) -> None:
        if threading.current_thread() is not threading.main_thread() or self._previous:
            return
        for sig in self.signals:
            try:
                self._previous[sig] = signal.signal(sig, self._handle)
            except (ValueError, OSError):  # pragma: no cover - platform without that signal
                continue

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            with contextlib.suppress(ValueError, OSError):
                signal.signal(sig, handler)
        self._previous = {}

    def _handle(self, signum: int, frame: Any) -> None:
        if self.received is not None and signum == signal.SIGINT:
            self.restore()
            raise KeyboardInterrupt
        self.received = signum
        if self.verbose >= 1:
            print(f"\nReceived {signal.Signals(signum).name}: stopping at the next step and saving a checkpoint")

    def _on_training_start(self) -> None:
        self.boundary_timesteps = int(self.model.num_timesteps)
        self.install()

    def _on_rollout_start(self) -> None:
        self.boundary_timesteps = int(self.model.num_timesteps)

    def _on_step(self) -> bool:
        return self.received is None

    def _on_training_end(self) -> None:
        self.restore()


# --------------------------------------------------------------------------- progress lines
def _duration(seconds: float) -> str:
    """``42 s``, ``3 min 05 s``, ``1 h 02 min``: short enough for a log line, exact enough to plan by."""
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    minutes, sec = divmod(seconds, 60)
    if minutes < 60:
        return f"{minutes} min {sec:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


class ProgressLinesCallback(BaseCallback):
    """Say how far training is, one line every ``every`` of the run: joint steps done / total,
    time elapsed and an estimate of the time left; and a last line when training ends.

    A run with ``verbose=0`` and no progress bar (``sb3-coma reproduce --train``, whose output
    often goes to a log file) is otherwise silent for as long as it trains; tqdm's bar redraws
    one line with carriage returns, which a log file keeps as one unreadable line. The estimate
    is the rate so far (validations included) applied to the steps left.

    :param every: fraction of the run between lines, in (0, 1] (default 0.1: ten lines)
    :param label: what the line starts with (e.g. ``"training env3"``)
    :param log: where the lines go (default: ``print`` with a flush, so a log file shows them
        as they come)
    :param clock: seconds, monotonic (tests pass a fake)
    """

    def __init__(
        self,
        every: float = 0.1,
        label: str = "training",
        log: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if not (is_real(every) and 0 < every <= 1):
            raise ValueError(f"every must be a fraction in (0, 1], got {every!r}")
        self.every = float(every)
        self.label = label
        self.log = log or (lambda line: print(line, flush=True))
        self.clock = clock
        self.lines: list[str] = []

    def _on_training_start(self) -> None:
        # learn() counts its total from the steps already done when it continues a run
        self._first = int(self.model.num_timesteps)
        self._total = int(self.model._total_timesteps)
        self._tic = self.clock()
        self._said = 0  # tenths (units of ``every``) already reported

    def _say(self, text: str) -> None:
        line = f"{self.label}: {text}"
        self.lines.append(line)
        self.log(line)

    def _on_step(self) -> bool:
        span = max(self._total - self._first, 1)
        done = int(self.num_timesteps) - self._first
        reached = int(done / span / self.every + 1e-9)  # whole units of ``every`` done
        if reached > self._said and done < span:  # the end has its own line
            self._said = reached
            elapsed = self.clock() - self._tic
            left = elapsed / done * (span - done)  # done > 0: a unit of ``every`` was reached
            self._say(
                f"{self.num_timesteps}/{self._total} joint steps ({100 * done / span:.0f} %), "
                f"{_duration(elapsed)} elapsed, about {_duration(left)} left"
            )
        return True

    def _on_training_end(self) -> None:
        elapsed = _duration(self.clock() - self._tic)
        finished = self.num_timesteps >= self._total
        what = "done" if finished else "stopped"
        self._say(f"{what} at {self.num_timesteps}/{self._total} joint steps after {elapsed}")


# --------------------------------------------------------------------------- evaluation
class SaveBestModelCallback(BaseCallback):
    """Child of an ``EvalCallback``: atomically save ``best_model.zip`` on a new best mean reward."""

    def __init__(self, save_path: str | os.PathLike[str], verbose: int = 0) -> None:
        super().__init__(verbose)
        self.save_path = Path(save_path)

    def _on_step(self) -> bool:
        path = atomic_save(self.model, self.save_path / "best_model.zip")
        if self.verbose >= 1:
            print(f"New best mean reward: saved {path}")
        return True


class MissionEvalCallback(EvalCallback):
    """SB3's ``EvalCallback`` for multi-agent vec envs: frequencies in joint steps, missions counted.

    ``eval_freq`` is in joint steps (converted to vec-env steps from the model's env copies) and
    ``n_eval_missions`` missions are run (SB3 counts episodes per row, so it is asked for
    ``n_eval_missions * n_agents`` agent-episodes, which the rows of each copy split evenly).
    Besides SB3's ``eval/mean_reward`` (the mean team return), it logs ``eval/mean_f1`` and
    ``eval/mean_entropy`` at the end of the missions. A new best model is written atomically to
    ``best_model_save_path/best_model.zip``.

    With ``eval_seed`` every evaluation re-seeds the eval env first, so every checkpoint flies the
    SAME missions and "best" compares policies, not luck of the draw (SB3's own callback lets the
    missions run on, so two evaluations see different noise). Use seeds the final evaluation does
    not use (``sb3_coma.app.training.VALIDATION_SEED``): choosing a checkpoint on the test missions
    would report a selected, optimistic number.

    ``select_after`` (joint steps): evaluations at or before it are logged but never become the
    best model. A warm-started run holds its actor still at first (the clone, not yet trained by
    COMA): a checkpoint of that phase must not be shipped as "COMA".
    """

    def __init__(
        self,
        eval_env: Any,
        eval_freq: int = 10_000,
        n_eval_missions: int = 5,
        best_model_save_path: str | os.PathLike[str] | None = None,
        log_path: str | os.PathLike[str] | None = None,
        deterministic: bool = True,
        callback_after_eval: BaseCallback | None = None,
        verbose: int = 1,
        eval_seed: int | None = None,
        select_after: int = 0,
    ) -> None:
        _check_counts(eval_freq=eval_freq, n_eval_missions=n_eval_missions)
        if eval_seed is not None and not is_whole(eval_seed):
            raise ValueError(f"eval_seed must be an integer or None, got {eval_seed!r}")
        self.eval_seed = None if eval_seed is None else int(eval_seed)
        self.select_after = int(select_after)
        self.eval_n_agents = resolve_n_agents(eval_env)
        self.eval_freq_joint = int(eval_freq)
        self.n_eval_missions = int(n_eval_missions)
        on_best = SaveBestModelCallback(best_model_save_path, verbose=verbose) if best_model_save_path else None
        super().__init__(
            eval_env,
            callback_on_new_best=on_best,
            callback_after_eval=callback_after_eval,
            n_eval_episodes=self.n_eval_missions * self.eval_n_agents,
            eval_freq=max(int(eval_freq), 1),
            log_path=str(log_path) if log_path is not None else None,
            best_model_save_path=None,
            deterministic=deterministic,
            verbose=verbose,
        )
        self._f1: list[float] = []
        self._entropy: list[float] = []

    def _init_callback(self) -> None:
        super()._init_callback()
        copies = max(self.training_env.num_envs // _agents_per_copy(self.model, self.training_env), 1)
        self.eval_freq = max(self.eval_freq_joint // copies, 1)
        self._restore_history()

    def _restore_history(self) -> None:
        """On resume, continue the run's evaluation record: keep its earlier evaluations and its
        best score, so the first evaluation after a resume cannot replace a better
        ``best_model.zip`` (SB3's callback starts from -inf and would)."""
        path = f"{self.log_path}.npz" if self.log_path is not None else None
        if path is None or not os.path.isfile(path):
            return
        with np.load(path) as data:
            self.evaluations_timesteps = [int(t) for t in data["timesteps"]]
            self.evaluations_results = [list(r) for r in data["results"]]
            self.evaluations_length = [list(e) for e in data["ep_lengths"]]
        selectable = [
            float(np.mean(r))
            for t, r in zip(self.evaluations_timesteps, self.evaluations_results)
            if t > self.select_after
        ]
        if selectable:
            self.best_mean_reward = max(selectable)

    def _on_step(self) -> bool:
        evaluating = self.eval_freq > 0 and self.n_calls % self.eval_freq == 0
        if evaluating:
            self._f1, self._entropy = [], []
            if self.eval_seed is not None:
                self.eval_env.seed(self.eval_seed)  # applies to the reset evaluate_policy starts with
        if not (evaluating and self.num_timesteps <= self.select_after):
            return super()._on_step()
        best, self.best_mean_reward = self.best_mean_reward, float("inf")  # logged, never the best
        try:
            return super()._on_step()
        finally:
            self.best_mean_reward = best

    def _log_success_callback(self, locals_: dict[str, Any], globals_: dict[str, Any]) -> None:
        super()._log_success_callback(locals_, globals_)
        if locals_["done"] and locals_["i"] % self.eval_n_agents == 0:
            info = locals_["info"]
            if "f1" in info:
                self._f1.append(float(info["f1"]))
                self.logger.record("eval/mean_f1", float(np.mean(self._f1)))
            if "entropy" in info:
                self._entropy.append(float(info["entropy"]))
                self.logger.record("eval/mean_entropy", float(np.mean(self._entropy)))
