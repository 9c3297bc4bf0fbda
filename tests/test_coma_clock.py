"""``COMA(critic_time_feature=...)``: the critic reads the time left in each copy's episode
(docs/training.md, round 20); the actors and the task stay as they are."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch as th
from coma_fakes import collect_rollout
from gymnasium import spaces
from pettingzoo import ParallelEnv

from sb3_coma import COMA, make_marl_vec_env
from sb3_coma.coma.clock import EpisodeClock, append_time_left, with_time_left

LIMIT = 25  # simple_spread's max_cycles
FAST = {"n_steps": 30, "batch_size": 20, "n_epochs": 1, "n_critic_epochs": 1}


def _spread() -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=LIMIT, continuous_actions=False)


def _model(state: str = "auto", **kwargs: Any) -> COMA:
    args = {"seed": 0, "device": "cpu", "critic_time_feature": LIMIT, **FAST, **kwargs}
    return COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=2, seed=0, state=state), **args)


def test_the_clock_counts_each_copy_and_restarts_the_copies_that_ended() -> None:
    clock = EpisodeClock(n_copies=2, limit=4)
    np.testing.assert_allclose(clock.time_left(), [1.0, 1.0])
    clock.advance(np.array([False, False]))
    clock.advance(np.array([False, True]))
    np.testing.assert_allclose(clock.time_left(), [0.5, 1.0])
    for _ in range(3):
        clock.advance(np.array([False, False]))
    np.testing.assert_allclose(clock.time_left(), [0.0, 0.25])  # past the limit: 0, not negative
    np.testing.assert_allclose(clock.time_left(np.array([1, 3])), [0.75, 0.25])


def test_the_time_left_is_one_more_bounded_state_feature() -> None:
    space = with_time_left(spaces.Box(-np.inf, np.inf, (6,), dtype=np.float32))
    assert space.shape == (7,) and space.low[-1] == 0.0 and space.high[-1] == 1.0
    state = th.arange(12.0).view(2, 3, 2)
    out = append_time_left(state, th.tensor([0.25, 1.0]))
    assert out.shape == (2, 3, 3)
    th.testing.assert_close(out[..., :2], state)
    th.testing.assert_close(out[..., 2], th.tensor([[0.25] * 3, [1.0] * 3]))


@pytest.mark.parametrize(
    "space",
    [spaces.Box(0, 255, (3, 8, 8), dtype=np.uint8), spaces.Dict({"a": spaces.Box(0, 1, (2,))})],
    ids=["image", "dict"],
)
def test_a_state_without_room_for_a_number_is_refused_in_one_line(space: spaces.Space) -> None:
    with pytest.raises(ValueError, match="critic_time_feature needs a flat state"):
        with_time_left(space)


@pytest.mark.parametrize(("value", "error"), [(0, ValueError), (-3, ValueError), (2.5, TypeError)])
def test_a_bad_time_limit_is_refused_naming_it(value: Any, error: type[Exception]) -> None:
    with pytest.raises(error, match="critic_time_feature"):
        _model(critic_time_feature=value)


def test_without_the_option_nothing_changes() -> None:
    model = _model(critic_time_feature=None)
    collect_rollout(model)
    assert model._clock is None and model.rollout_buffer.time_left is None
    assert model.state_space.shape == (3 * 18,)  # type: ignore[union-attr]  # simple_spread: 18 per agent


@pytest.mark.parametrize("state", ["env", "concat"])
def test_the_critic_reads_the_time_left_of_every_joint_step(state: str) -> None:
    """Whether the state is the env's (stored apart, the clock added when read) or the agents'
    observations side by side (simple_spread's state() is as long as those: 3 x 18)."""
    model = _model(state=state)
    assert model.state_source == state and model.state_space.shape == (3 * 18 + 1,)  # type: ignore[union-attr]
    collect_rollout(model)
    time_left = model.rollout_buffer.time_left
    assert time_left is not None
    expected = np.array([1.0 - (t % LIMIT) / LIMIT for t in range(FAST["n_steps"])], dtype=np.float32)
    np.testing.assert_allclose(time_left, np.stack([expected, expected], axis=1), rtol=0, atol=1e-6)
    data = model.rollout_buffer.joint_steps()
    idx = th.arange(len(data["actions"]))
    state = model._critic_state(data, model._take(data["obs"], idx), idx)
    th.testing.assert_close(state[..., -1], data["time_left"][:, None].expand(-1, 3))


def test_the_bootstraps_read_the_clock_of_the_state_they_value() -> None:
    """Where the time limit cuts an episode the terminal state has no time left; the rollout's last
    state (30 steps in: 5 into the second episode) has 20 of 25 steps left."""
    model = _model()
    seen: list[th.Tensor] = []
    real = model._expected_target_values

    def spy(obs: Any, masks: np.ndarray, states: Any, time_left: th.Tensor | None = None) -> th.Tensor:
        assert time_left is not None
        seen.append(time_left.clone())
        return real(obs, masks, states, time_left)

    model._expected_target_values = spy  # type: ignore[method-assign]
    collect_rollout(model)
    truncations, rollout_end = seen[:-1], seen[-1]
    assert len(truncations) == 1  # both copies cut at step 25, valued in one call
    th.testing.assert_close(truncations[0], th.zeros(2))
    th.testing.assert_close(rollout_end, th.full((2,), 0.8))


def test_a_fresh_learn_restarts_the_clock_and_a_continued_one_keeps_it() -> None:
    model = _model()
    model.learn(60)  # one rollout: 30 steps of each of 2 copies, 25 + 5
    clock = model._clock
    assert clock is not None and clock.elapsed.tolist() == [5, 5]
    model.learn(60, reset_num_timesteps=False)
    assert model._clock is clock and clock.elapsed.tolist() == [10, 10]
    model.learn(60)  # reset_num_timesteps=True: SB3 resets the env, every episode begins again
    assert model._clock is not clock and model._clock.elapsed.tolist() == [5, 5]  # type: ignore[union-attr]


def test_the_option_is_saved_and_a_loaded_model_trains_on(tmp_path: Path) -> None:
    model = _model()
    model.learn(30)
    model.save(tmp_path / "clock.zip")
    loaded = COMA.load(tmp_path / "clock.zip", device="cpu")
    assert loaded.critic_time_feature == LIMIT and loaded.state_space == model.state_space
    for name, tensor in model.policy.state_dict().items():
        th.testing.assert_close(loaded.policy.state_dict()[name], tensor)
    again = COMA.load(tmp_path / "clock.zip", env=make_marl_vec_env(_spread, n_envs=2, seed=1), device="cpu")
    again.learn(30)
    assert again.state_space == model.state_space and again._clock is not None
