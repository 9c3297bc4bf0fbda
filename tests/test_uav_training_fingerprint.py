"""The UAV world trains as it did: checks that catch a changed algorithm but not a changed CPU.

Float sums are not associative, and CPUs (and torch's ATen kernels: default, AVX2, AVX-512) sum
in different orders, so a training's numbers differ in their last bits from one machine to the
next, and Adam's first steps (about ``lr * sign(gradient)``) turn a last-bit difference of a
near-zero gradient into a whole step. Three checks, each with a tolerance it can justify:

1. **One update, compared tightly** (:func:`test_one_update_matches_its_record`): one rollout
   from a fixed seed and one ``train()`` call; the losses, Q and advantage statistics it logs
   against ``tests/data/uav_one_update.json``. They are smooth functions of the batch, so they
   agree across kernels to a few parts per million; the record holds the spread measured across
   the ATen kernels of the recording CPU, and the tolerance must be at least 10 times it.
2. **The same process, exactly** (:func:`test_a_training_repeats_exactly_in_one_process`): two
   trainings of 72 joint steps with one seed give identical parameters and actions.
3. **Against 0.2** (:func:`test_the_uav_world_trains_as_before_coma_became_generic`): the
   per-tensor parameter sums that sb3-coma 0.2 recorded after 72 joint steps, at a tolerance
   derived from the measured cross-CPU spread (:data:`SUMS_REL`).

``python tests/test_uav_training_fingerprint.py`` rewrites ``tests/data/uav_one_update.json``
(the current code's numbers under each ATen kernel this CPU supports, and their spread).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import torch as th

from sb3_coma import COMA
from sb3_coma.common.checkpoints import atomic_write_text

ROOT = Path(__file__).resolve().parent.parent
ONE_UPDATE = ROOT / "tests" / "data" / "uav_one_update.json"
SUMS_02 = ROOT / "tests" / "data" / "uav_fingerprint_0.2.json"
#: The two short trainings: policy, extra policy_kwargs, COMA arguments.
ARMS: dict[str, tuple[str, dict[str, Any], dict[str, Any]]] = {
    "cbam_gain": ("CBAMPolicy", {"gain_inputs": True}, {"advantage": "q"}),
    "cnn_eps": ("UavCnnPolicy", {}, {"exploration_initial_eps": 0.3, "exploration_final_eps": 0.05}),
}
#: What one ``train()`` logs that depends on the data and the algorithm (not the schedules).
LOGGED = (
    "critic_loss",
    "actor_loss",
    "q_mean",
    "advantage_mean",
    "advantage_std",
    "explained_variance",
    "entropy",
    "clip_fraction",
)
#: Joint steps of one rollout: 12 steps of 2 env copies.
ONE_ROLLOUT = 24
#: One update: relative tolerance, and an absolute one for values near 0 (advantage means).
UPDATE_REL, UPDATE_ABS = 1e-3, 2e-5
#: Parameter sums after 72 joint steps: measured on an AMD EPYC (AVX-512) under the default, AVX2
#: and AVX-512 kernels, and against the Intel machine that recorded 0.2, they differ by up to
#: 1.6e-3 relative (the 8-element first CBAM bias, through Adam's sign-like first steps); 2e-2 is
#: 12 times that. A changed random stream or network moves the sums by far more (order 1).
SUMS_REL, SUMS_ABS = 2e-2, 1e-3
#: ATen kernels the recorder runs under (torch falls back to the best one the CPU has).
KERNELS = ("default", "avx2", "avx512")


def _train(arm: str, joint_steps: int) -> COMA:
    """The recorded short training: 3 UAVs, 6 decisions, 2 copies, small networks, one thread."""
    import uav_ipp

    policy, policy_kwargs, kwargs = ARMS[arm]
    small = {"features_extractor_kwargs": {"features_dim": 16, "channels": [8, 8, 8]}}
    threads = th.get_num_threads()
    th.set_num_threads(1)
    try:
        env = uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=3, n_uavs=3, budget=6, action_gain=True)
        model = COMA(
            policy,
            env,
            n_steps=12,
            batch_size=8,
            n_epochs=2,
            n_critic_epochs=2,
            seed=5,
            policy_kwargs={**small, **policy_kwargs},
            **kwargs,
        )
        model.learn(joint_steps)
    finally:
        th.set_num_threads(threads)
    return model


def one_update(arm: str) -> dict[str, float]:
    """What the first ``train()`` of :func:`_train` logs (``train/<key>`` for :data:`LOGGED`)."""
    model = _train(arm, ONE_ROLLOUT)
    assert model._n_updates == 1
    return {key: float(model.logger.name_to_value[f"train/{key}"]) for key in LOGGED}


def parameter_sums(model: COMA) -> dict[str, float]:
    return {name: float(value.double().sum()) for name, value in model.policy.state_dict().items()}


@pytest.mark.slow
@pytest.mark.parametrize("arm", sorted(ARMS))
def test_one_update_matches_its_record(arm: str) -> None:
    record = json.loads(ONE_UPDATE.read_text())
    spread = record["spread"][arm]
    for key, value in record["values"][arm].items():
        # the tolerance is justified by the recording CPU's measured spread, with room to spare
        assert spread[key] * 10 <= max(UPDATE_REL * abs(value), UPDATE_ABS), (key, spread[key])
    got = one_update(arm)
    for key, value in record["values"][arm].items():
        assert got[key] == pytest.approx(value, rel=UPDATE_REL, abs=UPDATE_ABS), key


@pytest.mark.slow
def test_a_training_repeats_exactly_in_one_process() -> None:
    runs = []
    for _ in range(2):
        model = _train("cbam_gain", 72)
        obs = model.get_env().reset()  # type: ignore[union-attr]
        runs.append((parameter_sums(model), model.predict(obs, deterministic=True)[0].tolist()))
    assert runs[0] == runs[1]


@pytest.mark.slow
@pytest.mark.parametrize("arm", sorted(ARMS))
def test_the_uav_world_trains_as_before_coma_became_generic(arm: str) -> None:
    """Parameter for parameter against sums recorded by sb3-coma 0.2 (tolerance: :data:`SUMS_REL`)."""
    recorded = json.loads(SUMS_02.read_text())[arm]["params"]
    got = parameter_sums(_train(arm, 72))
    assert set(got) == set(recorded)
    for key, value in recorded.items():
        assert got[key] == pytest.approx(value, rel=SUMS_REL, abs=SUMS_ABS), key


def _record_here() -> dict[str, dict[str, float]]:
    return {arm: one_update(arm) for arm in sorted(ARMS)}


def _cpu_model() -> str:
    """The CPU's model name (Linux), else the machine type."""
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        for line in cpuinfo.read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    return platform.machine()


def main() -> int:
    """Record :func:`one_update` under each ATen kernel (one subprocess each) and their spread."""
    if os.environ.get("_UAV_ONE_UPDATE_CHILD"):
        print(json.dumps(_record_here()))
        return 0
    runs = {}
    for kernel in KERNELS:
        env = {**os.environ, "ATEN_CPU_CAPABILITY": kernel, "_UAV_ONE_UPDATE_CHILD": "1"}
        out = subprocess.run([sys.executable, __file__], env=env, capture_output=True, text=True, check=True)
        runs[kernel] = json.loads(out.stdout.strip().splitlines()[-1])
    first = runs[KERNELS[0]]
    spread = {
        arm: {key: max(r[arm][key] for r in runs.values()) - min(r[arm][key] for r in runs.values()) for key in LOGGED}
        for arm in first
    }
    record = {
        "_provenance": "python tests/test_uav_training_fingerprint.py: what one train() of the fixed-seed training "
        "logs (values: the default ATen kernel), and the spread (max - min) across the ATen kernels "
        f"{', '.join(KERNELS)} of the recording CPU ({_cpu_model()}, torch "
        f"{th.__version__})",
        "values": first,
        "spread": spread,
    }
    atomic_write_text(ONE_UPDATE, json.dumps(record, indent=1, sort_keys=True) + "\n")
    print(json.dumps(spread, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
