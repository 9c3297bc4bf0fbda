"""SenDFuse weight files: safetensors (no pickle, so loading a file cannot run code).

A file holds the network's ``state_dict`` plus string metadata that describes the architecture
(format version, layer layout, R, channel widths), so :func:`load_weights` rebuilds the right
network without the caller knowing how it was trained, and a SHA-256 of the tensors, because
safetensors itself only validates the header: a flipped bit inside the tensor data would otherwise
load silently as slightly wrong weights. Every problem with a file is reported as
:class:`SenDFuseWeightsError` (a ``ValueError``) whose message says what is wrong and what to do.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch
from safetensors import safe_open
from safetensors.torch import save_file
from torch import Tensor

from .network import ARCHITECTURE, DEFAULT_GRID_SIZE, SenDFuseConfig, SenDFuseNet

#: Value of the ``format`` metadata key: tells our files from other safetensors files.
FORMAT_NAME = "sb3_coma.sendfuse"
#: Bumped whenever the meaning of the stored tensors or metadata changes.
FORMAT_VERSION = 1
_PREFIX = "sendfuse."
_KEY_FORMAT = "format"
_KEY_VERSION = _PREFIX + "format_version"
_KEY_ARCH = _PREFIX + "architecture"
_KEY_GRID = _PREFIX + "grid_size"
_KEY_CHANNELS = _PREFIX + "channels"
_KEY_SHA = _PREFIX + "sha256"
_HOW_TO_CREATE = "create it with `sb3-coma pretrain-sendfuse` (add --help for the output path and options)"


class SenDFuseWeightsError(ValueError):
    """A SenDFuse weight file is missing, unreadable, corrupt, or does not fit the expected network."""


def shipped_weights_dir() -> Path:
    """The package folder that holds the shipped weights (``sb3_coma/pretrained``): a file there
    under a shipped name is verified against :data:`SHIPPED_SHA256`, however it is named."""
    return Path(__file__).resolve().parent.parent / "pretrained"


def _shipped_name(grid_size: int) -> str:
    return f"sendfuse_r{int(grid_size)}.safetensors"


def default_weights_path(grid_size: int = DEFAULT_GRID_SIZE) -> Path:
    """Where the shipped pre-trained weights for an R x R grid live (inside the package).

    The file may not exist (e.g. in a source checkout before pre-training); :func:`load_weights`
    then says how to create it.
    """
    return shipped_weights_dir() / _shipped_name(grid_size)


def _digest(tensors: Mapping[str, Tensor]) -> str:
    """SHA-256 over names, dtypes, shapes and raw bytes, in sorted-name order (order-independent)."""
    h = hashlib.sha256()
    for name in sorted(tensors):
        t = tensors[name].detach().to("cpu").contiguous()
        h.update(f"{name}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return h.hexdigest()


def _config_metadata(config: SenDFuseConfig) -> dict[str, str]:
    return {
        _KEY_FORMAT: FORMAT_NAME,
        _KEY_VERSION: str(FORMAT_VERSION),
        _KEY_ARCH: ARCHITECTURE,
        _KEY_GRID: str(config.grid_size),
        _KEY_CHANNELS: ",".join(str(c) for c in config.channels),
    }


def canonicalize_safetensors(path: str | os.PathLike[str]) -> None:
    """Rewrite a safetensors header with sorted keys, so equal contents give equal bytes.

    The safetensors writer serialises the header (tensor entries and ``__metadata__``) from a
    hash map whose iteration order is randomised per process, so two runs that produce the same
    tensors and metadata still write different bytes. Only the JSON header is rewritten (its
    8-byte length prefix updated, padded with spaces to a multiple of 8 as safetensors does);
    tensor bytes and their offsets, which are relative to the end of the header, are untouched.
    :func:`save_weights` does this itself; exposed for files written by other tools.
    """
    target = Path(path)
    raw = target.read_bytes()
    (length,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + length])
    if "__metadata__" in header:
        header["__metadata__"] = dict(sorted(header["__metadata__"].items()))
    text = json.dumps(header, sort_keys=True, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    tmp = target.with_name(target.name + ".canonical.tmp")
    tmp.write_bytes(struct.pack("<Q", len(text)) + text + raw[8 + length :])
    os.replace(tmp, target)


def save_weights(model: SenDFuseNet, path: str | os.PathLike[str], metadata: Mapping[str, str] | None = None) -> Path:
    """Write ``model``'s weights and architecture to a safetensors file; returns the path.

    Args:
        model: the network to save.
        path: target file (parent folders are created). Written to a temporary file first and
            renamed, so an interrupted save never leaves a truncated file behind. The header is
            written in sorted order (:func:`canonicalize_safetensors`), so the same weights and
            metadata always give the same bytes.
        metadata: extra provenance strings (e.g. the command, seed, noise level, final loss);
            keys ``format`` and ``sendfuse.*`` are reserved for the architecture record.
    """
    if not isinstance(model, SenDFuseNet):
        raise TypeError(f"save_weights expects a SenDFuseNet, got {type(model).__name__}")
    extra = dict(metadata or {})
    for key, value in extra.items():
        if not (isinstance(key, str) and isinstance(value, str)) or key == _KEY_FORMAT or key.startswith(_PREFIX):
            raise ValueError(
                f"metadata {key!r}: {value!r}: keys and values must be str (safetensors stores strings), and "
                f"{_KEY_FORMAT!r} and {_PREFIX}* keys are reserved for the architecture record"
            )
    # Contiguous copies: the model keeps its parameters channels-last, safetensors needs plain
    # row-major tensors; the values (and hence a reload) are bit-identical.
    tensors = {name: t.detach().to("cpu").contiguous() for name, t in model.state_dict().items()}
    record = {**extra, **_config_metadata(model.config), _KEY_SHA: _digest(tensors)}
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=target.name + ".", suffix=".tmp", dir=target.parent)
    os.close(fd)
    try:
        save_file(tensors, tmp_name, metadata=record)
        canonicalize_safetensors(tmp_name)  # the writer's header order is randomised per process
        os.replace(tmp_name, target)
    except BaseException:
        Path(tmp_name).unlink(missing_ok=True)
        raise
    return target


#: SHA-256 of every shipped weight file, per grid size: the shipped weights are verified before
#: they are read, like the shipped models (``sb3_coma/pretrained/SENDFUSE.md`` has the provenance).
SHIPPED_SHA256: dict[int, str] = {
    44: "525d986f3c00f3923c6058332372781a719bf89626f3fa247e1f900044c31058",
}


def _file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def shipped_digest(path: str | os.PathLike[str]) -> str | None:
    """The recorded SHA-256 when ``path`` *is* a shipped weight file, else ``None``.

    Decided by where the file really is (symlinks and ``..`` resolved), not by how it was named:
    the shipped weights are checked whether they come as ``None``, as the default path the fusion
    wrapper passes, or as any path that leads to them; a user's own file elsewhere is not compared
    with the shipped hash.
    """
    target = Path(path).resolve()
    folder = shipped_weights_dir().resolve()
    for grid_size, digest in SHIPPED_SHA256.items():
        if target == folder / _shipped_name(grid_size):
            return digest
    return None


def _resolve(path: str | os.PathLike[str] | None) -> Path:
    target = default_weights_path() if path is None else Path(path)
    if not target.is_file():
        which = "the shipped pre-trained SenDFuse weights" if path is None else "SenDFuse weights"
        there = " (there is a folder, not a file)" if target.exists() else ""
        raise SenDFuseWeightsError(f"{which} not found at {target}{there}; {_HOW_TO_CREATE}")
    expected = SHIPPED_SHA256.get(DEFAULT_GRID_SIZE) if path is None else shipped_digest(target)
    if expected is not None and _file_sha256(target) != expected:
        raise SenDFuseWeightsError(
            f"the shipped SenDFuse weights {target} do not match their recorded SHA-256 "
            f"({expected}): the install is damaged or the file was replaced; reinstall "
            f"sb3-coma, or pass your own file from another folder"
        )
    return target


def _read(target: Path, with_tensors: bool) -> tuple[dict[str, str], dict[str, torch.Tensor]]:
    """(metadata, tensors or ``{}``) of a safetensors file; any failure of the reader is one
    :class:`SenDFuseWeightsError` (the header or the layout is broken)."""
    try:
        with safe_open(str(target), framework="pt") as handle:
            meta = dict(handle.metadata() or {})
            names = handle.keys() if with_tensors else []
            return meta, {name: handle.get_tensor(name) for name in names}
    except Exception as exc:  # SafetensorError, OSError, UnicodeDecodeError, ...
        raise SenDFuseWeightsError(
            f"{target} is not a readable safetensors file (truncated or corrupt?): {exc}; "
            f"re-download or {_HOW_TO_CREATE}"
        ) from exc


def read_metadata(path: str | os.PathLike[str] | None = None) -> dict[str, str]:
    """The string metadata of a weight file (architecture record plus provenance), unvalidated."""
    return _read(_resolve(path), with_tensors=False)[0]


def _config_from_metadata(meta: Mapping[str, str], target: Path) -> SenDFuseConfig:
    """The architecture a file records, once its format, format version and architecture are the
    ones this sb3-coma writes (one rule: every field of the record as expected)."""
    version = meta.get(_KEY_VERSION, "")
    record = (
        ("format", meta.get(_KEY_FORMAT), FORMAT_NAME),
        ("format version", int(version) if version.isdigit() else version, FORMAT_VERSION),
        ("architecture", meta.get(_KEY_ARCH), ARCHITECTURE),
    )
    wrong = [f"{field} {got!r}, expected {want!r}" for field, got, want in record if got != want]
    if wrong:
        raise SenDFuseWeightsError(
            f"{target} is not a SenDFuse weight file this sb3-coma reads: its metadata has {'; '.join(wrong)}; "
            f"re-create it ({_HOW_TO_CREATE}), or upgrade sb3-coma for a newer format"
        )
    try:
        grid_size = int(meta[_KEY_GRID])
        channels = tuple(int(c) for c in meta[_KEY_CHANNELS].split(","))
        return SenDFuseConfig(grid_size=grid_size, channels=channels)  # type: ignore[arg-type]
    except (KeyError, ValueError) as exc:
        raise SenDFuseWeightsError(f"{target}: bad architecture record in metadata ({exc})") from exc


def _check_expected(config: SenDFuseConfig, expected: SenDFuseConfig | Mapping[str, Any] | None, target: Path) -> None:
    if expected is None:
        return
    wanted = expected.as_dict() if isinstance(expected, SenDFuseConfig) else dict(expected)
    known = set(config.as_dict())
    unknown = set(wanted) - known
    if unknown:
        raise ValueError(f"expected_config has unknown keys {sorted(unknown)}; known: {sorted(known)}")
    actual = config.as_dict()
    diffs = []
    for key, value in wanted.items():
        value = tuple(value) if key == "channels" else value
        if actual[key] != value:
            diffs.append(f"{key}: file has {actual[key]!r}, expected {value!r}")
    if diffs:
        raise SenDFuseWeightsError(
            f"{target} does not match the expected SenDFuse configuration ({'; '.join(diffs)}); "
            f"use weights trained for this setting or {_HOW_TO_CREATE}"
        )


def load_weights(
    path: str | os.PathLike[str] | None = None,
    expected_config: SenDFuseConfig | Mapping[str, Any] | None = None,
) -> SenDFuseNet:
    """Rebuild a :class:`SenDFuseNet` from a weight file and load its weights (CPU, eval mode).

    Args:
        path: the file; ``None`` means :func:`default_weights_path` (the shipped weights).
        expected_config: a :class:`SenDFuseConfig`, or a dict with some of its fields (e.g.
            ``{"grid_size": 44}`` from the environment's ``comm_grid``); a mismatch is an error
            rather than a network that silently expects another grid.

    Raises:
        SenDFuseWeightsError: missing file, not safetensors / truncated / corrupt (checksum),
            not a SenDFuse file, unsupported version, missing or unexpected tensors, wrong
            shapes or dtypes, non-finite values, or a config mismatch.
    """
    target = _resolve(path)
    meta, tensors = _read(target, with_tensors=True)
    config = _config_from_metadata(meta, target)
    _check_expected(config, expected_config, target)

    model = SenDFuseNet.from_config(config)
    reference = model.state_dict()
    missing = sorted(set(reference) - set(tensors))
    unexpected = sorted(set(tensors) - set(reference))
    problems = [f"missing {missing}"] if missing else []
    problems += [f"unexpected {unexpected}"] if unexpected else []
    problems += [
        f"tensor {name!r} has shape {tuple(t.shape)} and dtype {t.dtype}, the architecture record implies "
        f"{tuple(reference[name].shape)} and {reference[name].dtype}"
        for name, t in tensors.items()
        if name in reference and (t.shape != reference[name].shape or t.dtype != reference[name].dtype)
    ]
    if problems:
        raise SenDFuseWeightsError(
            f"{target} does not hold the tensors of a {ARCHITECTURE} network with {config.as_dict()}: "
            + "; ".join(problems)
        )
    stored_digest = meta.get(_KEY_SHA)
    if stored_digest is None or _digest(tensors) != stored_digest:
        raise SenDFuseWeightsError(
            f"{target}: tensor data does not match its checksum {_KEY_SHA!r} ({stored_digest or 'missing'}): a "
            f"corrupt file, or not written by sb3-coma; re-download or {_HOW_TO_CREATE}"
        )
    for name, tensor in tensors.items():
        if not bool(torch.isfinite(tensor).all()):
            raise SenDFuseWeightsError(f"{target}: tensor {name!r} holds NaN or inf (diverged training?)")
    model.load_state_dict(tensors)
    model.weights_metadata = meta
    return model.eval()
