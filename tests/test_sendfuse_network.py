"""SenDFuse network, fusion strategy, loss and weight files (fast, seeded, CPU only)."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest
import torch

from sb3_coma.sendfuse import weights as weights_mod
from sb3_coma.sendfuse.loss import DEFAULT_WEIGHTS, SenDFuseLoss
from sb3_coma.sendfuse.network import SenDFuseConfig, SenDFuseNet, fusion_strategy, fusion_weights
from sb3_coma.sendfuse.weights import (
    SenDFuseWeightsError,
    default_weights_path,
    load_weights,
    read_metadata,
    save_weights,
)


@pytest.fixture(autouse=True)
def _seed() -> None:
    torch.manual_seed(1234)


def _net(grid: int = 44) -> SenDFuseNet:
    """A fresh network whose (zero-initialised) residual head is randomised, so that its
    correction is not identically 0 and the tests below see the network at work."""
    torch.manual_seed(0)
    net = SenDFuseNet(grid_size=grid).eval()
    with torch.no_grad():
        net.head.weight.normal_(0.0, 0.05)
        net.head.bias.normal_(0.0, 0.01)
    return net


def _sensor_maps(count: int, grid: int = 44, seed: int = 0) -> torch.Tensor:
    """Clean env-like sensor maps: binary blobs where observed (square footprints), 0.5 elsewhere."""
    gen = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.arange(grid), torch.arange(grid), indexing="ij")
    maps = torch.full((count, grid, grid), 0.5)
    for i in range(count):
        truth = torch.zeros(grid, grid, dtype=torch.bool)
        for _ in range(3):
            cx, cy, r = (torch.rand(3, generator=gen) * torch.tensor([grid, grid, grid / 4])).tolist()
            truth |= (xx - cx) ** 2 + (yy - cy) ** 2 < (r + 2) ** 2
        for _ in range(3):
            side = int(torch.randint(5, 16, (1,), generator=gen))
            x0, y0 = (int(v) for v in torch.randint(0, grid - side, (2,), generator=gen))
            maps[i, y0 : y0 + side, x0 : x0 + side] = truth[y0 : y0 + side, x0 : x0 + side].float()
    return maps


def _channel(clean: torch.Tensor, lo: float = 0.6, sigma: float = 0.06, seed: int = 1) -> torch.Tensor:
    """The paper's channel: I_r = a(x, y) I + n, a ~ U(lo, 1), n ~ N(0, sigma^2) (loud by default)."""
    gen = torch.Generator().manual_seed(seed)
    a = lo + (1.0 - lo) * torch.rand(clean.shape, generator=gen)
    return a * clean + sigma * torch.randn(clean.shape, generator=gen)


# --------------------------------------------------------------------------- network shapes
@pytest.mark.parametrize("grid", [44, 32])
@pytest.mark.parametrize("n", [1, 2, 4, 6])
def test_fuse_shapes_and_range(grid: int, n: int) -> None:
    net = _net(grid)
    maps = _channel(_sensor_maps(3 * n, grid).view(3, n, grid, grid))
    valid = torch.ones(3, n, dtype=torch.bool)
    valid[1, 1:] = False  # one fusion with only its own map
    with torch.inference_mode():
        fused = net.fuse(maps, valid)
    assert fused.shape == (3, grid, grid)
    assert torch.isfinite(fused).all() and fused.min() >= 0.0 and fused.max() <= 1.0


@pytest.mark.parametrize("grid", [44, 32])
def test_encode_decode_forward_shapes(grid: int) -> None:
    net = _net(grid)
    x = torch.rand(5, 1, grid, grid)
    feats = net.encode(x)
    c1, c2, c3 = net.channels
    assert [tuple(f.shape) for f in feats] == [
        (5, c1, grid, grid),
        (5, c2, grid // 2, grid // 2),
        (5, c3, grid // 4, grid // 4),
    ]
    out = net(x)
    assert out.shape == (5, 1, grid, grid)
    # residual output: the decoder emits a correction, added where the map holds data, clipped
    expected = torch.clamp(torch.where(x != 0.5, x + net.decode(feats), x), 0.0, 1.0)
    assert torch.equal(out, expected)
    assert 10_000 <= net.num_parameters() <= 150_000


def test_unobserved_ground_has_zero_activity_at_every_scale() -> None:
    """Bias-free encoder on centred input: 0.5 everywhere (nothing observed) encodes to exactly 0,
    and scaling the centred signal scales every feature (positive homogeneity)."""
    net = _net()
    unknown = torch.full((2, 1, 44, 44), 0.5)
    assert all(bool((f == 0).all()) for f in net.encode(unknown))
    x = _sensor_maps(2)[:, None]
    half = 0.5 + 0.5 * (x - 0.5)  # centred signal x 0.5
    for full, scaled in zip(net.encode(x), net.encode(half)):
        torch.testing.assert_close(scaled, 0.5 * full, rtol=1e-5, atol=1e-6)


def test_fuse_accepts_float_validity_and_gradients_flow() -> None:
    net = SenDFuseNet()
    maps = torch.rand(2, 3, 44, 44)
    fused_bool = net.fuse(maps, torch.tensor([[True, True, False], [True, False, True]]))
    fused_float = net.fuse(maps, torch.tensor([[1.0, 1.0, 0.0], [1.0, 0.0, 1.0]]))
    torch.testing.assert_close(fused_bool, fused_float, rtol=0, atol=0)
    fused_bool.sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in net.parameters())


# --------------------------------------------------------------------------- fusion strategy
def test_fusion_weights_sum_to_one_and_masked_sources_get_zero() -> None:
    features = torch.randn(3, 5, 4, 6, 6)
    valid = torch.tensor(
        [[True, True, True, True, True], [True, False, True, False, False], [False, False, False, True, False]]
    )
    channel_w, spatial_w = fusion_weights(features, valid)
    assert channel_w.shape == (3, 5, 4) and spatial_w.shape == (3, 5, 6, 6)
    torch.testing.assert_close(channel_w.sum(1), torch.ones(3, 4))
    torch.testing.assert_close(spatial_w.sum(1), torch.ones(3, 6, 6))
    invalid = ~valid
    assert (channel_w[invalid] == 0).all() and (spatial_w[invalid] == 0).all()
    assert (channel_w[valid] > 0).all() and (spatial_w[valid] > 0).all()
    # A single valid source gets weight exactly 1.
    assert (channel_w[2, 3] == 1).all() and (spatial_w[2, 3] == 1).all()


def test_fusion_weights_follow_activity() -> None:
    """The more active source dominates: per channel (pooled) and per pixel (L1 over channels)."""
    quiet = torch.zeros(1, 1, 2, 3, 3)
    loud = torch.zeros(1, 1, 2, 3, 3)
    loud[..., 1, 1] = 5.0
    channel_w, spatial_w = fusion_weights(torch.cat((quiet, loud), 1), torch.ones(1, 2, dtype=torch.bool))
    assert (channel_w[0, 1] > channel_w[0, 0]).all()
    assert spatial_w[0, 1, 1, 1] > 0.99 and spatial_w[0, 1, 0, 0] == pytest.approx(0.5)


def test_fusion_of_identical_sources_is_that_source() -> None:
    stack = torch.randn(2, 1, 8, 11, 11)
    for n in (1, 2, 4, 6):
        features = stack.expand(2, n, 8, 11, 11)
        for alpha in (0.0, 0.3, 0.5, 1.0):
            fused = fusion_strategy(features, torch.ones(2, n, dtype=torch.bool), alpha)
            torch.testing.assert_close(fused, stack[:, 0], rtol=1e-6, atol=1e-6)


def test_fusion_is_layout_independent_and_permutation_invariant() -> None:
    features = torch.relu(torch.randn(2 * 4, 8, 12, 12))
    valid = torch.tensor([[True, True, False, True], [True, True, True, True]])
    plain = fusion_strategy(features.view(2, 4, 8, 12, 12), valid, 0.4)
    channels_last = features.contiguous(memory_format=torch.channels_last)
    torch.testing.assert_close(fusion_strategy(channels_last.view(2, 4, 8, 12, 12), valid, 0.4), plain)
    perm = torch.tensor([3, 1, 0, 2])
    permuted = fusion_strategy(features.view(2, 4, 8, 12, 12)[:, perm], valid[:, perm], 0.4)
    torch.testing.assert_close(permuted, plain)


def test_fusion_is_stable_with_large_activations_and_ignores_garbage_in_masked_slots() -> None:
    features = torch.randn(2, 6, 16, 11, 11) * 1e4  # L1 over 16 channels ~ 1e5: exp() would overflow
    features[0, 2] = float("nan")  # a slot that holds no data may hold anything
    features[1, 5] = float("inf")
    valid = torch.ones(2, 6, dtype=torch.bool)
    valid[0, 2] = False
    valid[1, 5] = False
    channel_w, spatial_w = fusion_weights(features, valid)
    assert torch.isfinite(channel_w).all() and torch.isfinite(spatial_w).all()
    torch.testing.assert_close(spatial_w.sum(1), torch.ones(2, 11, 11))
    fused = fusion_strategy(features, valid, 0.5)
    assert torch.isfinite(fused).all()
    # With huge gaps between activities the softmax is a hard max: spatial weights are one-hot.
    assert ((spatial_w.max(1).values - 1).abs() < 1e-6).float().mean() > 0.9


def test_fuse_with_the_own_map_alone_returns_it_and_one_received_map_is_denoised() -> None:
    net = _net()
    maps = _channel(_sensor_maps(8).view(2, 4, 44, 44)).clamp(0.0, 1.0)
    with torch.inference_mode():
        # Own map only: it bypasses the network and comes back exactly.
        single = net.fuse(maps[:, :1], torch.ones(2, 1, dtype=torch.bool))
        assert torch.equal(single, maps[:, 0])
        # Other slots invalid (even if they hold NaN): the same.
        garbage = maps.clone()
        garbage[:, 1:] = float("nan")
        valid = torch.tensor([[True, False, False, False]] * 2)
        assert torch.equal(net.fuse(garbage, valid), maps[:, 0])
        # Own map + one received map: the mean of the own map and the denoised received map
        # (where no clipping binds).
        two = net.fuse(maps[:, :2], torch.ones(2, 2, dtype=torch.bool))
        denoised = net(maps[:, 1:2])[:, 0]
        expected = (maps[:, 0] + denoised) / 2
        free = (denoised > 0) & (denoised < 1)
        assert free.float().mean() > 0.5
        torch.testing.assert_close(two[free], expected[free], rtol=0, atol=1e-5)
        # Dropping an invalid slot changes nothing.
        valid = torch.tensor([[True, True, False, True], [True, False, True, True]])
        full = net.fuse(maps, valid)
        torch.testing.assert_close(full[0], net.fuse(maps[:1, [0, 1, 3]], torch.ones(1, 3, dtype=torch.bool))[0])
        torch.testing.assert_close(full[1], net.fuse(maps[1:, [0, 2, 3]], torch.ones(1, 3, dtype=torch.bool))[0])


def test_the_clean_own_slot_passes_through_the_fusion_linearly() -> None:
    """Slot 0 (the UAV's own map, never sent over the channel) is not denoised: changing it by
    delta changes the fused map by exactly delta / n_valid, whatever the received maps hold."""
    net = _net()
    maps = _channel(_sensor_maps(12).view(3, 4, 44, 44)).clamp(0.2, 0.8)  # keep clear of the clip
    valid = torch.tensor([[True, True, True, True], [True, True, False, True], [True, False, False, True]])
    delta = 0.1 * torch.randn(3, 44, 44).clamp(-1.0, 1.0)
    shifted = maps.clone()
    shifted[:, 0] += delta
    with torch.inference_mode():
        base, moved = net.fuse(maps, valid), net.fuse(shifted, valid)
    n_valid = valid.sum(1, dtype=torch.float32)[:, None, None]
    torch.testing.assert_close(moved - base, delta / n_valid, rtol=0, atol=1e-5)
    # ... while the received maps do go through the network (a nonlinear correction).
    shifted = maps.clone()
    shifted[:, 3] += delta
    with torch.inference_mode():
        moved = net.fuse(shifted, valid)
    assert (moved - base - delta / n_valid).abs().max() > 1e-3


def test_cells_where_nothing_arrived_get_no_correction() -> None:
    """Received maps are exactly 0.5 where they hold no data: there the fusion is the plain mean,
    and a map that holds no data anywhere only dilutes the mean like it does in ``mean``."""
    net = _net()
    maps = _channel(_sensor_maps(8).view(2, 4, 44, 44)).clamp(0.0, 1.0)
    maps[:, 1:, :, :20] = 0.5  # left part: no received map holds data
    maps[1, 2] = 0.5  # an empty (but valid) received map
    valid = torch.ones(2, 4, dtype=torch.bool)
    with torch.inference_mode():
        fused = net.fuse(maps, valid)
    torch.testing.assert_close(fused[:, :, :20], maps[:, :, :, :20].mean(1), rtol=0, atol=1e-6)
    assert (fused[:, :, 20:] - maps[:, :, :, 20:].mean(1)).abs().max() > 1e-3  # elsewhere it works


def test_an_untrained_network_is_the_mean_fusion() -> None:
    """The residual head starts at zero: before training, fusion = the naive mean (clipped)."""
    torch.manual_seed(0)
    net = SenDFuseNet().eval()
    maps = _channel(_sensor_maps(12).view(3, 4, 44, 44))
    valid = torch.tensor([[True, True, True, True], [True, False, True, True], [True, False, False, False]])
    with torch.inference_mode():
        fused = net.fuse(maps, valid)
    w = valid.float()[:, :, None, None]
    expected = ((maps * w).sum(1) / w.sum(1)).clamp(0.0, 1.0)
    torch.testing.assert_close(fused, expected, rtol=0, atol=1e-6)


# --------------------------------------------------------------------------- argument checks
@pytest.mark.parametrize("grid", [42, 0, 2, -4, 45])
def test_bad_grid_size_is_rejected(grid: int) -> None:
    with pytest.raises(ValueError, match="multiple of 4"):
        SenDFuseNet(grid_size=grid)


@pytest.mark.parametrize("grid", ["44", 44.0, True])
def test_non_int_grid_size_is_rejected(grid: object) -> None:
    with pytest.raises(ValueError, match="grid_size must be an int"):
        SenDFuseNet(grid_size=grid)  # type: ignore[arg-type]


@pytest.mark.parametrize("alpha", [-0.1, 1.5, float("nan"), "half", None])
def test_bad_alpha_is_rejected(alpha: object) -> None:
    with pytest.raises(ValueError, match="alpha"):
        fusion_strategy(torch.rand(1, 2, 3, 4, 4), torch.ones(1, 2, dtype=torch.bool), alpha)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="alpha"):
        SenDFuseNet(fusion_alpha=alpha)  # type: ignore[arg-type]


def test_bad_shapes_and_validity_are_rejected() -> None:
    net = _net()
    maps = torch.rand(2, 3, 44, 44)
    with pytest.raises(ValueError, match=r"valid must have shape \(B, n\) = \(2, 3\)"):
        net.fuse(maps, torch.ones(2, 4, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"valid must have shape"):
        net.fuse(maps, torch.ones(3, dtype=torch.bool))
    with pytest.raises(ValueError, match="at least one valid source"):
        net.fuse(maps, torch.tensor([[True, False, False], [False, False, False]]))
    with pytest.raises(ValueError, match="R = 44"):
        net.fuse(torch.rand(2, 3, 32, 32), torch.ones(2, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match=r"\(B, 1, R, R\)"):
        net(torch.rand(2, 44, 44))
    with pytest.raises(ValueError, match="one channel"):
        net(torch.rand(2, 2, 44, 44))
    with pytest.raises(ValueError, match="floating-point"):
        net(torch.ones(2, 1, 44, 44, dtype=torch.long))
    with pytest.raises(ValueError, match=r"\(B, n, C, H, W\)"):
        fusion_strategy(torch.rand(2, 3, 4, 4), torch.ones(2, 3, dtype=torch.bool))
    with pytest.raises(ValueError, match="channels"):
        SenDFuseConfig(channels=(8, 16))  # type: ignore[arg-type]


# --------------------------------------------------------------------------- loss
def test_loss_is_zero_for_identical_inputs_and_positive_otherwise() -> None:
    loss = SenDFuseLoss()
    target = _sensor_maps(4)[:, None]
    same = loss(target, target.clone())
    for term in same:
        assert abs(float(term)) < 1e-6
    pred = _channel(target).clamp(0, 1)
    diff = loss(pred, target)
    assert diff.mse > 0 and diff.mae > 0 and diff.ssim > 0
    w_mse, w_mae, w_ssim = DEFAULT_WEIGHTS
    assert float(diff.total) == pytest.approx(
        w_mse * float(diff.mse) + w_mae * float(diff.mae) + w_ssim * float(diff.ssim)
    )
    # (B, H, W) inputs and maps smaller than the SSIM window work too.
    small = torch.rand(2, 6, 6)
    assert torch.isfinite(loss(small, small.flip(-1)).total)


def test_loss_rejects_bad_weights_and_shapes() -> None:
    with pytest.raises(ValueError, match="w_mse"):
        SenDFuseLoss(w_mse=-1.0)
    with pytest.raises(ValueError, match="at least one"):
        SenDFuseLoss(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="win_size"):
        SenDFuseLoss(win_size=4)
    with pytest.raises(ValueError, match="differ in shape"):
        SenDFuseLoss()(torch.rand(2, 1, 44, 44), torch.rand(2, 1, 32, 32))


def test_short_denoising_training_halves_the_loss() -> None:
    """150 Adam steps of the one-to-one denoising AE on fixed noisy/clean pairs."""
    torch.manual_seed(0)
    net = SenDFuseNet()
    loss_fn = SenDFuseLoss()
    clean = _sensor_maps(4)[:, None]
    noisy = _channel(clean)
    optimizer = torch.optim.Adam(net.parameters(), lr=3e-3)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # pytest-xdist runs one worker per core: more threads would thrash
    try:
        start = time.perf_counter()
        with torch.no_grad():
            initial = float(loss_fn(net(noisy), clean).total)
        for _ in range(150):
            optimizer.zero_grad()
            loss_fn(net(noisy), clean).total.backward()
            optimizer.step()
        with torch.no_grad():
            final = float(loss_fn(net(noisy), clean).total)
        elapsed = time.perf_counter() - start
    finally:
        torch.set_num_threads(threads)
    assert final <= 0.5 * initial, (initial, final)
    assert elapsed < 60, f"took {elapsed:.1f} s (budget ~5 s on one core)"  # only catches pathologies


# --------------------------------------------------------------------------- weight files
def test_weights_round_trip_bit_exactly(tmp_path: Path) -> None:
    net = _net(32)
    with torch.no_grad():  # make every tensor non-trivial
        for p in net.parameters():
            p.add_(torch.randn_like(p))
    path = save_weights(net, tmp_path / "sub" / "w.safetensors", {"command": "unit test", "seed": "0"})
    loaded = load_weights(path, expected_config={"grid_size": 32})
    assert loaded.config == net.config and not loaded.training
    original, restored = net.state_dict(), loaded.state_dict()
    assert original.keys() == restored.keys()
    for name in original:
        assert torch.equal(original[name], restored[name]), name
    x = torch.rand(2, 1, 32, 32)
    with torch.no_grad():
        assert torch.equal(net(x), loaded(x))
    meta = read_metadata(path)
    assert meta["command"] == "unit test" and meta["sendfuse.grid_size"] == "32"
    assert loaded.weights_metadata == meta
    assert not list(tmp_path.glob("sub/*.tmp"))  # atomic write left nothing behind


def test_saved_files_have_a_sorted_header_so_equal_weights_give_equal_bytes(tmp_path: Path) -> None:
    import json
    import struct

    net = _net(32)
    a = save_weights(net, tmp_path / "a.safetensors", {"zeta": "1", "alpha": "2", "mid": "3"})
    b = save_weights(net, tmp_path / "b.safetensors", {"mid": "3", "alpha": "2", "zeta": "1"})
    assert a.read_bytes() == b.read_bytes()
    raw = a.read_bytes()
    (length,) = struct.unpack("<Q", raw[:8])
    assert length % 8 == 0
    header = json.loads(raw[8 : 8 + length])
    assert list(header) == sorted(header) and list(header["__metadata__"]) == sorted(header["__metadata__"])
    load_weights(a)


def test_save_rejects_reserved_or_non_string_metadata(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="reserved"):
        save_weights(_net(), tmp_path / "w.safetensors", {"sendfuse.grid_size": "12"})
    with pytest.raises(ValueError, match="must be str"):
        save_weights(_net(), tmp_path / "w.safetensors", {"seed": 3})  # type: ignore[dict-item]


def test_missing_files_say_how_to_create_them(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    assert default_weights_path().parts[-3:] == ("sb3_coma", "pretrained", "sendfuse_r44.safetensors")
    with pytest.raises(SenDFuseWeightsError, match="sb3-coma pretrain-sendfuse"):
        load_weights(tmp_path / "nope.safetensors")
    monkeypatch.setattr(weights_mod, "default_weights_path", lambda grid_size=44: tmp_path / "absent.safetensors")
    with pytest.raises(SenDFuseWeightsError, match=r"shipped pre-trained.*sb3-coma pretrain-sendfuse"):
        load_weights()
    with pytest.raises(SenDFuseWeightsError, match="not a file"):
        load_weights(tmp_path)


def _good_file(tmp_path: Path) -> Path:
    return save_weights(_net(), tmp_path / "good.safetensors", {"note": "x"})


@pytest.mark.parametrize(
    "damage",
    ["truncate", "truncate_header", "empty", "garbage"],
)
def test_unreadable_files_raise(tmp_path: Path, damage: str) -> None:
    path = _good_file(tmp_path)
    data = path.read_bytes()
    bad = {
        "truncate": data[: len(data) - 100],
        "truncate_header": data[:20],
        "empty": b"",
        "garbage": b"PK\x03\x04 this is a zip, not safetensors" * 4,
    }[damage]
    path.write_bytes(bad)
    with pytest.raises(SenDFuseWeightsError, match="not a readable safetensors file"):
        load_weights(path)


def test_flipped_bits_in_tensor_data_are_detected(tmp_path: Path) -> None:
    path = _good_file(tmp_path)
    data = bytearray(path.read_bytes())
    data[-10] ^= 0x40  # inside the last tensor's bytes; the header stays valid
    path.write_bytes(bytes(data))
    with pytest.raises(SenDFuseWeightsError, match="checksum"):
        load_weights(path)


def _write_raw(path: Path, tensors: dict[str, torch.Tensor], meta: dict[str, str]) -> Path:
    from safetensors.torch import save_file

    save_file({k: v.contiguous() for k, v in tensors.items()}, str(path), metadata=meta)
    return path


def test_mismatched_tensors_and_configs_raise(tmp_path: Path) -> None:
    net = _net()
    good = _good_file(tmp_path)
    meta = read_metadata(good)
    state = {k: v.contiguous() for k, v in net.state_dict().items()}

    with pytest.raises(SenDFuseWeightsError, match="not a SenDFuse weight file"):
        load_weights(_write_raw(tmp_path / "foreign.safetensors", state, {"format": "pt"}))

    def resealed(tensors: dict[str, torch.Tensor], **changes: str) -> dict[str, str]:
        return {**meta, "sendfuse.sha256": weights_mod._digest(tensors), **changes}

    missing = {k: v for k, v in state.items() if k != "head.bias"}
    with pytest.raises(SenDFuseWeightsError, match=r"missing \['head.bias'\]"):
        load_weights(_write_raw(tmp_path / "missing.safetensors", missing, resealed(missing)))

    extra = {**state, "bonus.weight": torch.zeros(3)}
    with pytest.raises(SenDFuseWeightsError, match=r"unexpected \['bonus.weight'\]"):
        load_weights(_write_raw(tmp_path / "extra.safetensors", extra, resealed(extra)))

    reshaped = {**state, "head.bias": torch.zeros(2)}
    with pytest.raises(SenDFuseWeightsError, match=r"head\.bias.*shape"):
        load_weights(_write_raw(tmp_path / "shape.safetensors", reshaped, resealed(reshaped)))

    # The record says other widths than the tensors have.
    with pytest.raises(SenDFuseWeightsError, match="shape"):
        load_weights(
            _write_raw(tmp_path / "record.safetensors", state, resealed(state, **{"sendfuse.channels": "8,16,48"}))
        )

    with pytest.raises(SenDFuseWeightsError, match="format version 2"):
        load_weights(
            _write_raw(tmp_path / "v2.safetensors", state, resealed(state, **{"sendfuse.format_version": "2"}))
        )

    nan_state = {**state, "head.bias": torch.full_like(state["head.bias"], math.nan)}
    with pytest.raises(SenDFuseWeightsError, match="NaN"):
        load_weights(_write_raw(tmp_path / "nan.safetensors", nan_state, resealed(nan_state)))

    with pytest.raises(SenDFuseWeightsError, match="grid_size: file has 44, expected 32"):
        load_weights(good, expected_config={"grid_size": 32})
    with pytest.raises(SenDFuseWeightsError, match="channels"):
        load_weights(good, expected_config=SenDFuseConfig(channels=(4, 8, 16)))
    with pytest.raises(ValueError, match="unknown keys"):
        load_weights(good, expected_config={"grid": 44})
    assert load_weights(good, expected_config=SenDFuseConfig()).config == SenDFuseConfig()


# --------------------------------------------------------------------------- import hygiene
def test_the_world_imports_nothing_of_sb3_coma() -> None:
    """``envs`` finds the SenDFuse wrapper through an entry point when a vec env is built, so
    importing the environment package leaves the algorithm side alone (docs/design.md §2)."""
    import subprocess
    import sys

    code = "import sys, uav_ipp; uav_ipp.make_env('env1'); print(','.join(m for m in sys.modules if m.split('.')[0] == 'sb3_coma'))"
    root = Path(__file__).resolve().parents[1]
    result = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "", f"import uav_ipp pulled in: {result.stdout.strip()}"


def test_tune_cpu_allocator_is_safe_to_call() -> None:
    from sb3_coma.sendfuse.network import tune_cpu_allocator

    assert isinstance(tune_cpu_allocator(), bool)
