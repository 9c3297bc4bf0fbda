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
from stable_baselines3.common.vec_env import VecEnv

from uav_ipp import layout

__all__ = [
    "check_batch_fits_rollout",
    "check_device",
    "check_positive_int",
    "check_positive_rate",
    "check_spaces",
    "check_unit_interval",
    "resolve_n_agents",
]


def resolve_n_agents(env: VecEnv) -> int:
    """Agents per env copy, read from the vec env (wrappers forward the attribute).

    :raises TypeError: ``env`` is not an SB3 ``VecEnv``
    :raises ValueError: no usable ``n_agents``, or ``num_envs`` not a multiple of it
    """
    if not isinstance(env, VecEnv):
        raise TypeError(
            f"COMA needs an SB3 VecEnv whose rows are agents (e.g. uav_ipp.make_vec_env(...)), got {type(env).__name__}"
        )
    n_agents: Any = getattr(env, "n_agents", None)
    if n_agents is None:
        try:
            values = env.get_attr("n_agents")
            n_agents = values[0] if values else None
        except Exception:  # any failure means "the env does not say"
            n_agents = None
    if n_agents is None:
        raise ValueError(
            "the vec env does not expose `n_agents` (agents per env copy); COMA cannot regroup its "
            "rows into joint steps. Build it with uav_ipp.make_vec_env(...) or set `n_agents` on it."
        )
    if isinstance(n_agents, bool) or not isinstance(n_agents, int) or n_agents < 1:
        raise ValueError(f"`n_agents` must be a positive int, got {n_agents!r}")
    if env.num_envs % n_agents != 0:
        raise ValueError(
            f"num_envs={env.num_envs} is not a multiple of n_agents={n_agents}: the vec env must hold "
            "whole env copies (agent a of copy e at index e * n_agents + a)"
        )
    return n_agents


def _check_box(obs_space: spaces.Dict, key: str, shape: tuple[int, ...] | None, what: str) -> spaces.Box:
    if key not in obs_space.spaces:
        raise ValueError(f"observation space lacks the key {key!r} ({what}); it has {list(obs_space.spaces)}")
    box = obs_space.spaces[key]
    if not isinstance(box, spaces.Box):
        raise ValueError(f"observation[{key!r}] must be a Box ({what}), got {box}")
    if shape is not None and tuple(box.shape) != shape:
        raise ValueError(f"observation[{key!r}] ({what}) must have shape {shape}, got {tuple(box.shape)}")
    return box


def check_spaces(observation_space: spaces.Space, action_space: spaces.Space) -> None:
    """The per-agent spaces COMA is built for (see ``uav_ipp.layout``).

    ``local`` must hold the 8 channels of the fusion wrapper's output (a raw env has 7: wrap it
    with a fusion wrapper first), ``state`` the 3 global channels on the same grid, and
    ``action_mask`` one entry per action of ``Discrete(6)``.

    :raises TypeError: wrong space types
    :raises ValueError: missing keys or wrong shapes
    """
    if not isinstance(action_space, spaces.Discrete) or int(action_space.n) != layout.N_ACTIONS:
        raise ValueError(f"COMA needs the action space Discrete({layout.N_ACTIONS}), got {action_space}")
    if not isinstance(observation_space, spaces.Dict):
        raise ValueError(
            "COMA needs a Dict observation space with keys "
            f"{layout.KEY_LOCAL!r}, {layout.KEY_STATE!r}, {layout.KEY_MASK!r}; got {observation_space}"
        )
    local = _check_box(observation_space, layout.KEY_LOCAL, None, f"{layout.LOCAL_CHANNELS} x H x W actor maps")
    v2, v3 = layout.LOCAL_CHANNELS, layout.LOCAL_CHANNELS + layout.V3_LOCAL_EXTRA
    if len(local.shape) != 3 or local.shape[0] not in (v2, v3):
        raw = local.shape[:1] in ((layout.RAW_LOCAL_CHANNELS,), (v3 - 1,))
        raise ValueError(
            f"observation[{layout.KEY_LOCAL!r}] must have shape ({v2}, H, W) or, observation v3, ({v3}, H, W); got "
            f"{tuple(local.shape)}" + (" (a raw env: add a fusion wrapper)" if raw else "")
        )
    if local.shape[1] < 4 or local.shape[2] < 4:
        raise ValueError(f"observation[{layout.KEY_LOCAL!r}] maps must be at least 4 x 4, got {tuple(local.shape)}")
    state_channels = layout.STATE_CHANNELS + (layout.V3_STATE_EXTRA if local.shape[0] == v3 else 0)
    _check_box(observation_space, layout.KEY_STATE, (state_channels, *local.shape[1:]), "critic's global maps")
    _check_box(observation_space, layout.KEY_MASK, (layout.N_ACTIONS,), "valid-action mask")


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


def check_observation(observation: Any) -> None:
    """What ``COMA.predict`` is given: the vec env's observation dict, with the action mask and
    finite maps. A NaN would silently become some action; say so at the API boundary instead."""
    if not isinstance(observation, dict):
        raise TypeError(f"COMA.predict needs the vec env's observation dict, got {type(observation).__name__}")
    for key in (layout.KEY_LOCAL, layout.KEY_MASK):
        if key not in observation:
            raise ValueError(f"observation lacks {key!r} (keys: {sorted(observation)}); pass what the vec env returns")
    for key, value in observation.items():
        array = np.asarray(value)
        if array.dtype.kind == "f" and not np.isfinite(array).all():
            raise ValueError(f"observation {key!r} holds NaN or inf ({int((~np.isfinite(array)).sum())} values)")


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
    if args["advantage"] not in ADVANTAGES:
        raise ValueError(f"advantage must be one of {ADVANTAGES}, got {args['advantage']!r}")
    seed = args["seed"]
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0):
        raise ValueError(f"seed must be None or an integer >= 0, got {seed!r}")
