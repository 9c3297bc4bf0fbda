"""Pre-train SenDFuse as a one-to-one denoising autoencoder (paper III-B; ``sb3-coma pretrain-sendfuse``).

Fusion is off during pre-training: the network learns to encode a single received map and to
decode it without the channel noise, from (noisy, clean) pairs that the environment generates
(:mod:`sb3_coma.sendfuse.data`). Loss: :class:`SenDFuseLoss` (MSE + MAE + (1 - SSIM)). Adam with a
cosine learning-rate decay, because a short fixed budget (minutes on a laptop CPU) gains more
from annealing than from a longer constant rate.

Reproducibility: numpy and torch are seeded from ``seed``, the data generator from ``seed`` too,
and the number of torch threads is fixed (``threads``, default 1) because oneDNN's reduction
order in the backward pass depends on it. Same command + same seed + same thread count -> the
same weight file, byte for byte (checked by the tests on a tiny setting).

Augmentation: each batch is flipped / rotated by a random element of the square's symmetry group
(the same one for input and target). The channel noise is per cell and the maps have no preferred
orientation, so this multiplies the useful data by up to eight at no generation cost.

Fusion calibration (``calibrate=True``, the default): the encoder is bias-free conv + ReLU +
max-pool, hence positively homogeneous, so scaling its first layer by ``c`` and the decoder
weights that read encoder features by ``1/c`` leaves the autoencoder's output unchanged. The
pre-training loss therefore cannot fix the scale of the encoder features, yet the fusion's
softmaxes (over sources, of channel and pixel activities) depend on it like on a temperature.
After training we pick ``c`` from a small grid by the fused-map error on *pre-training* maps
(never the evaluation maps) and fold it into the weights; :func:`rescale_encoder` does the
exact rewrite.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from uav_ipp.config import is_real, is_whole

from .data import NOISE_PRESETS, PairConfig, PairDataset, collect_fusions, generate_pairs
from .loss import SenDFuseLoss
from .network import SenDFuseNet
from .quality import fusion_set_errors


@dataclass(frozen=True)
class PretrainConfig:
    """Hyper-parameters of one pre-training run (defaults: the shipped weights)."""

    samples: int = 12_000
    epochs: int = 3
    batch: int = 32
    lr: float = 2e-3
    final_lr_fraction: float = 0.05
    seed: int = 0
    threads: int = 1
    val_fraction: float = 0.05
    augment: bool = True
    calibrate: bool = True
    calibration_scales: tuple[float, ...] = (3.0, 1.0, 0.3, 0.1, 0.03, 0.01)
    calibration_fusions: int = 240
    loss_weights: tuple[float, float, float] | None = None  # None: SenDFuseLoss defaults
    grid_size: int = 44
    data: PairConfig = field(default_factory=PairConfig)

    def validate(self) -> None:
        """Reject bad values with a message naming the option (the CLI turns it into a user error)."""

        def count(v: Any) -> bool:
            return is_whole(v) and v >= 1

        # One row per option: (name as the CLI spells it, accepted, what is allowed).
        rules = [(f"--{name}", count(getattr(self, name)), "a positive integer") for name in _COUNTS]
        rules += [
            ("--seed", is_whole(self.seed) and 0 <= self.seed < 2**32, "an integer from 0 to 2**32 - 1"),
            ("--lr", is_real(self.lr) and math.isfinite(self.lr) and self.lr > 0, "a positive number"),
            ("val_fraction", is_real(self.val_fraction) and 0.0 <= self.val_fraction < 1.0, "in [0, 1)"),
            ("final_lr_fraction", is_real(self.final_lr_fraction) and 0.0 < self.final_lr_fraction <= 1.0, "in (0, 1]"),
            (
                "calibration_scales",
                bool(self.calibration_scales) and all(math.isfinite(c) and c > 0 for c in self.calibration_scales),
                "positive numbers",
            ),
        ]
        for name, accepted, allowed in rules:
            if not accepted:
                value = getattr(self, name.lstrip("-"))
                raise ValueError(f"{name} must be {allowed}, got {value!r}")
        self.data.validate()


#: The counts of :class:`PretrainConfig`, each an integer >= 1.
_COUNTS = ("samples", "epochs", "batch", "threads", "calibration_fusions")


@dataclass(frozen=True)
class EpochLog:
    """Mean raw loss terms of one epoch (train) and on the held-out pairs (val)."""

    epoch: int
    total: float
    mse: float
    mae: float
    ssim: float
    val_total: float
    val_mse: float
    seconds: float

    def line(self) -> str:
        return (
            f"epoch {self.epoch}: loss {self.total:.4f} (mse {self.mse:.3g}, mae {self.mae:.3g}, "
            f"1-ssim {self.ssim:.3g}) | val loss {self.val_total:.4f}, val mse {self.val_mse:.3g} "
            f"| {self.seconds:.0f}s"
        )


@dataclass
class PretrainResult:
    """The trained network and everything the provenance record needs."""

    model: SenDFuseNet
    history: list[EpochLog]
    data_summary: str
    identity_val_mse: float  # MSE(noisy, clean) on the validation pairs: the bar to beat
    val_mse_by_preset: dict[str, float]
    scale: float  # fusion calibration factor folded into the weights (1 = none)
    calibration: dict[float, float]  # scale -> fused-map MSE on pre-training maps
    seconds: float


def dihedral(x: torch.Tensor, k: int) -> torch.Tensor:
    """Element ``k`` (0-7) of the square's symmetry group applied to the last two dims."""
    if k >= 4:
        x = x.transpose(-1, -2)
    return torch.rot90(x, k % 4, dims=(-2, -1))


def rescale_encoder(model: SenDFuseNet, scale: float) -> SenDFuseNet:
    """Scale all encoder features by ``scale`` without changing the autoencoder's output.

    The encoder is bias-free conv + ReLU + max-pool, so multiplying the first conv by ``scale``
    multiplies E1, E2 and E3 by ``scale``; every decoder conv input channel that carries encoder
    features is multiplied by ``1 / scale`` to compensate (exact up to float rounding). Only the
    fusion, whose softmaxes read feature magnitudes, sees the difference.
    """
    if not (math.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale!r}")
    if scale == 1.0:
        return model

    def convs(block: torch.nn.Module) -> list[torch.nn.Conv2d]:
        return [m for m in block.modules() if isinstance(m, torch.nn.Conv2d)]

    if any(conv.bias is not None for block in (model.enc1, model.enc2, model.enc3) for conv in convs(block)):
        raise ValueError("rescale_encoder needs a bias-free encoder (positively homogeneous)")
    c1 = model.channels[0]
    with torch.no_grad():
        convs(model.enc1)[0].weight.mul_(scale)
        convs(model.dec1_1)[0].weight.div_(scale)  # input: E1 ++ up(E2), all encoder features
        convs(model.dec2_1)[0].weight.div_(scale)  # input: E2 ++ up(E3)
        convs(model.dec1_2)[0].weight[:, :c1].div_(scale)  # input: E1 ++ D1_1 ++ up(D2_1): only E1
    return model


def _batches(n: int, batch: int, rng: np.random.Generator) -> list[np.ndarray]:
    order = rng.permutation(n)
    return [order[i : i + batch] for i in range(0, n, batch)]


def _evaluate(
    model: SenDFuseNet, loss_fn: SenDFuseLoss, x: torch.Tensor, y: torch.Tensor, batch: int = 256
) -> tuple[float, float, np.ndarray]:
    """(mean total loss, mean MSE, per-sample MSE) without gradients."""
    totals, mses, per = [], [], []
    with torch.no_grad():
        for i in range(0, len(x), batch):
            out = model(x[i : i + batch])
            terms = loss_fn(out, y[i : i + batch])
            n = len(out)
            totals.append(float(terms.total) * n)
            mses.append(float(terms.mse) * n)
            per.append(((out - y[i : i + batch]) ** 2).mean(dim=(1, 2, 3)).numpy())
    n = max(len(x), 1)
    return sum(totals) / n, sum(mses) / n, np.concatenate(per) if per else np.zeros(0)


def _calibrate(
    model: SenDFuseNet, config: PretrainConfig, log: Callable[[str], None]
) -> tuple[float, dict[float, float]]:
    """Choose the encoder scale whose fusion best matches the clean mean on pre-training-style maps.

    The fusions come from fresh random maps (seeded from ``seed``, disjoint from the training
    pairs' missions) with 4 UAVs, an equal share per noise preset; the criterion is the SenDFuse
    fused-map MSE summed over the presets. Evaluation maps (env2, env3) are never touched.
    """
    fusions = collect_fusions(config.calibration_fusions, seed=config.seed + 7919, config=config.data)
    results: dict[float, float] = {}
    base = {k: v.detach().clone() for k, v in model.state_dict().items()}
    for scale in config.calibration_scales:
        model.load_state_dict(base)
        rescale_encoder(model, scale)
        errors = fusion_set_errors(model, fusions)
        results[scale] = float(sum(sendfuse for _, sendfuse in errors.values()))
        log(
            f"calibration: encoder scale {scale:g}: fused-map MSE "
            + ", ".join(f"{k} {v[1]:.3g} (mean {v[0]:.3g})" for k, v in errors.items())
        )
    best = min(results, key=lambda s: (results[s], -s))
    model.load_state_dict(base)
    rescale_encoder(model, best)
    return best, results


def pretrain(
    config: PretrainConfig | None = None,
    log: Callable[[str], None] = print,
    progress: bool = True,
    data: PairDataset | None = None,
) -> PretrainResult:
    """Generate pairs (unless ``data`` is given), train, calibrate; return the model and its record."""
    config = config or PretrainConfig()
    config.validate()
    start = time.perf_counter()
    torch.set_num_threads(config.threads)
    torch.manual_seed(config.seed)
    np.random.seed(config.seed)
    rng = np.random.default_rng(config.seed)

    if data is None:
        bar = _progress_bar(config.samples, "generating pairs", progress)
        data = generate_pairs(config.samples, seed=config.seed, config=config.data, progress=bar.update)
        bar.close()
    log(f"data: {data.summary()} ({time.perf_counter() - start:.0f}s)")

    n_val = round(len(data) * float(config.val_fraction))
    perm = rng.permutation(len(data))
    val_idx, train_idx = np.sort(perm[:n_val]), np.sort(perm[n_val:])
    x = torch.from_numpy(data.noisy[:, None])
    y = torch.from_numpy(data.clean[:, None])
    x_train, y_train, x_val, y_val = x[train_idx], y[train_idx], x[val_idx], y[val_idx]
    identity_val = float(((x_val - y_val) ** 2).mean()) if n_val else float("nan")

    model = SenDFuseNet(grid_size=config.grid_size)
    loss_fn = SenDFuseLoss(*config.loss_weights) if config.loss_weights else SenDFuseLoss()
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    steps_per_epoch = math.ceil(len(train_idx) / config.batch)
    total_steps = steps_per_epoch * config.epochs

    def cosine(step: int) -> float:
        """Learning-rate factor: 1 at the start, ``final_lr_fraction`` at the last step."""
        floor = config.final_lr_fraction
        return floor + (1.0 - floor) * 0.5 * (1.0 + math.cos(math.pi * min(step, total_steps) / total_steps))

    schedule = torch.optim.lr_scheduler.LambdaLR(optimizer, cosine)
    report = bar_write if progress else log
    history: list[EpochLog] = []
    bar = _progress_bar(total_steps, "training", progress)
    for epoch in range(1, config.epochs + 1):
        model.train()
        epoch_start = time.perf_counter()
        total, mse, mae, ssim = _train_epoch(model, loss_fn, optimizer, schedule, x_train, y_train, config, rng, bar)
        model.eval()
        val_total, val_mse, per = float("nan"), float("nan"), np.zeros(0)
        if n_val:
            val_total, val_mse, per = _evaluate(model, loss_fn, x_val, y_val)
        history.append(EpochLog(epoch, total, mse, mae, ssim, val_total, val_mse, time.perf_counter() - epoch_start))
        report(history[-1].line())
    bar.close()

    by_preset: dict[str, float] = {}
    if n_val:  # ``per``: per-pair validation MSE of the final epoch
        by_preset = _mse_by_preset(data.preset[val_idx], per)
        log(
            f"validation MSE: identity (noisy input) {identity_val:.4g}, SenDFuse {float(per.mean()):.4g}; "
            + ", ".join(f"{k} {v:.3g}" for k, v in by_preset.items())
        )
    scale = 1.0
    calibration: dict[float, float] = {}
    if config.calibrate:
        scale, calibration = _calibrate(model, config, log)
    model.eval()
    return PretrainResult(
        model, history, data.summary(), identity_val, by_preset, scale, calibration, time.perf_counter() - start
    )


def _train_epoch(
    model: SenDFuseNet,
    loss_fn: SenDFuseLoss,
    optimizer: torch.optim.Optimizer,
    schedule: torch.optim.lr_scheduler.LRScheduler,
    x_train: torch.Tensor,
    y_train: torch.Tensor,
    config: PretrainConfig,
    rng: np.random.Generator,
    bar: Any,
) -> tuple[float, float, float, float]:
    """One pass over the training pairs in shuffled batches (a random dihedral element per batch
    with ``augment``); the mean raw loss terms (total, MSE, MAE, 1 - SSIM) over the pairs."""
    sums = np.zeros(4)
    seen = 0
    for idx in _batches(len(x_train), config.batch, rng):
        xb, yb = x_train[idx], y_train[idx]
        if config.augment:
            k = int(rng.integers(8))
            xb, yb = dihedral(xb, k), dihedral(yb, k)
        terms = loss_fn(model(xb), yb)
        optimizer.zero_grad(set_to_none=True)
        terms.total.backward()
        optimizer.step()
        schedule.step()
        n = len(idx)
        values = np.array([float(t.detach()) for t in terms])
        sums += n * values
        seen += n
        bar.update(1)
        bar.set_postfix_str(f"loss {values[0]:.4f}", refresh=False)
    total, mse, mae, ssim = (float(v) for v in sums / max(seen, 1))
    return total, mse, mae, ssim


def _mse_by_preset(presets: np.ndarray, per: np.ndarray) -> dict[str, float]:
    """Mean per-pair MSE of each noise preset present (``presets``: the pairs' preset indices)."""
    by_preset: dict[str, float] = {}
    for i, name in enumerate(NOISE_PRESETS):
        if (presets == i).any():
            by_preset[name] = float(per[presets == i].mean())
    return by_preset


def bar_write(line: str) -> None:
    """Print a line above an active tqdm bar (plain print would break the bar)."""
    from tqdm.auto import tqdm

    tqdm.write(line)


class _NullBar:
    """Stand-in for tqdm when progress output is off (tests, logs)."""

    def update(self, n: int = 1) -> None:
        pass

    def set_postfix_str(self, s: str, refresh: bool = True) -> None:
        pass

    def close(self) -> None:
        pass


def _progress_bar(total: int, desc: str, enabled: bool):
    if not enabled:
        return _NullBar()
    from tqdm.auto import tqdm

    return tqdm(
        total=total,
        desc=desc,
        unit="pair" if "pair" in desc else "step",
        file=sys.stderr,
        dynamic_ncols=True,
        leave=False,
    )
