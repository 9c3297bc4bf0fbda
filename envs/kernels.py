"""Hot-path kernels: one fused pass over the cells a footprint covers.

Why it looks like this (measured, see ``benchmarks/env_throughput.py``): a plain numpy footprint
update walks the footprint a dozen times (draw flips, read, update log-odds, two entropy
evaluations, class weights, block sums, ...) and tops out near 500 joint steps/s. Here each
covered cell is visited once, inside numba, and every per-cell quantity comes from a lookup
table:

* the global belief is stored as fixed-point log-odds (``int16``, 1/1024 units, clamped at
  +-31), so entropy, class-weighted entropy and probability of a cell are table look-ups;
* sensor flips come from a per-environment xorshift64* stream (seeded from the env's
  ``numpy.random.Generator`` at every reset, so episodes are reproducible);
* everything the observations and the reward need (block sums of probability, entropy and
  coverage on the 11 x 11 lattice, the class-weighted entropy total, F1 counts, the entropy over
  valuable cells, comm-grid reading sums) is updated incrementally in the same pass.
"""
from __future__ import annotations

import math

import numba
import numpy as np

#: Fixed-point scale of the global log-odds: value / SCALE = log-odds.
SCALE = 1024
#: Saturation of the global log-odds (about +-31.25, p within 3e-14 of 0 or 1).
CLAMP = 32000
LUT_OFFSET = 32768
LUT_SIZE = 65536
#: Class-weighting thresholds of ipp-marl: believed valuable above, not valuable below.
WEIGHT_HIGH = 0.501
WEIGHT_LOW = 0.499
#: Probability clip of ipp-marl's entropy inside the weighted entropy.
ENTROPY_CLIP = 1e-4


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


REWARD_ENTROPIES = ("plain", "weighted")


def reward_entropy(p: np.ndarray, kind: str = "plain") -> np.ndarray:
    """Per-cell entropy that the reward sums: ``plain`` binary entropy or ipp-marl's ``weighted``."""
    if kind == "weighted":
        return weighted_entropy(p)
    if kind == "plain":
        return binary_entropy(p)
    raise ValueError(f"unknown reward entropy {kind!r}; choose one of {REWARD_ENTROPIES}")


def build_table(kind: str = "plain") -> np.ndarray:
    """Packed look-up table over every int16 log-odds value.

    Row ``v + 32768`` holds (reward entropy, entropy in bits, probability, 0) of the log-odds
    ``v / SCALE``; float32 keeps the table at 1 MiB, sums are accumulated in float64.
    """
    values = (np.arange(LUT_SIZE, dtype=np.float64) - LUT_OFFSET) / SCALE
    p = 1.0 / (1.0 + np.exp(-values))
    table = np.zeros((LUT_SIZE, 4), dtype=np.float32)
    table[:, 0] = reward_entropy(p, kind)
    table[:, 1] = binary_entropy(p)
    table[:, 2] = p
    return table


def fixed_point_increment(flip_probability: float) -> int:
    """Log-odds increment log((1-q)/q) of a reading, in fixed-point units."""
    return int(round(math.log((1.0 - flip_probability) / flip_probability) * SCALE))


def flip_threshold(flip_probability: float) -> int:
    """A reading flips when a uniform 16-bit integer is below this threshold."""
    return int(round(flip_probability * 65536.0))


@numba.njit(cache=True, inline="always")
def _next(state: np.ndarray) -> np.uint64:
    """xorshift64* step; returns the scrambled output and advances ``state[0]``."""
    x = state[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    state[0] = x
    return x * np.uint64(0x2545F4914F6CDD1D)


@numba.njit(cache=True)
def uniform(state: np.ndarray) -> float:
    """A uniform float in [0, 1) from the stream."""
    return float(_next(state) >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True, fastmath=True)
def measure_global(logodds, truth, measured, r0, r1, c0, c1, increment, threshold, state, lut,
                   block_of_cell, comm_of_cell, block_prob, block_ent, block_cov, comm_sum, comm_cnt):
    """Take one noisy measurement over a footprint and fold it into the global belief.

    ``lut`` is the packed (65536, 4) float32 table of (reward entropy, entropy, probability, 0)
    per fixed-point log-odds value: one cache line serves all three look-ups of a cell.
    Returns (change of the reward-entropy total, change of the entropy summed over
    valuable cells, change of true positives, change of predicted positives). Block sums and the
    footprint's readings per comm-grid cell are accumulated in place; per-cell sums are flushed
    once per run of cells that share a block and a comm cell, so no store-to-load chain
    serialises the loop. The loop body is branch-free: the readings are random and a branch on
    them would be mispredicted a third of the time.
    """
    d_went = 0.0
    d_ent_true = 0.0
    d_tp = 0
    d_pp = 0
    inc = np.int32(increment)
    thr = np.int32(threshold)
    x = state[0]
    have = 0
    bits = np.uint64(0)
    for i in range(r0, r1):
        bi = block_of_cell[i]
        ci = comm_of_cell[i]
        j = c0
        while j < c1:
            bj = block_of_cell[j]
            cj = comm_of_cell[j]
            e = j + 1
            while e < c1 and block_of_cell[e] == bj and comm_of_cell[e] == cj:
                e += 1
            s_prob = 0.0
            s_ent = 0.0
            s_cov = np.int32(0)
            s_read = np.int32(0)
            for jj in range(j, e):
                if have == 0:
                    x ^= x >> np.uint64(12)
                    x ^= x << np.uint64(25)
                    x ^= x >> np.uint64(27)
                    bits = x * np.uint64(0x2545F4914F6CDD1D)
                    have = 4
                r = np.int32(bits & np.uint64(0xFFFF))
                bits >>= np.uint64(16)
                have -= 1
                t = np.int32(truth[i, jj])
                reading = t ^ ((r - thr) >> 31 & 1)  # flip when r < thr
                old = np.int32(logodds[i, jj])
                new = min(max(old + inc * (2 * reading - 1), -CLAMP), CLAMP)
                logodds[i, jj] = new
                io = old + LUT_OFFSET
                inw = new + LUT_OFFSET
                d_went += lut[inw, 0] - lut[io, 0]
                de = lut[inw, 1] - lut[io, 1]
                s_ent += de
                s_prob += lut[inw, 2] - lut[io, 2]
                ch = np.int32(new > 0) - np.int32(old > 0)
                d_pp += ch
                d_ent_true += de * t
                d_tp += ch * t
                s_cov += 1 - np.int32(measured[i, jj])
                measured[i, jj] = 1
                s_read += reading
            block_ent[bi, bj] += s_ent
            block_prob[bi, bj] += s_prob
            block_cov[bi, bj] += s_cov
            comm_sum[ci, cj] += s_read
            comm_cnt[ci, cj] += e - j
            j = e
    state[0] = x
    return d_went, d_ent_true, d_tp, d_pp


@numba.njit(cache=True)
def communicate(sender, fresh, fresh_mask, cr0, cr1, cc0, cc1, increment, receivers, distances,
                comm_range, noise_low, noise_sigma, slots, received, received_valid,
                local_logodds, local_prob, local_ent, lattice_agg, comm_blocks, comm_weights, state):
    """Deliver a sender's fresh comm-grid patch to its receivers and update their local beliefs.

    ``fresh``/``fresh_mask`` hold the sender's clean readings (fraction of valuable readings per
    comm cell) on the cells its footprint covered this step. A receiver ``r`` with
    ``receivers[r]`` true gets ``a * I + n`` (a ~ U(lo(d), 1), n ~ N(0, sigma^2); lo falls
    linearly from 1 at distance 0 to ``noise_low`` at ``comm_range``) written into its copy of the
    sender's map, and folds the received value into its local log-odds as soft evidence. The
    sender itself (``r == sender``) uses its clean data. The receivers' probability and entropy
    maps are refreshed on the touched cells only, and so are their 11 x 11 area-weighted block
    means ``lattice_agg[r, (sensor, belief, entropy)]`` (each comm cell overlaps at most two
    blocks per axis: ``comm_blocks``/``comm_weights``), so observations never recompute maps.
    """
    inv_ln2 = 1.0 / math.log(2.0)
    n = receivers.shape[0]
    for r in range(n):
        if not receivers[r]:
            continue
        slot = slots[r, sender]
        received_valid[r, slot] = 1.0
        own = r == sender
        if own or comm_range <= 0.0 or not math.isfinite(comm_range):
            frac = 1.0 if own else 0.0
        else:
            frac = min(distances[r] / comm_range, 1.0)
        low = 1.0 - (1.0 - noise_low) * frac
        for i in range(cr0, cr1):
            for j in range(cc0, cc1):
                if not fresh_mask[i, j]:
                    continue
                value = fresh[i, j]
                if not own:
                    a = low + (1.0 - low) * uniform(state)
                    noise = 0.0
                    if noise_sigma > 0.0:
                        u1 = uniform(state)
                        u2 = uniform(state)
                        noise = noise_sigma * math.sqrt(-2.0 * math.log(1.0 - u1)) * math.cos(2.0 * math.pi * u2)
                    value = min(max(a * value + noise, -0.5), 1.5)
                d_sensor = value - received[r, slot, i, j]
                received[r, slot, i, j] = value
                evidence = min(max(value, 0.0), 1.0)
                lo = local_logodds[r, i, j] + increment * (2.0 * evidence - 1.0)
                if lo > 30.0:
                    lo = 30.0
                elif lo < -30.0:
                    lo = -30.0
                local_logodds[r, i, j] = lo
                ax = abs(lo)
                ex = math.exp(-ax)
                p = 1.0 / (1.0 + ex)
                if lo < 0.0:
                    p = 1.0 - p
                h = (math.log1p(ex) + ax * ex / (1.0 + ex)) * inv_ln2
                d_prob = p - local_prob[r, i, j]
                d_ent = h - local_ent[r, i, j]
                local_prob[r, i, j] = p
                local_ent[r, i, j] = h
                for a in range(2):
                    wa = comm_weights[i, a]
                    if wa == 0.0:
                        continue
                    ka = comm_blocks[i, a]
                    for b in range(2):
                        w = wa * comm_weights[j, b]
                        if w == 0.0:
                            continue
                        kb = comm_blocks[j, b]
                        if own:
                            lattice_agg[r, 0, ka, kb] += w * d_sensor
                        lattice_agg[r, 1, ka, kb] += w * d_prob
                        lattice_agg[r, 2, ka, kb] += w * d_ent


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
