"""Figures: metric curves, training reward, mission picture and GIF, ablation bars."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_coma.app.evaluation import evaluate
from sb3_coma.experiments import plots

PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def results():
    return [evaluate(m, env="env3", n_trials=2, seed=0, budget=3) for m in ("lawnmower", "random")]


def _is_file(path, magic: bytes) -> bool:
    data = path.read_bytes()
    return len(data) > 1000 and data.startswith(magic)


def test_metric_curves_and_grid(results, tmp_path):
    assert _is_file(plots.plot_metric_curves(results, tmp_path / "curves.png"), PNG)
    assert _is_file(plots.plot_metric_grid({"none": results, "loud": results[:1]}, tmp_path / "grid.png"), PNG)
    with pytest.raises(ValueError):
        plots.plot_metric_curves([], tmp_path / "empty.png")


def test_mission_picture_and_gif(results, tmp_path):
    assert _is_file(plots.plot_mission(results[0], tmp_path / "m.png"), PNG)
    gif = plots.animate_mission(results[0], tmp_path / "m.gif", fps=4)
    assert _is_file(gif, b"GIF8")
    from PIL import Image

    with Image.open(gif) as im:
        assert im.n_frames == results[0].budget + 1
    with pytest.raises(ValueError, match="record"):
        plots.plot_mission(results[0], tmp_path / "x.png", trial=1)  # only trial 0 kept its belief


def test_ablation_bars(results, tmp_path):
    data = {("Base", "none"): results[0], ("Base", "loud"): results[1], ("CBAM", "none"): results[1]}
    assert _is_file(plots.plot_ablation(data, tmp_path / "bars.png"), PNG)


def test_training_reward_from_csv_monitor_and_tensorboard(tmp_path):
    rewards = np.linspace(-2, 3, 60) + np.sin(np.arange(60))
    metrics = tmp_path / "metrics.csv"
    metrics.write_text(
        "episode,timesteps,reward,f1\n" + "".join(f"{i + 1},{15 * (i + 1)},{r},0.5\n" for i, r in enumerate(rewards))
    )
    curve = plots.load_training_log(metrics)
    assert np.allclose(curve.rewards, rewards) and curve.episodes[0] == 1
    # VecMonitor over 4 agents: one row per agent of each mission, averaged back to one point
    monitor = tmp_path / "run" / "monitor.csv"
    monitor.parent.mkdir()
    monitor.write_text(
        '#{"t_start": 0, "env_id": "env1"}\nr,l,t\n'
        + "".join(f"{r},15,{i}\n" for i, r in enumerate(np.repeat(rewards[:10], 4)))
    )
    curve = plots.load_training_log(monitor.parent, agents_per_episode=4)
    assert np.allclose(curve.rewards, rewards[:10])
    # TensorBoard: the callbacks' per-mission scalar
    from torch.utils.tensorboard import SummaryWriter

    tb = tmp_path / "tb"
    with SummaryWriter(str(tb)) as writer:
        for i, r in enumerate(rewards[:20]):
            writer.add_scalar("mission/reward", float(r), i * 15)
            writer.add_scalar("train/loss", 1.0, i * 15)
    curve = plots.load_training_log(tb)
    assert np.allclose(curve.rewards, rewards[:20], atol=1e-5)
    png = plots.plot_training_reward({"csv": metrics, "tensorboard": tb}, tmp_path / "reward.png", window=5)
    assert _is_file(png, PNG)


def test_training_log_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        plots.load_training_log(tmp_path / "missing.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("step,loss\n1,0.3\n")
    with pytest.raises(ValueError, match="reward"):
        plots.load_training_log(bad)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match=r"no metrics\.csv"):
        plots.load_training_log(empty)


# --------------------------------------------------------------------------- readability (#37)
class FakeResult:
    """What the figures read of an evaluation result: per-trial metric curves of one method."""

    def __init__(self, method: str, n_trials: int = 4, steps: int = 7) -> None:
        rng = np.random.default_rng(sum(map(ord, method)))
        self.method, self.env, self.n_trials = method, "env1", n_trials
        rise = np.linspace(0.1, 0.8, steps) * rng.uniform(0.8, 1.0)
        self.f1 = np.clip(rise + rng.normal(0, 0.04, (n_trials, steps)), 0, 1)
        self.entropy = np.clip(1 - rise + rng.normal(0, 0.04, (n_trials, steps)), 0, 1)
        self.team_entropy = np.clip(self.entropy + 0.1, 0, 1)

    def metric(self, name: str) -> np.ndarray:
        return getattr(self, name)

    def mean_std(self, name: str, fraction: float) -> tuple[float, float]:
        final = getattr(self, name)[:, -1]
        return float(final.mean()), float(final.std())


#: The rows of the generated tables and two more: past the palette's eight colours.
METHODS = ["coma", "ag", "ag-k3", "lawnmower", "random", "oracle", "ag-comm", "ag-central", "my model"]


@pytest.fixture
def drawn(monkeypatch):
    """Every figure a plot function saves, kept for inspection (after it was written)."""
    figures = []
    save = plots._save

    def keep(fig, path, **kwargs):
        figures.append(fig)
        return save(fig, path, **kwargs)

    monkeypatch.setattr(plots, "_save", keep)
    return figures


def _hex(colour) -> str:
    from matplotlib import colors as mcolors

    return mcolors.to_hex(colour).upper()


def _styles(fig) -> dict[str, tuple]:
    """label -> (colour, line style, marker) of every legend entry that is a line (errorbar
    containers by their data line), checked to be the same wherever the label appears."""
    from matplotlib.container import ErrorbarContainer
    from matplotlib.lines import Line2D

    found: dict[str, tuple] = {}
    for ax in fig.axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            line = handle.lines[0] if isinstance(handle, ErrorbarContainer) else handle
            if not isinstance(line, Line2D):
                continue
            # the dash pattern tells custom dashes apart (get_linestyle says "--" for all of them)
            dashes = str(line.get_linestyle()) + str(getattr(line, "_unscaled_dash_pattern", ""))
            style = (_hex(line.get_color()), dashes, line.get_marker())
            assert found.setdefault(label, style) == style, f"{label} drawn in two styles"
    return found


def _check_readable(fig, n_styles: int) -> None:
    """Okabe-Ito colours, one (colour, line style, marker) per legend entry, a legend that
    overlaps no axes, and every axes with both labels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.transforms import Bbox

    from sb3_coma.experiments.figure_style import OKABE_ITO

    styles = _styles(fig)
    assert len(styles) == n_styles, sorted(styles)
    assert {colour for colour, _, _ in styles.values()} <= set(OKABE_ITO), styles
    assert len(set(styles.values())) == len(styles), "two entries share colour, line style and marker"
    assert all(marker not in ("None", "", None) for _, _, marker in styles.values())
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]
    assert legends, "no legend"
    for legend in legends:
        box = legend.get_window_extent(renderer)
        for ax in fig.axes:
            inside = Bbox.intersection(box, ax.get_window_extent(renderer))
            assert inside is None or inside.width * inside.height < 1.0, f"legend over the axes {ax.get_title()!r}"
    for ax in fig.axes:
        assert ax.get_xlabel().strip(), ax.get_title()
    assert all(ax.get_ylabel().strip() for ax in fig.axes if ax.get_subplotspec().is_first_col())


def _legend_texts(fig) -> str:
    legends = [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]
    return " ".join(
        [legend.get_title().get_text() for legend in legends] + [t.get_text() for lg in legends for t in lg.get_texts()]
    )


def test_metric_curves_are_readable(drawn, tmp_path):
    results = [FakeResult(m) for m in METHODS]
    plots.plot_metric_curves(results, tmp_path / "curves.png")
    plots.plot_metric_grid({"none": results[:5], "loud": results[3:]}, tmp_path / "grid.png")
    for fig in drawn:
        _check_readable(fig, len(METHODS))
        assert "±1 s.d. over 4 trials" in _legend_texts(fig)  # what the shaded bands are
        assert "bits per valuable cell" in " ".join(ax.get_ylabel() for ax in fig.axes)
    styles = _styles(drawn[0])
    assert styles["coma"][0] == "#0072B2" and styles["ag"][0] == "#D55E00"  # fixed across figures
    assert _styles(drawn[1]) == styles  # the grid draws each method as the curves do


def test_training_reward_ablation_and_noise_sweep_are_readable(drawn, tmp_path):
    from sb3_coma.experiments.figure_style import OKABE_ITO
    from sb3_coma.experiments.noise_sweep import NoiseSweepResult, SweepPoint

    x = np.arange(1, 41, dtype=float)
    logs = {m: plots.TrainingCurve(x, np.sin(x / (3 + k)), m) for k, m in enumerate(METHODS[:3])}
    plots.plot_training_reward(logs, tmp_path / "reward.png", window=5)
    _check_readable(drawn[-1], 3)
    assert "trailing mean of 5" in _legend_texts(drawn[-1])

    points = [SweepPoint(s, 0.8, 0.0, d, "sigma" if s else "centre") for d in ("soft", "threshold") for s in (0, 0.1)]
    arms = ["ag", "coma", "Base"]
    sweep = NoiseSweepResult("env3", 4, 0, {}, points, arms)
    sweep.results = {(arm, p): FakeResult(f"{arm}{p.sigma}{p.decoder}") for arm in arms for p in points}
    plots.plot_noise_sweep(sweep, tmp_path / "sweep.png")
    _check_readable(drawn[-1], len(arms) * 2)  # each arm in both decoders
    assert "±1 s.e. of the mean" in _legend_texts(drawn[-1])

    bars = {(v, n): FakeResult(v + n) for v in ("Base", "CBAM", "SenDFuse", "Full") for n in ("none", "loud")}
    plots.plot_ablation(bars, tmp_path / "bars.png")
    fig = drawn[-1]
    fills = {(_hex(p.get_facecolor()), p.get_hatch()) for ax in fig.axes for p in ax.patches}
    assert len(fills) == 4 and {colour for colour, _ in fills} <= set(OKABE_ITO)
    assert "±1 s.d. over 4 trials" in _legend_texts(fig)
    _check_legend_outside_only(fig)


def _check_legend_outside_only(fig) -> None:
    """The legend check of :func:`_check_readable` alone (bar charts have no line styles)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.transforms import Bbox

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    for legend in fig.legends:
        for ax in fig.axes:
            inside = Bbox.intersection(legend.get_window_extent(renderer), ax.get_window_extent(renderer))
            assert inside is None or inside.width * inside.height < 1.0
    assert fig.legends and all(ax.get_xlabel() and ax.get_ylabel() for ax in fig.axes)


def test_method_styles_are_distinct_and_stable():
    from sb3_coma.experiments.figure_style import OKABE_ITO, method_styles

    many = method_styles([f"m{k}" for k in range(40)])
    assert len({(s.color, s.linestyle, s.marker) for s in many.values()}) == 40
    assert {s.color for s in many.values()} == set(OKABE_ITO)
    a = method_styles(["random", "coma"])
    b = method_styles(["coma", "x", "COMA (oracle warm start)", "random"])
    assert a["coma"] == b["coma"] and a["random"] == b["random"]  # the well-known keep their look
    assert b["COMA (oracle warm start)"] != b["coma"]  # the slot is taken: the next free one
    assert method_styles(["COMA (oracle warm start)"])["COMA (oracle warm start)"] == a["coma"]


def test_learning_curves_are_readable(tmp_path):
    from sb3_coma.experiments import learning_curves as lc

    validation = lc.Validation("UavIpp-Env1-v0", "{}", 4, 1000, 2)
    steps = np.arange(1, 9) * 300.0
    runs = [lc.RunCurve(tmp_path / f"s{k}", k, 15, validation, steps, steps, steps) for k in range(3)]
    rng = np.random.default_rng(0)
    levels = {name: (0.6 + 0.05 * k, 0.4 - 0.05 * k) for k, name in enumerate(lc.BASELINES)}
    groups = [
        lc.GroupCurve(
            name, runs, steps, steps / 15, rng.uniform(0.5, 0.8, (3, 8)), rng.uniform(0.2, 0.5, (3, 8)), levels
        )
        for name in ("env1", "env3")
    ]
    fig = lc.draw_groups(groups)
    _check_readable(fig, 1 + len(lc.BASELINES))
    assert "±1 s.d. over seeds" in _legend_texts(fig)
    assert lc.plot_groups(groups, tmp_path / "curves.png").read_bytes().startswith(PNG)


def test_learning_curves_count_the_teacher_labelled_missions(tmp_path):
    """A warm-started run's curve starts after its DAgger missions, with the clone's phase marked (#35)."""
    import json

    from sb3_coma.experiments import learning_curves as lc

    run = tmp_path / "warm"
    run.mkdir()
    (run / "warm_start.json").write_text(json.dumps({"teacher": "oracle", "rounds": 8, "missions": 128}))
    assert lc._teacher_missions(run) == 1024 and lc._teacher_missions(tmp_path) == 0
    validation = lc.Validation("UavIpp-Env3-v0", "{}", 4, 1000, 4)
    steps = np.arange(1, 5) * 3000.0
    warm = [lc.RunCurve(run, k, 15, validation, steps, steps, steps, teacher_missions=1024) for k in range(2)]
    group = lc.build_group("env3", warm, lambda _v: {name: (0.7, 0.4) for name in lc.BASELINES})
    assert group.teacher_missions == 1024 and list(group.missions) == [1224.0, 1424.0, 1624.0, 1824.0]
    fig = lc.draw_groups([group])
    assert "DAgger: teacher-labelled missions" in _legend_texts(fig)
    assert fig.axes[0].get_xlim()[0] == 0
    cold = lc.RunCurve(run, 2, 15, validation, steps, steps, steps)
    with pytest.raises(lc.RunDirError, match="teacher-labelled missions"):
        lc.build_group("mixed", [*warm, cold], lambda _v: {})
