"""RGB rendering of a mission: global belief in grey, no-fly columns in red, footprints and UAVs."""

from __future__ import annotations

import numpy as np

UAV_COLOURS = np.array(
    [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
    ],
    dtype=np.uint8,
)


def render_rgb(env) -> np.ndarray:
    """(grid, grid, 3) uint8 image, row 0 = y 0 (flip vertically to show north up)."""
    belief = env.global_belief()
    image = np.repeat((255 * (1.0 - belief)).astype(np.uint8)[..., None], 3, axis=2)
    geo = env.geometry
    no_fly = env.ground_truth.no_fly
    if no_fly.any():
        mask = no_fly[geo.block_of_cell[:, None], geo.block_of_cell[None, :]]
        image[mask] = (0.5 * image[mask] + 0.5 * np.array([220, 60, 60])).astype(np.uint8)
    for i, (ix, iy, lev) in enumerate(env._pos):
        colour = UAV_COLOURS[i % len(UAV_COLOURS)]
        fp = geo.footprint(int(ix), int(iy), int(lev))
        image[fp.r0, fp.c0 : fp.c1] = colour
        image[fp.r1 - 1, fp.c0 : fp.c1] = colour
        image[fp.r0 : fp.r1, fp.c0] = colour
        image[fp.r0 : fp.r1, fp.c1 - 1] = colour
        cy, cx = (fp.r0 + fp.r1) // 2, (fp.c0 + fp.c1) // 2
        image[max(cy - 4, 0) : cy + 5, max(cx - 4, 0) : cx + 5] = colour
    return image
