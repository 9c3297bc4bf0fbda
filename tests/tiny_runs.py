"""The tiny training config the run-folder tests share: 2 UAVs, 4-step missions, 8 joint steps
per rollout (= 2 missions), so every run is a few rollouts."""

from __future__ import annotations

from typing import Any

ENV = "UavIpp-Env1-v0"
ENV_KWARGS: dict[str, Any] = {"fusion": "mean", "n_uavs": 2, "budget": 4, "noise": "moderate"}


def tiny_entry() -> dict[str, Any]:
    """A fresh copy of the tiny config entry of ``ENV`` (callers may change it)."""
    return {
        "n_timesteps": 40,
        "n_envs": 1,
        "policy": "UavCnnPolicy",
        "policy_kwargs": {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}},
        "learning_rate": 1.0e-4,
        "critic_learning_rate": 1.0e-3,
        "batch_size": 8,
        "n_steps": 8,
        "n_epochs": 1,
        "n_critic_epochs": 1,
        "gamma": 0.99,
        "td_lambda": 0.8,
        "env_kwargs": dict(ENV_KWARGS),
    }
