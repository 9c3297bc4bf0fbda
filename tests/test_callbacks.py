"""Callbacks: mission metrics equal the env's infos, checkpoints, stop-on-target, atomic writes."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from stable_baselines3.common.logger import KVWriter, Logger, make_output_format
from stable_baselines3.common.vec_env import VecEnvWrapper

import uav_ipp
from sb3_coma.coma import COMA
from sb3_coma.common.callbacks import (
    EpisodeMetricsCallback,
    JointCheckpointCallback,
    MissionEvalCallback,
    ProgressLinesCallback,
    StopOnTargetCallback,
    truncate_metrics_csv,
)
from sb3_coma.common.checkpoints import (
    CheckpointError,
    atomic_save,
    atomic_write_text,
    find_checkpoints,
    validate_checkpoint,
)

N_AGENTS, BUDGET = 2, 3


# Runs write run folders and logs into the working directory: keep them in tmp_path.
pytestmark = pytest.mark.usefixtures("tmp_cwd")


class Recorder(VecEnvWrapper):
    """Keeps (dones, infos) of every step, as the learner receives them."""

    def __init__(self, venv):
        super().__init__(venv)
        self.n_agents = venv.n_agents
        self.steps: list[tuple[np.ndarray, list[dict]]] = []

    def reset(self):
        return self.venv.reset()

    def step_wait(self):
        obs, rewards, dones, infos = self.venv.step_wait()
        kept = [{k: v for k, v in info.items() if k != "terminal_observation"} for info in infos]
        self.steps.append((np.array(dones), kept))
        return obs, rewards, dones, infos

    def missions(self) -> list[dict]:
        """Expected records: one per env copy whose mission ended, from its first agent's info."""
        out = []
        for dones, infos in self.steps:
            for row in range(0, len(infos), self.n_agents):
                if dones[row]:
                    info = infos[row]
                    out.append(
                        {
                            "env_copy": row // self.n_agents,
                            "reward": info["episode"]["r"],
                            "length": info["episode"]["l"],
                            "f1": info["f1"],
                            "entropy": info["entropy"],
                        }
                    )
        return out


class Capture(KVWriter):
    def __init__(self):
        self.dumps: list[tuple[int, dict]] = []

    def write(self, key_values, key_excluded, step=0):
        self.dumps.append((step, dict(key_values)))

    def close(self):
        pass


def make_env(n_envs: int = 2, seed: int = 0) -> Recorder:
    venv = uav_ipp.make_vec_env("env1", n_envs=n_envs, fusion="mean", seed=seed, n_uavs=N_AGENTS, budget=BUDGET)
    return Recorder(venv)


def make_model(env, batch_size: int = 6) -> COMA:
    # 2 copies, batch 6 -> 3 steps per copy per rollout = 6 joint steps = one mission per copy.
    return COMA(
        "UavCnnPolicy",
        env,
        batch_size=batch_size,
        n_steps=batch_size // 2,
        learning_rate=1e-4,
        critic_learning_rate=1e-3,
        seed=0,
        device="cpu",
        policy_kwargs={"features_extractor_kwargs": {"features_dim": 16, "channels": (8, 8, 8)}},
    )


def test_mission_metrics_equal_env_infos(tmp_path):
    env = make_env()
    model = make_model(env)
    capture = Capture()
    model.set_logger(
        Logger(folder=None, output_formats=[capture, make_output_format("tensorboard", str(tmp_path / "tb"))])
    )
    eval_env = make_env(n_envs=1, seed=5)
    metrics = EpisodeMetricsCallback(csv_path=tmp_path / "metrics.csv")
    evaluation = MissionEvalCallback(eval_env, eval_freq=12, n_eval_missions=2, verbose=0)
    model.learn(18, callback=[metrics, evaluation])
    model.logger.close()

    expected = env.missions()
    assert len(expected) == 6  # 18 joint steps / 3 per mission, one value per env copy (not per agent)
    got = [{k: r[k] for k in ("env_copy", "reward", "length", "f1", "entropy")} for r in metrics.history]
    assert len(got) == len(expected)
    for row, want in zip(got, expected):
        assert row.keys() == want.keys()
        for key in row:
            assert float(row[key]) == pytest.approx(float(want[key])), key
    assert [r["timesteps"] for r in metrics.history] == [6, 6, 12, 12, 18, 18]

    # CSV: same rows
    with (tmp_path / "metrics.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["episode"]) for r in rows] == list(range(1, 7))
    assert [float(r["f1"]) for r in rows] == pytest.approx([e["f1"] for e in expected])
    assert [float(r["reward"]) for r in rows] == pytest.approx([e["reward"] for e in expected])

    # SB3 logger: means over the window at each dump
    last = [values for _, values in capture.dumps if "mission/reward_mean" in values][-1]
    assert last["mission/missions"] == 6
    for key in ("reward", "f1", "entropy"):
        assert last[f"mission/{key}_mean"] == pytest.approx(np.mean([e[key] for e in expected]))
        assert last[f"mission/{key}_last"] == pytest.approx(expected[-1][key])

    # TensorBoard: one point per mission
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    assert [e.value for e in acc.Scalars("mission/entropy")] == pytest.approx([e["entropy"] for e in expected])
    assert [e.step for e in acc.Scalars("mission/f1")] == [6, 6, 12, 12, 18, 18]

    # Evaluation: 2 missions at 12 joint steps, F1 / entropy from the eval env's infos
    eval_expected = eval_env.missions()
    assert len(eval_expected) == 2
    eval_dump = next(values for _, values in capture.dumps if "eval/mean_reward" in values)
    assert eval_dump["eval/mean_f1"] == pytest.approx(np.mean([e["f1"] for e in eval_expected]))
    assert eval_dump["eval/mean_entropy"] == pytest.approx(np.mean([e["entropy"] for e in eval_expected]))
    assert eval_dump["eval/mean_reward"] == pytest.approx(np.mean([e["reward"] for e in eval_expected]))

    # Rows after a resume point are dropped
    assert truncate_metrics_csv(tmp_path / "metrics.csv", 12) == 4


def test_checkpoints_at_rollout_boundaries(tmp_path):
    model = make_model(make_env())
    ckpt = JointCheckpointCallback(save_freq=6, save_path=tmp_path / "ck", keep_last=1)
    model.learn(24, callback=ckpt)
    # at the start of each later rollout, and at the end (after the last complete rollout)
    assert [p.name for p in ckpt.saved] == [f"rl_model_{s}_steps.zip" for s in (6, 12, 18, 24)]
    assert [s for s, _ in find_checkpoints(tmp_path / "ck")] == [24]  # keep_last=1
    assert validate_checkpoint(ckpt.saved[-1]).num_timesteps == 24
    # A stop in the middle of a rollout is not a boundary: no checkpoint then.
    stop_early = JointCheckpointCallback(save_freq=1, save_path=tmp_path / "ck2")
    model.learn(24, callback=[stop_early, StopOnTargetCallback("entropy", 2.0, window=1, verbose=0)])
    assert model.num_timesteps == 6 and stop_early.saved == []
    assert not list((tmp_path / "ck").glob("*.tmp"))
    with pytest.raises(ValueError, match="save_freq"):
        JointCheckpointCallback(save_freq=0, save_path=tmp_path)


def test_stop_on_target():
    model = make_model(make_env())
    stop = StopOnTargetCallback("entropy", threshold=2.0, window=2, verbose=0)  # any mission meets it
    model.learn(60, callback=stop)
    assert stop.reached and stop.reached_at == 6 and model.num_timesteps == 6
    never = StopOnTargetCallback("f1", threshold=2.0, window=2, verbose=0)
    assert never.mode == "above"
    model.learn(12, callback=never)
    assert not never.reached and model.num_timesteps == 12
    with pytest.raises(ValueError, match="metric"):
        StopOnTargetCallback("loss", 1.0)


def test_progress_lines_say_steps_elapsed_and_time_left(capsys):
    """A quiet run says how far it is every quarter (``every=0.25``), then once at the end: joint
    steps (2 copies: 2 per step), elapsed time and the rate so far applied to the steps left."""
    model = make_model(make_env())  # 6 joint steps per rollout
    ticks = iter(range(0, 1000, 5))  # the clock advances 5 s at each reading
    progress = ProgressLinesCallback(every=0.25, label="training env1", clock=lambda: float(next(ticks)))
    model.learn(24, callback=progress)
    assert capsys.readouterr().out.splitlines() == [
        "training env1: 6/24 joint steps (25 %), 5 s elapsed, about 15 s left",
        "training env1: 12/24 joint steps (50 %), 10 s elapsed, about 10 s left",
        "training env1: 18/24 joint steps (75 %), 15 s elapsed, about 5 s left",
        "training env1: done at 24/24 joint steps after 20 s",
    ]
    lines: list[str] = []  # a continued run counts from where it is, to learn's new total
    model.learn(12, callback=ProgressLinesCallback(every=0.5, log=lines.append), reset_num_timesteps=False)
    assert [line.split(" joint")[0] for line in lines] == ["training: 30/36", "training: done at 36/36"]
    assert capsys.readouterr().out == ""
    with pytest.raises(ValueError, match="every"):
        ProgressLinesCallback(every=0)


class _Partial:
    def __init__(self, payload: bytes, fail: bool):
        self.payload, self.fail = payload, fail

    def save(self, handle):
        handle.write(self.payload)
        if self.fail:
            raise OSError("disk full")


def test_atomic_save_keeps_previous_file(tmp_path):
    dest = tmp_path / "model.zip"
    dest.write_bytes(b"previous")
    with pytest.raises(OSError, match="disk full"):
        atomic_save(_Partial(b"PK\x03\x04half", fail=True), dest)
    with pytest.raises(CheckpointError, match=r"model\.zip is unusable"):
        atomic_save(_Partial(b"junk", fail=False), dest)
    assert dest.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.zip"]


def test_an_atomic_write_keeps_the_replaced_files_mode_and_gives_a_new_one_the_umasks(tmp_path):
    """The temporary file is made 0600; what lands is readable as ``open(path, "w")`` would make it
    (results, tables and the README shared with a group stay readable)."""
    import os

    mask = os.umask(0o022)
    os.umask(mask)
    made = atomic_write_text(tmp_path / "new.md", "a")
    assert made.stat().st_mode & 0o777 == 0o666 & ~mask
    kept = tmp_path / "kept.md"
    kept.write_text("x")
    kept.chmod(0o640)
    atomic_write_text(kept, "y")
    assert kept.read_text() == "y" and kept.stat().st_mode & 0o777 == 0o640


@pytest.mark.parametrize("eval_seed", [None, 7])
def test_seeded_evaluations_fly_the_same_missions(eval_seed, tmp_path):
    """With ``eval_seed`` every evaluation re-seeds: a policy that does not change (lr 1e-12) scores the same
    each time (without it the missions run on and the scores differ)."""
    env = make_env()
    model = COMA(
        "UavCnnPolicy",
        env,
        batch_size=6,
        n_steps=3,
        learning_rate=1e-12,
        critic_learning_rate=1e-12,
        seed=0,
        device="cpu",
        policy_kwargs={"features_extractor_kwargs": {"features_dim": 16, "channels": (8, 8, 8)}},
    )
    eval_env = make_env(n_envs=1, seed=5)
    evaluation = MissionEvalCallback(
        eval_env, eval_freq=6, n_eval_missions=3, verbose=0, eval_seed=eval_seed, log_path=tmp_path
    )
    model.learn(18, callback=evaluation)
    scores = [float(np.mean(r)) for r in evaluation.evaluations_results]
    assert len(scores) == 3
    if eval_seed is None:
        assert len(set(scores)) > 1
    else:
        assert scores == [scores[0]] * 3


def test_eval_seed_must_be_an_integer():
    with pytest.raises(ValueError, match=r"eval_seed must be an integer or None, got 1\.5"):
        MissionEvalCallback(make_env(n_envs=1), eval_freq=6, eval_seed=1.5, verbose=0)


def _seeded_validation(folder, select_after: int = 0) -> MissionEvalCallback:
    """Two validation missions every 6 joint steps, re-seeded each time, best model into ``folder``."""
    return MissionEvalCallback(
        make_env(n_envs=1, seed=5),
        eval_freq=6,
        n_eval_missions=2,
        verbose=0,
        eval_seed=7,
        log_path=folder,
        best_model_save_path=folder,
        select_after=select_after,
    )


def test_resumed_evaluation_keeps_the_earlier_record_and_best(tmp_path):
    """A resumed run continues evaluations.npz and its best score: the first evaluation after a
    resume must not replace a better best_model.zip (SB3's callback would start from -inf)."""
    model = make_model(make_env())

    def callback() -> MissionEvalCallback:  # the same validation set-up before and after the resume
        return _seeded_validation(tmp_path)

    first = callback()
    model.learn(12, callback=first)
    earlier = [float(np.mean(r)) for r in first.evaluations_results]
    assert len(earlier) == 2
    # pretend the record holds a score no later checkpoint can reach
    data = dict(np.load(tmp_path / "evaluations.npz"))
    data["results"] = data["results"].copy()
    data["results"][0] = 1e6
    np.savez(tmp_path / "evaluations.npz", **data)
    best = (tmp_path / "best_model.zip").read_bytes()
    resumed = callback()
    model.learn(12, callback=resumed, reset_num_timesteps=False)
    assert resumed.best_mean_reward == 1e6
    assert len(resumed.evaluations_results) == 4  # two earlier + two new, one file
    assert len(np.load(tmp_path / "evaluations.npz")["timesteps"]) == 4
    assert (tmp_path / "best_model.zip").read_bytes() == best  # not replaced by a worse model


def test_a_half_written_metrics_row_is_dropped_on_resume(tmp_path):
    from sb3_coma.common.callbacks import METRIC_COLUMNS, truncate_metrics_csv

    path = tmp_path / "metrics.csv"
    full = ",".join(str(i + 1) for i in range(len(METRIC_COLUMNS)))
    path.write_text(",".join(METRIC_COLUMNS) + "\n" + full + "\n" + full + "\n" + "3,45,2")  # crash mid-row
    assert truncate_metrics_csv(path, max_timesteps=10**9) == 2
    lines = path.read_text().splitlines()
    assert len(lines) == 3 and all(line.count(",") == len(METRIC_COLUMNS) - 1 for line in lines)


def test_evaluations_up_to_select_after_are_logged_but_never_the_best_model(tmp_path):
    """A warm-started run holds its actor still at first: its checkpoints of that phase are the
    clone, not COMA's; they are evaluated (the curve) but cannot become best_model.zip."""
    model = make_model(make_env())
    evaluation = _seeded_validation(tmp_path, select_after=6)
    model.learn(6, callback=evaluation)
    assert len(evaluation.evaluations_results) == 1 and not (tmp_path / "best_model.zip").exists()
    assert evaluation.best_mean_reward == -np.inf
    model.learn(6, callback=evaluation, reset_num_timesteps=False)
    assert len(evaluation.evaluations_results) == 2
    assert evaluation.best_mean_reward == float(np.mean(evaluation.evaluations_results[1]))
    assert validate_checkpoint(tmp_path / "best_model.zip").num_timesteps == 12


def test_selection_ends_after_the_critic_warm_up_of_a_warm_started_entry():
    from sb3_coma.app.training import selection_end

    assert selection_end({"n_timesteps": 18000}, 18000) == 0
    assert selection_end({"warm_start": None}, 18000) == 0
    spec = {"teacher": "oracle", "rounds": 8, "missions": 128, "critic_warmup": 0.25}
    assert selection_end({"warm_start": spec}, 18000) == 4500
