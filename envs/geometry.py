"""Static geometry of the field: lattice, belief grid, communication grid, camera footprints.

Everything here is computed once per environment and then only indexed, so the per-step cost of
a measurement depends on the footprint's area and never on the size of the map.

Conventions: arrays are indexed ``[y, x]`` (row = y), lattice index ``k`` sits at ``k * spacing``
metres, belief cell ``i`` spans ``[i, i+1) * cell_size`` metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import kernels
from .config import ConfigError, IppConfig
from .maps import block_index


def comm_index(n_cells: int, comm_grid: int) -> np.ndarray:
    """Communication-grid cell of every belief cell along one axis (equal-width bins)."""
    return np.minimum((np.arange(n_cells) * comm_grid) // n_cells, comm_grid - 1).astype(np.int64)


def overlap_matrix(comm_grid: int, field_size: float, lattice: int) -> np.ndarray:
    """Row-stochastic (lattice x comm_grid) matrix of area weights from comm cells to lattice blocks.

    ``A @ m @ A.T`` turns a comm-grid map into the 11 x 11 block means in two tiny matmuls.
    """
    spacing = field_size / (lattice - 1)
    edges = np.linspace(0.0, field_size, comm_grid + 1)
    a = np.zeros((lattice, comm_grid), dtype=np.float64)
    for k in range(lattice):
        lo = max(0.0, (k - 0.5) * spacing)
        hi = min(field_size, (k + 0.5) * spacing)
        a[k] = np.clip(np.minimum(edges[1:], hi) - np.maximum(edges[:-1], lo), 0.0, None)
    a /= a.sum(axis=1, keepdims=True)
    return a.astype(np.float32)


@dataclass(frozen=True)
class Footprint:
    """A camera footprint clipped to the field, as half-open index ranges on both grids."""

    r0: int
    r1: int
    c0: int
    c1: int

    @property
    def shape(self) -> tuple[int, int]:
        return (self.r1 - self.r0, self.c1 - self.c0)


class FieldGeometry:
    """Lattice, grids and the footprint table of one environment configuration."""

    def __init__(self, config: IppConfig) -> None:
        self.config = config
        self.lattice = config.lattice
        self.grid = config.grid
        self.comm_grid = config.comm_grid
        self.spacing = config.spacing
        self.cell = config.cell_size
        self.altitudes = np.asarray(config.altitudes, dtype=np.float64)
        half_fov = math.radians(config.fov_deg) / 2.0
        #: Half side of the square footprint per altitude level, metres.
        self.half_side = self.altitudes * math.tan(half_fov)
        self.block_of_cell = block_index(self.grid, self.lattice)
        self.comm_of_cell = comm_index(self.grid, self.comm_grid)
        self.cells_per_block = np.bincount(self.block_of_cell, minlength=self.lattice).astype(np.int64)
        self.block_area = np.outer(self.cells_per_block, self.cells_per_block).astype(np.float64)
        self.cells_per_comm = np.bincount(self.comm_of_cell, minlength=self.comm_grid).astype(np.int64)
        self.comm_to_lattice = overlap_matrix(self.comm_grid, config.field_size, self.lattice)
        self._ranges = self._footprint_ranges()
        empty = self._ranges[..., 1] <= self._ranges[..., 0]
        if empty.any():
            level = int(np.argwhere(empty)[0][1])
            raise ConfigError(
                f"invalid options fov_deg={config.fov_deg!r} / field_size={config.field_size!r} / grid={config.grid!r}: "
                f"the camera footprint at {config.altitudes[level]:g} m covers no belief cell "
                f"(side {2 * self.half_side[level]:.3g} m, cell {self.cell:.3g} m)"
            )
        self.comm_cell_area = np.outer(self.cells_per_comm, self.cells_per_comm).astype(np.float32)
        self.comm_blocks, self.comm_weights = self._comm_block_weights()
        self._build_segments()

    def _build_segments(self) -> None:
        """Cut each axis into *segments*: runs of belief cells that share a lattice block, a comm
        cell and a gain strip.

        Gain strips are the runs between consecutive footprint edges, so every footprint is an
        exact union of strips along each axis: the expected gain of any footprint is a sum of
        per-strip sums that the kernels keep up to date (no per-action pass over cells). The
        kernels walk a footprint segment by segment and flush their running sums once per
        segment, so each running sum lives in a register across the cells of one segment.
        """
        edges_fp = {0, self.grid}
        edges_fp.update(int(v) for v in self._ranges.ravel())
        strip_edges = np.array(sorted(edges_fp), dtype=np.int64)
        edges = set(edges_fp)
        edges.update(int(v) for v in np.flatnonzero(np.diff(self.block_of_cell)) + 1)
        edges.update(int(v) for v in np.flatnonzero(np.diff(self.comm_of_cell)) + 1)
        seg_edges = np.array(sorted(edges), dtype=np.int64)
        cells = np.arange(self.grid)
        #: (S + 1,) first cell of every segment along one axis, then ``grid``.
        self.seg_start = seg_edges
        #: (grid,) segment of every cell.
        self.seg_of_cell = np.searchsorted(seg_edges, cells, side="right") - 1
        #: (Sg,) number of gain strips is ``len(strip_edges) - 1``; (grid,) strip of every cell.
        self.strip_of_cell = np.searchsorted(strip_edges, cells, side="right") - 1
        self.n_strips = len(strip_edges) - 1
        self.strip_cells = np.diff(strip_edges).astype(np.float64)
        starts = seg_edges[:-1]
        self.seg_block = self.block_of_cell[starts]
        self.seg_comm = self.comm_of_cell[starts]
        self.seg_strip = self.strip_of_cell[starts]
        #: (lattice, n_alt, 2) half-open strip range of each footprint along one axis.
        first = self.strip_of_cell[self._ranges[..., 0]]
        last = self.strip_of_cell[self._ranges[..., 1] - 1] + 1
        self.footprint_strips = np.stack([first, last], axis=-1).astype(np.int64)
        #: (lattice, n_alt, 2) half-open belief-cell range of each footprint along one axis.
        self.footprint_ranges = self._ranges
        self.max_footprint = int((self._ranges[..., 1] - self._ranges[..., 0]).max())

    def kernel_geometry(self) -> kernels.Geometry:
        """The index arrays the footprint kernels read, as one bundle (the same arrays, except the
        comm-cell areas in float64 for the kernels' half-covered test)."""
        return kernels.Geometry(
            ranges=self.footprint_ranges,
            seg_start=self.seg_start,
            seg_of_cell=self.seg_of_cell,
            seg_block=self.seg_block,
            seg_comm=self.seg_comm,
            seg_strip=self.seg_strip,
            block_of_cell=self.block_of_cell,
            comm_of_cell=self.comm_of_cell,
            strip_of_cell=self.strip_of_cell,
            comm_area=self.comm_cell_area.astype(np.float64),
        )

    def _comm_block_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """For each comm cell along one axis, the (at most two) lattice blocks it overlaps and
        the weights of ``comm_to_lattice`` for them, for incremental block means."""
        a = self.comm_to_lattice
        blocks = np.zeros((self.comm_grid, 2), dtype=np.int64)
        weights = np.zeros((self.comm_grid, 2), dtype=np.float64)
        for c in range(self.comm_grid):
            nz = np.flatnonzero(a[:, c] > 0)
            if len(nz) > 2:
                raise ValueError(f"comm_grid={self.comm_grid} is coarser than the lattice blocks; use a finer grid")
            blocks[c, : len(nz)] = nz
            weights[c, : len(nz)] = a[nz, c]
        return blocks, weights

    def _footprint_ranges(self) -> np.ndarray:
        """(lattice, n_alt, 2) half-open belief-cell ranges covered along one axis.

        A cell is covered when its centre lies inside the footprint (clipped to the field).
        """
        n_alt = len(self.altitudes)
        ranges = np.zeros((self.lattice, n_alt, 2), dtype=np.int64)
        for k in range(self.lattice):
            centre = k * self.spacing
            for a in range(n_alt):
                lo = (centre - self.half_side[a]) / self.cell - 0.5
                hi = (centre + self.half_side[a]) / self.cell - 0.5
                first = max(0, math.ceil(lo - 1e-9))
                last = min(self.grid - 1, math.floor(hi + 1e-9))
                ranges[k, a] = (first, last + 1)
        return ranges

    def footprint(self, ix: int, iy: int, alt_level: int) -> Footprint:
        """Footprint of a UAV at lattice column (ix, iy) and altitude level index ``alt_level``."""
        r0, r1 = self._ranges[iy, alt_level]
        c0, c1 = self._ranges[ix, alt_level]
        return Footprint(int(r0), int(r1), int(c0), int(c1))

    def footprint_side_cells(self, alt_level: int) -> int:
        """Side of an unclipped footprint in belief cells (57 / 114 / 171 by default)."""
        centre = self.lattice // 2
        r0, r1 = self._ranges[centre, alt_level]
        return int(r1 - r0)

    def block_sums(self, grid_map: np.ndarray) -> np.ndarray:
        """(L, L) float64 sums of a (G, G) map over every lattice block (once per map, not per step)."""
        starts = np.flatnonzero(np.diff(self.block_of_cell, prepend=-1))
        rows = np.add.reduceat(grid_map.astype(np.float64), starts, axis=0)
        return np.add.reduceat(rows, starts, axis=1)

    def to_lattice(self, comm_map: np.ndarray) -> np.ndarray:
        """Area-weighted 11 x 11 block means of one or many comm-grid maps (..., R, R)."""
        a = self.comm_to_lattice
        return np.matmul(np.matmul(a, comm_map), a.T)

    def lattice_of(self, x: float, y: float) -> tuple[int, int]:
        return round(x / self.spacing), round(y / self.spacing)
