"""``sb3_coma.common.memory``: what ``release_freed_memory`` promises, each part checked so that it
fails when that part is gone.

1. It collects unreachable objects held by reference cycles (env parts), even with the automatic
   collector off or not yet due.
2. It then calls the C library's ``malloc_trim(0)`` (pad 0: give back every free page), once,
   after the collection, so the pages the collection freed go back too.
3. Where the C library has no ``malloc_trim`` it is a no-op that still collects.
4. On glibc the trim is real: freed heap blocks between survivors stay resident after ``free``
   and leave only when ``release_freed_memory`` runs.
"""

from __future__ import annotations

import gc
import platform
import weakref
from collections.abc import Iterator

import numpy as np
import pytest

from sb3_coma.common import memory

GLIBC = platform.system() == "Linux" and platform.libc_ver()[0] == "glibc"


class _Node:
    """A stand-in for an env part kept alive only by a reference cycle."""

    def __init__(self) -> None:
        self.other: _Node | None = None


def _cycle() -> weakref.ref[_Node]:
    """Two nodes pointing at each other, unreachable once this returns; a weak reference to one."""
    a, b = _Node(), _Node()
    a.other, b.other = b, a
    return weakref.ref(a)


@pytest.fixture
def no_automatic_gc() -> Iterator[None]:
    """The automatic collector off, so only an explicit collection can free a cycle."""
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


class _FakeTrim:
    """Records each call of the trim function and whether the cycle was already collected then."""

    def __init__(self, watched: weakref.ref[_Node]) -> None:
        self.watched = watched
        self.calls: list[tuple[int, bool]] = []

    def __call__(self, pad: int) -> int:
        self.calls.append((pad, self.watched() is None))
        return 1


def _rss_bytes() -> int:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * 4096


def test_release_collects_reference_cycles(no_automatic_gc: None) -> None:
    ref = _cycle()
    assert ref() is not None  # the cycle outlives its last name without a collection
    memory.release_freed_memory()
    assert ref() is None


def test_release_trims_the_heap_with_pad_zero_after_collecting(
    no_automatic_gc: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    ref = _cycle()
    trim = _FakeTrim(ref)
    monkeypatch.setattr(memory, "_malloc_trim", lambda: trim)
    memory.release_freed_memory()
    assert trim.calls == [(0, True)]  # once, pad 0, and only after the cycle was collected


def test_without_malloc_trim_it_still_collects_and_does_nothing_else(
    no_automatic_gc: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(memory, "_malloc_trim", lambda: None)  # macOS, musl, Windows
    ref = _cycle()
    memory.release_freed_memory()
    memory.release_freed_memory()  # safe to call again
    assert ref() is None


def test_malloc_trim_is_found_where_glibc_has_it_and_looked_up_once() -> None:
    found = memory._malloc_trim()
    assert memory._malloc_trim() is found  # cached: the library is opened once per process
    if GLIBC:
        assert callable(found)
        assert found(0) in (0, 1)  # glibc: 1 if memory was released, 0 if there was none to release
    else:
        assert found is None or callable(found)


@pytest.mark.skipif(not GLIBC, reason="glibc only")
def test_trim_returns_freed_heap_blocks() -> None:
    """Freed blocks between survivors (a fragmented heap, as many short-lived env copies leave it)
    stay resident after ``free`` and leave only when ``release_freed_memory`` trims the heap."""
    assert memory._malloc_trim() is not None
    memory.release_freed_memory()
    blocks = [np.ones(8_000, dtype=np.float64) for _ in range(1600)]  # 64 kB each (below mmap's 128 kB): 100 MB
    survivors = blocks[::10]
    peak = _rss_bytes()
    del blocks
    gc.collect()  # everything Python can free is freed; only the trim is left
    before = _rss_bytes()
    assert peak - before < 20e6  # free() alone keeps the 90 MB of holes resident
    memory.release_freed_memory()
    assert before - _rss_bytes() > 50e6
    assert len(survivors) == 160
