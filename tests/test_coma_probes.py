"""The study's probe ``StateValueBaselineCOMA``: COMA's trainer with ``V_i(s)`` as the baseline."""

from __future__ import annotations

from typing import Any

import pytest
import torch as th
from coma_fakes import collect_rollout
from pettingzoo import ParallelEnv

from sb3_coma import COMA, make_marl_vec_env
from sb3_coma.experiments import coma_study
from sb3_coma.experiments.coma_probes import StateValueBaselineCOMA

FAST = {"n_steps": 16, "batch_size": 8, "n_epochs": 1, "n_critic_epochs": 3, "advantage": "v_return"}


def _spread() -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False)


def _advantage_seen(algorithm: type[COMA], monkeypatch: pytest.MonkeyPatch) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """(the advantage the actor is trained on, V of collection time, the V-bootstrapped returns)."""
    model = algorithm("MlpPolicy", make_marl_vec_env(_spread, n_envs=2, seed=0), seed=0, device="cpu", **FAST)
    collect_rollout(model)
    values, returns = model._state_value_returns()  # type: ignore[misc]
    seen: list[th.Tensor] = []
    real = model._fit_actor

    def spy(data: dict[str, Any], advantage: th.Tensor, old_log_prob: th.Tensor) -> Any:
        seen.append(advantage.clone())
        return real(data, advantage, old_log_prob)

    monkeypatch.setattr(model, "_fit_actor", spy)
    model.train()
    return seen[0], values, returns


def test_the_probe_subtracts_the_state_value(monkeypatch: pytest.MonkeyPatch) -> None:
    advantage, values, returns = _advantage_seen(StateValueBaselineCOMA, monkeypatch)
    assert th.allclose(advantage, returns - values, atol=1e-5)


def test_coma_subtracts_the_counterfactual_baseline_there(monkeypatch: pytest.MonkeyPatch) -> None:
    advantage, values, returns = _advantage_seen(COMA, monkeypatch)
    assert not th.allclose(advantage, returns - values, atol=1e-3)


def test_the_probe_needs_the_state_value() -> None:
    env = make_marl_vec_env(_spread, n_envs=2, seed=0)
    with pytest.raises(ValueError, match="needs advantage='v_return', got 'return'"):
        StateValueBaselineCOMA("MlpPolicy", env, device="cpu", advantage="return")


def test_every_probe_is_a_study_variant_and_a_class() -> None:
    from sb3_coma.experiments import coma_probes

    for variant, name in coma_study.PROBES.items():
        assert variant in coma_study.VARIANTS and issubclass(getattr(coma_probes, name), COMA)


def test_a_probes_row_says_it_is_not_coma(tmp_path: Any) -> None:
    import json

    (tmp_path / "runs").mkdir()
    for variant in coma_study.ROUNDS["state_value_round"]:
        name = f"simple_spread-{variant}-{coma_study.VALIDATION_TRAIN_SEED}"
        record = {
            "task": "simple_spread",
            "variant": variant,
            "seed": coma_study.VALIDATION_TRAIN_SEED,
            "validation_return": -50.0,
            "seconds": 60.0,
            "curve": [[0, -60.0], [1000, -50.0]],
        }
        (tmp_path / "runs" / f"{name}.json").write_text(json.dumps(record))
        columns = ("time/total_timesteps", *coma_study.DIAGNOSTICS)
        (tmp_path / "runs" / f"{name}.csv").write_text(",".join(columns) + "\n" + ",".join(["1"] * len(columns)) + "\n")
    text = coma_study.report_phase(tmp_path, 1, "state_value_round")
    probe_row = next(line for line in text.splitlines() if "| before_lambda_95_q_norm_v_baseline |" in line)
    assert "probe, not COMA: StateValueBaselineCOMA" in probe_row
    coma_row = next(line for line in text.splitlines() if "| before_lambda_95_q_norm_v_return |" in line)
    assert "not COMA" not in coma_row and "advantage=v_return" in coma_row
