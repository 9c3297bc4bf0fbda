"""Wall-clock measurements of single decisions: the costs table and ``reproduce`` time the same way.

Planning times are medians over repeats after a warm-up (numba's compilation and torch's first
call are not a decision's cost), in one torch thread (a UAV's computer has one core to spare).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
import torch as th

from sb3_coma.sendfuse.weights import default_weights_path, load_weights
from uav_ipp.geometry import overlap_matrix


def time_call(fn: Callable[[], Any], repeats: int, warmup: int = 5) -> tuple[float, float]:
    """(median, 90th percentile) wall ms of ``fn()``."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(max(int(repeats), 1)):
        tic = time.perf_counter()
        fn()
        times.append((time.perf_counter() - tic) * 1e3)
    times.sort()
    return statistics.median(times), times[min(len(times) - 1, int(0.9 * len(times)))]


@contextmanager
def one_thread() -> Iterator[None]:
    """Torch on one CPU thread within the block (restored after): a decision's time on one core."""
    before = th.get_num_threads()
    th.set_num_threads(1)
    try:
        yield
    finally:
        th.set_num_threads(before)


def torch_fusion(fusion: str, n_agents: int, comm: int, lattice: int) -> Callable[[], Any]:
    """One UAV's fusion of ``n_agents`` maps (all valid) + the projection to the lattice, in PyTorch."""
    rng = np.random.default_rng(0)
    received = th.as_tensor(rng.random((1, n_agents, comm, comm), dtype=np.float32))
    valid = th.ones((1, n_agents), dtype=th.bool)
    a = th.as_tensor(overlap_matrix(comm, float(lattice - 1), lattice).astype(np.float32))
    if fusion == "mean":

        def fuse() -> Any:
            return received.mean(dim=1)
    else:
        net = load_weights(default_weights_path(comm), expected_config={"grid_size": comm})

        def fuse() -> Any:
            return net.fuse(received, valid)

    def run() -> Any:
        with th.inference_mode():
            return th.clamp(a @ fuse() @ a.T, 0.0, 1.0)

    return run
