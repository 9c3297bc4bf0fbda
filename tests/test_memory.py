"""``sb3_coma.common.memory``: freed heap goes back to the OS between mission batches."""

from __future__ import annotations

import platform

import numpy as np
import pytest

from sb3_coma.common import memory


def _rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096


def test_release_freed_memory_is_safe_to_call_anywhere():
    memory.release_freed_memory()
    memory.release_freed_memory()


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_trim_returns_freed_heap_blocks():
    """Freed blocks between survivors (a fragmented heap, as many short-lived env copies leave it)
    stay resident until ``malloc_trim`` hands their pages back."""
    assert memory._malloc_trim() is not None
    memory.release_freed_memory()
    blocks = [np.ones(8_000, dtype=np.float64) for _ in range(1600)]  # 64 kB each (below mmap's 128 kB): 100 MB
    survivors = blocks[::10]
    del blocks
    before = _rss_bytes()
    memory.release_freed_memory()
    assert before - _rss_bytes() > 50e6
    assert len(survivors) == 160
