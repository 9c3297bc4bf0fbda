"""Pre-training loss of SenDFuse: ``w_mse * MSE + w_mae * MAE + w_ssim * (1 - SSIM)`` (paper eq. 8).

MSE punishes large per-cell errors, MAE keeps pushing small residual noise to zero (its gradient
does not vanish near the target, unlike MSE's), and SSIM rewards keeping the *structure* of
the map (edges of observed footprints, blobs of valuable ground) rather than only per-cell
values. The paper only says the weights "balance the magnitude of the three loss components";
the defaults below are chosen that way, from measured term magnitudes (see ``DEFAULT_WEIGHTS``).
"""

from __future__ import annotations

import math
from typing import NamedTuple

from pytorch_msssim import ssim
from torch import Tensor, nn

from uav_ipp.config import is_real, is_whole

#: Default (w_mse, w_mae, w_ssim) = (10, 1, 0.5): each term contributes about a third of the loss
#: on a *trained* reconstruction, i.e. w_i ~ 1 / E[term_i], normalised to w_mae = 1 and rounded.
#: Balancing at convergence rather than at initialisation because that is where the weighting
#: decides what the network keeps improving; at initialisation every weighting descends.
#: Measured on R = 44 env-like sensor maps (random blob ground truth, 1-15 square footprints at
#: random altitudes with the sensor's flip rates, 0.5 where unobserved, loud channel noise),
#: Adam 1e-3, batches of 16, 256 held-out maps (rows 2-3: a 28k-parameter depth variant; row 4:
#: the shipped 26k layout):
#:   raw terms        MSE      MAE     1-SSIM
#:   initialisation   0.033    0.13    0.56
#:   800 steps        0.0041   0.035   0.073   -> x (10, 1, 0.5) = 0.041, 0.035, 0.037
#:   1500 steps       0.0035   0.030   0.055   -> x (10, 1, 0.5) = 0.035, 0.030, 0.027
#:   600 steps        0.0044   0.037   0.084   -> x (10, 1, 0.5) = 0.044, 0.037, 0.042
#: (the noisy input itself scores 0.016 / 0.10 / 0.48: SSIM is what punishes leftover noise in
#: flat "unobserved" areas the most). Re-check when the pre-training data changes.
DEFAULT_WEIGHTS: tuple[float, float, float] = (10.0, 1.0, 0.5)
#: Gaussian SSIM window. pytorch-msssim's default 11 is meant for photographs; on a 44 x 44 map
#: a 7-wide window (sigma 1.5) still leaves 38 x 38 valid positions and spans about one 5 m
#: lattice cell (4 grid cells), the scale at which footprint edges and blobs live.
SSIM_WIN_SIZE = 7
SSIM_WIN_SIGMA = 1.5


class SenDFuseLossTerms(NamedTuple):
    """The total (to back-propagate) and its three raw, unweighted terms (to log)."""

    total: Tensor
    mse: Tensor
    mae: Tensor
    ssim: Tensor  # 1 - SSIM, so that 0 means perfect like the other two


def _check_weight(name: str, value: float) -> float:
    if not is_real(value) or not math.isfinite(value) or value < 0.0:
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return float(value)


class SenDFuseLoss(nn.Module):
    """``w_mse * MSE + w_mae * MAE + w_ssim * (1 - SSIM)`` between a reconstruction and its target.

    Both inputs are maps in ``[0, 1]`` shaped ``(B, 1, H, W)`` or ``(B, H, W)`` (SSIM uses
    ``data_range = 1``). The SSIM window shrinks to the largest odd size that fits when a map is
    smaller than ``win_size``, so tiny test grids work too.

    Args:
        w_mse, w_mae, w_ssim: non-negative weights, not all zero.
        win_size: odd Gaussian window of SSIM (default 7, see ``SSIM_WIN_SIZE``).
    """

    def __init__(
        self,
        w_mse: float = DEFAULT_WEIGHTS[0],
        w_mae: float = DEFAULT_WEIGHTS[1],
        w_ssim: float = DEFAULT_WEIGHTS[2],
        win_size: int = SSIM_WIN_SIZE,
    ) -> None:
        super().__init__()
        self.w_mse = _check_weight("w_mse", w_mse)
        self.w_mae = _check_weight("w_mae", w_mae)
        self.w_ssim = _check_weight("w_ssim", w_ssim)
        if self.w_mse + self.w_mae + self.w_ssim == 0.0:
            raise ValueError("at least one of w_mse, w_mae, w_ssim must be > 0")
        if not is_whole(win_size) or win_size < 1 or win_size % 2 == 0:
            raise ValueError(f"win_size must be a positive odd int, got {win_size!r}")
        self.win_size = int(win_size)

    @staticmethod
    def _as_nchw(x: Tensor, name: str) -> Tensor:
        if x.dim() == 3:
            return x.unsqueeze(1)
        if x.dim() == 4 and x.shape[1] == 1:
            return x
        raise ValueError(f"{name} must be (B, 1, H, W) or (B, H, W), got shape {tuple(x.shape)}")

    def forward(self, prediction: Tensor, target: Tensor) -> SenDFuseLossTerms:
        """Return :class:`SenDFuseLossTerms`; ``.total`` carries the gradient."""
        pred = self._as_nchw(prediction, "prediction")
        tgt = self._as_nchw(target, "target")
        if pred.shape != tgt.shape:
            raise ValueError(f"prediction {tuple(pred.shape)} and target {tuple(tgt.shape)} differ in shape")
        tgt = tgt.to(pred.dtype)
        diff = pred - tgt
        mse = diff.square().mean()
        mae = diff.abs().mean()
        side = min(pred.shape[-2:])
        win = min(self.win_size, side if side % 2 == 1 else side - 1)
        # SSIM of pytorch-msssim: per-image mean over the valid window positions, then batch mean.
        ssim_term = 1.0 - ssim(pred, tgt, data_range=1.0, win_size=win, win_sigma=SSIM_WIN_SIGMA, size_average=True)
        total = self.w_mse * mse + self.w_mae * mae + self.w_ssim * ssim_term
        return SenDFuseLossTerms(total=total, mse=mse, mae=mae, ssim=ssim_term)

    def extra_repr(self) -> str:
        return f"w_mse={self.w_mse}, w_mae={self.w_mae}, w_ssim={self.w_ssim}, win_size={self.win_size}"
