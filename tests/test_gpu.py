"""The GPU learner: COMA and SenDFuse on ``cuda`` when a GPU exists (skipped without one).

CPU behaviour is what every other test checks; these only run where ``torch.cuda.is_available()``.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

import uav_ipp
from sb3_coma import COMA

pytestmark = pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA GPU")

SMALL = {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}}


def test_coma_learns_on_the_gpu_with_cpu_collection() -> None:
    venv = uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=0)
    model = COMA("UavCnnPolicy", venv, seed=0, n_steps=8, batch_size=8, device="cuda", policy_kwargs=SMALL)
    model.learn(32)
    assert next(model.policy.parameters()).device.type == "cuda"
    actions, _ = model.predict(venv.reset(), deterministic=True)
    assert actions.shape == (venv.num_envs,)


def test_sendfuse_on_the_gpu_matches_the_cpu() -> None:
    fused = []
    for device in ("cpu", "cuda"):
        venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="sendfuse", seed=0, fusion_kwargs={"device": device})
        obs = venv.reset()
        for _ in range(3):
            obs, *_ = venv.step(np.zeros(venv.num_envs, dtype=np.int64))
        fused.append(obs["local"][:, -1])
        venv.close()
    np.testing.assert_allclose(fused[0], fused[1], atol=1e-4)
