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
