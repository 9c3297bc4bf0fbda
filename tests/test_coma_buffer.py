"""Joint-step regrouping: rows e * N + a become (e, a), and minibatches keep joint steps whole."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from coma_fakes import obs_space

from sb3_coma.coma.buffer import JointRolloutBuffer

E, N, T = 3, 2, 4


def step_obs(t: int) -> dict[str, np.ndarray]:
    rows = np.arange(E * N)
    local = np.zeros((E * N, 8, 11, 11), np.float32)
    local[:, 0, 0, 0] = 100 * t + rows  # tag every row with (t, row)
    state = np.zeros((E * N, 3, 11, 11), np.float32)
    return {"local": local, "state": state, "action_mask": np.ones((E * N, 6), np.float32)}


def filled() -> JointRolloutBuffer:
    buf = JointRolloutBuffer(T, E, N, obs_space(), n_actions=6)
    for t in range(T):
        rows = np.arange(E * N)
        obs = step_obs(t)
        buf.add(obs, obs["action_mask"], rows % 6, rows.astype(np.float32) + t, rows == t)
    buf.set_bootstrap(np.arange(E * N, dtype=np.float32))
    return buf


def test_rows_regroup_into_copy_and_agent() -> None:
    buf = filled()
    assert buf.full and buf.n_joint_steps == T * E
    data = buf.time_major()
    assert data["actions"].shape == (T, E, N)
    for t in range(T):
        for e in range(E):
            for a in range(N):
                assert data["obs"]["local"][t, e, a, 0, 0, 0].item() == 100 * t + e * N + a
                assert data["rewards"][t, e, a].item() == e * N + a + t
    assert data["bootstrap"][2, 1].item() == 2 * N + 1
    with pytest.raises(RuntimeError, match="full"):
        buf.add(step_obs(0), np.ones((E * N, 6)), np.zeros(E * N), np.zeros(E * N), np.zeros(E * N))


def test_minibatches_hold_whole_joint_steps() -> None:
    buf = filled()
    flat = buf.joint_steps()
    assert flat["obs"]["local"].shape[:2] == (T * E, N)
    th.manual_seed(0)
    batches = list(buf.minibatch_indices(T * E, 5))
    assert sorted(th.cat(batches).tolist()) == list(range(T * E))
    assert [len(b) for b in batches] == [5, 5, 2]
    tags = flat["obs"]["local"][batches[0], :, 0, 0, 0]  # (5, N): each row one joint step
    for row in tags:
        t, base = divmod(int(row[0].item()), 100)
        assert base % N == 0 and row.tolist() == [100 * t + base + a for a in range(N)]


def test_a_rollout_without_masks_reads_none_even_after_one_with_masks() -> None:
    """An env that gives no masks leaves the rollout's mask ``None`` (nothing to mask), also when the
    buffer's last rollout came from an env that gave some (``set_env`` with another env)."""
    buf = filled()
    assert buf.time_major()["mask"] is not None
    buf.reset()
    rows = np.arange(E * N)
    for t in range(T):
        buf.add(step_obs(t), None, rows % 6, np.zeros(E * N), np.zeros(E * N))
    assert buf.time_major()["mask"] is None and buf.joint_steps()["mask"] is None
