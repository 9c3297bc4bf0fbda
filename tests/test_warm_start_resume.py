"""A warm-started run stopped and resumed trains the same recipe as an unbroken one.

#35: a checkpoint holds the KL reference actor and the actor's hold (``critic_warmup``), so
``train(resume=...)`` continues with the same pull and the same hold; a checkpoint saved before
they were saved takes them from the run's ``warm_start.zip``, or the resume is refused.
#36: the DAgger warm start saves its progress after every round, stops cleanly on SIGTERM, and a
resume continues after its last finished round with the clone an unbroken warm start gives.

Tiny sizes (2 UAVs, 4-step missions, 8 joint steps per rollout, 2 DAgger rounds of 2 missions).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import zipfile
from pathlib import Path

import pytest
import torch as th
import yaml
from stable_baselines3.common.callbacks import BaseCallback
from tiny_runs import ENV, tiny_entry

from sb3_coma import COMA
from sb3_coma.app.config import TrainingError
from sb3_coma.app.training import TrainingInterrupted, train

pytestmark = pytest.mark.usefixtures("tmp_cwd")

SEED = 3
QUIET = {"progress_bar": False, "verbose": 0}


def _config(tmp_path: Path, n_timesteps: int, critic_warmup: float) -> Path:
    entry = tiny_entry()
    entry.update(
        n_timesteps=n_timesteps,
        kl_coef=1.0,
        kl_fraction=1.0,
        warm_start={"rounds": 2, "missions": 2, "critic_warmup": critic_warmup},
    )
    path = tmp_path / "warm.yml"
    path.write_text(yaml.safe_dump({ENV: entry}))
    return path


def _same_networks(a: Path, b: Path) -> bool:
    x, y = COMA.load(a, device="cpu"), COMA.load(b, device="cpu")
    left, right = x.policy.state_dict(), y.policy.state_dict()
    return left.keys() == right.keys() and all(th.equal(left[k], right[k]) for k in left)


def _same_module(a: th.nn.Module, b: th.nn.Module) -> bool:
    return all(th.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values()))


class _Signal(BaseCallback):
    """SIGTERM to this process once training has passed ``after`` joint steps."""

    def __init__(self, after: int) -> None:
        super().__init__()
        self.after, self.sent = after, False

    def _on_step(self) -> bool:
        if not self.sent and self.num_timesteps > self.after:
            self.sent = True
            os.kill(os.getpid(), signal.SIGTERM)
        return True


class _AsIfResumed(BaseCallback):
    """At the rollout boundary ``at``, do to the random state what a resume from there does: reseed
    with ``seed + at`` (the resumed run's seed), draw a new policy's initial weights (loading builds
    one before it puts the saved weights in) and start new missions. Everything else an unbroken
    run keeps in memory, so a resume that restored it all (weights, optimisers, counters, the KL
    reference, the actor's hold) gives this run's parameters bit for bit."""

    def __init__(self, seed: int, at: int) -> None:
        super().__init__()
        self.seed, self.at = seed, at

    def _on_rollout_start(self) -> None:
        model = self.model
        if model.num_timesteps != self.at:
            return
        model.set_random_seed(self.seed + self.at)
        model.policy_class(
            model.observation_space,
            model.action_space,
            model.lr_schedule,
            critic_lr_schedule=model.critic_lr_schedule,
            n_agents=model.n_agents,
            state_space=model.state_space,
            **model.policy_kwargs,
        )
        model._last_obs = model.env.reset()
        model._last_states = model._current_states()

    def _on_step(self) -> bool:
        return True


def _strip_recipe(path: Path) -> None:
    """Rewrite a checkpoint as sb3-coma 0.3.0 saved it: no reference actor, no ``critic_warmup``."""
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist() if name != "reference_actor.pth"}
    data = json.loads(members["data"])
    del data["critic_warmup"]
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


# ----------------------------------------------------------------------------- #35: the same recipe
def test_a_warm_started_run_resumed_mid_way_matches_an_unbroken_run(tmp_path):
    """32 joint steps, the actor held over the first 60%, the KL pull over the whole run: stopped at
    8, the resumed run's updates at 16 (held), 24 (pulled) and 32 are the unbroken run's."""
    config = _config(tmp_path, 32, critic_warmup=0.6)
    _, unbroken = train(
        ENV, config=config, seed=SEED, run_dir=tmp_path / "unbroken", callbacks=[_AsIfResumed(SEED, 8)], **QUIET
    )
    with pytest.raises(TrainingInterrupted) as info:
        train(ENV, config=config, seed=SEED, run_dir=tmp_path / "run", callbacks=[_Signal(after=8)], **QUIET)
    run, checkpoint = info.value.run_dir, info.value.checkpoint
    assert info.value.num_timesteps == 8
    with zipfile.ZipFile(checkpoint) as archive:
        assert "reference_actor.pth" in archive.namelist()
    stopped, clone = COMA.load(checkpoint, device="cpu"), COMA.load(run / "warm_start.zip", device="cpu")
    assert stopped.critic_warmup == 0.6 and stopped.lr_schedule(0.5) == 0.0 and stopped.lr_schedule(0.3) > 0.0
    assert stopped.reference_actor is not None and _same_module(stopped.reference_actor, clone.policy.actor)

    model, _ = train(resume=run, **QUIET)
    assert model.num_timesteps == 32
    assert _same_networks(unbroken / "model.zip", run / "model.zip")


def test_a_checkpoint_without_its_reference_takes_it_from_the_clone_or_is_refused(tmp_path):
    """A checkpoint saved before the reference was saved: the run's warm_start.zip is that
    reference, so the resume restores it (with a warning); with no clone at hand it is refused."""
    config = _config(tmp_path, 16, critic_warmup=0.5)
    _, run = train(ENV, config=config, seed=SEED, run_dir=tmp_path / "run", save_freq=8, **QUIET)
    checkpoint = run / "checkpoints" / "rl_model_8_steps.zip"
    _strip_recipe(checkpoint)
    assert COMA.load(checkpoint, device="cpu").reference_actor is None
    with pytest.warns(UserWarning, match="holds no KL reference actor"):
        model, _ = train(resume=checkpoint, fork=True, run_dir=tmp_path / "fork", total_timesteps=8, **QUIET)
    clone = COMA.load(run / "warm_start.zip", device="cpu")
    assert model.reference_actor is not None and _same_module(model.reference_actor, clone.policy.actor)
    assert model.critic_warmup == 0.5 and model.lr_schedule(0.9) == 0.0
    lonely = tmp_path / "lonely.zip"
    shutil.copy(checkpoint, lonely)
    with pytest.raises(TrainingError, match=r"lonely\.zip: the checkpoint of this warm-started run holds no KL"):
        train(ENV, config=config, resume=lonely, runs_root=tmp_path / "runs", **QUIET)


# ----------------------------------------------------------------------------- #36: the warm start resumes
def test_a_warm_start_stopped_by_sigterm_resumes_after_its_last_round_with_the_same_clone(tmp_path):
    config = _config(tmp_path, 8, critic_warmup=0.5)
    handler = signal.getsignal(signal.SIGTERM)  # SIG_DFL, or Ray's if a Ray test ran in this worker first
    _, unbroken = train(ENV, config=config, seed=SEED, run_dir=tmp_path / "unbroken", **QUIET)

    def stop_after_round_1(line: str) -> None:
        if line.strip().startswith("round 1/"):
            os.kill(os.getpid(), signal.SIGTERM)  # arrives during round 2

    with pytest.raises(TrainingInterrupted) as info:
        train(ENV, config=config, seed=SEED, run_dir=tmp_path / "run", log=stop_after_round_1, **QUIET)
    run = info.value.run_dir
    assert info.value.signum == signal.SIGTERM and info.value.num_timesteps == 0
    assert signal.getsignal(signal.SIGTERM) is handler  # handlers restored
    state = run / "warm_start_state"
    assert sorted(p.name for p in state.iterdir()) == ["progress.json", "round_0.npz", "state.pt"]
    progress = json.loads((state / "progress.json").read_text())
    assert (progress["rounds_done"], progress["rounds"], progress["stopped_by"]) == (1, 2, "SIGTERM")
    assert not (run / "warm_start.zip").exists() and not list(run.glob("checkpoints/*.zip"))

    lines: list[str] = []
    train(resume=run, log=lines.append, **QUIET)
    assert any("continuing after round 1/2" in line for line in lines), lines
    assert [line.strip()[:9] for line in lines if line.strip().startswith("round ")] == ["round 2/2"]
    assert not state.exists()  # the clone is saved: DAgger's progress is no longer needed
    assert _same_networks(unbroken / "warm_start.zip", run / "warm_start.zip")
    records = [json.loads((r / "warm_start.json").read_text())["rounds_record"] for r in (unbroken, run)]
    assert records[0] == records[1]
    assert _same_networks(unbroken / "model.zip", run / "model.zip")
    assert yaml.safe_load((run / "config.yml").read_text())["run"]["resumes"][0]["from"] == str(state)
