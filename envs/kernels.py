"""Hot-path kernels: one fused pass over the cells a footprint covers, per belief it changes.

Why it looks like this (measured, ``benchmarks/env_throughput.py``, docs/environment.md):

* every belief (the global map and each UAV's local map M_i) is stored as fixed-point log-odds,
  ``int16`` in 1/64 units clamped at +-31.25. Everything the env derives from a cell (probability,
  entropy, class-weighted entropy, expected information gain of a reading at each altitude) is
  then one row of a small table (4001 rows: 64-160 KB, resident in L2), never a logarithm;
* a footprint is walked *segment* by segment (runs of cells sharing a lattice block, a comm cell
  and a gain strip, :class:`uav_ipp.geometry.FieldGeometry`), and running sums are flushed once per
  segment, so no store-to-load chain serialises the loop;
* the sender's pass updates the global map and its own M_i from the same readings in one go;
  each receiver's pass decodes the sender's noisy image into its M_i;
* every random draw is counter-based (common random numbers): a splitmix64 hash of a stream key
  and the cell index, the key chaining (mission seed, domain, step, ids) through the same mixer
  (:func:`stream_key`). Sensor flips: (seed, step, UAV, cell), 16 bits against a threshold;
  channel noise: (seed, step, sender, receiver, cell), 16 bits for ``a`` and 12 bits picking ``n``
  from a 4096-level normal quantile table; message drops: (seed, step, sender, receiver). A draw
  never depends on how many draws came before it, so two plans that take the same measurement get
  the same reading and the same channel noise on the same link, the visiting order of cells does
  not matter, and no transcendental function runs per cell.

* the kernels take the env's state as a few named tuples of arrays (:class:`Tables`,
  :class:`Geometry`, :class:`GlobalMaps`, :class:`LocalMaps`, :class:`CommState`,
  :class:`Channel`), built once per env: numba passes them like their arrays (no copy), and a
  kernel's signature says which state it reads and writes. The per-cell work sits in small
  ``inline="always"`` helpers that carry their running sums as tuples, so the inlined loop is the
  same as a hand-written one (bit-identical results, same speed, measured).

The mission seed is the reset seed (``UavIppEnv.reset``): same seed and actions, same mission,
bit for bit.
"""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import NamedTuple

import numba
import numpy as np

#: Fixed-point scale of all log-odds: value / SCALE = log-odds.
SCALE = 64
#: Saturation of the log-odds (+-31.25: p within 3e-14 of 0 or 1).
CLAMP = 2000
#: Row of log-odds 0 in the tables.
OFFSET = CLAMP
TABLE_SIZE = 2 * CLAMP + 1
#: Class-weighting thresholds of ipp-marl: believed valuable above, not valuable below.
WEIGHT_HIGH = 0.501
WEIGHT_LOW = 0.499
#: Probability clip of ipp-marl's entropy inside the weighted entropy.
ENTROPY_CLIP = 1e-4
#: Levels of the channel-noise normal table (12 bits of a hash pick one).
NORMAL_LEVELS = 4096

REWARD_ENTROPIES = ("plain", "weighted")

# Columns of the global table.
G_REWARD, G_ENTROPY, G_PROB = 0, 1, 2
# Columns of the local table: probability, entropy, then the gains (see uav_ipp.gain).
L_PROB, L_ENTROPY, L_GAIN0 = 0, 1, 2
# Global scalars accumulated by the kernels.
S_REWARD, S_ENT_TRUE, S_TP, S_PP = 0, 1, 2, 3


def binary_entropy(p: np.ndarray) -> np.ndarray:
    """Binary entropy in bits, exact at 0 and 1."""
    p = np.asarray(p, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        h = -(p * np.log2(p) + (1.0 - p) * np.log2(1.0 - p))
    return np.nan_to_num(h, nan=0.0)


def class_weight(p: np.ndarray) -> np.ndarray:
    """ipp-marl's class weighting: 1 believed valuable, 0 believed not valuable, 0.5 unknown."""
    p = np.asarray(p, dtype=np.float64)
    return np.where(p > WEIGHT_HIGH, 1.0, np.where(p < WEIGHT_LOW, 0.0, 0.5))


def weighted_entropy(p: np.ndarray) -> np.ndarray:
    """Class-weighted entropy of ipp-marl (clipped entropy times class weight)."""
    pc = np.clip(np.asarray(p, dtype=np.float64), ENTROPY_CLIP, 1.0 - ENTROPY_CLIP)
    return class_weight(p) * binary_entropy(pc)


def reward_entropy(p: np.ndarray, kind: str = "plain") -> np.ndarray:
    """Per-cell entropy that the reward sums: ``plain`` binary entropy or ipp-marl's ``weighted``."""
    if kind == "weighted":
        return weighted_entropy(p)
    if kind == "plain":
        return binary_entropy(p)
    raise ValueError(f"unknown reward entropy {kind!r}; choose one of {REWARD_ENTROPIES}")


def table_probabilities() -> np.ndarray:
    """(TABLE_SIZE,) probability of every fixed-point log-odds value, row ``v + OFFSET``."""
    values = (np.arange(TABLE_SIZE, dtype=np.float64) - OFFSET) / SCALE
    return 1.0 / (1.0 + np.exp(-values))


def probability(logodds: np.ndarray) -> np.ndarray:
    """Probabilities of stored fixed-point log-odds (any shape), float32."""
    return (1.0 / (1.0 + np.exp(-np.asarray(logodds, dtype=np.float32) / SCALE))).astype(np.float32)


def build_global_table(kind: str = "plain") -> np.ndarray:
    """(TABLE_SIZE, 4) float32: reward entropy, entropy (bits), probability, 0 per log-odds value."""
    p = table_probabilities()
    table = np.zeros((TABLE_SIZE, 4), dtype=np.float32)
    table[:, G_REWARD] = reward_entropy(p, kind)
    table[:, G_ENTROPY] = binary_entropy(p)
    table[:, G_PROB] = p
    return table


def step_table(table: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """(2 A TABLE_SIZE, C) float32: row ``(2 a + reading) * TABLE_SIZE + v + OFFSET`` holds the change of
    every column of ``table`` when a clean reading (0 or 1) at altitude level ``a`` moves log-odds ``v``.

    A clean reading moves a cell by exactly +-increment, so the kernels read one row of changes per
    cell instead of the rows before and after (half the table loads on the sensing pass).
    """
    values = np.arange(TABLE_SIZE) - OFFSET
    blocks = []
    for inc in increments:
        for reading in (0, 1):
            new = np.clip(values + (inc if reading else -inc), -CLAMP, CLAMP) + OFFSET
            blocks.append(table[new].astype(np.float64) - table[values + OFFSET])
    return np.concatenate(blocks).astype(np.float32)


def fixed_point_increment(flip_probability: float) -> int:
    """Log-odds increment log((1-q)/q) of a reading, in fixed-point units."""
    return round(math.log((1.0 - flip_probability) / flip_probability) * SCALE)


def flip_threshold(flip_probability: float) -> int:
    """A reading flips when a uniform 16-bit integer is below this threshold."""
    return round(flip_probability * 65536.0)


def normal_table() -> np.ndarray:
    """(NORMAL_LEVELS,) float32 standard-normal quantiles at (k + 0.5) / NORMAL_LEVELS (|z| <= 3.67)."""
    dist = NormalDist()
    return np.array([dist.inv_cdf((k + 0.5) / NORMAL_LEVELS) for k in range(NORMAL_LEVELS)], dtype=np.float32)


#: Golden-ratio increment of splitmix64: consecutive counters land far apart before mixing.
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
#: Domains of the counter-based draws: the same (seed, step, ids, cell) gives independent bits
#: to sensor flips, channel noise and message drops.
DOMAIN_FLIP = 1
DOMAIN_CHANNEL = 2
DOMAIN_DROP = 3
#: A footprint (or any cell rectangle) as half-open ranges: (r0, r1, c0, c1), rows first.
Rect = tuple[int, int, int, int]


@numba.njit(cache=True, inline="always")
def _mix(z: np.uint64) -> np.uint64:
    """splitmix64's finaliser (Stafford's mix 13): a bijection of 64 bits with full avalanche."""
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True, inline="always")
def _hash(key: np.uint64, counter: np.uint64) -> np.uint64:
    """Output ``counter`` of the splitmix64 stream seeded at ``key``: 64 random-looking bits per
    (key, counter), so a draw never depends on which other draws were made before it."""
    return _mix(np.uint64(key) + np.uint64(counter) * GOLDEN)  # casts: a key may arrive as a Python int


@numba.njit(cache=True)
def stream_key(seed: np.uint64, domain: int, step: int, a: int, b: int) -> np.uint64:
    """Key of one stream of counter-based draws: ``(mission seed, domain, step, a, b)`` chained
    through the mixer (``a, b``: the UAV and 0 for flips; sender and receiver for messages).

    Every random draw of the env is ``_hash(stream_key(...), counter)`` with the cell index (or 0)
    as counter: a pure function of *what* is drawn, never of how many draws came before, so two
    plans that take the same measurement see the same noise (common random numbers).
    """
    k = _hash(_mix(np.uint64(seed)), np.uint64(domain))  # mixed first: nearby seeds share no stream
    k = _hash(k, np.uint64(step))
    k = _hash(k, np.uint64(a))
    return _hash(k, np.uint64(b))


def mission_seed(seed: int) -> np.uint64:
    """The 64-bit mission seed of a reset seed (an integer >= 0; larger ones are folded mod 2**64)."""
    return np.uint64(int(seed) % 2**64)


@numba.njit(cache=True, inline="always")
def _flip_draw(key: np.uint64, cell: np.uint64) -> np.int32:
    """Uniform 16-bit draw of one cell's sensor reading (the top 16 bits of its hash)."""
    return np.int32(_hash(key, cell) >> np.uint64(48))


@numba.njit(cache=True, inline="always")
def _channel_draw(key: np.uint64, cell: np.uint64, alpha_low: float, spread: float, sigma: float, normals):
    """``(a, n)`` of one received cell: 16 bits give ``a ~ U(alpha_low, 1)``, 12 more pick ``n``
    from the normal quantile table (no transcendental function per cell)."""
    h = _hash(key, cell)
    a = alpha_low + spread * (float(np.int32(h & np.uint64(0xFFFF))) * (1.0 / 65536.0))
    noise = sigma * normals[np.int32(h >> np.uint64(16)) & np.int32(NORMAL_LEVELS - 1)]
    return a, noise


@numba.njit(cache=True)
def flip_draws(seed: np.uint64, step: int, uav: int, fp: Rect, grid: int) -> np.ndarray:
    """(r1 - r0, c1 - c0) int32 16-bit draws of UAV ``uav``'s sensor at ``step`` over the cell
    rectangle ``fp = (r0, r1, c0, c1)``, exactly as :func:`sense` draws them (a reading is flipped
    where the draw is below :func:`flip_threshold`): the keying contract, for tests and replays."""
    r0, r1, c0, c1 = fp
    key = stream_key(seed, DOMAIN_FLIP, step, uav, 0)
    out = np.empty((r1 - r0, c1 - c0), dtype=np.int32)
    for i in range(r0, r1):
        for j in range(c0, c1):
            out[i - r0, j - c0] = _flip_draw(key, np.uint64(i * grid + j))
    return out


@numba.njit(cache=True)
def channel_draws(
    seed: np.uint64,
    step: int,
    sender: int,
    receiver: int,
    fp: Rect,
    grid: int,
    alpha_low: float,
    sigma: float,
    normals: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``(a, n)``, each (r1 - r0, c1 - c0) float64: the attenuation and additive noise of every cell
    of the rectangle ``fp = (r0, r1, c0, c1)`` in the message ``sender -> receiver`` at ``step``,
    exactly as :func:`receive` draws them."""
    r0, r1, c0, c1 = fp
    key = stream_key(seed, DOMAIN_CHANNEL, step, sender, receiver)
    a = np.empty((r1 - r0, c1 - c0), dtype=np.float64)
    n = np.empty((r1 - r0, c1 - c0), dtype=np.float64)
    for i in range(r0, r1):
        for j in range(c0, c1):
            a[i - r0, j - c0], n[i - r0, j - c0] = _channel_draw(
                key, np.uint64(i * grid + j), alpha_low, 1.0 - alpha_low, sigma, normals
            )
    return a, n


@numba.njit(cache=True)
def link_uniforms(seed: np.uint64, step: int, out: np.ndarray) -> None:
    """Fill ``out[r, s]`` with the uniform [0, 1) draw that decides whether the message from
    sender ``s`` to receiver ``r`` at ``step`` is lost (it is when the draw is below
    ``drop_probability``), keyed on (seed, step, sender, receiver) only."""
    n = out.shape[0]
    for r in range(n):
        for s in range(n):
            h = _hash(stream_key(seed, DOMAIN_DROP, step, s, r), np.uint64(0))
            out[r, s] = float(h >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, inline="always")
def _clamp(v):
    return min(max(v, -CLAMP), CLAMP)


#: Gain columns the kernels carry: 2 weightings x at most 3 altitude levels (unused ones are 0).
GAIN_SLOTS = 6


@numba.njit(cache=True, inline="always")
def _gain_delta(acc, ltab, io, inw):
    """``acc`` plus the change of the six gain columns from table row ``io`` to row ``inw``."""
    return (
        acc[0] + (ltab[inw, L_GAIN0] - ltab[io, L_GAIN0]),
        acc[1] + (ltab[inw, L_GAIN0 + 1] - ltab[io, L_GAIN0 + 1]),
        acc[2] + (ltab[inw, L_GAIN0 + 2] - ltab[io, L_GAIN0 + 2]),
        acc[3] + (ltab[inw, L_GAIN0 + 3] - ltab[io, L_GAIN0 + 3]),
        acc[4] + (ltab[inw, L_GAIN0 + 4] - ltab[io, L_GAIN0 + 4]),
        acc[5] + (ltab[inw, L_GAIN0 + 5] - ltab[io, L_GAIN0 + 5]),
    )


@numba.njit(cache=True, inline="always")
def _gain_step(acc, lstep, row):
    """``acc`` plus the six gain-column changes of one step-table row (see :func:`step_table`)."""
    return (
        acc[0] + lstep[row, L_GAIN0],
        acc[1] + lstep[row, L_GAIN0 + 1],
        acc[2] + lstep[row, L_GAIN0 + 2],
        acc[3] + lstep[row, L_GAIN0 + 3],
        acc[4] + lstep[row, L_GAIN0 + 4],
        acc[5] + lstep[row, L_GAIN0 + 5],
    )


@numba.njit(cache=True, inline="always")
def _flush_gains(l_strip, gi, gj, acc):
    for k in range(GAIN_SLOTS):
        l_strip[k, gi, gj] += acc[k]


# --------------------------------------------------------------------------- kernel state bundles
# The kernels see the env's state as a few named tuples of arrays, built once per env (numba
# passes a tuple of arrays like its arrays: no copy, the kernels write into the env's own arrays).


class Tables(NamedTuple):
    """Read-only lookup tables: why a footprint pass needs no logarithm (decision 1)."""

    #: (2 A TABLE_SIZE, 4) float32 change of every global-table column per clean reading (:func:`step_table`).
    gstep: np.ndarray
    #: (2 A TABLE_SIZE, 2 + GAIN_SLOTS) float32, the same for the local table.
    lstep: np.ndarray
    #: (TABLE_SIZE, 2 + GAIN_SLOTS) float32 local table: probability, entropy, gains (``uav_ipp.gain``).
    ltab: np.ndarray
    #: (NORMAL_LEVELS,) float32 standard-normal quantiles of the channel noise (:func:`normal_table`).
    normals: np.ndarray
    #: (A,) int64 log-odds increment of one reading per altitude level (:func:`fixed_point_increment`).
    increments: np.ndarray
    #: (A,) int64 16-bit flip threshold per altitude level (:func:`flip_threshold`).
    thresholds: np.ndarray


class Geometry(NamedTuple):
    """Static index arrays of the field (``uav_ipp.geometry.FieldGeometry.kernel_geometry``)."""

    #: (lattice, A, 2) int64 half-open belief-cell range of a footprint along one axis.
    ranges: np.ndarray
    #: (S + 1,) first cell of every segment along one axis, then ``grid``.
    seg_start: np.ndarray
    #: (grid,) segment of every cell; (S,) lattice block, comm cell and gain strip of every segment.
    seg_of_cell: np.ndarray
    seg_block: np.ndarray
    seg_comm: np.ndarray
    seg_strip: np.ndarray
    #: (grid,) lattice block, comm cell and gain strip of every cell along one axis.
    block_of_cell: np.ndarray
    comm_of_cell: np.ndarray
    strip_of_cell: np.ndarray
    #: (R, R) float64 belief cells per comm cell (a comm cell counts once half covered).
    comm_area: np.ndarray


class GlobalMaps(NamedTuple):
    """The global map (all true readings) and its running sums (decision 2)."""

    #: (G, G) uint8 ground truth: read for the readings and the metrics, never written.
    truth: np.ndarray
    #: (G, G) int16 fixed-point log-odds.
    logodds: np.ndarray
    #: (G, G) uint8 1 where a cell was measured at least once (coverage).
    measured: np.ndarray
    #: (4, L, L) float64 block sums of probability, entropy, coverage and probability over the truly
    #: valuable cells (the last one feeds the critic's privileged error channel, observation v3).
    block: np.ndarray
    #: (4,) float64 reward-entropy total, entropy over valuable cells, true and predicted positives.
    scal: np.ndarray

    @classmethod
    def blank(cls, grid: int, lattice: int) -> GlobalMaps:
        """Zeroed maps and sums: the owner copies a truth in and sets the prior sums at a reset."""
        cells = (grid, grid)
        return cls(
            truth=np.zeros(cells, dtype=np.uint8),
            logodds=np.zeros(cells, dtype=np.int16),
            measured=np.zeros(cells, dtype=np.uint8),
            block=np.zeros((4, lattice, lattice), dtype=np.float64),
            scal=np.zeros(4, dtype=np.float64),
        )


class LocalMaps(NamedTuple):
    """Every UAV's local map M_i and its running sums (first axis: the UAV)."""

    #: (N, G, G) int16 fixed-point log-odds.
    logodds: np.ndarray
    #: (N, 2, L, L) float64 block sums of probability and entropy.
    block: np.ndarray
    #: (N, 2, R, R) float64 the same sums per comm cell (the fine view of observation v3).
    fine: np.ndarray
    #: (N, GAIN_SLOTS, S, S) float64 gain of one reading per gain-strip cell (decision 14).
    strip: np.ndarray
    #: (N, 3) float64 entropy over valuable cells, true and predicted positives.
    scal: np.ndarray

    @classmethod
    def blank(cls, n: int, grid: int, lattice: int, n_strips: int, comm_grid: int) -> LocalMaps:
        """Zeroed maps and sums for ``n`` UAVs: the owner sets the prior sums at a reset."""
        return cls(
            logodds=np.zeros((n, grid, grid), dtype=np.int16),
            block=np.zeros((n, 2, lattice, lattice), dtype=np.float64),
            fine=np.zeros((n, 2, comm_grid, comm_grid), dtype=np.float64),
            strip=np.zeros((n, GAIN_SLOTS, n_strips, n_strips), dtype=np.float64),
            scal=np.zeros((n, 3), dtype=np.float64),
        )


class CommState(NamedTuple):
    """Messages: this step's readings, what every UAV keeps of every sender, and scratch sums."""

    #: (N, F, F) uint8 each UAV's readings of this step, footprint-relative (its message).
    readings: np.ndarray
    #: (N, N, R, R) float32 ``received[r, slot]``: comm-grid average of what r got from a sender.
    received: np.ndarray
    #: (N, N) float32 1 where the slot ever received a message.
    received_valid: np.ndarray
    #: (R, R) float64 per-message scratch sums (zero between messages).
    comm_sum: np.ndarray
    comm_cnt: np.ndarray
    #: (N, N) int64 ``slots[r, s]``: where receiver r keeps sender s (0: itself, then the others in id order).
    slots: np.ndarray

    @classmethod
    def blank(cls, n: int, max_footprint: int, comm_grid: int) -> CommState:
        """Nothing received yet (0.5 everywhere, no valid slot), zero scratch sums, the slot layout."""
        slots = np.array([[s + 1 if s < r else s for s in range(n)] for r in range(n)], dtype=np.int64)
        slots[np.arange(n), np.arange(n)] = 0
        return cls(
            readings=np.zeros((n, max_footprint, max_footprint), dtype=np.uint8),
            received=np.full((n, n, comm_grid, comm_grid), 0.5, dtype=np.float32),
            received_valid=np.zeros((n, n), dtype=np.float32),
            comm_sum=np.zeros((comm_grid, comm_grid), dtype=np.float64),
            comm_cnt=np.zeros((comm_grid, comm_grid), dtype=np.float64),
            slots=slots,
        )


class Channel(NamedTuple):
    """This step's links and the channel model (buffers refilled every step)."""

    #: (N, N) bool ``links[r, s]``: r receives s's message this step.
    links: np.ndarray
    #: (N, N) float64 lower bound ``alpha_low`` of the attenuation on each link.
    bound: np.ndarray
    #: Standard deviation of the additive noise.
    sigma: float
    #: True: soft decoder; False: threshold decoder (decision 7).
    soft: bool


# --------------------------------------------------------------------------- footprint kernels
@numba.njit(cache=True, inline="always")
def _footprint(geo: Geometry, pos: np.ndarray, u: int) -> tuple[Rect, int]:
    """((r0, r1, c0, c1), altitude level) of UAV ``u``'s footprint: half-open cell ranges."""
    lev = pos[u, 2]
    rows = geo.ranges[pos[u, 1], lev]
    cols = geo.ranges[pos[u, 0], lev]
    return (rows[0], rows[1], cols[0], cols[1]), lev


@numba.njit(cache=True, inline="always")
def _fold(logodds: np.ndarray, i: int, j: int, d: int) -> tuple[int, int, int]:
    """Move cell (i, j) of a log-odds map by ``d``, clamped. Returns the old and new values and the
    change of "believed valuable" (-1, 0 or 1: the F1 counts move by it)."""
    old = np.int32(logodds[i, j])
    new = _clamp(old + d)
    logodds[i, j] = new
    return old, new, np.int32(new > 0) - np.int32(old > 0)


@numba.njit(cache=True)
def _flush_comm(comm: CommState, geo: Geometry, slot_map: np.ndarray, fp: Rect) -> None:
    """Write the comm-grid averages of this message into ``slot_map`` where at least half of a comm
    cell was covered (the rest keeps what it had), then zero the scratch sums for the next message."""
    r0, r1, c0, c1 = fp
    for ci in range(geo.comm_of_cell[r0], geo.comm_of_cell[r1 - 1] + 1):
        for cj in range(geo.comm_of_cell[c0], geo.comm_of_cell[c1 - 1] + 1):
            cnt = comm.comm_cnt[ci, cj]
            if 2.0 * cnt >= geo.comm_area[ci, cj]:
                slot_map[ci, cj] = min(max(comm.comm_sum[ci, cj] / cnt, -0.5), 1.5)
            comm.comm_sum[ci, cj] = 0.0
            comm.comm_cnt[ci, cj] = 0.0


@numba.njit(cache=True, inline="always")
def _sense_run(
    i: int,
    j0: int,
    j1: int,
    ctx: tuple,
    tables: Tables,
    glob: GlobalMaps,
    local: np.ndarray,
    readings: np.ndarray,
    tot: tuple,
) -> tuple[tuple, tuple]:
    """Read cells ``j0..j1`` of row ``i`` (one segment) and fold every reading into the global map
    and the UAV's M_i. ``ctx``: (r0, c0, increment, flip threshold, table base of the level, flip
    key). ``tot``: the footprint's running scalars, carried cell by cell so the summation order
    (and so every float) does not depend on how the footprint is cut. Returns the segment's sums
    (global prob / entropy / coverage / prob over valuable cells, local prob / entropy, readings,
    gains) and ``tot``."""
    r0, c0, inc, thr, level_base, key = ctx
    g_went, g_ent_true, g_tp, g_pp, l_ent_true, l_tp, l_pp = tot
    gstep, lstep = tables.gstep, tables.lstep
    gs_prob = gs_ent = gs_prob_true = ls_prob = ls_ent = 0.0
    gs_cov = s_read = 0
    acc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    cell_row = np.uint64(i * glob.truth.shape[1])
    for j in range(j0, j1):
        t = np.int32(glob.truth[i, j])
        reading = t ^ ((_flip_draw(key, cell_row + np.uint64(j)) - thr) >> 31 & 1)  # flip when draw < thr
        readings[i - r0, j - c0] = reading
        d = inc * (2 * reading - 1)
        base = level_base + reading * TABLE_SIZE
        old, _, ch = _fold(glob.logodds, i, j, d)
        row = base + old + OFFSET
        g_went += gstep[row, G_REWARD]
        de = gstep[row, G_ENTROPY]
        gs_ent += de
        dp = gstep[row, G_PROB]
        gs_prob += dp
        gs_prob_true += dp * t
        g_pp += ch
        g_tp += ch * t
        g_ent_true += de * t
        gs_cov += 1 - np.int32(glob.measured[i, j])
        glob.measured[i, j] = 1
        old, _, ch = _fold(local, i, j, d)
        row = base + old + OFFSET
        de = lstep[row, L_ENTROPY]
        ls_ent += de
        ls_prob += lstep[row, L_PROB]
        l_pp += ch
        l_tp += ch * t
        l_ent_true += de * t
        acc = _gain_step(acc, lstep, row)
        s_read += reading
    seg = (gs_prob, gs_ent, gs_cov, gs_prob_true, ls_prob, ls_ent, s_read, acc)
    return seg, (g_went, g_ent_true, g_tp, g_pp, l_ent_true, l_tp, l_pp)


@numba.njit(cache=True, fastmath=True)
def sense(
    u: int,
    fp: Rect,
    level: int,
    key: np.uint64,
    tables: Tables,
    geo: Geometry,
    glob: GlobalMaps,
    loc: LocalMaps,
    comm: CommState,
) -> None:
    """UAV ``u``'s measurement over its footprint ``fp`` = (r0, r1, c0, c1) at altitude ``level``:
    fold the readings into the global map and into the UAV's own M_i (the same readings, the same
    increments, one pass), store them in ``comm.readings[u]`` (footprint-relative) for the
    messages, and keep every derived sum up to date. ``key``: the UAV's flip stream this step
    (:func:`stream_key`); a cell's reading depends on (key, cell) only.

    The footprint is walked segment by segment (cells sharing a lattice block, a comm cell and a
    gain strip): the per-segment sums live in registers and are flushed once per segment into
    ``glob.block``, ``loc.block[u]``, ``loc.fine[u]``, ``loc.strip[u]`` and ``comm.comm_sum/comm_cnt`` (the UAV's
    own sensor map); the footprint's scalars go to ``glob.scal`` and ``loc.scal[u]`` at the end.
    """
    r0, r1, c0, c1 = fp
    inc, thr = np.int32(tables.increments[level]), np.int32(tables.thresholds[level])
    ctx = (r0, c0, inc, thr, 2 * level * TABLE_SIZE, key)
    local, readings, l_block, l_strip = loc.logodds[u], comm.readings[u], loc.block[u], loc.strip[u]
    l_fine = loc.fine[u]
    tot = (0.0, 0.0, 0, 0, 0.0, 0, 0)
    for i in range(r0, r1):
        bi, ci, gi = geo.block_of_cell[i], geo.comm_of_cell[i], geo.strip_of_cell[i]
        s = geo.seg_of_cell[c0]
        while geo.seg_start[s] < c1:
            j0, j1 = geo.seg_start[s], geo.seg_start[s + 1]
            seg, tot = _sense_run(i, j0, j1, ctx, tables, glob, local, readings, tot)
            gs_prob, gs_ent, gs_cov, gs_prob_true, ls_prob, ls_ent, s_read, acc = seg
            bj = geo.seg_block[s]
            glob.block[0, bi, bj] += gs_prob
            glob.block[1, bi, bj] += gs_ent
            glob.block[2, bi, bj] += gs_cov
            glob.block[3, bi, bj] += gs_prob_true
            l_block[0, bi, bj] += ls_prob
            l_block[1, bi, bj] += ls_ent
            _flush_gains(l_strip, gi, geo.seg_strip[s], acc)
            cj = geo.seg_comm[s]
            l_fine[0, ci, cj] += ls_prob
            l_fine[1, ci, cj] += ls_ent
            comm.comm_sum[ci, cj] += s_read
            comm.comm_cnt[ci, cj] += j1 - j0
            s += 1
    g_went, g_ent_true, g_tp, g_pp, l_ent_true, l_tp, l_pp = tot
    glob.scal[S_REWARD] += g_went
    glob.scal[S_ENT_TRUE] += g_ent_true
    glob.scal[S_TP] += g_tp
    glob.scal[S_PP] += g_pp
    loc.scal[u, 0] += l_ent_true
    loc.scal[u, 1] += l_tp
    loc.scal[u, 2] += l_pp


@numba.njit(cache=True, inline="always")
def _decode(value: float, inc: int, incf: float, soft: bool) -> int:
    """Log-odds change of one received cell ``I_r = value`` (decision 7): ``soft`` folds the
    evidence ``clip(I_r, 0, 1)`` as ``round(inc (2 e - 1))``; otherwise ``+-inc`` by ``I_r > 0.5``."""
    if soft:
        e = min(max(value, 0.0), 1.0)
        return np.int32(incf * (2.0 * e - 1.0) + (CLAMP + 0.5)) - CLAMP  # round half up (truncation of a positive)
    return inc * (2 * np.int32(value > 0.5) - 1)


@numba.njit(cache=True, inline="always")
def _receive_run(
    i: int,
    j0: int,
    j1: int,
    ctx: tuple,
    tables: Tables,
    truth: np.ndarray,
    local: np.ndarray,
    readings: np.ndarray,
    tot: tuple,
) -> tuple[tuple, tuple]:
    """Decode cells ``j0..j1`` of row ``i`` (one segment) of a message into the receiver's M_r.
    ``ctx``: (r0, c0, increment, alpha_low, 1 - alpha_low, sigma, soft, channel key); ``tot``:
    the message's running scalars, carried cell by cell. Returns the segment's sums (local
    prob / entropy, sum of ``I_r``, gains) and ``tot``."""
    r0, c0, inc, alpha_low, spread, sigma, soft, key = ctx
    l_ent_true, l_tp, l_pp = tot
    ltab, normals = tables.ltab, tables.normals
    incf = float(inc)
    ls_prob = ls_ent = s_val = 0.0
    acc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    cell_row = np.uint64(i * truth.shape[1])
    for j in range(j0, j1):
        a, noise = _channel_draw(key, cell_row + np.uint64(j), alpha_low, spread, sigma, normals)
        value = a * float(readings[i - r0, j - c0]) + noise
        s_val += value
        t = np.int32(truth[i, j])
        old, new, ch = _fold(local, i, j, _decode(value, inc, incf, soft))
        io, inw = old + OFFSET, new + OFFSET
        de = ltab[inw, L_ENTROPY] - ltab[io, L_ENTROPY]
        ls_ent += de
        ls_prob += ltab[inw, L_PROB] - ltab[io, L_PROB]
        l_pp += ch
        l_tp += ch * t
        l_ent_true += de * t
        acc = _gain_delta(acc, ltab, io, inw)
    return (ls_prob, ls_ent, s_val, acc), (l_ent_true, l_tp, l_pp)


@numba.njit(cache=True, fastmath=True)
def receive(
    r: int,
    s: int,
    fp: Rect,
    level: int,
    key: np.uint64,
    channel: Channel,
    tables: Tables,
    geo: Geometry,
    glob: GlobalMaps,
    loc: LocalMaps,
    comm: CommState,
) -> None:
    """Receiver ``r`` decodes sender ``s``'s message (footprint ``fp`` at the sender's altitude
    ``level``) into its M_r.

    The sender's 0/1 image ``comm.readings[s]`` arrives cell by cell as ``I_r = a I + n``,
    ``a ~ U(channel.bound[r, s], 1)``, ``n ~ N(0, sigma^2)``, both from a hash of ``key`` (the
    link's stream this step) and the cell index, and is folded with the sender's increment
    (:func:`_decode`). ``comm.comm_sum/comm_cnt`` receive ``I_r`` per comm cell (the received
    sensor map). ``glob.truth`` is read only for the team metrics.
    """
    r0, r1, c0, c1 = fp
    alpha_low = channel.bound[r, s]
    inc = np.int32(tables.increments[level])
    ctx = (r0, c0, inc, alpha_low, 1.0 - alpha_low, channel.sigma, channel.soft, key)
    local, readings, l_block, l_strip = loc.logodds[r], comm.readings[s], loc.block[r], loc.strip[r]
    l_fine = loc.fine[r]
    tot = (0.0, 0, 0)
    for i in range(r0, r1):
        gi, ci = geo.strip_of_cell[i], geo.comm_of_cell[i]
        bi = geo.seg_block[geo.seg_of_cell[i]]
        seg = geo.seg_of_cell[c0]
        while geo.seg_start[seg] < c1:
            j0, j1 = geo.seg_start[seg], geo.seg_start[seg + 1]
            sums, tot = _receive_run(i, j0, j1, ctx, tables, glob.truth, local, readings, tot)
            ls_prob, ls_ent, s_val, acc = sums
            bj = geo.seg_block[seg]
            l_block[0, bi, bj] += ls_prob
            l_block[1, bi, bj] += ls_ent
            _flush_gains(l_strip, gi, geo.seg_strip[seg], acc)
            cj = geo.seg_comm[seg]
            l_fine[0, ci, cj] += ls_prob
            l_fine[1, ci, cj] += ls_ent
            comm.comm_sum[ci, cj] += s_val
            comm.comm_cnt[ci, cj] += j1 - j0
            seg += 1
    l_ent_true, l_tp, l_pp = tot
    loc.scal[r, 0] += l_ent_true
    loc.scal[r, 1] += l_tp
    loc.scal[r, 2] += l_pp


@numba.njit(cache=True)
def measure_and_communicate(
    seed: np.uint64,
    step: int,
    pos: np.ndarray,
    channel: Channel,
    tables: Tables,
    geo: Geometry,
    glob: GlobalMaps,
    loc: LocalMaps,
    comm: CommState,
) -> None:
    """A whole step of sensing and messaging in one call (numba's per-call overhead is paid once
    per step): every UAV measures, then every message ``channel.links[r, s]`` (r != s) is
    delivered. ``seed``, ``step``: the mission seed and step index that key every draw.

    ``comm.slots[r, s]`` is where receiver r keeps sender s's map in ``comm.received[r]``; slot 0
    is the UAV's own clean sensor map.
    """
    n = pos.shape[0]
    for u in range(n):
        fp, lev = _footprint(geo, pos, u)
        sense(u, fp, lev, stream_key(seed, DOMAIN_FLIP, step, u, 0), tables, geo, glob, loc, comm)
        _flush_comm(comm, geo, comm.received[u, 0], fp)
    for s in range(n):
        fp, lev = _footprint(geo, pos, s)
        for r in range(n):
            if r == s or not channel.links[r, s]:
                continue
            key = stream_key(seed, DOMAIN_CHANNEL, step, s, r)
            receive(r, s, fp, lev, key, channel, tables, geo, glob, loc, comm)
            slot = comm.slots[r, s]
            comm.received_valid[r, slot] = 1.0
            _flush_comm(comm, geo, comm.received[r, slot], fp)


@numba.njit(cache=True)
def action_gains(pos, masks, deltas, footprint_strips, l_strip, n_levels, out):
    """Each UAV's expected information gain of each action's footprint, from its own M_i.

    ``l_strip[u, w * 3 + a]`` holds per strip cell the gain of a reading at altitude level a
    under weighting w; a footprint's gain is the sum over its strip rectangle (exact: footprints
    are unions of strips). ``out[u, w, a]`` is divided by the largest absolute gain over the valid
    actions (the best valid action scores 1); invalid actions score 0.
    """
    n = pos.shape[0]
    lat = footprint_strips.shape[0]
    n_w = out.shape[1]
    for u in range(n):
        for w in range(n_w):
            scale = 0.0
            for act in range(deltas.shape[0]):
                out[u, w, act] = 0.0
                if masks[u, act] == 0:
                    continue
                x = min(max(pos[u, 0] + deltas[act, 0], 0), lat - 1)
                y = min(max(pos[u, 1] + deltas[act, 1], 0), lat - 1)
                z = min(max(pos[u, 2] + deltas[act, 2], 0), n_levels - 1)
                col = w * (GAIN_SLOTS // n_w) + z
                total = 0.0
                for gi in range(footprint_strips[y, z, 0], footprint_strips[y, z, 1]):
                    for gj in range(footprint_strips[x, z, 0], footprint_strips[x, z, 1]):
                        total += l_strip[u, col, gi, gj]
                out[u, w, act] = total
                scale = max(scale, abs(total))
            if scale > 0.0:
                for act in range(deltas.shape[0]):
                    out[u, w, act] /= scale


@numba.njit(cache=True)
def action_masks(pos, no_fly, n_levels, deltas, out):
    """(N, 6) validity of each action from the current positions (see ``UavIppEnv.action_masks``)."""
    n = pos.shape[0]
    lat = no_fly.shape[0]
    for i in range(n):
        any_valid = False
        for a in range(deltas.shape[0]):
            x = pos[i, 0] + deltas[a, 0]
            y = pos[i, 1] + deltas[a, 1]
            z = pos[i, 2] + deltas[a, 2]
            ok = 0 <= x < lat and 0 <= y < lat and 0 <= z < n_levels
            if ok:
                ok = not no_fly[y, x]
            if ok and (deltas[a, 0] != 0 or deltas[a, 1] != 0):
                for j in range(n):
                    if j != i and pos[j, 0] == x and pos[j, 1] == y:
                        ok = False
                        break
            out[i, a] = 1 if ok else 0
            any_valid = any_valid or ok
        if not any_valid:
            out[i, 0] = 1


@numba.njit(cache=True)
def apply_actions(pos, actions, no_fly, n_levels, deltas, executed):
    """Move UAVs in id order; a move that is invalid when executed hovers instead."""
    n = pos.shape[0]
    lat = no_fly.shape[0]
    for i in range(n):
        a = actions[i]
        x = pos[i, 0] + deltas[a, 0]
        y = pos[i, 1] + deltas[a, 1]
        z = pos[i, 2] + deltas[a, 2]
        executed[i] = False
        if not (0 <= x < lat and 0 <= y < lat and 0 <= z < n_levels) or no_fly[y, x]:
            continue
        blocked = False
        if deltas[a, 0] != 0 or deltas[a, 1] != 0:
            for j in range(n):
                if j != i and pos[j, 0] == x and pos[j, 1] == y:
                    blocked = True
                    break
        if blocked:
            continue
        pos[i, 0] = x
        pos[i, 1] = y
        pos[i, 2] = z
        executed[i] = True
