"""Checkpoint files: atomic writes, validation and discovery.

A model is written to a temporary file in the destination folder, flushed to disk, checked, and
only then moved over the destination with :func:`os.replace` (atomic on POSIX and Windows). A
crash or a full disk in the middle of a save therefore leaves the previous file untouched and at
worst a stray ``.*.tmp`` file, never a half-written ``model.zip``.

:func:`validate_checkpoint` tells a user *which* file is wrong and *why* (missing, not a zip,
truncated or corrupt, an SB3 model of another algorithm) before SB3's loader fails with a
traceback from inside ``zipfile`` or ``torch``.

Checkpoint names follow rl-zoo3 (``rl_model_<joint steps>_steps.zip``), so rl-zoo3's
``enjoy --load-checkpoint N`` / ``--load-last-checkpoint`` find them.
"""

from __future__ import annotations

import errno
import json
import os
import re
import tempfile
import warnings
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from sb3_coma.common.numbers import is_whole

#: rl-zoo3's checkpoint prefix: ``rl_model_<steps>_steps.zip``.
CHECKPOINT_PREFIX = "rl_model"
_CHECKPOINT_RE = re.compile(r"^(?P<prefix>.+)_(?P<steps>\d+)_steps\.zip$")
#: Members every SB3 model zip holds.
_REQUIRED_MEMBERS = ("data", "policy.pth")
#: Every member an SB3 zip of a COMA model holds (the shipped compact form leaves out the optimizers);
#: anything else is not SB3's and may carry a payload, so a checkpoint holding it is refused.
_COMA_MEMBERS = frozenset(
    {
        "data",
        "pytorch_variables.pth",
        "policy.pth",
        "policy.optimizer.pth",
        "policy.critic_optimizer.pth",
        "reference_actor.pth",  # the KL reference of a warm-started run (COMA.set_reference_actor)
        "_stable_baselines3_version",
        "system_info.txt",
    }
)
#: Saved attributes that only a COMA model has (see ``sb3_coma.coma.COMA``).
_COMA_ATTRIBUTES = ("n_agents", "td_lambda", "critic_learning_rate")


class CheckpointError(ValueError):
    """A checkpoint or model file that cannot be used; the message names the file and the reason."""


class DiskFullError(OSError):
    """The disk filled up while a file was saved atomically; the message names the file and says
    that its previous version (or the earlier checkpoints) is intact. Not a bad input, so the CLI
    prints it as one line with exit status 1 (not 2), never as a traceback."""

    def __str__(self) -> str:
        return str(self.strerror)


def _disk_full(exc: BaseException, final: Path, existed: bool) -> DiskFullError | None:
    """The :class:`DiskFullError` for an ``ENOSPC`` raised while writing ``final``, else ``None``."""
    if not isinstance(exc, OSError) or exc.errno != errno.ENOSPC:
        return None
    kept = "its previous version is intact" if existed else "no partial file was left and other files are untouched"
    return DiskFullError(errno.ENOSPC, f"no space left on device to save {final}; {kept}", str(final))


@dataclass(frozen=True)
class CheckpointInfo:
    """What :func:`validate_checkpoint` learned about a model zip without loading its networks."""

    path: Path
    num_timesteps: int
    n_agents: int | None
    policy: str
    sb3_version: str | None


def checkpoint_name(num_timesteps: int, prefix: str = CHECKPOINT_PREFIX) -> str:
    """``rl_model_<num_timesteps>_steps.zip`` (rl-zoo3's and SB3's ``CheckpointCallback`` naming)."""
    return f"{prefix}_{int(num_timesteps)}_steps.zip"


# --------------------------------------------------------------------------- atomic writes
def fsync_path(path: str | os.PathLike[str]) -> None:
    """fsync one file or folder, e.g. to make a rename durable (best effort: not every platform
    can open a folder)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _umask() -> int:
    """The process's umask (read by setting it and putting it back: at import, before any thread)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: The mode of a file :func:`atomic_write` creates: what ``open(path, "w")`` would give it.
_NEW_FILE_MODE = 0o666 & ~_umask()


def atomic_write(
    path: str | os.PathLike[str],
    write: Callable[[BinaryIO], Any],
    check: Callable[[Path], Any] | None = None,
) -> Path:
    """Write a binary file atomically; return ``path``.

    ``write(handle)`` fills a hidden temporary file next to ``path`` (same file system, so the
    final :func:`os.replace` is atomic), which is flushed and fsynced, optionally checked
    (``check(temporary path)``), then moved into place. On any error the temporary file is removed
    and ``path`` keeps its previous content; a full disk (``ENOSPC``) is raised as
    :class:`DiskFullError` naming ``path``.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    existed = final.exists()
    mode = final.stat().st_mode & 0o7777 if existed else _NEW_FILE_MODE
    fd, tmp_name = tempfile.mkstemp(prefix=f".{final.name}.", suffix=".tmp", dir=final.parent)
    tmp = Path(tmp_name)
    try:
        with os.fdopen(fd, "wb") as handle:
            write(handle)
            handle.flush()
            os.fsync(handle.fileno())
        os.chmod(tmp, mode)  # mkstemp makes 0600: keep the replaced file's mode, or give the umask's
        if check is not None:
            check(tmp)
        os.replace(tmp, final)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        full = _disk_full(exc, final, existed)
        if full is not None:
            raise full from exc
        raise
    fsync_path(final.parent)
    return final


def atomic_save(model: Any, path: str | os.PathLike[str], validate: bool = True) -> Path:
    """Save an SB3 model to ``path`` atomically (:func:`atomic_write`); return the final path.

    :param model: anything with SB3's ``save(file_object)``
    :param path: destination; ``.zip`` is appended when it has no suffix (as SB3 does)
    :param validate: re-read the written zip before replacing ``path``
    """
    final = Path(path)
    if final.suffix == "":
        final = final.with_suffix(".zip")
    return atomic_write(final, model.save, (lambda tmp: _check_zip(tmp, display=final)) if validate else None)


def atomic_write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write a text file atomically: :func:`atomic_write` of its UTF-8 bytes (newlines as given)."""
    data = text.encode("utf-8")
    return atomic_write(path, lambda handle: handle.write(data))


def write_between_markers(path: str | os.PathLike[str], markers: tuple[str, str], text: str) -> bool:
    """Replace what lies between ``markers`` (start, end) in the text file ``path`` by ``text``,
    atomically: how a generated paragraph reaches a hand-written file (README). ``False`` when the
    file or its markers are missing (nothing is written then)."""
    target = Path(path)
    if not target.is_file():
        return False
    content = target.read_text(encoding="utf-8")
    start, end = markers
    if start not in content or end not in content.split(start, 1)[1]:
        return False
    head, rest = content.split(start, 1)
    atomic_write_text(target, f"{head}{start}\n{text.strip()}\n{end}{rest.split(end, 1)[1]}")
    return True


def folder_write_problem(path: str | os.PathLike[str]) -> str | None:
    """Why files cannot be written into the folder ``path`` (made when missing), or ``None``.

    Output folders are checked with this before minutes of work (building envs and models,
    flying missions), so that a path whose own name or a parent is a file, or that lies on a
    read-only or forbidden location, is refused in one line instead of failing in ``mkdir`` at
    the end. The nearest existing ancestor decides: it must be a folder this process may write.
    """
    target = Path(path)
    existing = next((p for p in (target, *target.parents) if p.exists()), Path("."))
    if not existing.is_dir():
        return f"{existing} is a file, not a folder" if existing == target else f"its parent {existing} is a file"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"{existing} is not writable"
    return None


# --------------------------------------------------------------------------- validation
def _check_zip(path: Path, display: Path | None = None) -> dict[str, Any]:
    """Open ``path`` as an SB3 model zip; return its parsed ``data`` member.

    :raises CheckpointError: not a zip, truncated, a corrupt member, or not an SB3 model
    """
    shown = display or path
    if not zipfile.is_zipfile(path):
        size = path.stat().st_size
        why = "it is empty" if size == 0 else f"it is not a zip archive ({size} bytes; truncated or another format)"
        raise CheckpointError(f"checkpoint {shown} is unusable: {why}")
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
            missing = [m for m in _REQUIRED_MEMBERS if m not in names]
            if missing:  # a cut-off SB3 zip can expose the zip nested in policy.pth: say "truncated" too
                held = sorted(names)
                listing = ", ".join(held[:4]) + (f", ... ({len(held)} members)" if len(held) > 4 else "")
                raise CheckpointError(
                    f"checkpoint {shown} is truncated or not a Stable-Baselines3 model: it lacks {missing} "
                    f"(it holds {listing or 'nothing'})"
                )
            bad = archive.testzip()
            if bad is not None:
                raise CheckpointError(f"checkpoint {shown} is corrupt: member {bad!r} fails its CRC check")
            raw = archive.read("data").decode("utf-8")
    except (zipfile.BadZipFile, EOFError, OSError, zlib.error, NotImplementedError) as exc:
        raise CheckpointError(f"checkpoint {shown} is truncated or corrupt: {exc}") from exc
    try:
        data: Any = json.loads(raw)
    except json.JSONDecodeError as exc:
        data = exc
    if not isinstance(data, dict):  # one rule: the 'data' member is a JSON object
        reason = data if isinstance(data, json.JSONDecodeError) else "not a JSON object"
        raise CheckpointError(f"checkpoint {shown} has an unreadable 'data' member: {reason}")
    return data


def _describe_policy(data: dict[str, Any]) -> tuple[str, str]:
    """``(module, qualified name)`` of the saved policy class, as far as the JSON says."""
    entry = data.get("policy_class")
    if isinstance(entry, dict):
        module = str(entry.get("__module__", ""))
        type_name = str(entry.get(":type:", ""))
        qualname = str(entry.get("__qualname__", entry.get("__name__", "")))
        if not qualname:  # SB3 stores the class's dict: read its name off a method's repr
            match = re.match(r"<function (\w+)\.", str(entry.get("__init__", "")))
            qualname = match.group(1) if match else type_name
        return module, qualname
    return "", str(entry or "")


def validate_checkpoint(path: str | os.PathLike[str]) -> CheckpointInfo:
    """Check that ``path`` is a complete COMA model zip (without building networks).

    :raises FileNotFoundError: ``path`` does not exist
    :raises CheckpointError: ``path`` is a folder, not a zip, truncated/corrupt, or a model of
        another algorithm
    """
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(f"checkpoint {p} does not exist")
    if p.is_dir():
        raise CheckpointError(f"checkpoint {p} is a folder, not a model zip")
    data = _check_zip(p)
    module, policy = _describe_policy(data)
    missing = [key for key in _COMA_ATTRIBUTES if key not in data]
    if not module.startswith("sb3_coma") or missing:
        what = f"a model with policy {policy or '?'} from {module or 'an unknown module'}"
        raise CheckpointError(f"checkpoint {p} is not a COMA checkpoint: it holds {what}")
    version = None
    try:
        with zipfile.ZipFile(p) as archive:
            names = archive.namelist()
            if "_stable_baselines3_version" in names:
                version = archive.read("_stable_baselines3_version").decode().strip()
    except (zipfile.BadZipFile, OSError):  # already checked above; keep validation total
        names = []
    extra = sorted(set(names) - _COMA_MEMBERS)
    if extra:
        raise CheckpointError(
            f"checkpoint {p} holds members a COMA model zip never has: {extra[:4]} "
            f"(SB3 writes only {sorted(_COMA_MEMBERS)}); it is not loaded"
        )
    steps = data.get("num_timesteps") or 0
    if not is_whole(steps) or steps < 0:
        # resume and newest_model() count joint steps from it: a hand-edited or foreign value
        # would otherwise fail as a bare int() error or pick the wrong checkpoint.
        raise CheckpointError(
            f"checkpoint {p} is corrupt: field 'num_timesteps' of its 'data' member is {steps!r}, "
            "not a whole number of joint steps >= 0"
        )
    n_agents = data.get("n_agents")
    return CheckpointInfo(
        path=p,
        num_timesteps=int(steps),
        n_agents=int(n_agents) if is_whole(n_agents) else None,
        policy=policy,
        sb3_version=version,
    )


# --------------------------------------------------------------------------- discovery
def find_checkpoints(folder: str | os.PathLike[str], prefix: str = CHECKPOINT_PREFIX) -> list[tuple[int, Path]]:
    """``(joint steps, path)`` of every ``<prefix>_<steps>_steps.zip`` in ``folder``, oldest first."""
    root = Path(folder)
    if not root.is_dir():
        return []
    found = []
    for entry in root.iterdir():
        match = _CHECKPOINT_RE.match(entry.name)
        if match and match.group("prefix") == prefix and entry.is_file():
            found.append((int(match.group("steps")), entry))
    return sorted(found)


def last_checkpoint(folder: str | os.PathLike[str], prefix: str = CHECKPOINT_PREFIX) -> Path | None:
    """The newest checkpoint in ``folder`` that validates; broken ones are skipped with a warning."""
    for _, path in reversed(find_checkpoints(folder, prefix)):
        try:
            validate_checkpoint(path)
        except CheckpointError as exc:
            warnings.warn(f"skipping {exc}", stacklevel=2)
            continue
        return path
    return None


# --------------------------------------------------------------------------- training settings
def training_options(model_or_path: Any) -> dict[str, Any] | None:
    """The env options a COMA model was trained with, or ``None`` when it does not record them.

    ``model_or_path``: a COMA model (its ``env_options`` attribute, set by ``sb3-coma train``,
    ``python -m sb3_coma.app.zoo train`` and ``sb3_coma.app.training.train``; for a shipped model
    ``load_pretrained`` fills it from ``models.json`` and the config variant it names) or a model
    zip (read from its ``data`` member; the networks are not loaded). The dict is
    ``{"map": "env3", "fusion": "sendfuse", "fusion_kwargs": {...}, <every uav_ipp.IppConfig option>}``,
    so ``uav_ipp.make_vec_env(opts.pop("map"), **opts)`` rebuilds the training env (override
    ``split``/``start`` for an evaluation protocol). Models saved before this was recorded (and
    models trained with a bare ``COMA(...).learn()``) give ``None``.

    :raises FileNotFoundError: a path that does not exist
    :raises CheckpointError: a path that is not a readable COMA zip
    """
    if isinstance(model_or_path, (str, os.PathLike)):
        options = validate_checkpoint(model_or_path) and _check_zip(Path(model_or_path)).get("env_options")
    else:
        options = getattr(model_or_path, "env_options", None)
    return dict(options) if isinstance(options, dict) else None
