"""SB3 vectorisation of any PettingZoo ``ParallelEnv``: one vec-env row per agent.

``make_marl_vec_env`` builds ParallelEnv -> :class:`_InfoChannel` -> SuperSuit's
``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1(base_class="gymnasium")`` ->
:class:`MarlVecEnv` -> SB3 ``VecMonitor``. Agent ``a`` (in ``possible_agents`` order) of env copy
``e`` sits at row ``e * n_agents + a``; multi-agent learners (COMA) read ``n_agents``,
``n_copies``, ``state_source``, ``state_space`` and :meth:`MarlVecEnv.get_state` to regroup rows
into joint steps.

Why an adapter of our own: SuperSuit's ``base_class="stable_baselines3"`` raises in
``get_attr``/``env_method``/``seed``, does not seed copies per reset, leaves out
``TimeLimit.truncated`` and lets reset infos overwrite the infos of the step that ended an
episode. SuperSuit's gymnasium vector env does supply ``terminal_observation`` (the last
observation of every agent) but also merges reset infos into step infos, so :class:`_InfoChannel`
nests each reset info under a private key (and, for ``state_source="env"``, adds the global state
to every info), which the adapter takes apart again. Reading the state from infos rather than
calling ``state()`` on the copies keeps this correct if the copies ever run in subprocesses.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np
import supersuit
from gymnasium import spaces
from gymnasium.vector import VectorEnv
from pettingzoo import AECEnv, ParallelEnv
from pettingzoo.utils.wrappers import BaseParallelWrapper
from stable_baselines3.common.vec_env import VecEnv, VecMonitor
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from sb3_coma.common.joint import STATE_SOURCES
from sb3_coma.common.numbers import is_whole

# Private info keys of the channel between _InfoChannel (inside each copy) and MarlVecEnv.
_RESET_KEY = "_marl_reset_info"
_STATE_KEY = "_marl_state"

#: Attributes of the multi-agent contract that ``get_attr`` answers from the adapter itself.
_ADAPTER_ATTRS: tuple[str, ...] = ("n_agents", "n_copies", "state_source", "state_space")


class _InfoChannel(BaseParallelWrapper):
    """Wraps each env copy so that what the adapter needs survives SuperSuit's info handling.

    Reset infos are nested under ``_RESET_KEY`` (SuperSuit merges them into the infos of the step
    that ended the episode, which would otherwise overwrite step keys), the global state is
    written into every agent's info when ``with_state`` and a step where only some agents finish
    is refused (SuperSuit would report those rows done without resetting the episode).
    """

    def __init__(self, env: ParallelEnv, with_state: bool) -> None:
        super().__init__(env)
        self.with_state = with_state

    def _infos(self, infos: dict[str, Any]) -> dict[str, dict[str, Any]]:
        """Every agent's info (a copy), with the global state when ``with_state``: one ``state()``
        call per step, the same array in every agent's info (computing it per agent cost more
        than COMA's whole update on simple_spread)."""
        state = np.asarray(self.env.state(), dtype=np.float32) if self.with_state else None
        out = {}
        for agent in self.env.possible_agents:
            info = dict(infos.get(agent, {}))
            if state is not None:
                info[_STATE_KEY] = state
            out[agent] = info
        return out

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        observations, infos = self.env.reset(seed=seed, options=options)
        return observations, {agent: {_RESET_KEY: info} for agent, info in self._infos(infos).items()}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        observations, rewards, terminations, truncations, infos = self.env.step(actions)
        done = {agent: bool(terminations.get(agent) or truncations.get(agent)) for agent in self.env.possible_agents}
        if any(done.values()) and not all(done.values()):
            finished = [agent for agent, d in done.items() if d]
            raise RuntimeError(
                f"agents {finished} finished before the others; make_marl_vec_env needs all agents of an episode to end on the same step"
            )
        return observations, rewards, terminations, truncations, self._infos(infos)


class MarlVecEnv(VecEnv):
    """SB3 ``VecEnv`` over SuperSuit's gymnasium vector env of ParallelEnv copies (one row per agent).

    Built by :func:`make_marl_vec_env`; ``copies`` are the user's ParallelEnv copies (inside the
    :class:`_InfoChannel` that SuperSuit steps), used for ``get_attr``/``set_attr``/``env_method``.
    """

    def __init__(
        self, venv: VectorEnv, copies: Sequence[ParallelEnv], state_source: str, state_space: spaces.Box | None
    ) -> None:
        self.venv = venv
        self.copies = list(copies)
        self.n_agents = len(self.copies[0].possible_agents)
        self.n_copies = len(self.copies)
        self.state_source = state_source
        self.state_space = state_space
        # SuperSuit's vector env gives the per-agent (per-row) spaces as observation_space/action_space
        super().__init__(venv.num_envs, venv.observation_space, venv.action_space)
        self._n_actions = int(cast("spaces.Discrete", self.action_space).n)
        self._next_seed: int | None = None
        self._actions: np.ndarray | None = None
        self._observations: VecEnvObs | None = None
        self._states: np.ndarray | None = None
        self._info_masks: list[np.ndarray | None] = [None] * self.num_envs

    # ------------------------------------------------------------------ core API
    def reset(self) -> VecEnvObs:
        seed, self._next_seed = self._next_seed, None
        observations, infos = self.venv.reset(seed=seed, options=self._common_options())
        self._reset_seeds()
        self._reset_options()
        self.reset_infos = [
            self._current_info(row, dict(info[_RESET_KEY]))
            for row, info in enumerate(cast("list[dict[str, Any]]", infos))
        ]
        self._observations = observations
        return observations

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        assert self._actions is not None, "step_wait() called without step_async()"  # VecEnv protocol
        observations, rewards, terminations, truncations, step_infos = self.venv.step(self._actions)
        self._actions = None
        terminations = np.asarray(terminations, dtype=bool)
        truncations = np.asarray(truncations, dtype=bool)
        dones = terminations | truncations
        infos = []
        for row, row_info in enumerate(cast("list[dict[str, Any]]", step_infos)):
            info = dict(row_info)
            reset_info = info.pop(_RESET_KEY, None)
            step_state = info.pop(_STATE_KEY, None)
            if dones[row]:
                info["TimeLimit.truncated"] = bool(truncations[row] and not terminations[row])
                if step_state is not None:
                    info["terminal_state"] = step_state
            if reset_info is None:
                self._current_info(row, {**info, _STATE_KEY: step_state})
            else:
                self.reset_infos[row] = self._current_info(row, dict(reset_info))
            infos.append(info)
        self._observations = observations
        return observations, np.asarray(rewards, dtype=np.float32), dones, infos

    def _current_info(self, row: int, info: dict[str, Any]) -> dict[str, Any]:
        """Record what ``info`` (the info matching the row's current observation) says about the
        state and action mask; return it without the private state key."""
        state = info.pop(_STATE_KEY, None)
        if state is not None and row % self.n_agents == 0:
            if self._states is None:
                self._states = np.zeros((self.n_copies, *np.shape(state)), dtype=np.float32)
            self._states[row // self.n_agents] = state
        mask = info.get("action_mask")
        self._info_masks[row] = None if mask is None else np.asarray(mask, dtype=bool)
        return info

    def _common_options(self) -> dict[str, Any] | None:
        """SuperSuit passes one options dict to every copy: refuse per-row options that differ."""
        if any(options != self._options[0] for options in self._options):
            raise ValueError("MarlVecEnv resets every env copy with the same options; got different options per row")
        return self._options[0] or None

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next reset: copy ``e`` gets ``seed + e`` (all its agents share it)."""
        if seed is None:
            seed = int(np.random.randint(0, 2**31 - 1))
        self._next_seed = int(seed)
        return [self._next_seed + row // self.n_agents for row in range(self.num_envs)]

    def close(self) -> None:
        self.venv.close()

    # ------------------------------------------------------------------ multi-agent API
    def get_state(self) -> np.ndarray:
        """Global state of each copy's current joint step, shape ``(n_copies, *state_space.shape)``."""
        if self.state_source != "env":
            raise RuntimeError(
                f"get_state() needs state_source 'env' (PettingZoo's state()); this env's is {self.state_source!r}"
            )
        assert self._states is not None, "get_state() called before reset()"
        return self._states.copy()

    def action_masks(self) -> np.ndarray:
        """Valid actions per row, ``(num_envs, n_actions)`` bool (sb3-contrib's convention)."""
        if isinstance(self._observations, dict) and "action_mask" in self._observations:
            return np.asarray(self._observations["action_mask"], dtype=bool).reshape(self.num_envs, self._n_actions)
        masks = np.ones((self.num_envs, self._n_actions), dtype=bool)
        for row, mask in enumerate(self._info_masks):
            if mask is not None:
                masks[row] = mask
        return masks

    # ------------------------------------------------------------------ attributes
    def _copies_of(self, indices: VecEnvIndices) -> list[int]:
        return [row // self.n_agents for row in self._get_indices(indices)]

    def _owner(self, copy: ParallelEnv, attr_name: str, required: bool = True) -> Any:
        """The copy itself, or its unwrapped env when only that has ``attr_name`` (PettingZoo's
        conversion wrappers, e.g. ``aec_to_parallel``, forward little). When neither has it: the
        copy (``required=False``, where ``set_attr`` makes a new attribute) or an ``AttributeError``
        naming it (``get_attr`` and ``env_method``)."""
        for owner in (copy, copy.unwrapped):
            if hasattr(owner, attr_name):
                return owner
        if required:
            raise AttributeError(
                f"neither MarlVecEnv nor the env {type(copy).__name__} has an attribute or method {attr_name!r}"
            )
        return copy

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        rows = list(self._get_indices(indices))
        if attr_name in _ADAPTER_ATTRS:
            return [getattr(self, attr_name)] * len(rows)
        return [getattr(self._owner(self.copies[c], attr_name), attr_name) for c in self._copies_of(rows)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        if attr_name in _ADAPTER_ATTRS:
            raise AttributeError(f"{attr_name!r} is fixed when MarlVecEnv is built")
        for c in sorted(set(self._copies_of(indices))):
            setattr(self._owner(self.copies[c], attr_name, required=False), attr_name, value)

    def env_method(
        self, method_name: str, *method_args: Any, indices: VecEnvIndices = None, **method_kwargs: Any
    ) -> list[Any]:
        """Call a method once per env copy and give its result to each of the copy's rows;
        ``"action_masks"`` answers each row's mask (how sb3-contrib's ``get_action_masks`` asks)."""
        rows = list(self._get_indices(indices))
        if method_name == "action_masks":
            masks = self.action_masks()
            return [masks[row] for row in rows]
        results: dict[int, Any] = {}
        for c in self._copies_of(rows):
            if c not in results:
                results[c] = getattr(self._owner(self.copies[c], method_name), method_name)(
                    *method_args, **method_kwargs
                )
        return [results[c] for c in self._copies_of(rows)]

    def env_is_wrapped(self, wrapper_class: type, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self) -> Sequence[np.ndarray | None]:
        """One frame per env copy (not per row: a copy's agents share one scene)."""
        return [cast("np.ndarray | None", copy.render()) for copy in self.copies]


# ---------------------------------------------------------------------- checks
def _check_options(n_envs: Any, state: Any, seed: Any) -> None:
    """:func:`make_marl_vec_env`'s own options, one (value, rule, what is allowed) row each."""
    rules = (
        ("n_envs", n_envs, is_whole(n_envs) and n_envs >= 1, "an integer >= 1 (env copies)"),
        ("seed", seed, seed is None or (is_whole(seed) and seed >= 0), "None or an integer >= 0"),
        ("state", state, state == "auto" or state in STATE_SOURCES, f"'auto' or one of {STATE_SOURCES}"),
    )
    for name, value, ok, allowed in rules:
        if not ok:
            raise ValueError(f"{name} must be {allowed}, got {value!r}")


def _resolve_env(env: Any) -> ParallelEnv:
    """The ParallelEnv that ``env`` is or that the zero-argument factory ``env`` returns."""
    factory = callable(env) and not isinstance(env, (ParallelEnv, AECEnv))
    made = env() if factory else env
    if isinstance(made, ParallelEnv):
        return made
    if factory:
        given = f"the factory {env!r:.100}, which returned {type(made).__name__}"
    else:
        given = (
            f"the AEC env {type(env).__name__}" if isinstance(env, AECEnv) else f"{type(env).__name__}: {env!r:.100}"
        )
    raise TypeError(
        f"env must be a PettingZoo ParallelEnv or a zero-argument callable returning one, got {given}; "
        "convert an AEC env with pettingzoo.utils.conversions.aec_to_parallel(env)"
    )


def _check_spaces(env: ParallelEnv) -> None:
    """Discrete actions and equal spaces for all agents: one set of weights acts for every row."""
    agents = list(getattr(env, "possible_agents", None) or [])
    if not agents:
        raise ValueError(f"the env {type(env).__name__} has no agents (possible_agents is empty or missing)")
    for agent in agents:
        space = env.action_space(agent)
        if not isinstance(space, spaces.Discrete):
            raise ValueError(
                f"COMA and the other multi-agent learners need Discrete actions per agent, got {space} for agent {agent!r}"
            )
    first = agents[0]
    for kind, pad in (("observation", "pad_observations_v0"), ("action", "pad_action_space_v0")):
        space_of = env.observation_space if kind == "observation" else env.action_space
        for agent in agents[1:]:
            if space_of(agent) != space_of(first):
                raise ValueError(
                    f"agents {first!r} and {agent!r} have different {kind} spaces ({space_of(first)} vs {space_of(agent)}); "
                    f"parameter sharing needs equal spaces: wrap the env with supersuit.{pad}"
                )


def _state_source(env: ParallelEnv, state: str, seed: int | None) -> tuple[str, spaces.Box | None]:
    """Pick where the global state comes from (see :func:`make_marl_vec_env`); probes ``env.state()``."""
    obs_space = env.observation_space(env.possible_agents[0])
    in_obs = isinstance(obs_space, spaces.Dict) and "state" in obs_space.spaces
    if state == "obs" and not in_obs:
        raise ValueError(f"state='obs' needs a Dict observation space with a 'state' key, got {obs_space}")
    if state == "concat" or (state == "auto" and in_obs) or state == "obs":
        return ("obs" if state != "concat" else "concat"), None
    state_space = getattr(env, "state_space", None)
    why = _why_no_state(env, state_space, seed)
    if why is None:
        return "env", cast("spaces.Box", state_space)
    if state == "env":
        raise ValueError(f"state='env' needs a working PettingZoo state(): the env {type(env).__name__} {why}")
    return "concat", None


def _why_no_state(env: ParallelEnv, state_space: Any, seed: int | None) -> str | None:
    """Why ``env.state()`` cannot serve as the global state, or None when it can."""
    if not isinstance(state_space, spaces.Box):
        return f"has no gymnasium Box state_space (got {state_space!r})"
    env.reset(seed=seed)
    try:
        probe = np.asarray(env.state())
    except NotImplementedError:
        return "does not implement state()"
    if probe.shape != state_space.shape:
        raise ValueError(
            f"the env {type(env).__name__}'s state() has shape {probe.shape} but its state_space is {state_space}"
        )
    return None


# ---------------------------------------------------------------------- builder
def make_marl_vec_env(
    env: ParallelEnv | Callable[[], ParallelEnv], n_envs: int = 1, state: str = "auto", seed: int | None = None
) -> VecEnv:
    """Build an SB3 vec env of ``n_envs`` copies of a PettingZoo ParallelEnv, one row per agent.

    ``state`` says where learners find the global state: ``"obs"`` (a ``"state"`` key of a Dict
    observation), ``"env"`` (PettingZoo's ``state()``, read with ``get_state()``), ``"concat"``
    (none: the learner concatenates the agents' observations) or ``"auto"`` (the first of those
    that works). ``seed`` seeds copy ``e`` with ``seed + e`` at the first reset; with None a random
    base seed is drawn, because the copies are clones of one env and would otherwise share its
    random generator (and play identical episodes).
    """
    _check_options(n_envs, state, seed)
    par_env = _resolve_env(env)
    _check_spaces(par_env)
    state_source, state_space = _state_source(par_env, state, seed)
    if not hasattr(par_env.unwrapped, "render_mode"):
        setattr(par_env.unwrapped, "render_mode", None)  # noqa: B010 (SuperSuit reads it; mypy does not know it)
    markov = supersuit.pettingzoo_env_to_vec_env_v1(_InfoChannel(par_env, with_state=state_source == "env"))
    concat = supersuit.concat_vec_envs_v1(markov, int(n_envs), num_cpus=0, base_class="gymnasium")
    copies = [vec_env.par_env.env for vec_env in concat.vec_envs]
    venv = MarlVecEnv(concat, copies, state_source, state_space)
    venv.seed(None if seed is None else int(seed))
    return VecMonitor(venv)
