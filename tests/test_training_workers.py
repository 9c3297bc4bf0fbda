"""Training on worker processes gives the model that training in one process gives."""

from __future__ import annotations

import torch as th

import uav_ipp
from sb3_coma import COMA

SMALL = {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}}


def _train(workers: int) -> th.Tensor:
    venv = uav_ipp.make_vec_env("env1", n_envs=4, fusion="mean", seed=3, split="train", start="random", workers=workers)
    try:
        model = COMA("UavCnnPolicy", venv, seed=3, n_steps=8, batch_size=16, policy_kwargs=SMALL)
        model.learn(64)  # two rollouts: the missions end and reset inside the workers
        return th.cat([p.detach().flatten() for p in model.policy.parameters()])
    finally:
        venv.close()


def test_same_seed_same_model_on_one_or_two_workers() -> None:
    assert th.equal(_train(1), _train(2))
