"""Hand freed heap memory back to the operating system after each evaluation and training run.

Every batch of missions builds env copies whose maps (a few MB each) are freed when the batch
closes, but glibc keeps the freed blocks in its heap: a long job that flies hundreds of batches
(``sb3-coma reproduce``) grew from 0.54 to 0.94 GB of resident memory without holding more data.
``malloc_trim(0)`` returns those blocks (measured: 8 evaluations of 20 missions stay at 0.55 GB
instead of climbing to 0.75 GB). Elsewhere (macOS, musl, Windows) this is a no-op.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools
import gc
from collections.abc import Callable


@functools.cache
def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's ``malloc_trim``, or ``None`` where the C library has none."""
    name = ctypes.util.find_library("c")
    try:
        return getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    except OSError:
        return None


def release_freed_memory() -> None:
    """Collect unreachable objects (env parts held by reference cycles), then trim the C heap.

    The collection costs ~0.26 s with a model loaded, so it runs once per ``evaluate`` call and
    once after training, not per batch of missions."""
    gc.collect()
    trim = _malloc_trim()
    if trim is not None:
        trim(0)
