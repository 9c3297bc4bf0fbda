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
to its ``--out`` (``<out>.partial-<pid>``, so on the same file system) and puts them in place
only when everything is written. An output owns only what sb3-coma wrote:

* What a command wrote is listed in ``<out>/.sb3-coma-<command>.json`` (its manifest). An
  ``--out`` that exists, is not empty and holds anything that no manifest in it lists (and that is
  not itself a folder of sb3-coma output) is refused with one line before any work starts: pass an
  empty or new folder. So nothing is ever deleted, moved or overwritten because of its name.
* ``--out`` did not exist: one ``rename``.
* ``--out`` exists: the entries this command did not write last time (other commands' outputs)
  are hard-linked into the staging folder (copied where links are impossible), then the two
  folders are swapped with one atomic ``renameat2(..., RENAME_EXCHANGE)`` and the old one is
  deleted. Where that call is missing the old folder is renamed aside (``<out>.old-<pid>``) and the
  new one renamed in; a crash between those two renames is finished by the next run.
* ``--out`` cannot be renamed (a mount point such as a container volume: ``EBUSY``, ``EXDEV``):
  the new entries are put into the existing folder one by one, each with one atomic ``rename``,
  and the command's old entries are removed. The staging folder stays whole until the end.
* If putting the output in place fails anyway, the staging folder with the finished results is
  kept, and the one-line error says where. Only a failure of the command's own work (or SIGTERM)
  before that step deletes it.

Leftovers of interrupted runs are recognised by a marker, never by their names: every staging
folder holds ``.sb3-coma-staging.json`` (the target's name, the command, the writer's pid and a
random token), and an old output gets one (``"role": "retired"``) just before it is swapped out or
set aside. A later run, once the writer is dead, deletes an unfinished staging folder with one line,
moves a finished one in when ``--out`` is missing and otherwise leaves it alone (one line), and
restores a retired folder when ``--out`` is missing or else deletes it. A folder that is only
*named* like ``<out>.partial-123`` is never touched; one line says so.

So a SIGKILL at any moment leaves ``--out`` as the old complete output or the new complete one
(entry by entry where ``--out`` cannot be renamed), never a mix of two runs of the command.
SIGTERM while a staged output is written raises :class:`OutputInterrupted` (the CLI exits with 143
and one line: the output was not written); the staging folder is removed.
"""

from __future__ import annotations

import contextlib
import ctypes
import datetime as _dt
import errno
import functools
import json
import os
import re
import secrets
import shutil
import signal
import socket
import threading
import time
import unicodedata
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType
from typing import Any

from sb3_coma.common.checkpoints import DiskFullError, fsync_path

try:  # POSIX only; without it folders are not locked (documented above)
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

#: The lock file of a run folder.
LOCK_FILE = ".lock"
#: The lock file of a staging folder (removed once the folder is in place).
STAGING_LOCK = ".sb3-coma-staging.lock"
#: The marker that makes a folder next to ``--out`` sb3-coma's own (a staging folder, or an old
#: output on its way out): later runs touch a leftover folder only when it holds this.
STAGING_MARKER = ".sb3-coma-staging.json"
_PARTIAL = ".partial-"
_ASIDE = ".old-"
#: Temporary names inside ``--out`` while entries are put in one by one (listed in the manifest).
_INCOMING = ".sb3-coma-in-"
_OUTGOING = ".sb3-coma-out-"
_LEFTOVER_TAIL = re.compile(r"\d+(?:-\d+)?")
_MANIFEST_NAME = re.compile(r"\.sb3-coma-(.+)\.json")
#: ``rename`` errors meaning "this folder cannot be renamed": a mount point (EBUSY), another file
#: system (EXDEV), a protected parent (EPERM, EACCES). The output then goes in entry by entry.
_IMMOVABLE = frozenset({errno.EBUSY, errno.EXDEV, errno.EPERM, errno.EACCES})
#: How deep a folder of sb3-coma output may sit inside ``--out`` and still count as sb3-coma's.
_NESTING = 3
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

    def still_the_file(self) -> bool:
        """Whether the held lock is on the file now at :attr:`path` (a holder that removes its lock
        file as it finishes leaves a late opener locking an unlinked inode)."""
        try:
            return self._fd is not None and os.fstat(self._fd).st_ino == os.stat(self.path).st_ino
        except FileNotFoundError:
            return False

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
class _TargetLock:
    """One writer per ``--out``: an exclusive lock on ``.<name>.sb3-coma.lock`` beside the target,
    held while a staged output is written and committed, so a second command given the same
    ``--out`` is refused up front instead of replacing the first one's results as it commits.
    The lock file is removed on release; a process that opened it just before then finds its
    inode unlinked and counts the target as busy (no two holders)."""

    def __init__(self, final: Path, shown: str | os.PathLike[str]) -> None:
        self.lock: FolderLock | None = FolderLock(final.parent, f".{final.name}.sb3-coma.lock")
        self.shown = shown

    def __enter__(self) -> _TargetLock:
        if self.lock is None:
            return self
        try:
            self.lock.folder.mkdir(parents=True, exist_ok=True)
            self.lock.acquire()
        except FolderInUseError as exc:
            raise OutputFolderError(
                f"--out {self.shown} is being written by {exc.holder.describe()}; wait for it to finish or "
                "choose another --out"
            ) from None
        except OSError:  # a parent that takes no files (read-only around a mounted --out): no lock there
            self.lock = None
            return self
        if (
            not self.lock.still_the_file()
        ):  # the holder removed the file as it finished: count it as busy, once more later
            self.lock.release()
            raise OutputFolderError(f"--out {self.shown} was being written a moment ago; run the command again")
        return self

    def __exit__(self, *exc: object) -> None:
        if self.lock is None:
            return
        with contextlib.suppress(OSError):
            self.lock.path.unlink()
        self.lock.release()


class OutputFolderError(ValueError):
    """An ``--out`` that cannot take the output: a file, the current folder (or one holding it), a
    name sb3-coma does not make folders under, a folder holding files sb3-coma did not write, or a
    folder the finished output could not be put into (the message then says where it was kept)."""


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


def folder_name_problem(path: str | os.PathLike[str]) -> str | None:
    """Why ``path`` is no name for a folder that sb3-coma makes, or ``None``.

    A control character anywhere (a pasted newline or tab) makes a folder nobody can type; a path
    with no name of its own (``.``, ``..``, a root) or one starting with a dot ends up hidden:
    ``--run-dir .`` used to put the run into ``._2``.
    """
    text = os.fspath(path)
    bad = next((i for i, char in enumerate(text) if unicodedata.category(char) == "Cc"), None)
    if bad is not None:
        return f"holds a control character ({text[bad]!r} at position {bad})"
    name = Path(text).name
    if name in ("", ".", ".."):
        return "names no folder of its own ('.', '..' or a root)"
    if name.startswith("."):
        return "starts with a dot, which would make a hidden folder"
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


def _free_name(path: Path) -> Path:
    """``path``, or ``path-1``, ``path-2``... whichever is free: a folder of that name that is not
    sb3-coma's is never reused (a rename onto an empty folder would silently replace it)."""
    candidate, n = path, 0
    while os.path.lexists(candidate):
        n += 1
        candidate = path.with_name(f"{path.name}-{n}")
    return candidate


def _leftovers(target: Path, kind: str) -> list[Path]:
    """Folders next to ``target`` named like its staging (``.partial-``) or set-aside (``.old-``)
    folders. The name only nominates them: whether they are sb3-coma's is for their marker to say."""
    prefix = target.name + kind
    if not target.parent.is_dir():
        return []
    return sorted(
        entry
        for entry in target.parent.iterdir()
        if entry.name.startswith(prefix)
        and _LEFTOVER_TAIL.fullmatch(entry.name[len(prefix) :])
        and entry.is_dir()
        and not entry.is_symlink()
    )


def _read_json(path: Path) -> dict[str, Any] | None:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _write_json(path: Path, record: dict[str, Any]) -> None:
    """Write ``record`` through a ``.tmp`` file and one ``rename``: a reader sees all or nothing."""
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as handle:
        handle.write(json.dumps(record, indent=1) + "\n")
        handle.flush()
        os.fsync(handle.fileno())
    os.replace(tmp, path)


def _now() -> str:
    return _dt.datetime.now().isoformat(sep=" ", timespec="seconds")


def _read_manifest(folder: Path, command: str) -> dict[str, Any] | None:
    return _read_json(folder / manifest_name(command))


def _write_manifest(folder: Path, command: str, complete: bool, entries: Iterable[str] = ()) -> None:
    record = {"command": command, "complete": complete, "pid": os.getpid(), "written": _now()}
    _write_json(folder / manifest_name(command), {**record, "entries": sorted(entries)})


def _write_marker(folder: Path, target: Path, command: str, role: str, token: str) -> None:
    """Mark ``folder`` as sb3-coma's: a staging folder of ``target`` (``role="staging"``) or the
    old output of ``target`` on its way out (``"retired"``). Later runs touch a leftover folder
    only when it carries this, so a user's folder that merely has such a name is safe."""
    record = {"sb3_coma_staging": True, "role": role, "target": target.name, "command": command}
    record |= {"pid": os.getpid(), "host": socket.gethostname(), "token": token, "written": _now()}
    _write_json(folder / STAGING_MARKER, record)


def _read_marker(folder: Path, target: Path) -> dict[str, Any] | None:
    """``folder``'s marker when it is one of ``target``'s, else ``None`` (the folder is not ours)."""
    data = _read_json(folder / STAGING_MARKER)
    if data is None or data.get("sb3_coma_staging") is not True or data.get("target") != target.name:
        return None
    if data.get("role") not in ("staging", "retired") or not isinstance(data.get("pid"), int):
        return None
    return data


def _drop_marker(folder: Path) -> None:
    """Remove the marker from a folder that is ``--out`` again (best effort: it is only a hint)."""
    for name in (STAGING_MARKER, STAGING_MARKER + ".tmp"):
        with contextlib.suppress(OSError):
            (folder / name).unlink(missing_ok=True)


def _writer_alive(folder: Path, marker: dict[str, Any]) -> bool:
    """Whether the process that marked ``folder`` may still be writing it: its staging lock is held,
    or (no lock file, no ``fcntl``) its pid lives. Another machine's process cannot be checked, so it
    counts as alive."""
    if fcntl is not None and (folder / STAGING_LOCK).exists():
        return lock_holder(folder, STAGING_LOCK) is not None
    if marker.get("host") not in (None, socket.gethostname()):
        return True
    pid = int(marker["pid"])
    return pid != os.getpid() and _pid_alive(pid)


def _is_real_dir(path: Path) -> bool:
    return path.is_dir() and not path.is_symlink()


def _remove_entry(path: Path, strict: bool = True) -> None:
    """Delete a file, link or folder tree that sb3-coma wrote; errors only when ``strict``."""
    try:
        if _is_real_dir(path):
            shutil.rmtree(path)
        else:
            path.unlink(missing_ok=True)
    except OSError:
        if strict:
            raise


def _remove_tree(folder: Path) -> None:
    """Delete a marked folder, its marker last: a crash half-way leaves a folder that the next run
    still recognises and finishes deleting (best effort, as a leftover is harmless)."""
    with contextlib.suppress(OSError):
        for entry in os.scandir(folder):
            if entry.name != STAGING_MARKER:
                _remove_entry(Path(entry.path), strict=False)
    with contextlib.suppress(OSError):
        (folder / STAGING_MARKER).unlink(missing_ok=True)
    with contextlib.suppress(OSError):
        os.rmdir(folder)


def _not_ours(folder: Path, target: Path) -> str:
    return f"left {folder} alone: it is named like a staging folder of {target} but sb3-coma did not mark it as one"


def _settle_staging(folder: Path, target: Path, marker: dict[str, Any], say: Callable[[str], None]) -> None:
    """What a dead writer left under a staging name: an old output it swapped out (deleted); an
    unfinished output (deleted, one line); a finished one (moved in when ``target`` is missing,
    else left alone with one line: finished work is never deleted)."""
    if marker["role"] == "retired":
        _remove_tree(folder)
        return
    manifest = _read_manifest(folder, str(marker.get("command"))) or {}
    if manifest.get("complete") is not True:
        _remove_tree(folder)
        say(f"removed {folder}: the unfinished output of an interrupted run (pid {marker['pid']}); starting clean")
    elif not os.path.lexists(target):
        (folder / STAGING_LOCK).unlink(missing_ok=True)
        os.rename(folder, target)
        _drop_marker(target)
        say(f"moved {folder} into {target}: an interrupted run had written it completely")
    else:
        say(f"left {folder} as it is: it holds the finished output of an earlier run that was not put into {target}")


def _clean_stale(target: Path, say: Callable[[str], None]) -> None:
    """Deal with what interrupted runs left next to ``target``, recognised by their marker only
    (see the module docstring); a folder without one is named in one line and left alone."""
    for folder in _leftovers(target, _PARTIAL):
        marker = _read_marker(folder, target)
        if marker is None:
            say(_not_ours(folder, target))
        elif not _writer_alive(folder, marker):
            _settle_staging(folder, target, marker, say)
    for folder in _leftovers(target, _ASIDE):
        marker = _read_marker(folder, target)
        if marker is None:
            say(_not_ours(folder, target))
        elif marker["role"] == "retired" and not _writer_alive(folder, marker):
            if os.path.lexists(target):
                _remove_tree(folder)
                continue
            os.rename(folder, target)
            _drop_marker(target)
            say(f"restored {target} from {folder}, set aside by an interrupted run")


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


def _make_staging(target: Path) -> Path:
    """Create this run's staging folder: ``<target>.partial-<pid>``, or ``...-<n>`` when a folder
    that is not ours has that name (``mkdir`` never takes over what exists). A parent folder that
    cannot take it (read-only around a mounted ``--out``) is one line, before any work."""
    base = _sibling(target, _PARTIAL, os.getpid())
    for n in range(1000):
        staging = base if n == 0 else base.with_name(f"{base.name}-{n}")
        try:
            if n == 0:
                target.parent.mkdir(parents=True, exist_ok=True)
            staging.mkdir()
        except FileExistsError:
            if not target.parent.is_dir():
                raise OutputFolderError(f"--out {target}: {target.parent} is not a folder") from None
            continue
        except OSError as exc:
            raise OutputFolderError(
                f"--out {target}: cannot make the staging folder {staging.name} next to it ({exc.strerror}); "
                f"outputs are written there first, so {target.parent} must be writable"
            ) from None
        return staging
    raise OutputFolderError(f"no free name for a staging folder next to {target}")  # pragma: no cover


@dataclass(frozen=True)
class _Inventory:
    """What an existing folder holds, by who wrote it (:func:`_inventory`)."""

    own: frozenset[str]  # the command's entries: its manifest lists them and no other manifest does
    listed: frozenset[str]  # all that sb3-coma accounts for: manifests' entries, manifests, markers
    foreign: tuple[str, ...]  # the rest: never deleted, and refused before any work
    recorded: bool  # the folder holds at least one manifest


def _manifest_entries(folder: Path, name: str) -> set[str] | None:
    """The entries a manifest ``folder/name`` lists, or ``None`` when ``name`` is not a readable one."""
    if name == STAGING_MARKER or not _MANIFEST_NAME.fullmatch(name):
        return None
    data = _read_json(folder / name)
    if data is None or not isinstance(data.get("entries"), list):
        return None
    return {entry for entry in data["entries"] if isinstance(entry, str)}


def _inventory(folder: Path, command: str | None, depth: int = _NESTING) -> _Inventory:
    """Sort the entries of ``folder`` by the manifests in it: ``command``'s own, other sb3-coma
    outputs' (other commands', and folders that are themselves sb3-coma outputs, such as a
    ``noise-sweep --out results/sweep`` inside ``results``), and foreign ones, which only the
    user can have put there. Names decide nothing here: only what a manifest lists."""
    names = sorted(os.listdir(folder))
    manifests = {name: found for name in names if (found := _manifest_entries(folder, name)) is not None}
    mine = manifests.get(manifest_name(command), set()) if command else set()
    others: set[str] = set()
    for name, entries in manifests.items():
        if command is None or name != manifest_name(command):
            others |= entries
    housekeeping = {STAGING_LOCK, STAGING_MARKER, STAGING_MARKER + ".tmp", *manifests}
    housekeeping |= {name + ".tmp" for name in manifests}
    if command:
        housekeeping |= {manifest_name(command), manifest_name(command) + ".tmp"}
    listed = housekeeping | mine | others
    foreign = tuple(name for name in names if name not in listed and not _is_output(folder / name, depth - 1))
    return _Inventory(frozenset(mine - others), frozenset(listed), foreign, bool(manifests))


def _is_output(path: Path, depth: int) -> bool:
    """``path`` is a folder of sb3-coma output: it holds a manifest and nothing unaccounted for."""
    if depth <= 0 or not _is_real_dir(path):
        return False
    try:
        inventory = _inventory(path, None, depth)
    except OSError:
        return False
    return inventory.recorded and not inventory.foreign


def _names(names: Iterable[str], shown: int = 3) -> str:
    listed = list(names)
    more = f" and {len(listed) - shown} more" if len(listed) > shown else ""
    return ", ".join(repr(name) for name in listed[:shown]) + more


def _refuse_foreign(final: Path, command: str, shown: Path) -> None:
    """Refuse, before any work, an ``--out`` holding what no sb3-coma manifest lists: replacing it
    could only delete or hide the user's files, and guessing which are the command's by their
    names is how a user's spreadsheet or figure used to be deleted."""
    try:
        foreign = _inventory(final, command).foreign
        problem = (
            f"is not empty and holds what no sb3-coma command wrote there ({_names(foreign)}); nothing was changed"
            if foreign
            else None
        )
    except OSError as exc:
        problem = f"cannot be read ({exc.strerror})"
    if problem is not None:  # one rule: a folder known to hold only sb3-coma's outputs
        raise OutputFolderError(f"--out {shown} {problem}: pass an empty or new folder")


def _link_or_copy(src: str, dst: str) -> None:
    """A hard link (instant, no extra space); a copy where the file system refuses links."""
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:
        shutil.copy2(src, dst, follow_symlinks=False)


def _duplicate(src: Path, dst: Path) -> None:
    """``dst`` as a copy of ``src`` (a file, link or folder) made of hard links where possible."""
    if src.is_symlink():
        os.symlink(os.readlink(src), dst)
    elif src.is_dir():
        shutil.copytree(src, dst, symlinks=True, copy_function=_link_or_copy)
    else:
        _link_or_copy(str(src), str(dst))


def _carry_over(old: Path, new: Path, skip: frozenset[str]) -> list[str]:
    """Give ``new`` the entries of ``old`` it does not replace (other outputs survive the swap) and
    return their names; ``old`` itself is not changed, so a crash here leaves it whole."""
    carried = []
    for entry in sorted(old.iterdir()):
        if entry.name in skip or os.path.lexists(new / entry.name):
            continue
        _duplicate(entry, new / entry.name)
        carried.append(entry.name)
    return carried


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


def _settle(target: Path) -> None:
    """After the output is in place: the renames to disk, the staging lock and marker gone. Best
    effort: the results are in place whatever happens here."""
    with contextlib.suppress(OSError):
        fsync_path(target.parent)
    with contextlib.suppress(OSError):
        (target / STAGING_LOCK).unlink(missing_ok=True)
    _drop_marker(target)


def _replace_folder(staging: Path, target: Path, command: str, token: str) -> bool:
    """Replace the folder ``target`` by ``staging`` as a whole; ``False`` (nothing changed) where
    ``target`` itself cannot be renamed. The old output is marked retired first, so that a crash
    anywhere leaves it recognisable to the next run."""
    _write_marker(target, target, command, "retired", token)
    try:
        if _exchange(staging, target):
            _remove_tree(staging)  # the old output, now under the staging name
            return True
        aside = _free_name(_sibling(target, _ASIDE, os.getpid()))
        os.rename(target, aside)
    except OSError as exc:
        _drop_marker(target)
        if exc.errno in _IMMOVABLE:
            return False
        raise
    try:
        os.rename(staging, target)
    except OSError:
        os.rename(aside, target)
        _drop_marker(target)
        raise
    _remove_tree(aside)
    return True


def _place(src: Path, folder: Path, name: str) -> None:
    """Put a copy of ``src`` at ``folder/name`` with one ``rename`` (two where a folder is replaced
    or replaces: renames cannot replace a folder that holds anything). The copy is made inside
    ``folder``, so the rename never crosses file systems, and ``src`` stays as it is."""
    arriving, leaving, dst = folder / (_INCOMING + name), folder / (_OUTGOING + name), folder / name
    _remove_entry(arriving)  # left by an earlier run that stopped half-way (its manifest lists it)
    _duplicate(src, arriving)
    if not (os.path.lexists(dst) and (_is_real_dir(dst) or _is_real_dir(arriving))):
        os.replace(arriving, dst)
        return
    _remove_entry(leaving)
    os.rename(dst, leaving)
    try:
        os.rename(arriving, dst)
    except OSError:
        os.rename(leaving, dst)
        raise
    _remove_entry(leaving, strict=False)


def _fill_in_place(staging: Path, target: Path, command: str, written: list[str]) -> None:
    """Put the output into the existing folder ``target`` entry by entry (``target`` cannot be
    renamed: a mount point, a container volume). While it runs the manifest lists the old entries,
    the new ones and the temporary names, so a crash half-way leaves a folder the next run accepts
    and tidies; ``staging`` stays whole until the end, so a failure loses nothing."""
    old = _inventory(target, command)
    temps = {prefix + name for name in written for prefix in (_INCOMING, _OUTGOING)}
    blocked = sorted(name for name in temps if os.path.lexists(target / name) and name not in old.listed)
    if blocked:
        raise OutputFolderError(f"--out {target} holds {_names(blocked)}, which sb3-coma did not write")
    _write_manifest(target, command, complete=False, entries=set(written) | old.own | temps)
    for name in written:
        _place(staging / name, target, name)
    for name in sorted(old.own - set(written)):
        _remove_entry(target / name, strict=False)
    _write_manifest(target, command, complete=True, entries=written)
    with contextlib.suppress(OSError):
        fsync_path(target)
    _remove_tree(staging)


@dataclass
class _Progress:
    """How far a commit got, for the message when it fails."""

    written: list[str] = field(default_factory=list)  # what this run wrote (the results)
    carried: list[str] = field(default_factory=list)  # others' entries linked into the staging folder
    touched: bool = False  # ``--out`` itself was changed (the entry-by-entry fallback started)


def _swap_in(staging: Path, target: Path, command: str, token: str, progress: _Progress) -> None:
    """Move the complete ``staging`` folder to ``target``, replacing what is there as a whole, or
    entry by entry where ``target`` cannot be renamed."""
    for _ in range(3):
        if not os.path.lexists(target):
            try:
                os.rename(staging, target)
            except OSError as exc:  # another run put a folder there meanwhile: swap with it
                if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                    raise
                continue
            _settle(target)
            return
        if _replace_folder(staging, target, command, token):
            _settle(target)
            return
        progress.touched = True
        _fill_in_place(staging, target, command, progress.written)
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


def _commit(staging: Path, target: Path, command: str, token: str, guard: _TermGuard, progress: _Progress) -> None:
    """Record what was written, keep other outputs' entries of the old ``target``, put it in place.

    The manifest is marked complete first: from then on the staging folder holds finished work,
    which no later run deletes. A foreign entry that appeared in ``target`` during the run is
    carried over like other outputs' entries, but one with the name of a result stops the commit.
    """
    housekeeping = {STAGING_LOCK, STAGING_MARKER, manifest_name(command)}
    progress.written = sorted(e.name for e in staging.iterdir() if e.name not in housekeeping)
    _write_manifest(staging, command, complete=True, entries=progress.written)
    _sync_tree(staging)
    if _is_real_dir(target):
        inventory = _inventory(target, command)
        clash = sorted(set(progress.written) & set(inventory.foreign))
        if clash:
            raise OutputFolderError(
                f"--out {target} now holds {_names(clash)}, put there during the run and not written by sb3-coma"
            )
        skip = inventory.own | {manifest_name(command) + ".tmp", STAGING_MARKER + ".tmp"}
        progress.carried = _carry_over(target, staging, skip)
    guard.swapping = True
    _swap_in(staging, target, command, token, progress)


def _kept(
    exc: BaseException, target: Path, staging: Path, progress: _Progress, say: Callable[[str], None]
) -> BaseException:
    """The error for a commit that failed: the staging folder holds the finished results and is
    kept (without the other outputs' entries linked in for the swap); the one line says where."""
    for name in progress.carried:
        _remove_entry(staging / name, strict=False)
    state = (
        "may hold part of the new results"
        if progress.touched
        else "was not replaced (its previous content is untouched)"
    )
    where = f"the finished results are kept in {staging}"
    if not isinstance(exc, Exception):  # Ctrl-C, SystemExit: they go on, with one line on where the results are
        say(f"--out {target} {state}; {where}")
        return exc
    if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
        return DiskFullError(
            errno.ENOSPC, f"the disk is full: --out {target} {state}; {where}: free some space and move them there"
        )
    reason = " ".join(str(exc).split()) or type(exc).__name__
    return OutputFolderError(f"--out {target} could not be put in place ({reason}) and {state}; {where}")


def _checked_target(target: str | os.PathLike[str], command: str) -> Path:
    """The real path of ``target``, after the checks that refuse it before any work (see
    :func:`staged_output`)."""
    shown = Path(target)
    problem = replace_problem(shown)
    if problem is not None:
        raise OutputFolderError(f"--out {shown} {problem}")
    problem = folder_name_problem(target)
    if problem is not None:
        raise OutputFolderError(
            f"--out {os.fspath(target)!r} {problem}: pass a visible folder name such as results/run1"
        )
    final = Path(os.path.realpath(shown))  # one spelling for the siblings and the swap; a link's folder
    if _is_real_dir(final):
        _refuse_foreign(final, command, shown)
    return final


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
    On leaving the block normally the folder replaces ``target`` (see the module docstring); on an
    exception inside, SIGTERM included (:class:`OutputInterrupted`), it is deleted and ``target``
    is not touched. When putting it in place fails, it is kept and the error says where.

    :param command: the writing command (``"evaluate"``...): names the manifest
    :param own: ``fnmatch`` patterns of the names the command writes. Informational only since
        0.3.0: nothing is deleted, kept or refused because of its name (the manifests decide)
    :param say: where the one-line notes about leftovers of interrupted runs go
    :raises OutputFolderError: before any work: ``target`` is a file, the current folder (or holds
        it), a bad name (:func:`folder_name_problem`) or a folder holding what no sb3-coma manifest
        lists; at the end: the output could not be put in place (the results are kept)
    :raises DiskFullError: the disk filled up (one line; says whether the results were kept)
    """
    del own  # see above: kept so that callers need not change
    final = _checked_target(target, command)
    with _TargetLock(final, target):
        yield from _staged(final, target, command, say)


def _staged(final: Path, target: str | os.PathLike[str], command: str, say: Callable[[str], None]) -> Iterator[Path]:
    """:func:`staged_output` once ``final`` is this process's to write (:class:`_TargetLock`)."""
    _clean_stale(final, say)
    token = secrets.token_hex(8)
    staging = _make_staging(final)
    guard = _TermGuard(Path(target), existed=final.is_dir())
    lock: FolderLock | None = None
    progress: _Progress | None = None
    try:
        with _sigterm_raises(guard):
            _write_marker(staging, final, command, "staging", token)
            lock = _lock_staging(staging)
            _write_manifest(staging, command, complete=False)
            yield staging
            progress = _Progress()
            _commit(staging, final, command, token, guard, progress)
    except BaseException as exc:
        if lock is not None:
            lock.release()
        if progress is not None and not isinstance(exc, OutputInterrupted):
            error = _kept(exc, Path(target), staging, progress, say)
        else:
            _remove_tree(staging)  # the unfinished output: nothing finished is lost
            full = isinstance(exc, OSError) and exc.errno == errno.ENOSPC
            error = exc
            if full:
                error = DiskFullError(
                    errno.ENOSPC,
                    f"the disk is full: --out {target} was not written and its previous content is untouched "
                    "(nothing of this run was left behind); free some space and run it again",
                )
        if error is exc:  # one exit: the error itself, or the one line that replaces it
            raise
        raise error from None
    if lock is not None:
        lock.release()
