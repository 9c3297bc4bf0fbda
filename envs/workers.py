"""Env copies stepped in worker processes (one machine) or Ray actors (one machine or a cluster).

Why: one env copy steps at a few hundred joint steps/s on one core (README, Speed), so a learner
that collects from ``n_envs`` copies in its own process leaves the other cores idle. Here the
copies are split into ``workers`` batches; each worker builds its batch with exactly the
in-process pipeline (ParallelEnv -> SuperSuit concat -> fusion wrapper -> :class:`IppVecEnv`,
without VecMonitor), so the fusion still runs batched over the worker's agents, and the learner
holds one SB3 ``VecEnv`` (:class:`WorkerVecEnv`) that scatters actions and gathers the results.

* **Layout.** Copy ``e`` of ``n_envs`` goes to worker ``w`` with ``w * n_envs // W <= e <
  (w + 1) * n_envs // W`` (contiguous blocks; with an uneven split the later workers hold one
  more copy). Results are concatenated in worker order, so agent ``a`` of copy ``e`` stays at
  row ``e * n_agents + a``, as in :class:`IppVecEnv`.
* **Seeds.** ``seed(s)`` gives copy ``e`` the seed ``s + e`` (worker ``w`` is seeded with ``s`` plus
  its first copy), so a seeded run flies the same missions, bit for bit, whatever ``workers`` and
  the backend are.
* **Protocol.** SB3's ``SubprocVecEnv``: one ``(command, data)`` message per worker and call over a
  ``multiprocessing`` pipe, the env factory shipped in a ``CloudpickleWrapper``, ``forkserver``
  (else ``spawn``) processes, ``step_async``/``step_wait``; ``get_attr``/``set_attr``/``env_method``
  go only to the workers that hold the requested rows. Unlike SB3, every reply says whether the
  command failed, so an exception inside a worker is raised in the learner with its own type and
  message (and the worker's traceback as its cause), and a worker that dies is reported as
  :class:`EnvWorkerError` instead of a hang: the learner polls the pipe and checks the process.
* **Ray.** ``backend="ray"`` runs the same worker class (:class:`WorkerCore`) as Ray actors of one
  CPU each, on this machine or on any node of a cluster (``ray_address``); ``ray`` is imported only
  then.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import multiprocessing as mp
import os
import pickle
import signal
import socket
import sys
import traceback
from abc import ABC, abstractmethod
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.process import BaseProcess
from pathlib import Path
from types import FrameType
from typing import Any

import gymnasium
import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import (
    CloudpickleWrapper,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)

from .config import ConfigError, IppConfig, invalid_option
from .fusion import RAW_FUSION, available_fusions, fusion_factory
from .vec_env import IppVecEnv
from .vec_env import make_vec_env as make_in_process_vec_env

#: ``backend=`` values of :func:`make_worker_vec_env` (and ``uav_ipp.make_vec_env``).
BACKENDS = ("subprocess", "ray")
#: How often (s) a waiting learner checks that the worker it waits for is still alive.
POLL_INTERVAL_S = 0.1
#: How long (s) ``close()`` waits for a worker to finish before it terminates it.
CLOSE_TIMEOUT_S = 10.0
#: How long (s) a vec env waits for its Ray actors to be placed and built before it gives up.
RAY_START_TIMEOUT_S = 180.0
RAY_MISSING = "backend='ray' needs the ray package: pip install \"sb3-coma[ray]\""


class EnvWorkerError(RuntimeError):
    """A worker process or Ray actor died (or cannot be reached); the vec env cannot go on."""


class _RemoteTraceback(Exception):
    """The worker's formatted traceback, attached as ``__cause__`` of a re-raised exception."""

    def __init__(self, text: str) -> None:
        super().__init__(text)
        self.text = text

    def __str__(self) -> str:
        return self.text


# ====================================================================================== layout
def split_copies(n_envs: int, workers: int) -> list[range]:
    """The env copies of each worker: contiguous blocks ``[w * n // W, (w + 1) * n // W)``."""
    return [range(w * n_envs // workers, (w + 1) * n_envs // workers) for w in range(workers)]


def check_workers(n_envs: int, workers: Any, backend: Any, ray_address: Any) -> None:
    """One-line :class:`ConfigError` for bad scale-out options (``n_envs`` already checked), one
    (option, value, accepted, what is allowed) row per option, checked in this order."""
    is_count = isinstance(workers, (int, np.integer)) and not isinstance(workers, bool)
    rules = (
        ("workers", workers, is_count and workers >= 1, "an integer >= 1 (processes or Ray actors)"),
        (
            "workers",
            workers,
            is_count and workers <= n_envs,
            f"at most n_envs={n_envs} (each worker holds at least one env copy)",
        ),
        ("backend", backend, backend in BACKENDS, f"one of {list(BACKENDS)}"),
        (
            "ray_address",
            ray_address,
            ray_address is None or (backend == "ray" and isinstance(ray_address, str) and bool(ray_address)),
            "a Ray address 'HOST:PORT' (or 'auto'), used only with backend='ray'",
        ),
    )
    for option, value, accepted, allowed in rules:
        if not accepted:
            invalid_option(option, value, allowed)


# ================================================================================= worker side
@dataclass(frozen=True)
class WorkerSpec:
    """What one worker builds: ``n_envs`` copies of one resolved config, fused with ``fusion``."""

    config: IppConfig
    n_envs: int
    fusion: str
    fusion_kwargs: dict[str, Any] | None = None


def _one_thread() -> None:
    """Workers share the machine's cores: one intra-op thread each (torch, for SenDFuse) avoids
    oversubscribed, spin-waiting thread pools. torch is optional for ``envs``."""
    try:
        import torch
    except ImportError:
        return
    torch.set_num_threads(1)


class WorkerCore:
    """The worker side, the same for a process and a Ray actor: one :class:`IppVecEnv` batch,
    one command at a time. :meth:`handle` never raises: it returns ``(True, result)`` or
    ``(False, (exception, traceback text))``, so both transports report failures the same way."""

    def __init__(self, spec: WorkerSpec) -> None:
        self.spec = spec
        self.venv: IppVecEnv | None = None

    def handle(self, cmd: str, data: Any) -> tuple[bool, Any]:
        try:
            return True, self._dispatch(cmd, data)
        except Exception as exc:
            return False, (_portable(exc), traceback.format_exc())

    def _build(self) -> dict[str, Any]:
        _one_thread()
        spec = self.spec
        venv = make_in_process_vec_env(
            spec.config, n_envs=spec.n_envs, fusion=spec.fusion, seed=None, monitor=False,
            fusion_kwargs=spec.fusion_kwargs,
        )  # fmt: skip
        assert isinstance(venv, IppVecEnv)
        self.venv = venv
        return {
            "pid": os.getpid(),
            "num_envs": venv.num_envs,
            "n_agents": venv.n_agents,
            "observation_space": venv.observation_space,
            "action_space": venv.action_space,
        }

    def _dispatch(self, cmd: str, data: Any) -> Any:
        """Run one command of :data:`_COMMANDS` (only :class:`WorkerVecEnv` sends them, ``build``
        first, so an unknown or early command is a programming error)."""
        if cmd == "build":
            return self._build()
        assert self.venv is not None, f"env worker received {cmd!r} before 'build'"
        return _COMMANDS[cmd](self.venv, data)


def _step(venv: IppVecEnv, actions: Any) -> Any:
    venv.step_async(actions)
    return venv.step_wait()


#: What a worker does for each command of the learner, given its vec env and the command's data.
_COMMANDS: dict[str, Callable[[IppVecEnv, Any], Any]] = {
    "step": _step,
    "reset": lambda venv, _: (venv.reset(), venv.reset_infos),
    "seed": lambda venv, seed: list(venv.seed(seed)),
    "mission_stride": lambda venv, stride: venv.set_mission_stride(stride),
    "get_attr": lambda venv, d: venv.get_attr(d[0], indices=d[1]),
    "set_attr": lambda venv, d: venv.set_attr(d[0], d[1], indices=d[2]),
    "env_method": lambda venv, d: venv.env_method(d[0], *d[1], indices=d[3], **d[2]),
    "is_wrapped": lambda venv, d: venv.env_is_wrapped(d[0], indices=d[1]),
    "get_images": lambda venv, _: list(venv.get_images()),
    "close": lambda venv, _: venv.close(),
}


def _portable(exc: BaseException) -> BaseException:
    """The exception itself if it survives pickling, else a ``RuntimeError`` with its text."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _pipe_worker(remote: Connection, parent_remote: Connection, spec: CloudpickleWrapper) -> None:
    """Process target (SB3's ``_worker`` shape): serve commands until ``close`` or a closed pipe.

    Ctrl-C reaches the whole process group; the worker ignores it, so the learner decides (SB3's
    Ctrl-C handling saves a model, and may still step or close the env). A learner that exits
    without ``close()`` ends its daemon workers; one killed outright closes their pipes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    parent_remote.close()
    core = WorkerCore(spec.var)
    try:
        while True:
            try:
                cmd, data = remote.recv()
            except EOFError:
                break
            reply = core.handle(cmd, data)
            try:
                remote.send(reply)
            except (pickle.PicklingError, TypeError, AttributeError) as exc:  # an unpicklable result
                remote.send((False, (RuntimeError(f"{cmd}: the result cannot be sent back: {exc}"), "")))
            if cmd == "close":
                break
    finally:
        remote.close()


# ======================================================================= the __main__ guard
#: The guard a script that starts worker processes needs, as the error names it.
MAIN_GUARD = 'if __name__ == "__main__":'


def _main_is_rerun() -> bool:
    """Whether a ``spawn`` / ``forkserver`` child re-runs this process's ``__main__`` before it
    serves (``multiprocessing.spawn.get_preparation_data``): a script run by path, or a module
    run with ``-m`` other than a package's ``__main__``; not ``python -c`` nor an interactive session."""
    main = sys.modules.get("__main__")
    name = getattr(getattr(main, "__spec__", None), "name", None)
    if name is not None:
        return not (name == "__main__" or name.endswith(".__main__"))
    return getattr(main, "__file__", None) is not None


@functools.lru_cache(maxsize=8)
def _guarded_lines(filename: str, stamp: float) -> tuple[tuple[int, int], ...] | None:
    """The line ranges of the ``if`` statements of a script that test ``__name__`` (its guard,
    however spelt); ``None`` when its source cannot be read (then nothing is refused)."""
    try:
        tree = ast.parse(Path(filename).read_text(encoding="utf-8"), filename)
    except (OSError, SyntaxError, UnicodeDecodeError, ValueError):
        return None
    return tuple(
        (node.lineno, node.end_lineno or node.lineno)
        for node in ast.walk(tree)
        if isinstance(node, ast.If)
        and any(isinstance(name, ast.Name) and name.id == "__name__" for name in ast.walk(node.test))
    )


def check_main_guard(what: str, start_method: str) -> None:
    """Refuse to start ``start_method`` processes from the unguarded top level of the main script.

    A ``spawn`` / ``forkserver`` child first re-runs the parent's ``__main__`` script; a call at its
    top level, outside :data:`MAIN_GUARD`, would start workers again in every child, which
    multiprocessing stops with its "bootstrapping phase" error, so the parent saw only dead workers
    ("out of memory?"). Found on the caller's stack: the main script's module-level frame, at a
    line outside every ``if`` that tests ``__name__``.

    :raises RuntimeError: one line naming the call, the script and its line, and the guard
    """
    main = sys.modules.get("__main__")
    if start_method not in ("spawn", "forkserver") or main is None or not _main_is_rerun():
        return
    frame: FrameType | None = sys._getframe(1)
    while frame is not None and not (frame.f_globals is vars(main) and frame.f_code.co_name == "<module>"):
        frame = frame.f_back
    if frame is None:
        return  # not below the script's own top level (a thread, a callback of another process)
    script, line = frame.f_code.co_filename, frame.f_lineno
    try:
        guarded = _guarded_lines(script, os.stat(script).st_mtime)
    except OSError:
        return
    if guarded is None or any(first <= line <= last for first, last in guarded):
        return
    raise RuntimeError(
        f"{what} starts worker processes ({start_method}) from the top level of {script!r} (line {line}), "
        f"outside `{MAIN_GUARD}`: each worker re-runs that script first, so put the call under "
        f"`{MAIN_GUARD}` (or use workers=1)"
    )


# ================================================================================ transports
class _Transport(ABC):
    """How the learner talks to its workers: ``send`` one command, ``recv`` its reply in order."""

    def __init__(self, n_workers: int) -> None:
        self.n_workers = n_workers
        self.pids: list[int | None] = [None] * n_workers

    @abstractmethod
    def send(self, w: int, cmd: str, data: Any) -> None: ...

    @abstractmethod
    def recv_raw(self, w: int) -> tuple[bool, Any]: ...

    def recv_all_raw(self, ws: Sequence[int]) -> list[tuple[bool, Any]]:
        return [self.recv_raw(w) for w in ws]

    def await_start(self) -> None:
        """Return once every worker can answer its first command (the build), or raise. Processes
        start at once (a death while building is caught by :meth:`recv_raw`)."""
        return None

    @abstractmethod
    def shutdown(self) -> None:
        """Stop every worker; best effort, never raises (also after a worker died)."""

    def died(self, w: int, why: str) -> EnvWorkerError:
        pid = self.pids[w] if self.pids[w] is not None else "?"
        return EnvWorkerError(
            f"env worker {w} (pid {pid}) died: {why}; this vec env cannot continue (close it and build a new one)"
        )


class _PipeTransport(_Transport):
    """Worker processes and SB3-style pipes (``forkserver`` where available, else ``spawn``)."""

    def __init__(self, specs: Sequence[WorkerSpec], start_method: str | None = None) -> None:
        super().__init__(len(specs))
        if start_method is None:
            start_method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        check_main_guard(f"make_vec_env(workers={len(specs)})", start_method)
        ctx = mp.get_context(start_method)
        self.remotes: list[Connection] = []
        self.processes: list[BaseProcess] = []
        for w, spec in enumerate(specs):
            remote, work_remote = ctx.Pipe()
            args = (work_remote, remote, CloudpickleWrapper(spec))
            # daemon=True: if the learner crashes, its workers do not outlive it
            process = ctx.Process(target=_pipe_worker, args=args, daemon=True)  # type: ignore[attr-defined]
            process.start()
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(process)
            self.pids[w] = process.pid

    def _exit_reason(self, w: int) -> str:
        code = self.processes[w].exitcode
        if code is None:
            return "its pipe closed"
        if code < 0:
            try:
                return f"killed by {signal.Signals(-code).name}"
            except ValueError:
                return f"killed by signal {-code}"
        return f"exit code {code}"

    def _dead(self, w: int) -> EnvWorkerError:
        self.processes[w].join(timeout=1.0)  # reap it, so its exit code is known
        return self.died(w, self._exit_reason(w))

    @contextlib.contextmanager
    def _pipe_to(self, w: int) -> Iterator[Connection]:
        """Worker ``w``'s pipe; a pipe that breaks (the worker died) becomes the one error naming
        the worker and why it died."""
        try:
            yield self.remotes[w]
        except (EOFError, OSError):  # OSError: BrokenPipeError, ConnectionResetError, ...
            raise self._dead(w) from None

    def send(self, w: int, cmd: str, data: Any) -> None:
        with self._pipe_to(w) as remote:
            remote.send((cmd, data))

    def recv_raw(self, w: int) -> tuple[bool, Any]:
        process = self.processes[w]
        with self._pipe_to(w) as remote:
            while not remote.poll(POLL_INTERVAL_S) and process.is_alive():
                pass  # a dead worker's pipe holds what it sent, then reads as closed (EOFError)
            return remote.recv()

    def shutdown(self) -> None:
        for remote, process in zip(self.remotes, self.processes):
            if process.is_alive():
                with contextlib.suppress(OSError, EOFError):
                    remote.send(("close", None))
        for process in self.processes:
            process.join(timeout=CLOSE_TIMEOUT_S)
            if process.is_alive():
                process.terminate()
                process.join(timeout=1.0)
        for remote in self.remotes:
            remote.close()


class _RayTransport(_Transport):
    """Ray actors running :class:`WorkerCore`; replies are object refs fetched in order."""

    def __init__(self, specs: Sequence[WorkerSpec], ray_address: str | None) -> None:
        super().__init__(len(specs))
        self.ray = import_ray()
        connect_ray(self.ray, ray_address, len(specs))
        actor_class = self.ray.remote(num_cpus=1, max_restarts=0)(WorkerCore)
        self.actors = [actor_class.remote(spec) for spec in specs]
        self.pending: list[deque[Any]] = [deque() for _ in specs]
        self.started = False  # every actor placed and built: close() asks them to close first

    def send(self, w: int, cmd: str, data: Any) -> None:
        self.pending[w].append(self.actors[w].handle.remote(cmd, data))

    def await_start(self) -> None:
        """Actors reserve one CPU each and wait, unplaced, while the cluster's CPUs are taken (by
        another Ray vec env not closed, say): give up after a while with the numbers, not hang."""
        refs = [pending[0] for pending in self.pending]
        ready, _ = self.ray.wait(refs, num_returns=len(refs), timeout=RAY_START_TIMEOUT_S)
        if len(ready) < len(refs):
            total = float(self.ray.cluster_resources().get("CPU", 0.0))
            free = float(self.ray.available_resources().get("CPU", 0.0))
            raise EnvWorkerError(
                f"{len(refs) - len(ready)} of {len(refs)} Ray env workers not started after {RAY_START_TIMEOUT_S:g} s; "
                f"each takes one CPU and the Ray cluster has {total:g} CPUs, {free:g} free "
                "(close other Ray vec envs, or give Ray more CPUs)"
            )
        self.started = True

    def recv_raw(self, w: int) -> tuple[bool, Any]:
        ref = self.pending[w].popleft()
        try:
            return self.ray.get(ref)
        except self.ray.exceptions.RayActorError as exc:
            raise self.died(w, str(exc).splitlines()[0]) from None

    def recv_all_raw(self, ws: Sequence[int]) -> list[tuple[bool, Any]]:
        """One ``ray.get`` for all replies (the common case); one by one to name a dead actor."""
        refs = [self.pending[w].popleft() for w in ws]
        try:
            return self.ray.get(refs)
        except self.ray.exceptions.RayActorError:
            for w, ref in zip(ws, refs):
                self.pending[w].appendleft(ref)
            return [self.recv_raw(w) for w in ws]

    def shutdown(self) -> None:
        if self.started:
            refs = [actor.handle.remote("close", None) for actor in self.actors]
            with contextlib.suppress(Exception):  # an actor already dead fails its close; kill it anyway
                self.ray.wait(refs, num_returns=len(refs), timeout=CLOSE_TIMEOUT_S)
        for actor in self.actors:
            with contextlib.suppress(Exception):
                self.ray.kill(actor)


# ======================================================================================= Ray
def import_ray() -> Any:
    """``ray``, imported only for ``backend="ray"`` (an optional dependency: the ``ray`` extra)."""
    try:
        import ray
    except ImportError as exc:
        raise ConfigError(RAY_MISSING) from exc
    return ray


def _probe(address: str) -> None:
    """Fail fast on an address nobody listens at: ``ray.init`` would retry for minutes."""
    if address in ("auto", "local"):
        return
    hostport = address.split("://", 1)[-1].rstrip("/")
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"invalid option ray_address={address!r}: 'HOST:PORT' (e.g. '10.0.0.1:6379') or 'auto'")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=5.0).close()
    except OSError as exc:
        raise ConfigError(
            f"cannot reach the Ray cluster at ray_address={address!r} ({exc}); start its head with "
            "`ray start --head --port=6379`, or pass ray_address=None for a local Ray"
        ) from None


def connect_ray(ray: Any, address: str | None, workers: int) -> None:
    """Join Ray unless this process already has: ``address`` (or ``RAY_ADDRESS``) names a running
    cluster; without either, a new local Ray with one CPU per core (at least ``workers``)."""
    if not ray.is_initialized():
        target = address or os.environ.get("RAY_ADDRESS") or None
        kwargs: dict[str, Any] = {"ignore_reinit_error": True, "include_dashboard": False}
        if target is None:
            kwargs.update(address="local", num_cpus=max(workers, os.cpu_count() or 1))
        else:
            _probe(target)
            kwargs["address"] = target
        try:
            ray.init(**kwargs)
        except (ConnectionError, RuntimeError, ValueError, TimeoutError) as exc:
            line = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ConfigError(f"cannot connect to the Ray cluster at ray_address={target!r}: {line}") from None
    total = float(ray.cluster_resources().get("CPU", 0.0))
    if total < workers:
        raise ConfigError(
            f"invalid option workers={workers}: each Ray env worker takes one CPU and the Ray cluster has {total:g}"
        )


# ================================================================================ learner side
class WorkerVecEnv(VecEnv):
    """SB3 ``VecEnv`` over ``len(specs)`` workers, each holding a batch of env copies.

    Rows are concatenated in worker order (worker ``w``'s rows follow worker ``w - 1``'s), so the
    row of agent ``a`` of copy ``e`` is ``e * n_agents + a`` as in :class:`IppVecEnv`.
    ``pids`` are the workers' process ids (Ray actors included)."""

    def __init__(
        self,
        specs: Sequence[WorkerSpec],
        backend: str = "subprocess",
        ray_address: str | None = None,
        start_method: str | None = None,
    ) -> None:
        self.waiting = False
        self.closed = False
        self.backend = backend
        self._broken: EnvWorkerError | None = None
        self._transport: _Transport = (
            _RayTransport(specs, ray_address) if backend == "ray" else _PipeTransport(specs, start_method)
        )
        try:
            for w in range(len(specs)):
                self._transport.send(w, "build", None)
            self._transport.await_start()
            metas = [self._unwrap(r) for r in self._transport.recv_all_raw(range(len(specs)))]
        except BaseException:
            self._transport.shutdown()
            raise
        self.pids: list[int] = [int(m["pid"]) for m in metas]
        self._transport.pids = list(self.pids)
        self.n_agents = int(metas[0]["n_agents"])
        self.n_copies = sum(spec.n_envs for spec in specs)
        rows = np.cumsum([0] + [int(m["num_envs"]) for m in metas])
        self._row_bounds = [(int(rows[w]), int(rows[w + 1])) for w in range(len(specs))]
        self._first_copy = [int(rows[w]) // self.n_agents for w in range(len(specs))]
        super().__init__(int(rows[-1]), metas[0]["observation_space"], metas[0]["action_space"])

    @property
    def n_workers(self) -> int:
        return len(self._row_bounds)

    # ------------------------------------------------------------------ messaging
    def _unwrap(self, reply: tuple[bool, Any]) -> Any:
        ok, payload = reply
        if ok:
            return payload
        exc, text = payload
        raise exc from (_RemoteTraceback(text) if text else None)

    @contextlib.contextmanager
    def _marks_broken(self) -> Iterator[None]:
        """A worker that died breaks this vec env for good: remember its error for every later call."""
        try:
            yield
        except EnvWorkerError as exc:
            self._broken = exc
            raise

    def _checked(self) -> None:
        if self.closed:
            raise RuntimeError("this vec env is closed")
        if self._broken is not None:
            raise self._broken

    def _call_all(self, cmd: str, data: Sequence[Any], ws: Sequence[int] | None = None) -> list[Any]:
        """Send ``data[k]`` to worker ``ws[k]`` (all workers by default), then gather in order."""
        ws = list(range(self._transport.n_workers)) if ws is None else list(ws)
        with self._marks_broken():
            for w, d in zip(ws, data):
                self._transport.send(w, cmd, d)
            replies = self._transport.recv_all_raw(ws)
        return [self._unwrap(r) for r in replies]

    def _route(self, indices: VecEnvIndices) -> tuple[list[int], list[list[int]], list[list[int]]]:
        """Workers holding the requested rows, each one's local rows, and where each result goes."""
        by_worker: dict[int, tuple[list[int], list[int]]] = {}
        for pos, i in enumerate(self._get_indices(indices)):
            w = next(k for k, (lo, hi) in enumerate(self._row_bounds) if lo <= i < hi)
            local, where = by_worker.setdefault(w, ([], []))
            local.append(i - self._row_bounds[w][0])
            where.append(pos)
        ws = sorted(by_worker)
        return ws, [by_worker[w][0] for w in ws], [by_worker[w][1] for w in ws]

    def _routed(self, cmd: str, make: Any, indices: VecEnvIndices) -> list[Any]:
        """Run ``cmd`` on the workers that hold ``indices``; results in the order of ``indices``."""
        self._checked()
        ws, locals_, wheres = self._route(indices)
        results = self._call_all(cmd, [make(local) for local in locals_], ws)
        out: list[Any] = [None] * sum(len(where) for where in wheres)
        for where, result in zip(wheres, results):
            for pos, value in zip(where, result if result is not None else [None] * len(where)):
                out[pos] = value
        return out

    # ------------------------------------------------------------------ core API
    def reset(self) -> VecEnvObs:
        self._checked()
        results = self._call_all("reset", [None] * self.n_workers)
        self.reset_infos = [dict(info) for _, infos in results for info in infos]
        self._reset_seeds()
        self._reset_options()
        return concat_obs([obs for obs, _ in results])

    def step_async(self, actions: np.ndarray) -> None:
        self._checked()
        actions = np.asarray(actions)
        with self._marks_broken():
            for w, (lo, hi) in enumerate(self._row_bounds):
                self._transport.send(w, "step", actions[lo:hi])
        self.waiting = True

    def step_wait(self) -> VecEnvStepReturn:
        assert self.waiting, "step_wait() called without step_async()"  # VecEnv protocol
        self.waiting = False
        with self._marks_broken():
            replies = self._transport.recv_all_raw(range(self.n_workers))
        results = [self._unwrap(r) for r in replies]
        observations = concat_obs([r[0] for r in results])
        rewards = np.concatenate([r[1] for r in results])
        dones = np.concatenate([r[2] for r in results])
        infos = [info for r in results for info in r[3]]
        return observations, rewards, dones, infos

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next reset: copy ``e`` gets ``seed + e``, wherever it runs."""
        self._checked()
        if seed is None:
            seed = int(np.random.randint(0, 2**31 - 1))
        seeds = self._call_all("seed", [int(seed) + first for first in self._first_copy])
        self._call_all("mission_stride", [self.n_copies] * self.n_workers)
        return [s for worker_seeds in seeds for s in worker_seeds]

    def close(self) -> None:
        """Stop the workers; safe to call twice and after a worker died."""
        if self.closed:
            return
        if self.waiting and self._broken is None:
            with contextlib.suppress(EnvWorkerError):
                self._transport.recv_all_raw(range(self.n_workers))
        self.waiting = False
        self._transport.shutdown()
        self.closed = True

    # ------------------------------------------------------------------ attributes
    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return self._routed("get_attr", lambda local: (attr_name, local), indices)

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        self._routed("set_attr", lambda local: (attr_name, value, local), indices)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any):
        return self._routed("env_method", lambda local: (method_name, method_args, method_kwargs, local), indices)

    def env_is_wrapped(self, wrapper_class: type[gymnasium.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return self._routed("is_wrapped", lambda local: (wrapper_class, local), indices)

    def get_images(self) -> Sequence[np.ndarray | None]:
        self._checked()
        return [image for images in self._call_all("get_images", [None] * self.n_workers) for image in images]


def concat_obs(parts: Sequence[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Join the workers' batched dict observations row-wise, keys in the workers' order (SB3's
    ``_stack_obs`` stacks one observation per env; a worker returns a batch of rows)."""
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}


def make_worker_vec_env(
    config: IppConfig,
    n_envs: int = 1,
    fusion: str = "sendfuse",
    seed: int | None = None,
    workers: int = 2,
    backend: str = "subprocess",
    ray_address: str | None = None,
    monitor: bool = True,
    fusion_kwargs: dict[str, Any] | None = None,
) -> VecEnv:
    """:class:`WorkerVecEnv` of ``n_envs`` copies of one resolved config on ``workers`` workers,
    seeded and wrapped in VecMonitor like the in-process pipeline. Counts and scale-out options
    come checked from the front door (``uav_ipp.make_vec_env``); the fusion is checked here, so a
    bad one is one line before any process or actor starts."""
    if fusion != RAW_FUSION and (not isinstance(fusion, str) or fusion not in available_fusions()):
        fusion_factory(fusion)  # raises the usual "unknown fusion" error
    specs = [
        WorkerSpec(config, len(block), fusion, dict(fusion_kwargs) if fusion_kwargs else None)
        for block in split_copies(int(n_envs), int(workers))
    ]
    venv: VecEnv = WorkerVecEnv(specs, backend=backend, ray_address=ray_address)
    if seed is not None:
        venv.seed(int(seed))
    if monitor:
        venv = VecMonitor(venv, info_keywords=("f1", "entropy"))
    return venv
