"""How well SenDFuse fuses what a UAV receives, compared with the naive mean (``sb3-coma eval-sendfuse``).

The question the ablation asks is "does the fused channel the actor sees carry less channel
noise with SenDFuse than with a plain average?". So the reference is the fusion the mean wrapper
*would* produce if the channel were perfect: for each receiving UAV, the average of the
noise-free versions of its valid received maps. Missions are flown in lockstep with and without
channel noise (:class:`sb3_coma.sendfuse.data.LockstepPair`), so that reference is exact, and
both fusions see the very same noisy maps.

Two resolutions are reported, because both matter: the communication grid (R x R, what SenDFuse
outputs) and the 11 x 11 lattice (what the fusion wrapper hands to the actor, via the same
area-weighted downsampling). Per-cell channel noise partly averages out on the lattice while an
attenuation bias does not, so the two can rank the methods differently.

Only fusions with at least two valid sources are scored (with the own map alone, the mean is the
own map, exact by construction); the error of SenDFuse's fusion of the own map alone is reported
separately (0 since the own map bypasses the network).
Evaluation maps default to env3 and env2, which the pre-training never sees.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from uav_ipp.fusion import mean_fusion
from uav_ipp.geometry import overlap_matrix

from .data import NOISE_PRESETS, FusionSet, LockstepPair
from .network import SenDFuseNet


@dataclass(frozen=True)
class QualityRow:
    """Mean squared errors against the clean fused map for one noise preset (lower is better)."""

    noise: str
    fusions: int  # scored (receiver, step) fusions with >= 2 valid sources
    mean_mse: float  # naive mean of the noisy maps, comm grid
    sendfuse_mse: float  # SenDFuse fusion, comm grid
    mean_mse_lattice: float  # the same two after downsampling to the 11 x 11 lattice
    sendfuse_mse_lattice: float
    own_only_mse: float  # SenDFuse fusion vs the own map when nothing else arrived
    own_only: int  # how many such cases

    @property
    def ratio(self) -> float:
        """SenDFuse MSE / mean MSE on the comm grid (< 1: SenDFuse is better); inf when mean is exact."""
        return self.sendfuse_mse / self.mean_mse if self.mean_mse > 0 else float("inf")

    @property
    def ratio_lattice(self) -> float:
        return self.sendfuse_mse_lattice / self.mean_mse_lattice if self.mean_mse_lattice > 0 else float("inf")


class _Accumulator:
    """Running sums of squared errors, so memory stays flat however many missions are flown."""

    def __init__(self, network: SenDFuseNet, to_lattice: np.ndarray, batch: int) -> None:
        self.network = network
        self.a = torch.from_numpy(to_lattice)
        self.batch = batch
        self.pending: dict[int, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
        self.sums = np.zeros(4)  # mean, sendfuse, mean lattice, sendfuse lattice
        self.count = 0
        self.own_sum = 0.0
        self.own_count = 0

    def add(self, noisy: np.ndarray, clean: np.ndarray, valid: np.ndarray) -> None:
        """One step of one mission: (N, N, R, R) maps and (N, N) validity of every receiver."""
        n_valid = valid.sum(axis=1)
        for i in np.flatnonzero(n_valid >= 2):
            # group by source count: fuse() batches (B, n, R, R) with one n
            self.pending.setdefault(int(noisy.shape[1]), []).append((noisy[i], clean[i], valid[i]))
        alone = np.flatnonzero(n_valid < 2)
        if len(alone):
            # what the wrapper gets when only the own map is there (exact with the own-map bypass)
            with torch.inference_mode():
                out = self.network.fuse(torch.from_numpy(noisy[alone]), torch.from_numpy(valid[alone])).numpy()
            self.own_sum += float(np.mean((out - noisy[alone, 0]) ** 2, axis=(1, 2)).sum())
            self.own_count += len(alone)
        for n, items in list(self.pending.items()):
            if len(items) >= self.batch:
                self._flush(n)

    def _lattice(self, maps: torch.Tensor) -> torch.Tensor:
        return torch.clamp(self.a @ maps @ self.a.T, 0.0, 1.0)  # as the fusion wrapper does

    def _flush(self, n: int) -> None:
        items = self.pending.pop(n, [])
        if not items:
            return
        noisy = np.stack([x[0] for x in items])
        clean = np.stack([x[1] for x in items])
        valid = np.stack([x[2] for x in items])
        target = torch.from_numpy(mean_fusion(clean, valid))
        naive = torch.from_numpy(mean_fusion(noisy, valid))
        with torch.inference_mode():
            fused = self.network.fuse(torch.from_numpy(noisy), torch.from_numpy(valid))
        # the wrapper's 11 x 11 channel is clipped to [0, 1]; the mean can leave it on the comm grid
        t_l, n_l, f_l = self._lattice(target), self._lattice(naive), self._lattice(fused)
        for k, (a, b) in enumerate(((naive, target), (fused, target), (n_l, t_l), (f_l, t_l))):
            self.sums[k] += float(((a - b) ** 2).mean(dim=(1, 2)).sum())
        self.count += len(items)

    def finish(self) -> tuple[int, np.ndarray, float, int]:
        for n in list(self.pending):
            self._flush(n)
        per = self.sums / max(self.count, 1)
        return self.count, per, self.own_sum / max(self.own_count, 1), self.own_count


def evaluate_quality(
    network: SenDFuseNet,
    env: str = "env3",
    missions: int = 20,
    seed: int = 0,
    presets: Sequence[str] = NOISE_PRESETS,
    n_uavs: int = 4,
    budget: int = 15,
    batch: int = 64,
    progress: Callable[[int], None] | None = None,
    **options: object,
) -> list[QualityRow]:
    """Fly ``missions`` random-action missions per noise preset and score both fusions.

    Mission ``m`` uses seed ``seed + m`` for the env and for its actions, so every preset flies
    the same trajectories over the same readings and only the channel differs. ``options`` go to
    the environment (e.g. ``map_path``, ``valuable``, ``comm_range``). ``progress(1)`` after each
    mission.
    """
    if missions < 1:
        raise ValueError(f"missions must be >= 1, got {missions}")
    unknown = [p for p in presets if p not in NOISE_PRESETS]
    if unknown:
        raise ValueError(f"unknown noise preset(s) {unknown}; choose from {NOISE_PRESETS}")
    network = network.eval()
    rows = []
    for preset in presets:
        pair = LockstepPair(env, preset, n_uavs=n_uavs, budget=budget, **options)
        grid = pair.noisy.config.comm_grid
        if network.grid_size != grid:
            raise ValueError(f"the network is built for R = {network.grid_size}, the env uses comm_grid={grid}")
        lattice = pair.noisy.config.lattice
        acc = _Accumulator(network, overlap_matrix(grid, float(lattice - 1), lattice), batch)
        for m in range(missions):
            for step in pair.run(seed + m, np.random.default_rng(seed + m)):
                acc.add(step.noisy, step.clean, step.valid)
            if progress is not None:
                progress(1)
        count, per, own_mse, own_count = acc.finish()
        mean_mse, sendfuse_mse, mean_lattice, sendfuse_lattice = (float(v) for v in per)
        rows.append(
            QualityRow(preset, count, mean_mse, sendfuse_mse, mean_lattice, sendfuse_lattice, own_mse, own_count)
        )
    return rows


def fusion_set_errors(network: SenDFuseNet, fusions: FusionSet, batch: int = 64) -> dict[str, tuple[float, float]]:
    """Comm-grid MSE against the clean mean, per noise preset: ``{preset: (mean, sendfuse)}``."""
    out: dict[str, tuple[float, float]] = {}
    network = network.eval()
    for index, preset in enumerate(NOISE_PRESETS):
        rows = np.flatnonzero(fusions.preset == index)
        if not len(rows):
            continue
        sums = np.zeros(2)
        for start in range(0, len(rows), batch):
            sel = rows[start : start + batch]
            noisy, clean, valid = fusions.noisy[sel], fusions.clean[sel], fusions.valid[sel]
            target = mean_fusion(clean, valid)
            with torch.inference_mode():
                fused = network.fuse(torch.from_numpy(noisy), torch.from_numpy(valid)).numpy()
            sums += [
                float(((mean_fusion(noisy, valid) - target) ** 2).mean(axis=(1, 2)).sum()),
                float(((fused - target) ** 2).mean(axis=(1, 2)).sum()),
            ]
        out[preset] = (sums[0] / len(rows), sums[1] / len(rows))
    return out


def _fmt(value: float) -> str:
    return "-" if not np.isfinite(value) else f"{value:.3g}"


def format_table(rows: Iterable[QualityRow], markdown: bool = False) -> str:
    """The quality table as aligned text or as Markdown (for SENDFUSE.md and reports)."""
    header = [
        "noise",
        "fusions",
        "mean MSE",
        "SenDFuse MSE",
        "ratio",
        "mean MSE 11x11",
        "SenDFuse MSE 11x11",
        "ratio 11x11",
        "own-only MSE",
    ]
    body = [
        [
            r.noise,
            str(r.fusions),
            f"{r.mean_mse:.3g}",
            f"{r.sendfuse_mse:.3g}",
            _fmt(r.ratio),
            f"{r.mean_mse_lattice:.3g}",
            f"{r.sendfuse_mse_lattice:.3g}",
            _fmt(r.ratio_lattice),
            f"{r.own_only_mse:.3g} (n={r.own_only})",
        ]
        for r in rows
    ]
    if markdown:
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(row) + " |" for row in body]
        return "\n".join(lines)
    widths = [max(len(h), *(len(row[k]) for row in body)) if body else len(h) for k, h in enumerate(header)]
    lines = ["  ".join(h.rjust(w) for h, w in zip(header, widths))]
    lines += ["  ".join(c.rjust(w) for c, w in zip(row, widths)) for row in body]
    return "\n".join(lines)
