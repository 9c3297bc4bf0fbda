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
from collections.abc import Callable
from importlib import metadata
from typing import Any, cast

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv, VectorWrapper

from . import layout
from .config import ConfigError
from .geometry import overlap_matrix

#: Keys a fusion wrapper replaces by the 8th ``local`` channel (``layout.FUSED``).
_CONSUMED = (layout.KEY_LOCAL, layout.KEY_RECEIVED, layout.KEY_RECEIVED_VALID)


def _shape(space: spaces.Dict, key: str) -> tuple[int, ...]:
    box = space[key]
    if not isinstance(box, spaces.Box):
        raise TypeError(f"observation[{key!r}] must be a Box, got {box}")
    return box.shape


def fused_observation_space(raw: spaces.Dict) -> spaces.Dict:
    """The per-agent space after fusion: ``local`` (8 ch), ``state``, ``action_mask`` and any other
    key of the raw space (``action_gain``) as it is; the received maps are consumed."""
    channels, h, w = _shape(raw, layout.KEY_LOCAL)
    entries: dict[str, spaces.Space[Any]] = {layout.KEY_LOCAL: spaces.Box(0.0, 1.0, (channels + 1, h, w), np.float32)}
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
            raise TypeError(
                f"{type(self).__name__} needs the raw IPP observation (a Dict with '{layout.KEY_RECEIVED}'), got {raw}"
            )
        self.raw_observation_space = raw
        # SuperSuit resets a finished copy inside step() and returns the last observation in infos.
        self.metadata = {**dict(env.metadata), "autoreset_mode": AutoresetMode.SAME_STEP}
        self.observation_space = fused_observation_space(raw)
        self.single_observation_space = self.observation_space
        comm = _shape(raw, layout.KEY_RECEIVED)[-1]
        lattice = _shape(raw, layout.KEY_LOCAL)[-1]
        self._to_lattice = overlap_matrix(comm, float(lattice - 1), lattice)

    def fuse(self, received: np.ndarray, valid: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def observations(self, observations: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Batched: raw dict of (B, ...) arrays -> fused dict of (B, ...) arrays."""
        fused = self.fuse(observations[layout.KEY_RECEIVED], observations[layout.KEY_RECEIVED_VALID])
        a = self._to_lattice
        small = np.clip(np.matmul(np.matmul(a, fused), a.T), 0.0, 1.0).astype(np.float32)
        raw = observations[layout.KEY_LOCAL]
        cut = layout.RAW_LOCAL_CHANNELS  # FUSED sits after the raw 7; observation v3's channels follow it
        local = np.concatenate([raw[:, :cut], small[:, None], raw[:, cut:]], axis=1)
        out = {layout.KEY_LOCAL: local}
        out.update((key, value) for key, value in observations.items() if key not in _CONSUMED)
        return out

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        observations, infos = self.env.reset(seed=seed, options=options)
        return self.observations(observations), infos

    def step(self, actions):
        """Fuse the step's observations and, where copies finished, their terminal observations, in
        one call of :meth:`fuse` (one network pass for SenDFuse, even at episode ends)."""
        observations, rewards, terminations, truncations, step_infos = self.env.step(actions)
        infos = cast("list[dict[str, Any]]", step_infos)  # SuperSuit: one info dict per row
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


#: The fusion of every entry point that builds a vec env: the paper's SenDFuse (an entry point).
DEFAULT_FUSION = "sendfuse"
#: Fusions built into ``envs``; ``"none"`` keeps the raw observation (for tools).
BUILTIN_FUSIONS: dict[str, Callable[..., FusionWrapper]] = {"mean": MeanFusionWrapper}
RAW_FUSION = "none"
#: Entry-point group through which installed packages provide more fusion wrappers: a name and
#: ``module:Class`` of a :class:`FusionWrapper` subclass (sb3-coma's setup.cfg declares
#: ``sendfuse = sb3_coma.sendfuse.wrapper:SenDFuseFusionWrapper``). Looked up when an env is
#: wrapped, so importing ``envs`` imports nothing of those packages.
ENTRY_POINT_GROUP = "uav_ipp.fusion"


def _installed_fusions() -> dict[str, metadata.EntryPoint]:
    """Name -> entry point over every distribution on the path. Not ``metadata.entry_points()``,
    which reads only the first distribution of each name: a stale ``*.egg-info`` folder in a
    source checkout (on ``sys.path`` as the working directory) would hide the installed one."""
    found: dict[str, metadata.EntryPoint] = {}
    for dist in metadata.distributions():
        for entry in dist.entry_points:
            if entry.group == ENTRY_POINT_GROUP:
                found.setdefault(entry.name, entry)
    return found


def available_fusions() -> list[str]:
    """Every name ``make_vec_env(fusion=...)`` accepts here: built-in and installed ones."""
    return sorted({*BUILTIN_FUSIONS, RAW_FUSION, *_installed_fusions()})


def fusion_factory(name: str) -> Callable[..., FusionWrapper]:
    """The wrapper class of a fusion name; ``ValueError`` listing the available names for an unknown
    one, :class:`ConfigError` for an installed one that cannot be loaded."""
    if name in BUILTIN_FUSIONS:
        return BUILTIN_FUSIONS[name]
    installed = _installed_fusions()
    if not isinstance(name, str) or name not in installed:
        raise ValueError(
            f"unknown fusion {name!r}; choose one of {available_fusions()}"
            + (
                ""
                if installed
                else f" (no package provides entry points {ENTRY_POINT_GROUP!r}: "
                "`pip install -e .` in the sb3-coma checkout adds 'sendfuse')"
            )
        )
    entry = installed[name]
    try:  # one rule: the entry point loads a FusionWrapper subclass
        factory = entry.load()
        why = (
            None if isinstance(factory, type) and issubclass(factory, FusionWrapper) else "not a FusionWrapper subclass"
        )
    except (ImportError, AttributeError) as exc:
        why = str(exc)
    if why is not None:
        raise ConfigError(f"fusion {name!r} ({entry.value}) cannot be loaded: {why}")
    return factory


def wrap_fusion(env: VectorEnv, fusion: str, **kwargs: Any) -> FusionWrapper | VectorEnv:
    """Apply the named fusion wrapper; ``"none"`` keeps the raw observation (for tools)."""
    factory = None if fusion == RAW_FUSION else fusion_factory(fusion)
    parameters = [] if factory is None else list(inspect.signature(factory).parameters)[1:]
    accepted = [n for n in parameters if n not in ("args", "kwargs")]
    unknown = sorted(set(kwargs) - set(accepted))
    if unknown:
        raise ConfigError(
            f"invalid option fusion_kwargs={kwargs!r}: fusion {fusion!r} does not take {unknown}; "
            f"it takes {accepted or 'no options'}"
        )
    return env if factory is None else factory(env, **kwargs)
