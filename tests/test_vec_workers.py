"""Env copies in worker processes and Ray actors (``uav_ipp.make_vec_env(workers=, backend=)``).

The contract checked here: the same rows (agent ``a`` of copy ``e`` at ``e * n_agents + a``), the
same seeds and so bit-identical trajectories as the in-process vec env, attribute calls routed to
the worker that holds the row, and every failure one clear error instead of a hang.
"""

from __future__ import annotations

import os
import signal
import socket
import sys
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

import uav_ipp
from uav_ipp import ConfigError, EnvWorkerError, WorkerVecEnv, layout, workers
from uav_ipp.workers import connect_ray, split_copies

N_ENVS, WORKERS, N_AGENTS, BUDGET, SEED = 4, 2, 4, 3, 7
OPTIONS: dict[str, Any] = {"budget": BUDGET}


def rollout(venv: VecEnv, missions: int = 2, seed: int = SEED) -> list[Any]:
    """``missions`` whole missions of every copy, seeded, with random valid actions from a seeded rng."""
    venv.seed(seed)
    rng = np.random.default_rng(seed)
    obs = venv.reset()
    record: list[Any] = [obs, venv.reset_infos]
    for _ in range(missions * BUDGET):
        actions = np.array([rng.choice(np.flatnonzero(m)) for m in obs[layout.KEY_MASK]])
        obs, rewards, dones, infos = venv.step(actions)
        record.append((actions, obs, rewards, dones, infos))
    assert dones.all()
    return record


def assert_identical(a: Any, b: Any, where: str = "") -> None:
    """Bitwise equality of nested dicts / lists / arrays / numbers; VecMonitor's wall time aside."""
    if isinstance(a, dict):
        keys = set(a) - ({"t"} if {"r", "l", "t"} <= set(a) else set())
        assert keys == set(b) - ({"t"} if {"r", "l", "t"} <= set(b) else set()), where
        for k in keys:
            assert_identical(a[k], b[k], f"{where}.{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            assert_identical(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    else:
        assert type(a) is type(b) and a == b, f"{where}: {a!r} != {b!r}"


@pytest.fixture(scope="module")
def in_process() -> Iterator[VecEnv]:
    venv = uav_ipp.make_vec_env("env1", n_envs=N_ENVS, fusion="mean", seed=SEED, **OPTIONS)
    yield venv
    venv.close()


@pytest.fixture(scope="module")
def reference(in_process: VecEnv) -> list[Any]:
    return rollout(in_process)


@pytest.fixture(scope="module")
def subproc() -> Iterator[VecEnv]:
    venv = uav_ipp.make_vec_env("env1", n_envs=N_ENVS, fusion="mean", seed=SEED, workers=WORKERS, **OPTIONS)
    yield venv
    venv.close()


@pytest.fixture(scope="module")
def ray_session() -> Iterator[Any]:
    """A small local Ray (2 CPUs) for this module, shut down after it if this module started it."""
    ray = pytest.importorskip("ray")
    started = not ray.is_initialized()
    if started:
        ray.init(num_cpus=2, include_dashboard=False, ignore_reinit_error=True)
    yield ray
    if started:
        ray.shutdown()


def check_routing(venv: VecEnv, in_process: VecEnv) -> None:
    """Attribute calls reach the copy that holds each row, in the order asked."""
    assert venv.n_agents == N_AGENTS and venv.num_envs == N_ENVS * N_AGENTS
    assert venv.get_attr("n_agents") == [N_AGENTS] * venv.num_envs
    assert venv.render_mode is None and venv.get_attr("render_mode") == [None] * venv.num_envs
    assert list(venv.seed(3)) == [3 + i // N_AGENTS for i in range(venv.num_envs)]
    in_process.seed(3)
    venv.reset()
    in_process.reset()
    rows = [13, 0, 6, 7, 12]
    assert_identical(venv.env_method("positions_m", indices=rows), in_process.env_method("positions_m", indices=rows))
    assert_identical(venv.env_method("metrics", indices=rows), in_process.env_method("metrics", indices=rows))
    assert venv.env_is_wrapped(VecMonitor, indices=[1, 9]) == [False, False]
    venv.set_attr("render_mode", "ansi", indices=[9])  # row 9: copy 2, the first copy of worker 1
    assert venv.get_attr("render_mode") == ["ansi" if i // N_AGENTS == 2 else None for i in range(venv.num_envs)]
    venv.set_attr("render_mode", None)
    assert venv.get_attr("render_mode", indices=[8, 11]) == [None, None]
    # an exception inside a worker keeps its type and message, and the vec env goes on
    with pytest.raises(AttributeError, match="no_such_method"):
        venv.env_method("no_such_method", indices=[5])
    assert venv.get_attr("n_agents", indices=[15]) == [N_AGENTS]


# ================================================================================== layout
def test_split_copies_contiguous_blocks() -> None:
    assert split_copies(4, 2) == [range(0, 2), range(2, 4)]
    assert split_copies(5, 2) == [range(0, 2), range(2, 5)]
    assert split_copies(8, 3) == [range(0, 2), range(2, 5), range(5, 8)]
    for n in range(1, 9):
        for w in range(1, n + 1):
            blocks = split_copies(n, w)
            assert [e for b in blocks for e in b] == list(range(n)) and all(len(b) >= 1 for b in blocks)


def test_one_worker_is_the_in_process_vec_env(in_process: VecEnv) -> None:
    assert isinstance(in_process, VecMonitor) and isinstance(in_process.venv, uav_ipp.IppVecEnv)


# ============================================================================== subprocess
def test_subprocess_workers_fly_identical_missions(subproc: VecEnv, reference: list[Any]) -> None:
    assert isinstance(subproc, VecMonitor) and isinstance(subproc.venv, WorkerVecEnv)
    assert len(set(subproc.pids)) == WORKERS and os.getpid() not in subproc.pids
    assert_identical(rollout(subproc), reference, "trajectory")


def test_subprocess_routing(subproc: VecEnv, in_process: VecEnv) -> None:
    check_routing(subproc, in_process)


def test_sendfuse_in_workers_matches_one_process_then_closes() -> None:
    one = uav_ipp.make_vec_env("env1", n_envs=2, fusion="sendfuse", seed=SEED, **OPTIONS)
    two = uav_ipp.make_vec_env("env1", n_envs=2, fusion="sendfuse", seed=SEED, workers=2, **OPTIONS)
    try:
        assert_identical(rollout(two, missions=1), rollout(one, missions=1), "trajectory")
    finally:
        # close() drains a step in flight, stops every worker, and is idempotent and final
        inner = two.venv
        assert isinstance(inner, WorkerVecEnv)
        processes = inner._transport.processes  # type: ignore[attr-defined]
        two.step_async(np.zeros(two.num_envs, dtype=np.int64))
        two.close()
        two.close()
    assert not any(p.is_alive() for p in processes)
    with pytest.raises(RuntimeError, match="closed"):
        two.reset()


def test_error_inside_a_worker_is_raised_with_its_type() -> None:
    with pytest.raises(ConfigError, match="nonsense"):
        uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", workers=2, fusion_kwargs={"nonsense": 1}, **OPTIONS)


def test_dead_subprocess_worker_is_one_clear_error() -> None:
    venv = uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=0, workers=2, **OPTIONS)
    obs = venv.reset()
    pid = venv.pids[1]
    os.kill(pid, signal.SIGKILL)
    start = time.monotonic()
    with pytest.raises(EnvWorkerError, match=rf"env worker 1 \(pid {pid}\) died: killed by SIGKILL"):
        venv.step(np.zeros(len(obs[layout.KEY_MASK]), dtype=np.int64))
    assert time.monotonic() - start < 10
    with pytest.raises(EnvWorkerError, match="env worker 1"):  # and stays broken, without a hang
        venv.get_attr("n_agents")
    venv.close()
    venv.close()


# ==================================================================================== errors
@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"workers": 0}, "workers=0"),
        ({"workers": 1.5}, "workers=1.5"),
        ({"workers": "2"}, "workers='2'"),
        ({"workers": True}, "workers=True"),
        ({"workers": 5}, "workers=5: at most n_envs=4"),
        ({"workers": 2, "backend": "mpi"}, "backend='mpi'"),
        ({"backend": None}, "backend=None"),
        ({"workers": 2, "ray_address": "10.0.0.1:6379"}, "ray_address='10.0.0.1:6379'"),
        ({"workers": 2, "n_envs": 0}, "n_envs=0"),
    ],
)
def test_bad_scale_out_options(kwargs: dict[str, Any], match: str) -> None:
    kwargs = {"n_envs": N_ENVS, **kwargs}
    with pytest.raises(ConfigError, match=match):
        uav_ipp.make_vec_env("env1", fusion="mean", **kwargs)


def test_ray_backend_without_ray_is_one_line(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    with pytest.raises(ConfigError, match=r'pip install "sb3-coma\[ray\]"'):
        uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", workers=2, backend="ray", **OPTIONS)


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_ray_address_is_one_line() -> None:
    class NotStarted:  # the Ray calls connect_ray makes, before any of them reaches a network
        def is_initialized(self) -> bool:
            return False

        def init(self, **kwargs: Any) -> None:
            raise AssertionError("ray.init must not be tried on an address nobody listens at")

    address = f"127.0.0.1:{_closed_port()}"
    with pytest.raises(ConfigError, match=f"cannot reach the Ray cluster at ray_address='{address}'"):
        connect_ray(NotStarted(), address, 2)
    with pytest.raises(ConfigError, match="ray_address='nowhere'"):
        connect_ray(NotStarted(), "nowhere", 2)


# ======================================================================================= Ray
def test_ray_workers_fly_identical_missions_and_route(
    ray_session: Any, reference: list[Any], in_process: VecEnv, monkeypatch: pytest.MonkeyPatch
) -> None:
    venv = uav_ipp.make_vec_env("env1", n_envs=N_ENVS, fusion="mean", seed=SEED, workers=2, backend="ray", **OPTIONS)
    try:
        assert isinstance(venv.venv, WorkerVecEnv) and len(set(venv.pids)) == 2
        assert_identical(rollout(venv), reference, "trajectory")
        check_routing(venv, in_process)
        # its actors hold 2 CPUs: actors asking for more than the rest wait unplaced, and the vec
        # env gives up with the numbers instead of hanging
        monkeypatch.setattr(workers, "RAY_START_TIMEOUT_S", 2.0)
        more = int(ray_session.cluster_resources()["CPU"]) - 1  # 1 when this module started Ray
        with pytest.raises(EnvWorkerError, match=rf"of {more} Ray env workers not started after 2 s; .* CPUs, "):
            uav_ipp.make_vec_env("env1", n_envs=more, fusion="mean", workers=more, backend="ray", **OPTIONS)
    finally:
        venv.close()
    venv.close()


def test_ray_refuses_more_workers_than_cpus(ray_session: Any) -> None:
    cpus = int(ray_session.cluster_resources()["CPU"])  # 2 when this module started Ray
    match = f"workers={cpus + 1}: each Ray env worker takes one CPU and the Ray cluster has {cpus}"
    with pytest.raises(ConfigError, match=match):
        uav_ipp.make_vec_env("env1", n_envs=cpus + 1, fusion="mean", workers=cpus + 1, backend="ray", **OPTIONS)


def test_dead_ray_worker_is_one_clear_error(ray_session: Any) -> None:
    venv = uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=0, workers=2, backend="ray", **OPTIONS)
    obs = venv.reset()
    pid = venv.pids[1]
    os.kill(pid, signal.SIGKILL)
    with pytest.raises(EnvWorkerError, match=rf"env worker 1 \(pid {pid}\) died: "):
        venv.step(np.zeros(len(obs[layout.KEY_MASK]), dtype=np.int64))
    venv.close()
    venv.close()
