"""What counts as a number, an integer or a flag in a user's input: one predicate each.

Two facts of Python and numpy make a bare ``isinstance`` check wrong both ways:

* ``bool`` is a subclass of ``int``: ``isinstance(True, int)`` holds, so ``n_steps=True`` would
  pass as 1 and ``gamma=False`` as 0;
* numpy's scalars are no subclasses of ``int`` or ``float`` (except ``np.float64``, a ``float``):
  ``isinstance(np.int64(3), int)`` and ``isinstance(np.float32(0.5), float)`` are false, so a
  value read from an array would be refused, and ``np.bool_`` is not a ``bool``.

The algorithms (``coma``, ``mappo``, ``common``) and the application ask these predicates (typed
as narrowing to ``int``, ``float`` and ``bool``, which numpy's scalars behave as) and store what
they accept through :func:`plain`, so that saving a model or writing its YAML / JSON record never
meets a numpy scalar. The world has the same four in ``uav_ipp.config`` (with the command-line
integer types), which the world-side library folders (``baselines``, ``sendfuse``) use; these are
a second copy only because the algorithms know no world and may not import it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeGuard, TypeVar, cast

import numpy as np

F = TypeVar("F", bound=Callable[..., Any])


def is_flag(value: Any) -> TypeGuard[bool]:
    """True or False: a ``bool`` or numpy's ``np.bool_`` (which is not a ``bool`` subclass)."""
    return isinstance(value, (bool, np.bool_))


def flag(name: str, value: Any) -> bool:
    """``value`` as a ``bool`` if it is a flag, else a ``ValueError`` naming ``name`` and the value: a
    string such as ``"no"`` from a config would otherwise turn the option on."""
    if not is_flag(value):
        raise ValueError(f"{name}={value!r}: must be true or false")
    return bool(value)


def is_whole(value: Any) -> TypeGuard[int]:
    """An integer: an ``int`` or a numpy integer (``np.int64`` is not an ``int`` subclass), never a
    flag (``True`` is an ``int``; ``np.bool_`` is not a numpy integer)."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def is_real(value: Any) -> TypeGuard[float]:
    """A real number: an ``int``, a ``float`` or a numpy integer or floating scalar (``np.float32``
    is not a ``float`` subclass), never a flag. NaN and inf are numbers: ranges are the caller's."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def plain(value: Any) -> Any:
    """A numpy scalar as the Python ``bool``, ``int`` or ``float`` it holds; anything else as it is."""
    return value.item() if isinstance(value, (np.bool_, np.integer, np.floating)) else value


def plain_arguments(function: F) -> F:
    """``function`` called with every numpy scalar argument as the Python number it holds: for a
    constructor that stores its arguments (``COMA(n_steps=np.int64(8), gamma=np.float32(0.9))``
    keeps an ``int`` and a ``float``, which its saved ``data`` member writes as JSON)."""

    @functools.wraps(function)
    def called(*args: Any, **kwargs: Any) -> Any:
        return function(*[plain(a) for a in args], **{k: plain(v) for k, v in kwargs.items()})

    return cast(F, called)
