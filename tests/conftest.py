"""Test-session settings shared by every test module.

The suite runs as ``pytest -n 2`` on two cores: each worker keeps torch (and the OpenMP pools of
subprocesses it starts) on one thread, because oversubscribed, spin-waiting thread pools made
small COMA runs up to 20x slower on a loaded 2-core machine.
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import pytest
import torch

torch.set_num_threads(1)


@pytest.fixture
def tmp_cwd(tmp_path, monkeypatch):
    """Run the test inside its tmp_path, so nothing it writes lands in the repository."""
    monkeypatch.chdir(tmp_path)
    return tmp_path
