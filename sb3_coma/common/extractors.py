"""Convolutional features extractors for the 11 x 11 observation maps.

The paper's actor and critic share one trunk shape: conv 5x5 -> CBAM -> conv 4x4 -> CBAM ->
conv 4x4 -> FC. ``CBAMExtractor`` is that trunk; ``CnnExtractor`` is the same trunk without the
attention blocks (the ablation's "cnn" arm), so the two differ in CBAM only.

Geometry on an 11 x 11 map (default widths 32/64/64):

====================  =========================  ==========
layer                 kernel / stride / padding  output
====================  =========================  ==========
conv1 + ReLU          5 / 1 / 2                  32 x 11 x 11
CBAM                                             32 x 11 x 11
conv2 + ReLU          4 / 2 / 1                  64 x 5 x 5
CBAM                                             64 x 5 x 5
conv3 + ReLU          4 / 1 / 1                  64 x 4 x 4
flatten, FC + ReLU                               features_dim
====================  =========================  ==========

``residual=True`` turns each CBAM row into ``x + CBAM(x)`` (the shipped models' setting).

The first convolution keeps full resolution, so the attention sees every lattice cell; the
stride-2 second convolution keeps the trunk cheap on a CPU (about 3 M multiply-adds per map),
which matters because COMA's critic runs on every agent of every joint step.

Both extractors accept either a ``Box(C, H, W)`` space or a ``Dict`` space plus ``key`` (the
actor reads ``obs["local"]``), so they plug into SB3 policies as ``features_extractor_class``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from sb3_coma.common.numbers import is_flag, is_whole

#: Width of the learned encoder of the per-action gains (``gain_inputs=True``: COMA's UAV actor and
#: the PPO baselines' ``MapsExtractor``): the gains are mapped to this many features before they
#: join the trunk's features.
GAIN_ENCODER_DIM = 64


class ChannelGate(nn.Module):
    """CBAM's channel attention: which feature maps matter for this input.

    Average- and max-pooled channel descriptors go through one shared two-layer MLP; their sum
    through a sigmoid gives one weight in [0, 1] per channel. ``open_bias`` is added before the
    sigmoid (0, the default, in Woo et al.; see :class:`CBAMExtractor`).
    """

    def __init__(self, channels: int, reduction: int = 8, open_bias: float = 0.0) -> None:
        super().__init__()
        hidden = max(1, channels // reduction)
        self.mlp = nn.Sequential(nn.Linear(channels, hidden), nn.ReLU(), nn.Linear(hidden, channels))
        self.open_bias = float(open_bias)

    def gate(self, x: th.Tensor) -> th.Tensor:
        """Channel weights, shape (B, C, 1, 1), each in [0, 1]."""
        avg = x.mean(dim=(2, 3))
        mx = x.amax(dim=(2, 3))
        return th.sigmoid(self.mlp(avg) + self.mlp(mx) + self.open_bias)[:, :, None, None]

    def forward(self, x: th.Tensor) -> th.Tensor:
        return x * self.gate(x)


class SpatialGate(nn.Module):
    """CBAM's spatial attention: where in the map to look.

    The channel-wise mean and max maps are stacked and convolved by a single 7x7 kernel; a
    sigmoid gives one weight in [0, 1] per cell (``open_bias`` added before it, as in
    :class:`ChannelGate`).
    """

    def __init__(self, kernel_size: int = 7, open_bias: float = 0.0) -> None:
        super().__init__()
        self.conv = nn.Conv2d(2, 1, kernel_size, padding=kernel_size // 2)
        self.open_bias = float(open_bias)

    def gate(self, x: th.Tensor) -> th.Tensor:
        """Cell weights, shape (B, 1, H, W), each in [0, 1]."""
        pooled = th.cat([x.mean(dim=1, keepdim=True), x.amax(dim=1, keepdim=True)], dim=1)
        return th.sigmoid(self.conv(pooled) + self.open_bias)

    def forward(self, x: th.Tensor) -> th.Tensor:
        return x * self.gate(x)


class CBAM(nn.Module):
    """Convolutional Block Attention Module: channel gate, then spatial gate (Woo et al. 2018).

    ``residual=True`` returns ``x + CBAM(x)``, i.e. ``x * (1 + gates)``: the attention then
    re-weights features without shrinking them (the "attention residual" form of Wang et al.
    2017; Woo et al. place CBAM on a ResNet block's branch, which the identity shortcut adds to).
    """

    def __init__(
        self, channels: int, reduction: int = 8, spatial_kernel: int = 7, open_bias: float = 0.0, residual: bool = False
    ) -> None:
        super().__init__()
        self.channel = ChannelGate(channels, reduction, open_bias)
        self.spatial = SpatialGate(spatial_kernel, open_bias)
        self.residual = bool(residual)

    def forward(self, x: th.Tensor) -> th.Tensor:
        attended = self.spatial(self.channel(x))
        return x + attended if self.residual else attended


def _map_space(observation_space: spaces.Space, key: str | None) -> spaces.Box:
    """The (C, H, W) Box the trunk reads, from a Box or from ``observation_space[key]``."""
    space = observation_space.spaces.get(key or "") if isinstance(observation_space, spaces.Dict) else observation_space
    if not isinstance(space, spaces.Box) or len(space.shape) != 3:
        raise ValueError(
            f"expected a (C, H, W) Box observation space, or a Dict with `key` naming one, got {observation_space}"
            f"{f' and key={key!r}' if isinstance(observation_space, spaces.Dict) else ''}"
        )
    observation_space = space
    return observation_space


def _is_count(value: Any) -> bool:
    return is_whole(value) and value >= 1


def _is_finite(value: Any) -> bool:
    """A finite number, or anything ``float()`` turns into one (a YAML string such as ``"0.5"``);
    not a flag (``float(True)`` is 1.0)."""
    if is_flag(value):
        return False
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False


class _Trunk(BaseFeaturesExtractor):
    """Shared body of both extractors; ``use_cbam`` is the only difference between them."""

    def __init__(
        self,
        observation_space: spaces.Space,
        features_dim: int = 256,
        key: str | None = "local",
        channels: Sequence[int] = (32, 64, 64),
        use_cbam: bool = True,
        reduction: int = 8,
        gate_bias: float = 0.0,
        residual: bool = False,
    ) -> None:
        box = _map_space(observation_space, key if isinstance(observation_space, spaces.Dict) else None)
        # One row per argument: (name, value, accepted, what is allowed).
        rules = (
            ("features_dim", features_dim, _is_count(features_dim), "an integer >= 1"),
            ("reduction", reduction, _is_count(reduction), "an integer >= 1"),
            (
                "channels",
                channels,
                len(channels) == 3 and all(_is_count(c) for c in channels),
                "three widths (conv1, conv2, conv3), integers >= 1",
            ),
            ("gate_bias", gate_bias, _is_finite(gate_bias), "a number (finite)"),
            ("residual", residual, is_flag(residual), "true or false"),
        )
        for name, value, accepted, allowed in rules:
            if not accepted:
                raise ValueError(f"{name} must be {allowed}, got {value!r}")
        features_dim, reduction, residual = int(features_dim), int(reduction), bool(residual)
        super().__init__(observation_space, features_dim)
        self.key = key if isinstance(observation_space, spaces.Dict) else None
        in_ch, height, width = box.shape
        c1, c2, c3 = (int(c) for c in channels)
        gate_bias = float(gate_bias)

        def attend(width: int) -> nn.Module:
            return CBAM(width, reduction, open_bias=gate_bias, residual=residual) if use_cbam else nn.Identity()

        self.cnn = nn.Sequential(
            nn.Conv2d(in_ch, c1, kernel_size=5, stride=1, padding=2),
            nn.ReLU(),
            attend(c1),
            nn.Conv2d(c1, c2, kernel_size=4, stride=2, padding=1),
            nn.ReLU(),
            attend(c2),
            nn.Conv2d(c2, c3, kernel_size=4, stride=1, padding=1),
            nn.ReLU(),
            nn.Flatten(),
        )
        with th.no_grad():
            n_flat = self.cnn(th.zeros(1, in_ch, height, width)).shape[1]
        self.linear = nn.Sequential(nn.Linear(n_flat, features_dim), nn.ReLU())

    def forward(self, observations: th.Tensor | dict[str, th.Tensor]) -> th.Tensor:
        if isinstance(observations, dict):
            assert self.key is not None  # a Dict observation space always names its key (_map_space)
            observations = observations[self.key]
        return self.linear(self.cnn(observations))

    @property
    def cbams(self) -> list[CBAM]:
        """The attention blocks in order (empty for the plain CNN); handy for inspecting gates."""
        return [m for m in self.cnn if isinstance(m, CBAM)]


class CBAMExtractor(_Trunk):
    """Paper trunk with attention: conv 5x5 -> CBAM -> conv 4x4 -> CBAM -> conv 4x4 -> FC.

    :param observation_space: a ``Box(C, H, W)`` or a ``Dict`` holding one under ``key``
    :param features_dim: width of the final fully connected layer
    :param key: which entry of a ``Dict`` observation to read (ignored for a ``Box``)
    :param channels: widths of the three convolutions
    :param reduction: channel-gate MLP reduction ratio
    :param gate_bias: added to both gates' logits before the sigmoid. ``0`` (default) is Woo et
        al.'s CBAM: its gates start near 0.5 each, so two blocks shrink the trunk's features about
        30-fold at initialisation (feature std 0.014 vs 0.46 for the plain CNN on env3
        observations). ``3`` starts the gates near 0.95 (open), so the untrained trunk passes its
        features almost unchanged. Measured on env3 with the shipped settings, three seeds each,
        it did not train better models (docs/ABLATION.md), so the shipped models keep ``0``.
    :param residual: each block returns ``x + CBAM(x)`` (see :class:`CBAM`), so attention
        re-weights the trunk's features without shrinking them. The shipped models use it: with
        it the CBAM actor learns corrections as large as the plain CNN's (docs/training.md)
    """

    def __init__(
        self,
        observation_space: spaces.Space,
        features_dim: int = 256,
        key: str | None = "local",
        channels: Sequence[int] = (32, 64, 64),
        reduction: int = 8,
        gate_bias: float = 0.0,
        residual: bool = False,
    ) -> None:
        super().__init__(
            observation_space,
            features_dim,
            key,
            channels,
            use_cbam=True,
            reduction=reduction,
            gate_bias=gate_bias,
            residual=residual,
        )


class CnnExtractor(_Trunk):
    """The same trunk without CBAM, for the ablation (``UavCnnPolicy``)."""

    def __init__(
        self,
        observation_space: spaces.Space,
        features_dim: int = 256,
        key: str | None = "local",
        channels: Sequence[int] = (32, 64, 64),
    ) -> None:
        super().__init__(observation_space, features_dim, key, channels, use_cbam=False)
