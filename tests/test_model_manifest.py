"""models.json has one writer (``sb3_coma.app.model_manifest``) and one schema: the shipped file
goes through it unchanged, to the byte, and what reproduce and ship_models write goes through it."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest

from sb3_coma.app import model_manifest as mm
from sb3_coma.app import pretrained as pt

SHIPPED = pt.pretrained_dir() / pt.MANIFEST
pytestmark = pytest.mark.skipif(not SHIPPED.is_file(), reason="no shipped models")


@pytest.fixture
def copy_of_shipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """The shipped manifest, alone in a folder that stands for the shipped one."""
    shutil.copyfile(SHIPPED, tmp_path / pt.MANIFEST)
    monkeypatch.setattr(pt, "pretrained_dir", lambda: tmp_path)
    return tmp_path


def test_rewriting_the_shipped_manifest_gives_its_bytes(copy_of_shipped: Path) -> None:
    original = SHIPPED.read_bytes()
    assert mm.manifest_text(json.loads(original)).encode() == original
    path = mm.update_models({})  # read and written back, nothing changed
    assert path == copy_of_shipped / pt.MANIFEST and path.read_bytes() == original
    models = pt.read_manifest(copy_of_shipped)["models"]
    mm.update_models({name: dict(entry) for name, entry in models.items()})  # every key updated in place
    assert path.read_bytes() == original
    mm.update_models({name: mm.as_entry(name, entry) for name, entry in models.items()}, replace=True)
    assert path.read_bytes() == original  # every entry replaced by itself: same place, same key order


def test_every_key_of_the_shipped_file_is_in_the_schema() -> None:
    for name, entry in pt.read_manifest()["models"].items():
        assert set(entry) <= mm.entry_keys(), (name, sorted(set(entry) - mm.entry_keys()))
        assert {"file", "sha256", "size_bytes"} <= set(entry)


def test_an_update_keeps_the_keys_order_and_adds_new_keys_last(copy_of_shipped: Path) -> None:
    before = pt.read_manifest(copy_of_shipped)["models"]["env1"]
    mm.update_models({"env1": {"title": "x", "algo": "coma"}})
    after = pt.read_manifest(copy_of_shipped)["models"]["env1"]
    assert list(after) == [*before, "algo"] and after["title"] == "x"
    assert {k: v for k, v in after.items() if k not in ("title", "algo")} == {
        k: v for k, v in before.items() if k != "title"
    }


def test_a_key_outside_the_schema_or_a_whole_entry_without_its_file_is_refused(copy_of_shipped: Path) -> None:
    original = SHIPPED.read_bytes()
    with pytest.raises(ValueError, match=r"unknown keys \['metric'\]"):
        mm.update_models({"env1": {"title": "x", "metric": 1}})  # type: ignore[typeddict-unknown-key]
    with pytest.raises(ValueError, match=r"missing \['sha256', 'size_bytes'\]"):
        mm.update_models({"env9": {"file": "coma_env9.zip"}}, replace=True)
    with pytest.raises(pt.PretrainedError, match="no entry 'env9' to update"):
        mm.update_models({"env9": {"title": "x"}})
    assert (copy_of_shipped / pt.MANIFEST).read_bytes() == original  # nothing written


def test_a_first_ship_starts_the_manifest_an_update_needs_one(tmp_path: Path) -> None:
    entry: mm.ModelEntry = {"file": "coma_env1.zip", "sha256": "0" * 64, "size_bytes": 3, "env": "env1"}
    with pytest.raises(pt.PretrainedError, match="is missing"):
        mm.update_models({"env1": {"title": "x"}}, directory=tmp_path)
    mm.update_models({"env1": entry}, replace=True, directory=tmp_path)
    assert json.loads((tmp_path / pt.MANIFEST).read_text()) == {"format": 1, "models": {"env1": entry}}


def test_reproduce_record_writes_only_the_metrics_of_the_models_it_flew(copy_of_shipped: Path) -> None:
    from sb3_coma.experiments.reproduce.shipping import record_metrics

    def row(env: str, method: str) -> SimpleNamespace:
        return SimpleNamespace(
            env=env,
            method=method,
            n_trials=2,
            seed=0,
            fusion="mean",
            env_options={"noise": "moderate"},
            summary=lambda: {"f1_100_mean": 0.123456},
        )

    before = pt.read_manifest(copy_of_shipped)["models"]
    said: list[str] = []
    record_metrics([row("env1", "coma"), row("env3", "coma[mean-cnn]"), row("env1", "ag")], said.append)
    after = pt.read_manifest(copy_of_shipped)["models"]
    assert after["env1"]["metrics"] == {"f1_100_mean": 0.1235} == after["env3-mean-cnn"]["metrics"]
    assert after["env1"]["metrics_note"].startswith("measured by sb3-coma reproduce: 2 trials, env seeds 0..1")
    assert list(after["env1"]) == list(before["env1"])  # the keys keep their places
    assert {n: e for n, e in after.items() if n not in ("env1", "env3-mean-cnn")} == {
        n: e for n, e in before.items() if n not in ("env1", "env3-mean-cnn")
    }
    assert said == [f"recorded metrics in {copy_of_shipped / pt.MANIFEST}"]


def test_ship_models_rescore_writes_through_the_one_writer(copy_of_shipped: Path, monkeypatch) -> None:
    from sb3_coma.experiments import ship_models as sm

    spread = {"protocol": "unseen", "missions": 2, "noise": "moderate", "metrics": {"seed 0": {}}, "scored": "x"}
    monkeypatch.setattr(sm, "rescore_shipped_seed", lambda name: spread)
    before = pt.read_manifest(copy_of_shipped)["models"]
    assert sm.main(["--rescore", "env1"]) == 0
    after = pt.read_manifest(copy_of_shipped)["models"]
    assert after["env1"] == {**before["env1"], "seeds_unseen": spread} and list(after["env1"]) == list(before["env1"])
    assert {n: e for n, e in after.items() if n != "env1"} == {n: e for n, e in before.items() if n != "env1"}
