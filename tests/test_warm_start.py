"""The ``warm_start`` config key: DAgger from the oracle, then COMA with the actor held at first."""

from __future__ import annotations

import json

import pytest
import torch as th
import yaml
from stable_baselines3.common.callbacks import BaseCallback
from tiny_runs import ENV, tiny_entry

from sb3_coma import COMA
from sb3_coma.app.config import TrainingError, load_config
from sb3_coma.app.training import train


def _config(tmp_path, **warm):
    entry = tiny_entry()
    entry.update(n_timesteps=16, kl_coef=1.0, warm_start={"rounds": 2, "missions": 2, **warm})
    path = tmp_path / "c.yml"
    path.write_text(yaml.safe_dump({ENV: entry}))
    return path


class _ActorAfterFirstUpdate(BaseCallback):
    """Copies the actor's weights when the second rollout starts (after the first update)."""

    def __init__(self) -> None:
        super().__init__()
        self.rollouts, self.actor = 0, None

    def _on_rollout_start(self) -> None:
        self.rollouts += 1
        if self.rollouts == 2:
            self.actor = [p.detach().clone() for p in self.model.policy.actor.parameters()]

    def _on_step(self) -> bool:
        return True


def test_warm_start_clones_then_holds_the_actor_while_the_critic_learns(tmp_path):
    config = _config(tmp_path, critic_warmup=0.6)  # 2 rollouts: the update at half-time holds the actor
    spy = _ActorAfterFirstUpdate()
    _, run = train(ENV, config=config, seed=0, run_dir=tmp_path / "run", progress_bar=False, verbose=0, callbacks=[spy])
    record = json.loads((run / "warm_start.json").read_text())
    assert record["teacher"] == "oracle" and len(record["rounds_record"]) == 2
    assert 0.0 <= record["agreement"] <= 1.0
    clone = COMA.load(run / "warm_start.zip", device="cpu")
    trained = COMA.load(run / "model.zip", device="cpu")
    assert spy.actor is not None
    for a, b in zip(clone.policy.actor.parameters(), spy.actor):
        assert th.equal(a, b)  # the first update held the actor ...
    assert any(not th.equal(a, b) for a, b in zip(clone.policy.actor.parameters(), trained.policy.actor.parameters()))
    # ... and the critic learned meanwhile; the clone is not the untrained actor
    assert any(not th.equal(a, b) for a, b in zip(clone.policy.critic.parameters(), trained.policy.critic.parameters()))
    _, plain_run = train(
        ENV, config=_plain(tmp_path), seed=0, run_dir=tmp_path / "plain", progress_bar=False, verbose=0
    )
    untrained = [p.detach() for p in COMA.load(plain_run / "model.zip", device="cpu").policy.actor.parameters()]
    assert any(not th.equal(a, b) for a, b in zip(clone.policy.actor.parameters(), untrained))


def _plain(tmp_path):
    entry = tiny_entry()
    entry.update(n_timesteps=8)
    path = tmp_path / "plain.yml"
    path.write_text(yaml.safe_dump({ENV: entry}))
    return path


def test_warm_start_without_warmup_lets_the_actor_move(tmp_path):
    config = _config(tmp_path, critic_warmup=0.0)
    _, run = train(ENV, config=config, seed=0, run_dir=tmp_path / "run", progress_bar=False, verbose=0)
    clone = COMA.load(run / "warm_start.zip", device="cpu")
    trained = COMA.load(run / "model.zip", device="cpu")
    assert any(not th.equal(a, b) for a, b in zip(clone.policy.actor.parameters(), trained.policy.actor.parameters()))


@pytest.mark.parametrize(
    ("warm", "match"),
    [
        ({"teacher": "random"}, "teacher"),
        ({"rounds": 0}, "rounds"),
        ({"missions": "many"}, "missions"),
        ({"critic_warmup": 1.0}, "critic_warmup"),
        ({"teachr": "oracle"}, "teachr"),
    ],
)
def test_bad_warm_start_is_named(tmp_path, warm, match):
    with pytest.raises(TrainingError, match=match):
        load_config(ENV, _config(tmp_path, **warm))


def test_the_warm_start_says_every_round_with_elapsed_time_and_an_estimate(tmp_path):
    """A user waiting minutes for DAgger sees each round end, not a silent process (newcomer issue)."""
    lines: list[str] = []
    train(
        ENV,
        config=_config(tmp_path, critic_warmup=0.6),
        seed=0,
        run_dir=tmp_path / "run",
        progress_bar=False,
        verbose=0,
        log=lines.append,
    )
    rounds = [line for line in lines if line.strip().startswith("round ")]
    assert len(rounds) == 2, lines
    assert rounds[0].strip().startswith("round 1/2:") and rounds[1].strip().startswith("round 2/2:")
    assert all("agreement" in line and "s elapsed, about" in line and "s left" in line for line in rounds)
