"""COMA (Foerster et al. 2018) as a Stable-Baselines3 on-policy algorithm.

One vec env row per agent, ``N`` agents per env copy (agent ``a`` of copy ``e`` at row
``e * N + a``). Each rollout is regrouped into joint steps ``(T, E, N)``; the centralised critic
learns ``Q(s, u_-i, .)`` from TD(lambda) targets of a target critic; the shared actor follows
``-log pi(u_i | o_i) * A_i`` with COMA's counterfactual advantage over valid actions.

Time is counted in **joint steps**: ``num_timesteps`` grows by one per env copy per step (not
per agent), so ``learn(total_timesteps)`` means joint steps. The paper trains 1200 missions of
15 steps: ``total_timesteps=18_000``. ``n_steps`` is per env copy, ``batch_size`` in joint steps.

Choices the paper leaves open, as implemented here:

* Rollouts end mid-mission; the last TD(lambda) target is bootstrapped with the target critic's
  expected value under the current policy, ``sum_u pi(u|o_i) Q_target(s, (u_-i, u))``, where
  ``u_-i`` are drawn from the current policy (no exploration). Episode ends cut the return;
  a time-limit truncation (``TimeLimit.truncated``) adds ``gamma * V(terminal state)`` instead.
* Per rollout: ``n_critic_epochs`` passes of critic minibatch updates, then one pass of actor
  updates (on-policy, so no more). The advantages use the critic's Q as scored in its last
  epoch, just before each minibatch's own update, which saves a forward pass over the rollout.
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
from collections import deque
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
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
from sb3_coma.coma.policies import CBAMPolicy, CnnPolicy, COMAPolicy
from sb3_coma.coma.progress import JointStepProgressBar
from sb3_coma.coma.targets import counterfactual_advantage, td_lambda_targets
from sb3_coma.coma.validation import (
    ADVANTAGES,
    check_batch_fits_rollout,
    check_coma_arguments,
    check_device,
    check_observation,
    check_spaces,
    resolve_n_agents,
)
from sb3_coma.common.shipped import check_shipped_file
from uav_ipp import layout

SelfCOMA = TypeVar("SelfCOMA", bound="COMA")

#: Steps per env copy per rollout when ``n_steps`` is not given (256 joint steps with 8 copies).
DEFAULT_ROLLOUT_STEPS = 32

__all__ = ["ADVANTAGES", "COMA"]

#: Joint steps per forward pass when the target critic scores a whole rollout (bounds memory).
_SCORING_CHUNK = 1024


class COMA(OnPolicyAlgorithm):
    """Counterfactual multi-agent policy gradients with a shared actor and a centralised critic.

    :param policy: ``"CBAMPolicy"`` (paper), ``"CnnPolicy"`` (ablation) or a ``COMAPolicy`` subclass
    :param env: an SB3 ``VecEnv`` with one row per agent and an ``n_agents`` attribute
        (``uav_ipp.make_vec_env``); may be ``None`` only when loading for prediction
    :param learning_rate: actor learning rate (Adam), float or schedule; paper 1e-5
    :param critic_learning_rate: critic learning rate (Adam), float or schedule; paper 1e-4
    :param n_steps: steps per env copy per rollout; ``None``: 32, stretched when needed so that a
        rollout holds at least ``batch_size`` joint steps
    :param batch_size: minibatch size in joint steps (all agents of a step stay together); paper 512
    :param n_epochs: passes of actor minibatch updates over each rollout; paper 1
    :param clip_range: PPO-style clip of the probability ratio in the actor's surrogate, so several
        passes cannot move the policy far from the one that collected the rollout; ``None``: the
        plain policy gradient (paper)
    :param advantage: first term of the counterfactual advantage ``A_i = X - sum_u' pi(u'|o_i)
        Q(s, (u_-i, u'))``: ``"return"``, the TD(lambda) return of the joint action taken
        (measured to learn, docs/training.md), or ``"q"``, the critic's ``Q(s, u)`` (the paper)
    :param n_critic_epochs: passes of critic minibatch updates over each rollout
    :param gamma: discount factor
    :param td_lambda: TD(lambda) trace decay for the critic targets
    :param ent_coef: entropy bonus weight in the actor loss
    :param max_grad_norm: gradient-norm clip for actor and critic
    :param normalize_advantage: standardise advantages per actor minibatch
    :param target_update_interval: critic updates between target-critic synchronisations (a hard copy)
    :param exploration_initial_eps: initial weight of uniform-over-valid-actions exploration
    :param exploration_final_eps: final weight
    :param exploration_fraction: fraction of training over which epsilon anneals linearly
    :param stats_window_size: episodes averaged in the rollout/ logs
    :param tensorboard_log: TensorBoard log folder (``None``: no TensorBoard)
    :param policy_kwargs: extra arguments for the policy (extractor classes and kwargs, ...)
    :param verbose: 0 silent, 1 info, 2 debug
    :param seed: seed for torch, numpy, python and the env
    :param device: torch device
    :param _init_setup_model: build networks now (SB3's ``load`` passes ``False``)

    ``env_options`` (``None`` until a trainer sets it, saved with the model): the env the model
    was trained on, as ``{"map": ..., "fusion": ..., "fusion_kwargs": {...}, <IppConfig options>}``
    (``sb3_coma.training_options`` reads it from a model or a zip).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "CBAMPolicy": CBAMPolicy,
        "CnnPolicy": CnnPolicy,
        "COMAPolicy": COMAPolicy,
    }
    policy: COMAPolicy  # type: ignore[assignment]  # SB3 types it as ActorCriticPolicy
    rollout_buffer: JointRolloutBuffer  # type: ignore[assignment]
    #: The manifest entry of a shipped model, set by ``sb3_coma.load_pretrained`` (absent otherwise).
    pretrained_info: dict[str, Any]

    def __init__(
        self,
        policy: str | type[COMAPolicy],
        env: GymEnv | None,
        learning_rate: float | Schedule = 3e-4,
        critic_learning_rate: float | Schedule = 1e-3,
        n_steps: int | None = None,
        batch_size: int = 64,
        n_epochs: int = 4,
        clip_range: float | None = 0.2,
        advantage: str = "return",
        n_critic_epochs: int = 2,
        gamma: float = 0.99,
        td_lambda: float = 0.8,
        ent_coef: float = 0.01,
        max_grad_norm: float = 10.0,
        normalize_advantage: bool = True,
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
        if env is not None and n_steps is not None:
            assert n_agents is not None
            check_batch_fits_rollout(batch_size, n_steps, env.num_envs // n_agents)  # type: ignore[union-attr]

        super().__init__(
            policy_class,  # type: ignore[arg-type]  # SB3 types it as an ActorCriticPolicy class
            env,  # type: ignore[arg-type]  # None only when loading (SB3's load does the same)
            learning_rate=learning_rate,
            n_steps=n_steps or 1,  # resolved in _setup_model
            gamma=gamma,
            gae_lambda=td_lambda,
            ent_coef=ent_coef,
            vf_coef=1.0,
            max_grad_norm=max_grad_norm,
            use_sde=False,
            sde_sample_freq=-1,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
            supported_action_spaces=(spaces.Discrete,),
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
        self.target_update_interval = target_update_interval
        self.exploration_initial_eps = exploration_initial_eps
        self.exploration_final_eps = exploration_final_eps
        self.exploration_fraction = exploration_fraction
        self.exploration_rate = exploration_initial_eps
        self.kl_coef = kl_coef
        self.kl_fraction = kl_fraction
        self._init_run_state()
        if _init_setup_model:
            self._setup_model()

    # ------------------------------------------------------------ set-up
    @staticmethod
    def _agents_of(env: GymEnv | None) -> int | None:
        """UAVs per env copy (``None`` without an env), after checking the env's spaces."""
        if env is None:
            return None
        n_agents = resolve_n_agents(env)  # type: ignore[arg-type]
        check_spaces(env.observation_space, env.action_space)
        return n_agents

    def _init_run_state(self) -> None:
        """What a model holds besides its hyperparameters: KL reference, env options, counters."""
        #: A frozen copy of the actor that the KL term pulls toward (``set_reference_actor``);
        #: not saved: the pull decays to zero within the run that set it.
        self.reference_actor: th.nn.Module | None = None
        self.env_options: dict[str, Any] | None = None
        self._n_critic_updates = 0
        self._n_target_updates = 0

    @classmethod
    def _resolve_policy(cls, policy: str | type[COMAPolicy]) -> type[COMAPolicy]:
        """Map an alias to its class here (SB3's base refuses "CnnPolicy" on Dict spaces)."""
        if isinstance(policy, str):
            if policy not in cls.policy_aliases:
                raise ValueError(f"unknown policy alias {policy!r}; COMA knows {sorted(cls.policy_aliases)}")
            return cls.policy_aliases[policy]  # type: ignore[return-value]
        if not (isinstance(policy, type) and issubclass(policy, COMAPolicy)):
            raise TypeError(f"policy must be an alias or a COMAPolicy subclass, got {policy!r}")
        return policy

    def _setup_model(self) -> None:
        """Build schedules, buffer and policy from attributes alone (``load`` relies on that)."""
        self._setup_lr_schedule()
        self.critic_lr_schedule = FloatSchedule(self.critic_learning_rate)
        self.exploration_schedule = LinearSchedule(
            self.exploration_initial_eps, self.exploration_final_eps, self.exploration_fraction
        )
        if self.env is not None:
            check_spaces(self.observation_space, self.action_space)
            self.n_agents = resolve_n_agents(self.env)
            self.n_envs = self.env.num_envs
        if self.n_agents is None:
            raise ValueError("n_agents is unknown: pass an env built by uav_ipp.make_vec_env")
        self.n_copies = self.n_envs // self.n_agents
        # A rollout must hold at least one minibatch of joint steps. The constructor rejects an
        # explicit n_steps that is too short; a model loaded onto an env with fewer copies (e.g.
        # evaluation on 2 copies of a model trained on 8) stretches its rollouts instead.
        min_steps = math.ceil(self.batch_size / self.n_copies)
        requested = DEFAULT_ROLLOUT_STEPS if self.n_steps_requested is None else self.n_steps_requested
        self.n_steps = max(requested, min_steps)
        check_batch_fits_rollout(self.batch_size, self.n_steps, self.n_copies)
        self.set_random_seed(self.seed)

        self.rollout_buffer = JointRolloutBuffer(
            self.n_steps,
            self.n_copies,
            self.n_agents,
            self.observation_space,  # type: ignore[arg-type]
            device=self.device,
        )
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space,
            self.action_space,
            self.lr_schedule,
            critic_lr_schedule=self.critic_lr_schedule,
            **self.policy_kwargs,
        )
        self.policy = self.policy.to(self.device)
        self._ep_metrics: dict[str, deque] = {
            "f1": deque(maxlen=self._stats_window_size),
            "entropy": deque(maxlen=self._stats_window_size),
        }

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "reference_actor"]

    def set_reference_actor(self) -> None:
        """Freeze a copy of the current actor (e.g. after :func:`~sb3_coma.coma.imitation.clone_teacher`)
        as the policy that ``kl_coef`` pulls the fine-tuning toward, with a weight that falls linearly
        from ``kl_coef`` to 0 over the first ``kl_fraction`` of ``learn()``."""
        self.reference_actor = copy.deepcopy(self.policy.actor).requires_grad_(False).eval()

    def _kl_weight(self) -> float:
        """The KL term's weight now: ``kl_coef`` at the start of ``learn()``, 0 after ``kl_fraction``."""
        if self.reference_actor is None or self.kl_coef == 0.0:
            return 0.0
        elapsed = 1.0 - self._current_progress_remaining
        return self.kl_coef * max(0.0, 1.0 - elapsed / self.kl_fraction)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        """The policy holds actor, critic and target critic; both optimizers are saved too."""
        return ["policy", "policy.optimizer", "policy.critic_optimizer"], []

    # ----------------------------------------------------------- helpers
    @property
    def _agents(self) -> int:
        """``n_agents``, known once the model is set up."""
        if self.n_agents is None:
            raise ValueError("n_agents is unknown: pass an env built by uav_ipp.make_vec_env")
        return self.n_agents

    def _obs_tensors(
        self, obs: dict[str, np.ndarray], grouped: bool
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor | None]:
        """``local``, ``state``, ``mask`` and the actor's prior (``action_gain``, or ``None``) as
        tensors; ``grouped`` reshapes rows to ``(E, N, ...)``."""
        out: list[th.Tensor | None] = []
        for key in (layout.KEY_LOCAL, layout.KEY_STATE, layout.KEY_MASK, layout.KEY_GAIN):
            if key not in obs:
                out.append(None)
                continue
            x = th.as_tensor(obs[key], device=self.device).float()
            if grouped:
                x = x.view(-1, self._agents, *x.shape[1:])
            out.append(x)
        return out[0], out[1], out[2], out[3]  # type: ignore[return-value]

    @th.no_grad()
    def _expected_target_values(self, obs: dict[str, np.ndarray]) -> th.Tensor:
        """``V_i(s) = sum_u pi(u|o_i) Q_target(s, (u_-i, u))`` per agent of every copy in ``obs``.

        The other agents' actions ``u_-i`` are drawn from the current policy (no exploration),
        so this is the on-policy value of the state the rollout stopped in.
        """
        local, state, mask, prior = self._obs_tensors(obs, grouped=True)
        flat_local, flat_mask = local.flatten(0, 1), mask.flatten(0, 1)
        probs = self.policy.action_probs(flat_local, flat_mask, prior=None if prior is None else prior.flatten(0, 1))
        actions = th.multinomial(probs, 1).view(local.shape[:2])
        q = self.policy.q_values(local, state, actions, target=True)
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
        terminal = {
            key: np.stack([infos[r]["terminal_observation"][key] for r in rows])
            for key in (layout.KEY_LOCAL, layout.KEY_STATE, layout.KEY_MASK, layout.KEY_GAIN)
            if key in infos[rows[0]]["terminal_observation"]
        }
        values = self._expected_target_values(terminal).flatten().cpu().numpy()
        for row, value in zip(rows, values):
            if row in truncated:
                rewards[row] += self.gamma * value
        return rewards

    def _update_info_buffer(self, infos: list[dict[str, Any]], dones: np.ndarray | None = None) -> None:
        """Record each mission once (from its first agent's row), with its final F1 and entropy."""
        assert self.ep_info_buffer is not None
        for row in range(0, len(infos), self.n_agents or 1):
            info = infos[row]
            episode = info.get("episode")
            if episode is not None:
                self.ep_info_buffer.append(episode)
            if dones is not None and dones[row]:
                for key in ("f1", "entropy"):
                    if key in info:
                        self._ep_metrics[key].append(float(info[key]))

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
        while buffer.pos < n_rollout_steps:
            progress = 1.0 - float(self.num_timesteps) / float(max(self._total_timesteps, 1))
            self.exploration_rate = self.exploration_schedule(progress)
            with th.no_grad():
                local, _, mask, prior = self._obs_tensors(self._last_obs, grouped=False)  # type: ignore[arg-type]
                actions = self.policy.act(local, mask, epsilon=self.exploration_rate, prior=prior).cpu().numpy()

            new_obs, rewards, dones, infos = env.step(actions)  # type: ignore[assignment]
            self.num_timesteps += self.n_copies  # joint steps, not agent steps

            callback.update_locals(locals())
            if not callback.on_step():
                return False
            self._update_info_buffer(infos, dones)
            rewards = self._bootstrap_truncations(rewards, dones, infos)
            buffer.add(self._last_obs, actions, rewards, dones)  # type: ignore[arg-type]
            self._last_obs = new_obs  # type: ignore[assignment]
            self._last_episode_starts = dones

        buffer.set_bootstrap(self._expected_target_values(new_obs).cpu().numpy())  # type: ignore[arg-type]
        callback.update_locals(locals())
        callback.on_rollout_end()
        return True

    # ---------------------------------------------------------- training
    @th.no_grad()
    def _td_targets(self) -> th.Tensor:
        """TD(lambda) targets ``(T * E, N)`` from the target critic's Q at the taken joint actions."""
        data = self.rollout_buffer.time_major()
        T, E, N = data["actions"].shape
        flat = {k: data[k].flatten(0, 1) for k in ("local", "state", "actions")}
        q_taken = th.cat(
            [
                self.policy.q_values(flat["local"][idx], flat["state"][idx], flat["actions"][idx], target=True)
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

    def _critic_step(self, loss: th.Tensor) -> None:
        self._check_finite("critic", loss)
        opt = self.policy.critic_optimizer
        opt.zero_grad(set_to_none=True)
        loss.backward()
        th.nn.utils.clip_grad_norm_(self.policy.critic.parameters(), self.max_grad_norm)
        opt.step()
        self._n_critic_updates += 1
        if self._n_critic_updates % self.target_update_interval == 0:
            self.policy.sync_target()
            self._n_target_updates += 1

    @th.no_grad()
    def _advantages(
        self, data: dict[str, th.Tensor], q_all: th.Tensor, targets: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        """COMA's advantage ``(T * E, N)`` per agent and the log-probability of the taken action
        under the policy that collected the rollout.

        ``A_i = X - b_i`` with the counterfactual baseline ``b_i = sum_u' pi(u'|o_i) Q(s, (u_-i, u'))``
        over valid actions; ``X`` is the TD(lambda) return of the joint action taken
        (``advantage="return"``) or the critic's ``Q(s, u)`` (``"q"``, the paper).
        """
        local, mask, actions = data["local"], data["mask"], data["actions"]
        logits = self.policy.masked_logits(local.flatten(0, 1), mask.flatten(0, 1), data["prior"].flatten(0, 1))
        log_probs = th.log_softmax(logits, dim=-1).view(*actions.shape, -1)
        q_advantage, baseline, _ = counterfactual_advantage(q_all, actions, log_probs.exp())
        advantage = targets - baseline if self.advantage == "return" else q_advantage
        return advantage, log_probs.gather(-1, actions.unsqueeze(-1)).squeeze(-1)

    def _actor_loss(
        self, data: dict[str, th.Tensor], idx: th.Tensor, advantage: th.Tensor, old_log_prob: th.Tensor
    ) -> tuple[th.Tensor, float, float]:
        """Clipped surrogate (or plain policy gradient) minus the entropy bonus on one minibatch
        of joint steps; returns (loss, mean entropy, fraction of clipped ratios)."""
        b_actions = data["actions"][idx].flatten()
        logits = self.policy.masked_logits(
            data["local"][idx].flatten(0, 1), data["mask"][idx].flatten(0, 1), data["prior"][idx].flatten(0, 1)
        )
        log_probs = th.log_softmax(logits, dim=-1)
        advantage = advantage.flatten()
        if self.normalize_advantage and advantage.numel() > 1:
            advantage = (advantage - advantage.mean()) / (advantage.std() + 1e-8)
        ratio = th.exp(log_probs.gather(-1, b_actions.unsqueeze(-1)).squeeze(-1) - old_log_prob.flatten())
        surrogate = ratio * advantage
        clip_fraction = 0.0
        if self.clip_range is not None:
            low, high = 1.0 - self.clip_range, 1.0 + self.clip_range
            surrogate = th.min(surrogate, th.clamp(ratio, low, high) * advantage)
            clip_fraction = float(((ratio < low) | (ratio > high)).float().mean())
        entropy = -(log_probs.exp() * log_probs).sum(-1).mean()
        loss = -surrogate.mean() - self.ent_coef * entropy
        kl_weight = self._kl_weight()
        if kl_weight > 0.0:
            assert self.reference_actor is not None
            with th.no_grad():
                ref = th.log_softmax(
                    self.policy.masked_logits_of(
                        self.reference_actor,
                        data["local"][idx].flatten(0, 1),
                        data["mask"][idx].flatten(0, 1),
                        data["prior"][idx].flatten(0, 1),
                    ),
                    dim=-1,
                )
            loss = loss + kl_weight * (ref.exp() * (ref - log_probs)).sum(-1).mean()
        return loss, entropy.item(), clip_fraction

    def train(self) -> None:
        """Per rollout: the critic on TD(lambda) targets (``n_critic_epochs``), then the actor on
        COMA's counterfactual advantage (``n_epochs``, clipped surrogate).

        The advantages use the critic's Q from its last epoch (each minibatch as scored just
        before its own update), which saves a full extra forward pass over the rollout, and the
        policy as it was when the rollout was collected.
        """
        self.policy.set_training_mode(True)
        progress = self._current_progress_remaining
        update_learning_rate(self.policy.optimizer, self.lr_schedule(progress))
        update_learning_rate(self.policy.critic_optimizer, self.critic_lr_schedule(progress))

        targets = self._td_targets()
        data = self.rollout_buffer.joint_steps()
        local, state, _mask, actions = data["local"], data["state"], data["mask"], data["actions"]
        n_joint = actions.shape[0]
        q_all = th.zeros(*actions.shape, self.policy.n_actions, device=self.device)

        critic_losses = []
        for epoch in range(self.n_critic_epochs):
            for idx in self.rollout_buffer.minibatch_indices(n_joint, self.batch_size):
                q = self.policy.q_values(local[idx], state[idx], actions[idx])
                q_taken = q.gather(-1, actions[idx].unsqueeze(-1)).squeeze(-1)
                loss = F.mse_loss(q_taken, targets[idx])
                self._critic_step(loss)
                critic_losses.append(loss.item())
                if epoch == self.n_critic_epochs - 1:
                    q_all[idx] = q.detach()

        advantage, old_log_prob = self._advantages(data, q_all, targets)
        actor_losses, entropies, clipped = [], [], []
        for _ in range(self.n_epochs):
            for idx in self.rollout_buffer.minibatch_indices(n_joint, self.batch_size):
                loss, entropy, clip_fraction = self._actor_loss(data, idx, advantage[idx], old_log_prob[idx])
                self._check_finite("actor", loss)
                self.policy.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                th.nn.utils.clip_grad_norm_(self.policy.actor.parameters(), self.max_grad_norm)
                self.policy.optimizer.step()
                actor_losses.append(loss.item())
                entropies.append(entropy)
                clipped.append(clip_fraction)
        self._n_updates += 1

        self.logger.record("train/clip_fraction", float(np.mean(clipped)))
        q_taken_flat = q_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
        self.logger.record("train/critic_loss", float(np.mean(critic_losses)))
        self.logger.record("train/actor_loss", float(np.mean(actor_losses)))
        self.logger.record("train/q_mean", float(q_taken_flat.mean()))
        self.logger.record("train/advantage_mean", float(advantage.mean()))
        self.logger.record("train/advantage_std", float(advantage.std()) if advantage.numel() > 1 else 0.0)
        self.logger.record(
            "train/explained_variance",
            float(explained_variance(q_taken_flat.flatten().cpu().numpy(), targets.flatten().cpu().numpy())),
        )
        self.logger.record("train/epsilon", self.exploration_rate)
        self.logger.record("train/kl_weight", self._kl_weight())
        self.logger.record("train/entropy", float(np.mean(entropies)))
        self.logger.record("train/target_updates", self._n_target_updates)
        weights = self.policy.actor.prior_weights
        if weights is not None:
            for name, w in zip(layout.GAIN_WEIGHTINGS, weights.tolist()):
                self.logger.record(f"train/gain_prior_{name}", w)
        self.logger.record("train/critic_updates", self._n_critic_updates)
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/learning_rate", self.lr_schedule(progress))
        self.logger.record("train/critic_learning_rate", self.critic_lr_schedule(progress))

    # ----------------------------------------------------------- logging
    def dump_logs(self, iteration: int = 0) -> None:
        """SB3's rollout/time logs plus the mission's final F1 and entropy."""
        if len(self._ep_metrics["f1"]) > 0:
            self.logger.record("rollout/ep_f1", safe_mean(self._ep_metrics["f1"]))
        if len(self._ep_metrics["entropy"]) > 0:
            self.logger.record("rollout/ep_entropy", safe_mean(self._ep_metrics["entropy"]))
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
        (:mod:`sb3_coma.common.shipped`): no path reaches a replaced shipped zip unchecked."""
        if isinstance(path, (str, os.PathLike)):
            check_shipped_file(path)
        return super().load(path, env, device, custom_objects, print_system_info, force_reset, **kwargs)

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict`` (one action per vec-env row, masked), after checking the observation:
        a missing ``action_mask`` or a NaN in the maps is an error naming the key."""
        check_observation(observation)
        return super().predict(observation, state, episode_start, deterministic)

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
        if (
            isinstance(total_timesteps, bool)
            or not isinstance(total_timesteps, (int, np.integer))
            or total_timesteps < 1
        ):
            raise ValueError(f"total_timesteps must be an integer >= 1 (joint steps), got {total_timesteps!r}")
        return super().learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
