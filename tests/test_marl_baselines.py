"""IPPO / MAPPO (sb3_coma.mappo.mappo): masking, what the actor reads, save/load, a short run."""

from __future__ import annotations

import base64
import json
import pickle
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch as th
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.utils import obs_as_tensor

import uav_ipp
from sb3_coma.mappo.mappo import (
    DEFAULT_PPO_KWARGS,
    IPPOPolicy,
    MAPPOPolicy,
    MapsExtractor,
    make_ippo,
    make_mappo,
    missions_of,
    timesteps_for_missions,
)
from uav_ipp import layout

TINY = dict(n_uavs=2, budget=4, split="train")  # random stars and random starts: varied masks
FACTORIES = {"ippo": make_ippo, "mappo": make_mappo}


def tiny_venv(n_envs: int = 2, seed: int = 0, **options):
    return uav_ipp.make_vec_env("env1", n_envs=n_envs, fusion="mean", seed=seed, **{**TINY, **options})


def tiny_model(kind: str, venv, **kwargs):
    return FACTORIES[kind](venv, seed=0, n_steps=32, batch_size=64, n_epochs=2, **kwargs)


def collect_observations(venv, steps: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Observations of ``steps`` vec-env steps under random valid actions, stacked over rows."""
    rng = np.random.default_rng(seed)
    obs = venv.reset()
    out = [obs]
    for _ in range(steps):
        mask = obs[layout.KEY_MASK].astype(bool)
        actions = np.array([rng.choice(np.flatnonzero(m)) for m in mask])
        obs, _, _, _ = venv.step(actions)
        out.append(obs)
    return {k: np.concatenate([o[k] for o in out]) for k in out[0]}


def assert_valid(actions, mask) -> None:
    actions = np.asarray(actions).reshape(-1)
    mask = np.asarray(mask)
    assert mask[np.arange(len(actions)), actions].all(), f"invalid actions {actions} for masks {mask}"


class MaskCheck(BaseCallback):
    """Checks, at every rollout step, that the sampled actions are valid under the observed mask."""

    def __init__(self) -> None:
        super().__init__()
        self.checked = 0
        self.restricted = 0

    def _on_step(self) -> bool:
        mask = self.locals["obs_tensor"][layout.KEY_MASK].cpu().numpy()
        assert_valid(self.locals["actions"], mask)
        self.checked += len(mask)
        self.restricted += int((mask == 0).any(axis=1).sum())
        return True


def force_invalid_preference(model: PPO) -> None:
    """Make every action's raw logit huge where the mask forbids it: only masking keeps it out."""
    with th.no_grad():
        model.policy.action_net.weight.zero_()
        model.policy.action_net.bias.copy_(th.tensor([50.0, 0.0, 0.0, 0.0, 0.0, 50.0]))


@pytest.mark.parametrize("kind", ["ippo", "mappo"])
def test_masks_honoured_in_rollouts_and_predict(kind):
    venv = tiny_venv()
    model = tiny_model(kind, venv)
    force_invalid_preference(model)  # up / down preferred: invalid at the top / bottom altitude
    check = MaskCheck()
    model.learn(total_timesteps=512, callback=check)
    assert check.checked >= 512 and check.restricted > 0
    other = tiny_venv(seed=3)
    obs = collect_observations(other, 8)
    other.close()
    probs = model.policy.action_probs(obs_as_tensor(obs, "cpu")).detach().numpy()
    assert (probs[obs[layout.KEY_MASK] == 0] == 0).all()
    for deterministic in (True, False):
        for _ in range(3):
            actions, _ = model.predict(obs, deterministic=deterministic)
            assert actions.shape == (len(obs[layout.KEY_MASK]),)
            assert_valid(actions, obs[layout.KEY_MASK])
    venv.close()


@pytest.mark.parametrize("kind", ["ippo", "mappo"])
def test_masks_honoured_after_training(kind):
    venv = tiny_venv()
    model = tiny_model(kind, venv)
    check = MaskCheck()
    model.learn(total_timesteps=384, callback=check)
    obs = collect_observations(venv, 10, seed=1)
    for deterministic in (True, False):
        actions, _ = model.predict(obs, deterministic=deterministic)
        assert_valid(actions, obs[layout.KEY_MASK])
    probs = model.policy.action_probs(obs_as_tensor(obs, "cpu")).detach().numpy()
    assert (probs[obs[layout.KEY_MASK] == 0] == 0).all()
    np.testing.assert_allclose(probs.sum(axis=1), 1.0, atol=1e-5)
    venv.close()


def _perturbed(obs: dict[str, np.ndarray], key: str, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    out = dict(obs)
    out[key] = rng.uniform(0.0, 1.0, obs[key].shape).astype(obs[key].dtype)
    return out


def _probs_and_values(model: PPO, obs: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    with th.no_grad():
        t = obs_as_tensor(obs, "cpu")
        return model.policy.action_probs(t).numpy(), model.policy.predict_values(t).numpy()


@pytest.mark.parametrize("kind", ["ippo", "mappo"])
def test_actor_never_reads_state_or_gain(kind):
    venv = tiny_venv()
    model = tiny_model(kind, venv)
    model.learn(total_timesteps=256)  # weights away from their initialisation
    obs = collect_observations(venv, 4, seed=2)
    probs, values = _probs_and_values(model, obs)
    for key in (layout.KEY_STATE, layout.KEY_GAIN):
        p2, v2 = _probs_and_values(model, _perturbed(obs, key))
        np.testing.assert_array_equal(p2, probs)  # the actor reads neither, bit for bit
        if key == layout.KEY_STATE and kind == "mappo":
            assert np.abs(v2 - values).max() > 1e-4  # the centralised value function does read state
        else:
            np.testing.assert_array_equal(v2, values)
    p3, _ = _probs_and_values(model, _perturbed(obs, layout.KEY_LOCAL))
    assert np.abs(p3 - probs).max() > 1e-6  # ... while it does read local
    venv.close()


@pytest.mark.parametrize("kind", ["ippo", "mappo"])
def test_gain_inputs_make_the_actor_read_the_gains(kind):
    """``gain_inputs=True``: the same on-board gains COMA's ``gain_inputs`` actor reads."""
    from sb3_coma.common.extractors import GAIN_ENCODER_DIM

    venv = tiny_venv()
    model = tiny_model(kind, venv, policy_kwargs=dict(features_extractor_kwargs=dict(gain_inputs=True)))
    extractor = model.policy.pi_features_extractor
    assert extractor.gain_encoder is not None and extractor.features_dim == 256 + GAIN_ENCODER_DIM
    model.learn(total_timesteps=256)
    obs = collect_observations(venv, 4, seed=2)
    probs, _ = _probs_and_values(model, obs)
    p2, _ = _probs_and_values(model, _perturbed(obs, layout.KEY_GAIN))
    assert np.abs(p2 - probs).max() > 1e-6
    venv.close()
    gainless = tiny_venv(action_gain=False)
    with pytest.raises(ValueError, match=r"gain_inputs=True needs observation\['action_gain'\]"):
        tiny_model(kind, gainless, policy_kwargs=dict(features_extractor_kwargs=dict(gain_inputs=True)))
    gainless.close()


def test_policy_structure():
    venv = tiny_venv()
    ippo, mappo = make_ippo(venv), make_mappo(venv)
    assert isinstance(ippo.policy, IPPOPolicy) and isinstance(mappo.policy, MAPPOPolicy)
    assert ippo.policy.share_features_extractor and ippo.policy.features_extractor.keys == ("local",)
    assert not mappo.policy.share_features_extractor
    assert mappo.policy.pi_features_extractor.keys == ("local",)
    assert mappo.policy.vf_features_extractor.keys == ("local", "state")
    assert mappo.policy.vf_features_extractor.trunk.cnn[0].in_channels == layout.LOCAL_CHANNELS + layout.STATE_CHANNELS
    for model in (ippo, mappo):
        assert (model.n_steps, model.batch_size, model.ent_coef) == (64, 256, 0.01)
        assert {k: getattr(model, k) for k in DEFAULT_PPO_KWARGS} == DEFAULT_PPO_KWARGS
    cbam = make_ippo(venv, policy_kwargs=dict(features_extractor_kwargs=dict(trunk="cbam", residual=True)))
    assert cbam.policy.features_extractor.trunk.cbams
    venv.close()


def test_mission_counting():
    venv = tiny_venv()
    assert timesteps_for_missions(10, venv) == 10 * 2 * 4
    assert missions_of(80, venv) == 10.0
    venv.close()


def test_bad_inputs():
    raw = uav_ipp.make_vec_env("env1", n_envs=1, fusion="none", seed=0, n_uavs=2, budget=4)
    with pytest.raises(ValueError, match="fusion"):
        make_ippo(raw)
    raw.close()
    venv = tiny_venv(n_envs=1)
    with pytest.raises(ValueError, match="no \\['nope'\\]"):
        MapsExtractor(venv.observation_space, keys=("nope",))
    with pytest.raises(ValueError, match="trunk"):
        MapsExtractor(venv.observation_space, trunk="resnet")
    with pytest.raises(ValueError, match="share_features_extractor=False"):
        make_ippo(venv, batch_size=64, policy_kwargs=dict(vf_features_extractor_kwargs=dict(keys=("local", "state"))))
    venv.close()


@pytest.mark.parametrize("kind", ["ippo", "mappo"])
def test_save_load_round_trip(kind, tmp_path):
    venv = tiny_venv()
    model = tiny_model(kind, venv)
    model.learn(total_timesteps=256)
    obs = collect_observations(venv, 6, seed=4)
    before, _ = model.predict(obs, deterministic=True)
    probs, values = _probs_and_values(model, obs)
    path = tmp_path / f"{kind}.zip"
    model.save(path)
    loaded = PPO.load(path, env=venv, device="cpu")
    assert type(loaded.policy) is type(model.policy)
    after, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(after, before)
    p2, v2 = _probs_and_values(loaded, obs)
    np.testing.assert_array_equal(p2, probs)
    np.testing.assert_array_equal(v2, values)
    if kind == "mappo":
        assert loaded.policy.vf_features_extractor.keys == ("local", "state")
    loaded.learn(total_timesteps=128)  # the loaded model keeps training
    venv.close()


def _as_saved_from_common(path: Path, module: str) -> None:
    """Rewrite a saved zip so that its policy class is pickled under ``module``, as zips saved while
    IPPO / MAPPO lived in ``sb3_coma.common`` (``marl_baselines``, ``central_value``) name it."""
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(members["data"])
    name = pickle.loads(base64.b64decode(data["policy_class"][":serialized:"])).__name__
    data["policy_class"][":serialized:"] = base64.b64encode(f"c{module}\n{name}\n.".encode()).decode()
    data["policy_class"]["__module__"] = module
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for member, content in members.items():
            archive.writestr(member, content)


def _load_in_a_fresh_interpreter(path: Path) -> str:
    """``module.Class`` of the policy that SB3's own ``PPO.load`` gives, nothing of ours imported first."""
    code = (
        "from stable_baselines3 import PPO\n"
        f"policy = type(PPO.load({str(path)!r}, device='cpu').policy)\n"
        "print(f'{policy.__module__}.{policy.__name__}')\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    return result.stdout.strip().splitlines()[-1]


def test_zips_saved_from_common_load_with_their_policy_class_moved(tmp_path):
    """Older zips pickle the policies under ``sb3_coma.common.marl_baselines``; ``sb3_coma.mappo``
    holds them now, and a plain ``PPO.load`` of such a zip still gives the same policy and actions."""
    venv = tiny_venv(n_envs=1)
    model = tiny_model("mappo", venv)
    obs = collect_observations(venv, 2, seed=1)
    path = tmp_path / "mappo_from_common.zip"
    model.save(path)
    _as_saved_from_common(path, "sb3_coma.common.marl_baselines")
    assert _load_in_a_fresh_interpreter(path) == "sb3_coma.mappo.mappo.MAPPOPolicy"
    loaded = PPO.load(path, env=venv, device="cpu")
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], model.predict(obs, deterministic=True)[0])
    import sb3_coma.common.marl_baselines as old  # the old public name (docs/design.md §7)

    assert old.make_ippo is make_ippo and old.MAPPOPolicy is MAPPOPolicy
    venv.close()


def test_zips_saved_from_common_load_with_the_central_value_policy_moved(tmp_path):
    """MAPPO on any env: older zips pickle ``CentralValuePolicy`` under ``sb3_coma.common.central_value``."""
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    from sb3_coma import make_marl_vec_env

    venv = make_marl_vec_env(lambda: simple_spread_v3.parallel_env(N=2, max_cycles=5), n_envs=1, seed=0)
    model = make_mappo(venv, n_steps=8, batch_size=16, seed=0)
    path = tmp_path / "mappo_any_env_from_common.zip"
    model.save(path)
    _as_saved_from_common(path, "sb3_coma.common.central_value")
    assert _load_in_a_fresh_interpreter(path) == "sb3_coma.mappo.central_value.CentralValuePolicy"


@pytest.mark.parametrize("kind", ["ippo", "mappo"])
def test_end_to_end_train_and_evaluate(kind):
    from sb3_coma import evaluate

    tic = time.perf_counter()
    venv = tiny_venv(n_envs=2, seed=0)
    model = FACTORIES[kind](venv, seed=0, n_epochs=4)  # the library defaults: n_steps 64, batch 256
    missions = 200
    model.learn(total_timesteps=timesteps_for_missions(missions, venv))  # 1,600 agent-steps
    assert model.num_timesteps >= 1600 and missions_of(model.num_timesteps, venv) >= missions
    result = evaluate(model, env="env1", n_trials=3, fusion="mean", n_uavs=2, budget=4, split="test")
    assert result.f1.shape == (3, 5) and np.isfinite(result.entropy).all()
    assert time.perf_counter() - tic < 60.0
    venv.close()
