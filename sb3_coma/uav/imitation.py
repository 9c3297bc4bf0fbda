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

Every round draws its randomness from ``(seed, round)`` alone (the env's missions, the coin that
picks teacher or actor, the teacher's tie-breaks), so a run stopped after round ``k`` and continued
from its :class:`DaggerCheckpoint` flies the same rounds ``k + 1, ...`` and gives the same clone as
a run that was never stopped.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F

from sb3_coma.common.checkpoints import atomic_write
from sb3_coma.common.numbers import is_real, is_whole
from uav_ipp import layout


@dataclass
class DaggerReport:
    """What one DAgger run did: per round, beta, missions, dataset size, fit loss and agreement."""

    rounds: list[dict[str, float]] = field(default_factory=list)

    @property
    def agreement(self) -> float:
        """Share of the last round's states where the actor's argmax equals the teacher's move."""
        return self.rounds[-1]["agreement"] if self.rounds else float("nan")


class DaggerInterrupted(KeyboardInterrupt):
    """:func:`clone_teacher` stopped because its ``stop()`` said so (a signal); the round in progress
    is dropped and the :attr:`rounds_done` finished ones are in its checkpoint. A
    ``KeyboardInterrupt``, so that ``except Exception`` guards let it through."""

    def __init__(self, rounds_done: int) -> None:
        super().__init__(f"DAgger stopped after {rounds_done} finished round(s)")
        self.rounds_done = rounds_done


class _Dataset:
    """Aggregated (observation, teacher move) pairs, stored in float16 to bound memory."""

    def __init__(self) -> None:
        self.parts: dict[str, list[np.ndarray]] = {"local": [], "mask": [], "prior": [], "target": []}

    def arrays(self) -> dict[str, np.ndarray]:
        """Each key's chunks as one array (keys without data left out): what a round file holds."""
        return {key: np.concatenate(chunks) for key, chunks in self.parts.items() if chunks}

    def extend(self, arrays: dict[str, np.ndarray]) -> None:
        """Append a round's :meth:`arrays`; :meth:`tensors` concatenates in the same order as if the
        round's chunks had been added one by one, so a restored aggregate fits identically."""
        for key, value in arrays.items():
            self.parts[key].append(value)

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


class DaggerCheckpoint:
    """Where :func:`clone_teacher` keeps its progress, so that an interrupted DAgger continues from
    its last finished round and gives the clone an unbroken run gives.

    After round ``k``: ``round_<k>.npz``, the states that round labelled (the aggregate's arrays as
    held in memory, float16 observations, compressed: rewriting the whole aggregate every round
    would cost O(rounds^2) writes, and 8 rounds x 128 env3 missions are about 120 MB raw), then
    ``state.pt``: the policy and its optimiser, the report so far and the settings the rounds were
    flown with. Each file is written atomically (a temporary file in the folder, then
    :func:`os.replace`) and ``state.pt`` last, so it never names a round whose data is missing.
    """

    STATE = "state.pt"

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)

    def rounds_done(self) -> int:
        """Finished rounds recorded in the folder (0: none, or no checkpoint)."""
        if not (self.folder / self.STATE).is_file():
            return 0
        return int(th.load(self.folder / self.STATE, map_location="cpu", weights_only=True)["rounds_done"])

    def save(self, model: Any, arrays: dict[str, np.ndarray], report: DaggerReport, settings: dict[str, Any]) -> None:
        """Record the round just finished (``arrays``: its labelled states)."""
        k = len(report.rounds) - 1
        compact: dict[str, Any] = dict(arrays)
        atomic_write(self.folder / f"round_{k}.npz", lambda handle: np.savez_compressed(handle, **compact))
        state = {
            "rounds_done": k + 1,
            "report": report.rounds,
            "settings": settings,
            "policy": model.policy.state_dict(),
            "optimizer": model.policy.optimizer.state_dict(),
        }
        atomic_write(self.folder / self.STATE, lambda handle: th.save(state, handle))

    def load(self, model: Any, settings: dict[str, Any]) -> tuple[_Dataset, DaggerReport]:
        """Put the last finished round's policy and optimiser into ``model``; return the aggregate
        and the report so far. Refused when the rounds were flown with other ``settings``."""
        state = th.load(self.folder / self.STATE, map_location=model.device, weights_only=True)
        if state["settings"] != settings:
            changed = sorted(
                k for k in set(settings) | set(state["settings"]) if settings.get(k) != state["settings"].get(k)
            )
            raise ValueError(
                f"DAgger checkpoint {self.folder} was made with other settings ({', '.join(changed)}: "
                f"{[state['settings'].get(k) for k in changed]}, now {[settings.get(k) for k in changed]})"
            )
        model.policy.load_state_dict(state["policy"])
        model.policy.optimizer.load_state_dict(state["optimizer"])
        data = _Dataset()
        for k in range(int(state["rounds_done"])):
            with np.load(self.folder / f"round_{k}.npz") as saved:
                data.extend({key: saved[key] for key in saved.files})
        return data, DaggerReport(rounds=[dict(r) for r in state["report"]])

    def clear(self) -> None:
        """Remove the folder (the warm start is over, or starts afresh)."""
        shutil.rmtree(self.folder, ignore_errors=True)


def _student_actions(model: Any, obs: dict[str, np.ndarray]) -> np.ndarray:
    tensors = {key: th.as_tensor(np.asarray(value), device=model.device) for key, value in obs.items()}
    mask = tensors[layout.KEY_MASK].float()
    with th.no_grad():
        return model.policy.act(tensors, mask, deterministic=True).cpu().numpy()


def _fly_round(
    model: Any,
    teacher: Any,
    data: _Dataset,
    missions: int,
    beta: float,
    seeds: tuple[int, int],
    halt: Callable[[], None],
) -> int:
    """Fly ``missions`` missions in ``model.env``, every copy following the teacher with
    probability ``beta`` per mission (else the actor); label every state with the teacher's move.

    ``seeds`` = ``(seed, round k)``: round ``k`` flies the env seeds after round ``k - 1``'s and
    draws its coins and the teacher's tie-breaks from its own stream, so it never depends on an
    earlier round's draws (a resumed DAgger flies it as an unbroken one would). ``halt()`` is
    called at every step (it raises to stop)."""
    venv, n = model.env, model.n_agents
    copies = venv.num_envs // n
    seed, k = seeds
    coin, ties = np.random.SeedSequence([seed, k]).spawn(2)
    rng = np.random.default_rng(coin)
    venv.seed(seed + k * math.ceil(missions / copies) * copies)
    teacher.reset(seed=int(ties.generate_state(1)[0]))
    flown = 0
    while flown < missions:
        obs = venv.reset()
        teacher.reset()
        follow = np.repeat(rng.random(copies) < beta, n)
        for _ in range(int(venv.get_attr("config", indices=[0])[0].budget)):
            halt()
            target, _ = teacher.predict(obs, deterministic=True)
            data.add(obs, target)
            acted = np.where(follow, target, _student_actions(model, obs))
            obs, _, dones, _ = venv.step(acted)
        assert dones.all(), "the world ends every mission after its budget"
        flown += copies
    return flown


def _fit(
    model: Any, tensors: dict[str, th.Tensor | None], epochs: int, batch_size: int, halt: Callable[[], None]
) -> tuple[float, float]:
    """Masked cross-entropy of the actor on the aggregated data; returns (last loss, agreement).
    ``halt()`` is called before every gradient step (it raises to stop)."""
    policy, device = model.policy, model.device
    targets = tensors["target"]
    assert targets is not None
    n = len(targets)
    gen = th.Generator().manual_seed(int(model.seed or 0) + n)
    policy.set_training_mode(True)
    loss_value = float("nan")
    for _ in range(epochs):
        for idx in th.randperm(n, generator=gen).split(batch_size):
            halt()
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


def _check_arguments(model: Any, missions_per_round: Any, rounds: Any, epochs: Any, beta_decay: float) -> None:
    for name, value in (("missions_per_round", missions_per_round), ("rounds", rounds), ("epochs", epochs)):
        if not is_whole(value) or value < 1:
            raise ValueError(f"{name}={value!r}: must be an integer >= 1")
    if not (is_real(beta_decay) and 0.0 <= beta_decay <= 1.0):
        raise ValueError(f"beta_decay={beta_decay!r}: must be in [0, 1]")
    if model.env is None:
        raise ValueError("clone_teacher needs a model with an env (COMA(..., env))")


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
    checkpoint: DaggerCheckpoint | None = None,
    stop: Callable[[], bool] | None = None,
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
    :param checkpoint: saved after every round; when it already holds rounds (flown with the same
        settings), DAgger continues after the last of them
    :param stop: polled at every env step and gradient step; once true, the round in progress is
        dropped and :class:`DaggerInterrupted` raised (the finished rounds are in ``checkpoint``)
    :raises ValueError: a bad argument, or a checkpoint made with other settings
    """
    _check_arguments(model, missions_per_round, rounds, epochs, beta_decay)
    settings = {
        "missions_per_round": missions_per_round,
        "rounds": rounds,
        "beta_decay": float(beta_decay),
        "epochs": epochs,
        "batch_size": batch_size,
        "seed": int(seed),
        "learning_rate": float(learning_rate),
    }
    rates = [g["lr"] for g in model.policy.optimizer.param_groups]
    for g in model.policy.optimizer.param_groups:
        g["lr"] = learning_rate
    try:
        resumed = checkpoint is not None and checkpoint.rounds_done() > 0
        data, report = (
            checkpoint.load(model, settings) if checkpoint is not None and resumed else (_Dataset(), DaggerReport())
        )

        def halt() -> None:
            if stop is not None and stop():
                raise DaggerInterrupted(len(report.rounds))

        for k in range(len(report.rounds), rounds):
            fresh = _Dataset()
            flown = _fly_round(model, teacher, fresh, missions_per_round, beta_decay**k, (int(seed), k), halt)
            arrays = fresh.arrays()
            data.extend(arrays)
            loss, agreement = _fit(model, data.tensors(), epochs, batch_size, halt)
            report.rounds.append(
                {
                    "round": k,
                    "beta": beta_decay**k,
                    "missions": flown,
                    "states": len(data),
                    "loss": loss,
                    "agreement": agreement,
                }
            )
            if checkpoint is not None:
                checkpoint.save(model, arrays, report, settings)
            if on_round is not None:
                on_round(report.rounds[-1])
    finally:
        # load_state_dict replaces the optimiser's param_groups: restore the rates on the current ones
        for g, rate in zip(model.policy.optimizer.param_groups, rates):
            g["lr"] = rate
    model._last_obs = None  # the next learn() resets the env
    return report
