"""SenDFuse: denoise and fuse the sensor maps UAVs receive over a noisy channel (paper III-B).

* :class:`SenDFuseNet` / :func:`fusion_strategy` (``network``): the NestFuse-style autoencoder and
  its attention fusion over n sources; torch-only, so the environment's wrapper can import it.
* :class:`SenDFuseLoss` (``loss``): MSE + MAE + (1 - SSIM) for the denoising pre-training.
* :func:`save_weights` / :func:`load_weights` (``weights``): safetensors files that record the
  architecture, with clear errors for every way a file can be wrong.

Names are resolved lazily: importing the network (as ``envs`` does in every environment worker)
does not pull in pytorch-msssim or safetensors.
"""
from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
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

#: Public name -> submodule. Resolved on first access, so importing the package is free and
#: ``python -m sb3_coma.sendfuse.network`` (the timing benchmark) runs without a double import.
_EXPORTS = {
    "DEFAULT_CHANNELS": "network",
    "DEFAULT_FUSION_ALPHA": "network",
    "DEFAULT_GRID_SIZE": "network",
    "SenDFuseConfig": "network",
    "SenDFuseNet": "network",
    "fusion_strategy": "network",
    "fusion_weights": "network",
    "DEFAULT_WEIGHTS": "loss",
    "SenDFuseLoss": "loss",
    "SenDFuseLossTerms": "loss",
    "SenDFuseWeightsError": "weights",
    "default_weights_path": "weights",
    "load_weights": "weights",
    "read_metadata": "weights",
    "save_weights": "weights",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(import_module(f".{module}", __name__), name)
    globals()[name] = value  # cache: later lookups skip __getattr__
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_EXPORTS))
