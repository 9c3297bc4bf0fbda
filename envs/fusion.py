"""Fusion wrappers: turn each agent's ``received`` maps into the 8th ``local`` channel.

They wrap the *vectorised* env (SuperSuit's gymnasium ``VectorEnv`` whose index is
``copy * n_agents + agent``), so one call fuses the received maps of every agent of every env
copy at once: one numpy reduction for ``mean``, one batched forward pass for ``sendfuse``.

SuperSuit auto-resets a finished copy inside ``step`` and puts the last observation in
``infos[i]["terminal_observation"]``; gymnasium's ``VectorObservationWrapper`` refuses that
auto-reset mode and would leave those observations unfused, so these wrappers subclass
``VectorWrapper`` and transform both (the same ``observations()`` hook as the gymnasium API).
"""
from __future__ import annotations

import inspect
from typing import Any, Callable

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv, VectorWrapper

from . import layout
from .config import ConfigError
from .geometry import overlap_matrix


#: Keys a fusion wrapper replaces by the 8th ``local`` channel.
_CONSUMED = (layout.KEY_LOCAL, layout.KEY_RECEIVED, layout.KEY_RECEIVED_VALID)


def fused_observation_space(raw: spaces.Dict) -> spaces.Dict:
    """The per-agent space after fusion: ``local`` (8 ch), ``state``, ``action_mask`` and any other
    key of the raw space (``action_gain``) as it is; the received maps are consumed."""
    local = raw[layout.KEY_LOCAL]
    channels, h, w = local.shape
    entries = {layout.KEY_LOCAL: spaces.Box(0.0, 1.0, (channels + 1, h, w), np.float32)}
    entries.update((key, space) for key, space in raw.spaces.items() if key not in _CONSUMED)
    return spaces.Dict(entries)


def mean_fusion(received: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Naive average of the valid received maps: (B, N, R, R), (B, N) -> (B, R, R).

    The ablation's "no SenDFuse": noise and unknown cells (0.5) are averaged in as they are.
    """
    weights = valid.astype(np.float32)
    total = np.maximum(weights.sum(axis=1), 1.0)
    return np.einsum("bn,bnij->bij", weights, received, optimize=False) / total[:, None, None]


class FusionWrapper(VectorWrapper):
    """Base: replaces ``received``/``received_valid`` by a fused ``local`` channel.

    Subclasses provide :meth:`fuse` (batched over agents and copies).
    """

    name = "base"

    def __init__(self, env: VectorEnv) -> None:
        super().__init__(env)
        raw = env.observation_space
        if not isinstance(raw, spaces.Dict) or layout.KEY_RECEIVED not in raw.spaces:
            raise TypeError(f"{type(self).__name__} needs the raw IPP observation (a Dict with "
                            f"'{layout.KEY_RECEIVED}'), got {raw}")
        self.raw_observation_space = raw
        # SuperSuit resets a finished copy inside step() and returns the last observation in infos.
        self.metadata = {**dict(env.metadata), "autoreset_mode": AutoresetMode.SAME_STEP}
        self.observation_space = fused_observation_space(raw)
        self.single_observation_space = self.observation_space
        comm = raw[layout.KEY_RECEIVED].shape[-1]
        lattice = raw[layout.KEY_LOCAL].shape[-1]
        self._to_lattice = overlap_matrix(comm, float(lattice - 1), lattice)

    def fuse(self, received: np.ndarray, valid: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def observations(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Batched: raw dict of (B, ...) arrays -> fused dict of (B, ...) arrays."""
        fused = self.fuse(observations[layout.KEY_RECEIVED], observations[layout.KEY_RECEIVED_VALID])
        a = self._to_lattice
        small = np.clip(np.matmul(np.matmul(a, fused), a.T), 0.0, 1.0).astype(np.float32)
        local = np.concatenate([observations[layout.KEY_LOCAL], small[:, None]], axis=1)
        out = {layout.KEY_LOCAL: local}
        out.update((key, value) for key, value in observations.items() if key not in _CONSUMED)
        return out

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        observations, infos = self.env.reset(seed=seed, options=options)
        return self.observations(observations), infos

    def step(self, actions):
        """Fuse the step's observations and, where copies finished, their terminal observations, in
        one call of :meth:`fuse` (one network pass for SenDFuse, even at episode ends)."""
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        ended = [i for i, info in enumerate(infos) if "terminal_observation" in info]
        if not ended:
            return self.observations(observations), rewards, terminations, truncations, infos
        raw = [infos[i]["terminal_observation"] for i in ended]
        batch = {key: np.concatenate([observations[key], np.stack([obs[key] for obs in raw])]) for key in observations}
        fused = self.observations(batch)
        rows = len(observations[layout.KEY_LOCAL])
        for k, i in enumerate(ended):
            infos[i]["terminal_observation"] = {key: value[rows + k] for key, value in fused.items()}
        return {key: value[:rows] for key, value in fused.items()}, rewards, terminations, truncations, infos


class MeanFusionWrapper(FusionWrapper):
    """``fusion="mean"``: the naive average (ablation baseline)."""

    name = "mean"

    def fuse(self, received: np.ndarray, valid: np.ndarray) -> np.ndarray:
        return mean_fusion(received, valid)


FUSION_WRAPPERS: dict[str, Callable[..., FusionWrapper]] = {"mean": MeanFusionWrapper}


def register_fusion(name: str, factory: Callable[..., FusionWrapper]) -> None:
    """Make a fusion wrapper available to ``make_vec_env(fusion=name)``."""
    FUSION_WRAPPERS[name] = factory


def wrap_fusion(env: VectorEnv, fusion: str, **kwargs: Any) -> FusionWrapper | VectorEnv:
    """Apply the named fusion wrapper; ``"none"`` keeps the raw observation (for tools)."""
    if fusion == "none":
        return env
    if fusion == "sendfuse" and fusion not in FUSION_WRAPPERS:
        try:
            from . import sendfuse_wrapper  # noqa: F401  (registers itself)
        except ImportError as exc:  # pragma: no cover - only when the module is missing
            raise ValueError(f"fusion='sendfuse' is unavailable: {exc}") from exc
    if fusion not in FUSION_WRAPPERS:
        raise ValueError(f"unknown fusion {fusion!r}; choose one of {sorted(FUSION_WRAPPERS) + ['none']}")
    factory = FUSION_WRAPPERS[fusion]
    accepted = [n for n in list(inspect.signature(factory).parameters)[1:] if n not in ("args", "kwargs")]
    unknown = sorted(set(kwargs) - set(accepted))
    if unknown:
        raise ConfigError(f"invalid option fusion_kwargs={kwargs!r}: fusion {fusion!r} does not take {unknown}; "
                          f"it takes {accepted or 'no options'}")
    return factory(env, **kwargs)
