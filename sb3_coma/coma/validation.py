"""Argument and environment checks for COMA, raising errors that name the bad value.

They run before any network is built, so a wrong env or hyperparameter fails at construction
with a message saying what was expected, instead of a shape error deep inside a rollout.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces

from sb3_coma.common.joint import KEY_MASK


def check_spaces(observation_space: spaces.Space, action_space: spaces.Space) -> None:
    """What COMA needs of one agent's spaces: ``Discrete(n)`` actions; an ``action_mask`` key, if
    any, with one entry per action. All other shapes are the env's and the policy's business.

    :raises ValueError: naming the space
    """
    if not isinstance(action_space, spaces.Discrete):
        raise ValueError(
            f"COMA needs Discrete actions per agent, got {action_space} (SuperSuit's "
            "pad_action_space_v0 does not discretise; a continuous env needs a discrete action wrapper)"
        )
    if isinstance(observation_space, spaces.Dict) and KEY_MASK in observation_space.spaces:
        mask = observation_space[KEY_MASK]
        if tuple(mask.shape or ()) != (int(action_space.n),):
            raise ValueError(
                f"observation[{KEY_MASK!r}] must have shape ({int(action_space.n)},), one entry per action of "
                f"{action_space}; got {mask}"
            )


def check_masks(masks: np.ndarray, n_actions: int) -> None:
    """Masks of every row ``(rows, n)``, each row with at least one valid action.

    :raises ValueError: the wrong shape, or the rows that allow nothing
    """
    if masks.ndim != 2 or masks.shape[1] != n_actions:
        raise ValueError(f"action masks must have shape (rows, {n_actions}), got {masks.shape}")
    empty = np.flatnonzero(~(masks > 0.5).any(axis=1))
    if empty.size:
        raise ValueError(f"action masks of rows {empty[:8].tolist()} allow no action: every agent needs a valid one")


#: The most joint steps one ``learn()`` may be asked for: 10^10 is weeks of the fastest collection
#: measured here; a larger number is a typo (``1e100``), and floats lose whole steps past 2^53.
MAX_JOINT_STEPS = 10**10


def check_total_timesteps(value: Any, what: str = "total_timesteps") -> int:
    """A whole number of joint steps in ``[1, MAX_JOINT_STEPS]`` (``3.6e4`` passes), the one rule for
    ``learn()``, the config's ``n_timesteps`` and ``--timesteps``.

    :raises ValueError: naming the value and the bounds
    """
    given = value
    if isinstance(value, float) and math.isfinite(value) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= MAX_JOINT_STEPS:
        raise ValueError(f"{what} must be a whole number of joint steps from 1 to {MAX_JOINT_STEPS:.0e}, got {given!r}")
    return int(value)


def check_positive_rate(name: str, value: float | Callable[[float], float]) -> None:
    """A learning rate: a positive number, or a schedule whose starting value is positive."""
    start = value(1.0) if callable(value) else value
    if isinstance(start, bool) or not isinstance(start, (int, float)) or not (start > 0 and math.isfinite(start)):
        raise ValueError(f"{name} must be a finite positive number, got {value!r}")


def check_unit_interval(name: str, value: float, low_open: bool = False) -> None:
    """A number in [0, 1] (or (0, 1] with ``low_open``)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise TypeError(f"{name} must be a number, got {value!r}")
    if not (0.0 < value <= 1.0 if low_open else 0.0 <= value <= 1.0):
        raise ValueError(f"{name} must lie in {'(0, 1]' if low_open else '[0, 1]'}, got {value!r}")


def check_non_negative(name: str, value: float) -> None:
    """A weight such as ``ent_coef``: a number >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{name} must be a number >= 0, got {value!r}")
    if not value >= 0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")


def check_positive_int(name: str, value: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise TypeError(f"{name} must be an int, got {value!r}")
    if value < 1:
        raise ValueError(f"{name} must be >= 1, got {value!r}")


def check_batch_fits_rollout(batch_size: int, n_steps: int, n_copies: int) -> None:
    """A minibatch of joint steps cannot be larger than what one rollout collects."""
    if batch_size > n_steps * n_copies:
        raise ValueError(
            f"batch_size={batch_size} joint steps is larger than one rollout (n_steps={n_steps} x "
            f"{n_copies} env copies = {n_steps * n_copies} joint steps); raise n_steps or lower batch_size"
        )


def check_observation(observation: Any, observation_space: spaces.Space | None = None) -> None:
    """What ``COMA.predict`` is given: every key of a ``Dict`` observation space present, and finite
    numbers. A NaN would silently become some action; say so at the API boundary instead."""
    if isinstance(observation_space, spaces.Dict):
        if not isinstance(observation, dict):
            raise TypeError(f"COMA.predict needs the vec env's observation dict, got {type(observation).__name__}")
        for key in observation_space.spaces:
            if key not in observation:
                raise ValueError(
                    f"observation lacks {key!r} (keys: {sorted(observation)}); pass what the vec env returns"
                )
    values = observation.items() if isinstance(observation, dict) else [("observation", observation)]
    for key, value in values:
        array = np.asarray(value)
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            raise ValueError(f"observation {key!r} holds NaN or inf ({int((~np.isfinite(array)).sum())} values)")


def check_finite_weights(module: th.nn.Module, where: Any) -> None:
    """Every parameter and buffer finite: a diverged or damaged model would otherwise fly and
    export as some arbitrary policy without a word.

    :raises ValueError: naming the file and the first non-finite tensor
    """
    for name, tensor in [*module.named_parameters(), *module.named_buffers()]:
        if tensor.is_floating_point() and not th.isfinite(tensor).all():
            bad = int((~th.isfinite(tensor)).sum())
            raise ValueError(
                f"{where}: tensor {name!r} holds {bad} NaN or inf values (a diverged run or a damaged file); not loaded"
            )


def check_device(device: Any) -> None:
    """Refuse a device torch cannot parse or this machine does not have, before anything is built.

    SB3 quietly trains on the CPU when ``cuda`` is asked for and no GPU is visible (and torch fails
    only at the first tensor for a missing ``cuda:<index>`` or ``mps``): a run meant for a GPU would
    then take hours with no word. ``auto`` keeps SB3's choice (the GPU when there is one).

    :raises ValueError: naming the device and what this machine has
    """
    if isinstance(device, str) and device == "auto":
        return
    try:
        parsed = th.device(device)
    except (RuntimeError, TypeError, ValueError) as exc:
        raise ValueError(f"device {device!r} is not a torch device: use auto, cpu, cuda or cuda:<index>") from exc
    if parsed.type == "cuda":
        count = th.cuda.device_count() if th.cuda.is_available() else 0
        if count == 0:
            raise ValueError(f"device {device!r}: no CUDA device is available on this machine; use auto or cpu")
        if parsed.index is not None and parsed.index >= count:
            raise ValueError(
                f"device {device!r}: no such CUDA device (this machine has {count}: cuda:0..cuda:{count - 1})"
            )
    if parsed.type == "mps" and not th.backends.mps.is_available():
        raise ValueError(f"device {device!r}: no MPS (Apple GPU) device is available on this machine; use auto or cpu")


#: COMA's advantage estimators: ``"return"`` (TD(lambda) return minus the counterfactual baseline,
#: the default) and ``"q"`` (the paper's ``Q(s, u)`` minus the baseline).
ADVANTAGES = ("return", "q")


def _check_positive_number(name: str, value: Any, what: str = "positive") -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 < value < math.inf:
        raise ValueError(f"{name} must be {what}, got {value!r}")


def check_coma_arguments(args: dict[str, Any]) -> None:
    """Check ``COMA``'s constructor arguments (``locals()`` of ``__init__``), one rule per setting,
    each error naming the argument and its value (SB3-style programming-error checks)."""
    for name in ("learning_rate", "critic_learning_rate"):
        check_positive_rate(name, args[name])
    for name in ("gamma", "td_lambda", "exploration_initial_eps", "exploration_final_eps"):
        check_unit_interval(name, args[name])
    for name in ("exploration_fraction", "kl_fraction"):
        check_unit_interval(name, args[name], low_open=True)
    for name in ("batch_size", "n_critic_epochs", "n_epochs", "target_update_interval", "stats_window_size"):
        check_positive_int(name, args[name])
    for name in ("ent_coef", "kl_coef"):
        check_non_negative(name, args[name])
    if args["n_steps"] is not None:
        check_positive_int("n_steps", args["n_steps"])
    if args["clip_range"] is not None:
        _check_positive_number("clip_range", args["clip_range"], "None or a positive number")
    _check_positive_number("max_grad_norm", args["max_grad_norm"])
    if not isinstance(args["normalize_advantage"], (bool, np.bool_)):
        raise ValueError(f"normalize_advantage must be True or False, got {args['normalize_advantage']!r}")
    if args["advantage"] not in ADVANTAGES:
        raise ValueError(f"advantage must be one of {ADVANTAGES}, got {args['advantage']!r}")
    seed = args["seed"]
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise ValueError(f"seed must be None or an integer >= 0, got {seed!r}")
