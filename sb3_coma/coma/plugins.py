"""Policy aliases that live outside the algorithm, and saved models whose policy class moved.

The algorithm knows no world: a package that brings COMA policies for its own env (the UAV world's
``CBAMPolicy`` here, a user's package elsewhere) declares them under the entry-point group
``sb3_coma.policies`` (``CBAMPolicy = sb3_coma.uav.policies:CBAMPolicy``), and
``COMA("CBAMPolicy", env)`` loads the class on first use. Nothing is imported until an alias
outside SB3's three is asked for.
"""

from __future__ import annotations

import base64
import io
import json
import os
import pickletools
import zipfile
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from stable_baselines3.common.policies import BasePolicy

#: Entry-point group of policy aliases brought by other packages.
POLICY_ENTRY_POINTS = "sb3_coma.policies"

#: Policy classes pickled under their sb3-coma 0.2 home -> the alias they load as today. The UAV
#: policies moved out of the algorithm (``sb3_coma.coma.policies``) when COMA became generic, and
#: that module's ``CnnPolicy`` is now the generic one: a 0.2 ``CnnPolicy`` is the UAV plain CNN.
_MOVED = {
    ("sb3_coma.coma.policies", "CBAMPolicy"): "CBAMPolicy",
    ("sb3_coma.coma.policies", "CnnPolicy"): "UavCnnPolicy",
    ("sb3_coma.coma.policies", "COMAPolicy"): "UavCOMAPolicy",
}


def plugin_policies() -> dict[str, EntryPoint]:
    """Alias -> entry point of every installed package's COMA policies."""
    return {ep.name: ep for ep in entry_points(group=POLICY_ENTRY_POINTS)}


def _policy_base() -> type[BasePolicy]:
    from sb3_coma.coma.policies import COMAPolicy  # the base class, imported late: policies imports joint only

    return COMAPolicy


def resolve_policy(policy: Any, aliases: dict[str, type[BasePolicy]]) -> type[BasePolicy]:
    """The policy class of an alias (SB3's three, then plug-ins) or a ``COMAPolicy`` subclass.

    :raises ValueError: an unknown alias, naming the known ones
    :raises TypeError: anything else
    """
    base = _policy_base()
    if isinstance(policy, str):
        if policy in aliases:
            return aliases[policy]
        plugins = plugin_policies()
        if policy not in plugins:
            raise ValueError(f"unknown policy alias {policy!r}; COMA knows {sorted({*aliases, *plugins})}")
        policy = plugins[policy].load()
    if not (isinstance(policy, type) and issubclass(policy, base)):
        raise TypeError(f"policy must be an alias or a COMAPolicy subclass, got {policy!r}")
    return policy


def _pickled_global(serialized: str) -> tuple[str, str] | None:
    """``(module, name)`` of a class pickled by reference, read from the opcodes without running them."""
    strings: list[str] = []
    for opcode, arg, _pos in pickletools.genops(base64.b64decode(serialized)):
        if isinstance(arg, str):
            strings.append(arg)
        if opcode.name == "STACK_GLOBAL" and len(strings) >= 2:
            return strings[-2], strings[-1]
        if opcode.name == "GLOBAL" and isinstance(arg, str):
            module, _, name = arg.partition(" ")
            return module, name
    return None


def _saved_data(path: str | os.PathLike[str] | io.BufferedIOBase) -> dict[str, Any] | None:
    """The ``data`` JSON of an SB3 zip (a file object is read and rewound), or ``None``."""
    try:
        if isinstance(path, (str, os.PathLike)):
            target = os.fspath(path)
            target = target if os.path.exists(target) or target.endswith(".zip") else target + ".zip"
            with zipfile.ZipFile(target) as archive:
                return json.loads(archive.read("data"))
        start = path.tell()
        try:
            with zipfile.ZipFile(path) as archive:  # type: ignore[arg-type]
                return json.loads(archive.read("data"))
        finally:
            path.seek(start)
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None  # not ours to judge: SB3's load reports what is wrong with the file


def saved_policy_class(path: str | os.PathLike[str] | io.BufferedIOBase) -> type[BasePolicy] | None:
    """The class a model saved under a moved policy class loads as (``None``: nothing moved)."""
    data = _saved_data(path)
    if data is None or "coma_format" in data:  # saved since COMA became generic: its classes are where they say
        return None
    serialized = (data.get("policy_class") or {}).get(":serialized:")
    if not isinstance(serialized, str):
        return None
    try:
        found = _pickled_global(serialized)
    except Exception:  # a pickle pickletools cannot walk: SB3 reports it
        return None
    if found not in _MOVED:
        return None
    return resolve_policy(_MOVED[found], {})
