"""SenDFuse: denoise and fuse the sensor maps UAVs receive over a noisy channel (paper III-B).

* :class:`SenDFuseNet` / :func:`fusion_strategy` (``network``): the NestFuse-style autoencoder and
  its attention fusion over n sources.
* :class:`SenDFuseLoss` (``loss``): MSE + MAE + (1 - SSIM) for the denoising pre-training.
* :func:`save_weights` / :func:`load_weights` (``weights``): safetensors files that record the
  architecture, with clear errors for every way a file can be wrong.
* :class:`SenDFuseFusionWrapper` (``wrapper``): ``uav_ipp.make_vec_env(fusion="sendfuse")``, found
  through the ``uav_ipp.fusion`` entry point.

Pre-training data (``data``), the pre-training loop (``pretrain``) and the quality table
(``quality``) are imported from their modules.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .loss import DEFAULT_WEIGHTS, SenDFuseLoss, SenDFuseLossTerms
from .network import (
    DEFAULT_CHANNELS,
    DEFAULT_FUSION_ALPHA,
    DEFAULT_GRID_SIZE,
    SenDFuseConfig,
    SenDFuseNet,
    fusion_strategy,
    fusion_weights,
)
from .weights import SenDFuseWeightsError, default_weights_path, load_weights, read_metadata, save_weights

if TYPE_CHECKING:
    from .wrapper import SenDFuseFusionWrapper


def __getattr__(name: str) -> Any:
    """PEP 562: the wrapper (which loads the UAV world) is imported on first use, so that
    ``import sb3_coma`` does not load the world's kernels and maps."""
    if name == "SenDFuseFusionWrapper":
        from .wrapper import SenDFuseFusionWrapper

        return SenDFuseFusionWrapper
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "DEFAULT_CHANNELS",
    "DEFAULT_FUSION_ALPHA",
    "DEFAULT_GRID_SIZE",
    "DEFAULT_WEIGHTS",
    "SenDFuseConfig",
    "SenDFuseFusionWrapper",
    "SenDFuseLoss",
    "SenDFuseLossTerms",
    "SenDFuseNet",
    "SenDFuseWeightsError",
    "default_weights_path",
    "fusion_strategy",
    "fusion_weights",
    "load_weights",
    "read_metadata",
    "save_weights",
]
