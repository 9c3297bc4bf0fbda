"""The one writer of ``sb3_coma/pretrained/models.json``, and the schema of one model's entry.

Two tools change the manifest: ``sb3-coma reproduce`` (``--ship`` replaces a retrained map's
entry, ``--record`` adds the measured Table I numbers to the shipped models' entries) and the
maintainer tool ``sb3_coma.experiments.ship_models`` (a selected model's whole entry, or its
re-scored seed spread). Both go through :func:`update_models`, so the file has one set of keys
(:class:`ModelEntry`), one layout (two-space JSON, keys in the order they were first written)
and one atomic write: a reader (``sb3_coma.app.pretrained``) never sees half a file, and an entry
with a misspelt key is refused before anything is written.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TypedDict, cast

from sb3_coma.app import pretrained as pt

#: The manifest's ``format`` (written when a first entry makes the file).
FORMAT = 1


class ModelFields(TypedDict, total=False):
    """What a ``models.json`` entry may record besides its file (every key is optional; an update
    with ``replace=False`` names only the keys it changes). The keys are those the shipped file
    has today, plus ``algo``, which ``sb3_coma.experiments.protocols`` reads for IPPO / MAPPO
    entries."""

    env: str
    fusion: str
    extractor: str
    actor_inputs: str
    variant: str | None
    world: int
    seed: int
    deterministic: bool
    timesteps: int | None
    command: str
    command_note: str
    config: str
    model_file_of_run: str
    train_wall_s: float
    train_wall_note: str
    shipped_form: str
    training_curve: list[float]
    env_options: dict[str, Any]
    warm_start: dict[str, Any]
    ablation_arm: list[str]
    selection: dict[str, Any]
    seeds_unseen: dict[str, Any]
    train_timesteps: int
    metrics: dict[str, float]
    metrics_note: str
    title: str
    algo: str


class ModelEntry(ModelFields):
    """One shipped model's whole entry: its zip (``pretrained.save_for_shipping``'s three fields,
    without which ``load_pretrained`` cannot verify the file) and any of :class:`ModelFields`."""

    file: str
    sha256: str
    size_bytes: int


def entry_keys() -> frozenset[str]:
    """Every key an entry may have (:class:`ModelEntry`'s)."""
    return frozenset(ModelEntry.__required_keys__ | ModelEntry.__optional_keys__)


def _checked(name: str, fields: Mapping[str, Any], whole: bool) -> None:
    """Refuse keys outside the schema and, for a whole entry, one without its file's fields: what
    is refused here never reaches the file."""
    unknown = sorted(set(fields) - entry_keys())
    missing = sorted(ModelEntry.__required_keys__ - set(fields)) if whole else []
    if unknown or missing:  # one rule: the schema's keys, all of them for a whole entry
        problem = f"unknown keys {unknown} (schema: sb3_coma.app.model_manifest)" if unknown else f"missing {missing}"
        raise ValueError(f"models.json entry {name!r}: {problem}")


def as_entry(name: str, fields: Mapping[str, Any]) -> ModelEntry:
    """``fields`` checked as model ``name``'s whole entry (every key in the schema, the file's
    fields present): where an entry assembled as a plain dict from a run folder's records becomes
    a typed one, so that a wrong key is refused where it was made."""
    _checked(name, fields, whole=True)
    return cast(ModelEntry, dict(fields))


def manifest_text(data: Mapping[str, Any]) -> str:
    """The file's text for a parsed manifest: two-space JSON, keys in their order, ASCII, a final newline."""
    return json.dumps(data, indent=2, sort_keys=False) + "\n"


def update_models(
    changes: Mapping[str, ModelFields],
    *,
    replace: bool = False,
    directory: str | os.PathLike[str] | None = None,
) -> Path:
    """Apply ``changes`` (``{model name: fields}``) to ``models.json`` and write it atomically
    (temporary file + ``os.replace``); returns its path.

    :param replace: ``False``: each name must have an entry already, and its keys are updated in
        place (an existing key keeps its position, a new one goes last), the ``--record`` /
        ``--rescore`` kind of change. ``True``: each change is the model's whole entry
        (:class:`ModelEntry`), which takes the old one's place or goes last; a missing manifest
        is then started (``{"format": 1, "models": {}}``), the first ship of an install.
    :param directory: the folder of ``models.json`` (default: the shipped one)
    :raises PretrainedError: no manifest to update, or no entry for a name to update
    :raises ValueError: a key outside :class:`ModelEntry`, or a whole entry without its file's fields
    """
    folder = Path(directory or pt.pretrained_dir())  # looked up per call: tests point it elsewhere
    try:
        data = pt.read_manifest(folder)
    except pt.PretrainedError:
        if not replace or (folder / pt.MANIFEST).exists():
            raise
        data = {"format": FORMAT, "models": {}}
    models = data["models"]
    for name, fields in changes.items():
        _checked(name, fields, whole=replace)
        if replace:
            models[name] = dict(fields)
        elif name in models:
            models[name].update(fields)
        else:
            raise pt.PretrainedError(f"models.json has no entry {name!r} to update")
    path = folder / pt.MANIFEST
    folder.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(manifest_text(data), encoding="utf-8")
    os.replace(tmp, path)
    return path
