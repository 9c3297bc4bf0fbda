"""user_maps: the shipped user-map images match their provenance; the experiment pairs the model
with AG and AG-k3 on the same missions of every image, clustered by image."""

from __future__ import annotations

import hashlib
import re

import cv2
import pytest

from sb3_coma.experiments import user_maps as um


def test_the_shipped_images_are_the_recorded_crops():
    paths = um.images()
    assert [p.stem for p in paths] == [f"landsat_{name}" for name in um.CROPS]
    recorded = dict(
        (name, digest)
        for digest, name in re.findall(
            r"^([0-9a-f]{64})  (\S+\.png)$", (um.IMAGE_DIR / "PROVENANCE.md").read_text(), re.M
        )
    )
    for path in paths:
        assert recorded[path.name] == hashlib.sha256(path.read_bytes()).hexdigest()
        image = cv2.imread(str(path))
        assert image.shape == (um.SIDE, um.SIDE, 3)


def test_the_crops_are_disjoint_windows_of_the_scene():
    windows = list(um.CROPS.values())
    for i, (r1, c1) in enumerate(windows):
        assert 0 <= r1 <= 603 - um.SIDE and 0 <= c1 <= 627 - um.SIDE
        for r2, c2 in windows[i + 1 :]:
            assert abs(r1 - r2) >= um.SIDE or abs(c1 - c2) >= um.SIDE


def test_missing_images_name_the_files(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"landsat_north1\.png"):
        um.images(tmp_path)


def test_verdicts_pair_the_model_with_ag_and_ag_k3_clustered_by_image(monkeypatch):
    monkeypatch.setattr(um, "PLANNERS", um.PLANNERS[:2])  # AG and AG-k3 (the oracle is a reference row)
    results = um.fly("random", um.images()[:2], missions=2, noise="moderate")
    assert list(results) == ["model", "ag", "ag-k3"]
    assert results["model"].scenes == ("landsat_north1",) * 2 + ("landsat_north2",) * 2
    rows = um.verdicts(results)
    assert [(d.b, d.metric) for d in rows] == [("ag", "f1"), ("ag", "entropy"), ("ag-k3", "f1"), ("ag-k3", "entropy")]
    assert all(d.n == 4 and d.n_clusters == 2 and d.p_holm is not None for d in rows)
    assert rows[0].mean_b > rows[0].mean_a  # AG finds more valuable ground than random flights
