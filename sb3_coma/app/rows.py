"""The rows of the result tables: which methods every protocol flies on a map.

The baselines (:data:`BASELINE_METHODS`) and the learned models that exist for a map
(:func:`shipped_methods`: every shipped COMA model of the map, IPPO / MAPPO models when shipped),
with the row label a shipped model gets (:func:`shipped_label`) and its inverse, so a row of
docs/RESULTS.md can be flown again by its name. The protocols, ``reproduce`` and the CLI's
``--methods`` all read these, so they live here, below the studies.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from sb3_coma.app.methods import Method
from sb3_coma.app.pretrained import load_pretrained, read_manifest
from uav_ipp import WORLD_VERSION

#: Kinds of learned methods besides COMA that get rows when their models exist (the hook: a
#: manifest entry with ``"algo"`` one of these, loaded by ``sb3_coma.app.pretrained.load_pretrained``).
LEARNED_BASELINES: tuple[str, ...] = ("ippo", "mappo")


#: The baselines every protocol flies: AG (the map's weighting; every UAV knows every teammate's
#: position and the moves lower ids chose this step, whatever the range: "AG, shared positions"),
#: AG searching 2 and 3 moves ahead, AG that knows only the teammates within communication range
#: ("AG, comm only"), the lawnmower (the paper's NL) and random; and two upper references, never
#: competitors: AG planning centrally from the global belief, and the clairvoyant oracle.
BASELINE_METHODS: tuple[Method, ...] = (
    Method("ag", "ag"),
    Method("ag-k2", "ag", planner_kwargs={"lookahead": 2}),
    Method("ag-k3", "ag", planner_kwargs={"lookahead": 3}),
    Method("ag-comm", "ag", planner_kwargs={"knowledge": "comm"}),
    Method("lawnmower", "lawnmower"),
    Method("random", "random"),
    Method("ag-central", "ag", kind="reference", planner_kwargs={"knowledge": "central"}),
    Method("oracle", "oracle", kind="reference"),
)


def _manifest_models() -> dict[str, dict[str, Any]]:
    try:
        return dict(read_manifest()["models"])
    except ValueError:  # no manifest in this install
        return {}


def outdated_note(info: Mapping[str, Any]) -> str:
    """ "outdated: ..." when a shipped model was trained on another world version than this env's."""
    world = info.get("world", 1)
    return "" if world == WORLD_VERSION else f"outdated: trained on world v{world}, this is v{WORLD_VERSION}"


def shipped_label(name: str, info: Mapping[str, Any], env: str) -> str:
    """Row label of a shipped model: ``"coma"`` for the map's own model, ``"coma[sendfuse-cnn]"``
    for another COMA model of that map, the algorithm name (``"ippo"``) for learned baselines."""
    algo = str(info.get("algo", "coma")).lower()
    suffix = name[len(env) + 1 :] if name.startswith(env + "-") else ("" if name == env else name)
    if algo != "coma":
        return algo + (f"[{suffix}]" if suffix and suffix != algo else "")
    return "coma" + (f"[{suffix}]" if suffix else "")


def shipped_name_of_label(label: str, env: str) -> str | None:
    """The shipped model a table row names on map ``env``, the inverse of :func:`shipped_label`:
    ``"coma"`` -> ``"env3"``, ``"coma[mean-cnn]"`` -> ``"env3-mean-cnn"``; None when no shipped
    model of that map has this row. So a row of docs/RESULTS.md can be flown again by its name."""
    models = _manifest_models()
    return next(
        (name for name, info in models.items() if info.get("env") == env and shipped_label(name, info, env) == label),
        None,
    )


def shipped_methods(
    env: str,
    loaded: Mapping[str, Any] | None = None,
    skip: Sequence[str] = (),
    log: Callable[[str], None] | None = None,
) -> list[Method]:
    """The learned methods that exist for map ``env``: every shipped model whose manifest ``env`` is
    this map, COMA first (the map's own model, then the others in manifest order), then IPPO /
    MAPPO. ``loaded`` maps shipped names to models already loaded (reused, not reloaded); names in
    ``skip`` are left out; a model that cannot be loaded is left out with a message."""

    models = {k: v for k, v in _manifest_models().items() if v.get("env") == env and k not in skip}
    order = sorted(models, key=lambda k: (str(models[k].get("algo", "coma")).lower() != "coma", k != env))
    out = []
    for name in order:
        info = models[name]
        algo = str(info.get("algo", "coma")).lower()
        if algo not in ("coma", *LEARNED_BASELINES):
            continue
        model = (loaded or {}).get(name)
        if model is None:
            try:
                model = load_pretrained(name)
            except (ValueError, RuntimeError, OSError, KeyError) as exc:
                if log:
                    log(f"leaving out shipped model {name!r}: {exc}")
                continue
        out.append(
            Method(
                shipped_label(name, info, env),
                model,
                kind=algo,
                fusion=info.get("fusion"),
                deterministic=info.get("deterministic"),
                note=outdated_note(info),
            )
        )
    return out
