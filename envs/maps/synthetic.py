"""Env1: a star-shaped valuable region with random structure, drawn from a seed.

The paper's Env1 is a hand-drawn star with "a certain degree of random structure". We draw one
procedurally so that every seed gives a different star (an agent that only memorised one star
would not generalise) while the same seed always gives the same one (evaluation trials must be
repeatable):

* 5-8 arms at roughly even angles, each with its own length and tip width, so no two arms match;
* a wobbly outline (each edge is split and its midpoints pushed in or out), like a hand drawing;
* the whole star is rescaled to cover a random 24-36 % of the field before the extras below, so
  the valuable fraction stays in a range where both classes matter to F1 and entropy;
* a few satellite blobs (valuable) and holes (not valuable) add structure away from the arms.

Everything is one ``cv2.fillPoly`` plus a handful of ``cv2.ellipse`` calls on a uint8 canvas:
about 0.2 ms at 493 x 493, so the environment can draw a fresh star at every reset.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

#: Accepted valuable fraction of a star; draws outside are redrawn from the same generator
#: (deterministic per seed). The brief asks for roughly 20-45 %.
MIN_FRACTION = 0.20
MAX_FRACTION = 0.45
#: Fixed-point bits for cv2 drawing: sub-pixel vertices keep small grids from looking blocky.
_SHIFT = 4
_ONE = 1 << _SHIFT


def _outline(rng: np.random.Generator, grid: int) -> tuple[np.ndarray, np.ndarray]:
    """Centre (2,) and closed star outline (P, 2) in pixel units, before area normalisation."""
    centre = grid * (0.5 + rng.uniform(-0.07, 0.07, size=2))
    n_arms = int(rng.integers(5, 9))
    step = 2.0 * math.pi / n_arms
    start = rng.uniform(0.0, 2.0 * math.pi)
    tips = start + step * np.arange(n_arms) + rng.uniform(-0.22, 0.22, n_arms) * step
    lengths = rng.uniform(0.55, 1.0, n_arms)  # irregular arm lengths (relative)
    half_tip = rng.uniform(0.03, 0.16, n_arms) * step  # irregular arm widths at the tip
    valleys = rng.uniform(0.18, 0.38, n_arms)  # depth between arms (relative radius)
    corners: list[tuple[float, float]] = []  # (angle, radius) around the centre
    for i in range(n_arms):
        nxt = tips[(i + 1) % n_arms] + (2.0 * math.pi if i == n_arms - 1 else 0.0)
        corners.append((tips[i] - half_tip[i], lengths[i] * rng.uniform(0.88, 1.0)))
        corners.append((tips[i] + half_tip[i], lengths[i] * rng.uniform(0.88, 1.0)))
        corners.append((0.5 * (tips[i] + nxt) + rng.uniform(-0.15, 0.15) * step, valleys[i]))
    ang = np.array([a for a, _ in corners])
    rad = np.array([r for _, r in corners])
    pts = np.stack([np.cos(ang) * rad, np.sin(ang) * rad], axis=1)
    # wobble: split every edge in three and push the inner points sideways by a few per cent
    a, b = pts, np.roll(pts, -1, axis=0)
    edge = b - a
    normal = np.stack([-edge[:, 1], edge[:, 0]], axis=1)
    wobble = rng.normal(0.0, 0.06, size=(len(pts), 2))
    p1 = a + edge / 3.0 + normal * wobble[:, :1]
    p2 = a + 2.0 * edge / 3.0 + normal * wobble[:, 1:]
    outline = np.stack([a, p1, p2], axis=1).reshape(-1, 2)
    return centre, outline


def _polygon_area(points: np.ndarray) -> float:
    """Shoelace area; used to scale the star to its target coverage before drawing."""
    x, y = points[:, 0], points[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _draw_once(rng: np.random.Generator, grid: int) -> np.ndarray:
    """One star on a uint8 canvas (1 = valuable)."""
    canvas = np.zeros((grid, grid), dtype=np.uint8)
    centre, outline = _outline(rng, grid)
    target = rng.uniform(0.24, 0.36) * grid * grid
    outline = outline * math.sqrt(target / max(_polygon_area(outline), 1e-12)) + centre
    cv2.fillPoly(canvas, [np.round(outline * _ONE).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=_SHIFT)
    for _ in range(int(rng.integers(1, 4))):  # satellite blobs, anywhere
        c = rng.uniform(0.08, 0.92, size=2) * grid
        axes = rng.uniform(0.025, 0.07, size=2) * grid
        _ellipse(canvas, c, axes, rng.uniform(0, 180), 1)
    for _ in range(int(rng.integers(1, 4))):  # holes, on the way out along an arm
        k = int(rng.integers(len(outline)))
        c = centre + rng.uniform(0.25, 0.7) * (outline[k] - centre)
        axes = rng.uniform(0.015, 0.045, size=2) * grid
        _ellipse(canvas, c, axes, rng.uniform(0, 180), 0)
    return canvas


def _ellipse(canvas: np.ndarray, centre: np.ndarray, axes: np.ndarray, angle: float, value: int) -> None:
    cv2.ellipse(
        canvas,
        (round(float(centre[0] * _ONE)), round(float(centre[1] * _ONE))),
        (max(round(float(axes[0] * _ONE)), 1), max(round(float(axes[1] * _ONE)), 1)),
        float(angle),
        0.0,
        360.0,
        value,
        -1,
        cv2.LINE_8,
        _SHIFT,
    )


def draw_star(rng: np.random.Generator, grid: int = 493) -> np.ndarray:
    """Boolean (grid, grid) star drawn from ``rng``; row = y, column = x.

    Redraws (from the same generator, so still deterministic) in the rare case that borders,
    blobs and holes push the valuable fraction outside [MIN_FRACTION, MAX_FRACTION].
    """
    canvas = _draw_once(rng, grid)
    for _ in range(20):
        frac = float(canvas.mean())
        if MIN_FRACTION <= frac <= MAX_FRACTION:
            break
        canvas = _draw_once(rng, grid)
    return canvas.astype(bool)


def star_map(seed: int | None, grid: int = 493) -> np.ndarray:
    """The env1 star for ``seed`` (``None``: fresh OS entropy, a new star every call)."""
    return draw_star(np.random.default_rng(seed), grid)
