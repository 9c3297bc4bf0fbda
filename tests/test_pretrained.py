"""Shipped models: load_pretrained verifies the checksum, returns a COMA that honours masks."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import uav_ipp
from sb3_coma import COMA
from sb3_coma import load_pretrained as exported
from sb3_coma.app import pretrained as pt
from sb3_coma.app.pretrained import PretrainedError, load_pretrained
from sb3_coma.common.checkpoints import training_options

pytestmark = pytest.mark.skipif(not (pt.pretrained_dir() / pt.MANIFEST).is_file(), reason="no shipped models")


def test_manifest_records_checksums_commands_metrics():
    data = pt.read_manifest()
    assert set(pt.available()) >= {"env1", "env2", "env3"}
    for name, entry in data["models"].items():
        path = pt.pretrained_dir() / entry["file"]
        assert path.is_file() and path.stat().st_size == entry["size_bytes"]
        assert pt.sha256_file(path) == entry["sha256"]
        command = entry["command"].split()
        assert command[:4] == ["sb3-coma", "train", "--env", entry["env"]]
        assert command[command.index("--seed") + 1] == str(entry["seed"])
        assert (command[command.index("--variant") + 1] if "--variant" in command else None) == entry["variant"]
        assert entry["train_wall_s"] > 0 and entry["timesteps"] > 0
        if "ablation_arm" in entry:  # flown by `sb3-coma reproduce` in the ablation table
            assert name == f"{entry['env']}-{entry['ablation_arm'][0]}-{entry['ablation_arm'][1]}"
        else:  # a map's model, or another actor of that map named after its variant
            assert name == entry["env"] + (f"-{entry['variant']}" if entry["variant"] else "")
            assert {"f1_100_mean", "entropy_100_mean"} <= set(entry["metrics"])


def test_manifest_env_options_are_the_models_own_record():
    """evaluate flies a shipped model with the manifest's options: they must be the zip's own
    record, not the current config's (which may have changed since the model was trained)."""
    for name, entry in pt.read_manifest()["models"].items():
        assert pt.shipped_env_options(name) == entry["env_options"] == training_options(load_pretrained(name))


def test_ablation_arms_are_shipped_with_their_fusion_and_extractor():
    from sb3_coma.common.extractors import CBAMExtractor
    from sb3_coma.experiments.reproduce import ABLATION_ARMS

    for (fusion, extractor), name in ABLATION_ARMS.items():
        model = load_pretrained(name)
        assert model.pretrained_info["fusion"] == fusion and model.pretrained_info["ablation_arm"] == [
            fusion,
            extractor,
        ]
        assert isinstance(model.policy.actor.features_extractor, CBAMExtractor) == (extractor == "cbam")


def test_load_pretrained_predict_honours_masks():
    assert exported is load_pretrained
    model = load_pretrained("env3")
    assert isinstance(model, COMA) and model.pretrained_info["env"] == "env3"
    assert pt.model_info("UavIpp-Env3-v0")["file"] == model.pretrained_info["file"]
    trained = training_options(model)
    venv = uav_ipp.make_vec_env(
        "env3", n_envs=2, fusion=trained["fusion"], seed=0, action_gain=trained["action_gain"], split="test"
    )
    obs = venv.reset()
    rng = np.random.default_rng(0)
    for _ in range(2):
        mask = np.zeros_like(obs["action_mask"])
        allowed = rng.integers(0, mask.shape[1], size=mask.shape[0])
        mask[np.arange(mask.shape[0]), allowed] = 1.0
        obs = dict(obs, action_mask=mask)
        for deterministic in (True, False):
            actions, _ = model.predict(obs, deterministic=deterministic)
            assert np.array_equal(actions, allowed)
        obs, *_ = venv.step(model.predict(obs, deterministic=True)[0])
    venv.close()


def test_unknown_name_is_a_clear_error():
    with pytest.raises(
        PretrainedError,
        match=r"unknown shipped model 'env9'; available: env1, env1-paper-actor, env2, env2-paper-actor, env3, env3-mean-cbam",
    ):
        load_pretrained("env9")
    assert issubclass(PretrainedError, ValueError)


def _copy(tmp_path):
    src = pt.pretrained_dir()
    entry = pt.model_info("env1")
    shutil.copyfile(src / pt.MANIFEST, tmp_path / pt.MANIFEST)
    shutil.copyfile(src / entry["file"], tmp_path / entry["file"])
    return tmp_path / entry["file"]


def test_checksum_mismatch_refuses_to_load(tmp_path):
    path = _copy(tmp_path)
    assert isinstance(load_pretrained("env1", directory=tmp_path), COMA)
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    with pytest.raises(PretrainedError, match=r"checksum mismatch.*NOT loaded"):
        load_pretrained("env1", directory=tmp_path)


def test_missing_file_and_manifest(tmp_path):
    path = _copy(tmp_path)
    path.unlink()
    with pytest.raises(PretrainedError, match="is missing"):
        load_pretrained("env1", directory=tmp_path)
    (tmp_path / pt.MANIFEST).unlink()
    with pytest.raises(PretrainedError, match=r"models\.json is missing"):
        load_pretrained("env1", directory=tmp_path)
    (tmp_path / pt.MANIFEST).write_text(json.dumps({"nothing": 1}))
    with pytest.raises(PretrainedError, match="no 'models' mapping"):
        load_pretrained("env1", directory=tmp_path)


def test_shipped_form_is_compact_and_flies_like_the_full_model(tmp_path):
    import zipfile

    import numpy as np
    import torch as th

    import uav_ipp
    from sb3_coma.app.pretrained import save_for_shipping

    venv = uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=0, n_uavs=2, budget=4)
    model = COMA("CBAMPolicy", venv, seed=0, n_steps=8, batch_size=8, n_epochs=1, device="cpu")
    model.learn(64)
    full = tmp_path / "full.zip"
    model.save(full)
    info = save_for_shipping(model, "small.zip", tmp_path)
    small = tmp_path / "small.zip"
    assert info["size_bytes"] == small.stat().st_size < 0.2 * full.stat().st_size
    with zipfile.ZipFile(small) as archive:
        assert all(entry.compress_type == zipfile.ZIP_DEFLATED for entry in archive.infolist())
    reference, shipped = COMA.load(full, device="cpu"), COMA.load(small, device="cpu")
    for a, b in zip(shipped.policy.critic.state_dict().values(), shipped.policy.critic_target.state_dict().values()):
        assert th.equal(a, b)  # the target critic is rebuilt as the critic
    obs = venv.reset()
    for _ in range(8):
        expected = reference.predict(obs, deterministic=True)[0]
        np.testing.assert_array_equal(shipped.predict(obs, deterministic=True)[0], expected)
        obs, *_ = venv.step(expected)
    shipped.set_env(venv)
    shipped.learn(16)  # a shipped model still trains


def test_coma_load_checks_a_shipped_zip_whatever_path_reaches_it(tmp_path, monkeypatch):
    """COMA.load itself refuses a replaced shipped zip (by path, through a symlink or '..');
    a copy elsewhere is the user's own and loads."""
    import shutil

    from sb3_coma.common import shipped

    folder = tmp_path / "pretrained"
    shutil.copytree(shipped.SHIPPED_DIR, folder, ignore=shutil.ignore_patterns("*.safetensors"))
    monkeypatch.setattr(shipped, "SHIPPED_DIR", folder)
    target = folder / "coma_env1.zip"
    COMA.load(target, device="cpu")  # intact: loads
    own = tmp_path / "mine.zip"
    shutil.copy(target, own)
    with open(target, "ab") as fh:
        fh.write(b"tampered")
    for path in (target, str(target)[: -len(".zip")], folder / ".." / "pretrained" / "coma_env1.zip"):
        with pytest.raises(shipped.ShippedFileError, match=r"coma_env1\.zip"):
            COMA.load(path, device="cpu")
    link = tmp_path / "link.zip"
    link.symlink_to(target)
    with pytest.raises(shipped.ShippedFileError, match="checksum mismatch"):
        COMA.load(link, device="cpu")
    COMA.load(own, device="cpu")  # the user's own copy elsewhere is not checked against the manifest
