"""Shipped model files are checked against their recorded SHA-256 wherever they are loaded from.

The shipped zips live in ``sb3_coma/pretrained`` next to ``models.json``, which records each
file's SHA-256. An SB3 zip can run code when loaded, and a replaced shipped file would otherwise
be used under the shipped model's name; so every load of a file that IS one of them (decided by
where the file really is: symlinks and ``..`` resolved) verifies it first, ``COMA.load`` included.
A zip anywhere else is the user's own and passes unchecked. The application's
``sb3_coma.load_pretrained`` adds names, messages and the manifest's other records on top.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

#: The folder of the shipped models and of their manifest ``models.json``.
SHIPPED_DIR = Path(__file__).resolve().parents[1] / "pretrained"


class ShippedFileError(ValueError):
    """A shipped file that does not match its recorded checksum; the message names the file."""


def sha256_of(path: str | os.PathLike[str]) -> str:
    """Hex SHA-256 of a file, read in 1 MiB blocks."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def _recorded_digest(target: Path, folder: Path) -> tuple[str, str] | None:
    """(model name, recorded SHA-256) of a file of the shipped folder, or ``None``."""
    try:
        models = json.loads((folder / "models.json").read_text())["models"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    for name, info in sorted(models.items()):
        if isinstance(info, dict) and info.get("file") == target.name:
            return name, str(info.get("sha256", "")).lower()
    return None


def check_shipped_file(path: str | os.PathLike[str], folder: str | os.PathLike[str] | None = None) -> None:
    """Raise :class:`ShippedFileError` when ``path`` (or ``path + ".zip"``, as SB3 resolves it) is a
    shipped model whose bytes differ from the recorded checksum; do nothing for any other file."""
    home = Path(folder or SHIPPED_DIR).resolve()
    candidate = Path(path)
    if not candidate.is_file() and Path(f"{path}.zip").is_file():
        candidate = Path(f"{path}.zip")
    target = candidate.resolve()
    if target.parent != home or not target.is_file():
        return
    record = _recorded_digest(target, home)
    if record is None:
        return
    name, expected = record
    actual = sha256_of(target)
    if actual != expected:
        raise ShippedFileError(
            f"shipped model {name!r}: checksum mismatch for {target} (sha256 {actual}, recorded {expected}): "
            "the file was replaced or damaged; reinstall sb3-coma, or load your own copy from another folder"
        )
