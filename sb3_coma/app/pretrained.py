"""Shipped COMA models: ``load_pretrained("env1" | "env2" | "env3")``.

The models live in ``sb3_coma/pretrained/`` next to ``models.json``, which records for each name
the zip's file name, its SHA-256 checksum and size, the exact command that retrains it, the
training wall-clock, the fusion it was trained with and the metrics measured by
``sb3-coma reproduce`` (how they were trained: ``docs/tuning_log.md``).

Security: an SB3 ``.zip`` is loaded with ``torch.load`` and may contain pickled Python objects,
so loading a zip from an untrusted source can run code. :func:`load_pretrained` therefore checks
the file's SHA-256 against ``models.json`` *before* loading it; a missing file or a checksum
mismatch raises :class:`PretrainedError` and nothing is loaded. The check follows the file, not
the name: a path that leads to a shipped zip (``sb3-coma evaluate --model
<package>/pretrained/coma_env1.zip``, ``sb3-coma export --model ...``) is verified the same way
(:func:`verify_shipped_file`). Any other zip loaded by path (``COMA.load``, ``sb3-coma evaluate
--model PATH``) is the user's own and is trusted as it is.
"""

from __future__ import annotations

import io
import json
import os
import warnings
import zipfile
from pathlib import Path
from typing import Any

import torch as th

from sb3_coma.coma import COMA
from sb3_coma.common.shipped import SHIPPED_DIR, sha256_of
from uav_ipp import WORLD_VERSION

#: File name of the manifest inside the pretrained folder.
MANIFEST = "models.json"
#: What a shipped model warm-started from the oracle is called in every generated table and text:
#: its COMA training fine-tunes a behaviour clone of a clairvoyant teacher (docs/training.md).
WARM_START_TITLE = "COMA (oracle warm start)"
#: What the ablation's arms (fusion, extractor) are called in every table, figure and verdict:
#: the ablation, the noise sweep and ``reproduce`` name the shipped arm models so.
ABLATION_LABELS: dict[tuple[str, str], str] = {
    ("mean", "cnn"): "Base",
    ("mean", "cbam"): "CBAM",
    ("sendfuse", "cnn"): "SenDFuse",
    ("sendfuse", "cbam"): "SenDFuse+CBAM",
}


class PretrainedError(ValueError):
    """A shipped model that cannot be used: unknown name, missing file, checksum mismatch."""


def pretrained_dir() -> Path:
    """The folder that holds the shipped models (``sb3_coma/pretrained``)."""
    return SHIPPED_DIR


#: Hex SHA-256 of a file (the library's, re-exported for the application's callers).
sha256_file = sha256_of


def read_manifest(directory: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The parsed ``models.json`` (``{"format": 1, "models": {name: entry}}``); it is written by
    ``sb3_coma.app.model_manifest.update_models`` alone (the entry's schema is there)."""
    path = Path(directory or pretrained_dir()) / MANIFEST
    data: Any = None
    problem: str | None
    if not path.is_file():
        problem = (
            f"no shipped models: {path} is missing (this install has no sb3_coma/pretrained "
            f"data; retrain with `sb3-coma reproduce --train`)"
        )
    else:
        try:
            data = json.loads(path.read_text())
            problem = (
                None
                if isinstance(data, dict) and isinstance(data.get("models"), dict)
                else f"{path} has no 'models' mapping"
            )
        except json.JSONDecodeError as exc:
            problem = f"{path} is not valid JSON: {exc}"
    if problem is not None:  # one rule: a readable manifest with a models mapping
        raise PretrainedError(problem)
    return dict(data)


def save_for_shipping(model: Any, file: str, directory: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """Save ``model`` as ``file`` in the shipped folder in compact form and return its manifest
    fields ``file``, ``sha256``, ``size_bytes``.

    Compact: no Adam moments and no KL reference actor of a warm start (only needed to continue
    training), no target critic (loading makes it a copy of the critic, as after a
    synchronisation), weights in half precision (loading casts them back to float32),
    deflate-compressed. That turns ~10.8 MB into ~1.4 MB; the argmax actions
    are checked against the full-precision model by ``tests/test_pretrained.py``.
    """
    path = Path(directory or pretrained_dir()) / file
    model.policy.optimizer.state.clear()
    model.policy.critic_optimizer.state.clear()
    model.reference_actor = None
    model.save(path)
    _compact_policy(path)
    return {"file": file, "sha256": sha256_file(path), "size_bytes": path.stat().st_size}


def _compact_policy(path: Path) -> None:
    """Rewrite an SB3 zip: ``policy.pth`` in half precision without the target critic, deflated."""
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    state = th.load(io.BytesIO(members["policy.pth"]), map_location="cpu", weights_only=True)
    compact = {
        key: (value.half() if value.is_floating_point() else value)
        for key, value in state.items()
        if not key.startswith("critic_target.")
    }
    buffer = io.BytesIO()
    th.save(compact, buffer)
    members["policy.pth"] = buffer.getvalue()
    tmp = path.with_suffix(".tmp")
    with zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    os.replace(tmp, path)


def available(directory: str | os.PathLike[str] | None = None) -> list[str]:
    """Names of the shipped models, e.g. ``["env1", "env2", "env3"]``."""
    return sorted(read_manifest(directory)["models"])


def is_shipped(name: str, directory: str | os.PathLike[str] | None = None) -> bool:
    """Whether ``name`` is a shipped model's name (or gymnasium id) in the manifest."""
    try:
        models = read_manifest(directory)["models"]
    except PretrainedError:
        return False
    return _canonical(name) in models


def _canonical(name: str) -> str:
    text = str(name).strip()
    low = text.lower()
    # accept the gymnasium id too: UavIpp-Env3-v0 -> env3
    if low.startswith("uavipp-") and low.endswith("-v0"):
        low = low[len("uavipp-") : -len("-v0")]
    return low


def model_info(name: str, directory: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """The manifest entry of a shipped model (file, sha256, command, wall-clock, metrics ...)."""
    models = read_manifest(directory)["models"]
    key = _canonical(name)
    if key not in models:
        raise PretrainedError(f"unknown shipped model {name!r}; available: {', '.join(sorted(models)) or 'none'}")
    return dict(models[key])


def model_path(name: str, directory: str | os.PathLike[str] | None = None, verify: bool = True) -> Path:
    """Path of a shipped model's zip, checked against its SHA-256 unless ``verify=False``."""
    info = model_info(name, directory)
    path = Path(directory or pretrained_dir()) / info["file"]
    expected = str(info.get("sha256", "")).lower()
    actual = sha256_file(path) if verify and path.is_file() else expected
    if not path.is_file() or actual != expected:  # one rule: the file is there, as shipped
        raise PretrainedError(
            f"shipped model {name!r}: "
            + (
                f"checksum mismatch for {path} (sha256 {actual}, models.json expects {expected}); the file was "
                "modified or corrupted and is NOT loaded (an SB3 zip can run code when loaded)"
                if path.is_file()
                else f"file {path} is missing (reinstall sb3-coma or retrain with: "
                f"{info.get('command', 'sb3-coma reproduce --train')})"
            )
        )
    return path


def shipped_name_of(path: str | os.PathLike[str], directory: str | os.PathLike[str] | None = None) -> str | None:
    """The shipped model a file *is* (its manifest name), or ``None``: decided by where the file
    really is (symlinks and ``..`` resolved), so no path or argument reaches a shipped zip unchecked."""
    folder = Path(directory or pretrained_dir()).resolve()
    target = Path(path).resolve()
    if target.parent != folder:
        return None
    try:
        models = read_manifest(directory)["models"]
    except PretrainedError:
        return None
    return next((name for name, info in sorted(models.items()) if info.get("file") == target.name), None)


def verify_shipped_file(path: str | os.PathLike[str], directory: str | os.PathLike[str] | None = None) -> None:
    """Refuse a shipped model's zip that does not match its recorded SHA-256, whatever path led to it.

    An SB3 zip can run code when loaded, and a replaced shipped file would otherwise be used under
    the shipped model's name. A zip elsewhere is the user's own and passes unchecked.

    :raises PretrainedError: the file is a shipped one and its checksum differs
    """
    name = shipped_name_of(path, directory)
    if name is not None:
        model_path(name, directory, verify=True)


def load_pretrained(
    name: str, env: Any = None, device: str = "cpu", directory: str | os.PathLike[str] | None = None
) -> Any:
    """Load a shipped COMA model after verifying its checksum.

    :param name: ``"env1"``, ``"env2"``, ``"env3"`` (or the gymnasium id ``"UavIpp-Env3-v0"``)
    :param env: optional vec env (``uav_ipp.make_vec_env(name, fusion=model.fusion)``) to attach;
        ``None`` is enough for ``predict``
    :param device: torch device (default cpu)
    :param directory: folder holding ``models.json`` and the zips (default: the shipped one)
    :raises PretrainedError: unknown name, missing file, checksum mismatch (a ``ValueError``)

    The returned model carries ``pretrained_info`` (its manifest entry) and, when its zip does not
    record them, ``env_options`` resolved from the manifest's env and config variant
    (``sb3_coma.training_options(model)``); evaluate it with the fusion it was trained with:
    ``sb3_coma.evaluate(model, env="env3", fusion=sb3_coma.training_options(model)["fusion"])``.
    """
    info = model_info(name, directory)
    path = model_path(name, directory, verify=True)
    if info.get("world", 1) != WORLD_VERSION:
        warnings.warn(outdated_message(name, info), stacklevel=2)
    return load_verified(path, info, env=env, device=device)


def outdated_message(name: str, info: dict[str, Any]) -> str:
    """The warning of a shipped model trained on another world version than this env's."""
    return (
        f"shipped model {name!r} was trained on world v{info.get('world', 1)} (local beliefs on the "
        f"comm grid); this env is world v{WORLD_VERSION} (per-cell local beliefs, cell-level messages): "
        f"it is outdated and flies below its recorded numbers until retrained"
    )


def load_verified(path: Path, info: dict[str, Any], env: Any = None, device: str = "cpu") -> Any:
    """Load a shipped zip whose checksum the caller has just verified (``model_path``): an
    evaluation resolves a shipped model once and loads it per batch without hashing it again.
    The model carries ``pretrained_info`` and, when its zip does not record them, the manifest's
    ``env_options``."""
    model = COMA.load(str(path), env=env, device=device)
    model.pretrained_info = info
    if model.env_options is None:
        model.env_options = _manifest_env_options(info)
    return model


def shipped_env_options(name: str, directory: str | os.PathLike[str] | None = None) -> dict[str, Any] | None:
    """The env options a shipped model was trained with, from its manifest entry (no model load)."""
    return _manifest_env_options(model_info(name, directory))


def _manifest_env_options(info: dict[str, Any]) -> dict[str, Any] | None:
    """The env options a shipped model was trained with: the manifest's ``env_options`` (the
    model's own record, copied there when it was shipped, so a later change of the config cannot
    change how it is flown); ``None`` for an entry without them."""
    options = info.get("env_options")
    return dict(options) if isinstance(options, dict) else None
