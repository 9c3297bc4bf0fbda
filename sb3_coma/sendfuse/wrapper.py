"""``fusion="sendfuse"``: the fused channel from the pre-trained SenDFuse network.

``uav_ipp.make_vec_env(..., fusion="sendfuse")`` finds this wrapper through the ``uav_ipp.fusion``
entry point that sb3-coma's ``setup.cfg`` declares, so the environment package never imports
``sb3_coma``. One batched forward pass fuses the received maps of every agent of every env copy
at a step.
"""

from __future__ import annotations

import os

import numpy as np
import torch
from gymnasium.vector import VectorEnv

from sb3_coma.sendfuse.network import SenDFuseNet
from sb3_coma.sendfuse.weights import default_weights_path, load_weights
from uav_ipp.config import ConfigError, is_real
from uav_ipp.fusion import FusionWrapper

#: Agents fused per forward pass. Training batches (8 copies x 4 UAVs) fit in one; an evaluation
#: flying 50 missions at once would otherwise hold ~230 MB of activations for its 200 agents.
FUSE_CHUNK = 64


class SenDFuseFusionWrapper(FusionWrapper):
    """Fuses ``received`` with SenDFuse (denoise + attention fusion) into the 8th local channel.

    :param weights: a safetensors file from ``sb3-coma pretrain-sendfuse``; ``None`` = the
        weights shipped with the package for this communication grid. Whichever path leads to a
        shipped file, it is checked against its recorded SHA-256 before it is read
        (:func:`sb3_coma.sendfuse.weights.shipped_digest`), so a replaced shipped file is refused.
    :param network: an already built ``SenDFuseNet`` (overrides ``weights``; used by tools that
        evaluate a network being trained).
    :param alpha: channel- vs spatial-attention weight of the fusion (None = the network's).
    """

    name = "sendfuse"

    def __init__(
        self,
        env: VectorEnv,
        weights: str | os.PathLike[str] | None = None,
        network: SenDFuseNet | None = None,
        alpha: float | None = None,
        device: str = "cpu",
    ) -> None:
        if alpha is not None and not (is_real(alpha) and 0.0 <= alpha <= 1.0):
            raise ConfigError(
                f"invalid option fusion_kwargs alpha={alpha!r}: a number in [0, 1] "
                "(weight of channel vs spatial attention), or None for the network's own"
            )
        super().__init__(env)
        received_shape = self.raw_observation_space["received"].shape
        assert received_shape is not None  # a Box: FusionWrapper checked the raw observation space
        grid = received_shape[-1]
        if network is None:
            network = load_weights(weights if weights is not None else default_weights_path(grid))
        if network.grid_size != grid:
            raise ValueError(
                f"SenDFuse network was built for a {network.grid_size} x {network.grid_size} "
                f"communication grid, but the env uses comm_grid={grid}"
            )
        #: Where the fusion runs: ``"cpu"`` (default; every worker fuses its own copies) or a torch
        #: device such as ``"cuda"`` (the in-process learner's GPU; nothing changes but where).
        self.device = torch.device(device)
        self.network = network.eval().to(self.device)
        self.alpha = alpha

    def fuse(self, received: np.ndarray, valid: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            maps = torch.from_numpy(np.ascontiguousarray(received, dtype=np.float32)).to(self.device)
            mask = torch.from_numpy(np.asarray(valid) > 0.5).to(self.device)
            parts = [
                self.network.fuse(maps[i : i + FUSE_CHUNK], mask[i : i + FUSE_CHUNK], alpha=self.alpha)
                for i in range(0, len(maps), FUSE_CHUNK)
            ]
        return (parts[0] if len(parts) == 1 else torch.cat(parts)).cpu().numpy()
