"""Determinism on one machine: the same seed gives the same training curve and final networks,
and the same evaluation table.

COMA runs on the real environment (env1, 2 UAVs, budget 4, mean fusion) for 96 joint steps
(6 rollouts of 16, 6 critic and 6 actor updates); every value COMA logs under ``train/`` and
``rollout/`` is captured per rollout and compared exactly, as are all parameters, buffers and
both optimizer states at the end. Torch runs on one thread here (CPU kernels are deterministic
for a fixed thread count; the test pins it so that it also holds on machines with many cores).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stable_baselines3.common.logger import KVWriter, Logger

import uav_ipp
from sb3_coma import COMA, evaluate
from sb3_coma.stats.tables import rows_for, table_markdown

JOINT_STEPS = 96
SMALL_CNN = {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}}


class _Capture(KVWriter):
    """Keeps every dumped key/value (SB3 logger output format in memory)."""

    def __init__(self) -> None:
        self.rows: list[dict[str, float]] = []

    def write(self, key_values, key_excluded, step: int = 0) -> None:
        row = {k: v for k, v in key_values.items() if k.startswith(("train/", "rollout/"))}
        row["step"] = step
        self.rows.append(row)

    def close(self) -> None:
        pass


@pytest.fixture(autouse=True)
def _one_thread():
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _train(seed: int, policy: str = "UavCnnPolicy") -> tuple[list[dict[str, float]], dict[str, torch.Tensor], list]:
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", n_uavs=2, budget=4, noise="moderate")
    try:
        model = COMA(
            policy,
            venv,
            batch_size=16,
            n_steps=16,
            n_critic_epochs=2,
            exploration_initial_eps=0.3,
            exploration_final_eps=0.05,
            ent_coef=0.01,
            seed=seed,
            device="cpu",
            policy_kwargs=SMALL_CNN,
        )
        capture = _Capture()
        model.set_logger(Logger(folder=None, output_formats=[capture]))
        model.learn(JOINT_STEPS)
        state = {k: v.detach().clone() for k, v in model.policy.state_dict().items()}
        optimizers = [model.policy.optimizer.state_dict(), model.policy.critic_optimizer.state_dict()]
        assert model.num_timesteps == JOINT_STEPS
        return capture.rows, state, optimizers
    finally:
        venv.close()


def _same_optimizer_state(a: dict, b: dict) -> bool:
    if a["param_groups"] != b["param_groups"] or a["state"].keys() != b["state"].keys():
        return False
    for key, slot in a["state"].items():
        for name, value in slot.items():
            other = b["state"][key][name]
            if isinstance(value, torch.Tensor):
                if not torch.equal(value, other):
                    return False
            elif value != other:
                return False
    return True


def test_same_seed_same_training_curve_and_parameters():
    rows_a, state_a, opt_a = _train(seed=7)
    rows_b, state_b, opt_b = _train(seed=7)
    losses = [r["train/critic_loss"] for r in rows_a if "train/critic_loss" in r]
    assert len(losses) >= JOINT_STEPS // 16 - 1 and all(np.isfinite(losses))  # a real curve was logged
    assert rows_a == rows_b
    assert state_a.keys() == state_b.keys()
    different = [k for k in state_a if not torch.equal(state_a[k], state_b[k])]
    assert not different, f"parameters differ between two runs with the same seed: {different[:5]}"
    assert all(_same_optimizer_state(a, b) for a, b in zip(opt_a, opt_b))

    # The test can see a difference: another seed gives another curve and other parameters.
    rows_c, state_c, _ = _train(seed=8)
    assert rows_c != rows_a
    assert any(not torch.equal(state_a[k], state_c[k]) for k in state_a)


@pytest.mark.parametrize("method", ["ag", "random"])
def test_same_seed_same_evaluation_table(method):
    kwargs = dict(env="env1", n_trials=3, seed=3, n_uavs=2, budget=4, noise="moderate")
    first = evaluate(method, **kwargs)
    second = evaluate(method, **kwargs)
    for name in ("f1", "entropy", "returns", "trajectories"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name), err_msg=name)
    np.testing.assert_array_equal(first.final_beliefs, second.final_beliefs)
    assert table_markdown(rows_for([first])) == table_markdown(rows_for([second]))
    summary_a = {k: v for k, v in first.summary().items() if not k.startswith("planning")}
    summary_b = {k: v for k, v in second.summary().items() if not k.startswith("planning")}
    assert summary_a == summary_b
    # Trials differ from one another (each has its own seed), so equality above is not vacuous.
    assert len({tuple(t.ravel()) for t in first.trajectories}) > 1 or len(set(first.returns)) > 1
