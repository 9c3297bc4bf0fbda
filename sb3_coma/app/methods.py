"""What to fly, resolved once: :class:`Method` and :func:`resolve_method`.

A user names a method in many spellings: a baseline (``"ag"``, ``"NL"``), a table row of one
(``"ag-k3"``), a shipped model (``"env1"``, ``"UavIpp-Env3-v0"``), a model file (``run/model``,
``run/model.zip``) or an object (a COMA model, a planner, anything with SB3's ``predict``).
:func:`resolve_method` turns any of them into a :class:`Method` once, at the edge (the evaluation
front door, ``sb3-coma evaluate``, ``export``): the name is looked up once, a shipped zip is
hashed once, the training options are read once. Everything below takes the :class:`Method` and
trusts it, so a protocol of hundreds of batches neither re-tests the input's type nor re-hashes
the file per batch.
"""

from __future__ import annotations

import os
import pickle
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from sb3_coma.app import pretrained
from sb3_coma.baselines import PLANNERS, Planner, make_planner, planner_class
from sb3_coma.coma import COMA
from sb3_coma.common.checkpoints import training_options
from sb3_coma.common.evaluation import MODEL_LABEL
from uav_ipp import WORLD_VERSION

#: The baseline rows of the generated tables (``sb3_coma.experiments.protocols.BASELINE_METHODS``)
#: that are a planner with options: ``evaluate("ag-k3")`` and ``sb3-coma evaluate --methods ag-k3``
#: fly the row ``ag-k3`` of docs/RESULTS.md, labelled so. ``planner_kwargs`` given with one of
#: them override its options.
PLANNER_ALIASES: dict[str, tuple[str, dict[str, Any]]] = {
    "ag-k2": ("ag", {"lookahead": 2}),
    "ag-k3": ("ag", {"lookahead": 3}),
    "ag-comm": ("ag", {"knowledge": "comm"}),
    "ag-central": ("ag", {"knowledge": "central"}),
}

#: Where a resolved method's predictor comes from: a planner built per batch by name, a shipped
#: model's verified zip, a model file, or the caller's object itself.
Source = Literal["planner", "shipped", "file", "object"]


def baseline_names() -> list[str]:
    """Every name of a baseline: the planners and the table rows of :data:`PLANNER_ALIASES`."""
    return sorted([*PLANNERS, *PLANNER_ALIASES])


def _alias(name: str) -> str | None:
    """The :data:`PLANNER_ALIASES` key ``name`` spells (any case), or None."""
    key = name.strip().lower()
    return key if key in PLANNER_ALIASES else None


def is_baseline(name: str) -> bool:
    """Whether ``name`` names a baseline planner or a table row of one (``ag-k3`` ...); the one
    test every front door (evaluate, export) uses."""
    if _alias(name) is not None:
        return True
    try:
        planner_class(name)
        return True
    except ValueError:
        return False


def looks_like_path(name: str) -> bool:
    """Whether a model name is spelt as a file path (a typo there is "not found", not "unknown")."""
    return name.endswith(".zip") or os.sep in name or "/" in name or name.startswith(".")


def split_label(spec: str) -> tuple[str | None, str]:
    """``"LABEL=PATH"`` -> (label, path), split at the first ``=``; anything else -> (``None``, spec).

    A path that exists is a path even when it holds ``=`` (``sweep/lr=0.001/model.zip``, a model
    file without its ``.zip``, a log folder): the whole spec wins over the split, so only a spec
    that names nothing on disk is read as ``LABEL=PATH``; a "label" holding a folder separator is
    the start of a path (a missing ``sweep/lr=0.001/model.zip`` is named whole, not as ``0.001/...``).
    """
    text = spec.strip()
    label, sep, path = text.partition("=")
    whole = Path(text).exists() or Path(text + ".zip").is_file() or "/" in label or os.sep in label
    if not sep or not label.strip() or not path.strip() or whole:
        return None, text
    return label.strip(), path.strip()


def is_unknown_name(text: str) -> bool:
    """Whether :func:`resolve_method` refuses ``text`` as an unknown name (no baseline, no shipped
    model, no file or folder, not spelt as a path), so a front door can word that case its way."""
    found = is_baseline(text) or pretrained.is_shipped(text) or looks_like_path(text)
    return not (found or Path(text).exists() or Path(text + ".zip").is_file())


@dataclass(frozen=True)
class Method:
    """One method to fly: a row of a protocol's tables, and, once resolved, where its predictor
    comes from.

    A study writes the row (``Method("ag-k2", "ag", planner_kwargs={"lookahead": 2})``);
    :func:`resolve_method` fills the rest once (``source`` set), and everything below the front
    door reads the fields instead of testing the input again.

    :param label: row label (unique per map)
    :param policy: a baseline name, a model object, a ``.zip`` path or a shipped model name
        (resolved: the planner's registry name for baselines)
    :param kind: ``"baseline"``, ``"reference"`` (an upper reference that knows what no UAV knows:
        shown, never compared), ``"coma"``, ``"ippo"``, ``"mappo"`` or ``"policy"`` (any other
        object with SB3's ``predict``)
    :param fusion: fusion of received maps asked for (``None``: the model's own, ``"mean"`` for baselines)
    :param deterministic: argmax (``True``) or seeded draws (``False``); ``None``: a shipped
        model's recorded way, else ``True``
    :param planner_kwargs: baseline options (AG: ``lookahead``, ``weighting``)
    :param note: shown next to the label in the models list (e.g. "outdated: trained on world v1")
    :param source: where the predictor comes from (:data:`Source`); ``None``: not resolved yet
    :param path: the model file (shipped: verified against its SHA-256 when resolved)
    :param shipped: a shipped model's manifest entry (``models.json``), else empty
    :param trained: the env options the model trained with, else empty
    """

    label: str
    policy: Any
    kind: str = "baseline"
    fusion: str | None = None
    deterministic: bool | None = None
    planner_kwargs: Mapping[str, Any] = field(default_factory=dict)
    note: str = ""
    source: Source | None = None
    path: Path | None = None
    shipped: Mapping[str, Any] = field(default_factory=dict)
    trained: Mapping[str, Any] = field(default_factory=dict)

    @property
    def learned(self) -> bool:
        """A learned model (its network reads the fused channel), not a planner."""
        return self.kind not in ("baseline", "reference")

    @property
    def described(self) -> str:
        """How messages name it: ``model 'run/model.zip'``, or ``the model`` for an object."""
        return "the model" if self.source == "object" else f"model {str(self.policy)!r}"

    def predictor(self, venv: Any, seed: int | None) -> Any:
        """The predictor of one batch on ``venv``: a planner built on it (seeded), a model loaded
        from the resolved file (already verified: not hashed again), or the object itself."""
        if self.source == "planner":
            return make_planner(str(self.policy), venv, seed=seed, **dict(self.planner_kwargs))
        if self.source == "shipped" and self.path is not None:
            return pretrained.load_verified(self.path, dict(self.shipped), env=venv)
        if self.source == "file" and self.path is not None:
            return _load_model_file(self.path, venv)
        if isinstance(self.policy, Planner) and self.policy.uses_env_state and self.policy.venv is not venv:
            raise ValueError(
                f"a {self.policy.name!r} planner reads its own vec env's state: pass its name "
                f"({self.policy.name!r}) so that evaluate builds it on the evaluation env"
            )
        return self.policy


def _load_model_file(path: Path, venv: Any) -> Any:
    """Load a resolved model file on ``venv``, naming the file in the one-line errors."""
    try:
        return COMA.load(str(path), env=venv, device="cpu")
    except (pickle.UnpicklingError, ValueError, KeyError, AssertionError, RuntimeError, EOFError) as exc:
        why = (  # torch's "Weights only load failed ..." on a damaged member
            ": it is corrupt (a network or optimizer member is not a readable PyTorch file)"
            if isinstance(exc, pickle.UnpicklingError)
            else f" for this environment: {exc} (was it trained with another number of UAVs or observation layout?)"
        )
        raise ValueError(f"cannot load model {str(path)!r}{why}") from exc


def resolve_method(
    policy_or_name: Any, label: str | None = None, planner_kwargs: Mapping[str, Any] | None = None
) -> Method:
    """The one place that tells a name, a path and an object apart (module docstring).

    A resolved :class:`Method` comes back as it is (with ``label`` / ``planner_kwargs`` given:
    those replaced / merged); an unresolved row is resolved with its own fields kept. Nothing is
    loaded; a shipped zip is hashed here, once.

    :raises ValueError: an empty or unknown name, a folder; ``PretrainedError`` for a shipped file
        whose checksum differs; ``CheckpointError`` for a file that is not a COMA zip
    :raises FileNotFoundError: a path that leads nowhere
    :raises TypeError: an object without SB3's ``predict``
    """
    if isinstance(policy_or_name, Method):
        method = policy_or_name
        if method.source is None:  # a study's row: resolve its policy, keep the row's own fields
            found = _resolve(method.policy, None, method.planner_kwargs)
            method = replace(
                found,
                label=method.label,
                kind=found.kind if method.kind == "baseline" else method.kind,
                fusion=method.fusion,
                deterministic=method.deterministic,
                note=method.note,
            )
        return replace(
            method, label=label or method.label, planner_kwargs={**method.planner_kwargs, **dict(planner_kwargs or {})}
        )
    return _resolve(policy_or_name, label, planner_kwargs)


def _resolve(policy_or_name: Any, label: str | None, planner_kwargs: Mapping[str, Any] | None) -> Method:
    """:func:`resolve_method` of a name, path or object (not a :class:`Method`)."""
    options = dict(planner_kwargs or {})
    if isinstance(policy_or_name, str):
        return _resolve_name(policy_or_name, label, options)
    if isinstance(policy_or_name, os.PathLike):
        return _resolve_path(os.fspath(policy_or_name), label, explicit=True)
    if isinstance(policy_or_name, Planner):
        return Method(label or policy_or_name.name, policy_or_name, planner_kwargs=options, source="object")
    if not callable(getattr(policy_or_name, "predict", None)):
        raise TypeError(
            f"cannot evaluate {type(policy_or_name).__name__}: pass a baseline name, a model path "
            f"or an object with SB3's predict(observation, deterministic=...)"
        )
    info = getattr(policy_or_name, "pretrained_info", None)
    return Method(
        label or MODEL_LABEL,
        policy_or_name,
        kind="coma" if isinstance(policy_or_name, COMA) else "policy",
        planner_kwargs=options,
        source="object",
        shipped=dict(info) if isinstance(info, dict) else {},
        trained=training_options(policy_or_name) or {},
    )


def _resolve_name(text: str, label: str | None, options: dict[str, Any]) -> Method:
    """A baseline, a table row, a shipped name (always the verified package file, never a file of
    that name in the current folder: an SB3 zip can run code when loaded) or a model path."""
    alias = _alias(text)
    if alias is not None:
        planner, fixed = PLANNER_ALIASES[alias]
        return Method(label or alias, planner, planner_kwargs={**fixed, **options}, source="planner")
    if is_baseline(text):
        name = planner_class(text).name
        return Method(label or name, name, planner_kwargs=options, source="planner")
    if pretrained.is_shipped(text):
        return _resolve_shipped(text, label)
    if not text.strip():
        raise ValueError("empty method name")
    return _resolve_path(text, label, explicit=False)


def _resolve_shipped(name: str, label: str | None) -> Method:
    """A shipped model by name: its manifest entry, its zip verified (hashed) once, its options."""
    info = pretrained.model_info(name)
    path = pretrained.model_path(name, verify=True)
    if info.get("world", 1) != WORLD_VERSION:
        warnings.warn(pretrained.outdated_message(name, info), stacklevel=4)
    return Method(
        label or name,
        name,
        kind=str(info.get("algo", "coma")).lower(),
        source="shipped",
        path=path,
        shipped=info,
        trained=pretrained.shipped_env_options(name) or {},
    )


def _resolve_path(text: str, label: str | None, explicit: bool) -> Method:
    """A model file (``.zip`` optional); a shipped zip reached by its path is verified like the
    shipped name (``PretrainedError``). ``explicit``: given as a path object, so never "unknown"."""
    for path in (Path(text), Path(text + ".zip")):
        if path.is_file():
            pretrained.verify_shipped_file(path)
            trained = training_options(path) or {}  # also refuses a file that is not a COMA zip
            return Method(label or path.stem, text, kind="coma", source="file", path=path, trained=trained)
    if not Path(text).is_dir() and (explicit or looks_like_path(text)):
        raise FileNotFoundError(f"model file not found: {text!r}")
    raise ValueError(  # one rule for a name that is no model file: a folder, or an unknown name
        f"model {text!r} is a folder: pass the model .zip inside it (e.g. {text}/model.zip)"
        if Path(text).is_dir()
        else f"unknown method {text!r}: not a baseline ({', '.join(sorted(PLANNERS))}; table rows: "
        f"{', '.join(sorted(PLANNER_ALIASES))}), not a model file, and not "
        f"a shipped model (available: {', '.join(pretrained.available()) or 'none'})"
    )
