"""COMA's policies for any env: a shared masked actor, a centralised critic and its target.

Keeping critic, target critic and the critic's optimizer inside the policy (an ``nn.Module``)
means SB3's ``save``/``load`` store and restore all of them with no special casing: the policy's
``state_dict`` holds the three networks and ``policy.optimizer`` / ``policy.critic_optimizer``
are listed in :meth:`COMA._get_torch_save_params`.

Shapes: the actor works per agent row on ``(B, ...)``; the critic works on whole joint steps,
``(B, N, ...)`` with ``N`` agents, because agent ``i``'s input holds the other agents' actions.
The default critic is COMA's own (Foerster et al. 2018, as in pymarl's ``coma_critic``): the
global state, the agent's one-hot id, the other agents' one-hot actions and (``critic_obs``) the
agent's own observation -> ``Q(s, u_-i, .)`` for all of its ``n`` actions in one pass.
:meth:`COMAPolicy.critic_features` is the hook a world-specific policy overrides to build its
critic input another way (``sb3_coma.uav.CBAMPolicy`` draws the other UAVs' actions at their cells).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from functools import partial
from typing import Any, cast

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first, preprocess_obs
from stable_baselines3.common.torch_layers import (
    BaseFeaturesExtractor,
    CombinedExtractor,
    FlattenExtractor,
    NatureCNN,
    create_mlp,
)
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn
from torch.nn import functional as F

from sb3_coma.common.joint import KEY_MASK, actor_observation_space, actor_view, map_obs
from sb3_coma.common.masking import behaviour_probs, mask_logits, sample_actions
from sb3_coma.common.numbers import flag

_CRITIC_PREFIX = "critic."
_TARGET_PREFIX = "critic_target."

#: Hidden layers of the actor (``pi``, SB3's PPO default) and of the critic (``qf``, wider: it
#: reads the state and every agent's action).
DEFAULT_NET_ARCH: dict[str, list[int]] = {"pi": [64, 64], "qf": [128, 128]}


def _net_arch(net_arch: list[int] | dict[str, list[int]] | None) -> dict[str, list[int]]:
    """``None``: the default; a list: the same hidden layers for actor and critic; a dict ``pi`` / ``qf``."""
    if net_arch is None:
        return {key: list(value) for key, value in DEFAULT_NET_ARCH.items()}
    if isinstance(net_arch, dict):
        unknown = set(net_arch) - {"pi", "qf"}
        if unknown:
            raise ValueError(f"net_arch={net_arch!r}: keys must be 'pi' and/or 'qf', got {sorted(unknown)}")
        return {key: list(net_arch.get(key, DEFAULT_NET_ARCH[key])) for key in ("pi", "qf")}
    if isinstance(net_arch, list) and all(isinstance(n, int) and n > 0 for n in net_arch):
        return {"pi": list(net_arch), "qf": list(net_arch)}
    raise ValueError(f"net_arch={net_arch!r}: must be a list of layer sizes or a dict with 'pi' / 'qf' lists")


def optimizer_implementation(optimizer_class: type[th.optim.Optimizer], kwargs: dict[str, Any]) -> dict[str, Any]:
    """``kwargs`` with Adam's fused kernel when the caller chose no implementation (``fused`` /
    ``foreach``): COMA takes 10+ small updates per rollout of two networks, and on a CPU the default
    per-tensor Adam loop is the slower step (docs/design.md, "Speed"; the figure that counts is the
    ``learn()`` speed table of docs/marl_benchmark/results.md). Same algorithm; the float rounding
    differs from the loop's, so runs are reproducible per version."""
    chose = {"fused", "foreach"} & set(kwargs)
    if optimizer_class is th.optim.Adam and not chose:
        return {**kwargs, "fused": True}
    return dict(kwargs)


class ActorNet(nn.Module):
    """A features extractor, hidden layers and one logit per action."""

    def __init__(
        self,
        features_extractor: BaseFeaturesExtractor,
        hidden: list[int],
        activation_fn: type[nn.Module],
        n_actions: int,
    ) -> None:
        super().__init__()
        self.features_extractor = features_extractor
        self.mlp = nn.Sequential(*create_mlp(features_extractor.features_dim, -1, hidden, activation_fn))
        self.head = nn.Linear(hidden[-1] if hidden else features_extractor.features_dim, n_actions)

    def forward(self, obs: PyTorchObs) -> th.Tensor:
        return self.head(self.mlp(self.features_extractor(obs)))


class CriticNet(nn.Module):
    """COMA's critic: [state features, own observation features, one-hot id, others' one-hot
    actions] -> hidden layers -> ``Q`` of every action of the agent.

    ``dueling``: the head gives a value ``W(s, u_-i)`` and one deviation ``D(s, u_-i, u)`` per action,
    ``Q = W + D - mean_u D`` (Wang et al. 2016). A plain head fits only the taken action's output per
    sample, so the untaken actions' outputs, which COMA's baseline weighs by the policy, are what the
    shared layers leave them at; ``W``, which the baseline mostly reads, is fitted by every sample."""

    def __init__(
        self,
        state_extractor: BaseFeaturesExtractor,
        obs_extractor: BaseFeaturesExtractor | None,
        extra_dim: int,
        hidden: list[int],
        activation_fn: type[nn.Module],
        n_actions: int,
        dueling: bool = False,
    ) -> None:
        super().__init__()
        self.state_extractor = state_extractor
        self.obs_extractor = obs_extractor
        self.dueling = dueling
        width = state_extractor.features_dim + extra_dim + (obs_extractor.features_dim if obs_extractor else 0)
        self.mlp = nn.Sequential(*create_mlp(width, -1, hidden, activation_fn))
        self.head = nn.Linear(hidden[-1] if hidden else width, n_actions + int(dueling))

    def forward(self, state: th.Tensor, obs: PyTorchObs | None, extra: th.Tensor) -> th.Tensor:
        parts = [self.state_extractor(state), extra]
        if self.obs_extractor is not None:
            assert obs is not None
            parts.insert(1, self.obs_extractor(obs))
        out = self.head(self.mlp(th.cat(parts, dim=1)))
        return dueling_q(out) if self.dueling else out


def dueling_q(out: th.Tensor) -> th.Tensor:
    """``Q = W + D - mean_u D`` from a dueling head's outputs ``(B, 1 + n_actions)``: the value ``W`` first,
    then one deviation ``D`` per action. Centring makes ``W`` the mean of ``Q``, which is what COMA's
    baseline reads under a near-uniform policy, and lets PopArt rescale every output alike."""
    deviations = out[:, 1:]
    return out[:, :1] + deviations - deviations.mean(dim=1, keepdim=True)


def one_hot_others(actions: th.Tensor, n_actions: int) -> th.Tensor:
    """Row ``i`` of joint step ``b``: every other agent's one-hot action, agent ``i``'s own zeroed,
    ``(B, N, N * n)``: what makes ``Q(s, u_-i, .)`` a function of the others' actions only."""
    _batch, n_agents = actions.shape
    one_hot = F.one_hot(actions.long(), n_actions).float()  # (B, N_j, n)
    others = 1.0 - th.eye(n_agents, device=actions.device)  # [i, j] = j != i
    return (one_hot[:, None] * others[None, :, :, None]).flatten(2)


#: The smallest image side NatureCNN's convolutions (8 stride 4, 4 stride 2, 3) leave a pixel of.
_NATURE_CNN_MIN_SIDE = 36


def _check_extractor_fits(
    policy: str, extractor: type[BaseFeaturesExtractor], space: spaces.Space, kwargs: Mapping[str, Any]
) -> None:
    """SB3's one-input extractors on what the actor reads: ``NatureCNN`` (``CnnPolicy``) needs one
    image ``Box`` its three convolutions fit in, ``FlattenExtractor`` (``MlpPolicy``) anything but
    a ``Dict`` of several entries. One line naming the policy, the space and what reads it,
    instead of NatureCNN's bare ``AssertionError`` (or torch's size error) at construction or
    ``FlattenExtractor``'s ``AttributeError`` at the first step. Any other extractor is its own business.

    :raises ValueError: naming the policy and the space
    """
    if extractor not in (NatureCNN, FlattenExtractor):
        return
    image = extractor is NatureCNN and is_image_space(
        space, check_channels=False, normalized_image=bool(kwargs.get("normalized_image"))
    )  # NatureCNN's own test
    shape = tuple(space.shape or ())
    sides = shape[1:] if image and is_image_space_channels_first(space) else shape[:2]  # type: ignore[arg-type]
    if isinstance(space, spaces.Dict):
        problem = (
            f"reads one Box, but the actor's observation is a Dict of {sorted(space.spaces)} (besides 'state' / "
            "'action_mask'); use 'MultiInputPolicy' for a Dict observation (in the UAV world, uav_ipp: "
            "'UavCnnPolicy' or 'CBAMPolicy')"
        )
    elif extractor is NatureCNN and not image:
        problem = (
            f"reads an image Box (channels, height, width) of uint8 in [0, 255], but the actor's observation is "
            f"{space}; pass features_extractor_kwargs=dict(normalized_image=True) for float images, or use "
            "'MlpPolicy' for a vector"
        )
    elif extractor is NatureCNN and min(sides) < _NATURE_CNN_MIN_SIDE:
        problem = (
            f"needs images of at least {_NATURE_CNN_MIN_SIDE} x {_NATURE_CNN_MIN_SIDE} pixels, but the actor's "
            f"observation is {space}; use 'MlpPolicy', or a features_extractor_class for small images"
        )
    else:
        return
    raise ValueError(f"policy {policy!r} ({extractor.__name__}) {problem}")


class COMAPolicy(BasePolicy):
    """Shared actor ``pi(u | o_i)`` and centralised critic ``Q(s, u_-i, .)`` for ``Discrete(n)`` agents.

    :param observation_space: one agent's observation space (``state`` / ``action_mask`` keys of a
        ``Dict`` are not actor inputs)
    :param action_space: ``Discrete(n)``
    :param lr_schedule: actor learning-rate schedule (SB3 convention)
    :param critic_lr_schedule: critic learning-rate schedule; defaults to ``lr_schedule``
    :param n_agents: agents per joint step (the critic reads every agent's action)
    :param state_space: the global state's space (COMA passes it from the env's state source)
    :param net_arch: hidden layers, a list for both networks or ``{"pi": [...], "qf": [...]}``
    :param activation_fn: activation of the hidden layers
    :param features_extractor_class: the actor's features extractor (SB3's, or your own)
    :param features_extractor_kwargs: its keyword arguments
    :param critic_features_extractor_class: the critic's extractor of the state (default: the
        actor's class when the state is an image like the observation, else ``FlattenExtractor``)
    :param critic_features_extractor_kwargs: its keyword arguments
    :param critic_obs: the critic also reads the agent's own observation (pymarl's default)
    :param optimizer_class: optimizer of both networks
    :param optimizer_kwargs: its extra arguments, shared by both
    :param ortho_init: orthogonal initialisation as in SB3's A2C/PPO (0.01 on the actor's output,
        so the first policy is near-uniform over valid actions)
    :param normalize_images: divide image observations by 255 (SB3's convention)
    :param state_value: also build ``value_net``, a per-agent state value ``V_i(s)`` (the critic's
        input without the others' actions, one output) that COMA's ``advantage="v_return"``
        bootstraps its returns with; trained by the critic's optimizer. COMA sets it from its
        ``advantage``
    :param dueling_critic: the critic's head gives ``Q`` as a value of the others' actions plus
        centred per-action deviations (:class:`CriticNet`), so that the counterfactual baseline
        reads a value every sample fits (docs/training.md, round 36)
    """

    #: The shared actor, the critic and its target (world-specific policies build their own modules).
    actor: nn.Module
    critic: nn.Module
    critic_target: nn.Module
    #: ``V_i(s)`` (``state_value=True``), else ``None`` (an instance attribute: a class-level default
    #: would hide the registered module from ``nn.Module``'s attribute lookup).
    value_net: nn.Module | None
    #: Whether the policy can build ``value_net`` (a world-specific critic input has no generic ``V``).
    supports_state_value: bool = True

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        critic_lr_schedule: Schedule | None = None,
        n_agents: int = 1,
        state_space: spaces.Space | None = None,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        activation_fn: type[nn.Module] = nn.Tanh,
        features_extractor_class: type[BaseFeaturesExtractor] = FlattenExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        critic_features_extractor_class: type[BaseFeaturesExtractor] | None = None,
        critic_features_extractor_kwargs: dict[str, Any] | None = None,
        critic_obs: bool = True,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        ortho_init: bool = True,
        normalize_images: bool = True,
        state_value: bool = False,
        dueling_critic: bool = False,
    ) -> None:
        super().__init__(
            observation_space,
            action_space,
            features_extractor_class=features_extractor_class,
            features_extractor_kwargs=features_extractor_kwargs,
            normalize_images=normalize_images,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
        )
        self.n_agents = int(n_agents)
        self.state_space = state_space
        self.net_arch = _net_arch(net_arch)
        self.activation_fn = activation_fn
        self.critic_obs = flag("critic_obs", critic_obs)
        self.critic_features_extractor_class = critic_features_extractor_class
        self.critic_features_extractor_kwargs = dict(critic_features_extractor_kwargs or {})
        self.n_actions = int(action_space.n)
        self.ortho_init = ortho_init
        self.state_value = bool(state_value)
        self.dueling_critic = flag("dueling_critic", dueling_critic)
        #: What the actor reads (the observation without ``state`` / ``action_mask``).
        self.actor_space = actor_observation_space(observation_space)
        extractor = self.features_extractor_class
        _check_extractor_fits(type(self).__name__, extractor, self.actor_space, self.features_extractor_kwargs)
        self._build(lr_schedule, critic_lr_schedule or lr_schedule)

    # ------------------------------------------------------------ set-up
    def _state_extractor(self) -> BaseFeaturesExtractor:
        """The critic's extractor of the state (see ``critic_features_extractor_class``)."""
        if self.state_space is None:
            raise ValueError("COMAPolicy needs state_space (COMA passes it from the env's state source)")
        cls = self.critic_features_extractor_class
        kwargs = self.critic_features_extractor_kwargs
        if cls is None:
            same = all(
                is_image_space(space, check_channels=False, normalized_image=True)
                for space in (self.state_space, self.actor_space)
            )
            cls = self.features_extractor_class if same else FlattenExtractor
            kwargs = dict(self.features_extractor_kwargs) if same else {}
        return cls(self.state_space, **kwargs)

    def _build(self, lr_schedule: Schedule, critic_lr_schedule: Schedule) -> None:
        pi, qf = self.net_arch["pi"], self.net_arch["qf"]
        actor = ActorNet(
            self.features_extractor_class(self.actor_space, **self.features_extractor_kwargs),
            pi,
            self.activation_fn,
            self.n_actions,
        )
        obs_extractor = None
        if self.critic_obs:
            obs_extractor = self.features_extractor_class(self.actor_space, **self.features_extractor_kwargs)
        extra = self.n_agents + self.n_agents * self.n_actions
        critic = CriticNet(
            self._state_extractor(), obs_extractor, extra, qf, self.activation_fn, self.n_actions, self.dueling_critic
        )
        value_net = self._value_net() if self.state_value else None
        if self.ortho_init:
            for module in (actor, critic, value_net):
                if module is not None:
                    module.apply(partial(BasePolicy.init_weights, gain=math.sqrt(2)))
            nn.init.orthogonal_(actor.head.weight, gain=0.01)
            nn.init.orthogonal_(critic.head.weight, gain=1.0)
            if value_net is not None:
                nn.init.orthogonal_(value_net.head.weight, gain=1.0)
        self.actor, self.critic, self.value_net = actor, critic, value_net
        self._finish_build(lr_schedule, critic_lr_schedule)

    def _value_net(self) -> CriticNet:
        """``V_i(s)``: the critic's network with the agent's one-hot id in place of id and the
        others' actions, and one output (its own extractors: V and Q do not share weights)."""
        obs_extractor = None
        if self.critic_obs:
            obs_extractor = self.features_extractor_class(self.actor_space, **self.features_extractor_kwargs)
        return CriticNet(
            self._state_extractor(), obs_extractor, self.n_agents, self.net_arch["qf"], self.activation_fn, 1
        )

    def _finish_build(self, lr_schedule: Schedule, critic_lr_schedule: Schedule) -> None:
        """Target critic (a frozen copy) and the two optimizers."""
        if not hasattr(self, "value_net"):  # a world-specific _build builds none
            self.value_net = None
        self.critic_target = copy.deepcopy(self.critic)
        self.critic_target.requires_grad_(False)
        self.critic_target.train(False)
        kwargs = optimizer_implementation(self.optimizer_class, self.optimizer_kwargs)
        # SB3 types optimizer_class as Optimizer's own class, whose __init__ has no lr (SB3 ignores it too)
        self.optimizer = self.optimizer_class(  # type: ignore[call-arg]
            self.actor.parameters(), lr=lr_schedule(1), **kwargs
        )
        self.critic_optimizer = self.optimizer_class(  # type: ignore[call-arg]
            self.critic_parameters(), lr=critic_lr_schedule(1), **kwargs
        )

    def critic_parameters(self) -> list[nn.Parameter]:
        """What the critic's optimizer trains: the critic's parameters and ``value_net``'s, if any."""
        modules = [self.critic] if self.value_net is None else [self.critic, self.value_net]
        return [p for module in modules for p in module.parameters()]

    def _shared_constructor_parameters(self) -> dict[str, Any]:
        """What every COMA policy saves to be rebuilt (``load``); subclasses add their own options."""
        data = BasePolicy._get_constructor_parameters(self)
        data.update(
            lr_schedule=self._dummy_schedule,
            critic_lr_schedule=self._dummy_schedule,
            n_agents=self.n_agents,
            state_space=self.state_space,
            features_extractor_class=self.features_extractor_class,
            features_extractor_kwargs=self.features_extractor_kwargs,
            critic_features_extractor_class=self.critic_features_extractor_class,
            critic_features_extractor_kwargs=self.critic_features_extractor_kwargs,
            optimizer_class=self.optimizer_class,
            optimizer_kwargs=self.optimizer_kwargs,
            ortho_init=self.ortho_init,
        )
        return data

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {
            **self._shared_constructor_parameters(),
            "net_arch": self.net_arch,
            "activation_fn": self.activation_fn,
            "critic_obs": self.critic_obs,
            "state_value": self.state_value,
            "dueling_critic": self.dueling_critic,
        }

    def set_training_mode(self, mode: bool) -> None:
        """Train/eval mode for actor and critic; the target critic always stays in eval mode."""
        self.actor.train(mode)
        self.critic.train(mode)
        if self.value_net is not None:
            self.value_net.train(mode)
        self.training = mode

    def log_values(self) -> dict[str, float]:
        """Extra ``train/`` values a policy wants logged after each update (none here)."""
        return {}

    # ------------------------------------------------------------- actor
    def _actor_input(self, obs: PyTorchObs) -> PyTorchObs:
        """The actor's view of ``obs`` rows, preprocessed as SB3 does (floats, images / 255)."""
        return preprocess_obs(actor_view(obs, self.observation_space), self.actor_space, self.normalize_images)

    def masked_logits(self, obs: PyTorchObs, mask: th.Tensor | None, actor: nn.Module | None = None) -> th.Tensor:
        """Actor logits ``(B, n)`` of agent rows, invalid actions pushed to a large negative value.

        :param actor: another actor of the same shape (a frozen reference copy); default: this one
        """
        logits = (actor or self.actor)(self._actor_input(obs))
        return logits if mask is None else mask_logits(logits, mask)

    def action_probs(self, obs: PyTorchObs, mask: th.Tensor | None, epsilon: float = 0.0) -> th.Tensor:
        """Behaviour probabilities (the policy mixed with uniform-over-valid by ``epsilon``)."""
        logits = self.masked_logits(obs, mask)
        return behaviour_probs(logits, th.ones_like(logits) if mask is None else mask, epsilon)

    def act(
        self, obs: PyTorchObs, mask: th.Tensor | None, epsilon: float = 0.0, deterministic: bool = False
    ) -> th.Tensor:
        """One action per agent row; all agents of all env copies in a single forward pass."""
        if deterministic:
            return sample_actions(self.masked_logits(obs, mask), deterministic=True)
        return sample_actions(self.action_probs(obs, mask, epsilon))

    def forward(self, obs: PyTorchObs, deterministic: bool = False) -> th.Tensor:  # type: ignore[override]
        return self._predict(obs, deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        """SB3's ``predict`` path: the ``action_mask`` key of a ``Dict`` observation is applied."""
        mask = observation.get(KEY_MASK) if isinstance(observation, dict) else None
        return self.act(observation, None if mask is None else mask.float(), deterministic=deterministic)

    # ------------------------------------------------------------ critic
    def _state_rows(self, obs: PyTorchObs, state: th.Tensor) -> tuple[Any, Any]:
        """The preprocessed state and (``critic_obs``) own observation of every agent row, ``B * N``."""
        assert self.state_space is not None
        flat_state = preprocess_obs(state.flatten(0, 1), self.state_space, self.normalize_images)
        own = None
        if self.critic_obs:
            own = self._actor_input(map_obs(lambda x: x.flatten(0, 1), obs))
        return flat_state, own

    def critic_features(self, obs: PyTorchObs, state: th.Tensor, actions: th.Tensor) -> tuple[Any, ...]:
        """The critic's inputs for every agent of every joint step, rows ``B * N``.

        :param obs: joint observations ``(B, N, ...)``
        :param state: the global state per agent row, ``(B, N, ...)``
        :param actions: ``(B, N)`` joint actions (agent ``i``'s own entry does not matter for row ``i``)
        """
        batch, n_agents = actions.shape
        ids = th.eye(n_agents, device=actions.device).expand(batch, n_agents, n_agents)
        extra = th.cat([ids, one_hot_others(actions, self.n_actions)], dim=2).flatten(0, 1)
        return (*self._state_rows(obs, state), extra)

    def state_values(self, obs: PyTorchObs, state: th.Tensor) -> th.Tensor:
        """``V_i(s)`` of every agent of every joint step, ``(B, N)``, from joint observations
        ``(B, N, ...)`` and the state per agent row (needs ``state_value=True``)."""
        if self.value_net is None:
            raise RuntimeError(f"{type(self).__name__} was built without a state value (state_value=False)")
        batch, n_agents = state.shape[:2]
        ids = th.eye(n_agents, device=state.device).expand(batch, n_agents, n_agents).flatten(0, 1)
        return self.value_net(*self._state_rows(obs, state), ids).view(batch, n_agents)

    def q_values(self, obs: PyTorchObs, state: th.Tensor, actions: th.Tensor, target: bool = False) -> th.Tensor:
        """``Q(s, u_-i, .)`` for every agent of every joint step: ``(B, N, n)`` in one pass."""
        batch, n_agents = actions.shape
        net = self.critic_target if target else self.critic
        return net(*self.critic_features(obs, state, actions)).view(batch, n_agents, self.n_actions)

    def critic_output_layers(self) -> list[nn.Linear]:
        """The last linear layer of the critic, its target and ``value_net`` (if any): what
        :meth:`preserve_critic_outputs` rescales. A world-specific policy whose critic has no
        ``head`` layer overrides this."""
        modules = [self.critic, self.critic_target, self.value_net]
        heads = [module.head for module in modules if module is not None]
        if not all(isinstance(head, nn.Linear) for head in heads):
            raise TypeError(
                f"{type(self).__name__}: a critic's head is not one linear layer; override critic_output_layers"
            )
        return cast(list[nn.Linear], heads)

    @th.no_grad()
    def preserve_critic_outputs(self, old_mean: float, old_std: float, new_mean: float, new_std: float) -> None:
        """Rescale the output layers so that ``output * std + mean`` is unchanged when the critic's
        standardisation moves from ``(old_mean, old_std)`` to ``(new_mean, new_std)`` (PopArt's
        "preserving outputs precisely", van Hasselt et al. 2016): ``w' = w s / s'`` and
        ``b' = (b s + m - m') / s'``."""
        for layer in self.critic_output_layers():
            layer.weight.mul_(old_std / new_std)
            layer.bias.mul_(old_std).add_(old_mean - new_mean).div_(new_std)

    @th.no_grad()
    def sync_target(self) -> None:
        """Copy the critic into the target critic."""
        self.critic_target.load_state_dict(self.critic.state_dict())

    def load_state_dict(self, state_dict: Mapping[str, Any], strict: bool = True, assign: bool = False) -> Any:
        """Also accept the compact shipped form (``sb3_coma.app.pretrained.save_for_shipping``): weights
        in half precision (cast back to the parameters' float32) and no target critic, which is then
        the critic itself, as right after a synchronisation."""
        state = dict(state_dict)
        if not any(key.startswith(_TARGET_PREFIX) for key in state):
            state.update(
                {
                    _TARGET_PREFIX + key[len(_CRITIC_PREFIX) :]: value
                    for key, value in state_dict.items()
                    if key.startswith(_CRITIC_PREFIX)
                }
            )
        return super().load_state_dict(state, strict=strict, assign=assign)


class MlpPolicy(COMAPolicy):
    """Vector observations: flattened inputs, MLP actor and critic (SB3's ``MlpPolicy`` for COMA)."""


class CnnPolicy(COMAPolicy):
    """Image observations: SB3's ``NatureCNN`` (or ``features_extractor_class``, e.g.
    :class:`~sb3_coma.common.extractors.CBAMExtractor`) for the actor and an image state."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", NatureCNN)
        super().__init__(*args, **kwargs)


class MultiInputPolicy(COMAPolicy):
    """``Dict`` observations: SB3's ``CombinedExtractor`` over every key but ``state`` / ``action_mask``."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", CombinedExtractor)
        super().__init__(*args, **kwargs)
