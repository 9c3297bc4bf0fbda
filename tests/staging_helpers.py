"""Helpers of the staged-output tests (tests/test_staging.py, tests/test_output_ownership.py):
fingerprints of folders, dead pids, finished outputs and the staging marker."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

from sb3_coma.app import outputs
from sb3_coma.app.outputs import manifest_name


def snapshot(folder: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``folder`` (folders as ``"<dir>"``)."""
    out = {}
    for path in sorted(folder.rglob("*")):
        key = str(path.relative_to(folder))
        out[key] = "<dir>" if path.is_dir() else hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def siblings(target: Path) -> list[str]:
    return sorted(p.name for p in target.parent.iterdir() if p.name != target.name)


def dead_pid() -> int:
    """The pid of a process that has ended (so no live process has it, for now)."""
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def write_run(target: Path, command: str, files: dict[str, str], complete: bool = True) -> None:
    """An output of ``command`` (finished unless ``complete=False``): its files and its manifest."""
    target.mkdir(parents=True, exist_ok=True)
    for name, text in files.items():
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        (target / name).write_text(text)
    entries = sorted({name.split("/")[0] for name in files})
    record = {"command": command, "complete": complete, "entries": entries}
    (target / manifest_name(command)).write_text(json.dumps(record))


def mark(folder: Path, target: Path, pid: int, role: str = "staging", command: str = "evaluate") -> None:
    """The marker an sb3-coma run writes into its staging folder (``role="staging"``) or into an
    old output it is about to swap out or set aside (``"retired"``): only marked folders next to
    ``--out`` are ever cleaned up."""
    record = {"sb3_coma_staging": True, "role": role, "target": target.name, "command": command, "pid": pid}
    (folder / outputs.STAGING_MARKER).write_text(json.dumps(record))
