"""The speed scripts a reader reruns: COMA against PPO as whole processes in interleaved pairs."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAIRS = ROOT / "benchmarks" / "learn_pairs.py"


def test_learn_pairs_times_coma_against_ppo_pair_by_pair() -> None:
    pytest.importorskip("mpe2")
    done = subprocess.run(
        [sys.executable, str(PAIRS), "simple_spread", "--pairs", "1", "--joint-steps", "64"],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    )
    lines = done.stdout.strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith("pair 1:")  # the warm-up pair is not printed
    assert float(lines[0].rsplit(" ", 1)[1]) > 0
    assert lines[1].startswith("simple_spread: COMA / PPO wall time, median") and "over 1 pair" in lines[1]


def test_learn_pairs_names_a_bad_count_in_one_line() -> None:
    done = subprocess.run([sys.executable, str(PAIRS), "simple_spread", "--pairs", "0"], capture_output=True, text=True)
    assert done.returncode == 2 and "--pairs 0" in done.stderr.strip().splitlines()[-1]


def test_learn_pairs_names_an_unknown_task_before_running_anything() -> None:
    done = subprocess.run([sys.executable, str(PAIRS), "no_such_task"], capture_output=True, text=True)
    assert done.returncode == 2 and "no_such_task" in done.stderr.strip().splitlines()[-1]
    assert "Traceback" not in done.stderr
