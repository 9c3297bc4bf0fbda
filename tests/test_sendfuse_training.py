"""SenDFuse pre-training: env-generated pairs, a tiny seeded run, the shipped weights, the eval CLI.

Everything here is small enough to run in well under a minute on two CPU cores.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
import torch

from sb3_coma.cli import main
from sb3_coma.sendfuse.data import (
    NOISE_PRESETS,
    LockstepPair,
    PairConfig,
    collect_fusions,
    generate_pairs,
    random_truth,
)
from sb3_coma.sendfuse.network import SenDFuseNet
from sb3_coma.sendfuse.pretrain import PretrainConfig, dihedral, pretrain, rescale_encoder
from sb3_coma.sendfuse.weights import default_weights_path, load_weights, read_metadata

QUIET = {"none": 1.0}


# --------------------------------------------------------------------------- data
def test_quiet_preset_pairs_are_identical() -> None:
    """noise='none' in the noisy copy too: input and target must be the same maps, bit for bit."""
    data = generate_pairs(150, seed=3, config=PairConfig(noise_mix=QUIET))
    assert len(data) == 150
    assert np.array_equal(data.noisy, data.clean)
    assert (data.preset == NOISE_PRESETS.index("none")).all()
    # only valid slots: every map holds observed cells (a never-received slot is 0.5 everywhere)
    assert (np.abs(data.clean - 0.5) > 1e-6).any(axis=(1, 2)).all()


def test_noisy_pairs_are_aligned_with_their_clean_versions() -> None:
    data = generate_pairs(300, seed=4, config=PairConfig(noise_mix={"loud": 1.0}, own_take=0.3))
    own, other = data.own, ~data.own
    assert own.any() and other.any()
    assert np.array_equal(data.noisy[own], data.clean[own])  # own slot: never noised
    # channel noise only where something arrived: cells at 0.5 in the clean map (almost all of them
    # never received; a reading fraction can be exactly 1/2 too) stay 0.5 in the noisy map, and
    # elsewhere the noisy values are a*I + n around the clean ones
    unknown = data.clean[other] == 0.5
    assert np.mean(data.noisy[other][unknown] != 0.5) < 0.01
    diff = data.noisy[other][~unknown] - data.clean[other][~unknown]
    assert 0.0 < np.abs(diff).mean() < 0.2


def test_lockstep_runs_share_positions_links_and_global_map() -> None:
    pair = LockstepPair("env1", "loud", n_uavs=3, budget=4, map_seed=10_000, start="random")
    pair.set_truth(random_truth("field", np.random.default_rng(0)))
    steps = list(pair.run(seed=11, rng=np.random.default_rng(1)))
    assert [s.step for s in steps] == list(range(5))
    assert np.array_equal(pair.noisy.trajectory(), pair.quiet.trajectory())
    assert np.array_equal(pair.noisy.global_belief(), pair.quiet.global_belief())
    assert np.array_equal(pair.noisy.sensor_maps(), pair.quiet.sensor_maps())


def test_generation_is_seeded() -> None:
    a = generate_pairs(120, seed=5)
    b = generate_pairs(120, seed=5)
    c = generate_pairs(120, seed=6)
    assert np.array_equal(a.noisy, b.noisy) and np.array_equal(a.clean, b.clean)
    assert not np.array_equal(a.clean, c.clean)


def test_random_maps_have_both_classes() -> None:
    rng = np.random.default_rng(0)
    for kind in ("star", "blobs", "stripes", "field"):
        truth = random_truth(kind, rng)
        assert truth.valuable.shape == (493, 493) and 0.05 < truth.valuable.mean() < 0.75
    with pytest.raises(ValueError, match="unknown map kind"):
        random_truth("env3", rng)


def test_bad_pair_config_is_rejected() -> None:
    with pytest.raises(ValueError, match="noise presets"):
        generate_pairs(10, config=PairConfig(noise_mix={"deafening": 1.0}))
    with pytest.raises(ValueError, match="uavs"):
        generate_pairs(10, config=PairConfig(uavs=(1, 3)))


# --------------------------------------------------------------------------- training
def test_rescale_encoder_keeps_the_autoencoder_and_changes_only_the_fusion() -> None:
    torch.manual_seed(0)
    net = SenDFuseNet().eval()
    with torch.no_grad():
        net.head.weight.normal_(0.0, 0.05)  # zero-initialised: make the correction non-trivial
    x = torch.rand(3, 1, 44, 44)
    maps, valid = torch.rand(2, 3, 44, 44), torch.ones(2, 3, dtype=torch.bool)
    with torch.no_grad():
        before, fused_before = net(x), net.fuse(maps, valid)
        rescale_encoder(net, 0.05)
        torch.testing.assert_close(net(x), before, rtol=0, atol=1e-5)
        assert not torch.allclose(net.fuse(maps, valid), fused_before, atol=1e-4)


def test_dihedral_covers_the_eight_symmetries() -> None:
    x = torch.arange(9.0).view(1, 1, 3, 3)
    images = {tuple(dihedral(x, k).flatten().tolist()) for k in range(8)}
    assert len(images) == 8


def test_tiny_pretraining_lowers_the_loss() -> None:
    config = PretrainConfig(samples=96, epochs=3, batch=16, lr=3e-3, threads=1, calibrate=False, val_fraction=0.1)
    result = pretrain(config, progress=False, log=lambda _: None)
    losses = [h.total for h in result.history]
    assert losses[-1] < losses[0]
    assert np.isfinite(losses).all()
    assert result.scale == 1.0 and result.calibration == {}


def test_pretrain_command_is_deterministic(tmp_path, capsys) -> None:
    argv = [
        "pretrain-sendfuse",
        "--samples",
        "48",
        "--epochs",
        "1",
        "--batch",
        "16",
        "--threads",
        "1",
        "--seed",
        "7",
        "--calibration-fusions",
        "4",
        "--quiet",
    ]
    first, second = tmp_path / "a.safetensors", tmp_path / "b.safetensors"
    assert main([*argv, "--out", str(first)]) == 0
    assert main([*argv, "--out", str(second)]) == 0
    assert first.read_bytes() == second.read_bytes()
    meta = read_metadata(first)
    assert meta["seed"] == "7" and meta["samples"] == "48" and meta["epochs"] == "1"
    assert meta["command"].startswith("sb3-coma pretrain-sendfuse --samples 48")
    assert float(meta["final_loss"]) > 0
    assert float(meta["fusion_scale"]) in PretrainConfig().calibration_scales
    assert "final loss" in capsys.readouterr().out
    load_weights(first)  # a valid weight file


def test_pretrain_command_rejects_bad_values(capsys) -> None:
    assert main(["pretrain-sendfuse", "--samples", "0", "--quiet"]) == 2
    assert "--samples" in capsys.readouterr().err


# --------------------------------------------------------------------------- shipped weights
def test_shipped_weights_denoise_held_out_loud_maps() -> None:
    """On env3 (never seen in pre-training), loud channel: the network beats the noisy input."""
    path = default_weights_path(44)
    assert path.is_file(), f"shipped weights missing at {path}"
    net = load_weights(path)
    assert 10_000 < net.num_parameters() < 100_000 and path.stat().st_size < 200_000
    meta = read_metadata(path)
    assert meta["command"].startswith("sb3-coma pretrain-sendfuse")
    pair = LockstepPair("env3", "loud", n_uavs=4, budget=15, comm_range=30.0)
    noisy, clean = [], []
    for step in pair.run(seed=0, rng=np.random.default_rng(0)):
        receiver, slot = np.nonzero(step.valid)
        keep = slot > 0
        noisy.append(step.noisy[receiver[keep], slot[keep]])
        clean.append(step.clean[receiver[keep], slot[keep]])
    x = torch.from_numpy(np.concatenate(noisy))[:, None]
    y = torch.from_numpy(np.concatenate(clean))[:, None]
    assert len(x) > 10
    with torch.inference_mode():
        denoised = net(x)
    identity = float(((x - y) ** 2).mean())
    assert float(((denoised - y) ** 2).mean()) < identity


def test_calibration_set_and_fused_error_helpers() -> None:
    from sb3_coma.sendfuse.quality import fusion_set_errors

    fusions = collect_fusions(6, seed=0, config=PairConfig(noise_mix={"none": 1.0, "loud": 1.0}))
    assert len(fusions) == 6 and (fusions.valid.sum(axis=1) >= 2).all()
    errors = fusion_set_errors(load_weights(), fusions)
    assert set(errors) == {"none", "loud"}
    assert errors["none"][0] == 0.0  # the mean of clean maps is the reference itself


# --------------------------------------------------------------------------- eval CLI
def test_eval_command_runs_on_a_tiny_setting(capsys) -> None:
    assert main(["eval-sendfuse", "--env", "env2", "--missions", "1", "--budget", "4", "--markdown"]) == 0
    out = capsys.readouterr().out
    assert "| noise |" in out
    for preset in NOISE_PRESETS:
        assert f"| {preset} |" in out


def test_eval_command_reports_user_errors(tmp_path, capsys) -> None:
    assert main(["eval-sendfuse", "--missions", "1", "--noise", "deafening"]) == 2
    assert "--noise" in capsys.readouterr().err
    missing = tmp_path / "nope.safetensors"
    assert main(["eval-sendfuse", "--missions", "1", "--weights", str(missing)]) == 2
    assert str(missing) in capsys.readouterr().err


def test_quality_rows_and_table() -> None:
    from sb3_coma.sendfuse.quality import evaluate_quality, format_table

    net = copy.deepcopy(load_weights())
    rows = evaluate_quality(net, "env1", missions=1, budget=3, presets=("none", "loud"), comm_range=40.0)
    assert [r.noise for r in rows] == ["none", "loud"]
    assert rows[0].mean_mse == 0.0 and rows[1].mean_mse > 0.0
    assert all(r.fusions > 0 and np.isfinite(r.sendfuse_mse) for r in rows)
    text = format_table(rows)
    assert "SenDFuse MSE" in text and text.count("\n") == 2


def test_pretrain_never_writes_into_the_package(tmp_path, capsys) -> None:
    inside = default_weights_path(44).parent / "mine.safetensors"
    assert main(["pretrain-sendfuse", "--samples", "48", "--epochs", "1", "--quiet", "--out", str(inside)]) == 2
    assert "inside the installed package" in capsys.readouterr().err
    assert not inside.exists()


def test_shipped_weights_are_checksummed(tmp_path, monkeypatch) -> None:
    from sb3_coma.sendfuse import weights as weights_mod

    shipped = default_weights_path(44)
    assert weights_mod._file_sha256(shipped) == weights_mod.SHIPPED_SHA256[44]
    replaced = tmp_path / shipped.name
    replaced.write_bytes(shipped.read_bytes()[:-1] + b" ")  # still parses as safetensors? never trusted
    monkeypatch.setattr(weights_mod, "default_weights_path", lambda grid_size=44: replaced)
    with pytest.raises(weights_mod.SenDFuseWeightsError, match="recorded SHA-256"):
        load_weights()
    load_weights(shipped)  # an explicit path is the user's choice: checked for integrity, not for origin
