"""ONNX export (``sb3_coma.app.export``, ``sb3-coma export``): the exported graphs act like the model.

Observations are recorded once by flying random valid actions on env1, env2 and env3 with the raw
observation (``fusion="none"``: the 7 local channels plus the received maps), then fused by the
env's own fusion wrappers, so the same recordings check the fusion graph (against the wrapper)
and the actor graph (against ``model.predict(obs, deterministic=True)``). Models are small fresh
COMA models, one per fusion, so nothing depends on the shipped files except one CLI test.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import yaml

import uav_ipp
from sb3_coma import COMA
from sb3_coma.app.export import (
    ACTOR_FILE,
    FUSION_FILE,
    METADATA_FILE,
    ExportError,
    export_onnx,
    fusion_wrapper,
    onnx_session,
)
from sb3_coma.cli import main as cli_main
from uav_ipp import layout

MAPS = ("env1", "env2", "env3")
#: Joint steps recorded per map: 4 UAVs x 20 steps (one mission of 15 and the start of the next).
STEPS = 20


@pytest.fixture(scope="module")
def raw_observations() -> dict[str, np.ndarray]:
    """Raw observations of random valid flights, rows of all three maps stacked."""
    rows = []
    for k, name in enumerate(MAPS):
        venv = uav_ipp.make_vec_env(name, n_envs=1, fusion="none", seed=10 + k)
        rng = np.random.default_rng(k)
        obs = venv.reset()
        for _ in range(STEPS):
            rows.append(obs)
            actions = np.array([rng.choice(np.flatnonzero(m > 0.5)) for m in obs[layout.KEY_MASK]])
            obs, _, _, _ = venv.step(actions)
        venv.close()
    return {key: np.concatenate([r[key] for r in rows]) for key in rows[0]}


#: The exported actors: the paper's (8 local channels), one that reads the gains as inputs (the
#: shipped models), and one with a gain prior and bounded correction.
ACTORS = {
    "mean": ("mean", {}),
    "sendfuse-gain-inputs": ("sendfuse", {"gain_inputs": True}),
    "mean-gain-prior": ("mean", {"gain_prior": 10.0, "correction_bound": 5.0}),
}


@pytest.fixture(scope="module", params=list(ACTORS))
def exported(request, raw_observations, tmp_path_factory):
    """(model, written paths, fused observations, raw observations, the env's fusion wrapper).

    Both actor graphs (with and without the ``action_gain`` input) are covered."""
    fusion, policy_kwargs = ACTORS[request.param]
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion=fusion, seed=0)
    model = COMA("CBAMPolicy", venv, seed=0, device="cpu", policy_kwargs=policy_kwargs)
    paths = export_onnx(model, tmp_path_factory.mktemp(f"onnx_{request.param}"))
    wrapper = fusion_wrapper(venv)
    assert wrapper is not None and wrapper.name == fusion
    fused = wrapper.observations(dict(raw_observations))
    yield model, paths, fused, raw_observations, wrapper
    venv.close()


#: onnxruntime's type names of the dtypes observations use.
ORT_TYPES = {"tensor(float)": "float32", "tensor(int8)": "int8", "tensor(uint8)": "uint8", "tensor(bool)": "bool"}


def _actor_feeds(session, obs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The actor's inputs as the env gives them; the graph declares the model's observation dtypes."""
    feeds = {i.name: obs[i.name] for i in session.get_inputs()}
    assert all(feeds[i.name].dtype == ORT_TYPES[i.type] for i in session.get_inputs())
    return feeds


def test_actor_argmax_equals_predict(exported):
    model, paths, obs, _, _ = exported
    assert len(obs[layout.KEY_LOCAL]) >= 200
    want, _ = model.predict(obs, deterministic=True)
    session = onnx_session(paths["actor"])
    logits, actions = session.run(None, _actor_feeds(session, obs))
    np.testing.assert_array_equal(actions, want)
    assert len(np.unique(want)) > 1  # the check is not a constant answer
    assert np.all(obs[layout.KEY_MASK][np.arange(len(actions)), actions] > 0.5)  # never an invalid action
    import torch as th

    with th.no_grad():
        rows = {k: th.as_tensor(obs[k]) for k in (layout.KEY_LOCAL, layout.KEY_GAIN) if k in obs}
        ref = model.policy.masked_logits(rows, th.as_tensor(obs[layout.KEY_MASK])).numpy()
    np.testing.assert_allclose(logits, ref, rtol=1e-5, atol=1e-5)


def test_fusion_graph_equals_pytorch_fusion(exported):
    _, paths, obs, raw, wrapper = exported
    session = onnx_session(paths["fusion"])
    fused, channel = session.run(
        None, {"received": raw[layout.KEY_RECEIVED], "received_valid": raw[layout.KEY_RECEIVED_VALID]}
    )
    want = wrapper.fuse(raw[layout.KEY_RECEIVED], raw[layout.KEY_RECEIVED_VALID])
    np.testing.assert_allclose(fused, want, rtol=0, atol=1e-5)
    np.testing.assert_allclose(channel, obs[layout.KEY_LOCAL][:, layout.FUSED], rtol=0, atol=1e-5)
    # the recordings hold both kinds of rows: UAVs that received maps and UAVs that received none
    received_any = raw[layout.KEY_RECEIVED_VALID][:, 1:].max(axis=1)
    assert received_any.min() == 0.0 and received_any.max() == 1.0


def test_onboard_pipeline_acts_like_the_model(exported):
    """fusion.onnx -> 8th channel -> actor.onnx on raw observations gives the model's actions."""
    model, paths, obs, raw, _ = exported
    fusion, actor = onnx_session(paths["fusion"]), onnx_session(paths["actor"])
    _, channel = fusion.run(
        None, {"received": raw[layout.KEY_RECEIVED], "received_valid": raw[layout.KEY_RECEIVED_VALID]}
    )
    onboard = dict(raw, local=np.concatenate([raw[layout.KEY_LOCAL], channel[:, None]], axis=1))
    _, actions = actor.run(None, _actor_feeds(actor, onboard))
    np.testing.assert_array_equal(actions, model.predict(obs, deterministic=True)[0])


def test_metadata_describes_the_graphs(exported):
    model, paths, _, _, wrapper = exported
    meta = json.loads(paths["metadata"].read_text())
    assert set(paths) == {"actor", "fusion", "metadata"} and all(p.is_file() for p in paths.values())
    assert [p.name for p in (paths["actor"], paths["fusion"], paths["metadata"])] == [
        ACTOR_FILE,
        FUSION_FILE,
        METADATA_FILE,
    ]
    assert meta["opset"] >= 17 and meta["check"]["done"]
    for block, path in (("actor", paths["actor"]), ("fusion", paths["fusion"])):
        session = onnx_session(path)
        declared = [(i["name"], i["shape"][1:], i["dtype"]) for i in meta[block]["inputs"]]
        actual = [(i.name, list(i.shape[1:]), ORT_TYPES[i.type]) for i in session.get_inputs()]
        assert declared == actual
        assert [o["name"] for o in meta[block]["outputs"]] == [o.name for o in session.get_outputs()]
    assert meta["fusion"]["kind"] == wrapper.name
    env = meta["env"]
    assert env["name"] == "env1" and env["fusion"] == wrapper.name and env["config"]["n_uavs"] == 4
    assert env["config"]["comm_grid"] == 44 and env["config"]["noise"] == "moderate"
    assert ("action_gain" in [i["name"] for i in meta["actor"]["inputs"]]) == model.policy.actor.reads_gain
    assert meta["actor"]["actions"] == list(layout.ACTION_NAMES)
    space = model.policy.observation_space
    assert [i["dtype"] for i in meta["actor"]["inputs"][:2]] == [str(space[k].dtype) for k in ("local", "action_mask")]


def test_export_needs_a_known_fusion(tmp_path):
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", n_uavs=2, budget=3)
    model = COMA(
        "UavCnnPolicy",
        venv,
        seed=0,
        device="cpu",
        policy_kwargs={"features_extractor_kwargs": {"features_dim": 8, "channels": [4, 4, 4]}},
    )
    model.save(tmp_path / "bare.zip")
    with pytest.raises(ExportError, match="fusion='telepathy'"):
        export_onnx(model, tmp_path / "out", fusion="telepathy")
    with pytest.raises(ExportError, match="opset=11"):
        export_onnx(model, tmp_path / "out", opset=11)
    venv.close()
    assert not (tmp_path / "out").exists()

    # the CLI on a bare zip: no recorded fusion, so --fusion is required; with it, the export works
    rc = cli_main(["export", "--model", str(tmp_path / "bare.zip"), "--out", str(tmp_path / "out")])
    assert rc == 2 and not (tmp_path / "out").exists()
    rc = cli_main(["export", "--model", str(tmp_path / "bare.zip"), "--out", str(tmp_path / "out"), "--fusion", "mean"])
    assert rc == 0
    meta = json.loads((tmp_path / "out" / METADATA_FILE).read_text())
    assert meta["env"]["config"]["n_uavs"] == 2 and meta["fusion"]["kind"] == "mean"
    assert meta["source"]["path"] == str(tmp_path / "bare.zip") and len(meta["source"]["sha256"]) == 64
    assert "not recorded" in meta["env"]["from"]

    # a checkpoint of an `sb3-coma train` run folder: fusion and env options come from its config.yml
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.yml").write_text(
        yaml.safe_dump(
            {
                "UavIpp-Env1-v0": {
                    "n_timesteps": 8,
                    "policy": "UavCnnPolicy",
                    "env_kwargs": {"fusion": "mean", "n_uavs": 2, "budget": 3, "noise": "loud"},
                },
                "run": {"env": "UavIpp-Env1-v0"},
            }
        )
    )
    model.save(run / "checkpoints" / "rl_model_8_steps.zip")
    rc = cli_main(["export", "--model", str(run / "checkpoints" / "rl_model_8_steps.zip"), "--out", str(run / "onnx")])
    assert rc == 0
    env = json.loads((run / "onnx" / METADATA_FILE).read_text())["env"]
    assert env["fusion"] == "mean" and env["options"] == {"n_uavs": 2, "budget": 3, "noise": "loud"}
    assert env["config"]["noise"] == "loud" and env["from"].startswith("run config")


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_cli_bad_inputs_fail_before_any_work(tmp_path, capsys, monkeypatch):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    out = tmp_path / "out"
    cases = [
        (["--model", "env9", "--out", str(out)], "unknown model 'env9'"),
        (["--model", "ag", "--out", str(out)], "'ag' is a baseline planner"),
        (["--model", str(tmp_path / "missing.zip"), "--out", str(out)], "model file not found"),
        (["--model", "env1", "--out", str(a_file)], f"--out {str(a_file)!r} is an existing file"),
        (["--model", "env1", "--out", str(a_file / "sub")], f"{str(a_file)!r} is a file"),
        (["--model", "env1", "--out", str(out), "--opset", "13"], "--opset 13"),
    ]
    locked = tmp_path / "locked"
    locked.mkdir()
    if os.geteuid() != 0:
        locked.chmod(0o500)
    else:  # root may write anywhere: stand in for a read-only folder
        real_access = os.access
        monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(locked) else real_access(p, mode))
    cases.append(
        (["--model", "env1", "--out", str(locked / "onnx")], f"--out {str(locked / 'onnx')!r} is not writable")
    )
    for argv, message in cases:
        assert cli_main(["export", *argv]) == 2, argv
        line = _error_line(capsys)
        assert line.startswith("sb3-coma export: error: ") and message in line, (argv, line)
    assert not out.exists() and not (locked / "onnx").exists()
    locked.chmod(0o700)


def test_cli_exports_a_shipped_model(tmp_path, capsys):
    rc = cli_main(["export", "--model", "env1", "--out", str(tmp_path / "env1")])
    assert rc == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    assert "actor.onnx" in text and "fusion.onnx" in text and "sendfuse" in text
    meta = json.loads((tmp_path / "env1" / METADATA_FILE).read_text())
    assert meta["env"]["name"] == "env1" and meta["env"]["fusion"] == "sendfuse"
    assert "coma_env1.zip" in meta["env"]["from"] and meta["source"]["shipped"]  # the zip records its options
    # the shipped actor reads the on-board gains as inputs (gain_inputs); the paper's actor does not
    assert [i["name"] for i in meta["actor"]["inputs"]] == ["local", "action_mask", "action_gain"]
    assert meta["actor"]["policy"]["gain_inputs"] is True and meta["actor"]["policy"]["gain_prior_weights"] is None
    assert meta["check"]["actor_max_abs_diff"] < 1e-4 and meta["check"]["fusion_max_abs_diff"] < 1e-5
