"""The world's two front doors, :func:`make_env` and :func:`make_vec_env` (served by ``uav_ipp``)."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from .config import IppConfig
from .fusion import DEFAULT_FUSION
from .ipp_env import UavIppEnv
from .registration import map_name_of
from .vec_env import DEFAULT_MAP, check_copies_and_seed
from .vec_env import make_vec_env as _make_vec_env
from .workers import check_workers, make_worker_vec_env


def make_env(name: str = DEFAULT_MAP, **options: Any) -> UavIppEnv:
    """A PettingZoo ``ParallelEnv`` for the named map (``env1``/``env2``/``env3``, a gymnasium id,
    or any name with ``map_path=`` and ``valuable=``); options as in :class:`IppConfig`."""
    return UavIppEnv(IppConfig.from_options(map_name_of(name), **options))


def make_vec_env(
    name: str = DEFAULT_MAP,
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
    :func:`available_fusions`; ``options``: :class:`IppConfig` options, ``fusion_kwargs``, ``monitor``.

    Scale-out (docs/scaling.md): ``workers=1`` with the default backend steps every copy in this
    process (:class:`IppVecEnv`); ``workers=W > 1`` splits the copies into ``W`` contiguous blocks
    stepped in worker processes (``backend="subprocess"``) or, with ``backend="ray"`` (any
    ``workers``), in Ray actors on this machine or on the cluster at ``ray_address``. Row order,
    seeds and so trajectories are the same whatever ``workers`` and ``backend`` are."""
    check_copies_and_seed(n_envs, seed)
    check_workers(int(n_envs), workers, backend, ray_address)
    if workers == 1 and backend == "subprocess":
        return _make_vec_env(map_name_of(name), n_envs=n_envs, fusion=fusion, seed=seed, **options)
    return make_worker_vec_env(
        map_name_of(name), n_envs=n_envs, fusion=fusion, seed=seed, workers=int(workers), backend=backend,
        ray_address=ray_address, **options,
    )  # fmt: skip
