"""DAgger: clone a teacher planner into COMA's actor on the states the actor itself visits.

A teacher that knows more than the actor (the clairvoyant ``oracle`` knows the ground truth)
labels every state with its move; the actor learns to predict that move from what a UAV has on
board (its observation), so it has to infer from the belief's structure where the teacher knows
the valuable ground is. Plain behaviour cloning trains on the teacher's own states and fails on
the states its mistakes lead to; DAgger (Ross et al. 2011) flies round ``k`` with the teacher's
move with probability ``beta_k = beta_decay ** k`` and the actor's otherwise, labels every
visited state with the teacher's move, aggregates all rounds and refits.

The result is a warm start (``COMA(..., kl_coef=...)`` then pulls the fine-tuning toward it with a
weight that decays to zero), never a hand-made term in the logits: the network decides.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F

from uav_ipp import layout

__all__ = ["DaggerReport", "clone_teacher"]


@dataclass
class DaggerReport:
    """What one DAgger run did: per round, beta, missions, dataset size, fit loss and agreement."""

    rounds: list[dict[str, float]] = field(default_factory=list)

    @property
    def agreement(self) -> float:
        """Share of the last round's states where the actor's argmax equals the teacher's move."""
        return self.rounds[-1]["agreement"] if self.rounds else float("nan")


class _Dataset:
    """Aggregated (observation, teacher move) pairs, stored in float16 to bound memory."""

    def __init__(self) -> None:
        self.parts: dict[str, list[np.ndarray]] = {"local": [], "mask": [], "prior": [], "target": []}

    def add(self, obs: dict[str, np.ndarray], target: np.ndarray) -> None:
        self.parts["local"].append(np.asarray(obs[layout.KEY_LOCAL], dtype=np.float16))
        self.parts["mask"].append(np.asarray(obs[layout.KEY_MASK], dtype=np.float16))
        prior = obs.get(layout.KEY_GAIN)
        if prior is not None:
            self.parts["prior"].append(np.asarray(prior, dtype=np.float16))
        self.parts["target"].append(np.asarray(target, dtype=np.int64))

    def tensors(self) -> dict[str, th.Tensor | None]:
        out: dict[str, th.Tensor | None] = {}
        for key, chunks in self.parts.items():
            out[key] = th.as_tensor(np.concatenate(chunks)) if chunks else None
        return out

    def __len__(self) -> int:
        return sum(len(t) for t in self.parts["target"])


def _student_actions(model: Any, obs: dict[str, np.ndarray]) -> np.ndarray:
    tensors = {key: th.as_tensor(np.asarray(value), device=model.device) for key, value in obs.items()}
    mask = tensors[layout.KEY_MASK].float()
    with th.no_grad():
        return model.policy.act(tensors, mask, deterministic=True).cpu().numpy()


def _fly_round(model: Any, teacher: Any, data: _Dataset, missions: int, beta: float, rng: np.random.Generator) -> int:
    """Fly ``missions`` missions in ``model.env``, every copy following the teacher with
    probability ``beta`` per mission (else the actor); label every state with the teacher's move."""
    venv, n = model.env, model.n_agents
    copies = venv.num_envs // n
    flown = 0
    while flown < missions:
        obs = venv.reset()
        teacher.reset()
        follow = np.repeat(rng.random(copies) < beta, n)
        for _ in range(int(venv.get_attr("config", indices=[0])[0].budget)):
            target, _ = teacher.predict(obs, deterministic=True)
            data.add(obs, target)
            acted = np.where(follow, target, _student_actions(model, obs))
            obs, _, dones, _ = venv.step(acted)
        if not dones.all():
            raise RuntimeError("DAgger expects every copy to end its mission after the budget")
        flown += copies
    return flown


def _fit(model: Any, tensors: dict[str, th.Tensor | None], epochs: int, batch_size: int) -> tuple[float, float]:
    """Masked cross-entropy of the actor on the aggregated data; returns (last loss, agreement)."""
    policy, device = model.policy, model.device
    targets = tensors["target"]
    assert targets is not None
    n = len(targets)
    gen = th.Generator().manual_seed(int(model.seed or 0) + n)
    policy.set_training_mode(True)
    loss_value = float("nan")
    for _ in range(epochs):
        for idx in th.randperm(n, generator=gen).split(batch_size):
            logits = _logits(policy, tensors, idx, device)
            loss = F.cross_entropy(logits, targets[idx].to(device))
            policy.optimizer.zero_grad(set_to_none=True)
            loss.backward()
            th.nn.utils.clip_grad_norm_(policy.actor.parameters(), model.max_grad_norm)
            policy.optimizer.step()
            loss_value = float(loss.item())
    policy.set_training_mode(False)
    with th.no_grad():
        hits = [
            (_logits(policy, tensors, idx, device).argmax(-1).cpu() == targets[idx]).float().sum()
            for idx in th.arange(n).split(4 * batch_size)
        ]
    return loss_value, float(sum(hits) / n)


def _logits(policy: Any, tensors: dict[str, th.Tensor | None], idx: th.Tensor, device: th.device) -> th.Tensor:
    local, mask, prior = tensors["local"], tensors["mask"], tensors["prior"]
    assert local is not None and mask is not None
    obs = {layout.KEY_LOCAL: local[idx].to(device).float()}
    if prior is not None:
        obs[layout.KEY_GAIN] = prior[idx].to(device).float()
    return policy.masked_logits(obs, mask[idx].to(device).float())


def clone_teacher(
    model: Any,
    teacher: Any,
    missions_per_round: int = 64,
    rounds: int = 4,
    beta_decay: float = 0.5,
    epochs: int = 3,
    batch_size: int = 256,
    seed: int = 0,
    learning_rate: float = 3e-4,
    on_round: Callable[[dict[str, float]], None] | None = None,
) -> DaggerReport:
    """DAgger the actor of ``model`` (a :class:`~sb3_coma.COMA`) toward ``teacher`` (module docstring).

    :param teacher: a planner built on ``model.env`` (``make_planner("oracle", model.env)``)
    :param missions_per_round: missions flown per round (rounded up to whole rounds of env copies)
    :param rounds: DAgger rounds; round ``k`` follows the teacher with probability ``beta_decay ** k``
    :param epochs: passes over the aggregated data after each round
    :param batch_size: agent decisions per gradient step
    :param learning_rate: the actor optimiser's rate while fitting (restored afterwards): a model
        configured to fine-tune slowly still clones at the rate cloning needs
    :param on_round: called with each finished round's record (progress for a caller that shows it)
    """
    for name, value in (("missions_per_round", missions_per_round), ("rounds", rounds), ("epochs", epochs)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name}={value!r}: must be an integer >= 1")
    if not 0.0 <= beta_decay <= 1.0:
        raise ValueError(f"beta_decay={beta_decay!r}: must be in [0, 1]")
    if model.env is None:
        raise ValueError("clone_teacher needs a model with an env (COMA(..., env))")
    rng = np.random.default_rng(seed)
    model.env.seed(seed)
    data, report = _Dataset(), DaggerReport()
    groups = model.policy.optimizer.param_groups
    rates = [g["lr"] for g in groups]
    for g in groups:
        g["lr"] = learning_rate
    try:
        for k in range(rounds):
            beta = beta_decay**k
            flown = _fly_round(model, teacher, data, missions_per_round, beta, rng)
            loss, agreement = _fit(model, data.tensors(), epochs, batch_size)
            report.rounds.append(
                {"round": k, "beta": beta, "missions": flown, "states": len(data), "loss": loss, "agreement": agreement}
            )
            if on_round is not None:
                on_round(report.rounds[-1])
    finally:
        for g, rate in zip(groups, rates):
            g["lr"] = rate
    model._last_obs = None  # the next learn() resets the env
    return report
