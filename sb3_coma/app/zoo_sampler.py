"""Optuna search space for COMA, in rl-zoo3's sampler / converter format.

``python -m sb3_coma.zoo train --algo coma --env UavIpp-Env3-v0 -optimize ...`` registers
:func:`sample_coma_params` as ``HYPERPARAMS_SAMPLER["coma"]`` and :func:`convert_coma_params` as
``HYPERPARAMS_CONVERTER["coma"]`` (used by rl-zoo3 to turn a stored trial back into
hyperparameters, ``--trial-id``). With ``--storage sqlite:///coma.db --study-name NAME`` (or a
``.log`` journal file on a shared disk) several machines search the same study.

The space covers the optimiser side of COMA; the architecture (``policy``) and the environment
(``env_kwargs``) stay as the config says, so a study answers "how to train this arm" and the
ablation stays a comparison of arms. ``n_steps`` is left to COMA, which collects exactly one
minibatch worth of joint steps per rollout (``ceil(batch_size / n_envs)`` steps per copy) when the
config gives none; a config that fixes ``n_steps`` (the third-party tasks' entries) may make a
sampled batch larger than its rollout, and the managers prune such a trial instead of failing.
"""

from __future__ import annotations

from typing import Any

import optuna
from rl_zoo3.hyperparams_opt import HYPERPARAMS_CONVERTER, HYPERPARAMS_SAMPLER


def convert_coma_params(sampled_params: dict[str, Any]) -> dict[str, Any]:
    """Trial parameters (Optuna's names) -> COMA constructor arguments."""
    params = dict(sampled_params)
    out: dict[str, Any] = {}
    if "batch_size_pow" in params:
        out["batch_size"] = 2 ** int(params.pop("batch_size_pow"))
    if "one_minus_gamma" in params:
        out["gamma"] = 1.0 - float(params.pop("one_minus_gamma"))
    if "one_minus_td_lambda" in params:
        out["td_lambda"] = 1.0 - float(params.pop("one_minus_td_lambda"))
    if "exploration_initial_eps" in params:
        out["exploration_initial_eps"] = float(params.pop("exploration_initial_eps"))
        out["exploration_final_eps"] = 0.0
    out.update(params)
    return out


def sample_coma_params(
    trial: optuna.Trial, n_actions: int = 6, n_envs: int = 1, additional_args: dict | None = None
) -> dict[str, Any]:
    """Sample COMA hyperparameters (rl-zoo3's sampler signature)."""
    trial.suggest_float("learning_rate", 1e-6, 1e-3, log=True)
    trial.suggest_float("critic_learning_rate", 1e-5, 3e-3, log=True)
    trial.suggest_int("batch_size_pow", 6, 10)  # 64 .. 1024 joint steps
    trial.suggest_float("one_minus_gamma", 1e-3, 0.1, log=True)  # gamma 0.9 .. 0.999
    trial.suggest_float("one_minus_td_lambda", 0.01, 0.5, log=True)  # lambda 0.5 .. 0.99
    trial.suggest_int("n_critic_epochs", 1, 4)
    trial.suggest_categorical("n_epochs", [1, 4, 10])  # actor passes per rollout (docs/coma_study)
    trial.suggest_categorical("clip_range", [0.1, 0.2, 0.3])
    trial.suggest_categorical("target_update_interval", [1, 2, 5, 10, 20])
    trial.suggest_float("ent_coef", 1e-6, 5e-2, log=True)
    trial.suggest_float("max_grad_norm", 0.5, 20.0, log=True)
    trial.suggest_float("exploration_initial_eps", 0.0, 0.5)
    trial.suggest_categorical("normalize_advantage", [False, True])
    return convert_coma_params(trial.params)


def register() -> None:
    """Add the COMA sampler and converter to rl-zoo3's tables."""
    HYPERPARAMS_SAMPLER["coma"] = sample_coma_params
    HYPERPARAMS_CONVERTER["coma"] = convert_coma_params
