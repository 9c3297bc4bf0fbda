"""Smoke test of the installed wheel, run by .ci/run from an empty folder outside the checkout
that holds a dummy ``envs/`` package of its own (the layout of many users' RL projects): the
installed world is ``uav_ipp`` and must neither shadow nor be shadowed by it."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import numpy as np
import torch as th

th.set_num_threads(1)

import envs  # noqa: E402  (the user's own package, from the working folder)

assert envs.USER_PACKAGE, "the user's envs/ package was shadowed"

import sb3_coma  # noqa: E402
import uav_ipp  # noqa: E402
from sb3_coma import COMA  # noqa: E402

site = pathlib.Path(sb3_coma.__file__).resolve().parents[1]
assert "site-packages" in str(site), f"sb3_coma imported from {site}, not the installed wheel"
assert pathlib.Path(uav_ipp.__file__).resolve().parent.name == "uav_ipp", uav_ipp.__file__

# a few training steps on the UAV world
venv = uav_ipp.make_vec_env("env3", n_envs=1, fusion="mean", n_uavs=2, budget=4, seed=0)
small = {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}}
COMA("CBAMPolicy", venv, n_steps=8, batch_size=8, seed=0, policy_kwargs=small).learn(16)

demo = subprocess.run([sys.executable, "-m", "sb3_coma", "demo", "--env", "env3"], capture_output=True, text=True)
assert demo.returncode == 0, demo.stderr[-2000:]
assert "F1" in demo.stdout or "f1" in demo.stdout, demo.stdout[-2000:]

# COMA on a third-party PettingZoo env through the route SB3 users take (entry-point aliases and
# the generic policies come from the installed metadata, not the checkout)
from mpe2 import simple_spread_v3  # noqa: E402

spread = sb3_coma.make_marl_vec_env(lambda: simple_spread_v3.parallel_env(continuous_actions=False), n_envs=2, seed=0)
generic = COMA("MlpPolicy", spread, n_steps=16, batch_size=16, seed=0).learn(64)
generic.save("spread.zip")
assert COMA.load("spread.zip", env=spread).predict(spread.reset())[0].shape == (6,)

# the zoo on a third-party task from the installed wheel: its default config (zoo_configs/marl/,
# installed as data) and a tiny budget, into a folder of this smoke test's own
zoo_argv = ["train", "--algo", "coma", "--env", "simple_spread", "-n", "64", "-f", "zoo_logs", "--seed", "0"]
zoo = subprocess.run(
    [sys.executable, "-m", "sb3_coma.zoo", *zoo_argv, "-params", "n_steps:8", "n_envs:2", "batch_size:16"],
    capture_output=True,
    text=True,
)
assert zoo.returncode == 0, zoo.stderr[-2000:]
assert pathlib.Path("zoo_logs/coma/simple_spread_1/simple_spread.zip").is_file()

model = sb3_coma.load_pretrained("env3")
result = sb3_coma.evaluate(model, env="env3", n_trials=1, n_envs=1)
f1 = np.asarray(result.f1)
assert np.isfinite(f1).all() and 0.0 <= f1.ravel()[-1] <= 1.0, f1
print("wheel smoke test passed:", sb3_coma.__version__, "final F1", float(f1.ravel()[-1]))
