"""SB3 vectorisation: ParallelEnv -> SuperSuit (gymnasium) -> fusion -> our ``VecEnv`` -> VecMonitor.

SuperSuit's own ``base_class="stable_baselines3"`` adapter cannot be used as it is (its
``get_attr``, ``env_method`` and ``seed`` raise, resets are not seeded per copy, terminal infos
lack ``TimeLimit.truncated``), so :class:`IppVecEnv` is a small SB3 ``VecEnv`` over SuperSuit's
gymnasium vector env that fixes exactly those points. Agent ``a`` of env copy ``e`` sits at index
``e * n_agents + a``; ``n_agents`` is an attribute that learners read to regroup joint steps.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, cast

import numpy as np
import supersuit
from gymnasium.vector import VectorEnv
from stable_baselines3.common.vec_env import VecEnv, VecMonitor

from .config import IppConfig, invalid_option, is_whole
from .fusion import DEFAULT_FUSION, wrap_fusion
from .ipp_env import UavIppEnv


class IppVecEnv(VecEnv):
    """SB3 ``VecEnv`` adapter over SuperSuit's gymnasium vector env of IPP env copies."""

    def __init__(self, venv: VectorEnv, copies: Sequence[UavIppEnv]) -> None:
        self.venv = venv
        self.copies = list(copies)
        self.n_agents = self.copies[0].n_uavs
        self.n_copies = len(self.copies)
        super().__init__(venv.num_envs, venv.observation_space, venv.action_space)
        self.render_mode = self.copies[0].render_mode
        self._actions: np.ndarray | None = None
        self._copy_seed: int | None = None

    # ------------------------------------------------------------------ core API
    def reset(self):
        seed, self._copy_seed = self._copy_seed, None
        observations, reset_infos = self.venv.reset(seed=seed)
        self.reset_infos = [dict(info) for info in cast("list[dict[str, Any]]", reset_infos)]  # one per row
        self._reset_seeds()
        self._reset_options()
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self):
        assert self._actions is not None, "step_wait() called without step_async()"
        observations, rewards, terminations, truncations, step_infos = self.venv.step(self._actions)
        infos = cast("list[dict[str, Any]]", step_infos)  # SuperSuit: one info dict per row
        self._actions = None
        terminations = np.asarray(terminations, dtype=bool)
        truncations = np.asarray(truncations, dtype=bool)
        dones = terminations | truncations
        out_infos = []
        for i, row_info in enumerate(infos):
            info = dict(row_info)
            if dones[i]:
                info["TimeLimit.truncated"] = bool(truncations[i] and not terminations[i])
            out_infos.append(info)
        return observations, np.asarray(rewards, dtype=np.float32), dones, out_infos

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next reset: copy ``e`` gets ``seed + e`` (all its agents share it)."""
        if seed is None:
            seed = int(np.random.randint(0, 2**31 - 1))
        self._copy_seed = int(seed)
        self.set_mission_stride(self.n_copies)
        return [self._copy_seed + i // self.n_agents for i in range(self.num_envs)]

    def set_mission_stride(self, stride: int) -> None:
        """How far each copy's unseeded resets move on in a ``mission_from_seed`` sequence: the
        number of copies of the whole vec env (a worker's chunk is told the total, not its own)."""
        for env in self.copies:
            env.mission_stride = int(stride)

    def close(self) -> None:
        self.venv.close()

    # ------------------------------------------------------------------ attributes
    def _copy_indices(self, indices: int | Iterable[int] | None) -> list[int]:
        return [i // self.n_agents for i in self._get_indices(indices)]

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == "n_agents":
            return [self.n_agents for _ in self._get_indices(indices)]
        return [getattr(self.copies[c], attr_name) for c in self._copy_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        for c in sorted(set(self._copy_indices(indices))):
            setattr(self.copies[c], attr_name, value)

    def env_method(self, method_name: str, *method_args, indices=None, **method_kwargs) -> list[Any]:
        results: dict[int, Any] = {}
        out = []
        for c in self._copy_indices(indices):
            if c not in results:
                results[c] = getattr(self.copies[c], method_name)(*method_args, **method_kwargs)
            out.append(results[c])
        return out

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [self.copies[i // self.n_agents].render() for i in range(self.num_envs)]


def check_copies_and_seed(n_envs: Any, seed: Any) -> None:
    """One-line :class:`ConfigError` for a bad ``n_envs`` or ``seed``; shared with the worker
    pipeline (``uav_ipp.workers``), which must refuse them before it starts any process."""
    if not is_whole(n_envs) or n_envs < 1:
        invalid_option("n_envs", n_envs, "an integer >= 1 (env copies)")
    if seed is not None and not is_whole(seed):
        invalid_option("seed", seed, "an integer or None")


def make_vec_env(
    config: IppConfig,
    n_envs: int = 1,
    fusion: str = DEFAULT_FUSION,
    seed: int | None = None,
    monitor: bool = True,
    fusion_kwargs: dict[str, Any] | None = None,
) -> VecEnv:
    """Build the SB3 vec env of ``n_envs`` copies of one resolved :class:`IppConfig` in this process.

    ``uav_ipp.make_vec_env`` (docs/design.md, "Public names") resolves a map name and options into
    the config once and calls this; ``fusion`` is ``"sendfuse"`` (the paper's; provided by sb3-coma
    through the ``uav_ipp.fusion`` entry point), ``"mean"`` (the ablation's naive average) or
    ``"none"`` (the raw observation, for tools); ``fusion_kwargs`` are the fusion wrapper's options.
    """
    check_copies_and_seed(n_envs, seed)
    base = UavIppEnv(config)
    markov = supersuit.pettingzoo_env_to_vec_env_v1(base)
    concat = supersuit.concat_vec_envs_v1(markov, int(n_envs), num_cpus=0, base_class="gymnasium")
    copies = [v.par_env for v in concat.vec_envs]
    fused = wrap_fusion(concat, fusion, **(fusion_kwargs or {}))
    venv: VecEnv = IppVecEnv(fused, copies)
    if seed is not None:
        venv.seed(int(seed))
    if monitor:
        venv = VecMonitor(venv, info_keywords=("f1", "entropy"))
    return venv
