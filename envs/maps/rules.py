"""Turning an image into a binary "valuable" mask: image reading, resizing and the rule strings.

A rule is a short string so that it fits on a command line and in an rl-zoo YAML file:

=====================  ==========================================================================
``threshold[:T]``      grayscale (in [0, 1]) ``> T``; Otsu's threshold when ``T`` is omitted
``dark[:T]``           grayscale ``< T`` (a black-on-white drawing); Otsu's complement when omitted
``hottest:F``          the brightest fraction ``F`` of pixels (white-hot thermal images)
``coldest:F``          the darkest fraction ``F`` of pixels (black-hot thermal images)
``excess-green[:T]``   ExG = 2g - r - b on chromatic coordinates ``> T``; Otsu when omitted
``ndvi[:T]``           NDVI ``> T`` (default 0.5); only maps that ship a near-infrared band (env3)
=====================  ==========================================================================

Images are resized to the belief grid *before* the rule is applied, so quantile rules hit their
fraction on the grid the environment actually scores, and the mask is binary at that resolution.

A user's file is read as it is *shown*: its EXIF orientation is applied (a phone photo stored
sideways is turned upright, as every viewer does), and transparent pixels (an alpha channel, or a
palette / colour-key ``tRNS`` transparency) are "no data": never valuable, and left out when a
rule picks its threshold (Otsu, or the fraction of ``hottest`` / ``coldest``). So are the pixels of
a float raster that hold a standard NoData fill (:data:`STANDARD_NODATA`: float32's and float64's
lowest value, -9999) and, in any raster, the pixels that hold the NoData value its metadata
declares (a TIFF's ``GDAL_NODATA`` tag): a fill is a mark, not the coldest ground.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, TiffImagePlugin

from .errors import MapError

#: Canonical rule names, in the order error messages list them.
RULE_NAMES: tuple[str, ...] = ("threshold", "dark", "hottest", "coldest", "excess-green", "ndvi")
_ALIASES = {"excess_green": "excess-green", "exg": "excess-green", "otsu": "threshold"}
#: Rules whose parameter is a pixel fraction and therefore mandatory (no sensible default).
_FRACTION_RULES = ("hottest", "coldest")
#: The allowed range of each rule's number: a threshold's closed range (ExG = 3g - 1 lies in
#: [-1, 2], NDVI in [-1, 1]) or, for the fraction rules, the open interval (0, 1).
_RANGES = {
    "threshold": (0.0, 1.0),
    "dark": (0.0, 1.0),
    "excess-green": (-1.0, 2.0),
    "ndvi": (-1.0, 1.0),
    "hottest": (0.0, 1.0),
    "coldest": (0.0, 1.0),
}
#: The NDVI threshold used when ``ndvi`` comes without one: a common "dense green vegetation" cut.
DEFAULT_NDVI_THRESHOLD = 0.5
#: A pixel (or grid cell, by its area-averaged alpha) counts as transparent below this opacity:
#: more transparent than opaque, so an anti-aliased edge pixel goes with the side it mostly is.
OPAQUE = 0.5
#: EXIF tag of the orientation (TIFF/EXIF 0x0112), 1 = as stored.
_EXIF_ORIENTATION = 0x0112
#: The NoData fills of float rasters that declare none (GDAL's defaults for Float32 and Float64,
#: and the -9999 of many GIS exports), with the name a warning gives each.
STANDARD_NODATA: dict[float, str] = {
    float(np.finfo(np.float32).min): "-3.4028235e+38 (float32 lowest)",
    float(np.finfo(np.float64).min): "-1.7976931348623157e+308 (float64 lowest)",
    -9999.0: "-9999",
}
#: TIFF tag of GDAL's NoData value (ASCII text, e.g. "-9999" or "nan").
_GDAL_NODATA_TAG = 42113
#: The rules that read a band not every image has: rule -> (the :class:`MapImage` field, what
#: the rule needs, said to a user whose map lacks it).
_BANDS = {
    "excess-green": (
        "rgb",
        "a colour image, but map {label!r} is grayscale; use 'threshold', 'dark', 'hottest' or 'coldest'",
    ),
    "ndvi": ("ndvi", "a near-infrared band, which only env3 ships; map {label!r} has none (try 'excess-green')"),
}
_RULE_HELP = (
    "allowed rules: 'threshold[:T]', 'dark[:T]', 'hottest:F', 'coldest:F', "
    "'excess-green[:T]', 'ndvi[:T]' (T a number, F a fraction in (0, 1))"
)


@dataclass(frozen=True)
class Rule:
    """A parsed rule: canonical ``kind`` and its number (``None`` = Otsu / the rule's default)."""

    kind: str
    value: float | None = None

    def __str__(self) -> str:
        return self.kind if self.value is None else f"{self.kind}:{self.value:g}"


@dataclass(frozen=True)
class MapImage:
    """An image already resized to the grid, in the forms the rules need.

    ``gray`` is always present (float32 in [0, 1]); ``rgb`` (H, W, 3, RGB order, float32 in [0, 1])
    only for colour images; ``ndvi`` (float32 in [-1, 1]) only for maps that ship a near-infrared
    band; ``valid`` (bool) only for images with transparency: the cells that hold data (the rest
    are never valuable and do not take part in a rule's threshold). Keeping the derived forms here
    lets the rules stay one-liners and lets a missing form become a clear error instead of a
    silent fallback.
    """

    gray: np.ndarray
    rgb: np.ndarray | None = None
    ndvi: np.ndarray | None = None
    valid: np.ndarray | None = None


def parse_rule(rule: object) -> Rule:
    """Parse a rule string such as ``"hottest:0.3"``; raise :class:`MapError` naming what is wrong.

    One rule, one raise: the first problem (an unknown name, a missing number, one that is not
    finite, one outside the rule's range) is named with what is allowed.
    """
    name, sep, arg = (rule.strip().lower() if isinstance(rule, str) else "").partition(":")
    name, arg = _ALIASES.get(name.strip(), name.strip()), arg.strip()
    fraction = name in _FRACTION_RULES
    try:
        value = float(arg) if arg else None
    except ValueError:
        value = math.nan
    lo, hi = _RANGES.get(name, (0.0, 1.0))
    if name not in RULE_NAMES:  # also anything that is not a string
        problem = f"unknown valuable rule {rule!r} ({type(rule).__name__}); {_RULE_HELP}"
    elif value is None and (sep or fraction):
        # "hottest:" with nothing after the colon is a typo, not a request for a default
        what = "a fraction" if fraction else "a number after the ':'"
        problem = f"valuable rule {rule!r} needs {what}, e.g. '{name}:0.3'; {_RULE_HELP}"
    elif value is not None and not math.isfinite(value):
        problem = f"valuable rule {rule!r}: {arg!r} is not a number (a finite one); {_RULE_HELP}"
    elif value is not None and not (lo < value < hi if fraction else lo <= value <= hi):
        allowed = f"strictly between {lo:g} and {hi:g}" if fraction else f"in [{lo:g}, {hi:g}] for '{name}'"
        kind = "fraction" if fraction else "threshold"
        problem = f"valuable rule {rule!r}: the {kind} {value:g} must lie {allowed}"
    else:
        return Rule(name, value)
    raise MapError(problem)


def otsu_threshold(values: np.ndarray, bins: int = 256) -> float:
    """Otsu's threshold of a float array: the cut that maximises the between-class variance.

    Written on a histogram of the data's own range (not cv2's 8-bit Otsu) so that it works on
    16-bit, float and ExG/NDVI values alike. ``values > t`` is the upper class. A constant array
    has no split; its own value is returned, which makes the upper class empty and lets the caller
    report "no valuable pixels".
    """
    v = np.asarray(values, dtype=np.float64).ravel()
    lo, hi = float(v.min()), float(v.max())
    if not hi > lo:
        return lo
    hist, edges = np.histogram(v, bins=bins, range=(lo, hi))
    p = hist / hist.sum()
    centres = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(p)  # weight of the lower class for a cut after bin i
    m0 = np.cumsum(p * centres)  # its un-normalised mean
    mt = m0[-1]
    w1 = 1.0 - w0
    with np.errstate(divide="ignore", invalid="ignore"):
        between = (mt * w0 - m0) ** 2 / (w0 * w1)
    between[~np.isfinite(between)] = -1.0
    return float(edges[int(np.argmax(between)) + 1])


def _chromatic_exg(rgb: np.ndarray) -> np.ndarray:
    """Excess green 2g - r - b on chromatic coordinates; black pixels (r+g+b = 0) score 0."""
    total = rgb.sum(axis=2)
    safe = np.where(total > 0, total, 1.0)
    r, g, b = (rgb[..., k] / safe for k in range(3))
    return np.where(total > 0, 2.0 * g - r - b, 0.0).astype(np.float32)


def apply_rule(rule: Rule, image: MapImage, label: str) -> np.ndarray:
    """The boolean mask the rule selects on ``image``; ``label`` names the map in error messages.

    Raises :class:`MapError` when the image lacks what the rule needs (colour, near-infrared) and
    when the result is degenerate (no cell, or every cell, valuable): an all-or-nothing truth makes
    every reward and metric of the environment meaningless, so it must not reach training.
    """
    kind, value = rule.kind, rule.value
    gray = image.gray
    valid = image.valid
    # one rule: a rule that reads a band the image lacks is refused, naming the rules that fit
    band, needs = _BANDS.get(kind, (None, ""))
    if band is not None and getattr(image, band) is None:
        raise MapError(f"valuable rule '{rule}' needs {needs.format(label=label)}")

    def data(values: np.ndarray) -> np.ndarray:  # the cells a threshold is chosen on
        return values if valid is None else values[valid]

    if kind == "threshold":
        mask = gray > (otsu_threshold(data(gray)) if value is None else value)
    elif kind == "dark":
        mask = ~(gray > otsu_threshold(data(gray))) if value is None else gray < value
    elif kind == "hottest":
        assert value is not None  # parse_rule requires a fraction for "hottest"
        mask = gray > np.quantile(data(gray), 1.0 - value)
    elif kind == "coldest":
        assert value is not None  # ... and for "coldest"
        mask = gray < np.quantile(data(gray), value)
    elif kind == "excess-green":
        assert image.rgb is not None  # checked above (_BANDS)
        exg = _chromatic_exg(image.rgb)
        mask = exg > (otsu_threshold(data(exg)) if value is None else value)
    else:
        assert kind == "ndvi" and image.ndvi is not None, kind  # parse_rule only produces RULE_NAMES
        mask = image.ndvi > (DEFAULT_NDVI_THRESHOLD if value is None else value)
    if valid is not None:
        mask &= valid
    n = int(mask.sum())
    if n in (0, mask.size):  # all-or-nothing: one rule, whichever side it falls on
        which = "no" if n == 0 else "every"
        hidden = 0 if valid is None else int((~valid).sum())  # never valuable, so part of the reason
        note = f" (its {hidden:,} transparent grid cells are never valuable)" if hidden else ""
        raise MapError(
            f"valuable rule '{rule}' marks {which} pixel of map {label!r} valuable; choose another rule or "
            f"threshold{note}"
        )
    return mask


def resize_to_grid(image: np.ndarray, grid: int) -> np.ndarray:
    """Resize (any size and aspect) to ``grid`` x ``grid`` with area averaging, as float32.

    INTER_AREA averages the pixels a grid cell covers, which is what a downward camera sees of a
    cell; the aspect ratio is not kept because the field is square by definition.
    """
    img = np.ascontiguousarray(image, dtype=np.float32)
    if img.shape[0] == grid and img.shape[1] == grid:
        return img
    return cv2.resize(img, (grid, grid), interpolation=cv2.INTER_AREA)


def _normalise(img: np.ndarray, path: str, valid: np.ndarray | None = None) -> np.ndarray:
    """Pixel values to float32 in [0, 1] according to their storage type; ``valid`` (the pixels
    that hold data, (H, W)) keeps NoData fills out of a float image's stretch (they become 0)."""
    if valid is not None:  # a fill takes a valid pixel's value (no part in the stretch), then 0
        where = valid if img.ndim == 2 else valid[:, :, None]
        filled = np.where(where, img, img[valid].min(axis=0))
        return np.where(where, _normalise(filled, path), 0.0).astype(np.float32)
    if img.dtype == np.uint8:
        return img.astype(np.float32) / 255.0
    if img.dtype == np.uint16:
        return img.astype(np.float32) / 65535.0
    out = img.astype(np.float32)
    assert np.isfinite(out).all(), path  # _decode refuses non-finite pixels
    if np.issubdtype(img.dtype, np.floating) and out.min() >= 0.0 and out.max() <= 1.0:
        return out
    # signed integers or floats outside [0, 1] (e.g. a float32 TIFF of temperatures): stretch
    lo, hi = float(out.min()), float(out.max())
    return (out - lo) / (hi - lo) if hi > lo else np.zeros_like(out)


@dataclass(frozen=True)
class ImageFile:
    """A user's image as shown: EXIF orientation applied, values as float32 in [0, 1].

    ``rgb`` is ``None`` for single-channel files; ``alpha`` (opacity, 1 = opaque) is ``None`` unless
    some pixel is transparent (below :data:`OPAQUE`), so fully opaque RGBA files cost nothing extra.
    A pixel that holds a NoData fill is transparent (alpha 0); ``nodata`` names each fill found and
    how many pixels hold it.
    """

    gray: np.ndarray
    rgb: np.ndarray | None
    alpha: np.ndarray | None
    orientation: int = 1
    nodata: tuple[tuple[str, int], ...] = ()

    @property
    def transparent_pixels(self) -> int:
        """How many pixels are transparent (opacity below :data:`OPAQUE`)."""
        return 0 if self.alpha is None else int((self.alpha < OPAQUE).sum())


def orient(a: np.ndarray, orientation: int) -> np.ndarray:
    """``a`` (rows = y) turned as ``PIL.ImageOps.exif_transpose`` turns an image with this EXIF
    orientation (1-8; anything else is left as stored), on the first two axes.

    Done on the decoded array rather than by decoding with PIL, so the pixel values stay OpenCV's
    (16-bit, float TIFF, ...) whatever the orientation; ``tests/test_maps.py`` checks all 8 against
    ``exif_transpose`` itself.
    """
    if orientation == 2:  # FLIP_LEFT_RIGHT
        return a[:, ::-1]
    if orientation == 3:  # ROTATE_180
        return a[::-1, ::-1]
    if orientation == 4:  # FLIP_TOP_BOTTOM
        return a[::-1]
    if orientation == 5:  # TRANSPOSE
        return np.swapaxes(a, 0, 1)
    if orientation == 6:  # ROTATE_270 (a quarter turn clockwise)
        return np.rot90(a, -1)
    if orientation == 7:  # TRANSVERSE
        return np.swapaxes(a, 0, 1)[::-1, ::-1]
    if orientation == 8:  # ROTATE_90 (a quarter turn counter-clockwise)
        return np.rot90(a, 1)
    return a


def _pil_metadata(data: np.ndarray, shape: tuple[int, ...], need_alpha: bool) -> tuple[int, np.ndarray | None]:
    """(EXIF orientation, alpha from PIL or ``None``) of the encoded file ``data``.

    OpenCV ignores EXIF with ``IMREAD_UNCHANGED`` and a colour-key ``tRNS`` (gray or RGB PNG); PIL
    reads both. ``Image.open`` only parses headers, so this costs nothing unless an alpha has to be
    made. Any file PIL cannot open is taken as stored and opaque (OpenCV has already decoded it).
    """
    try:
        with Image.open(io.BytesIO(data.tobytes())) as im:
            orientation = int(im.getexif().get(_EXIF_ORIENTATION, 1) or 1)
            if not need_alpha or not ("transparency" in im.info or "A" in im.getbands()):
                return orientation, None
            try:
                alpha = np.asarray(im.convert("RGBA").getchannel("A"), dtype=np.float32) / 255.0
            except Exception:  # a mode PIL cannot turn into RGBA (e.g. 16-bit with a key): opaque
                return orientation, None
    except Exception:  # PIL raises many types for files it does not know; OpenCV decoded it already
        return 1, None
    return orientation, (alpha if alpha.shape == shape[:2] else None)


def _channels(
    img: np.ndarray, shown: str, valid: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """(gray, rgb, alpha) of a decoded OpenCV array (BGR / BGRA order), each float32 in [0, 1];
    ``valid``: the pixels that hold no NoData fill (``None``: all)."""
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return _normalise(img, shown, valid), None, None
    channels = img.shape[2]
    if channels == 2:  # gray + alpha
        return _normalise(img[:, :, 0], shown, valid), None, _normalise(img[:, :, 1], shown, valid)
    assert channels in (3, 4), channels  # _decode refuses other channel counts
    alpha = _normalise(img[:, :, 3], shown, valid) if channels == 4 else None
    rgb = np.ascontiguousarray(_normalise(img[:, :, 2::-1], shown, valid))
    return rgb_to_gray(rgb), rgb, alpha


def _declared_nodata(data: np.ndarray) -> tuple[float, str] | None:
    """(value, its text) of the NoData value a TIFF declares (``GDAL_NODATA``), else ``None``.

    Read from the file's first directory with PIL's TIFF tag parser (which, unlike ``Image.open``,
    reads the tags of any pixel layout, a 3-band float raster's too); anything unreadable
    declares nothing."""
    header = data[:8].tobytes()
    if header[:4] not in (b"II*\x00", b"MM\x00*"):
        return None
    try:
        stream = io.BytesIO(data.tobytes())
        tags = TiffImagePlugin.ImageFileDirectory_v2(stream.read(8))
        stream.seek(tags.next)
        tags.load(stream)
        text = str(tags.get(_GDAL_NODATA_TAG, "")).strip().rstrip("\x00").strip()
        return (float(text), text) if text else None
    except Exception:  # a damaged directory or a value that is no number: no declaration
        return None


def _nodata(img: np.ndarray, data: np.ndarray) -> tuple[np.ndarray | None, tuple[tuple[str, int], ...]]:
    """(the pixels that hold a NoData fill in any channel, or ``None``; (fill as shown, pixels) of
    each fill found): :data:`STANDARD_NODATA` in a float raster, the declared value in any."""
    fills = dict(STANDARD_NODATA) if img.dtype.kind == "f" else {}
    declared = _declared_nodata(data)
    if declared is not None:
        fills[declared[0]] = f"{declared[1]} (the file's GDAL_NODATA)"
    mask, found = np.zeros(img.shape[:2], dtype=bool), []
    for fill, shown in fills.items():
        hit = np.isnan(img) if math.isnan(fill) else img == np.float64(fill)  # float64: no overflow
        hit = (hit if hit.ndim == 2 else hit.any(axis=2)) & ~mask
        if hit.any():
            found.append((shown, int(hit.sum())))
            mask |= hit
    return (mask if found else None), tuple(found)


def fills_text(fills: tuple[tuple[str, int], ...]) -> str:
    """The fills of :func:`_nodata` in words: ``"the NoData fill -9999"``, or with several, each
    with its pixels: ``"the NoData fills -9999 (2,500 pixels), nan (the file's GDAL_NODATA) (12 pixels)"``."""
    if len(fills) == 1:
        return f"the NoData fill {fills[0][0]}"
    return "the NoData fills " + ", ".join(f"{fill} ({n:,} pixels)" for fill, n in fills)


def _with_data(img: np.ndarray, nodata: np.ndarray | None) -> np.ndarray:
    return img if nodata is None else img[~nodata]


def _decode(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, tuple[tuple[str, int], ...]]:
    """(encoded bytes, OpenCV's decoded array, its NoData pixels and fills (:func:`_nodata`)) of a
    user's file, with the file errors phrased.

    Bytes are decoded with ``cv2.imdecode`` (not ``imread``) so paths with non-ASCII characters
    work and a non-image file is an error we phrase, not an empty return. One rule, one raise: the
    file is an image we can read (there, readable, not empty, decodable, 1 to 4 channels, some
    pixel with data, finite values where there is data); the first thing wrong is named.
    """
    p = Path(path)
    data, img, problem = np.zeros(0, np.uint8), None, None
    nodata: np.ndarray | None = None
    fills: tuple[tuple[str, int], ...] = ()
    if not p.is_file():
        problem = "is not a file" if p.exists() else "does not exist"
    else:
        try:
            data = np.fromfile(p, dtype=np.uint8)
        except OSError as exc:
            problem = f"cannot be read: {exc.strerror or exc}"
    if problem is None and data.size == 0:
        problem = "is empty (0 bytes, no pixels)"
    if problem is None:
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # not libtiff's "Unknown field
        try:  # with tag 42113" (GDAL_NODATA, read here) and other GIS tags, printed on stderr
            with contextlib.suppress(cv2.error):
                img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
        finally:
            cv2.utils.logging.setLogLevel(level)
        channels = 1 if img is None or img.ndim < 3 else img.shape[2]
        if img is not None and img.size and img.ndim >= 2 and channels in (1, 2, 3, 4):
            nodata, fills = _nodata(img, data)
        if img is None or img.size == 0 or img.ndim < 2:
            problem = (
                "is not an image cv2 can decode, or one of 0 pixels "
                "(use PNG, JPEG, TIFF, BMP or another format OpenCV reads)"
            )
        elif channels not in (1, 2, 3, 4):
            problem = f"has {channels} channels; expected 1 (gray), 3 (colour) or 4 (with alpha)"
        elif nodata is not None and nodata.all():
            problem = f"holds only NoData pixels ({fills_text(fills)}); nothing to map"
        elif img.dtype.kind == "f" and not np.isfinite(_with_data(img, nodata).astype(np.float32, copy=False)).all():
            problem = (
                "contains NaN or infinite pixel values (a NoData mark? declare it in a TIFF's GDAL_NODATA tag, "
                "or save it as an alpha channel: no-data and transparent pixels are left out of the map)"
            )
    if problem is not None or img is None:
        raise MapError(f"map_path {os.fspath(path)!r} {problem}")
    return data, img, nodata, fills


def read_image(path: str | os.PathLike) -> ImageFile:
    """Read any image cv2 can decode, as it is shown: an :class:`ImageFile` at the file's own size.

    The EXIF orientation (JPEG, TIFF, PNG, WebP) is applied, as ``PIL.ImageOps.exif_transpose``
    would. Transparency comes from an alpha channel (RGBA, gray + alpha, a palette with ``tRNS``,
    which OpenCV expands to BGRA) or from a colour-key ``tRNS`` (read through PIL); the colour of a
    transparent pixel is whatever the file stores there, so the loader treats it as no data. A
    pixel that holds a NoData fill (:func:`_nodata`) is transparent too, and out of the stretch of
    a float image's values.
    """
    shown = os.fspath(path)
    data, img, nodata, fills = _decode(path)
    valid = None if nodata is None else ~nodata
    gray, rgb, alpha = _channels(img, shown, valid)
    orientation, pil_alpha = _pil_metadata(data, img.shape, need_alpha=alpha is None)
    alpha = pil_alpha if alpha is None else alpha
    if valid is not None:
        alpha = valid.astype(np.float32) if alpha is None else np.where(valid, alpha, 0.0).astype(np.float32)
    if alpha is not None and not (alpha < OPAQUE).any():
        alpha = None  # an alpha channel that hides nothing
    if alpha is not None and (alpha < OPAQUE).all():
        raise MapError(f"map_path {shown!r} is fully transparent (every pixel has alpha < {OPAQUE:g}); nothing to map")
    turned = [None if a is None else np.ascontiguousarray(orient(a, orientation)) for a in (gray, rgb, alpha)]
    assert turned[0] is not None
    return ImageFile(gray=turned[0], rgb=turned[1], alpha=turned[2], orientation=orientation, nodata=fills)


def image_on_grid(image: ImageFile, grid: int) -> tuple[MapImage, int]:
    """``image`` resized to ``grid`` x ``grid`` and the number of grid cells that are transparent.

    With transparency, colour is averaged weighted by opacity (what the opaque part of a cell
    shows, not the arbitrary colour stored under transparent pixels) and a cell whose mean opacity
    is below :data:`OPAQUE` is invalid: :func:`apply_rule` never marks it and leaves it out of its
    threshold.
    """
    if image.alpha is None:
        rgb = None if image.rgb is None else resize_to_grid(image.rgb, grid)
        return MapImage(gray=resize_to_grid(image.gray, grid), rgb=rgb), 0
    opacity = resize_to_grid(image.alpha, grid)
    valid = opacity >= OPAQUE
    if not valid.any():
        raise MapError(
            f"every cell of the {grid} x {grid} grid is mostly transparent (opacity < {OPAQUE:g}); "
            "use a finer grid or an image with more opaque pixels"
        )
    weight = np.where(valid, opacity, 1.0)

    def unpremultiply(premultiplied: np.ndarray, mask: np.ndarray, w: np.ndarray) -> np.ndarray:
        return np.clip(np.where(mask, premultiplied / w, 0.0), 0.0, 1.0).astype(np.float32)

    gray = unpremultiply(resize_to_grid(image.gray * image.alpha, grid), valid, weight)
    rgb = None
    if image.rgb is not None:
        premultiplied = resize_to_grid(image.rgb * image.alpha[:, :, None], grid)
        rgb = unpremultiply(premultiplied, valid[:, :, None], weight[:, :, None])
    return MapImage(gray=gray, rgb=rgb, valid=valid), int((~valid).sum())


def rgb_to_gray(rgb: np.ndarray) -> np.ndarray:
    """ITU-R BT.601 luma, the grayscale every common image tool shows for a colour image."""
    return (0.299 * rgb[..., 0] + 0.587 * rgb[..., 1] + 0.114 * rgb[..., 2]).astype(np.float32)
