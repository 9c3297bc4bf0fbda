"""``valuable=`` rules that turn an image into a boolean mask of valuable ground.

A rule is a short string ``name`` or ``name:parameter``; each rule documents its parameter.
"""
from __future__ import annotations

from typing import Callable

import cv2
import numpy as np


class MapError(ValueError):
    """A map name, file or rule is unusable; the message names the value and what is allowed."""


def grayscale(image: np.ndarray) -> np.ndarray:
    """[0, 1] float grayscale of an 8/16-bit gray or BGR(A) image."""
    img = image.astype(np.float32)
    scale = 65535.0 if image.dtype == np.uint16 else 255.0 if image.dtype == np.uint8 else max(float(img.max()), 1e-9)
    img = img / scale
    if img.ndim == 3:
        img = cv2.cvtColor(img[..., :3], cv2.COLOR_BGR2GRAY)
    return img


def _otsu(values: np.ndarray) -> float:
    u8 = np.clip(values * 255.0, 0, 255).astype(np.uint8)
    threshold, _ = cv2.threshold(u8, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return float(threshold) / 255.0


def _fraction(param: str | None, rule: str) -> float:
    if param is None:
        raise MapError(f"valuable rule {rule!r} needs a fraction, e.g. '{rule}:0.3'")
    f = _number(param, rule)
    if not 0.0 < f < 1.0:
        raise MapError(f"valuable rule {rule}:{param}: the fraction must be in (0, 1)")
    return f


def _number(param: str, rule: str) -> float:
    try:
        return float(param)
    except ValueError:
        raise MapError(f"valuable rule {rule}:{param}: {param!r} is not a number") from None


def _threshold(gray: np.ndarray, param: str | None, rule: str) -> float:
    if param is None:
        return _otsu(gray)
    t = _number(param, rule)
    if not 0.0 <= t <= 1.0:
        raise MapError(f"valuable rule {rule}:{param}: the threshold must be in [0, 1]")
    return t


def rule_threshold(image: np.ndarray, param: str | None) -> np.ndarray:
    """``threshold[:T]``: grayscale > T (Otsu when T is omitted)."""
    gray = grayscale(image)
    return gray > _threshold(gray, param, "threshold")


def rule_dark(image: np.ndarray, param: str | None) -> np.ndarray:
    """``dark[:T]``: grayscale < T, e.g. a black-on-white drawing (Otsu when T is omitted)."""
    gray = grayscale(image)
    return gray < _threshold(gray, param, "dark")


def rule_hottest(image: np.ndarray, param: str | None) -> np.ndarray:
    """``hottest:F``: the brightest fraction F of pixels (white-hot thermal images)."""
    gray = grayscale(image)
    return gray > np.quantile(gray, 1.0 - _fraction(param, "hottest"))


def rule_coldest(image: np.ndarray, param: str | None) -> np.ndarray:
    """``coldest:F``: the darkest fraction F of pixels."""
    gray = grayscale(image)
    return gray < np.quantile(gray, _fraction(param, "coldest"))


def rule_excess_green(image: np.ndarray, param: str | None) -> np.ndarray:
    """``excess-green[:T]``: ExG = 2g - r - b on chromatic coordinates > T (Otsu if omitted)."""
    if image.ndim != 3 or image.shape[2] < 3:
        raise MapError("valuable rule 'excess-green' needs a colour image (3 channels)")
    bgr = image[..., :3].astype(np.float32)
    total = np.maximum(bgr.sum(axis=2), 1e-6)
    b, g, r = (bgr[..., k] / total for k in range(3))
    exg = 2 * g - r - b  # in [-1, 2]
    scaled = (exg + 1.0) / 3.0
    if param is None:
        return scaled > _otsu(scaled)
    return exg > _number(param, "excess-green")


RULES: dict[str, Callable[[np.ndarray, str | None], np.ndarray]] = {
    "threshold": rule_threshold,
    "dark": rule_dark,
    "hottest": rule_hottest,
    "coldest": rule_coldest,
    "excess-green": rule_excess_green,
}


def apply_rule(image: np.ndarray, rule: str | None) -> np.ndarray:
    """Boolean mask of valuable pixels; ``None`` means ``threshold`` at Otsu."""
    if rule is None:
        rule = "threshold"
    if not isinstance(rule, str) or not rule.strip():
        raise MapError(f"valuable rule {rule!r} is not a rule string; allowed: {sorted(RULES)}")
    name, _, param = rule.strip().partition(":")
    if name not in RULES:
        raise MapError(f"unknown valuable rule {name!r}; allowed: {sorted(RULES)} (as 'name' or 'name:parameter')")
    return RULES[name](image, param or None)
