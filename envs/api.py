"""The world's two front doors, :func:`make_env` and :func:`make_vec_env` (served by ``uav_ipp``)."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from .config import DEFAULT_MAP, ConfigError, IppConfig
from .fusion import DEFAULT_FUSION
from .ipp_env import UavIppEnv
from .registration import map_name_of
from .vec_env import check_copies_and_seed
from .vec_env import make_vec_env as _make_vec_env
from .workers import check_workers, make_worker_vec_env


def resolve_config(name: str | IppConfig, options: dict[str, Any]) -> IppConfig:
    """The one place a map name and options become an :class:`IppConfig` (checked once, at
    construction); a config given as it is travels on untouched, and options beside it are refused
    rather than silently dropped."""
    if isinstance(name, IppConfig):
        if options:
            raise ConfigError(f"options {sorted(options)} given with an IppConfig: set them in the config")
        return name
    return IppConfig.from_options(map_name_of(name), **options)


def make_env(name: str | IppConfig = DEFAULT_MAP, **options: Any) -> UavIppEnv:
    """A PettingZoo ``ParallelEnv`` for the named map (``env1``/``env2``/``env3``, a gymnasium id,
    or any name with ``map_path=`` and ``valuable=``) or a resolved :class:`IppConfig`; options as
    in :class:`IppConfig`."""
    return UavIppEnv(resolve_config(name, options))


def make_vec_env(
    name: str | IppConfig = DEFAULT_MAP,
    n_envs: int = 1,
    fusion: str = DEFAULT_FUSION,
    seed: int | None = None,
    workers: int = 1,
    backend: str = "subprocess",
    ray_address: str | None = None,
    **options: Any,
) -> VecEnv:
    """SB3 ``VecEnv`` of ``n_envs`` copies; agent ``a`` of copy ``e`` at index ``e * n_agents + a``.

    ``fusion``: ``"sendfuse"`` (default), ``"mean"``, ``"none"`` or any name in
    :func:`available_fusions`; ``options``: :class:`IppConfig` options, ``fusion_kwargs``, ``monitor``;
    ``name`` may be a resolved :class:`IppConfig` (then no env options beside it), which travels to
    every copy and worker as it is, checked once.

    Scale-out (docs/scaling.md): ``workers=1`` with the default backend steps every copy in this
    process (:class:`IppVecEnv`); ``workers=W > 1`` splits the copies into ``W`` contiguous blocks
    stepped in worker processes (``backend="subprocess"``) or, with ``backend="ray"`` (any
    ``workers``), in Ray actors on this machine or on the cluster at ``ray_address``. Row order,
    seeds and so trajectories are the same whatever ``workers`` and ``backend`` are."""
    check_copies_and_seed(n_envs, seed)
    n_envs, seed = int(n_envs), None if seed is None else int(seed)  # numpy integers as Python ints
    check_workers(n_envs, workers, backend, ray_address)
    monitor = bool(options.pop("monitor", True))
    fusion_kwargs = options.pop("fusion_kwargs", None)
    config = resolve_config(name, options)
    if workers == 1 and backend == "subprocess":
        return _make_vec_env(config, n_envs, fusion, seed, monitor, fusion_kwargs)
    return make_worker_vec_env(
        config, n_envs=n_envs, fusion=fusion, seed=seed, workers=int(workers), backend=backend,
        ray_address=ray_address, monitor=monitor, fusion_kwargs=fusion_kwargs,
    )  # fmt: skip
