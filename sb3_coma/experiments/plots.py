"""The paper's figures as PNG/GIF files (matplotlib, Agg backend: no display needed).

* :func:`plot_metric_curves` - F1 and entropy vs sampling step, mean with a +-std band per method
  (Figures 4 and 5); :func:`plot_metric_grid` - the same per noise level (ablation);
* :func:`plot_training_reward` - team reward vs training episode (Figure 3) from a run's logs,
  read by :func:`load_training_log`;
* :func:`plot_mission` - ground truth, final global belief and the UAVs' 3-D trajectories
  coloured by altitude; :func:`animate_mission` - the same mission step by step as a GIF;
* :func:`plot_ablation` - final F1 / entropy of the ablation variants per noise level;
* :func:`plot_noise_sweep` - global and team entropy at 100 % vs each channel-noise axis per arm.

Training logs understood by :func:`load_training_log` (first match wins):

1. a CSV with columns ``episode`` and ``reward`` (``sb3-coma train``'s ``metrics.csv``; other
   columns are ignored; without ``episode`` the row number is the episode);
2. an SB3 ``monitor.csv`` / VecMonitor CSV (a ``#{...}`` JSON line, then ``r,l,t``): ``r`` is the
   reward. VecMonitor over the multi-agent vec env writes one row per agent of a mission; pass
   ``agents_per_episode=n_agents`` to average each mission's rows into one point;
3. a TensorBoard event file or directory: scalar ``mission/reward`` (one point per mission),
   else ``rollout/ep_rew_mean``, else the first tag containing "reward"; or name ``tag=``.

A directory is searched for ``metrics.csv``, then ``*monitor.csv``, then event files.

Every figure is meant to be read by anyone, printed in grey too: each method has a colour of
Okabe and Ito's colour-blind-safe palette, a line style and a marker of its own
(:mod:`sb3_coma.experiments.figure_style`), the legend sits outside the axes so that it never
hides data, what a band or an error bar spans is said in the legend or the title, and every axis
says its unit.
"""

from __future__ import annotations

import csv
import io
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib import cm, colors
from matplotlib.artist import Artist
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from sb3_coma.experiments.figure_style import AXIS_TITLES, OKABE_ITO, MethodStyle, method_styles, uav_colour

if TYPE_CHECKING:  # pragma: no cover
    from sb3_coma.common.evaluation import EvaluationResult
    from sb3_coma.experiments.noise_sweep import NoiseSweepResult

PathLike = str | os.PathLike
#: Preferred TensorBoard reward tags, in order.
REWARD_TAGS = ("mission/reward", "episode/reward", "rollout/ep_rew_mean")
ALTITUDE_CMAP = "viridis"  # perceptually uniform and colour-blind safe
UAV_COLOURS = OKABE_ITO
#: Axis labels with their units: F1 is a fraction; entropy is the mean binary entropy in bits over
#: the truly valuable cells (1 at the start of a mission); a step is one decision of every UAV.
F1_LABEL = "F1-score (0-1, higher is better)"
ENTROPY_LABEL = "entropy (bits per valuable cell, lower is better)"
STEP_LABEL = "step (decisions per UAV)"


def _save(fig: plt.Figure, path: PathLike, **kwargs) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, **kwargs)
    plt.close(fig)
    return path


def _legend_outside(fig: plt.Figure, axes: Sequence[plt.Axes], extra: Sequence[Patch] = (), **kwargs) -> None:
    """One legend for the figure, right of the axes (constrained layout makes room): it never
    covers a curve, whatever the data. Entries are taken from every axes, each label once."""
    entries: dict[str, Artist] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    for patch in extra:
        entries.setdefault(str(patch.get_label()), patch)
    fig.legend(
        list(entries.values()),
        list(entries),
        loc="outside right upper",
        fontsize=8,
        title_fontsize=8,
        alignment="left",
        **kwargs,
    )


def _band_patch(results: Sequence[EvaluationResult]) -> Patch:
    """Legend entry saying what the shaded bands are: the population s.d. (``ddof=0``) over the
    trials of each method, the spread of single missions, not an error of the mean."""
    counts = sorted({int(r.n_trials) for r in results})
    n = f"{counts[0]}" if len(counts) == 1 else "each method's"
    return Patch(facecolor="0.5", alpha=0.25, label=f"shaded: ±1 s.d. over {n} trials")


# ---------------------------------------------------------------------------------------------
# Figures 4 / 5: metrics vs step
# ---------------------------------------------------------------------------------------------
def _curves(
    ax: plt.Axes,
    results: Sequence[EvaluationResult],
    metric: str,
    labels: Sequence[str],
    styles: Mapping[str, MethodStyle],
) -> None:
    """Mean over trials per step, one line per method (its colour, style and marker), with a
    band of ±1 population s.d. in the line's colour."""
    for res, label in zip(results, labels):
        values = res.metric(metric)
        steps = np.arange(values.shape[1])
        mean, std = values.mean(axis=0), values.std(axis=0)
        style = styles[label]
        ax.plot(steps, mean, label=label, lw=1.6, ms=4, markevery=max(1, len(steps) // 8), **style.line())
        ax.fill_between(steps, mean - std, mean + std, color=style.color, alpha=0.15, lw=0)
    ax.set_xlabel(STEP_LABEL)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(alpha=0.3)


def plot_metric_curves(
    results: Sequence[EvaluationResult], path: PathLike, title: str | None = None, labels: Sequence[str] | None = None
) -> Path:
    """F1 (left) and entropy (right) vs step, mean ± s.d. over trials, one line per result."""
    if not results:
        raise ValueError("plot_metric_curves needs at least one result")
    labels = list(labels) if labels is not None else [r.method for r in results]
    styles = method_styles(labels)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    for ax, metric, name in zip(axes, ("f1", "entropy"), (F1_LABEL, ENTROPY_LABEL)):
        _curves(ax, results, metric, labels, styles)
        ax.set_ylabel(name)
    axes[0].set_ylim(0, 1)
    axes[1].set_ylim(0, 1.05)
    _legend_outside(fig, axes, [_band_patch(results)])
    r = results[0]
    fig.suptitle(title or f"{r.env}: F1 and entropy vs step ({r.n_trials} trials, mean ± 1 s.d.)")
    return _save(fig, path, dpi=120)


def plot_metric_grid(
    results: Mapping[str, Sequence[EvaluationResult]],
    path: PathLike,
    title: str | None = None,
    labels: Mapping[str, Sequence[str]] | None = None,
) -> Path:
    """F1 (top) and entropy (bottom) vs step, one column per group (e.g. noise level); a method
    keeps its style in every column, and the one legend lists every method."""
    groups = [g for g in results if results[g]]
    assert groups, "plot_metric_grid needs at least one non-empty group"  # its callers write it only then
    labs = {g: list(labels[g]) if labels and g in labels else [r.method for r in results[g]] for g in groups}
    styles = method_styles(label for g in groups for label in labs[g])
    fig, axes = plt.subplots(2, len(groups), figsize=(4.2 * len(groups) + 2.2, 7), squeeze=False, layout="constrained")
    for j, group in enumerate(groups):
        for i, metric in enumerate(("f1", "entropy")):
            _curves(axes[i, j], results[group], metric, labs[group], styles)
            axes[i, j].set_ylim(0, 1.05)
        axes[0, j].set_title(group)
    axes[0, 0].set_ylabel(F1_LABEL)
    axes[1, 0].set_ylabel(ENTROPY_LABEL)
    _legend_outside(fig, list(axes.flat), [_band_patch([r for g in groups for r in results[g]])])
    if title:
        fig.suptitle(title)
    return _save(fig, path, dpi=110)


# ---------------------------------------------------------------------------------------------
# Figure 3: training reward
# ---------------------------------------------------------------------------------------------
@dataclass
class TrainingCurve:
    """Team reward per training episode read from a log, and where it came from."""

    episodes: np.ndarray
    rewards: np.ndarray
    source: str


def _read_csv(path: Path, agents_per_episode: int) -> TrainingCurve:
    text = path.read_text()
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")]
    reader = csv.DictReader(io.StringIO("\n".join(lines)))
    fields = [f.strip() for f in (reader.fieldnames or [])]
    rows = list(reader)
    key = "reward" if "reward" in fields else "r" if "r" in fields else None
    if key is None:
        raise ValueError(f"{path}: no 'reward' (or monitor 'r') column; columns are {fields}")
    rewards = np.array([float(r[key]) for r in rows], dtype=np.float64)
    if "episode" in fields and agents_per_episode == 1:
        episodes = np.array([float(r["episode"]) for r in rows])
    else:
        episodes = np.arange(1, len(rewards) + 1, dtype=np.float64)
    if agents_per_episode > 1:
        n = len(rewards) // agents_per_episode
        rewards = rewards[: n * agents_per_episode].reshape(n, agents_per_episode).mean(axis=1)
        episodes = np.arange(1, n + 1, dtype=np.float64)
    return TrainingCurve(episodes, rewards, str(path))


def _read_tensorboard(path: Path, tag: str | None) -> TrainingCurve:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(path), size_guidance={"scalars": 0})
    acc.Reload()
    tags = acc.Tags().get("scalars", [])
    if tag is None:
        tag = next((t for t in REWARD_TAGS if t in tags), None) or next(
            (t for t in tags if "reward" in t.lower()), None
        )
    if tag is None or tag not in tags:
        raise ValueError(
            f"{path}: no reward scalar{'' if tag is None else f' {tag!r}'} in the TensorBoard log; "
            f"scalars are {sorted(tags)}"
        )
    events = acc.Scalars(tag)
    rewards = np.array([e.value for e in events], dtype=np.float64)
    return TrainingCurve(np.arange(1, len(rewards) + 1, dtype=np.float64), rewards, f"{path}:{tag}")


def load_training_log(path: PathLike, agents_per_episode: int = 1, tag: str | None = None) -> TrainingCurve:
    """Team reward per episode from a CSV, a monitor CSV or a TensorBoard log (module docstring)."""
    path = Path(path)
    # the edge (sb3-coma evaluate --agents-per-episode) checked it: a bad one is our bug
    assert not isinstance(agents_per_episode, bool) and int(agents_per_episode) == agents_per_episode >= 1, (
        f"agents_per_episode={agents_per_episode!r}: must be an integer >= 1"
    )
    if not path.exists():
        raise FileNotFoundError(f"training log not found: {str(path)!r}")
    if path.is_dir():
        for pattern in ("metrics.csv", "*monitor.csv", "**/metrics.csv", "**/*monitor.csv"):
            found = sorted(path.glob(pattern))
            if found:
                return _read_csv(found[0], int(agents_per_episode))
        if sorted(path.glob("**/events.out.tfevents.*")):
            events = sorted(path.glob("**/events.out.tfevents.*"))
            return _read_tensorboard(events[0].parent, tag)
        raise ValueError(f"{path}: no metrics.csv, monitor CSV or TensorBoard event file inside")
    if path.name.startswith("events.out.tfevents"):
        return _read_tensorboard(path, tag)
    return _read_csv(path, int(agents_per_episode))


def _rolling_mean(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over up to ``window`` points (shorter at the start, no lag padding)."""
    csum = np.concatenate([[0.0], np.cumsum(values)])
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(idx - window, 0)
    return (csum[idx] - csum[lo]) / (idx - lo)


def plot_training_reward(
    logs: PathLike | TrainingCurve | Mapping[str, PathLike | TrainingCurve],
    path: PathLike,
    window: int = 20,
    agents_per_episode: int = 1,
    title: str | None = None,
) -> Path:
    """Team reward vs training episode (Figure 3): raw values faint, a trailing mean on top."""
    if isinstance(logs, (str, os.PathLike, TrainingCurve)):
        logs = {"reward": logs}
    assert logs, "plot_training_reward needs at least one log"  # its callers draw it only then
    styles = method_styles(logs)
    fig, ax = plt.subplots(figsize=(8.5, 4), layout="constrained")
    for label, log in logs.items():
        curve = log if isinstance(log, TrainingCurve) else load_training_log(log, agents_per_episode)
        if len(curve.rewards) == 0:
            raise ValueError(f"training log {curve.source} has no episodes")
        style = styles[label]
        ax.plot(curve.episodes, curve.rewards, color=style.color, alpha=0.2, lw=0.8)
        mean = _rolling_mean(curve.rewards, max(int(window), 1))
        ax.plot(curve.episodes, mean, lw=1.8, ms=4, markevery=max(1, len(mean) // 8), label=label, **style.line())
    ax.set_xlabel("training episode (one mission of the team)")
    ax.set_ylabel("team reward (sum over the mission)")
    ax.grid(alpha=0.3)
    faint = Patch(facecolor="0.5", alpha=0.2, label="faint: each episode")
    _legend_outside(fig, [ax], [faint], title=f"bold: trailing mean of {window}")
    ax.set_title(title or f"Training reward (trailing mean over {window} episodes)")
    return _save(fig, path, dpi=120)


# ---------------------------------------------------------------------------------------------
# missions
# ---------------------------------------------------------------------------------------------
def _no_fly_overlay(ax: plt.Axes, no_fly: np.ndarray | None, field_size: float) -> None:
    """Hatch the no-fly lattice columns (5 m blocks around each lattice point)."""
    if no_fly is None or not np.any(no_fly):
        return
    lat = no_fly.shape[0]
    half = field_size / (lat - 1) / 2
    for iy, ix in zip(*np.nonzero(no_fly)):
        x, y = ix * field_size / (lat - 1), iy * field_size / (lat - 1)
        ax.add_patch(
            plt.Rectangle(
                (max(x - half, 0), max(y - half, 0)),
                2 * half,
                2 * half,
                fill=True,
                facecolor=(0.85, 0.2, 0.2, 0.35),
                edgecolor="tab:red",
                hatch="//",
                lw=0.5,
            )
        )


def _trail_2d(ax: plt.Axes, traj: np.ndarray, norm: colors.Normalize, upto: int | None = None) -> None:
    """Each UAV's path so far, segments coloured by altitude; a marker at its current position."""
    upto = traj.shape[0] if upto is None else upto
    cmap = plt.get_cmap(ALTITUDE_CMAP)
    for u in range(traj.shape[1]):
        pts = traj[:upto, u]
        if len(pts) > 1:
            segs = np.stack([pts[:-1, :2], pts[1:, :2]], axis=1)
            ax.add_collection(LineCollection(list(segs), colors=cmap(norm(pts[1:, 2])), lw=2.5))
        ax.plot(pts[0, 0], pts[0, 1], "o", ms=5, mfc="none", mec=uav_colour(u))
        ax.plot(pts[-1, 0], pts[-1, 1], "^", ms=8, color=uav_colour(u), mec="k")


def _check_recorded(result: EvaluationResult, trial: int, picture: bool = False, frames: bool = False) -> None:
    """What a mission's figure reads, recorded for ``trial``: its trajectory, and for the picture
    (``picture``) the final belief and the truth, for the animation (``frames``) the per-step
    beliefs. One table, one raise: the first thing missing is named with how to record it."""
    in_range = 0 <= trial < result.n_trials
    beliefs = result.final_beliefs
    needs = (
        (in_range, f"trial {trial} out of range: the result has {result.n_trials} trials"),
        (
            not in_range or not np.isnan(result.trajectories[trial]).any(),
            "this result has no trajectories (evaluated on an env without recorded copies)",
        ),
        (
            not picture or (beliefs is not None and trial < len(beliefs)),
            f"trial {trial} has no recorded final belief: evaluate(..., record={trial + 1})",
        ),
        (
            not picture or result.ground_truth is not None,
            "this result records no ground truth map (evaluate_policy records one)",
        ),
        (
            not frames or result.belief_frames is not None,
            "this result has no per-step beliefs: evaluate(..., record=1) keeps them for trial 0",
        ),
    )
    missing = next((message for ok, message in needs if not ok), None)
    if missing is not None:
        raise ValueError(missing)


def plot_mission(result: EvaluationResult, path: PathLike, trial: int = 0) -> Path:
    """Ground truth, final global belief, and the UAVs' 3-D trajectories coloured by altitude."""
    _check_recorded(result, trial, picture=True)
    truth = result.ground_truth
    assert truth is not None and result.final_beliefs is not None  # _check_recorded
    size = result.field_size
    traj = result.trajectories[trial]
    norm = colors.Normalize(min(result.altitudes), max(result.altitudes))
    extent = (0, size, 0, size)
    fig = plt.figure(figsize=(15, 4.8))
    ax1 = fig.add_subplot(1, 3, 1)
    ax1.imshow(truth, origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=1)
    _no_fly_overlay(ax1, result.no_fly, size)
    ax1.set_title("ground truth (black: valuable, red: no-fly)")
    ax2 = fig.add_subplot(1, 3, 2)
    im = ax2.imshow(result.final_beliefs[trial], origin="lower", extent=extent, cmap="Greys", vmin=0, vmax=1)
    _trail_2d(ax2, traj, norm)
    f1, ent = result.f1[trial, -1], result.entropy[trial, -1]
    ax2.set_title(f"final global belief (F1 {f1:.3f}, entropy {ent:.3f})")
    fig.colorbar(im, ax=ax2, fraction=0.046, pad=0.04, label="P(valuable)")
    for ax in (ax1, ax2):
        ax.set_xlim(0, size)
        ax.set_ylim(0, size)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
    ax3 = fig.add_subplot(1, 3, 3, projection="3d")
    small = _block_mean(truth, 32)  # a coarse floor keeps the 3-D draw fast
    gy, gx = np.mgrid[0 : small.shape[0], 0 : small.shape[1]] * (size / small.shape[0])
    ax3.plot_surface(
        gx,
        gy,
        np.zeros_like(gx),
        facecolors=plt.get_cmap("Greys")(0.15 + 0.6 * small),
        shade=False,
        rstride=1,
        cstride=1,
        linewidth=0,
    )
    cmap = plt.get_cmap(ALTITUDE_CMAP)

    for u in range(traj.shape[1]):
        pts = traj[:, u]
        segs = np.stack([pts[:-1], pts[1:]], axis=1)
        ax3.add_collection3d(Line3DCollection(segs, colors=cmap(norm(pts[1:, 2])), lw=2.5))
        ax3.scatter(*pts[0], marker="o", s=25, color=uav_colour(u))
        ax3.scatter(*pts[-1], marker="^", s=45, color=uav_colour(u), edgecolor="k")
        ax3.text(*pts[0], f" {u}", fontsize=8)
    ax3.set_xlim(0, size)
    ax3.set_ylim(0, size)
    ax3.set_zlim(0, max(result.altitudes) * 1.1)
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    ax3.set_title("trajectories (o start, ^ end)")
    fig.colorbar(cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax3, fraction=0.03, pad=0.1, label="altitude (m)")
    fig.suptitle(f"{result.env}, {result.method}: trial {trial} (seed {result.seed + trial})")
    fig.tight_layout()
    return _save(fig, path, dpi=110)


def _block_mean(image: np.ndarray, side: int) -> np.ndarray:
    """Block means of a square image down to about ``side`` x ``side`` (fraction valuable per block)."""
    k = max(1, image.shape[0] // side)
    n = image.shape[0] // k
    return image[: n * k, : n * k].reshape(n, k, n, k).mean(axis=(1, 3))


def _figure_rgb(fig: plt.Figure) -> np.ndarray:
    canvas = fig.canvas
    assert isinstance(canvas, FigureCanvasAgg)  # this module selects the Agg backend
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def animate_mission(result: EvaluationResult, path: PathLike, fps: float = 2.0, max_side: int = 247) -> Path:
    """GIF of trial 0 step by step: the global belief, each UAV's path (coloured by altitude) and
    its position, with F1 and entropy in the title."""
    from PIL import Image

    _check_recorded(result, 0, frames=True)
    frames = result.belief_frames
    assert frames is not None  # _check_recorded
    size = result.field_size
    stride = max(1, int(np.ceil(frames.shape[-1] / max_side)))
    norm = colors.Normalize(min(result.altitudes), max(result.altitudes))
    traj = result.trajectories[0]
    fig, ax = plt.subplots(figsize=(4.6, 4.6), dpi=80)
    images = []
    for t in range(frames.shape[0]):
        ax.clear()
        ax.imshow(
            frames[t, ::stride, ::stride].astype(np.float32),
            origin="lower",
            extent=(0, size, 0, size),
            cmap="Greys",
            vmin=0,
            vmax=1,
        )
        _no_fly_overlay(ax, result.no_fly, size)
        _trail_2d(ax, traj, norm, upto=t + 1)
        ax.set_xlim(0, size)
        ax.set_ylim(0, size)
        ax.set_title(
            f"{result.method} step {t}/{result.budget}  F1 {result.f1[0, t]:.3f}  H {result.entropy[0, t]:.3f}",
            fontsize=9,
        )
        ax.set_xticks([])
        ax.set_yticks([])
        fig.tight_layout()
        images.append(Image.fromarray(_figure_rgb(fig)))
    plt.close(fig)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    duration = round(1000.0 / fps)
    images[0].save(
        path,
        save_all=True,
        append_images=images[1:],
        duration=[duration] * (len(images) - 1) + [3 * duration],
        loop=0,
        optimize=True,
    )
    return path


# ---------------------------------------------------------------------------------------------
# ablation
# ---------------------------------------------------------------------------------------------
def plot_ablation(
    results: Mapping[tuple[str, str], EvaluationResult], path: PathLike, title: str | None = None
) -> Path:
    """Grouped bars: final F1 (left) and entropy (right) ± s.d. per noise level and variant; each
    variant a colour and a hatch of its own, the whiskers' meaning in the legend's title.

    ``results`` maps (variant label, noise level) to its result.
    """
    assert results, "plot_ablation needs at least one result"  # its callers draw it only then
    variants = list(dict.fromkeys(v for v, _ in results))
    noises = list(dict.fromkeys(n for _, n in results))
    styles = method_styles(variants)
    width = 0.8 / len(variants)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), layout="constrained")
    names = ("F1-score at 100 % of the budget (0-1)", "entropy at 100 % (bits per valuable cell)")
    for ax, metric, name in zip(axes, ("f1", "entropy"), names):
        for k, variant in enumerate(variants):
            xs, means, stds = [], [], []
            for j, noise in enumerate(noises):
                res = results.get((variant, noise))
                if res is None:
                    continue
                m, s = res.mean_std(metric, 1.0)
                xs.append(j + (k - (len(variants) - 1) / 2) * width)
                means.append(m)
                stds.append(s)
            style = styles[variant]
            ax.bar(xs, means, width * 0.95, yerr=stds, capsize=3, label=variant, color=style.color, hatch=style.hatch)
        ax.set_xticks(range(len(noises)), noises)
        ax.set_xlabel("channel noise (preset)")
        ax.set_ylabel(name)
        ax.set_ylim(0, 1.05)
        ax.grid(axis="y", alpha=0.3)
    counts = sorted({int(r.n_trials) for r in results.values()})
    n = f"{counts[0]}" if len(counts) == 1 else "each variant's"
    _legend_outside(fig, axes, title=f"bars: mean; whiskers:\n±1 s.d. over {n} trials")
    if title:
        fig.suptitle(title)
    return _save(fig, path, dpi=120)


# ---------------------------------------------------------------------------------------------
# noise sweep
# ---------------------------------------------------------------------------------------------
#: The swept channel axes with what they measure (I_r = a I + n per received cell, a ~ U(a_low, 1),
#: n ~ N(0, sigma^2); docs/environment.md), for the x labels.
SWEEP_AXIS_LABELS = {
    "sigma": "sigma (s.d. of the added noise, in map units 0-1)",
    "alpha_low": "a_low (lowest channel gain a, fraction)",
    "drop_probability": "drop p (probability a message is lost)",
}
#: Line style of each decoder in the noise sweep (an arm has its colour and marker).
DECODER_LINESTYLES = {"soft": "-", "threshold": "--"}


def _sweep_curve(
    result: NoiseSweepResult, axis: str, arm: str, decoder: str, metric: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(axis values, means, standard errors or None) of one arm and decoder: along the axis of a
    one-axis sweep, or, in a grid, averaged over the other axes (no error bar then)."""
    if not any(p.axis == "grid" for p in result.points):
        return result.curves(axis, arm, decoder, metric)
    xs = sorted({p.value(axis) for p in result.points})
    ys = [
        np.mean(
            [
                result.final(arm, p, metric).mean()
                for p in result.points
                if p.decoder == decoder and p.value(axis) == x and (arm, p) in result.results
            ]
        )
        for x in xs
    ]
    return np.array(xs), np.array(ys), None


def plot_noise_sweep(result: NoiseSweepResult, path: PathLike, title: str | None = None) -> Path:
    """Entropy at 100 % vs each swept channel axis, one line per arm and decoder (the arm's colour
    and marker; solid: soft decoder, dashed: threshold), error bars = ±1 standard error of the
    mean over the shared missions; top row the global map's entropy (the paper's), bottom row the
    team entropy on the UAVs' own maps.

    ``result`` is a ``sb3_coma.experiments.noise_sweep.NoiseSweepResult``.
    """
    axes_swept = [a for a in AXIS_TITLES if any(p.axis == a or p.axis == "grid" for p in result.points)] or ["sigma"]
    decoders = list(dict.fromkeys(p.decoder for p in result.points))
    assert result.results, "plot_noise_sweep needs at least one result"  # its callers draw it only then
    styles = method_styles(result.arms)
    fig, grid = plt.subplots(
        2,
        len(axes_swept),
        figsize=(4.2 * len(axes_swept) + 2.4, 6.4),
        squeeze=False,
        sharey="row",
        layout="constrained",
    )
    rows = (("entropy", "entropy of the global map"), ("team_entropy", "team entropy (own maps)"))
    for col, axis in enumerate(axes_swept):
        for row, (metric, name) in enumerate(rows):
            ax = grid[row][col]
            for arm in result.arms:
                for decoder in decoders:
                    x, mean, se = _sweep_curve(result, axis, arm, decoder, metric)
                    if len(x) == 0:
                        continue
                    style = styles[arm]
                    ax.errorbar(
                        x,
                        mean,
                        yerr=se,
                        color=style.color,
                        marker=style.marker,
                        ls=DECODER_LINESTYLES.get(decoder, ":"),
                        ms=4,
                        lw=1.4,
                        capsize=2,
                        label=f"{arm} ({decoder})",
                    )
            ax.set_xlabel(SWEEP_AXIS_LABELS.get(axis, AXIS_TITLES[axis]))
            if col == 0:
                ax.set_ylabel(f"{name} at 100 %\n(bits per valuable cell)")
            ax.grid(alpha=0.3)
    grid_sweep = any(p.axis == "grid" for p in result.points)
    bars = "mean over the other axes, no error bars" if grid_sweep else "error bars: ±1 s.e. of the mean"
    _legend_outside(fig, list(grid.flat), title=f"{bars}\nsolid: soft decoder\ndashed: threshold")
    fig.suptitle(title or f"{result.env}: entropy vs channel noise ({result.n_missions} shared missions)")
    return _save(fig, path, dpi=120)
