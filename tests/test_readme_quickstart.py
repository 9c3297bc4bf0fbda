"""The README's Python quick starts run as written and print what they measured."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"


def snippet(name: str) -> str:
    """The Python block between ``<!-- quickstart:NAME -->`` and ``<!-- /quickstart:NAME -->``."""
    text = README.read_text(encoding="utf-8")
    found = re.search(rf"<!-- quickstart:{name} -->\s*```python\n(.*?)```\s*<!-- /quickstart:{name} -->", text, re.S)
    assert found, f"README.md has no quickstart:{name} block"
    return found.group(1)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("name", "expected"),
    [
        (
            "uav",
            [
                r"one random mission: F1 \d\.\d{3}",
                r"COMA \(warm start\) \+ 50 missions: F1 \d\.\d{3}  entropy \d\.\d{3}",
                r"AG: F1",
                r"random: F1",
            ],
        ),
        (
            "own-env",
            [
                r"simple_spread, mean return per agent and episode: untrained -?\d+\.\d, after 50,000 joint steps -?\d+\.\d"
            ],
        ),
    ],
)
def test_quickstart_runs_as_written(name: str, expected: list[str], tmp_path: Path) -> None:
    if name == "own-env":
        pytest.importorskip("mpe2")
    script = tmp_path / f"{name}.py"
    script.write_text(snippet(name), encoding="utf-8")
    done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    for pattern in expected:
        assert re.search(pattern, done.stdout), f"{pattern!r} not in:\n{done.stdout}"
