"""SenDFuse: the sensor denoising and fusion network (paper section III-B, docs/design.md §4).

A NestFuse-style autoencoder sized for the communication grid (R x R, R = 44 by default):

* encoder, three scales (R, R/2, R/4; 2x max-pool between them), one small conv block per scale;
* nested decoder (UNet++-like dense skips): ``D1_1 = block(E1, up E2)``,
  ``D2_1 = block(E2, up E3)``, ``D1_2 = block(E1, D1_1, up D2_1)``, then a 1 x 1 conv that
  outputs a *correction*, not a map (residual output, see below);
* pre-training (:meth:`SenDFuseNet.forward`): one map in, one map out, fusion off (a denoising
  AE): ``clamp(x + observed(x) * correction(x), 0, 1)``;
* deployment (:meth:`SenDFuseNet.fuse`): the UAV's own map (slot 0, never sent over the channel,
  hence always clean) bypasses the network; every valid *received* map of every UAV is encoded
  in one batched pass, each scale is fused over the received maps with :func:`fusion_strategy`,
  the fused features are decoded once per UAV into a correction, and the output is the plain
  average of all valid maps plus that correction where received maps hold data.

Why residual + own-map bypass (issue #4): a clean 10-15 m sensor map varies from comm cell to
comm cell about as much as moderate channel noise does, so an autoencoder that has to
*reconstruct* every map smooths clean maps too, and the first layout (``nestfuse3-v1``, sigmoid
output of the fused features) lost to the plain mean at moderate noise on the comm grid. Now
(1) the own map, known to be clean, is used exactly as it is, (2) the network only has to learn
what to *change* in a received map (identity is the zero correction, and the head starts at
zero, i.e. at the mean fusion), and (3) cells where a received map holds no data (exactly 0.5:
the channel noises only delivered cells) get no correction from that map, so "nothing arrived"
stays neutral.

This module imports only torch and the standard library.

No batch normalisation anywhere: fusion mixes encoder features of *different* sources, and a
decoder whose normalisation statistics were learnt on single sources would see shifted inputs;
plain conv + ReLU keeps "fuse one source" exactly equal to "autoencode it".

Speed (the deployment budget is 4 fusions of 4 sources in <= 8 ms on one CPU core at R = 44):
at these tiny channel counts oneDNN convolutions are ~1.5x faster in channels-last layout, so the
parameters are kept channels-last and every intermediate stays channels-last; the fusion works
on a ``(B, n, pixels, C)`` view of that memory with one fused multiply-add per source (a plain
broadcast ``(w * f).sum(1)`` over a channels-last 5-D view was 3-4x slower); max-pooling is the
max of four strided views (2x faster than ``max_pool2d`` there). Whatever the layout of the
inputs, results are the same up to float rounding. Processes that fuse in a loop should call
:func:`tune_cpu_allocator` once (glibc otherwise re-faults a few MB of freed memory every step).
Time it with ``python -m sb3_coma.sendfuse [--tune-malloc]``.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from uav_ipp.config import is_flag, is_whole

#: Name of the layer layout below; stored in weight files so a future layout change is detected.
ARCHITECTURE = "nestfuse3-residual-v2"
#: Side of the communication grid the shipped weights are trained for (docs/design.md §3).
DEFAULT_GRID_SIZE = 44
#: Channel widths of the three encoder scales (full, half, quarter resolution); see SenDFuseNet.
DEFAULT_CHANNELS: tuple[int, int, int] = (8, 16, 32)
#: Weight of channel attention in ``F = alpha * C + (1 - alpha) * S`` (paper: alpha + beta = 1).
DEFAULT_FUSION_ALPHA = 0.5
#: Number of encoder scales (full, half, quarter resolution), hence R must be divisible by 4.
N_SCALES = 3
#: Value of a comm cell that holds no data (never observed / nothing received). The channel only
#: noises delivered cells, so a received map is exactly 0.5 where nothing arrived.
UNKNOWN = 0.5
#: Conv layers per block (encoder scales 1-3; decoder nodes D1_1, D2_1, D1_2). One conv per
#: block except the quarter-resolution encoder block: in a 600-step denoising comparison on
#: env-like maps, (1,1,2)/(1,1,1) matched deeper variants ((1,2,2)/(1,1,1), 28k parameters;
#: (1,1,1)/(1,1,1), 17k) within run-to-run noise, while every extra full- or half-resolution
#: conv over the 16 encoded maps costs 0.4-1 ms of the 8 ms fusion budget; quarter resolution
#: is where depth is cheap.
ENCODER_DEPTHS: tuple[int, int, int] = (1, 1, 2)
DECODER_DEPTHS: tuple[int, int, int] = (1, 1, 1)  # D1_1, D2_1, D1_2


def _check_grid_size(grid_size: Any) -> int:
    """Validate R early: the two 2x poolings and 2x upsamplings only round-trip when 4 | R."""
    if not is_whole(grid_size) or grid_size < 4 or grid_size % 4:
        raise ValueError(
            f"grid_size must be an int, a positive multiple of 4 (the encoder halves the map twice: "
            f"R, R/2, R/4), got {grid_size!r}; e.g. 44 = 4 x 11 for the 11 x 11 lattice"
        )
    return int(grid_size)


def _check_alpha(alpha: Any) -> float:
    """``alpha`` mixes two convex combinations; outside [0, 1] the result is no longer convex."""
    try:
        value = math.nan if is_flag(alpha) else float(alpha)
    except (TypeError, ValueError):
        value = math.nan
    if not 0.0 <= value <= 1.0:  # also rejects NaN, hence a bool or anything that is not a number
        raise ValueError(f"fusion alpha must be a number in [0, 1], got {alpha!r}")
    return value


@dataclass(frozen=True)
class SenDFuseConfig:
    """Everything needed to rebuild the architecture (stored in the weight file's metadata).

    ``fusion_alpha`` is deliberately not part of it: it is a deployment knob without learnt
    parameters, so one weight file stays usable with any alpha.
    """

    grid_size: int = DEFAULT_GRID_SIZE
    channels: tuple[int, ...] = DEFAULT_CHANNELS  # N_SCALES widths, checked in __post_init__

    def __post_init__(self) -> None:
        object.__setattr__(self, "grid_size", _check_grid_size(self.grid_size))
        try:
            channels = tuple(self.channels)
        except TypeError:
            channels = ()
        if len(channels) != N_SCALES or not all(is_whole(c) and c > 0 for c in channels):
            raise ValueError(
                f"channels must be {N_SCALES} positive ints (one width per encoder scale), got {self.channels!r}"
            )
        object.__setattr__(self, "channels", tuple(int(c) for c in channels))

    def as_dict(self) -> dict[str, Any]:
        """Plain dict of the fields (for logs and comparisons)."""
        return {"grid_size": self.grid_size, "channels": tuple(self.channels)}


class _ConvBlock(nn.Sequential):
    """``depth`` x (3x3 conv + ReLU). Zero padding: inputs are centred so that "never observed"
    is 0 (see ``SenDFuseNet._center``), hence the border reads as unobserved ground.
    ``bias=False`` for the encoder (see ``SenDFuseNet.__init__``)."""

    def __init__(self, in_channels: int, out_channels: int, depth: int, bias: bool = True) -> None:
        layers: list[nn.Module] = []
        for i in range(depth):
            layers.append(nn.Conv2d(in_channels if i == 0 else out_channels, out_channels, 3, padding=1, bias=bias))
            layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


def _pool2(x: Tensor) -> Tensor:
    """2x2 max-pool, stride 2, as the max of four strided views (same values as ``max_pool2d``,
    layout preserved, about twice as fast for channels-last inputs with few channels)."""
    top = torch.maximum(x[..., 0::2, 0::2], x[..., 0::2, 1::2])
    bottom = torch.maximum(x[..., 1::2, 0::2], x[..., 1::2, 1::2])
    return torch.maximum(top, bottom)


def _up(x: Tensor) -> Tensor:
    """Nearest 2x upsampling (exact inverse size of the 2x pool because 4 | R)."""
    return F.interpolate(x, scale_factor=2.0, mode="nearest")


def _as_bool_mask(valid: Tensor | Any, shape: tuple[int, int], device: torch.device) -> Tensor:
    """Turn a bool / 0-1 validity tensor into a bool mask of ``shape``, with a clear error."""
    valid = torch.as_tensor(valid, device=device)
    if tuple(valid.shape) != shape:
        raise ValueError(f"valid must have shape (B, n) = {shape} to match the sources, got {tuple(valid.shape)}")
    if valid.dtype != torch.bool:
        # Floats from an observation dict (0.0 / 1.0): threshold at 0.5 rather than test != 0,
        # so a flag that went through float arithmetic still reads as intended.
        valid = valid > 0.5
    if not bool(valid.any(dim=1).all()):
        raise ValueError(
            "every fusion needs at least one valid source (slot 0, the UAV's own map, always "
            "holds data); got a row of valid without any True entry"
        )
    return valid


def _masked_softmax(logits: Tensor, mask: Tensor | None) -> Tensor:
    """Softmax over dim 1 (the sources); masked-out entries get exactly 0.

    Masked logits are *replaced* by -inf (not shifted by a large negative number): exp(-inf) is
    exactly 0, and NaN/inf activities of slots that hold no data cannot leak in. ``torch.softmax``
    subtracts the max over the valid sources before exponentiating, so every exp() argument is
    <= 0 and no activity magnitude can overflow; at least one entry per column is valid (checked
    by the callers), so that max is finite.
    """
    if mask is not None:
        logits = logits.masked_fill(~mask, float("-inf"))
    return torch.softmax(logits, dim=1)


def _source_view(features: Tensor) -> tuple[Tensor, int, int]:
    """View ``(B, n, C, H, W)`` as a 4-D tensor whose last two dims are contiguous-friendly.

    Returns ``(view, channel_dim, pixel_dim)``: channels-last memory is viewed as
    ``(B, n, H*W, C)`` and standard memory as ``(B, n, C, H*W)``, both without copying, so every
    broadcast below runs over a contiguous inner dimension.
    """
    b, n, c, h, w = features.shape
    flat = features.reshape(b * n, c, h, w)
    if c > 1 and not flat.is_contiguous() and flat.is_contiguous(memory_format=torch.channels_last):
        return flat.permute(0, 2, 3, 1).reshape(b, n, h * w, c), 3, 2
    return features.reshape(b, n, c, h * w), 2, 3


def _weights_on_view(
    view: Tensor, channel_dim: int, pixel_dim: int, mask: Tensor | None, nonnegative: bool
) -> tuple[Tensor, Tensor]:
    """Channel and spatial source weights, shaped to broadcast against ``view``."""
    channel_activity = view.mean(dim=pixel_dim, keepdim=True)  # global average pool per channel
    magnitude = view if nonnegative else view.abs()
    if channel_dim == 3:
        # L1 over the innermost (channel) dim as a product with a ones vector: a reduction over
        # 8-16 contiguous floats per pixel is ~2x slower than this GEMV on the same data.
        ones = torch.ones((view.shape[3], 1), dtype=view.dtype, device=view.device)
        spatial_activity = torch.matmul(magnitude, ones)
    else:
        spatial_activity = magnitude.sum(dim=channel_dim, keepdim=True)
    view_mask = None if mask is None else mask[:, :, None, None]
    return _masked_softmax(channel_activity, view_mask), _masked_softmax(spatial_activity, view_mask)


def fusion_weights(features: Tensor, valid: Tensor | Any) -> tuple[Tensor, Tensor]:
    """Source weights of the two attentions: ``(channel (B, n, C), spatial (B, n, H, W))``.

    Both are softmaxes over the *sources* (dim 1), one per channel and one per pixel; they sum to
    1 over the valid sources and are exactly 0 for invalid ones. :func:`fusion_strategy` explains
    why the softmax runs over the sources. Exposed for inspection, plots and tests.
    """
    b, n, c, h, w = _check_sources(features)
    mask = _as_bool_mask(valid, (b, n), features.device)
    view, channel_dim, pixel_dim = _source_view(features)
    channel_w, spatial_w = _weights_on_view(view, channel_dim, pixel_dim, mask, nonnegative=False)
    return channel_w.reshape(b, n, c), spatial_w.reshape(b, n, h, w)


def _check_sources(features: Tensor) -> tuple[int, ...]:
    """The shape of one scale's features of n >= 1 sources, ``(B, n, C, H, W)``."""
    if features.dim() != 5 or features.shape[1] < 1:
        raise ValueError(f"features must be (B, n, C, H, W) with n >= 1 sources, got shape {tuple(features.shape)}")
    return tuple(features.shape)


def _fuse_scale(features: Tensor, mask: Tensor | None, alpha: float, nonnegative: bool) -> Tensor:
    """:func:`fusion_strategy` without argument checks (``fuse`` checks once, not per scale).

    ``mask`` None means every source is valid; callers that pass a mask must make sure the
    invalid slots hold finite values (``fuse`` zero-fills them; ``fusion_strategy`` zeroes them).
    """
    b, n, c, h, w = features.shape
    view, channel_dim, pixel_dim = _source_view(features)
    channel_w, spatial_w = _weights_on_view(view, channel_dim, pixel_dim, mask, nonnegative)
    # F = sum_k (alpha c_k + (1 - alpha) s_k) f_k, accumulated source by source with one fused
    # multiply-add each: no (B, n, C, H, W) temporary, and the loop has only n steps.
    channel_w = channel_w * alpha  # not in place: softmax's backward needs its output
    spatial_w = spatial_w * (1.0 - alpha)
    out = view[:, 0] * (channel_w[:, 0] + spatial_w[:, 0])
    for k in range(1, n):
        out.addcmul_(view[:, k], channel_w[:, k] + spatial_w[:, k])
    if channel_dim == 3:  # channels-last view (B, H*W, C) -> (B, C, H, W), still channels-last
        return out.reshape(b, h, w, c).permute(0, 3, 1, 2)
    return out.reshape(b, c, h, w)


def fusion_strategy(features: Tensor, valid: Tensor | Any, alpha: float = DEFAULT_FUSION_ALPHA) -> Tensor:
    """Fuse n sources' features of one scale: ``F = alpha * C + (1 - alpha) * S``.

    * Channel attention C: per source and channel, the global average pool of the feature map
      (its activity); softmax over the sources, separately for every channel; the fused channel
      is the weighted sum of that channel over the sources.
    * Spatial attention S: per source and pixel, the L1 norm over the channels; softmax over the
      sources, separately for every pixel; every channel at that pixel is the weighted sum over
      the sources.

    Softmax axis: the paper's formulas can be read as normalising over the channels (C) and over
    the pixels (S) of one source. Read that way, a source's weights would not depend on the other
    sources at all, so nothing would be *fused*: the result would be a per-source rescaling whose
    sum grows with n. We follow NestFuse, which the paper extends from 2 to n inputs: the weights
    are a softmax over the *sources*, so at every channel / pixel they form a convex combination.
    The fused features therefore stay on the encoder's feature scale (what the decoder was
    pre-trained on), the most active source (e.g. observed rather than unknown ground) dominates
    locally, and two properties the deployment relies on hold: one valid source -> plain
    autoencoding; n identical sources -> that source.

    Args:
        features: ``(B, n, C, H, W)``, n >= 1 sources per fusion.
        valid: ``(B, n)`` bool (or 0/1 float, thresholded at 0.5) marking sources that hold data;
            invalid sources get weight exactly 0 and their features (even NaN) are ignored.
        alpha: weight of channel attention in ``[0, 1]``; ``1 - alpha`` goes to spatial attention.

    Returns:
        ``(B, C, H, W)`` fused features.
    """
    alpha = _check_alpha(alpha)
    b, n = _check_sources(features)[:2]
    mask = _as_bool_mask(valid, (b, n), features.device)
    if bool(mask.all()):
        return _fuse_scale(features, None, alpha, nonnegative=False)
    # Zero the invalid slots so that a weight of 0 times NaN/inf garbage cannot poison the sums.
    features = features.masked_fill(~mask[:, :, None, None, None], 0.0)
    return _fuse_scale(features, mask, alpha, nonnegative=False)


class SenDFuseNet(nn.Module):
    """NestFuse-style denoising / fusion autoencoder for single-channel R x R sensor maps.

    Sizing (R = 44, channels (8, 16, 32): 26,033 parameters): the deployment budget is one fused
    map per UAV per step in <= 2 ms on one CPU core, i.e. 4 fusions of 4 sources (12 encodes of
    received maps, the own maps bypass the network, + 4 decodes) in <= 8 ms. Full-resolution layers dominate that cost, so widths stay small there
    and double at each coarser scale, where pixels are 4x cheaper (see ``ENCODER_DEPTHS``). The
    maps are simple (levels 0, 0.5, 1 plus channel noise), so this capacity suffices for
    denoising, and with the residual output it only has to model the *change* noise makes.
    Measure with ``python -m sb3_coma.sendfuse [--tune-malloc]``.

    Parameters are kept channels-last (see the module docstring); ``state_dict`` values are the
    same numbers either way, and :mod:`sb3_coma.sendfuse.weights` stores them contiguous.

    Args:
        grid_size: R, side of the communication grid; must be a positive multiple of 4.
        channels: widths of the three encoder scales (full, half, quarter resolution).
        fusion_alpha: default ``alpha`` of :meth:`fuse` (weight of channel attention).
    """

    def __init__(
        self,
        grid_size: int = DEFAULT_GRID_SIZE,
        channels: Sequence[int] = DEFAULT_CHANNELS,
        fusion_alpha: float = DEFAULT_FUSION_ALPHA,
    ) -> None:
        super().__init__()
        self.config = SenDFuseConfig(grid_size=grid_size, channels=tuple(channels))  # validates
        self.fusion_alpha = _check_alpha(fusion_alpha)
        #: Metadata of the weight file this network was loaded from (provenance for logs and
        #: reports); empty for a freshly built network. Filled by ``weights.load_weights``.
        self.weights_metadata: dict[str, str] = {}
        c1, c2, c3 = self.config.channels
        e1, e2, e3 = ENCODER_DEPTHS
        d11, d21, d12 = DECODER_DEPTHS
        # Encoder: one block per scale; scale k+1 sees the 2x max-pooled output of scale k.
        # No biases: with centred inputs the encoder is then positively homogeneous
        # (phi(t x) = t phi(x), t > 0), so a never-observed region (input 0) has exactly zero
        # activity at every scale and activity grows with signal strength. That is what makes
        # the activity-based fusion prefer the source that actually observed a cell; with biases
        # the fused map was clearly worse where only one UAV had observed (mean absolute error
        # to the union of the clean maps 0.23 -> 0.18 at alpha 0.5 after the same short
        # pre-training), at no cost in plain denoising.
        self.enc1 = _ConvBlock(1, c1, e1, bias=False)
        self.enc2 = _ConvBlock(c1, c2, e2, bias=False)
        self.enc3 = _ConvBlock(c2, c3, e3, bias=False)
        # Nested decoder (NestFuse / UNet++): every decoder node sees all earlier nodes of its
        # scale plus the upsampled node below, so fine detail survives the bottleneck.
        self.dec1_1 = _ConvBlock(c1 + c2, c1, d11)
        self.dec2_1 = _ConvBlock(c2 + c3, c2, d21)
        self.dec1_2 = _ConvBlock(c1 + c1 + c2, c1, d12)
        # Residual output: the head emits a correction to the input map, not the map itself.
        # Zero-initialised, so an untrained network is the identity (AE) / the mean (fusion) and
        # training starts from the baseline it has to beat rather than from a random map.
        self.head = nn.Conv2d(c1, 1, 1)
        nn.init.zeros_(self.head.weight)
        assert self.head.bias is not None  # Conv2d's default bias=True
        nn.init.zeros_(self.head.bias)
        # Module.to accepts memory_format at runtime; torch's overloads of Module.to do not list it.
        self.to(memory_format=torch.channels_last)  # type: ignore[call-overload]

    # ------------------------------------------------------------------ properties
    @property
    def grid_size(self) -> int:
        """R, the side of the maps this network accepts."""
        return self.config.grid_size

    @property
    def channels(self) -> tuple[int, int, int]:
        """Channel widths of the three encoder scales."""
        return self.config.channels  # type: ignore[return-value]

    def num_parameters(self) -> int:
        """Number of learnt scalars (for docs and sanity checks)."""
        return sum(p.numel() for p in self.parameters())

    # ------------------------------------------------------------------ input checks
    def _check_maps(self, x: Tensor, what: str, layout: str, channels: int | None = None) -> None:
        """Fail with a message naming the expected layout instead of a conv shape error: a float
        tensor ``(B, channels or n >= 1, R, R)``, all in one rule."""
        r, one = self.grid_size, channels == 1
        fits = isinstance(x, Tensor) and x.dim() == 4 and tuple(x.shape[-2:]) == (r, r)
        if not (fits and x.is_floating_point() and x.shape[1] == (channels or max(1, x.shape[1]))):
            got = f"shape {tuple(x.shape)}, dtype {x.dtype}" if isinstance(x, Tensor) else type(x).__name__
            raise ValueError(
                f"{what} expects a floating-point torch.Tensor of {'one channel, ' if one else 'n >= 1 '}{layout} "
                f"maps with R = {r} (this network's grid_size), got {got}"
            )

    @staticmethod
    def _center(x: Tensor) -> Tensor:
        """Map [0, 1] to [-1, 1] so that "never observed" (0.5) is 0: unobserved ground then
        looks like the zero padding outside the field, and the two classes are symmetric."""
        return x * 2.0 - 1.0

    # ------------------------------------------------------------------ building blocks
    def encode(self, x: Tensor) -> list[Tensor]:
        """``(B, 1, R, R)`` -> ``[E1 (B, c1, R, R), E2 (B, c2, R/2, R/2), E3 (B, c3, R/4, R/4)]``."""
        self._check_maps(x, "encode", "(B, 1, R, R)", channels=1)
        # Observations may arrive as float64 (numpy defaults); convert rather than fail in conv2d.
        e1 = self.enc1(self._center(x.to(self.head.weight.dtype)))
        e2 = self.enc2(_pool2(e1))
        e3 = self.enc3(_pool2(e2))
        return [e1, e2, e3]

    def decode(self, features: Sequence[Tensor]) -> Tensor:
        """Three-scale features (from :meth:`encode`, or fused) -> ``(B, 1, R, R)`` correction.

        The correction is what the network would add to a received map where it holds data
        (unbounded; :meth:`forward` and :meth:`fuse` add it and clip the result to [0, 1]).
        """
        if len(features) != N_SCALES:
            raise ValueError(f"decode expects {N_SCALES} feature maps (one per scale), got {len(features)}")
        e1, e2, e3 = features
        d1_1 = self.dec1_1(torch.cat((e1, _up(e2)), dim=1))
        d2_1 = self.dec2_1(torch.cat((e2, _up(e3)), dim=1))
        d1_2 = self.dec1_2(torch.cat((e1, d1_1, _up(d2_1)), dim=1))
        return self._head(d1_2)

    def _head(self, x: Tensor) -> Tensor:
        """The 1x1 output conv, computed as a per-pixel linear map: same parameters and values as
        ``self.head(x)``, but oneDNN has no fast path for 1x1 convs with one output channel (the
        generic fallback cost ~0.1 ms of the fusion budget)."""
        weight = self.head.weight.view(1, -1)
        pixels_last = F.linear(x.permute(0, 2, 3, 1), weight, self.head.bias)  # (B, H, W, 1)
        return pixels_last.permute(0, 3, 1, 2)

    # ------------------------------------------------------------------ public modes
    def forward(self, x: Tensor) -> Tensor:
        """Denoise one received map, fusion off: ``(B, 1, R, R)`` -> ``(B, 1, R, R)`` in [0, 1].

        ``clamp(x + observed(x) * correction(x), 0, 1)``, where ``observed`` is 0 on cells that
        hold no data (exactly 0.5) and 1 elsewhere. This is what pre-training fits, and what
        :meth:`fuse` computes for a UAV that received one map besides its own (up to the mean
        with the own map).
        """
        self._check_maps(x, "forward", "(B, 1, R, R)", channels=1)
        x = x.to(self.head.weight.dtype)
        correction = self.decode(self.encode(x))
        return torch.clamp(torch.where(x != UNKNOWN, x + correction, x), 0.0, 1.0)

    def fuse(self, maps: Tensor, valid: Tensor | Any, alpha: float | None = None) -> Tensor:
        """Fuse n maps per UAV into one clean map: ``(B, n, R, R)`` -> ``(B, R, R)`` in [0, 1].

        Slot 0 is the UAV's own map (never sent over the channel, hence clean) and bypasses the
        network; slots 1.. are received maps. The result is

            clamp((sum_valid x_k + m(p) * D(fuse_k E(x_k))) / n_valid, 0, 1)

        with E/D the encoder / decoder (D outputs a correction), the attention fusion of
        :func:`fusion_strategy` over the valid *received* maps at every scale, ``n_valid`` the
        number of valid slots (own included) and ``m(p)`` the number of valid received maps that
        hold data at cell p (value != 0.5). So the correction estimates the average change a
        received map needs where it holds data, weighted by the share of the maps at p it applies
        to: with nothing received (or only empty cells) the result is exactly the mean, with the
        own map alone it is the own map, with one received map it is the mean of the own map and
        :meth:`forward` of the received one (where no clipping binds).

        All valid received maps of all B fusions are encoded in one batched pass (empty slots,
        and the own maps, are not encoded at all) and decoded in one pass over the B fusions
        that received anything. Gradients flow as usual; wrap the call in
        ``torch.inference_mode()`` at deployment.

        Args:
            maps: ``(B, n, R, R)``: slot 0 the UAV's own map, slots 1.. the received maps.
            valid: ``(B, n)`` bool or 0/1 float; invalid slots are ignored whatever they hold.
            alpha: channel-attention weight in [0, 1]; defaults to ``self.fusion_alpha``.
        """
        self._check_maps(maps, "fuse", "(B, n, R, R)")
        alpha = self.fusion_alpha if alpha is None else _check_alpha(alpha)
        b, n, r, _ = maps.shape
        mask = _as_bool_mask(valid, (b, n), maps.device)
        maps = maps.to(self.head.weight.dtype)  # float64 observations: convert, don't fail
        all_valid = bool(mask.all())
        if not all_valid:
            # Zero the invalid slots: they may hold anything (even NaN) and must not reach a sum.
            maps = maps.masked_fill(~mask[:, :, None, None], 0.0)
        count = mask.sum(dim=1, dtype=maps.dtype)[:, None, None]
        total = maps.sum(dim=1)
        received = mask[:, 1:]
        rows = received.any(dim=1)
        if n == 1 or not bool(rows.any()):
            return torch.clamp(total / count, 0.0, 1.0)
        every_row = bool(rows.all())
        sub_maps = maps[:, 1:] if every_row else maps[rows, 1:]
        sub_mask = received if every_row else received[rows]
        rb, m = sub_mask.shape
        flat_mask = sub_mask.reshape(-1)
        flat_maps = sub_maps.reshape(rb * m, 1, r, r)
        all_received = bool(flat_mask.all())
        encoded = self.encode(flat_maps if all_received else flat_maps[flat_mask])
        fused: list[Tensor] = []
        for feat in encoded:
            if not all_received:
                # Put the encoded valid maps back in their slots; empty slots stay 0 (finite, as
                # _fuse_scale requires) and get weight exactly 0.
                full = torch.empty(
                    (rb * m, *feat.shape[1:]),
                    dtype=feat.dtype,
                    device=feat.device,
                    memory_format=torch.channels_last,
                ).zero_()
                full[flat_mask] = feat
                feat = full
            per_source = feat.reshape((rb, m, *feat.shape[1:]))
            # Encoder outputs are post-ReLU, hence >= 0: the L1 norm needs no abs().
            fused.append(_fuse_scale(per_source, None if all_received else sub_mask, alpha, nonnegative=True))
        correction = self.decode(fused)[:, 0]
        observed = sub_maps != UNKNOWN
        if not all_received:
            observed = observed & sub_mask[:, :, None, None]
        weight = observed.sum(dim=1, dtype=maps.dtype)  # m(p): received maps holding data at p
        if every_row:
            out = total + weight * correction
        else:
            out = total.index_put((rows.nonzero()[:, 0],), total[rows] + weight * correction)
        return torch.clamp(out / count, 0.0, 1.0)

    def extra_repr(self) -> str:
        return f"grid_size={self.grid_size}, channels={self.channels}, fusion_alpha={self.fusion_alpha}"

    @classmethod
    def from_config(cls, config: SenDFuseConfig | Mapping[str, Any], **kwargs: Any) -> SenDFuseNet:
        """Build an (untrained) network from a :class:`SenDFuseConfig` or a dict of its fields."""
        if not isinstance(config, SenDFuseConfig):
            config = SenDFuseConfig(**dict(config))
        return cls(grid_size=config.grid_size, channels=config.channels, **kwargs)


def tune_cpu_allocator(mmap_threshold: int = 16 << 20, trim_threshold: int = 64 << 20) -> bool:
    """Stop glibc from handing freed tensor memory back to the OS after every forward pass.

    A fusion step allocates and frees a few MB of short-lived tensors. With glibc's default
    (dynamic) thresholds the heap top is trimmed after each step and re-faulted in the next one:
    ~800 minor page faults per 4 x 4 fusion, about 20 % of its time on the 2-core dev VM. Fixing
    the thresholds (the ``MALLOC_MMAP_THRESHOLD_`` / ``MALLOC_TRIM_THRESHOLD_`` environment
    variables do the same before start-up) keeps that memory mapped; the cost is that the process
    holds on to up to ``trim_threshold`` bytes of freed memory.

    Process-wide, so never done at import: entry points that run fusion in a loop (the env's
    fusion wrapper, benchmarks, the CLI) opt in. Returns True when applied, False where glibc's
    ``mallopt`` is unavailable (macOS, Windows, musl), which is harmless.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3  # from glibc's <malloc.h>
    return bool(mallopt(m_mmap_threshold, int(mmap_threshold))) and bool(mallopt(m_trim_threshold, int(trim_threshold)))
