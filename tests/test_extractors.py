"""CBAM and plain-CNN extractors: shapes on the 11 x 11 maps, gates in [0, 1], clear errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_coma.common.extractors import CBAM, CBAMExtractor, CnnExtractor

LOCAL = spaces.Box(0.0, 1.0, (8, 11, 11), dtype=np.float32)
CRITIC = spaces.Box(0.0, 1.0, (12, 11, 11), dtype=np.float32)
DICT = spaces.Dict({"local": LOCAL, "action_mask": spaces.Box(0.0, 1.0, (6,), dtype=np.float32)})


@pytest.mark.parametrize("cls", [CBAMExtractor, CnnExtractor])
@pytest.mark.parametrize("space", [LOCAL, CRITIC])
@pytest.mark.parametrize("features_dim", [128, 256])
def test_box_shapes(cls: type, space: spaces.Box, features_dim: int) -> None:
    ext = cls(space, features_dim=features_dim)
    out = ext(th.rand(5, *space.shape))
    assert out.shape == (5, features_dim)
    assert ext.features_dim == features_dim
    assert th.isfinite(out).all()


@pytest.mark.parametrize("cls", [CBAMExtractor, CnnExtractor])
def test_dict_space_reads_the_local_key(cls: type) -> None:
    th.manual_seed(0)
    ext = cls(DICT, features_dim=64)
    local = th.rand(3, 8, 11, 11)
    from_dict = ext({"local": local, "action_mask": th.ones(3, 6)})
    assert from_dict.shape == (3, 64)
    # The mask is not a map: changing it must not change the features.
    assert th.equal(from_dict, ext({"local": local, "action_mask": th.zeros(3, 6)}))


def test_cbam_is_the_only_difference() -> None:
    cbam, cnn = CBAMExtractor(LOCAL), CnnExtractor(LOCAL)
    assert len(cbam.cbams) == 2 and len(cnn.cbams) == 0
    n_cbam = sum(p.numel() for p in cbam.parameters())
    n_cnn = sum(p.numel() for p in cnn.parameters())
    n_attention = sum(p.numel() for block in cbam.cbams for p in block.parameters())
    assert n_cbam - n_cnn == n_attention > 0


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_cbam_gates_lie_in_unit_interval(scale: float) -> None:
    th.manual_seed(1)
    block = CBAM(32)
    x = (th.randn(4, 32, 11, 11) * scale).relu()
    channel = block.channel.gate(x)
    spatial = block.spatial.gate(block.channel(x))
    assert channel.shape == (4, 32, 1, 1) and spatial.shape == (4, 1, 11, 11)
    for gate in (channel, spatial):
        assert (gate >= 0).all() and (gate <= 1).all()
    # The block only rescales: output = x * channel gate * spatial gate.
    assert th.allclose(block(x), x * channel * spatial, rtol=1e-5, atol=1e-6)


def test_gradients_reach_every_parameter() -> None:
    ext = CBAMExtractor(CRITIC, features_dim=32)
    ext(th.rand(6, 12, 11, 11)).square().sum().backward()
    assert all(p.grad is not None for p in ext.parameters())


def test_bad_spaces_raise() -> None:
    with pytest.raises(ValueError, match="key"):
        CBAMExtractor(DICT, key="state")
    with pytest.raises(ValueError, match="C, H, W"):
        CnnExtractor(spaces.Box(0.0, 1.0, (6,), dtype=np.float32))
    with pytest.raises(ValueError, match="three widths"):
        CBAMExtractor(LOCAL, channels=(8, 16))


def test_open_gates_keep_the_trunk_scale() -> None:
    """``gate_bias=3`` starts both gates near sigma(3) = 0.95 instead of 0.5, so an untrained
    CBAM trunk is not a much smaller copy of the CNN trunk (the default 0 is Woo et al.'s CBAM)."""
    from functools import partial

    from stable_baselines3.common.policies import BasePolicy

    x = th.rand(16, *LOCAL.shape)
    stds = {}
    for name, ext in (
        ("paper", CBAMExtractor(LOCAL)),
        ("open", CBAMExtractor(LOCAL, gate_bias=3.0)),
        ("cnn", CnnExtractor(LOCAL)),
    ):
        th.manual_seed(0)
        ext.apply(partial(BasePolicy.init_weights, gain=np.sqrt(2)))  # as the COMA policy initialises trunks
        with th.no_grad():
            stds[name] = float(ext(x).std())
            gate = ext.cbams[0].channel.gate(ext.cnn[:2](x)) if name != "cnn" else None
        if gate is not None:
            assert abs(float(gate.mean()) - (0.95 if name == "open" else 0.5)) < 0.15, (name, float(gate.mean()))
    assert stds["paper"] < 0.1 * stds["cnn"] < stds["open"]


@pytest.mark.parametrize("bad", ["wide", float("inf")])
def test_bad_gate_bias_is_named(bad) -> None:
    with pytest.raises(ValueError, match="gate_bias must be"):
        CBAMExtractor(LOCAL, gate_bias=bad)


def test_residual_cbam_reweights_without_shrinking() -> None:
    """``residual=True``: each block returns ``x + CBAM(x) = x * (1 + gates)``, between x and 2x."""
    th.manual_seed(0)
    block = CBAM(16, residual=True)
    x = th.rand(4, 16, 11, 11)
    with th.no_grad():
        y = block(x)
        plain = block.spatial(block.channel(x))
    th.testing.assert_close(y, x + plain)
    assert (y >= x).all() and (y <= 2 * x + 1e-6).all()
    ext = CBAMExtractor(LOCAL, residual=True)
    assert all(b.residual for b in ext.cbams) and not any(b.residual for b in CBAMExtractor(LOCAL).cbams)
    with pytest.raises(ValueError, match="residual must be true or false, got 'yes'"):
        CBAMExtractor(LOCAL, residual="yes")
