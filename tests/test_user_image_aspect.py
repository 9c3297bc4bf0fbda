"""A user's image that is not square is stretched onto the square field: said once, with its size."""

from __future__ import annotations

import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest

import uav_ipp


def _image(path: Path, width: int, height: int) -> Path:
    picture = np.zeros((height, width), np.uint8)
    picture[:, : width // 2] = 255
    assert cv2.imwrite(str(path), picture)
    return path


def test_a_non_square_image_is_named_with_its_size(tmp_path: Path) -> None:
    wide = _image(tmp_path / "wide.png", 120, 60)
    with pytest.warns(UserWarning, match=r"wide\.png'?: the image is 120 x 60 pixels, not square; it is stretched"):
        uav_ipp.make_env("mine", map_path=str(wide), n_uavs=2, budget=2)


def test_a_square_image_loads_without_a_word(tmp_path: Path) -> None:
    square = _image(tmp_path / "square.png", 64, 64)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        uav_ipp.make_env("mine", map_path=str(square), n_uavs=2, budget=2)
