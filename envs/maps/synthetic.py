"""Env1: a synthetic star-shaped valuable region with random structure, drawn from a seed.

Fast by construction (one polygon fill and a few discs with OpenCV, ~1 ms at 493 x 493), because
``map_seed=None`` draws a fresh star at every reset.
"""
from __future__ import annotations

import cv2
import numpy as np


def star_map(seed: int, grid: int = 493) -> np.ndarray:
    """Boolean (grid, grid) star: 5-8 arms of random length and width, jittered outline, a few
    satellite blobs and holes. Same seed -> same map; a different seed -> a different star."""
    rng = np.random.default_rng(seed)
    image = np.zeros((grid, grid), dtype=np.uint8)
    centre = grid * (0.5 + rng.uniform(-0.08, 0.08, size=2))
    n_arms = int(rng.integers(5, 9))
    inner = grid * rng.uniform(0.15, 0.21)
    offset = rng.uniform(0, 2 * np.pi)
    points = []
    for k in range(n_arms):
        tip_angle = offset + 2 * np.pi * k / n_arms + rng.uniform(-0.15, 0.15)
        valley_angle = tip_angle + np.pi / n_arms
        tip = grid * rng.uniform(0.32, 0.48)
        half_width = rng.uniform(0.08, 0.18)
        for angle, radius in ((tip_angle - half_width, tip * rng.uniform(0.75, 0.9)),
                              (tip_angle, tip),
                              (tip_angle + half_width, tip * rng.uniform(0.75, 0.9)),
                              (valley_angle, inner * rng.uniform(0.8, 1.2))):
            points.append((centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle)))
    polygon = np.round(np.array(points)).astype(np.int32)
    cv2.fillPoly(image, [polygon], 1)
    for _ in range(int(rng.integers(2, 6))):  # satellite blobs
        c = rng.uniform(0.1, 0.9, size=2) * grid
        cv2.circle(image, (int(c[0]), int(c[1])), int(grid * rng.uniform(0.02, 0.06)), 1, -1)
    for _ in range(int(rng.integers(1, 4))):  # holes inside the star
        angle = rng.uniform(0, 2 * np.pi)
        radius = inner * rng.uniform(0.2, 1.5)
        c = centre + radius * np.array([np.cos(angle), np.sin(angle)])
        cv2.circle(image, (int(c[0]), int(c[1])), int(grid * rng.uniform(0.015, 0.04)), 0, -1)
    return image.astype(bool)
