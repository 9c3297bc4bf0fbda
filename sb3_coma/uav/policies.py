"""The paper's policies for the UAV world: a CBAM (or plain-CNN) actor over the fused 11 x 11 maps,
and a centralised critic over 12 channels whose last one draws the other UAVs' actions at their cells.

They are COMA policies (:class:`sb3_coma.coma.policies.COMAPolicy`) that override two hooks: the
actor reads ``local`` (+ ``action_gain``), and :meth:`UavCOMAPolicy.critic_features` builds the
spatial critic input instead of the generic one-hot actions. Module names (``actor``, ``critic``,
``critic_target``) and the initialisation order are those of the models shipped before COMA became
generic, so their weights load unchanged and a fixed seed trains the same parameters.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial
from typing import Any, cast

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_coma.coma.policies import COMAPolicy, dueling_q
from sb3_coma.common.extractors import GAIN_ENCODER_DIM, CBAMExtractor, CnnExtractor
from sb3_coma.common.masking import mask_logits
from sb3_coma.common.numbers import flag, is_flag, is_real, plain
from uav_ipp import layout

#: FOOTPRINT marks the current cell with 1.0 and earlier visits with 0.5; anything above this
#: threshold is "here" (equivalent to ``== 1`` for those values, but immune to float round-off).
_HERE_THRESHOLD = 0.75


def other_actions_map(footprint: th.Tensor, actions: th.Tensor, n_actions: int = layout.N_ACTIONS) -> th.Tensor:
    """The critic's 12th channel: for agent ``i``, ``(u_j + 1) / A`` at each other agent ``j``'s cell.

    Agent ``j``'s cell is read from its own FOOTPRINT channel (1.0 at the current cell). Agent
    ``i``'s own action never enters its map, which is what makes ``Q(s, u_-i, .)`` a function of
    the other agents' actions only; the ``+ 1`` keeps action 0 distinguishable from "no UAV".

    :param footprint: ``(B, N, H, W)``, each agent's FOOTPRINT channel
    :param actions: ``(B, N)`` integer actions
    :return: ``(B, N, H, W)``; if two UAVs ever shared a column the larger value wins
    """
    _batch, n_agents = actions.shape
    here = (footprint > _HERE_THRESHOLD).to(footprint.dtype)
    contrib = here * ((actions.to(footprint.dtype) + 1.0) / n_actions)[:, :, None, None]  # (B, N, H, W)
    others = 1.0 - th.eye(n_agents, dtype=footprint.dtype, device=footprint.device)  # [i, j] = j != i
    # (B, 1, N, H, W) * (1, N, N, 1, 1) -> (B, N_i, N_j, H, W), then the max over j.
    return (contrib[:, None] * others[None, :, :, None, None]).amax(dim=2)


def critic_input(local: th.Tensor, state: th.Tensor, actions: th.Tensor) -> th.Tensor:
    """Stack ``local`` (8) + ``state`` (3) + other agents' actions (1) into ``(B, N, 12, H, W)``."""
    action_map = other_actions_map(local[:, :, layout.FOOTPRINT], actions)
    return th.cat([local, state, action_map[:, :, None]], dim=2)


class _Head(nn.Module):
    """A features extractor followed by one linear layer to one output per action (``dueling``: one more,
    a value, combined as :func:`~sb3_coma.coma.policies.dueling_q` does for the generic critic)."""

    def __init__(
        self,
        features_extractor: BaseFeaturesExtractor,
        n_actions: int,
        gain: float,
        ortho_init: bool = True,
        dueling: bool = False,
    ) -> None:
        super().__init__()
        self.features_extractor = features_extractor
        self.dueling = dueling
        self.head = nn.Linear(features_extractor.features_dim, n_actions + int(dueling))
        if ortho_init:
            # As SB3 does for A2C/PPO: PyTorch's default init shrinks activations through the
            # ReLU trunk until features barely vary between inputs and the actor cannot learn.
            features_extractor.apply(partial(BasePolicy.init_weights, gain=math.sqrt(2)))
        nn.init.orthogonal_(self.head.weight, gain=gain)
        nn.init.zeros_(self.head.bias)

    def forward(self, x: th.Tensor) -> th.Tensor:
        out = self.head(self.features_extractor(x))
        return dueling_q(out) if self.dueling else out


class _Actor(_Head):
    """The actor's head, plus an optional prior: ``logits = net(local) + sum_k beta_k * gain_k``.

    With a prior, the observation's per-action information gains (``action_gain``: the one-step
    look-ahead a UAV computes from its own belief, under K entropy weightings) are added to the
    logits with learned weights ``beta``, so the first policy is a soft greedy planner and COMA
    learns a correction to it instead of the whole planning skill from scratch
    (docs/training.md, "gain prior"). ``beta = speed * theta`` with ``theta`` the parameter: Adam
    moves a parameter by about the learning rate per step whatever its gradient's size, so the
    ``speed`` factor lets the few mixing weights move as fast as they need to while the network
    keeps the learning rate that keeps it stable.
    """

    def __init__(
        self,
        features_extractor: BaseFeaturesExtractor,
        n_actions: int,
        gain: float,
        ortho_init: bool = True,
        prior_init: Sequence[float] = (),
        prior_speed: float = 1.0,
        correction_bound: float | None = None,
        gain_inputs: int = 0,
    ) -> None:
        super().__init__(features_extractor, n_actions, gain, ortho_init)
        self.correction_bound = correction_bound
        #: With ``gain_inputs`` (the number of ``action_gain`` values), the network reads the gains
        #: as inputs: a learned encoder whose features join the trunk's in the head.
        self.gain_encoder: nn.Sequential | None = None
        if gain_inputs > 0:
            self.gain_encoder = nn.Sequential(nn.Linear(gain_inputs, GAIN_ENCODER_DIM), nn.ReLU())
            self.head = nn.Linear(features_extractor.features_dim + GAIN_ENCODER_DIM, n_actions)
            if ortho_init:
                self.gain_encoder.apply(partial(BasePolicy.init_weights, gain=math.sqrt(2)))
            nn.init.orthogonal_(self.head.weight, gain=gain)
            nn.init.zeros_(self.head.bias)
        self.prior_speed = float(prior_speed)
        self.prior_theta: nn.Parameter | None = None
        if any(w > 0 for w in prior_init):
            self.prior_theta = nn.Parameter(th.tensor([float(w) for w in prior_init]) / self.prior_speed)

    @property
    def prior_weights(self) -> th.Tensor | None:
        """``beta``: the weight of each gain row in the logits (``None`` without a prior)."""
        return None if self.prior_theta is None else self.prior_speed * self.prior_theta

    def prior_logits(self, prior: th.Tensor) -> th.Tensor:
        """The prior's own term ``sum_k beta_k * gain_k``, ``(B, A)`` from ``prior`` ``(B, K, A)``."""
        return th.einsum("k,bka->ba", self.prior_weights, prior)

    @property
    def reads_gain(self) -> bool:
        """Whether the actor needs ``observation["action_gain"]`` (as a prior or as inputs)."""
        return self.prior_theta is not None or self.gain_encoder is not None

    def network_logits(self, x: th.Tensor, gains: th.Tensor | None = None) -> th.Tensor:
        """The network's own term ``(B, A)``: ``c * tanh(net / c)`` with a ``correction_bound`` c,
        so it can reorder moves whose prior logits lie within about 2c of each other but never
        swamp the prior (unbounded, it grew to +-50 in collapsed runs, docs/training.md).
        ``gains`` ``(B, K, A)``: the encoder's input when the actor has one."""
        features = self.features_extractor(x)
        if self.gain_encoder is not None:
            assert gains is not None
            features = th.cat([features, self.gain_encoder(gains.flatten(1))], dim=1)
        net = self.head(features)
        if self.correction_bound is None:
            return net
        return self.correction_bound * th.tanh(net / self.correction_bound)

    def forward(self, x: th.Tensor, prior: th.Tensor | None = None) -> th.Tensor:  # type: ignore[override]
        if self.reads_gain and prior is None:
            role = (
                "adds it to its logits (gain_prior > 0)" if self.prior_theta is not None else "reads it (gain_inputs)"
            )
            raise ValueError(
                f"this actor needs observation[{layout.KEY_GAIN!r}] ({role}), "
                "but the observation has no such key: make the env with action_gain=True"
            )
        logits = self.network_logits(x, prior)
        if self.prior_theta is not None:
            assert prior is not None
            logits = logits + self.prior_logits(prior)
        return logits


def _is_positive(value: Any) -> bool:
    """A finite number > 0 (not a bool): the rule of ``correction_bound`` and ``gain_prior_speed``."""
    return is_real(value) and 0 < value < math.inf


def _correction_bound(value: Any) -> float | None:
    """``None`` or a finite number > 0, with an error that names the bad value."""
    if value is None:
        return None
    if not _is_positive(value):
        raise ValueError(f"correction_bound={value!r}: must be null (unbounded) or a finite number > 0")
    return float(value)


def _gain_input_size(value: Any, observation_space: spaces.Dict) -> int:
    """How many ``action_gain`` values the actor's network reads (0: none), with errors that name
    the bad value."""
    space = observation_space.spaces.get(layout.KEY_GAIN)
    if not is_flag(value) or (value and space is None):
        raise ValueError(
            f"gain_inputs={value!r}: must be true or false, and gain_inputs=True needs "
            f"observation[{layout.KEY_GAIN!r}]: make the env with action_gain=True"
        )
    return int(math.prod(space.shape or (0,))) if value and space is not None else 0


def _weight(value: Any) -> float:
    """One weight of a ``gain_prior`` list as a float; a flag is refused (``TypeError``)."""
    if is_flag(value):
        raise TypeError(f"{value!r} is a flag, not a weight")
    return float(value)


def _prior_init(gain_prior: Any, speed: Any, observation_space: spaces.Dict) -> tuple[float, ...]:
    """The starting weight of each ``action_gain`` row (empty: no prior), with errors that name the
    bad value. A single number applies to every row."""
    if not _is_positive(speed):
        raise ValueError(f"gain_prior_speed={speed!r}: must be a finite number > 0")
    scalar = is_real(gain_prior)
    try:
        weights = [float(gain_prior)] if scalar else [_weight(w) for w in gain_prior]
    except (TypeError, ValueError):
        weights = []
    if not weights or not all(w >= 0.0 and math.isfinite(w) for w in weights):
        raise ValueError(
            f"gain_prior={gain_prior!r}: must be a number or a list of numbers, one per {layout.KEY_GAIN!r} row "
            f"{layout.GAIN_WEIGHTINGS}; weights must be finite numbers >= 0 (0 = no prior)"
        )
    if not any(w > 0 for w in weights):
        return ()
    has_gain = layout.KEY_GAIN in observation_space.spaces
    rows = int((observation_space[layout.KEY_GAIN].shape or (0,))[0]) if has_gain else 0
    if not has_gain or not (scalar or len(weights) == rows):
        raise ValueError(
            f"gain_prior={gain_prior!r}: needs one weight per {layout.KEY_GAIN!r} row, "
            f"{rows} ({', '.join(layout.GAIN_WEIGHTINGS)}), got {len(weights)}"
            + (
                ""
                if has_gain
                else "; the observation has none: make the env with action_gain=True (the default), or use gain_prior=0"
            )
        )
    return tuple(weights * rows) if scalar else tuple(weights)


def _check_box(obs_space: spaces.Dict, key: str, shape: tuple[int, ...] | None, what: str) -> spaces.Box:
    """``obs_space[key]``, a Box (of ``shape`` when given): one rule, one message naming what is there."""
    box = obs_space.spaces.get(key)
    if not isinstance(box, spaces.Box) or shape not in (None, tuple(box.shape)):
        got = tuple(box.shape) if isinstance(box, spaces.Box) else box or f"no such key ({list(obs_space.spaces)})"
        raise ValueError(
            f"the UAV policies need observation[{key!r}] ({what}) as a Box{'' if shape is None else f' of shape {shape}'}"
            f", got {got}: for another env use MlpPolicy, CnnPolicy or MultiInputPolicy"
        )
    return box


def check_uav_spaces(observation_space: spaces.Space, action_space: spaces.Space) -> None:
    """The UAV world's layout (``uav_ipp.layout``), which these policies are built for.

    ``local`` must hold the 8 channels of the fusion wrapper's output (a raw env has 7: wrap it
    with a fusion wrapper first), ``state`` the 3 global channels on the same grid, and
    ``action_mask`` one entry per action of ``Discrete(6)``.

    :raises ValueError: naming what is missing or has the wrong shape, and what to use instead
    """
    discrete = isinstance(action_space, spaces.Discrete) and int(action_space.n) == layout.N_ACTIONS
    if not (discrete and isinstance(observation_space, spaces.Dict)):
        shown = "a Dict" if isinstance(observation_space, spaces.Dict) else observation_space
        raise ValueError(
            f"the UAV policies (CBAMPolicy, UavCnnPolicy) need the action space Discrete({layout.N_ACTIONS}), "
            f"got {action_space}, and need a Dict observation with keys {layout.KEY_LOCAL!r}, {layout.KEY_STATE!r}, "
            f"{layout.KEY_MASK!r} (uav_ipp.make_vec_env), got {shown}: for another env use MlpPolicy, CnnPolicy "
            "or MultiInputPolicy"
        )
    local = _check_box(observation_space, layout.KEY_LOCAL, None, f"{layout.LOCAL_CHANNELS} x H x W actor maps")
    v2, v3 = layout.LOCAL_CHANNELS, layout.LOCAL_CHANNELS + layout.V3_LOCAL_EXTRA
    if len(local.shape) != 3 or local.shape[0] not in (v2, v3) or min(local.shape[1:]) < 4:
        raw = local.shape[:1] in ((layout.RAW_LOCAL_CHANNELS,), (v3 - 1,))
        raise ValueError(
            f"observation[{layout.KEY_LOCAL!r}] must have shape ({v2}, H, W) or, observation v3, ({v3}, H, W); got "
            f"{tuple(local.shape)}" + (" (a raw env: add a fusion wrapper)" if raw else "") + "; H and W at least 4"
        )
    state_channels = layout.STATE_CHANNELS + (layout.V3_STATE_EXTRA if local.shape[0] == v3 else 0)
    _check_box(observation_space, layout.KEY_STATE, (state_channels, *local.shape[1:]), "critic's global maps")
    _check_box(observation_space, layout.KEY_MASK, (layout.N_ACTIONS,), "valid-action mask")


class UavCOMAPolicy(COMAPolicy):
    """Shared actor ``pi(u | o_i)`` over ``obs["local"]`` + mask, centralised critic ``Q(s, u_-i, .)``
    over the 12-channel spatial input (:func:`critic_input`).

    :param observation_space: the per-agent ``Dict`` (``local``, ``state``, ``action_mask``)
    :param action_space: ``Discrete(6)``
    :param lr_schedule: actor learning-rate schedule (SB3 convention)
    :param critic_lr_schedule: critic learning-rate schedule; defaults to ``lr_schedule``
    :param n_agents: UAVs per joint step (given by COMA; the spatial critic input works for any)
    :param state_space: the state's space (given by COMA: ``observation["state"]``)
    :param features_extractor_class: the actor's trunk
    :param features_extractor_kwargs: its keyword arguments
    :param critic_features_extractor_class: the critic's trunk (defaults to the actor's class)
    :param critic_features_extractor_kwargs: its keyword arguments (default: the actor's)
    :param optimizer_class: optimizer for both networks (Adam, as in the paper)
    :param optimizer_kwargs: extra optimizer arguments, shared by both
    :param ortho_init: orthogonal initialisation (gain sqrt 2 in the trunks, 0.01 on the actor's
        output so the first policy is near-uniform, 1 on the critic's), as SB3's A2C/PPO do
    :param normalize_images: unused (all maps are float in [0, 1]); kept for SB3's signature
    :param gain_prior: initial weight of the rows of the per-action information-gain prior added
        to the actor's logits: one number for every row, or one per row (``layout.GAIN_WEIGHTINGS``
        order: class-weighted, plain), e.g. ``[10, 0]`` starts as adaptive-gain's greedy choice.
        ``0`` (or all zeros): no prior, the paper's actor. Needs the ``action_gain`` key
    :param gain_prior_speed: how much faster than the network the prior's weights learn (see
        ``_Actor``)
    :param correction_bound: bound ``c`` on the network's term of the actor's logits, which
        becomes ``c * tanh(net / c)`` (``None``: unbounded, the paper's actor). With a gain prior
        it keeps the learned correction from swamping the prior (see ``_Actor.network_logits``)
    :param gain_inputs: the actor's network also reads ``observation["action_gain"]`` (every
        move's one-step gain, computed on board from the UAV's own belief) as input features,
        through a learned encoder joined to the trunk's features before the head. Nothing is
        added to the logits by hand: the weights start random and the network learns what the
        gains are worth. Needs the ``action_gain`` key
    :param dueling_critic: the critic's head gives ``Q`` as a value plus centred deviations, one per
        action (as the generic policy's option of the same name, which made COMA deliver on RWARE):
        a plain head fits only the taken action's output per sample, and the baseline reads them all.
        Off by default, so a model saved without the key (every shipped one) loads as a plain head
    """

    actor: _Actor
    critic: _Head
    #: The UAV critic reads the others' actions drawn into its image: it has no generic ``V(s)``.
    supports_state_value = False

    def __init__(
        self,
        observation_space: spaces.Dict,
        action_space: spaces.Discrete,
        lr_schedule: Schedule,
        critic_lr_schedule: Schedule | None = None,
        n_agents: int = 1,
        state_space: spaces.Space | None = None,
        features_extractor_class: type[BaseFeaturesExtractor] = CBAMExtractor,
        features_extractor_kwargs: dict[str, Any] | None = None,
        critic_features_extractor_class: type[BaseFeaturesExtractor] | None = None,
        critic_features_extractor_kwargs: dict[str, Any] | None = None,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        ortho_init: bool = True,
        normalize_images: bool = False,
        gain_prior: float | Sequence[float] = 0.0,
        gain_prior_speed: float = 100.0,
        correction_bound: float | None = None,
        gain_inputs: bool = False,
        dueling_critic: bool = False,
    ) -> None:
        check_uav_spaces(observation_space, action_space)
        self.dueling_critic = flag("dueling_critic", dueling_critic)
        self.correction_bound = _correction_bound(correction_bound)
        #: How many ``action_gain`` values the actor's network reads (0: it reads none).
        self.gain_input_size = _gain_input_size(gain_inputs, observation_space)
        self.gain_inputs = self.gain_input_size > 0
        #: The starting weight of each gain row (empty without a prior).
        self.gain_prior_init = _prior_init(gain_prior, gain_prior_speed, observation_space)
        self.gain_prior = (
            plain(gain_prior) if is_real(gain_prior) else [float(w) for w in cast("Sequence[float]", gain_prior)]
        )
        self.gain_prior_speed = float(gain_prior_speed)
        # The generic COMAPolicy.__init__ builds the generic networks: skip it, set what it would.
        BasePolicy.__init__(
            self,
            observation_space,
            action_space,
            features_extractor_class=features_extractor_class,
            features_extractor_kwargs=features_extractor_kwargs,
            normalize_images=normalize_images,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
        )
        self.n_agents = int(n_agents)
        self.state_space = state_space if state_space is not None else observation_space[layout.KEY_STATE]
        self.actor_space = observation_space[layout.KEY_LOCAL]
        self.critic_features_extractor_class = critic_features_extractor_class or features_extractor_class
        self.critic_features_extractor_kwargs = (
            dict(self.features_extractor_kwargs)
            if critic_features_extractor_kwargs is None
            else dict(critic_features_extractor_kwargs)
        )
        self.n_actions = int(action_space.n)
        self.ortho_init = ortho_init
        self._build(lr_schedule, critic_lr_schedule or lr_schedule)

    def _build(self, lr_schedule: Schedule, critic_lr_schedule: Schedule) -> None:
        observation_space = cast(spaces.Dict, self.observation_space)
        local, state = observation_space[layout.KEY_LOCAL], observation_space[layout.KEY_STATE]
        assert isinstance(local, spaces.Box) and isinstance(state, spaces.Box)
        channels = local.shape[0] + state.shape[0] + 1
        critic_space = spaces.Box(0.0, 1.0, (channels, *local.shape[1:]), dtype=local.dtype)
        actor_space = spaces.Box(0.0, 1.0, local.shape, dtype=local.dtype)

        # Small output gain: a near-uniform initial policy explores every valid action.
        self.actor = _Actor(
            self.features_extractor_class(actor_space, **self.features_extractor_kwargs),
            self.n_actions,
            gain=0.01,
            ortho_init=self.ortho_init,
            prior_init=self.gain_prior_init,
            prior_speed=self.gain_prior_speed,
            correction_bound=self.correction_bound,
            gain_inputs=self.gain_input_size,
        )
        critic_class = self.critic_features_extractor_class
        assert critic_class is not None  # the actor's class unless given
        self.critic = _Head(
            critic_class(critic_space, **self.critic_features_extractor_kwargs),
            self.n_actions,
            gain=1.0,
            ortho_init=self.ortho_init,
            dueling=self.dueling_critic,
        )
        self._finish_build(lr_schedule, critic_lr_schedule)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {
            **self._shared_constructor_parameters(),
            "gain_prior": self.gain_prior,
            "gain_prior_speed": self.gain_prior_speed,
            "correction_bound": self.correction_bound,
            "gain_inputs": self.gain_inputs,
            "dueling_critic": self.dueling_critic,
        }

    def log_values(self) -> dict[str, float]:
        """The gain prior's weights, one per weighting (none without a prior)."""
        weights = self.actor.prior_weights
        if weights is None:
            return {}
        return {f"gain_prior_{name}": float(w) for name, w in zip(layout.GAIN_WEIGHTINGS, weights.tolist())}

    def masked_logits(self, obs: PyTorchObs, mask: th.Tensor | None, actor: nn.Module | None = None) -> th.Tensor:
        """Actor logits ``(B, 6)`` from ``local`` (and ``action_gain`` when the actor reads it)."""
        assert isinstance(obs, dict)
        gain = obs.get(layout.KEY_GAIN)
        logits = (actor or self.actor)(obs[layout.KEY_LOCAL].float(), None if gain is None else gain.float())
        return logits if mask is None else mask_logits(logits, mask)

    def critic_features(self, obs: PyTorchObs, state: th.Tensor, actions: th.Tensor) -> tuple[Any, ...]:
        """The 12-channel critic input of every agent row, ``(B * N, 12, H, W)``."""
        assert isinstance(obs, dict)
        return (critic_input(obs[layout.KEY_LOCAL].float(), state.float(), actions).flatten(0, 1),)


class CBAMPolicy(UavCOMAPolicy):
    """CBAM actor + CBAM critic: the paper's networks."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", CBAMExtractor)
        super().__init__(*args, **kwargs)


class UavCnnPolicy(UavCOMAPolicy):
    """Plain-CNN actor + plain-CNN critic: the ablation without attention."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("features_extractor_class", CnnExtractor)
        super().__init__(*args, **kwargs)
