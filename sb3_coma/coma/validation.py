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
from sb3_coma.common.numbers import is_flag, is_real, is_whole


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
    if not is_whole(value) or not 1 <= value <= MAX_JOINT_STEPS:
        raise ValueError(f"{what} must be a whole number of joint steps from 1 to {MAX_JOINT_STEPS:.0e}, got {given!r}")
    return int(value)


class BatchLargerThanRollout(ValueError):
    """``batch_size`` is more joint steps than one rollout holds (a search prunes such a trial)."""


def check_batch_fits_rollout(batch_size: int, n_steps: int | None, env: Any, n_agents: int | None) -> None:
    """A minibatch of joint steps cannot be larger than what one rollout collects (``env``'s copies times
    ``n_steps``); before there is an env and a rollout length (loading) there is nothing to check."""
    if env is None or n_steps is None:
        return
    assert n_agents is not None  # an env gives its agent count
    n_copies = env.num_envs // n_agents
    if batch_size > n_steps * n_copies:
        raise BatchLargerThanRollout(
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
    n_cuda = th.cuda.device_count() if th.cuda.is_available() else 0
    # One rule for every accelerator: the device (and its index) must exist on this machine.
    present = {"cuda": (parsed.index or 0) < n_cuda, "mps": th.backends.mps.is_available()}
    if not present.get(parsed.type, True):
        kind, at = _ACCELERATORS[parsed.type], "" if parsed.index is None else f" at index {parsed.index}"
        has = f" (it has {n_cuda} CUDA device(s))" if parsed.type == "cuda" and n_cuda else ""
        raise ValueError(f"device {device!r}: no {kind} device is available{at} on this machine{has}; use auto or cpu")


#: The accelerators :func:`check_device` looks for, as its messages name them.
_ACCELERATORS = {"cuda": "CUDA", "mps": "MPS (Apple GPU)"}

#: COMA's advantage estimators: ``"return"`` (TD(lambda) return minus the counterfactual baseline,
#: the default), ``"q"`` (the paper's ``Q(s, u)`` minus the baseline), ``"gae"`` (the return
#: bootstrapped with the baseline) and ``"v_return"`` (bootstrapped with a fitted state value).
ADVANTAGES = ("return", "q", "gae", "v_return")
#: ``normalize_q``'s value that also rescales the critic's output layer when its statistics move.
POPART = "popart"


def _start(rate: Any) -> Any:
    """A learning rate's starting value (SB3 schedules are called with the remaining progress)."""
    return rate(1.0) if callable(rate) else rate


def _positive(value: Any) -> bool:
    return is_real(value) and 0.0 < value < math.inf


#: COMA's constructor arguments, one rule per group: (names, accepts, what is allowed). Each rule
#: is written once and applied to every argument of its group.
_ARGUMENT_RULES: tuple[tuple[tuple[str, ...], Callable[[Any], bool], str], ...] = (
    (("learning_rate", "critic_learning_rate"), lambda v: _positive(_start(v)), "be a finite positive number"),
    (
        ("gamma", "td_lambda", "exploration_initial_eps", "exploration_final_eps"),
        lambda v: is_real(v) and 0.0 <= v <= 1.0,
        "lie in [0, 1]",
    ),
    (("exploration_fraction", "kl_fraction"), lambda v: is_real(v) and 0.0 < v <= 1.0, "lie in (0, 1]"),
    (
        ("batch_size", "n_critic_epochs", "n_epochs", "target_update_interval", "stats_window_size"),
        lambda v: v >= 1,
        "be >= 1",
    ),
    (("n_steps", "critic_time_feature"), lambda v: v is None or v >= 1, "be None or >= 1"),
    (("ent_coef", "kl_coef"), lambda v: is_real(v) and v >= 0, "be a number >= 0"),
    (("clip_range",), lambda v: v is None or _positive(_start(v)), "be None, a positive number or a schedule of one"),
    (("max_grad_norm",), _positive, "be positive"),
    (
        ("normalize_advantage", "advantage_before_critic_update", "bootstrap_time_limits"),
        is_flag,
        "be True or False",
    ),
    (("normalize_q",), lambda v: is_flag(v) or v == POPART, f"be True, False or {POPART!r}"),
    (("advantage",), lambda v: v in ADVANTAGES, f"be one of {ADVANTAGES}"),
    (("seed",), lambda v: v is None or (is_whole(v) and v >= 0), "be None or an integer >= 0"),
)
#: The counts among them: a value of another type is a ``TypeError`` ("must be an int").
_COUNTS = frozenset(
    {
        "batch_size",
        "n_critic_epochs",
        "n_epochs",
        "target_update_interval",
        "stats_window_size",
        "n_steps",
        "critic_time_feature",
    }
)


def check_coma_arguments(args: dict[str, Any]) -> None:
    """Check ``COMA``'s constructor arguments (``locals()`` of ``__init__``) against
    :data:`_ARGUMENT_RULES`: one error naming the argument, its value and what is allowed
    (``TypeError`` for a count that is not an int, ``ValueError`` otherwise)."""
    for names, accepts, allowed in _ARGUMENT_RULES:
        for name in names:
            value = args[name]
            not_int = name in _COUNTS and value is not None and not is_whole(value)
            if not_int or not accepts(value):
                error = TypeError if not_int else ValueError
                raise error(f"{name} must {'be an int' if not_int else allowed}, got {value!r}")
