"""COMA (Foerster et al. 2018) as a Stable-Baselines3 on-policy algorithm.

A general algorithm for cooperative, parameter-sharing multi-agent envs with ``Discrete(n)``
actions. What it reads of an env (the multi-agent VecEnv contract, docs/design.md): one vec env
row per agent, ``N`` agents per env copy (agent ``a`` of copy ``e`` at row ``e * N + a``), an
``n_agents`` attribute, one global state per joint step (a ``state`` observation key, else the
env's ``get_state()``, else the concatenation of the agents' observations) and optional masks (an
``action_mask`` observation key, or sb3-contrib's ``action_masks()``). ``make_marl_vec_env``
builds such a VecEnv from any PettingZoo ``ParallelEnv``.

Each rollout is regrouped into joint steps ``(T, E, N)``; the centralised critic learns
``Q(s, u_-i, .)`` from TD(lambda) targets of a target critic; the shared actor follows
``-log pi(u_i | o_i) * A_i`` with COMA's counterfactual advantage over valid actions.

Time is counted in **joint steps**: ``num_timesteps`` grows by one per env copy per step (not
per agent), so ``learn(total_timesteps)`` means joint steps. ``n_steps`` is per env copy,
``batch_size`` in joint steps.

Choices the paper leaves open, as implemented here:

* Rollouts end mid-mission; the last TD(lambda) target is bootstrapped with the target critic's
  expected value under the current policy, ``sum_u pi(u|o_i) Q_target(s, (u_-i, u))``, where
  ``u_-i`` are drawn from the current policy (no exploration). Episode ends cut the return;
  a time-limit truncation (``TimeLimit.truncated``) adds ``gamma * V(terminal state)`` instead
  (``bootstrap_time_limits=False``: a time limit ends the return like any episode end).
* Per rollout: ``n_critic_epochs`` passes of critic minibatch updates, then ``n_epochs`` passes
  of actor updates. The advantages use the critic's Q as scored in its last epoch, just before
  each minibatch's own update, which saves a forward pass over the rollout
  (``advantage_before_critic_update=True``: as scored before the critic's first update).
* An epoch's last minibatch holds the remainder when the rollout is not a multiple of it.
* Exploration mixes the policy with the uniform distribution over *valid* actions; the actor
  loss uses the policy's own log-probabilities.
"""

from __future__ import annotations

import copy
import io
import math
import os
import pathlib
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.running_mean_std import RunningMeanStd
from stable_baselines3.common.save_util import load_from_zip_file
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule
from stable_baselines3.common.utils import (
    FloatSchedule,
    LinearSchedule,
    explained_variance,
    safe_mean,
    update_learning_rate,
)
from stable_baselines3.common.vec_env import VecEnv
from torch.nn import functional as F

from sb3_coma.coma.buffer import JointRolloutBuffer
from sb3_coma.coma.clock import EpisodeClock, append_time_left, with_time_left
from sb3_coma.coma.plugins import resolve_policy, saved_policy_class
from sb3_coma.coma.policies import CnnPolicy, COMAPolicy, MlpPolicy, MultiInputPolicy
from sb3_coma.coma.progress import JointStepProgressBar
from sb3_coma.coma.targets import counterfactual_advantage, td_lambda_targets
from sb3_coma.coma.validation import (
    POPART,
    check_batch_fits_rollout,
    check_coma_arguments,
    check_device,
    check_finite_weights,
    check_masks,
    check_observation,
    check_spaces,
    check_total_timesteps,
)
from sb3_coma.common.joint import (
    KEY_MASK,
    KEY_STATE,
    concat_state,
    map_obs,
    resolve_n_agents,
    resolve_state_source,
    state_space_of,
)
from sb3_coma.common.logger import folderless_logger
from sb3_coma.common.numbers import is_real, plain_arguments
from sb3_coma.common.shipped import check_shipped_file

SelfCOMA = TypeVar("SelfCOMA", bound="COMA")

#: Steps per env copy per rollout when ``n_steps`` is not given (256 joint steps with 8 copies).
DEFAULT_ROLLOUT_STEPS = 32

#: Format of the models this version saves (see ``coma_format``).
COMA_FORMAT = 2

#: Joint steps per forward pass when the target critic scores a whole rollout (bounds memory).
_SCORING_CHUNK = 1024


def actor_frozen_then(schedule: Schedule, fraction: float) -> Schedule:
    """The actor's learning rate: 0 over the first ``fraction`` of ``learn()``, then ``schedule``."""

    def rate(progress_remaining: float) -> float:
        return 0.0 if progress_remaining > 1.0 - fraction else float(schedule(progress_remaining))

    return rate


class COMA(OnPolicyAlgorithm):
    """Counterfactual multi-agent policy gradients with a shared actor and a centralised critic.

    :param policy: ``"MlpPolicy"``, ``"CnnPolicy"``, ``"MultiInputPolicy"`` (any env), an alias
        registered by a plug-in (``"CBAMPolicy"``, ``"UavCnnPolicy"``: the UAV world's) or a
        ``COMAPolicy`` subclass
    :param env: an SB3 ``VecEnv`` with one row per agent and an ``n_agents`` attribute
        (``sb3_coma.make_marl_vec_env``, ``uav_ipp.make_vec_env``); may be ``None`` only when
        loading for prediction
    :param learning_rate: actor learning rate (Adam), float or schedule
    :param critic_learning_rate: critic learning rate (Adam), float or schedule
    :param n_steps: steps per env copy per rollout; ``None``: 32, stretched when needed so that a
        rollout holds at least ``batch_size`` joint steps
    :param batch_size: minibatch size in joint steps (all agents of a step stay together)
    :param n_epochs: passes of actor minibatch updates over each rollout
    :param clip_range: PPO-style clip of the probability ratio in the actor's surrogate, so several
        passes cannot move the policy far from the one that collected the rollout, float or schedule
        of the remaining progress (as PPO's); ``None``: the plain policy gradient (the paper)
    :param advantage: first term of the counterfactual advantage ``A_i = X - sum_u' pi(u'|o_i)
        Q(s, (u_-i, u'))``: ``"return"``, the TD(lambda) return of the joint action taken
        (measured to learn, docs/training.md), ``"q"``, the critic's ``Q(s, u)`` (the paper), or
        ``"gae"``, the lambda-return bootstrapped with that same baseline at every step (GAE with
        the counterfactual baseline as the value), or ``"v_return"``, the lambda-return bootstrapped
        with a state value ``V_i(s)`` fitted beside the critic (the policy's ``value_net``): MAPPO's
        return, so the critic's errors at the actions taken enter the advantage only through the
        baseline, which does not depend on the agent's own action (docs/training.md, round 11)
    :param n_critic_epochs: passes of critic minibatch updates over each rollout
    :param gamma: discount factor
    :param td_lambda: TD(lambda) trace decay for the critic targets
    :param ent_coef: entropy bonus weight in the actor loss
    :param max_grad_norm: gradient-norm clip for actor and critic
    :param normalize_advantage: standardise advantages per actor minibatch
    :param normalize_q: the critic learns ``Q`` in units of its targets' running mean and standard
        deviation (as MAPPO's value normalisation): its output layer works near 0 and 1 whatever
        the scale of the team's returns; ``False``: the critic outputs ``Q`` itself (the paper);
        ``"popart"``: the same, and whenever a rollout moves the statistics the critic's (and its
        target's) output layer is rescaled so that its outputs in units of return stay where they
        were (PopArt, van Hasselt et al. 2016): early in training, when the targets' scale grows
        several-fold, the critic is otherwise read at a scale it was not fitted at
    :param advantage_before_critic_update: score the counterfactual baseline with the critic as it
        was when the rollout was collected (one extra forward pass), as PPO scores its advantages
        with the values of collection time; ``False``: with the critic after this rollout's
        ``n_critic_epochs`` (pymarl's order), which, when those epochs fit this rollout's own
        returns, pulls the baseline toward them and shrinks the advantage (docs/training.md)
    :param bootstrap_time_limits: where a time limit cut the episode, add ``gamma * V(terminal
        state)`` to the last reward, the return the episode would have had (Pardo et al. 2018);
        ``False``: the return stops there as at a true end (the MAPPO authors' code on MPE), so the
        critic's value of the last state, a guess about steps nobody flew, is not part of any
        advantage (docs/training.md, round 7)
    :param critic_time_feature: the episodes' time limit in steps: the critic (and ``V``) then
        reads the time left, ``1 - t / critic_time_feature`` (``t``: steps since the copy's episode
        began), as one more state feature, as sb3-contrib's ``TimeFeatureWrapper`` gives it to a
        single agent, but for the centralised critic only (the actors and the task stay as they
        are). With ``bootstrap_time_limits=False`` the critic learns the finite-horizon return the
        task scores (Pardo et al. 2018, "time awareness") instead of an infinite-horizon value
        carried in by the time-limit bootstrap; needs a flat state. ``None``: no clock
        (docs/training.md, round 20)
    :param target_update_interval: critic updates between target-critic synchronisations (a hard copy)
    :param exploration_initial_eps: initial weight of uniform-over-valid-actions exploration
    :param exploration_final_eps: final weight
    :param exploration_fraction: fraction of training over which epsilon anneals linearly
    :param kl_coef: weight of a KL pull toward a frozen reference actor (``set_reference_actor``)
    :param kl_fraction: fraction of ``learn()`` over which that weight falls to 0
    :param stats_window_size: episodes averaged in the rollout/ logs
    :param tensorboard_log: TensorBoard log folder (``None``: no TensorBoard)
    :param policy_kwargs: extra arguments for the policy (``net_arch``, extractor classes, ...)
    :param verbose: 0 silent, 1 info, 2 debug
    :param seed: seed for torch, numpy, python and the env
    :param device: torch device
    :param _init_setup_model: build networks now (SB3's ``load`` passes ``False``)

    ``reference_actor`` (``set_reference_actor``) and ``critic_warmup`` (``hold_actor``) are part
    of the training recipe and saved with the model (``reference_actor.pth``, a ``data`` field), so
    a model loaded to continue training pulls toward the same reference and holds the actor over
    the same fraction of the run as the one that was saved.

    ``env_options`` (``None`` until a trainer sets it, saved with the model): the env the model
    was trained on (the UAV world's trainer records its map and options there;
    ``sb3_coma.training_options`` reads it from a model or a zip). ``state_source`` (``"obs"``,
    ``"env"`` or ``"concat"``) and ``state_space`` are read from the env and saved with the model.
    Numeric keys of the episode infos that SB3's ``VecMonitor`` collects (``info_keywords``) are
    logged as ``rollout/ep_<key>``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "MlpPolicy": MlpPolicy,
        "CnnPolicy": CnnPolicy,
        "MultiInputPolicy": MultiInputPolicy,
    }
    policy: COMAPolicy  # type: ignore[assignment]  # SB3 types it as ActorCriticPolicy
    rollout_buffer: JointRolloutBuffer  # type: ignore[assignment]
    #: The manifest entry of a shipped model, set by ``sb3_coma.load_pretrained`` (absent otherwise).
    pretrained_info: dict[str, Any]

    #: What ``OnPolicyAlgorithm.__init__`` is always given: no value coefficient (the critic has its own
    #: optimizer), no gSDE, discrete actions only, and the model set up here, after COMA's own attributes.
    _SB3_FIXED: ClassVar[dict[str, Any]] = {
        "vf_coef": 1.0,
        "use_sde": False,
        "sde_sample_freq": -1,
        "supported_action_spaces": (spaces.Discrete,),
        "_init_setup_model": False,
    }

    @plain_arguments  # np.int64(8), np.float32(0.9): stored (and saved) as int and float
    def __init__(
        self,
        policy: str | type[COMAPolicy],
        env: GymEnv | None,
        learning_rate: float | Schedule = 3e-4,
        critic_learning_rate: float | Schedule = 1e-3,
        n_steps: int | None = None,
        batch_size: int = 64,
        n_epochs: int = 4,
        clip_range: float | Schedule | None = 0.2,
        advantage: str = "return",
        n_critic_epochs: int = 2,
        gamma: float = 0.99,
        td_lambda: float = 0.8,
        ent_coef: float = 0.01,
        max_grad_norm: float = 10.0,
        normalize_advantage: bool = True,
        normalize_q: bool | str = False,
        advantage_before_critic_update: bool = False,
        bootstrap_time_limits: bool = True,
        critic_time_feature: int | None = None,
        target_update_interval: int = 4,
        exploration_initial_eps: float = 0.0,
        exploration_final_eps: float = 0.0,
        exploration_fraction: float = 0.5,
        kl_coef: float = 0.0,
        kl_fraction: float = 0.5,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ) -> None:
        check_device(device)
        policy_class = self._resolve_policy(policy)
        n_agents = self._agents_of(env)
        check_coma_arguments(locals())
        check_batch_fits_rollout(batch_size, n_steps, env, n_agents)
        super().__init__(
            policy_class,  # type: ignore[arg-type]  # SB3 types it as an ActorCriticPolicy class
            env,  # type: ignore[arg-type]  # None only when loading (SB3's load does the same)
            learning_rate=learning_rate,
            n_steps=n_steps or 1,  # resolved in _setup_model
            gamma=gamma,
            gae_lambda=td_lambda,
            ent_coef=ent_coef,
            max_grad_norm=max_grad_norm,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            **self._SB3_FIXED,
        )
        self.n_agents = n_agents
        self.n_steps_requested = n_steps
        self.critic_learning_rate = critic_learning_rate
        self.batch_size = batch_size
        self.n_critic_epochs = n_critic_epochs
        self.n_epochs = n_epochs
        self.clip_range = clip_range
        self.advantage = advantage
        self.td_lambda = td_lambda
        self.normalize_advantage = normalize_advantage
        self.normalize_q: bool | str = normalize_q if normalize_q == POPART else bool(normalize_q)
        self.advantage_before_critic_update = bool(advantage_before_critic_update)
        self.bootstrap_time_limits = bool(bootstrap_time_limits)
        self.critic_time_feature = critic_time_feature
        self.target_update_interval = target_update_interval
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_fraction = exploration_fraction
        self.kl_coef = kl_coef
        self.kl_fraction = kl_fraction
        self._init_run_state()
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------ set-up
    @staticmethod
    def _agents_of(env: GymEnv | None) -> int | None:
        """Agents per env copy (``None`` without an env), after checking the env's spaces."""
        if env is None:
            return None
        n_agents = resolve_n_agents(env)  # type: ignore[arg-type]
        check_spaces(env.observation_space, env.action_space)
        return n_agents

    def _init_run_state(self) -> None:
        """What a model holds besides its hyperparameters: KL reference, env options, counters."""
        self.exploration_rate = self.exploration_initial_eps  # follows its schedule during learn()
        #: A frozen copy of the actor that the KL term pulls toward (``set_reference_actor``); saved
        #: as ``reference_actor.pth`` so that a resumed run keeps the pull (a model saved before it
        #: was saved loads without one).
        self.reference_actor: th.nn.Module | None = None
        #: Fraction of ``learn()`` in which the actor's learning rate is 0 (``hold_actor``); a plain
        #: attribute, so it is saved with the model and the schedule is rebuilt on load.
        self.critic_warmup = 0.0
        self.env_options: dict[str, Any] | None = None
        #: The saved-model format: 2 since COMA became generic (a 0.2 zip has none and names its
        #: UAV policy by the class's old home, :func:`~sb3_coma.coma.plugins.saved_policy_class`).
        self.coma_format = COMA_FORMAT
        self.state_source: str | None = None
        self.state_space: spaces.Space | None = None
        self._last_states: np.ndarray | None = None
        #: The critic's clock (``critic_time_feature``), rebuilt whenever ``learn()`` resets the env.
        self._clock: EpisodeClock | None = None
        self._n_critic_updates = 0
        self._n_target_updates = 0
        #: Running mean and variance of the critic's targets (``normalize_q``), saved with the model.
        self.q_scale = RunningMeanStd(shape=())

    @classmethod
    def _resolve_policy(cls, policy: str | type[COMAPolicy]) -> type[COMAPolicy]:
        """Map an alias to its class here (SB3's base refuses "CnnPolicy" on Dict spaces); aliases
        of plug-ins (the UAV world's ``CBAMPolicy``) load on first use (:mod:`sb3_coma.coma.plugins`)."""
        return resolve_policy(policy, cls.policy_aliases)  # type: ignore[return-value]

    def _resolve_state(self) -> None:
        """Where the global state comes from, and its space (kept from a saved model when loading
        without an env; a model saved before COMA was generic reads its ``state`` key)."""
        assert self.n_agents is not None
        if self.env is not None:
            self.state_source, self.state_space = resolve_state_source(self.env, self.n_agents)
        elif self.state_source is None:
            has_key = isinstance(self.observation_space, spaces.Dict) and KEY_STATE in self.observation_space.spaces
            self.state_source = "obs" if has_key else "concat"
            self.state_space = state_space_of(self.state_source, self.observation_space, self.n_agents)
        else:  # loaded without an env: the saved state space (with its clock, if any) stands
            return
        if self.critic_time_feature is not None:
            self.state_space = with_time_left(self.state_space)

    def _setup_model(self) -> None:
        """Build schedules, buffer and policy from attributes alone (``load`` relies on that)."""
        self._setup_lr_schedule()
        self.critic_lr_schedule = FloatSchedule(self.critic_learning_rate)
        self.clip_range_schedule = None if self.clip_range is None else FloatSchedule(self.clip_range)
        self.exploration_schedule = LinearSchedule(
            self.exploration_initial_eps, self.exploration_final_eps, self.exploration_fraction
        )
        if self.env is not None:  # its spaces were checked by the constructor or by SB3's load
            self.n_agents = resolve_n_agents(self.env)
            self.n_envs = self.env.num_envs
        self.n_copies = self.n_envs // self._agents
        self._resolve_state()
        value_kwargs = self._state_value_kwargs()
        # A rollout must hold at least one minibatch of joint steps. The constructor rejects an
        # explicit n_steps that is too short; a model loaded onto an env with fewer copies (e.g.
        # evaluation on 2 copies of a model trained on 8) stretches its rollouts instead, so the
        # minibatch fits by construction here.
        min_steps = math.ceil(self.batch_size / self.n_copies)
        requested = DEFAULT_ROLLOUT_STEPS if self.n_steps_requested is None else self.n_steps_requested
        self.n_steps = max(requested, min_steps)
        self.set_random_seed(self.seed)

        assert isinstance(self.action_space, spaces.Discrete) and self.state_space is not None
        self.rollout_buffer = JointRolloutBuffer(
            self.n_steps,
            self.n_copies,
            self._agents,
            self.observation_space,
            int(self.action_space.n),
            state_shape=self._stored_state_shape(),
            time_left=self.critic_time_feature is not None,
            device=self.device,
        )
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space,
            self.action_space,
            self.lr_schedule,
            critic_lr_schedule=self.critic_lr_schedule,
            n_agents=self.n_agents,
            state_space=self.state_space,
            **self.policy_kwargs,
            **value_kwargs,
        )
        self.policy = self.policy.to(self.device)

    def _stored_state_shape(self) -> tuple[int, ...] | None:
        """The env's state per copy that the buffer stores (state source ``"env"``; without the clock,
        which the buffer stores apart), else ``None``."""
        if self.state_source != "env":
            return None
        assert self.state_space is not None
        shape = tuple(self.state_space.shape or ())
        return (shape[0] - 1,) if self.critic_time_feature is not None else shape

    def _state_value_kwargs(self) -> dict[str, Any]:
        """``{"state_value": True}`` for the policy when the advantage bootstraps with ``V(s)``.

        :raises ValueError: a policy that cannot build one (the UAV world's image critic)
        """
        if self.advantage != "v_return":
            return {}
        if not getattr(self.policy_class, "supports_state_value", False):
            raise ValueError(
                f"advantage='v_return' needs a policy with a state value V(s) (MlpPolicy, CnnPolicy, "
                f"MultiInputPolicy); {self.policy_class.__name__} has none"
            )
        return {"state_value": True}

    def _setup_lr_schedule(self) -> None:
        """SB3's actor schedule, held at 0 over the first ``critic_warmup`` of ``learn()``: rebuilt
        from the saved fraction on load (the schedule itself is not restored by SB3's ``load``)."""
        super()._setup_lr_schedule()
        if self.critic_warmup > 0.0:
            self.lr_schedule = actor_frozen_then(self.lr_schedule, self.critic_warmup)

    def _excluded_save_params(self) -> list[str]:
        # the reference is a module: saved with the networks (_get_torch_save_params), not pickled
        return [*super()._excluded_save_params(), "reference_actor", "_clock"]

    def set_reference_actor(self) -> None:
        """Freeze a copy of the current actor (e.g. after :func:`~sb3_coma.uav.imitation.clone_teacher`)
        as the policy that ``kl_coef`` pulls the fine-tuning toward, with a weight that falls linearly
        from ``kl_coef`` to 0 over the first ``kl_fraction`` of ``learn()``. Saved with the model."""
        self.reference_actor = copy.deepcopy(self.policy.actor).requires_grad_(False).eval()

    def hold_actor(self, fraction: float) -> None:
        """Hold the actor (learning rate 0) over the first ``fraction`` of ``learn()`` while the
        critic learns, e.g. after a warm start: advantages from an untrained critic would undo the
        clone. Saved with the model, so a resumed run holds it over the same part of the run."""
        if not is_real(fraction) or not 0.0 <= fraction < 1.0:
            raise ValueError(f"critic_warmup={fraction!r}: a number in [0, 1)")
        self.critic_warmup = float(fraction)
        self._setup_lr_schedule()

    def set_parameters(
        self,
        load_path_or_dict: str | dict[str, Any],
        exact_match: bool = True,
        device: th.device | str = "auto",
    ) -> None:
        """SB3's ``set_parameters``; parameters that hold a KL reference actor (``reference_actor``)
        give this model one first (a frozen actor of the same shape), so ``load`` restores it."""
        params: dict[str, Any]
        if isinstance(load_path_or_dict, dict):
            params = load_path_or_dict
        else:
            _, loaded, _ = load_from_zip_file(load_path_or_dict, device=device, load_data=False)
            params = dict(loaded or {})
        if "reference_actor" in params and self.reference_actor is None:
            self.set_reference_actor()  # its weights are the saved ones once loaded below
        super().set_parameters(params, exact_match=exact_match, device=device)  # type: ignore[arg-type]

    def _kl_weight(self) -> float:
        """The KL term's weight now: ``kl_coef`` at the start of ``learn()``, 0 after ``kl_fraction``."""
        if self.reference_actor is None or self.kl_coef == 0.0:
            return 0.0
        elapsed = 1.0 - self._current_progress_remaining
        return self.kl_coef * max(0.0, 1.0 - elapsed / self.kl_fraction)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        """The policy holds actor, critic and target critic; both optimizers are saved too, and the
        KL reference actor when there is one (a resumed run must pull toward the same policy)."""
        names = ["policy", "policy.optimizer", "policy.critic_optimizer"]
        return [*names, *(["reference_actor"] if self.reference_actor is not None else [])], []

    # ----------------------------------------------------------- helpers
    @property
    def _agents(self) -> int:
        """``n_agents``, known once the model is set up."""
        if self.n_agents is None:
            raise ValueError("n_agents is unknown: pass an env built by sb3_coma.make_marl_vec_env")
        return self.n_agents

    def _grouped(self, obs: Any) -> Any:
        """Vec-env rows ``(E * N, ...)`` (arrays or a dict of them) as tensors ``(E, N, ...)``."""
        return map_obs(
            lambda x: th.as_tensor(np.asarray(x), device=self.device).view(-1, self._agents, *np.shape(x)[1:]), obs
        )

    def _masks(self, obs: Any, env: VecEnv | None = None) -> np.ndarray | None:
        """Valid actions of every row, float ``(rows, n)``: the ``action_mask`` key of the observation,
        else sb3-contrib's ``action_masks()`` of ``env``, else ``None`` (all valid: nothing to mask,
        as SB3's PPO masks nothing; the same logits and draws as an all-ones mask, bit for bit)."""
        assert isinstance(self.action_space, spaces.Discrete)
        if isinstance(obs, dict) and KEY_MASK in obs:
            masks = np.asarray(obs[KEY_MASK], dtype=np.float32)
        elif env is not None and self._env_masks:
            masks = np.stack(env.env_method("action_masks")).astype(np.float32)
        else:
            return None
        check_masks(masks, int(self.action_space.n))
        return masks

    def _mask_tensor(self, masks: np.ndarray | None) -> th.Tensor | None:
        """:meth:`_masks` as a tensor on the model's device (``None`` stays ``None``)."""
        return None if masks is None else th.as_tensor(masks, device=self.device)

    def _joint_state(self, obs: Any, states: th.Tensor | None, time_left: th.Tensor | None = None) -> th.Tensor:
        """The critic's state per agent row, ``(B, N, ...)``, from joint observations ``(B, N, ...)``,
        (state source ``"env"``) the env's states ``(B, ...)`` and (``critic_time_feature``) each
        joint step's time left ``(B,)``."""
        n = self._agents
        if self.state_source == "obs":
            state = obs[KEY_STATE].float()
        elif self.state_source == "env":
            assert states is not None
            state = states.float()[:, None].expand(-1, n, *states.shape[1:])
        else:
            state = concat_state(obs, self.observation_space, self.policy.normalize_images)[:, None].expand(-1, n, -1)
        if self.critic_time_feature is None:
            return state
        assert time_left is not None, "critic_time_feature: the time left of every joint step is needed"
        return append_time_left(state, time_left)

    def _time_left(self, elapsed: np.ndarray | None = None) -> th.Tensor | None:
        """The clock's time left per copy now (or after ``elapsed`` steps), ``None`` without one."""
        if self._clock is None:
            return None
        return th.as_tensor(self._clock.time_left(elapsed), device=self.device)

    def _current_states(self) -> np.ndarray | None:
        """The env's global state of every copy now (state source ``"env"`` only)."""
        if self.state_source != "env" or self.env is None:
            return None
        return np.asarray(self.env.get_state(), dtype=np.float32)  # type: ignore[attr-defined]

    def _setup_learn(self, *args: Any, **kwargs: Any) -> Any:
        """SB3's set-up, then the env's state and mask conventions for the rollouts.

        Without TensorBoard and a logger of the caller's, SB3 logs to stdout but first makes an
        empty ``SB3-<timestamp>`` folder in the system temp dir at every ``learn()``; the same
        logger is built here without a folder."""
        own_logger = not self._custom_logger and self.tensorboard_log is None
        if own_logger:
            self._logger = folderless_logger(self.verbose)
            self._custom_logger = True
        observed = self._last_obs
        try:
            out = super()._setup_learn(*args, **kwargs)
        finally:
            if own_logger:
                self._custom_logger = False
        self._env_masks = self.env is not None and self.env.has_attr("action_masks")
        self._last_states = self._current_states()
        restarted = self._last_obs is not observed  # SB3 reset the env: every episode begins now
        if self.critic_time_feature is not None and (restarted or self._clock is None):
            self._clock = EpisodeClock(self.n_copies, self.critic_time_feature)
        return out

    @th.no_grad()
    def _expected_target_values(
        self, obs: Any, masks: np.ndarray | None, states: np.ndarray | None, time_left: th.Tensor | None = None
    ) -> th.Tensor:
        """``V_i(s) = sum_u pi(u|o_i) Q_target(s, (u_-i, u))`` per agent of every copy in ``obs``.

        The other agents' actions ``u_-i`` are drawn from the current policy (no exploration),
        so this is the on-policy value of the state the rollout stopped in. With
        ``advantage="v_return"`` it is the fitted state value ``V_i(s)`` itself, so that its
        returns bootstrap with ``V`` wherever they bootstrap, as MAPPO's.
        """
        joint = self._grouped(obs)
        state = self._joint_state(
            joint, None if states is None else th.as_tensor(states, device=self.device), time_left
        )
        if self.policy.value_net is not None:
            return self._q_units(self.policy.state_values(joint, state))
        rows = map_obs(lambda x: x.flatten(0, 1), joint)
        probs = self.policy.action_probs(rows, self._mask_tensor(masks))
        actions = th.multinomial(probs, 1).view(-1, self._agents)
        q = self._q_units(self.policy.q_values(joint, state, actions, target=True))
        return (probs.view(q.shape) * q).sum(-1)

    def _bootstrap_truncations(self, rewards: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]) -> np.ndarray:
        """Add ``gamma * V(terminal state)`` where an episode was cut by a time limit, not ended."""
        truncated = [
            i
            for i, done in enumerate(dones)
            if done and infos[i].get("TimeLimit.truncated", False) and infos[i].get("terminal_observation") is not None
        ]
        if not truncated:
            return rewards
        rewards = np.array(rewards, dtype=np.float32, copy=True)
        n = self._agents
        copies = sorted({i // n for i in truncated})
        rows = [c * n + a for c in copies for a in range(n)]
        first = infos[rows[0]]["terminal_observation"]
        if isinstance(first, dict):
            terminal: Any = {key: np.stack([infos[r]["terminal_observation"][key] for r in rows]) for key in first}
        else:
            terminal = np.stack([infos[r]["terminal_observation"] for r in rows])
        states = None
        if self.state_source == "env":
            states = np.stack([infos[c * n]["terminal_state"] for c in copies])
        time_left = None  # the terminal state is one step past the clock's count (advanced after this)
        if self._clock is not None:
            time_left = self._time_left(self._clock.elapsed[copies] + 1)
        masks = self._masks(terminal)
        values = self._expected_target_values(terminal, masks, states, time_left).flatten().cpu().numpy()
        for row, value in zip(rows, values):
            if row in truncated:
                rewards[row] += self.gamma * value
        return rewards

    def _update_info_buffer(self, infos: list[dict[str, Any]], dones: np.ndarray | None = None) -> None:
        """Record each episode once (from its copy's first agent row, not once per agent)."""
        assert self.ep_info_buffer is not None
        for row in range(0, len(infos), self.n_agents or 1):
            episode = infos[row].get("episode")
            if episode is not None:
                self.ep_info_buffer.append(episode)

    # ---------------------------------------------------------- rollouts
    def collect_rollouts(
        self,
        env: VecEnv,
        callback: BaseCallback,
        rollout_buffer: RolloutBuffer,  # type: ignore[override]
        n_rollout_steps: int,
    ) -> bool:
        """Act with all agents of all copies in one forward pass per step; store joint steps."""
        assert self._last_obs is not None, "No previous observation was provided"
        buffer: JointRolloutBuffer = rollout_buffer  # type: ignore[assignment]
        self.policy.set_training_mode(False)
        buffer.reset()
        callback.on_rollout_start()

        new_obs = self._last_obs
        masks = self._masks(self._last_obs, env)
        while buffer.pos < n_rollout_steps:
            progress = 1.0 - float(self.num_timesteps) / float(max(self._total_timesteps, 1))
            self.exploration_rate = self.exploration_schedule(progress)
            with th.no_grad():
                obs_tensor = map_obs(lambda x: th.as_tensor(x, device=self.device), self._last_obs)
                mask_tensor = self._mask_tensor(masks)
                actions = self.policy.act(obs_tensor, mask_tensor, epsilon=self.exploration_rate).cpu().numpy()

            new_obs, rewards, dones, infos = env.step(actions)  # type: ignore[assignment]
            self.num_timesteps += self.n_copies  # joint steps, not agent steps

            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            if self.bootstrap_time_limits:
                rewards = self._bootstrap_truncations(rewards, dones, infos)
            time_left = None if self._clock is None else self._clock.time_left()
            buffer.add(self._last_obs, masks, actions, rewards, dones, self._last_states, time_left)  # type: ignore[arg-type]
            if self._clock is not None:
                self._clock.advance(np.asarray(dones).reshape(self.n_copies, -1).any(axis=1))
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_states = self._current_states()
            self._last_episode_starts = dones
            masks = self._masks(new_obs, env)

        bootstrap = self._expected_target_values(new_obs, masks, self._last_states, self._time_left())
        buffer.set_bootstrap(bootstrap.cpu().numpy())
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    # ---------------------------------------------------------- training
    @staticmethod
    def _take(obs: Any, idx: th.Tensor) -> Any:
        """Joint steps ``idx`` of joint observations (a tensor or a dict of them)."""
        return map_obs(lambda x: x[idx], obs)

    @staticmethod
    def _rows(obs: Any) -> Any:
        """Joint observations ``(B, N, ...)`` as agent rows ``(B * N, ...)``."""
        return map_obs(lambda x: x.flatten(0, 1), obs)

    def _q_units(self, q: th.Tensor) -> th.Tensor:
        """The critic's output in units of return: with ``normalize_q`` it learns ``Q`` (and ``V``)
        standardised by its targets' running mean and standard deviation, which this undoes."""
        if not self.normalize_q:
            return q
        mean, std = self._q_statistics()
        return q * std + mean

    def _standardised(self, returns: th.Tensor) -> th.Tensor:
        """``returns`` in the critic's units (standardised by the running statistics with ``normalize_q``)."""
        if not self.normalize_q:
            return returns
        return (returns - float(self.q_scale.mean)) / float(np.sqrt(self.q_scale.var + 1e-8))

    def _critic_targets(self, targets: th.Tensor) -> th.Tensor:
        """What the critic's output is fitted to: the targets, standardised with ``normalize_q``
        (after the running statistics took this rollout's targets in)."""
        if self.normalize_q:
            before = self._q_statistics()
            self.q_scale.update(targets.flatten().cpu().numpy().astype(np.float64))
            if self.normalize_q == POPART:
                self.policy.preserve_critic_outputs(*before, *self._q_statistics())
        return self._standardised(targets)

    def _q_statistics(self) -> tuple[float, float]:
        """The mean and standard deviation that :meth:`_q_units` reads the critic's output with."""
        return float(self.q_scale.mean), float(np.sqrt(self.q_scale.var + 1e-8))

    def _q(self, data: dict[str, Any], idx: th.Tensor, target: bool = False) -> th.Tensor:
        """The critic's output ``(b, N, n)`` for ``Q(s, u_-i, .)`` on joint steps ``idx`` of the
        rollout (standardised with ``normalize_q``: :meth:`_q_units` gives ``Q``)."""
        obs = self._take(data["obs"], idx)
        return self.policy.q_values(obs, self._critic_state(data, obs, idx), data["actions"][idx], target=target)

    def _v(self, data: dict[str, Any], idx: th.Tensor) -> th.Tensor:
        """The state value ``V_i(s)`` ``(b, N)`` on joint steps ``idx`` (critic's units)."""
        obs = self._take(data["obs"], idx)
        return self.policy.state_values(obs, self._critic_state(data, obs, idx))

    def _critic_state(self, data: dict[str, Any], obs: Any, idx: th.Tensor) -> th.Tensor:
        """The critic's state on joint steps ``idx`` of the rollout (``obs``: theirs, already taken)."""
        states = None if data["states"] is None else data["states"][idx]
        time_left = None if data["time_left"] is None else data["time_left"][idx]
        return self._joint_state(obs, states, time_left)

    @th.no_grad()
    def _state_value_returns(self) -> tuple[th.Tensor, th.Tensor] | None:
        """``advantage="v_return"``: the state values of collection time and the TD(lambda) returns
        bootstrapped with them, each ``(T * E, N)`` in units of return (``None`` otherwise).

        Read before this rollout's targets move the running statistics, in the units ``V`` was
        trained in; the rollout's last row bootstraps with ``V`` too (:meth:`_expected_target_values`)."""
        if self.advantage != "v_return":
            return None
        data = self.rollout_buffer.time_major()
        T, E, N = data["actions"].shape
        flat = self.rollout_buffer.joint_steps()
        values = th.cat([self._q_units(self._v(flat, idx)) for idx in th.arange(T * E).split(_SCORING_CHUNK)]).view(
            T, E, N
        )
        next_values = th.cat([values[1:], data["bootstrap"][None]], dim=0)
        returns = td_lambda_targets(data["rewards"], data["dones"], next_values, self.gamma, self.td_lambda)
        return values.flatten(0, 1), returns.flatten(0, 1)

    @th.no_grad()
    def _td_targets(self) -> th.Tensor:
        """TD(lambda) targets ``(T * E, N)`` from the target critic's Q at the taken joint actions."""
        data = self.rollout_buffer.time_major()
        T, E, N = data["actions"].shape
        flat = self.rollout_buffer.joint_steps()
        q_taken = th.cat(
            [
                self._q_units(self._q(flat, idx, target=True))
                .gather(-1, flat["actions"][idx].unsqueeze(-1))
                .squeeze(-1)
                for idx in th.arange(T * E).split(_SCORING_CHUNK)
            ]
        ).view(T, E, N)
        next_values = th.cat([q_taken[1:], data["bootstrap"][None]], dim=0)
        targets = td_lambda_targets(data["rewards"], data["dones"], next_values, self.gamma, self.td_lambda)
        return targets.flatten(0, 1)

    def _check_finite(self, name: str, loss: th.Tensor) -> None:
        """Stop before a non-finite loss reaches the weights: a NaN would silently spread to
        every parameter and the run would then save a broken model."""
        if not th.isfinite(loss).all():
            raise FloatingPointError(
                f"{name} loss is {loss.item()} at update {self._n_updates} (num_timesteps={self.num_timesteps}); "
                "training stopped before the weights were changed. Lower the learning rates or check the inputs."
            )

    def _critic_step(self, loss: th.Tensor, parameters: list[th.nn.Parameter]) -> None:
        """One critic update; ``parameters`` are the critic's, listed once per ``train()`` (listing
        walks every module: a visible cost at 10+ small updates per rollout)."""
        self._check_finite("critic", loss)
        opt = self.policy.critic_optimizer
        opt.zero_grad(set_to_none=True)
        loss.backward()
        th.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)
        opt.step()
        self._n_critic_updates += 1
        if self._n_critic_updates % self.target_update_interval == 0:
            self.policy.sync_target()
            self._n_target_updates += 1

    @th.no_grad()
    def _advantages(self, data: dict[str, Any], q_all: th.Tensor, returns: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """COMA's advantage ``(T * E, N)`` per agent and the log-probability of the taken action
        under the policy that collected the rollout.

        ``A_i = X - b_i`` with the counterfactual baseline ``b_i = sum_u' pi(u'|o_i) Q(s, (u_-i, u'))``
        over valid actions; ``X`` is ``returns``, the TD(lambda) return of the joint action taken
        (``advantage="return"``; bootstrapped with ``V_i(s)`` for ``"v_return"``), or the critic's
        ``Q(s, u)`` (``"q"``, the paper).
        """
        mask, actions = data["mask"], data["actions"]
        logits = self.policy.masked_logits(self._rows(data["obs"]), None if mask is None else mask.flatten(0, 1))
        log_probs = th.log_softmax(logits, dim=-1).view(*actions.shape, -1)
        q_advantage, baseline, _ = counterfactual_advantage(q_all, actions, log_probs.exp())
        if self.advantage == "gae":
            advantage = self._gae_over_baseline(baseline)
        else:
            advantage = q_advantage if self.advantage == "q" else returns - baseline
        return advantage, log_probs.gather(-1, actions.unsqueeze(-1)).squeeze(-1)

    def _gae_over_baseline(self, baseline: th.Tensor) -> th.Tensor:
        """GAE(lambda) with the counterfactual baseline as the value (``advantage="gae"``):
        ``sum_k (gamma lambda)^k delta_t+k``, ``delta_t = r_t + gamma b_i(t+1) - b_i(t)``; each step's
        bootstrap is the baseline itself (an expectation over the agent's own next action), not the
        Q of the joint action taken next, as MAPPO's GAE bootstraps with ``V`` (docs/training.md)."""
        data = self.rollout_buffer.time_major()
        values = baseline.view(data["actions"].shape)
        next_values = th.cat([values[1:], data["bootstrap"][None]], dim=0)
        returns = td_lambda_targets(data["rewards"], data["dones"], next_values, self.gamma, self.td_lambda)
        return (returns - values).flatten(0, 1)

    def _actor_loss(
        self, data: dict[str, Any], idx: th.Tensor, advantage: th.Tensor, old_log_prob: th.Tensor
    ) -> tuple[th.Tensor, float, float]:
        """Clipped surrogate (or plain policy gradient) minus the entropy bonus on one minibatch
        of joint steps; returns (loss, mean entropy, fraction of clipped ratios)."""
        b_actions = data["actions"][idx].flatten()
        obs = self._rows(self._take(data["obs"], idx))
        mask = None if data["mask"] is None else data["mask"][idx].flatten(0, 1)
        logits = self.policy.masked_logits(obs, mask)
        log_probs = th.log_softmax(logits, dim=-1)
        advantage = advantage.flatten()
        if self.normalize_advantage and advantage.numel() > 1:
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        ratio = th.exp(log_probs.gather(-1, b_actions.unsqueeze(-1)).squeeze(-1) - old_log_prob.flatten())
        surrogate = ratio * advantage
        clip_fraction = 0.0
        clip_range = self._clip_range_now()
        if clip_range is not None:
            low, high = 1.0 - clip_range, 1.0 + clip_range
            surrogate = th.min(surrogate, th.clamp(ratio, low, high) * advantage)
            clip_fraction = float(((ratio < low) | (ratio > high)).float().mean())
        entropy = -(log_probs.exp() * log_probs).sum(-1).mean()
        loss = -surrogate.mean() - self.ent_coef * entropy
        kl_weight = self._kl_weight()
        if kl_weight > 0.0:
            assert self.reference_actor is not None
            with th.no_grad():
                ref = th.log_softmax(self.policy.masked_logits(obs, mask, actor=self.reference_actor), dim=-1)
            loss = loss + kl_weight * (ref.exp() * (ref - log_probs)).sum(-1).mean()
        return loss, entropy.item(), clip_fraction

    def _clip_range_now(self) -> float | None:
        """The clip of the probability ratio at this point of ``learn()`` (``None``: no clipping)."""
        if self.clip_range_schedule is None:
            return None
        return float(self.clip_range_schedule(self._current_progress_remaining))

    def train(self) -> None:
        """Per rollout: the critic on TD(lambda) targets (``n_critic_epochs``), then the actor on
        COMA's counterfactual advantage (``n_epochs``, clipped surrogate).

        The advantages use the critic's Q from its last epoch (each minibatch as scored just
        before its own update), which saves a full extra forward pass over the rollout, or with
        ``advantage_before_critic_update`` the critic before this rollout's updates; and the
        policy as it was when the rollout was collected.
        """
        self.policy.set_training_mode(True)
        progress = self._current_progress_remaining
        update_learning_rate(self.policy.optimizer, self.lr_schedule(progress))
        update_learning_rate(self.policy.critic_optimizer, self.critic_lr_schedule(progress))

        targets = self._td_targets()
        state_value = self._state_value_returns()
        data = self.rollout_buffer.joint_steps()
        actions = data["actions"]
        q_all = th.zeros(*actions.shape, self.policy.n_actions, device=self.device)
        if self.advantage_before_critic_update:  # in the units the critic was trained in (normalize_q):
            with th.no_grad():  # before this rollout's targets move the running statistics
                for idx in th.arange(actions.shape[0], device=self.device).split(_SCORING_CHUNK):
                    q_all[idx] = self._q_units(self._q(data, idx))
        fitted = self._critic_targets(targets)
        fitted_values = None if state_value is None else self._standardised(state_value[1])
        critic_losses = self._fit_critic(data, fitted, fitted_values, q_all)

        returns = targets if state_value is None else state_value[1]
        advantage, old_log_prob = self._advantages(data, q_all, returns)
        actor_losses, entropies, clipped = self._fit_actor(data, advantage, old_log_prob)
        self._n_updates += 1

        self.logger.record("train/clip_fraction", float(np.mean(clipped)))
        clip_range = self._clip_range_now()
        if clip_range is not None:
            self.logger.record("train/clip_range", clip_range)
        q_taken_flat = q_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
        self.logger.record("train/critic_loss", float(np.mean(critic_losses)))  # standardised with normalize_q
        if self.normalize_q:
            self.logger.record("train/q_target_std", float(np.sqrt(self.q_scale.var)))
        self.logger.record("train/actor_loss", float(np.mean(actor_losses)))
        self.logger.record("train/q_mean", float(q_taken_flat.mean()))
        self.logger.record("train/advantage_mean", float(advantage.mean()))
        self.logger.record("train/advantage_std", float(advantage.std()) if advantage.numel() > 1 else 0.0)
        self.logger.record(
            "train/explained_variance",
            float(explained_variance(q_taken_flat.flatten().cpu().numpy(), targets.flatten().cpu().numpy())),
        )
        if self.advantage != "gae":  # the advantage's first term X (return or Q) minus the baseline
            first = q_taken_flat if self.advantage == "q" else returns
            baseline = (first - advantage).flatten().cpu().numpy()
            self.logger.record(
                "train/baseline_explained_variance",
                float(explained_variance(baseline, first.flatten().cpu().numpy())),
            )
        if state_value is not None:
            values, value_returns = (x.flatten().cpu().numpy() for x in state_value)
            self.logger.record("train/value_explained_variance", float(explained_variance(values, value_returns)))
        self.logger.record("train/epsilon", self.exploration_rate)
        self.logger.record("train/kl_weight", self._kl_weight())
        self.logger.record("train/entropy", float(np.mean(entropies)))
        self.logger.record("train/target_updates", self._n_target_updates)
        for name, value in self.policy.log_values().items():
            self.logger.record(f"train/{name}", value)
        self.logger.record("train/critic_updates", self._n_critic_updates)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/learning_rate", self.lr_schedule(progress))
        self.logger.record("train/critic_learning_rate", self.critic_lr_schedule(progress))

    def _fit_critic(
        self, data: dict[str, Any], fitted: th.Tensor, fitted_values: th.Tensor | None, q_all: th.Tensor
    ) -> list[float]:
        """``n_critic_epochs`` of minibatch updates of Q on the taken joint actions (and of ``V``
        with ``advantage="v_return"``, on the same minibatches by the same optimizer); without
        ``advantage_before_critic_update``, the last epoch fills ``q_all``. Returns the losses."""
        actions = data["actions"]
        parameters = self.policy.critic_parameters()
        losses = []
        for epoch in range(self.n_critic_epochs):
            for idx in self.rollout_buffer.minibatch_indices(actions.shape[0], self.batch_size):
                q = self._q(data, idx)
                q_taken = q.gather(-1, actions[idx].unsqueeze(-1)).squeeze(-1)
                loss = F.mse_loss(q_taken, fitted[idx])
                if fitted_values is not None:
                    loss = loss + F.mse_loss(self._v(data, idx), fitted_values[idx])
                self._critic_step(loss, parameters)
                losses.append(loss.item())
                if epoch == self.n_critic_epochs - 1 and not self.advantage_before_critic_update:
                    q_all[idx] = self._q_units(q.detach())
        return losses

    def _fit_actor(
        self, data: dict[str, Any], advantage: th.Tensor, old_log_prob: th.Tensor
    ) -> tuple[list[float], list[float], list[float]]:
        """``n_epochs`` of actor minibatch updates; returns the losses, entropies and clip fractions."""
        parameters = list(self.policy.actor.parameters())
        losses, entropies, clipped = [], [], []
        for _ in range(self.n_epochs):
            for idx in self.rollout_buffer.minibatch_indices(advantage.shape[0], self.batch_size):
                loss, entropy, clip_fraction = self._actor_loss(data, idx, advantage[idx], old_log_prob[idx])
                self._check_finite("actor", loss)
                self.policy.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                th.nn.utils.clip_grad_norm_(parameters, self.max_grad_norm)
                self.policy.optimizer.step()
                losses.append(loss.item())
                entropies.append(entropy)
                clipped.append(clip_fraction)
        return losses, entropies, clipped

    # ----------------------------------------------------------- logging
    def dump_logs(self, iteration: int = 0) -> None:
        """SB3's rollout/time logs plus the mean of every other numeric key of the episode infos
        (``VecMonitor(info_keywords=...)``; the UAV world's final F1 and entropy)."""
        assert self.ep_info_buffer is not None
        extra = sorted({key for info in self.ep_info_buffer for key in info} - {"r", "l", "t"})
        for key in extra:
            values = [info[key] for info in self.ep_info_buffer if isinstance(info.get(key), (int, float, np.number))]
            if values:
                self.logger.record(f"rollout/ep_{key}", safe_mean(values))
        super().dump_logs(iteration)

    def _init_callback(self, callback: MaybeCallback, progress_bar: bool = False) -> BaseCallback:
        """SB3's callback set-up, with a progress bar that counts joint steps."""
        callback = super()._init_callback(callback, progress_bar=False)
        if progress_bar:
            callback = CallbackList([callback, JointStepProgressBar()])
            callback.init_callback(self)
        return callback

    @classmethod
    def load(
        cls: type[SelfCOMA],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfCOMA:
        """SB3's ``load``, after checking a shipped model's file against its recorded SHA-256
        (:mod:`sb3_coma.common.shipped`): no path reaches a replaced shipped zip unchecked. A model
        saved by sb3-coma 0.2 names its UAV policy by the class's old home; it loads as that class.
        ``n_steps=...`` among ``kwargs`` sets the rollout length as the constructor's does (the
        buffer is sized from the requested steps, so SB3's plain attribute update would be lost)."""
        if "n_steps" in kwargs:
            kwargs["n_steps_requested"] = kwargs.pop("n_steps")
        named = path if isinstance(path, (str, os.PathLike)) else getattr(path, "name", None)
        if isinstance(named, (str, os.PathLike)):  # a path, or a file object opened from one
            check_shipped_file(named)
        renamed = saved_policy_class(path)
        if renamed is not None and "policy_class" not in (custom_objects or {}):
            custom_objects = {**(custom_objects or {}), "policy_class": renamed}
        model = super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)
        check_finite_weights(model.policy, named if named is not None else "the model")
        return model

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
        action_masks: np.ndarray | None = None,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """One action per vec-env row. Masks: the observation's ``action_mask`` key, or
        ``action_masks`` (sb3-contrib's ``MaskablePPO.predict`` convention, ``(rows, n)``).
        The observation is checked first: a missing key or a NaN is an error naming the key."""
        check_observation(observation, self.observation_space)
        if action_masks is None:
            return super().predict(observation, state, episode_start, deterministic)
        self.policy.set_training_mode(False)
        obs_tensor, vectorized = self.policy.obs_to_tensor(observation)
        masks = np.atleast_2d(np.asarray(action_masks, dtype=np.float32))
        check_masks(masks, self.policy.n_actions)
        with th.no_grad():
            actions = self.policy.act(obs_tensor, th.as_tensor(masks, device=self.device), deterministic=deterministic)
        out = actions.cpu().numpy()
        return (out if vectorized else out.squeeze(0)), state

    def learn(
        self: SelfCOMA,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 1,
        tb_log_name: str = "COMA",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfCOMA:
        """Train for ``total_timesteps`` **joint** steps (one per env copy per step)."""
        total_timesteps = check_total_timesteps(total_timesteps)
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
