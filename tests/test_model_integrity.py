"""A model file is checked whatever way it reaches ``COMA.load``: a replaced shipped zip opened as a
file object, non-finite weights, and zip members SB3 never writes are each one clear error."""

from __future__ import annotations

import shutil
import zipfile
from pathlib import Path

import pytest
import torch as th

from sb3_coma import COMA
from sb3_coma.app.runs import load_checkpoint
from sb3_coma.cli import main
from sb3_coma.common import shipped
from sb3_coma.common.checkpoints import CheckpointError, validate_checkpoint


@pytest.fixture
def shipped_copy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "pretrained"
    shutil.copytree(shipped.SHIPPED_DIR, folder, ignore=shutil.ignore_patterns("*.safetensors"))
    monkeypatch.setattr(shipped, "SHIPPED_DIR", folder)
    return folder


def test_a_replaced_shipped_zip_is_refused_as_an_open_file_too(shipped_copy: Path) -> None:
    target = shipped_copy / "coma_env1.zip"
    with open(target, "rb") as fh:
        COMA.load(fh, device="cpu")  # intact: loads
    with open(target, "ab") as fh:
        fh.write(b"tampered")
    with (
        open(target, "rb") as fh,
        pytest.raises(shipped.ShippedFileError, match=r"checksum mismatch for .*coma_env1\.zip"),
    ):
        COMA.load(fh, device="cpu")


def test_non_finite_weights_are_named_on_load(
    shipped_copy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    model = COMA.load(shipped_copy / "coma_env1.zip", device="cpu")
    with th.no_grad():
        model.policy.actor.head.weight[0, 0] = float("nan")
    broken = tmp_path / "diverged.zip"
    model.save(broken)
    with pytest.raises(ValueError, match=r"diverged\.zip: tensor 'actor\.head\.weight' holds 1 NaN or inf"):
        COMA.load(broken, device="cpu")
    with pytest.raises(CheckpointError, match=r"actor\.head\.weight"):
        load_checkpoint(broken, device="cpu")
    argv = ["export", "--model", str(broken), "--out", str(tmp_path / "onnx")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "actor.head.weight" in err[0]
    assert not (tmp_path / "onnx").exists()


def test_a_zip_member_sb3_never_writes_is_refused(shipped_copy: Path, tmp_path: Path) -> None:
    carrier = tmp_path / "carrier.zip"
    shutil.copy(shipped_copy / "coma_env1.zip", carrier)
    validate_checkpoint(carrier)
    with zipfile.ZipFile(carrier, "a") as archive:
        archive.writestr("payload.py", "print('hello')")
    with pytest.raises(
        CheckpointError, match=r"carrier\.zip holds members a COMA model zip never has: \['payload\.py'\]"
    ):
        validate_checkpoint(carrier)
