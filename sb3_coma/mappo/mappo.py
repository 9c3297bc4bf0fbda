"""Learned baselines a user would pick instead of COMA: IPPO and MAPPO on SB3's own ``PPO``.

Both fly the same vec env as COMA (``uav_ipp.make_vec_env``: agent ``a`` of env copy ``e`` is row
``e * n_agents + a``), so every UAV is one slot of PPO's rollout and one set of weights acts for
all of them (parameter sharing). The actor reads the UAV's decentralised observation only: the 8
``local`` channels (the fused map included) and ``action_mask``; it never reads ``state`` (the
global map, critic only). With ``features_extractor_kwargs=dict(gain_inputs=True)`` it also reads
``action_gain`` (each move's on-board gain) through the same kind of learned encoder as COMA's
``gain_inputs`` actor, so the two learners can be compared on the same inputs.

* **IPPO** (:func:`make_ippo`, :class:`IPPOPolicy`): actor and value function share one small CNN
  trunk over ``local``; ``V(o_i)`` is decentralised too.
* **MAPPO** (:func:`make_mappo`, :class:`MAPPOPolicy`): the same actor; the value function has its
  own trunk over ``local`` + ``state`` (11 channels, docs/design.md §3; the 12th channel of COMA's
  critic, the other UAVs' actions, is a Q-function input that a state-value function has no use
  for), i.e. SB3's ``share_features_extractor=False`` with a critic extractor that reads
  ``state`` and an actor extractor that does not.

Masking: invalid actions get the logit :data:`sb3_coma.common.masking.MASKED_LOGIT` before SB3's
categorical distribution is built (:class:`MaskedActorCriticPolicy` overrides ``forward``,
``evaluate_actions`` and ``get_distribution``), so they have probability exactly 0 in rollouts,
in PPO's ratio and entropy terms and in ``predict`` (argmax or sampled).

Counting: SB3 counts agent-steps, one per vec-env row per step, so ``total_timesteps`` of
``learn`` is ``missions * n_agents * budget`` (:func:`timesteps_for_missions`, :func:`missions_of`).
Models save and load with ``PPO.save`` / ``PPO.load``; every class here is importable by its dotted
path (``sb3_coma.mappo.mappo.IPPOPolicy`` ...), which is what the saved zip names.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import PPO
from stable_baselines3.common.distributions import CategoricalDistribution, Distribution
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from sb3_coma.common.extractors import GAIN_ENCODER_DIM, CBAMExtractor, CnnExtractor
from sb3_coma.common.logger import use_folderless_logger
from sb3_coma.common.masking import mask_logits
from sb3_coma.mappo.central_value import CentralStateVecEnv, CentralValuePolicy
from uav_ipp import layout

#: What the actor reads (besides the mask): the decentralised observation.
ACTOR_KEYS: tuple[str, ...] = (layout.KEY_LOCAL,)
#: What MAPPO's centralised value function reads: ``local`` (8) + ``state`` (3).
CRITIC_KEYS: tuple[str, ...] = (layout.KEY_LOCAL, layout.KEY_STATE)
#: The trunks a :class:`MapsExtractor` can use (``sb3_coma.common.extractors``).
TRUNKS: dict[str, type[BaseFeaturesExtractor]] = {"cnn": CnnExtractor, "cbam": CBAMExtractor}
#: PPO settings that differ from SB3's defaults (issue #18's measurement): rollouts of 64 steps per
#: vec-env row (64 * n_agents * n_envs agent-steps), minibatches of 256 agent-steps, a small
#: entropy bonus. Everything else is SB3's PPO default (lr 3e-4, 10 epochs, clip 0.2, GAE 0.95 ...).
DEFAULT_PPO_KWARGS: dict[str, Any] = {"n_steps": 64, "batch_size": 256, "ent_coef": 0.01}


class MapsExtractor(BaseFeaturesExtractor):
    """Stack the named 11 x 11 map entries of the ``Dict`` observation and run a CNN trunk on them.

    :param observation_space: the per-agent ``Dict`` observation space
    :param keys: which entries to read, in channel order (default: ``local`` only, the actor's view);
        every other entry (``state``, ``action_gain``, ``action_mask``) is ignored
    :param features_dim: width of the trunk's last layer
    :param trunk: ``"cnn"`` (:class:`~sb3_coma.common.extractors.CnnExtractor`, default) or ``"cbam"``
        (:class:`~sb3_coma.common.extractors.CBAMExtractor`, the paper's attention trunk)
    :param gain_inputs: also read ``action_gain`` through a learned encoder (``GAIN_ENCODER_DIM``
        features, as COMA's ``gain_inputs`` actor) joined to the trunk's features; ``features_dim``
        is then the trunk's width plus the encoder's
    :param trunk_kwargs: further arguments of the trunk (``channels``, and for CBAM ``residual`` ...)
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        keys: Sequence[str] = ACTOR_KEYS,
        features_dim: int = 256,
        trunk: str = "cnn",
        gain_inputs: bool = False,
        **trunk_kwargs: Any,
    ) -> None:
        keys = tuple(keys) if not isinstance(keys, str) else (keys,)
        entries = observation_space.spaces if isinstance(observation_space, spaces.Dict) else {}
        missing = [k for k in keys if k not in entries]
        boxes = [b for b in (entries.get(k) for k in keys) if isinstance(b, spaces.Box) and len(b.shape) == 3]
        # One rule for the input: at least one key, each a (C, H, W) Box of the Dict, all of one size.
        if missing or len(boxes) != len(keys) or len({b.shape[1:] for b in boxes}) != 1:
            raise ValueError(
                f"MapsExtractor: keys {list(keys)} must name (C, H, W) Box entries of one size of a Dict "
                f"observation space (it has no {missing}), got {observation_space}"
            )
        if trunk not in TRUNKS:
            raise ValueError(f"MapsExtractor: trunk={trunk!r}; choose one of {sorted(TRUNKS)}")
        gain_space = observation_space.spaces.get(layout.KEY_GAIN)
        if gain_inputs and gain_space is None:
            raise ValueError(
                f"MapsExtractor: gain_inputs=True needs observation[{layout.KEY_GAIN!r}]: make the env with action_gain=True"
            )
        super().__init__(observation_space, features_dim + (GAIN_ENCODER_DIM if gain_inputs else 0))
        self.keys = keys
        channels = sum(b.shape[0] for b in boxes)
        stacked = spaces.Box(0.0, 1.0, (channels, *boxes[0].shape[1:]), dtype=np.float32)
        self.trunk = TRUNKS[trunk](stacked, features_dim=features_dim, **trunk_kwargs)
        self.gain_encoder: nn.Sequential | None = None
        if gain_inputs:
            assert gain_space is not None and gain_space.shape is not None
            self.gain_encoder = nn.Sequential(nn.Linear(int(np.prod(gain_space.shape)), GAIN_ENCODER_DIM), nn.ReLU())

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        x = observations[self.keys[0]] if len(self.keys) == 1 else th.cat([observations[k] for k in self.keys], dim=1)
        features = self.trunk(x)
        if self.gain_encoder is None:
            return features
        return th.cat([features, self.gain_encoder(observations[layout.KEY_GAIN].flatten(1))], dim=1)


class MaskedActorCriticPolicy(ActorCriticPolicy):
    """SB3's ``ActorCriticPolicy`` whose categorical distribution honours ``obs["action_mask"]``.

    Defaults for the IPP observation: a :class:`MapsExtractor` over ``local``, no MLP between the
    trunk and the two linear heads (``net_arch=[]``, as SB3's ``CnnPolicy`` does after NatureCNN).

    :param vf_features_extractor_kwargs: with ``share_features_extractor=False``, the value
        function's own extractor's arguments (default: the actor's); its ``features_dim`` must
        equal the actor's (SB3's ``MlpExtractor`` takes one input width)
    :param mask_key: the observation entry holding the 0/1 validity of each action
    Every other argument is ``ActorCriticPolicy``'s.
    """

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        features_extractor_class: type[BaseFeaturesExtractor] = MapsExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        share_features_extractor: bool = True,
        normalize_images: bool = False,
        vf_features_extractor_kwargs: dict[str, Any] | None = None,
        mask_key: str = layout.KEY_MASK,
        **kwargs: Any,
    ) -> None:
        mask = observation_space.spaces.get(mask_key) if isinstance(observation_space, spaces.Dict) else None
        n_actions = action_space.n if isinstance(action_space, spaces.Discrete) else None
        if n_actions is None or mask is None or mask.shape != (n_actions,):
            raise ValueError(
                f"{type(self).__name__} needs a Discrete action space and a Dict observation whose {mask_key!r} "
                f"has one entry per action, got {action_space} and {observation_space}"
            )
        if vf_features_extractor_kwargs is not None and share_features_extractor:
            raise ValueError(
                "vf_features_extractor_kwargs needs share_features_extractor=False "
                "(a shared trunk cannot read other inputs for the value function)"
            )
        # Plain attributes, read by _build() during ActorCriticPolicy.__init__.
        self.mask_key = mask_key
        self.vf_features_extractor_kwargs = (
            None if vf_features_extractor_kwargs is None else dict(vf_features_extractor_kwargs)
        )
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=[] if net_arch is None else net_arch,
            activation_fn=activation_fn,
            features_extractor_class=features_extractor_class,
            features_extractor_kwargs=features_extractor_kwargs,
            share_features_extractor=share_features_extractor,
            normalize_images=normalize_images,
            **kwargs,
        )
        assert isinstance(self.action_dist, CategoricalDistribution)

    def _build(self, lr_schedule: Schedule) -> None:
        if not self.share_features_extractor and self.vf_features_extractor_kwargs is not None:
            vf = self.features_extractor_class(self.observation_space, **self.vf_features_extractor_kwargs)
            if vf.features_dim != self.features_dim:
                raise ValueError(
                    f"the value function's features_dim ({vf.features_dim}) must equal the actor's "
                    f"({self.features_dim})"
                )
            self.vf_features_extractor = vf
        super()._build(lr_schedule)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        data.update(
            share_features_extractor=self.share_features_extractor,
            normalize_images=self.normalize_images,
            vf_features_extractor_kwargs=self.vf_features_extractor_kwargs,
            mask_key=self.mask_key,
        )
        return data

    # ----------------------------------------------------------------- masking
    def masked_distribution(self, latent_pi: th.Tensor, obs: PyTorchObs) -> Distribution:
        """SB3's categorical distribution over the masked logits of ``action_net(latent_pi)``."""
        assert isinstance(obs, dict)
        logits = mask_logits(self.action_net(latent_pi), obs[self.mask_key].float())
        return self.action_dist.proba_distribution(action_logits=logits)

    def _latents(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor]:
        features = self.extract_features(obs)
        if self.share_features_extractor:
            return self.mlp_extractor(features)
        pi_features, vf_features = features
        return self.mlp_extractor.forward_actor(pi_features), self.mlp_extractor.forward_critic(vf_features)

    def forward(self, obs: PyTorchObs, deterministic: bool = False) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        latent_pi, latent_vf = self._latents(obs)
        values = self.value_net(latent_vf)
        distribution = self.masked_distribution(latent_pi, obs)
        actions = distribution.get_actions(deterministic=deterministic)
        log_prob = distribution.log_prob(actions)
        return actions.reshape((-1, *(self.action_space.shape or ()))), values, log_prob

    def evaluate_actions(self, obs: PyTorchObs, actions: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        latent_pi, latent_vf = self._latents(obs)
        distribution = self.masked_distribution(latent_pi, obs)
        return self.value_net(latent_vf), distribution.log_prob(actions), distribution.entropy()

    def get_distribution(self, obs: PyTorchObs) -> Distribution:
        features = super(ActorCriticPolicy, self).extract_features(obs, self.pi_features_extractor)
        return self.masked_distribution(self.mlp_extractor.forward_actor(features), obs)

    def action_probs(self, obs: PyTorchObs) -> th.Tensor:
        """``(B, A)`` action probabilities (0 for invalid actions) of a batch of tensor observations."""
        distribution = self.get_distribution(obs).distribution
        assert isinstance(distribution, th.distributions.Categorical)  # masked logits of a Discrete space
        return distribution.probs


class IPPOPolicy(MaskedActorCriticPolicy):
    """IPPO: one CNN trunk over ``local`` shared by the actor and the (decentralised) value function."""

    #: The observation entries a vec env must have for this policy (checked by ``make_ippo``).
    needs: tuple[str, ...] = (layout.KEY_LOCAL, layout.KEY_MASK)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_kwargs", {"keys": ACTOR_KEYS})
        super().__init__(*args, **kwargs)


class MAPPOPolicy(MaskedActorCriticPolicy):
    """MAPPO: the IPPO actor (trunk over ``local``) plus a value function with its own trunk over
    ``local`` + ``state`` (centralised)."""

    #: MAPPO's value function also reads the global state (checked by ``make_mappo``).
    needs: tuple[str, ...] = (layout.KEY_LOCAL, layout.KEY_MASK, layout.KEY_STATE)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        actor = dict(kwargs.get("features_extractor_kwargs") or {})
        actor.setdefault("keys", ACTOR_KEYS)
        kwargs["features_extractor_kwargs"] = actor
        kwargs.setdefault("share_features_extractor", False)
        if kwargs.get("vf_features_extractor_kwargs") is None:
            kwargs["vf_features_extractor_kwargs"] = {**actor, "keys": CRITIC_KEYS}
        super().__init__(*args, **kwargs)


# ---------------------------------------------------------------------------------------------
# factories and counting
# ---------------------------------------------------------------------------------------------
def _n_agents(venv: VecEnv) -> int:
    n = getattr(venv, "n_agents", None)
    if n is None:
        n = venv.get_attr("n_agents", indices=[0])[0]
    return int(n)


def _budget(venv: VecEnv) -> int:
    return int(venv.get_attr("config", indices=[0])[0].budget)


def timesteps_for_missions(missions: float, venv: VecEnv) -> int:
    """SB3 timesteps (agent-steps) of ``missions`` whole missions: ``missions * n_agents * budget``."""
    return round(float(missions) * _n_agents(venv) * _budget(venv))


def missions_of(timesteps: int, venv: VecEnv) -> float:
    """Missions flown in ``timesteps`` SB3 timesteps (agent-steps): ``timesteps / (n_agents * budget)``."""
    return float(timesteps) / (_n_agents(venv) * _budget(venv))


def _check_venv(venv: VecEnv, need: tuple[str, ...]) -> None:
    """The UAV world's fused layout: the entries ``need`` and ``local`` with a fusion's channels."""
    entries = getattr(venv.observation_space, "spaces", {})
    local = entries.get(layout.KEY_LOCAL)
    fused = local is not None and (local.shape or (0,))[0] in (
        layout.LOCAL_CHANNELS,
        layout.LOCAL_CHANNELS + layout.V3_LOCAL_EXTRA,
    )
    if not fused or any(k not in entries for k in need):
        raise ValueError(
            f"needs an uav_ipp.make_vec_env vec env with fusion 'mean' or 'sendfuse', not 'none' (observation "
            f"entries {list(need)}, {layout.LOCAL_CHANNELS} 'local' channels), got observation space "
            f"{venv.observation_space}"
        )


def _make(policy: type[IPPOPolicy] | type[MAPPOPolicy], venv: VecEnv, ppo_kwargs: dict[str, Any]) -> PPO:
    _check_venv(venv, policy.needs)
    kwargs = {**DEFAULT_PPO_KWARGS, "device": "cpu", **ppo_kwargs}
    kwargs.pop("policy", None)
    return use_folderless_logger(PPO(policy, venv, **kwargs))


def _is_uav(venv: VecEnv) -> bool:
    """Whether ``venv`` has the UAV world's layout (else it is any multi-agent VecEnv)."""
    return layout.KEY_LOCAL in getattr(venv.observation_space, "spaces", {})


def make_ippo(venv: VecEnv, **ppo_kwargs: Any) -> PPO:
    """IPPO on ``venv``: SB3 ``PPO`` with parameter sharing over the agent rows.

    On the UAV world (an ``uav_ipp.make_vec_env`` vec env) the policy is :class:`IPPOPolicy`,
    :data:`DEFAULT_PPO_KWARGS` and ``device="cpu"`` unless given; ``policy_kwargs`` reach
    :class:`MaskedActorCriticPolicy`, e.g.
    ``policy_kwargs=dict(features_extractor_kwargs=dict(trunk="cbam", residual=True))``. On any other
    multi-agent vec env (``sb3_coma.make_marl_vec_env``) it is SB3's own ``PPO(policy, venv,
    **ppo_kwargs)``, ``policy`` defaulting to ``"MlpPolicy"``: the route SB3 users take.
    """
    if not _is_uav(venv):
        kwargs = dict(ppo_kwargs)
        return use_folderless_logger(PPO(kwargs.pop("policy", "MlpPolicy"), venv, **kwargs))
    return _make(IPPOPolicy, venv, ppo_kwargs)


def make_mappo(venv: VecEnv, **ppo_kwargs: Any) -> PPO:
    """MAPPO on ``venv``: SB3 ``PPO`` with the IPPO actor and a centralised value function.

    On the UAV world, :class:`MAPPOPolicy` (value function over ``local`` + ``state``); on any other
    multi-agent vec env, :class:`~sb3_coma.mappo.central_value.CentralValuePolicy` over
    :class:`~sb3_coma.mappo.central_value.CentralStateVecEnv` (value function over the global
    state COMA's critic reads + the agent's one-hot id). Arguments as :func:`make_ippo`.
    """
    if not _is_uav(venv):
        return use_folderless_logger(PPO(CentralValuePolicy, CentralStateVecEnv(venv), **ppo_kwargs))
    return _make(MAPPOPolicy, venv, ppo_kwargs)
