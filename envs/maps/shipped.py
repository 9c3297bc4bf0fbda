"""The shipped real images (env2, env3): file names, encodings, default rules, and their decoding.

Both :func:`load_ground_truth` (which decodes) and ``build_shipped_maps`` (which encodes) import
the constants below, so the two directions cannot drift apart. Only the PNG files in ``data/`` are
read here; the public-domain sources they were made from are needed only to rebuild them
(see ``data/PROVENANCE.md``).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .errors import MapError
from .rules import MapImage, resize_to_grid, rgb_to_gray

DATA_DIR = Path(__file__).resolve().parent / "data"
#: Side of every shipped PNG: the default belief grid, so the default load does no resampling.
SHIPPED_SIZE = 493

#: env2: Landsat-8 band 10, 8-bit grayscale, white = hot (a linear map of the sensor's DN).
ENV2_FILE = "env2_thermal.png"
#: 30 % keeps several separate hot patches (one blob at 15 %, a connected sheet beyond 40 %).
ENV2_DEFAULT_RULE = "hottest:0.3"

#: env3: Sentinel-2 true colour (8-bit RGB) and near-infrared (8-bit gray), each stored as
#: ``value = round((DN - offset) / gain)``. The offsets (just under the scene's darkest pixels)
#: remove most of the atmospheric haze so the colour image looks natural and ExG works on it; the
#: loader adds them back so that NDVI is the usual top-of-atmosphere NDVI of the L1C product.
#: band name -> (offset in DN, gain in DN per 8-bit level); DN = 10000 x TOA reflectance.
ENV3_BANDS: dict[str, tuple[float, float]] = {
    "red": (330.0, 8.0),  # B04
    "green": (550.0, 8.0),  # B03
    "blue": (850.0, 8.0),  # B02
    "nir": (100.0, 24.0),  # B08
}
ENV3_RGB_FILE = "env3_rgb.png"
ENV3_NIR_FILE = "env3_nir.png"
#: Built-up pixels (1-bit PNG), classified at build time with the SWIR band B11 (not shipped).
ENV3_BUILTUP_FILE = "env3_builtup.png"
#: Vegetation: NDVI > 0.5, the usual "dense green vegetation" cut; 40 % of this scene.
ENV3_DEFAULT_RULE = "ndvi:0.5"
#: A lattice column is no-fly when more than this fraction of its block is built-up. At 10 m a
#: rural town is roofs mixed with trees and lawns, so a dense town block scores only 15-50 %;
#: 0.15 marks the town centre and the larger compounds (11 of 121 columns) and no field.
ENV3_NO_FLY_FRACTION = 0.15


def _read_shipped(file: str, flags: int) -> np.ndarray:
    """Read one shipped PNG; a missing or broken file means a broken install, so say so."""
    path = DATA_DIR / file
    img = cv2.imread(str(path), flags) if path.is_file() else None
    if img is None or img.size == 0:
        raise MapError(
            f"shipped map file {str(path)!r} is missing or unreadable; reinstall sb3-coma "
            "or rebuild it with `python -m uav_ipp.maps.build_shipped_maps`"
        )
    return img


def env2_image(grid: int) -> MapImage:
    """The thermal image at ``grid`` x ``grid`` (gray in [0, 1], 1 = hottest pixel of the crop)."""
    raw = _read_shipped(ENV2_FILE, cv2.IMREAD_UNCHANGED)
    scale = 65535.0 if raw.dtype == np.uint16 else 255.0
    return MapImage(gray=resize_to_grid(raw.astype(np.float32) / scale, grid))


def _decode(values: np.ndarray, band: str) -> np.ndarray:
    offset, gain = ENV3_BANDS[band]
    return values.astype(np.float32) * gain + offset


def env3_image(grid: int) -> MapImage:
    """The Sentinel-2 scene at ``grid`` x ``grid``: display RGB in [0, 1], its gray, and NDVI."""
    bgr = _read_shipped(ENV3_RGB_FILE, cv2.IMREAD_COLOR)
    nir8 = _read_shipped(ENV3_NIR_FILE, cv2.IMREAD_GRAYSCALE)
    return env3_image_from_codes(bgr[:, :, ::-1], nir8, grid)


def env3_image_from_codes(rgb_codes: np.ndarray, nir_codes: np.ndarray, grid: int) -> MapImage:
    """Decode 8-bit band codes (``ENV3_BANDS``; ``rgb_codes`` in RGB order) into a :class:`MapImage`.

    Bands are resampled as reflectances *before* NDVI is formed, because averaging reflectance is
    what a coarser sensor would measure, whereas averaging a ratio is not. The build tool runs the
    extra env3 scenes through this same function, so their shipped masks are what the paper
    loader would compute from their bands.
    """
    rgb8 = resize_to_grid(rgb_codes, grid)  # 0..255 floats, RGB order
    red = _decode(rgb8[:, :, 0], "red")
    nir = _decode(resize_to_grid(nir_codes, grid), "nir")
    total = nir + red
    ndvi = np.where(total > 0, (nir - red) / np.where(total > 0, total, 1.0), 0.0).astype(np.float32)
    rgb = np.ascontiguousarray(rgb8 / 255.0, dtype=np.float32)
    return MapImage(gray=rgb_to_gray(rgb), rgb=rgb, ndvi=ndvi)


def env3_builtup(grid: int) -> np.ndarray:
    """Built-up fraction of every grid cell (float32 in [0, 1]; binary at the shipped size)."""
    mask = _read_shipped(ENV3_BUILTUP_FILE, cv2.IMREAD_GRAYSCALE)
    return resize_to_grid((mask > 0).astype(np.float32), grid)


# --- the extra train / test scenes (uav_ipp.maps.scenes) ------------------------------------------------
def env2_scene_image(file: str, grid: int) -> MapImage:
    """An extra env2 scene: its 8-bit thermal crop (native crop size, white = hot) at ``grid``."""
    return env2_image_from_codes(_read_shipped(file, cv2.IMREAD_GRAYSCALE), grid)


def env2_image_from_codes(codes: np.ndarray, grid: int) -> MapImage:
    """An 8-bit thermal crop at ``grid``: the loader's decoding, shared with the build tool's report.

    Upsampled bicubically (as the paper scene was at build time; clipped back to [0, 1], since
    cubic interpolation overshoots), or area-averaged when the grid is coarser than the crop.
    """
    raw = codes.astype(np.float32) / 255.0
    if raw.shape[0] >= grid:
        return MapImage(gray=resize_to_grid(raw, grid))
    up = cv2.resize(raw, (grid, grid), interpolation=cv2.INTER_CUBIC)
    return MapImage(gray=np.clip(up, 0.0, 1.0))


def env3_scene_masks(valuable_file: str, builtup_file: str, grid: int) -> tuple[np.ndarray, np.ndarray]:
    """An extra env3 scene: (valuable bool mask, built-up fraction float32) at ``grid`` x ``grid``.

    The valuable mask ships only under the default rule (``ENV3_DEFAULT_RULE``), at 493 x 493; on
    another grid it is area-averaged and re-thresholded at one half (majority of the cell).
    """
    valuable = _read_shipped(valuable_file, cv2.IMREAD_GRAYSCALE) > 0
    built = _read_shipped(builtup_file, cv2.IMREAD_GRAYSCALE) > 0
    if valuable.shape[0] != grid:
        valuable = resize_to_grid(valuable.astype(np.float32), grid) > 0.5
    return valuable, resize_to_grid(built.astype(np.float32), grid)
