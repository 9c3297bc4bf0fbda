"""Output folders: one writer per run folder, and multi-file outputs that appear all at once.

**One writer per folder** (:class:`FolderLock`). A run folder is written by one process at a
time: the trainer holds an exclusive, non-blocking ``flock`` on ``<folder>/.lock`` for the whole
run. The operating system drops the lock when the process ends, however it ends (SIGKILL
included), so a crashed run never leaves a folder locked and there is no stale lock to clean up.
The file records the holder (pid, host, start time) so that a refused second writer can say who
holds it. The file itself stays after the run (removing it would let two processes lock two
different files of one name); it is a few bytes and names the last writer. Where ``fcntl`` is
missing (Windows), folders are not locked.

**Staged outputs** (:func:`staged_output`). A command whose output is several files
(``reproduce``, ``evaluate``, ``noise-sweep``, ``export``) writes them into a staging folder next
to its ``--out`` (``<out>.partial-<pid>``, so on the same file system) and moves that folder into
place only when everything is written:

* ``--out`` did not exist: one ``rename``;
* ``--out`` exists: the entries of the old folder that this command did not write last time
  (files of other commands, the user's own) are hard-linked into the staging folder (copied where
  links are impossible), then the two folders are swapped with one atomic ``renameat2(...,
  RENAME_EXCHANGE)`` and the old one is deleted. Where that call is missing (not Linux, or a file
  system without it) the old folder is renamed aside (``<out>.old-<pid>``) and the new one renamed
  in; a crash between those two renames is finished by the next run.

So a SIGKILL at any moment leaves ``--out`` as the old complete output or the new complete one,
never a mix of two runs of the command. What the command wrote is listed in
``<out>/.sb3-coma-<command>.json`` (``"complete": true``), which is how the next run tells its own
files from others'. A run that finds a staging folder left by a dead process says so in one line
and deletes it (or, in the one case where it is complete and ``--out`` is missing, moves it in).
SIGTERM while a staged output is open raises :class:`OutputInterrupted` (the CLI exits with 143
and one line: the output was not written); the staging folder is removed.
"""

from __future__ import annotations

import contextlib
import ctypes
import datetime as _dt
import errno
import fnmatch
import functools
import json
import os
import shutil
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from sb3_coma.common.checkpoints import DiskFullError, fsync_path

try:  # POSIX only; without it folders are not locked (documented above)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "LOCK_FILE",
    "FolderInUseError",
    "FolderLock",
    "LockHolder",
    "OutputFolderError",
    "OutputInterrupted",
    "lock_holder",
    "manifest_name",
    "replace_problem",
    "staged_output",
]

#: The lock file of a run folder.
LOCK_FILE = ".lock"
#: The lock file of a staging folder (removed once the folder is in place).
STAGING_LOCK = ".sb3-coma-staging.lock"
_PARTIAL = ".partial-"
_ASIDE = ".old-"
_RENAME_EXCHANGE = 2  # linux/fs.h
_AT_FDCWD = -100


# =========================================================================== folder locks
@dataclass(frozen=True)
class LockHolder:
    """Who holds a folder lock, as its lock file says (any field may be unknown)."""

    pid: int | None = None
    host: str | None = None
    started: str | None = None

    def describe(self) -> str:
        """``pid 1234 (started 2026-12-02 02:30:00)``; the host only when it is not this one."""
        who = f"pid {self.pid}" if self.pid is not None else "another process"
        if self.host and self.host != socket.gethostname():
            who += f" on {self.host}"
        return who + (f" (started {self.started})" if self.started else "")


class FolderInUseError(RuntimeError):
    """Another process holds the folder's lock; :attr:`holder` says which."""

    def __init__(self, folder: Path, holder: LockHolder) -> None:
        super().__init__(f"{folder} is in use by {holder.describe()}")
        self.folder = folder
        self.holder = holder


def _read_holder(fd: int) -> LockHolder:
    """The holder record of an open lock file (empty or unreadable: an unknown holder)."""
    try:
        data = json.loads(os.pread(fd, 4096, 0).decode("utf-8") or "{}")
    except (OSError, ValueError):
        return LockHolder()
    if not isinstance(data, dict):
        return LockHolder()
    pid = data.get("pid")
    return LockHolder(
        pid=pid if isinstance(pid, int) else None,
        host=str(data["host"]) if data.get("host") else None,
        started=str(data["started"]) if data.get("started") else None,
    )


class FolderLock:
    """An exclusive, non-blocking ``flock`` on ``<folder>/<name>``, held until :meth:`release`
    or the end of the process (the OS drops it then, whatever killed the process).

    The descriptor is opened close-on-exec, so programs this process starts do not keep the
    folder locked after it dies.
    """

    def __init__(self, folder: str | os.PathLike[str], name: str = LOCK_FILE) -> None:
        self.folder = Path(folder)
        self.path = self.folder / name
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self) -> FolderLock:
        """Take the lock and write this process's record into the file.

        :raises FolderInUseError: another process (or another :class:`FolderLock` of this one)
            holds it; the file is left as it was
        """
        if self._fd is not None:
            return self
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            if fcntl is not None:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            holder = _read_holder(fd)
            os.close(fd)
            if exc.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise FolderInUseError(self.folder, holder) from None
            raise
        started = _dt.datetime.now().isoformat(sep=" ", timespec="seconds")
        record = {"pid": os.getpid(), "host": socket.gethostname(), "started": started}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(record) + "\n").encode("utf-8"), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Drop the lock (closing the descriptor releases the ``flock``); the file stays."""
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def lock_holder(folder: str | os.PathLike[str], name: str = LOCK_FILE) -> LockHolder | None:
    """Who holds ``<folder>/<name>`` now, or ``None`` when nobody does (or there is no such file).

    Probing takes the lock for an instant when it is free, and creates nothing.
    """
    if fcntl is None:  # pragma: no cover - Windows
        return None
    try:
        fd = os.open(Path(folder) / name, os.O_RDONLY | os.O_CLOEXEC)
    except (FileNotFoundError, NotADirectoryError):
        return None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                return _read_holder(fd)
            raise
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


# =========================================================================== staged outputs
class OutputFolderError(ValueError):
    """An ``--out`` that cannot be replaced as a whole (the current folder, or a file)."""


class OutputInterrupted(KeyboardInterrupt):
    """SIGTERM arrived while a staged output was being written: nothing was moved into place.

    A ``KeyboardInterrupt`` so that the ``except Exception`` guards of optional steps let it
    through, as they let Ctrl-C through.
    """

    def __init__(self, target: Path, signum: int, existed: bool) -> None:
        kept = "its previous content is untouched" if existed else "nothing was written there"
        super().__init__(f"stopped by {signal.Signals(signum).name}: --out {target} was not written ({kept})")
        self.target = target
        self.signum = signum


def manifest_name(command: str) -> str:
    """``.sb3-coma-<command>.json``: the record of what ``command`` wrote into its ``--out``."""
    return f".sb3-coma-{command}.json"


def replace_problem(target: str | os.PathLike[str]) -> str | None:
    """Why ``target`` cannot be replaced as a whole, or ``None``: it is a file, or it is (or
    holds) the current folder, which the swap would delete from under this process."""
    path = Path(target)
    if path.exists() and not path.is_dir():
        return "is a file, not a folder"
    real = Path(os.path.realpath(path))
    cwd = Path(os.path.realpath(Path.cwd()))
    if real == cwd or real in cwd.parents:
        return "is the current folder or holds it, and an output replaces its folder as a whole: pass a folder below it"
    return None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _sibling(target: Path, kind: str, pid: int) -> Path:
    return target.with_name(f"{target.name}{kind}{pid}")


def _siblings(target: Path, kind: str) -> Iterator[tuple[Path, int]]:
    """``(path, pid)`` of the ``<target><kind><pid>`` folders next to ``target``."""
    prefix = target.name + kind
    if not target.parent.is_dir():
        return
    for entry in target.parent.iterdir():
        tail = entry.name[len(prefix) :]
        if entry.name.startswith(prefix) and tail.isdigit() and entry.is_dir() and not entry.is_symlink():
            yield entry, int(tail)


def _read_manifest(folder: Path, command: str) -> dict[str, Any] | None:
    try:
        data = json.loads((folder / manifest_name(command)).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _write_manifest(folder: Path, command: str, complete: bool, entries: Iterable[str] = ()) -> None:
    record = {
        "command": command,
        "complete": complete,
        "pid": os.getpid(),
        "written": _dt.datetime.now().isoformat(sep=" ", timespec="seconds"),
        "entries": sorted(entries),
    }
    path = folder / manifest_name(command)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as handle:
        handle.write(json.dumps(record, indent=1) + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def _clean_stale(target: Path, command: str, say: Callable[[str], None]) -> None:
    """Deal with what interrupted runs left next to ``target``: staging folders of dead
    processes are deleted, except a complete one when ``target`` is missing (a crash between the
    two renames of the fallback swap), which is moved in; an old folder set aside by such a crash
    is put back when ``target`` is still missing, else deleted."""
    for folder, pid in sorted(_siblings(target, _PARTIAL)):
        alive = lock_holder(folder, STAGING_LOCK) is not None if (folder / STAGING_LOCK).exists() else _pid_alive(pid)
        if alive or pid == os.getpid():
            continue
        manifest = _read_manifest(folder, command) or {}
        if manifest.get("complete") is True and not os.path.lexists(target):
            (folder / STAGING_LOCK).unlink(missing_ok=True)
            os.rename(folder, target)
            say(f"moved {folder} into {target}: an interrupted run had written it completely")
            continue
        shutil.rmtree(folder, ignore_errors=True)
        say(f"removed {folder}: the unfinished output of an interrupted run (pid {pid}); starting clean")
    for folder, pid in sorted(_siblings(target, _ASIDE)):
        if _pid_alive(pid):
            continue
        if not os.path.lexists(target):
            os.rename(folder, target)
            say(f"restored {target} from {folder}, set aside by an interrupted run")
        else:
            shutil.rmtree(folder, ignore_errors=True)


def _lock_staging(staging: Path) -> FolderLock:
    """The staging folder's own lock. Nobody else wants it; a stale-folder probe of another run
    may hold it for an instant, hence the retries."""
    lock = FolderLock(staging, STAGING_LOCK)
    for _ in range(100):
        try:
            return lock.acquire()
        except FolderInUseError:
            time.sleep(0.01)
    return lock.acquire()


def _own_entries(target: Path, command: str, own: Iterable[str]) -> set[str]:
    """Names in ``target`` that the last run of ``command`` wrote: its manifest's list, or for a
    folder written before manifests existed, the names matching the command's ``own`` patterns
    (none when another command's manifest shows the folder is not such an old one)."""
    manifest = _read_manifest(target, command)
    names = {manifest_name(command), STAGING_LOCK}
    if manifest is not None and isinstance(manifest.get("entries"), list):
        return names | {str(e) for e in manifest["entries"]}
    if any(fnmatch.fnmatchcase(e.name, manifest_name("*")) for e in target.iterdir()):
        return names
    patterns = list(own)
    return names | {e.name for e in target.iterdir() if any(fnmatch.fnmatchcase(e.name, p) for p in patterns)}


def _link_or_copy(src: str, dst: str) -> None:
    """A hard link (instant, no extra space); a copy where the file system refuses links."""
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:
        shutil.copy2(src, dst, follow_symlinks=False)


def _carry_over(old: Path, new: Path, skip: set[str]) -> None:
    """Give ``new`` the entries of ``old`` it does not replace (others' files survive the swap);
    ``old`` itself is not changed, so a crash here leaves it whole."""
    for entry in old.iterdir():
        if entry.name in skip or os.path.lexists(new / entry.name):
            continue
        if entry.is_symlink():
            os.symlink(os.readlink(entry), new / entry.name)
        elif entry.is_dir():
            shutil.copytree(entry, new / entry.name, symlinks=True, copy_function=_link_or_copy)
        else:
            _link_or_copy(str(entry), str(new / entry.name))


@functools.cache
def _renameat2() -> Any:
    """libc's ``renameat2`` (Linux, glibc >= 2.28), or ``None``."""
    try:
        func = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    func.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    func.restype = ctypes.c_int
    return func


def _exchange(a: Path, b: Path) -> bool:
    """Swap two existing paths in one atomic step; ``False`` where the system cannot."""
    func = _renameat2()
    if func is None:
        return False
    if func(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.EOPNOTSUPP, errno.EPERM):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _swap_in(staging: Path, target: Path) -> None:
    """Move the complete ``staging`` folder to ``target``, replacing what is there as a whole."""
    for _ in range(3):
        if not os.path.lexists(target):
            try:
                os.rename(staging, target)
                return
            except OSError as exc:  # another run put a folder there meanwhile: swap with it
                if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                    raise
                continue
        if _exchange(staging, target):
            shutil.rmtree(staging, ignore_errors=True)  # the old output, now under the staging name
            return
        aside = _sibling(target, _ASIDE, os.getpid())
        os.rename(target, aside)
        os.rename(staging, target)
        shutil.rmtree(aside, ignore_errors=True)
        return
    raise OSError(errno.EEXIST, f"{target} keeps changing under another run", str(target))


class _TermGuard:
    """SIGTERM -> :class:`OutputInterrupted`, except once the swap has started (the output is
    then being put in place, and the command ends right after)."""

    def __init__(self, target: Path, existed: bool) -> None:
        self.target = target
        self.existed = existed
        self.swapping = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        if not self.swapping:
            raise OutputInterrupted(self.target, signum, self.existed)


@contextlib.contextmanager
def _sigterm_raises(guard: _TermGuard) -> Iterator[None]:
    """Install ``guard`` for SIGTERM (main thread only: Python delivers signals there)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, guard)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)


def _sync_tree(root: Path) -> None:
    """fsync every file and folder under ``root``, so that what the swap puts in place is on
    disk, not only in the page cache, should the machine go down right after."""
    for folder, _, files in os.walk(root):
        for name in [*files, "."]:
            fsync_path(os.path.join(folder, name))


def _commit(staging: Path, target: Path, command: str, own: Iterable[str], guard: _TermGuard) -> None:
    """Record what was written, keep others' entries of the old ``target``, swap it in."""
    written = [e.name for e in staging.iterdir() if e.name not in (STAGING_LOCK, manifest_name(command))]
    _sync_tree(staging)
    if target.is_dir():
        _carry_over(target, staging, _own_entries(target, command, own))
    _write_manifest(staging, command, complete=True, entries=written)
    guard.swapping = True
    _swap_in(staging, target)
    fsync_path(target.parent)  # the renames themselves
    (target / STAGING_LOCK).unlink(missing_ok=True)


@contextlib.contextmanager
def staged_output(
    target: str | os.PathLike[str],
    *,
    command: str,
    own: Iterable[str] = (),
    say: Callable[[str], None] = print,
) -> Iterator[Path]:
    """Write a multi-file output into a staging folder and put it at ``target`` at the end.

    Yields the staging folder (``<target>.partial-<pid>``, made fresh); write everything there.
    On leaving the block normally the folder replaces ``target`` as a whole (see the module
    docstring); on an exception, SIGTERM included (:class:`OutputInterrupted`), it is deleted
    and ``target`` is not touched.

    :param command: the writing command (``"evaluate"``...): names the manifest
    :param own: ``fnmatch`` patterns of the names this command writes, to tell its files from
        others' in a ``target`` written before manifests existed
    :param say: where the one-line notes about stale staging folders go
    :raises OutputFolderError: ``target`` is a file or the current folder (or holds it)
    """
    final = Path(target)
    problem = replace_problem(final)
    if problem is not None:
        raise OutputFolderError(f"--out {final} {problem}")
    final = Path(os.path.realpath(final))  # one spelling for the siblings and the swap; a link's folder
    _clean_stale(final, command, say)
    staging = _sibling(final, _PARTIAL, os.getpid())
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    lock = _lock_staging(staging)
    guard = _TermGuard(Path(target), existed=final.is_dir())
    try:
        with _sigterm_raises(guard):
            _write_manifest(staging, command, complete=False)
            yield staging
            _commit(staging, final, command, own, guard)
    except BaseException as exc:
        lock.release()
        shutil.rmtree(staging, ignore_errors=True)  # the new output, or after a swap the old one
        if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
            raise DiskFullError(
                errno.ENOSPC,
                f"the disk is full: --out {target} was not written and its previous content is untouched "
                "(nothing of this run was left behind); free some space and run it again",
            ) from None
        raise
    lock.release()
