"""Hot-path kernels: one fused pass over the cells a footprint covers, per belief it changes.

Why it looks like this (measured, ``benchmarks/env_throughput.py``, docs/environment.md):

* every belief (the global map and each UAV's local map M_i) is stored as fixed-point log-odds,
  ``int16`` in 1/64 units clamped at +-31.25. Everything the env derives from a cell (probability,
  entropy, class-weighted entropy, expected information gain of a reading at each altitude) is
  then one row of a small table (4001 rows: 64-160 KB, resident in L2), never a logarithm;
* a footprint is walked *segment* by segment (runs of cells sharing a lattice block, a comm cell
  and a gain strip, :class:`envs.geometry.FieldGeometry`), and running sums are flushed once per
  segment, so no store-to-load chain serialises the loop;
* the sender's pass updates the global map and its own M_i from the same readings in one go;
  each receiver's pass decodes the sender's noisy image into its M_i;
* sensor flips come from an xorshift64* stream; channel noise from a counter-based hash of
  (message key, cell index) with a 4096-level normal quantile table, so the noise of a cell does
  not depend on the order cells are visited and no transcendental function runs per cell.

Streams are seeded from the env's ``numpy.random.Generator`` at every reset: same seed, same
mission, bit for bit.
"""

from __future__ import annotations

import math
from statistics import NormalDist

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
# Columns of the local table: probability, entropy, then the gains (see envs.gain).
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
    return int(round(math.log((1.0 - flip_probability) / flip_probability) * SCALE))


def flip_threshold(flip_probability: float) -> int:
    """A reading flips when a uniform 16-bit integer is below this threshold."""
    return int(round(flip_probability * 65536.0))


def normal_table() -> np.ndarray:
    """(NORMAL_LEVELS,) float32 standard-normal quantiles at (k + 0.5) / NORMAL_LEVELS (|z| <= 3.5)."""
    dist = NormalDist()
    return np.array([dist.inv_cdf((k + 0.5) / NORMAL_LEVELS) for k in range(NORMAL_LEVELS)], dtype=np.float32)


@numba.njit(cache=True, inline="always")
def _next(state: np.ndarray) -> np.uint64:
    """xorshift64* step; returns the scrambled output and advances ``state[0]``."""
    x = state[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    state[0] = x
    return x * np.uint64(0x2545F4914F6CDD1D)


@numba.njit(cache=True, inline="always")
def _hash(key: np.uint64, counter: np.uint64) -> np.uint64:
    """splitmix64 finaliser of ``key + counter``: independent 64 random bits per counter."""
    z = key + counter * np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


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


@numba.njit(cache=True)
def _flush_comm(received, slot_map, comm_sum, comm_cnt, comm_area, ca, cb, cc, cd):
    """Write the comm-grid averages of this message into ``slot_map`` where at least half of a comm
    cell was covered (the rest keeps what it had), then zero the scratch sums for the next message."""
    for ci in range(ca, cb):
        for cj in range(cc, cd):
            cnt = comm_cnt[ci, cj]
            if 2.0 * cnt >= comm_area[ci, cj]:
                slot_map[ci, cj] = min(max(comm_sum[ci, cj] / cnt, -0.5), 1.5)
            comm_sum[ci, cj] = 0.0
            comm_cnt[ci, cj] = 0.0


@numba.njit(cache=True, fastmath=True)
def sense(
    r0,
    r1,
    c0,
    c1,
    level,
    increment,
    threshold,
    truth,
    glob,
    measured,
    local,
    readings,
    gstep,
    lstep,
    seg_start,
    seg_of_cell,
    seg_block,
    seg_comm,
    seg_strip,
    block_of_cell,
    comm_of_cell,
    strip_of_cell,
    flip_state,
    g_block,
    g_scal,
    l_block,
    l_strip,
    l_scal,
    comm_sum,
    comm_cnt,
):
    """One UAV's measurement over a footprint: fold the readings into the global map and into the
    UAV's own local map M_i (the same readings, the same increments), store them in ``readings``
    (footprint-relative) for the messages, and keep every derived sum up to date.

    Global sums: ``g_block[(prob, entropy, coverage), bi, bj]`` and ``g_scal`` (reward-entropy total,
    entropy over valuable cells, true and predicted positives). Local sums: ``l_block[(prob,
    entropy)]``, ``l_strip[k, gi, gj]`` (gain column k of ``ltab`` per strip cell) and ``l_scal``
    (entropy over valuable cells, true and predicted positives). ``comm_sum/comm_cnt`` receive the
    readings per comm cell (the UAV's own sensor map).
    """
    inc = np.int32(increment)
    thr = np.int32(threshold)
    level_base = 2 * level * TABLE_SIZE
    x = flip_state[0]
    have = 0
    bits = np.uint64(0)
    g_went = 0.0
    g_ent_true = 0.0
    g_tp = 0
    g_pp = 0
    l_ent_true = 0.0
    l_tp = 0
    l_pp = 0
    for i in range(r0, r1):
        bi = block_of_cell[i]
        ci = comm_of_cell[i]
        gi = strip_of_cell[i]
        s = seg_of_cell[c0]
        while seg_start[s] < c1:
            j0 = seg_start[s]
            j1 = seg_start[s + 1]
            gs_prob = 0.0
            gs_ent = 0.0
            gs_cov = 0
            ls_prob = 0.0
            ls_ent = 0.0
            s_read = 0
            acc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            for j in range(j0, j1):
                if have == 0:
                    x ^= x >> np.uint64(12)
                    x ^= x << np.uint64(25)
                    x ^= x >> np.uint64(27)
                    bits = x * np.uint64(0x2545F4914F6CDD1D)
                    have = 4
                r = np.int32(bits & np.uint64(0xFFFF))
                bits >>= np.uint64(16)
                have -= 1
                t = np.int32(truth[i, j])
                reading = t ^ ((r - thr) >> 31 & 1)  # flip when r < thr
                readings[i - r0, j - c0] = reading
                d = inc * (2 * reading - 1)
                base = level_base + reading * TABLE_SIZE
                # global map
                old = np.int32(glob[i, j])
                new = _clamp(old + d)
                glob[i, j] = new
                row = base + old + OFFSET
                g_went += gstep[row, G_REWARD]
                de = gstep[row, G_ENTROPY]
                gs_ent += de
                gs_prob += gstep[row, G_PROB]
                ch = np.int32(new > 0) - np.int32(old > 0)
                g_pp += ch
                g_tp += ch * t
                g_ent_true += de * t
                gs_cov += 1 - np.int32(measured[i, j])
                measured[i, j] = 1
                # own local map
                old = np.int32(local[i, j])
                new = _clamp(old + d)
                local[i, j] = new
                row = base + old + OFFSET
                de = lstep[row, L_ENTROPY]
                ls_ent += de
                ls_prob += lstep[row, L_PROB]
                ch = np.int32(new > 0) - np.int32(old > 0)
                l_pp += ch
                l_tp += ch * t
                l_ent_true += de * t
                acc = _gain_step(acc, lstep, row)
                s_read += reading
            bj = seg_block[s]
            g_block[0, bi, bj] += gs_prob
            g_block[1, bi, bj] += gs_ent
            g_block[2, bi, bj] += gs_cov
            l_block[0, bi, bj] += ls_prob
            l_block[1, bi, bj] += ls_ent
            gj = seg_strip[s]
            _flush_gains(l_strip, gi, gj, acc)
            cj = seg_comm[s]
            comm_sum[ci, cj] += s_read
            comm_cnt[ci, cj] += j1 - j0
            s += 1
    flip_state[0] = x
    g_scal[S_REWARD] += g_went
    g_scal[S_ENT_TRUE] += g_ent_true
    g_scal[S_TP] += g_tp
    g_scal[S_PP] += g_pp
    l_scal[0] += l_ent_true
    l_scal[1] += l_tp
    l_scal[2] += l_pp


@numba.njit(cache=True, fastmath=True)
def receive(
    r0,
    r1,
    c0,
    c1,
    increment,
    alpha_low,
    sigma,
    soft,
    key,
    truth,
    local,
    readings,
    ltab,
    normals,
    seg_start,
    seg_of_cell,
    seg_block,
    seg_comm,
    seg_strip,
    comm_of_cell,
    strip_of_cell,
    grid,
    l_block,
    l_strip,
    l_scal,
    comm_sum,
    comm_cnt,
):
    """One receiver decodes one sender's message into its local map M_r.

    The sender's 0/1 image ``readings`` arrives cell by cell as ``I_r = a I + n``, ``a ~ U(alpha_low,
    1)``, ``n ~ N(0, sigma^2)`` (both from a hash of ``key`` and the cell index). ``soft`` decoding
    folds the evidence ``clip(I_r, 0, 1)`` with the sender's altitude increment scaled by
    ``2 e - 1``; otherwise the reading is ``I_r > 0.5``. ``comm_sum/comm_cnt`` receive ``I_r`` per
    comm cell (the received sensor map). ``truth`` is read only for the team metrics.
    """
    inc = np.int32(increment)
    incf = float(increment)
    spread = 1.0 - alpha_low
    l_ent_true = 0.0
    l_tp = 0
    l_pp = 0
    for i in range(r0, r1):
        gi = strip_of_cell[i]
        ci = comm_of_cell[i]
        row = np.uint64(i * grid)
        bi = seg_block[seg_of_cell[i]]
        s = seg_of_cell[c0]
        while seg_start[s] < c1:
            j0 = seg_start[s]
            j1 = seg_start[s + 1]
            ls_prob = 0.0
            ls_ent = 0.0
            s_val = 0.0
            acc = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
            for j in range(j0, j1):
                h = _hash(key, row + np.uint64(j))
                a = alpha_low + spread * (float(np.int32(h & np.uint64(0xFFFF))) * (1.0 / 65536.0))
                noise = sigma * normals[np.int32(h >> np.uint64(16)) & np.int32(NORMAL_LEVELS - 1)]
                value = a * float(readings[i - r0, j - c0]) + noise
                if soft:
                    e = min(max(value, 0.0), 1.0)
                    d = (
                        np.int32(incf * (2.0 * e - 1.0) + (CLAMP + 0.5)) - CLAMP
                    )  # round half up (truncation of a positive)
                else:
                    d = inc * (2 * np.int32(value > 0.5) - 1)
                s_val += value
                t = np.int32(truth[i, j])
                old = np.int32(local[i, j])
                new = _clamp(old + d)
                local[i, j] = new
                io = old + OFFSET
                inw = new + OFFSET
                de = ltab[inw, L_ENTROPY] - ltab[io, L_ENTROPY]
                ls_ent += de
                ls_prob += ltab[inw, L_PROB] - ltab[io, L_PROB]
                ch = np.int32(new > 0) - np.int32(old > 0)
                l_pp += ch
                l_tp += ch * t
                l_ent_true += de * t
                acc = _gain_delta(acc, ltab, io, inw)
            bj = seg_block[s]
            l_block[0, bi, bj] += ls_prob
            l_block[1, bi, bj] += ls_ent
            gj = seg_strip[s]
            _flush_gains(l_strip, gi, gj, acc)
            cj = seg_comm[s]
            comm_sum[ci, cj] += s_val
            comm_cnt[ci, cj] += j1 - j0
            s += 1
    l_scal[0] += l_ent_true
    l_scal[1] += l_tp
    l_scal[2] += l_pp


@numba.njit(cache=True)
def measure_and_communicate(
    pos,
    ranges,
    increments,
    thresholds,
    links,
    alpha_low,
    sigma,
    soft,
    slots,
    truth,
    glob,
    measured,
    local,
    readings,
    gstep,
    lstep,
    ltab,
    normals,
    seg_start,
    seg_of_cell,
    seg_block,
    seg_comm,
    seg_strip,
    block_of_cell,
    comm_of_cell,
    strip_of_cell,
    comm_area,
    flip_state,
    comm_state,
    g_block,
    g_scal,
    l_block,
    l_strip,
    l_scal,
    received,
    received_valid,
    comm_sum,
    comm_cnt,
):
    """A whole step of sensing and messaging, in one call (the per-call overhead of numba is paid
    once per step): every UAV measures, then every message ``links[r, s]`` (r != s) is delivered.

    ``alpha_low[r, s]`` is the attenuation bound of the link (1 for none), ``slots[r, s]`` where
    receiver r keeps sender s's map in ``received[r]``.
    """
    n = pos.shape[0]
    grid = glob.shape[0]
    for u in range(n):
        lev = pos[u, 2]
        r0 = ranges[pos[u, 1], lev, 0]
        r1 = ranges[pos[u, 1], lev, 1]
        c0 = ranges[pos[u, 0], lev, 0]
        c1 = ranges[pos[u, 0], lev, 1]
        sense(
            r0,
            r1,
            c0,
            c1,
            lev,
            increments[lev],
            thresholds[lev],
            truth,
            glob,
            measured,
            local[u],
            readings[u],
            gstep,
            lstep,
            seg_start,
            seg_of_cell,
            seg_block,
            seg_comm,
            seg_strip,
            block_of_cell,
            comm_of_cell,
            strip_of_cell,
            flip_state,
            g_block,
            g_scal,
            l_block[u],
            l_strip[u],
            l_scal[u],
            comm_sum,
            comm_cnt,
        )
        _flush_comm(
            received[u],
            received[u, 0],
            comm_sum,
            comm_cnt,
            comm_area,
            comm_of_cell[r0],
            comm_of_cell[r1 - 1] + 1,
            comm_of_cell[c0],
            comm_of_cell[c1 - 1] + 1,
        )
    for s in range(n):
        lev = pos[s, 2]
        r0 = ranges[pos[s, 1], lev, 0]
        r1 = ranges[pos[s, 1], lev, 1]
        c0 = ranges[pos[s, 0], lev, 0]
        c1 = ranges[pos[s, 0], lev, 1]
        for r in range(n):
            if r == s or not links[r, s]:
                continue
            key = _next(comm_state)
            receive(
                r0,
                r1,
                c0,
                c1,
                increments[lev],
                alpha_low[r, s],
                sigma,
                soft,
                key,
                truth,
                local[r],
                readings[s],
                ltab,
                normals,
                seg_start,
                seg_of_cell,
                seg_block,
                seg_comm,
                seg_strip,
                comm_of_cell,
                strip_of_cell,
                grid,
                l_block[r],
                l_strip[r],
                l_scal[r],
                comm_sum,
                comm_cnt,
            )
            slot = slots[r, s]
            received_valid[r, slot] = 1.0
            _flush_comm(
                received[r],
                received[r, slot],
                comm_sum,
                comm_cnt,
                comm_area,
                comm_of_cell[r0],
                comm_of_cell[r1 - 1] + 1,
                comm_of_cell[c0],
                comm_of_cell[c1 - 1] + 1,
            )


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
