"""Why COMA trails MAPPO on the third-party tasks, measured one change at a time (issue #45).

Each variant is the library's COMA with one group of settings changed (:data:`VARIANTS`); every
variant trains on the same tasks with the same **validation** training seeds (1000, 1001, ...:
never the benchmark's reported seeds 0..4) and is scored on validation episodes (env seeds from
:data:`VALIDATION_EVAL_SEED`, not the benchmark's). What COMA logs at every update (critic loss,
explained variance of Q against its TD(lambda) targets, the counterfactual advantage's spread,
the policy's entropy, the clipped fraction) is kept per run as SB3's ``progress.csv``.

Phases (resumable: a finished run's record is kept and skipped, files are moved into place whole):

* ``train``: every missing (task, variant, seed) run, ``--workers`` side by side;
* ``report``: ``study.md`` (validation return per variant and the diagnostics at the end of
  training) and ``study.png`` (their curves) in ``--out``.

``python -m sb3_coma.experiments.coma_study --out docs/coma_study`` runs both.
"""

from __future__ import annotations

import argparse
import copy
import csv
import dataclasses
import json
import shutil
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from sb3_coma.common.checkpoints import atomic_write_text
from sb3_coma.experiments.marl_benchmark import (
    TASKS,
    Task,
    _joint_to_learn,
    _trainee,
    _vec_env,
    evaluate_team_return,
    save_palette_png,
)

#: The variants: COMA's constructor arguments that differ from the library's defaults.
VARIANTS: dict[str, dict[str, Any]] = {
    # Foerster et al.: the critic's Q(s, u) minus the counterfactual baseline, one plain policy-gradient step
    "paper": {"advantage": "q", "clip_range": None, "n_epochs": 1},
    "library": {},  # sb3-coma's defaults: 32 steps x 8 copies, 4 clipped epochs on the TD(lambda) return
    "q_norm": {"normalize_q": True},  # the critic learns standardised Q (MAPPO's value normalisation)
    "rollout_1024": {"n_steps": 128, "batch_size": 256},  # MAPPO's rollout: 1024 joint steps, 4 minibatches
    "rollout_1024_epochs_10": {"n_steps": 128, "batch_size": 256, "n_epochs": 10},  # and MAPPO's 10 epochs
    "rollout_1024_epochs_10_q_norm": {"n_steps": 128, "batch_size": 256, "n_epochs": 10, "normalize_q": True},
    # the paper's COMA with a critic that can fit its targets: does the counterfactual Q advantage work then?
    "paper_q_norm": {"advantage": "q", "clip_range": None, "n_epochs": 1, "normalize_q": True},
    "q_advantage_q_norm": {"advantage": "q", "normalize_q": True},  # Q(s, u) - baseline, 4 clipped epochs
    # MAPPO's trace decay (its GAE lambda 0.95) for the TD(lambda) targets, with MAPPO's rollout and epochs
    "lambda_95_rollout_1024_epochs_10": {"n_steps": 128, "batch_size": 256, "n_epochs": 10, "td_lambda": 0.95},
    "lambda_95_rollout_1024_epochs_10_q_norm": {
        "n_steps": 128,
        "batch_size": 256,
        "n_epochs": 10,
        "td_lambda": 0.95,
        "normalize_q": True,
    },
}
#: Round 2 (after round 1 found the critic unfit on simple_spread and sample use carrying Foraging): how
#: many updates each network gets per rollout. Round 1's best gives the actor 4 minibatches x 10 epochs
#: and the critic 4 x 2 = 8 steps per rollout, where MAPPO takes 12 minibatches (256 agent steps)
#: x 10 epochs for both its policy and its value function.
CRITIC_ROUND: dict[str, dict[str, Any]] = {
    "critic_epochs_10": {"n_steps": 128, "batch_size": 256, "n_epochs": 10, "n_critic_epochs": 10},
    "critic_epochs_10_q_norm": {
        "n_steps": 128,
        "batch_size": 256,
        "n_epochs": 10,
        "n_critic_epochs": 10,
        "normalize_q": True,
    },
    # MAPPO's 12 minibatches a rollout (86 joint steps of 3 agents: 258 agent steps)
    "minibatch_86": {"n_steps": 128, "batch_size": 86, "n_epochs": 10},
    "minibatch_86_critic_epochs_10": {"n_steps": 128, "batch_size": 86, "n_epochs": 10, "n_critic_epochs": 10},
    "minibatch_86_critic_epochs_10_q_norm": {
        "n_steps": 128,
        "batch_size": 86,
        "n_epochs": 10,
        "n_critic_epochs": 10,
        "normalize_q": True,
    },
    "minibatch_86_critic_epochs_10_q_norm_lambda_95": {
        "n_steps": 128,
        "batch_size": 86,
        "n_epochs": 10,
        "n_critic_epochs": 10,
        "normalize_q": True,
        "td_lambda": 0.95,
    },
}
VARIANTS.update(CRITIC_ROUND)
#: Round 3 (after round 2 found that fitting the critic better made simple_spread worse, the
#: advantage's spread shrinking as the critic's explained variance grew): the baseline scored with
#: the critic of collection time (``advantage_before_critic_update``), each beside its round-2 twin.
BASELINE_ROUND: dict[str, dict[str, Any]] = {
    f"{twin}_before": {**VARIANTS[twin], "advantage_before_critic_update": True}
    for twin in (
        "rollout_1024_epochs_10",
        "critic_epochs_10",
        "minibatch_86",
        "minibatch_86_critic_epochs_10_q_norm",
    )
}
VARIANTS.update(BASELINE_ROUND)
#: Round 4 (after round 3 found a fitted critic raising the advantage's spread instead of lowering
#: it): GAE with the counterfactual baseline as the value (``advantage="gae"``), bootstrapping each
#: step with the baseline, an expectation over the agent's own next action, as MAPPO's GAE with V.
_ROLLOUT_EPOCHS = {"n_steps": 128, "batch_size": 256, "n_epochs": 10}
GAE_ROUND: dict[str, dict[str, Any]] = {
    "gae": {**_ROLLOUT_EPOCHS, "advantage": "gae"},
    "gae_lambda_95": {**_ROLLOUT_EPOCHS, "advantage": "gae", "td_lambda": 0.95},
    "gae_lambda_95_critic_epochs_10": {**_ROLLOUT_EPOCHS, "advantage": "gae", "td_lambda": 0.95, "n_critic_epochs": 10},
    "gae_lambda_95_critic_epochs_10_q_norm": {
        **_ROLLOUT_EPOCHS,
        "advantage": "gae",
        "td_lambda": 0.95,
        "n_critic_epochs": 10,
        "normalize_q": True,
    },
}
VARIANTS.update(GAE_ROUND)
#: Round 5 (after rounds 3-4 found COMA's sampled policy level with MAPPO's in training but still
#: near uniform, so its most likely actions weaker): a smaller entropy bonus on simple_spread's entry.
ENTROPY_ROUND: dict[str, dict[str, Any]] = {
    f"rollout_1024_epochs_10_before_ent_{name}": {**VARIANTS["rollout_1024_epochs_10_before"], "ent_coef": value}
    for name, value in (("0.001", 0.001), ("0", 0.0))
}
VARIANTS.update(ENTROPY_ROUND)
#: Round 6 (after rounds 2-5 found every fitted critic dragging the training return below random's
#: before it recovers): is it the bootstrap or the baseline? With trace decay 1 the advantage is the
#: Monte-Carlo return (bootstrapped only where the rollout or a time limit cuts the episode) minus
#: the counterfactual baseline, which does not depend on the agent's own action, so the critic's
#: errors can no longer bias the actor through the bootstrapped next-step Q, only add variance; and
#: a critic that fits slowly (a smaller critic rate), as MAPPO's value function does (its explained
#: variance rises only in the second third of training). Each beside the entry's settings.
_ENTRY = VARIANTS["rollout_1024_epochs_10_before"]
FIT_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_1": {**_ENTRY, "td_lambda": 1.0},
    "before_lambda_1_q_norm": {**_ENTRY, "td_lambda": 1.0, "normalize_q": True},
    "before_lambda_95_q_norm": {**_ENTRY, "td_lambda": 0.95, "normalize_q": True},
    "before_q_norm": {**_ENTRY, "normalize_q": True},
    "before_q_norm_critic_lr_3e-4": {**_ENTRY, "normalize_q": True, "critic_learning_rate": 3e-4},
    "before_q_norm_critic_lr_1e-4": {**_ENTRY, "normalize_q": True, "critic_learning_rate": 1e-4},
}
VARIANTS.update(FIT_ROUND)
#: Round 7 (after round 6 found a fitted critic hurting even with trace decay 1, whose only critic
#: term left in the return is the value added where MPE's time limit cuts every episode, 25 steps
#: in: gamma * V(s_25), several times the 25 steps' own rewards): the time limit ends the return
#: like a true end (``bootstrap_time_limits=False``, the MAPPO authors' code on MPE).
TIME_LIMIT_ROUND: dict[str, dict[str, Any]] = {
    f"{twin}_no_time_limit_bootstrap": {**VARIANTS[twin], "bootstrap_time_limits": False}
    for twin in ("rollout_1024_epochs_10_before", "before_q_norm", "critic_epochs_10_before")
}
VARIANTS.update(TIME_LIMIT_ROUND)
#: Round 8 (after rounds 6-7 found a critic that fits hurting wherever the return bootstraps from it:
#: with trace decay below 1, ``G_lambda - b = (Q(s, u) - b) + TD errors``, so the critic's own
#: judgement of the action taken, errors included, steers the actor, as in the paper's Q advantage):
#: the Monte-Carlo return (trace decay 1), which holds no critic term but the time-limit bootstrap
#: (dropped in the last two), minus a baseline that ten critic epochs fit: the advantage is then
#: unbiased whatever the critic's errors, and the fitted baseline only lowers its variance.
_MONTE_CARLO = {**_ENTRY, "td_lambda": 1.0, "n_critic_epochs": 10}
MONTE_CARLO_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_1_critic_epochs_10_q_norm": {**_MONTE_CARLO, "normalize_q": True},
    "before_lambda_1_critic_epochs_10_q_norm_no_time_limit_bootstrap": {
        **_MONTE_CARLO,
        "normalize_q": True,
        "bootstrap_time_limits": False,
    },
    "before_lambda_1_critic_epochs_10_no_time_limit_bootstrap": {**_MONTE_CARLO, "bootstrap_time_limits": False},
}
VARIANTS.update(MONTE_CARLO_ROUND)
#: Round 10 (after round 9 found simple_spread's entry ahead on simple_reference and behind on
#: Foraging-5x5): its two changes of the advantage (the baseline of collection time; the standardised
#: critic with trace decay 0.95) at the Foraging entry's 12 minibatches, flown on the tasks of round 9.
MINIBATCH_ROUND: dict[str, dict[str, Any]] = {
    "minibatch_86_before_lambda_95_q_norm": {**VARIANTS["minibatch_86_before"], "td_lambda": 0.95, "normalize_q": True}
}
VARIANTS.update(MINIBATCH_ROUND)
#: Round 11 (after rounds 2-8 found a fitted critic hurting wherever the return bootstraps from its Q,
#: and the benchmark's curves showing simple_spread's entry falling below random for its first third):
#: the return bootstrapped with a state value V_i(s) fitted beside Q (``advantage="v_return"``, MAPPO's
#: return), so Q enters the advantage only through the counterfactual baseline; with the critic's two
#: epochs (the default) and with ten (MAPPO fits its V with ten).
STATE_VALUE_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_v_return": {**VARIANTS["before_lambda_95_q_norm"], "advantage": "v_return"},
    "before_lambda_95_q_norm_v_return_critic_epochs_10": {
        **VARIANTS["before_lambda_95_q_norm"],
        "advantage": "v_return",
        "n_critic_epochs": 10,
    },
}
VARIANTS.update(STATE_VALUE_ROUND)
#: The probe of round 11 (``coma_probes.PROBES``: not a COMA): the same settings, with V_i(s) itself as
#: the baseline, MAPPO's advantage, so that beside ``before_lambda_95_q_norm_v_return`` only the baseline
#: differs.
VARIANTS["before_lambda_95_q_norm_v_baseline"] = dict(STATE_VALUE_ROUND["before_lambda_95_q_norm_v_return"])
#: Round 12 (after round 11's probe found MAPPO's own advantage no better than COMA's inside COMA's
#: trainer): how the trainer steps, where it differs from SB3's PPO under MAPPO: the gradient-norm clip
#: (COMA 10, PPO 0.5), and with it PPO's 12 minibatches a rollout (86 joint steps) and Adam's eps 1e-5.
_PPO_STEPS = {"max_grad_norm": 0.5, "batch_size": 86, "policy_kwargs": {"optimizer_kwargs": {"eps": 1e-5}}}
STEP_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_grad_0.5": {**VARIANTS["before_lambda_95_q_norm"], "max_grad_norm": 0.5},
    "before_lambda_95_q_norm_ppo_steps": {**VARIANTS["before_lambda_95_q_norm"], **_PPO_STEPS},
    "before_lambda_95_q_norm_v_baseline_ppo_steps": {**VARIANTS["before_lambda_95_q_norm_v_baseline"], **_PPO_STEPS},
}
VARIANTS.update(STEP_ROUND)
#: Round 13 (after round 12 found neither the gradient clip nor PPO's minibatches closing the gap, and the
#: logs showing the entry's policy losing entropy faster than MAPPO's in the first tenth of training and
#: its return falling further): the actor's step size, which no round had changed: PPO's clipping at
#: 0.1 (MAPPO's best change in its own round) and a third of the actor's learning rate (1e-4).
ACTOR_STEP_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_clip_0.1": {**VARIANTS["before_lambda_95_q_norm"], "clip_range": 0.1},
    "before_lambda_95_q_norm_lr_1e-4": {**VARIANTS["before_lambda_95_q_norm"], "learning_rate": 1e-4},
}
VARIANTS.update(ACTOR_STEP_ROUND)
#: Round 15 (after reading MAPPO's policy: SB3's actor behind :class:`~sb3_coma.mappo.central_value.KeysExtractor`,
#: whose own tanh layer comes before PPO's two 64-unit layers, so MAPPO's actor has three hidden layers
#: where COMA's and IPPO's have two, and on simple_spread both two-layer learners sit about 20 below
#: MAPPO in the benchmark): the entry with MAPPO's actor depth, three 64-unit tanh layers.
#: MAPPO's actor depth for COMA: three 64-unit tanh layers, the critic's two 128-unit layers unchanged
#: (rounds 15, 21 and 22 give it to an entry).
MAPPO_DEPTH: dict[str, Any] = {"policy_kwargs": {"net_arch": {"pi": [64, 64, 64], "qf": [128, 128]}}}
ACTOR_DEPTH_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_pi_64x3": {**VARIANTS["before_lambda_95_q_norm"], **MAPPO_DEPTH},
}
VARIANTS.update(ACTOR_DEPTH_ROUND)
#: Round 16 (after MAPPO's value-normalisation arm showed MAPPO falling as COMA does once its V fits
#: early: its entropy drops within the first tenth of training, its return with it; MAPPO's own V, fitted
#: on raw returns, explains nothing for the first fifth, and its entropy falls slowly): a larger entropy
#: bonus, to hold COMA's policy open while its fitted critic sharpens the advantage early.
ENTROPY_HOLD_ROUND: dict[str, dict[str, Any]] = {
    f"before_lambda_95_q_norm_ent_{value}": {**VARIANTS["before_lambda_95_q_norm"], "ent_coef": value}
    for value in (0.03, 0.1)
}
VARIANTS.update(ENTROPY_HOLD_ROUND)
#: The probe of round 14 (after round 12's probe with PPO's stepping, whose actor then differs from
#: MAPPO's in nothing but the fitted V_i it reads its advantage from, still trailing MAPPO): that V_i
#: fitted the way SB3's PPO fits MAPPO's, in the return's own units (no ``normalize_q``), at the actor's
#: learning rate 3e-4, ten epochs a rollout and 64-unit layers. Closing the gap here puts it in how V is
#: fitted; not closing it puts it in what V reads (the state and the agent's observation, where MAPPO's
#: reads the state and the agent's id).
VALUE_FIT_ROUND: dict[str, dict[str, Any]] = {
    "v_baseline_ppo_steps_mappo_value_fit": {
        **VARIANTS["before_lambda_95_q_norm_v_baseline_ppo_steps"],
        "normalize_q": False,
        "critic_learning_rate": 3e-4,
        "n_critic_epochs": 10,
        "policy_kwargs": {"optimizer_kwargs": {"eps": 1e-5}, "net_arch": {"pi": [64, 64], "qf": [64, 64]}},
    },
}
VARIANTS.update(VALUE_FIT_ROUND)
#: Round 17 (after the entry's logs showed its early fall while the scale of the critic's targets grows
#: six-fold, their standard deviation from 4 to 24 over the first 40k joint steps, as the time-limit
#: bootstrap carries the infinite-horizon value (about -80) into every return; and round 6's slower
#: critics doing far worse with ``normalize_q``): PopArt (``normalize_q="popart"``), which rescales the
#: critic's output layer whenever the statistics move, so it is never read at a scale it was not fitted
#: at; and the entry without the time-limit bootstrap (round 7 flew that at trace decay 0.8 only).
SCALE_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_popart": {**VARIANTS["before_lambda_95_q_norm"], "normalize_q": "popart"},
    "before_lambda_95_q_norm_no_time_limit_bootstrap": {
        **VARIANTS["before_lambda_95_q_norm"],
        "bootstrap_time_limits": False,
    },
}
VARIANTS.update(SCALE_ROUND)
#: Round 19 (after the whole-budget runs showed COMA's entry and round 3's both levelling off near a
#: training return of -18.6 per agent over the second half of the budget while MAPPO's keeps rising):
#: rl-zoo3's linear schedule to 0 for both learning rates (``lin_<x>``, read as the zoo reads it), so
#: the late updates, made on a policy that is already good, get smaller. Flown at the whole budget.
LATE_STEP_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_lin_lr": {
        **VARIANTS["before_lambda_95_q_norm"],
        "learning_rate": "lin_3e-4",
        "critic_learning_rate": "lin_1e-3",
    },
}
VARIANTS.update(LATE_STEP_ROUND)
#: Round 20 (after round 17 found that without the time-limit bootstrap the early fall is gone but the
#: critic cannot fit returns that depend on a clock the state lacks): the critic reads the time left in
#: the episode (``critic_time_feature``, MPE's limit of 25 steps: fly this round on the MPE tasks only),
#: with and without the bootstrap; with the clock and no bootstrap the critic learns the 25-step return
#: the task scores ("time awareness", Pardo et al. 2018). Round 17's arm without either is the fourth cell.
CLOCK_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_clock_25": {
        **VARIANTS["before_lambda_95_q_norm"],
        "critic_time_feature": 25,
        "bootstrap_time_limits": False,
    },
    "before_lambda_95_q_norm_clock_25_bootstrap": {**VARIANTS["before_lambda_95_q_norm"], "critic_time_feature": 25},
    # with the clock the early fall is gone and COMA's sampled return keeps pace with MAPPO's until half
    # the budget, then gains half as much; PPO under MAPPO takes three times as many actor steps a rollout
    "minibatch_86_before_lambda_95_q_norm_clock_25": {
        **VARIANTS["minibatch_86_before_lambda_95_q_norm"],
        "critic_time_feature": 25,
        "bootstrap_time_limits": False,
    },
}
VARIANTS.update(CLOCK_ROUND)
#: Round 21 (after round 20's clock and 12 minibatches brought simple_spread's entry level with MAPPO at
#: COMA's actor depth on the validation seeds): the new entry with MAPPO's depth (three 64-unit layers),
#: which round 15 measured as costing the old entry about 8 while it still fell early.
CLOCK_DEPTH_ROUND: dict[str, dict[str, Any]] = {
    "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3": {
        **VARIANTS["minibatch_86_before_lambda_95_q_norm_clock_25"],
        **MAPPO_DEPTH,
    },
}
VARIANTS.update(CLOCK_DEPTH_ROUND)
#: Round 21 on Foraging-5x5 (where COMA's entry scores 0.89 on the validation seeds at the study's budget
#: against MAPPO's 1.00): its entry with the same third layer.
FORAGING_DEPTH_ROUND: dict[str, dict[str, Any]] = {
    "minibatch_86_before_lambda_95_q_norm_pi_64x3": {**VARIANTS["minibatch_86_before_lambda_95_q_norm"], **MAPPO_DEPTH},
}
VARIANTS.update(FORAGING_DEPTH_ROUND)
#: Round 20 on simple_reference (its other MPE task, also 25 steps an episode): the clock on its entry.
REFERENCE_CLOCK_ROUND: dict[str, dict[str, Any]] = {
    "before_lambda_95_q_norm_lr_1e-4_clock_25": {
        **VARIANTS["before_lambda_95_q_norm_lr_1e-4"],
        "critic_time_feature": 25,
        "bootstrap_time_limits": False,
    },
}
VARIANTS.update(REFERENCE_CLOCK_ROUND)
#: Round 20 on the Foraging tasks (50 steps an episode, ended earlier when the food is gone): the clock on
#: each one's entry (Foraging-5x5's 12 minibatches with a standardised critic; Foraging-8x8's without).
FORAGING_CLOCK_ROUND: dict[str, dict[str, Any]] = {
    f"{entry}_clock_50": {**VARIANTS[entry], "critic_time_feature": 50, "bootstrap_time_limits": False}
    for entry in ("minibatch_86_before_lambda_95_q_norm", "minibatch_86_before")
}
VARIANTS.update(FORAGING_CLOCK_ROUND)
#: Round 22 (after round 21's third actor layer helped simple_spread and Foraging-5x5): the same third
#: layer on the entries of the two tasks it was not flown on, simple_reference and Foraging-8x8.
LATE_DEPTH_ROUND: dict[str, dict[str, Any]] = {
    f"{entry}_pi_64x3": {**VARIANTS[entry], **MAPPO_DEPTH}
    for entry in ("before_lambda_95_q_norm_lr_1e-4_clock_25", "minibatch_86_before")
}
VARIANTS.update(LATE_DEPTH_ROUND)
#: Round 23 (after round 21's entry scored level with MAPPO at COMA's old depth on the validation seeds
#: but 2.6 below MAPPO's entry on the reported ones): since round 20 COMA's actor takes 12 minibatch steps
#: an epoch, three times PPO's under MAPPO, each clipped at 0.2; MAPPO took clip 0.1 in its own round.
#: Round 13 found clip 0.1 costly while the entry still fell early, which the clock has since removed.
CLOCK_STEP_ROUND: dict[str, dict[str, Any]] = {
    "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.1": {
        **VARIANTS["minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3"],
        "clip_range": 0.1,
    },
}
VARIANTS.update(CLOCK_STEP_ROUND)
#: Round 24 (after round 23's clip 0.1 brought simple_spread's entry level with MAPPO's entry on the
#: validation seeds): the same clip on the other three studied tasks' entries.
LATE_STEP_CLIP_ROUND: dict[str, dict[str, Any]] = {
    f"{entry}_clip_0.1": {**VARIANTS[entry], "clip_range": 0.1}
    for entry in (
        "before_lambda_95_q_norm_lr_1e-4_clock_25",
        "minibatch_86_before_lambda_95_q_norm_pi_64x3",
        "minibatch_86_before",
    )
}
VARIANTS.update(LATE_STEP_CLIP_ROUND)
#: Round 27 (after round 26 offered MAPPO a clip of 0.05 on simple_spread): the same clip offered back
#: to COMA's entry there.
SMALL_CLIP_ROUND: dict[str, dict[str, Any]] = {
    "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.05": {
        **VARIANTS["minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3"],
        "clip_range": 0.05,
    },
}
VARIANTS.update(SMALL_CLIP_ROUND)
#: Variants flown by a class of :mod:`sb3_coma.experiments.coma_probes` (named, so that importing the
#: study loads no torch) instead of :class:`~sb3_coma.COMA`.
PROBES: dict[str, str] = {
    "before_lambda_95_q_norm_v_baseline": "StateValueBaselineCOMA",
    "before_lambda_95_q_norm_v_baseline_ppo_steps": "StateValueBaselineCOMA",
    "v_baseline_ppo_steps_mappo_value_fit": "StateValueBaselineCOMA",
}
#: The reference every variant is measured against: MAPPO with the MAPPO paper's MPE settings (not COMA;
#: its benchmark entry until MAPPO's own round changed simple_spread's).
REFERENCE = "mappo"
#: What the PPO learners' first rounds change of the MAPPO paper's MPE settings: what those fix, the
#: learning rate (7e-4 in the paper's MPE runs), minibatch size, epochs, clipping and entropy bonus.
PPO_CHANGES: dict[str, dict[str, Any]] = {
    "lr_7e-4": {"learning_rate": 7e-4},
    "lr_1e-4": {"learning_rate": 1e-4},
    "batch_1024": {"batch_size": 1024},
    "epochs_5": {"n_epochs": 5},
    "epochs_15": {"n_epochs": 15},
    "clip_0.1": {"clip_range": 0.1},
    "ent_0": {"ent_coef": 0.0},
}
#: The base of the PPO learners' variants: the MAPPO paper's MPE settings (Yu et al. 2022), fixed here
#: and not read from the zoo entries, so that a study record keeps its meaning after the study's own
#: choice changes an entry; and each learner's policy.
MAPPO_PAPER_MPE: dict[str, Any] = {"n_steps": 128, "batch_size": 256, "n_epochs": 10, "ent_coef": 0.01}
PPO_POLICIES = {REFERENCE: "CentralValuePolicy", "ippo": "MlpPolicy"}
#: The PPO learners' variants, their share of the tuning budget (issue #45, item 2): name -> (learner,
#: its change of :data:`MAPPO_PAPER_MPE`); ``mappo`` and ``ippo`` fly the paper's settings unchanged.
PPO_VARIANTS: dict[str, tuple[str, dict[str, Any]]] = {
    **{learner: (learner, {}) for learner in (REFERENCE, "ippo")},
    **{
        f"{learner}_{name}": (learner, change)
        for learner in (REFERENCE, "ippo")
        for name, change in PPO_CHANGES.items()
    },
}
#: MAPPO's value normalisation (after its rounds' logs showed its V explaining none of the return's
#: variance on simple_reference in any arm, and on simple_spread where its steps are fewer or smaller:
#: SB3's PPO fits V on the raw returns, where the MAPPO paper standardises them): SB3's own
#: ``VecNormalize`` on the rewards only (rl-zoo3's ``normalize`` key), so V fits returns of unit scale.
PPO_VARIANTS["mappo_norm_reward"] = (REFERENCE, {"normalize": {"norm_obs": False, "norm_reward": True}})
#: MAPPO's actor at COMA's and IPPO's depth (round 15's twin): the extractor's tanh layer and one 64-unit
#: layer, two hidden layers where MAPPO's policy otherwise has three.
PPO_VARIANTS["mappo_pi_64x2"] = (REFERENCE, {"policy_kwargs": {"net_arch": {"pi": [64], "vf": [64, 64]}}})
#: MAPPO's share of the whole-budget tuning on simple_spread (round 25): its entry (clip 0.1) with more
#: actor steps a rollout, as round 20 gave COMA (three times its minibatches): minibatches of 96 agent
#: rows, 32 an epoch where 256 give 12 (SB3's PPO counts a minibatch in agent rows, 24 a joint step of
#: 8 copies; 96 divides the rollout's 3072), or 15 epochs, the other change ahead in MAPPO's own round.
MAPPO_WHOLE_BUDGET_ROUND: dict[str, tuple[str, dict[str, Any]]] = {
    f"mappo_clip_0.1_{name}": (REFERENCE, {**PPO_CHANGES["clip_0.1"], **change})
    for name, change in (("batch_96", {"batch_size": 96}), ("epochs_15", PPO_CHANGES["epochs_15"]))
}
PPO_VARIANTS.update(MAPPO_WHOLE_BUDGET_ROUND)
#: Round 26, more of MAPPO's share on the axis that paid for both learners, the actor's step: a smaller
#: clip (0.05), or clip 0.1 with the MAPPO paper's MPE learning rate (7e-4, costly at clip 0.2 in
#: MAPPO's own round).
MAPPO_STEP_ROUND: dict[str, tuple[str, dict[str, Any]]] = {
    "mappo_clip_0.05": (REFERENCE, {"clip_range": 0.05}),
    "mappo_clip_0.1_lr_7e-4": (REFERENCE, {**PPO_CHANGES["clip_0.1"], **PPO_CHANGES["lr_7e-4"]}),
}
PPO_VARIANTS.update(MAPPO_STEP_ROUND)
#: Round 28, the PPO learners' share of the tuning budget (issue #45, item 3: the same number of validation
#: runs for every learner) on the two tasks where COMA's lead over them is least explained by ceiling
#: effects, simple_reference and Foraging-8x8: one-change neighbours of each PPO entry, in this order (the
#: changes that paid on simple_spread first), skipping any setting the entry already changes. They are
#: screened on the first validation seed, as the first rounds screened; the best of them then flies two
#: more seeds beside its entry (round 29). 128-row minibatches are 16 a rollout on these two-agent tasks.
#: The offers are the first rounds' changes (PPO_CHANGES) and three more.
_NEW_OFFERS: dict[str, dict[str, Any]] = {
    "clip_0.05": MAPPO_STEP_ROUND["mappo_clip_0.05"][1],
    "batch_128": {"batch_size": 128},
    "gae_0.99": {"gae_lambda": 0.99},
}
_OFFER_ORDER = (
    *("clip_0.05", "clip_0.1", "epochs_15", "epochs_5", "lr_7e-4"),
    *("lr_1e-4", "batch_128", "batch_1024", "ent_0", "gae_0.99"),
)
BUDGET_OFFERS: dict[str, dict[str, Any]] = {name: (PPO_CHANGES | _NEW_OFFERS)[name] for name in _OFFER_ORDER}


def _offered(
    entry: str, base: dict[str, Any], offers: dict[str, dict[str, Any]], flown: dict[str, str]
) -> dict[str, Any]:
    """Each of ``offers`` applied to ``base``, the settings of ``entry`` (overriding the entry's own value of
    that setting), by name: ``flown`` maps the settings an earlier round flew (as sorted JSON) to that arm's
    name, which the neighbour keeps (one setting, one record); a new one is named ``<entry>_<offer>``."""
    found = {}
    for name, offer in offers.items():
        settings = {**base, **offer}
        found[flown.get(json.dumps(settings, sort_keys=True), f"{entry}_{name}")] = settings
    return found


def ppo_neighbours(entry: str, offers: dict[str, dict[str, Any]]) -> dict[str, tuple[str, dict[str, Any]]]:
    """Each of ``offers`` applied to a PPO learner's ``entry`` variant (see :func:`_offered`)."""
    learner, change = PPO_VARIANTS[entry]
    flown = {
        json.dumps(settings, sort_keys=True): name
        for name, (owner, settings) in PPO_VARIANTS.items()
        if owner == learner
    }
    return {name: (learner, settings) for name, settings in _offered(entry, change, offers, flown).items()}


def entry_neighbours(entry: str, count: int) -> dict[str, tuple[str, dict[str, Any]]]:
    """The first ``count`` one-change neighbours of a PPO learner's ``entry`` variant from
    :data:`BUDGET_OFFERS`, skipping the offers of a setting the entry already changes."""
    change = PPO_VARIANTS[entry][1]
    offers = [(name, offer) for name, offer in BUDGET_OFFERS.items() if not offer.keys() & change.keys()]
    return ppo_neighbours(entry, dict(offers[:count]))


#: How many neighbours each (PPO entry, task) screens: its runs then reach COMA's on the task, counted as
#: :func:`tuning_runs` counts (before round 28: simple_reference COMA 27, MAPPO 19, IPPO 16; Foraging-8x8
#: COMA 21, MAPPO 14, IPPO 12), each count plus the two seeds round 29 adds to the best neighbour.
BUDGET_SCREENS: dict[str, tuple[tuple[str, int], ...]] = {
    "simple_reference": (("mappo_lr_1e-4", 6), ("ippo_ent_0", 9)),
    "lbf_8x8": (("mappo_lr_7e-4", 5), ("ippo_lr_7e-4", 7)),
}
# one screen at a time: a later screen's neighbour with an earlier one's settings finds it by name
# (Foraging-8x8's IPPO without the entropy bonus is simple_reference's ippo_ent_0_lr_7e-4)
for _entry, _count in (screen for screens in BUDGET_SCREENS.values() for screen in screens):
    PPO_VARIANTS.update(entry_neighbours(_entry, _count))


def budget_arms(task: str) -> tuple[str, ...]:
    """Round 28's arms on ``task``: each PPO entry followed by the neighbours it screens."""
    return tuple(name for entry, count in BUDGET_SCREENS[task] for name in (entry, *entry_neighbours(entry, count)))


#: Round 29: the neighbour of each PPO entry that round 28's seed ranked first, on the two other validation
#: seeds beside its entry, whether or not it beat the entry there (simple_reference: 128-row minibatches for
#: both MAPPO, -36.81 against its entry's -37.84, and IPPO, -36.67 against -37.31; Foraging-8x8: MAPPO's 5
#: epochs, 0.06 against 0.07, and IPPO without the entropy bonus, 0.23 against 0.21).
BUDGET_CONFIRMS: dict[str, tuple[str, ...]] = {
    "simple_reference": ("mappo_lr_1e-4_batch_128", "ippo_ent_0_batch_128"),
    "lbf_8x8": ("mappo_lr_7e-4_epochs_5", "ippo_ent_0_lr_7e-4"),
}


def confirm_arms(task: str) -> tuple[str, ...]:
    """Round 29's arms on ``task``: each PPO entry followed by its neighbour that round 28 ranked first."""
    return tuple(
        name
        for (entry, _), best in zip(BUDGET_SCREENS[task], BUDGET_CONFIRMS[task], strict=True)
        for name in (entry, best)
    )


#: Each learner's RWARE entry before round 30, the first round to fly RWARE (COMA's: round 2's
#: Foraging-5x5 entry, the best mean rank over rounds 1 and 2; MAPPO's and IPPO's: the MAPPO paper's
#: MPE settings).
WAREHOUSE_ENTRIES = ("minibatch_86", REFERENCE, "ippo")
#: Round 31, RWARE's tuning, the same for every learner: these offers applied to each learner's entry,
#: screened on the first validation seed. The first five budget offers, in their fixed order (COMA takes
#: them as they are: its clip, actor epochs and actor learning rate mean what PPO's do); then two that
#: round 30's logs point to. There the advantage's spread before standardising was 0.001 to 0.01 (a
#: delivery is rare), so the standardised advantage the actor steps on is mostly noise, and the actor's
#: entropy fell from 1.6 to about 0.6 (COMA) and 1.0 (MAPPO) with no return to show for it: the raw
#: advantage (SB3's ``normalize_advantage=False``, which COMA shares), whose noise is small beside the
#: entropy bonus, and a five times larger entropy bonus.
WAREHOUSE_OFFERS: dict[str, dict[str, Any]] = {
    **dict(list(BUDGET_OFFERS.items())[:5]),
    "adv_raw": {"normalize_advantage": False},
    "ent_0.05": {"ent_coef": 0.05},
}


def coma_neighbours(entry: str, offers: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each of ``offers`` applied to COMA's ``entry`` variant (see :func:`_offered`)."""
    flown = {json.dumps(settings, sort_keys=True): name for name, settings in VARIANTS.items()}
    return _offered(entry, VARIANTS[entry], offers, flown)


WAREHOUSE_ROUND = coma_neighbours(WAREHOUSE_ENTRIES[0], WAREHOUSE_OFFERS)
VARIANTS.update(WAREHOUSE_ROUND)
for _entry in WAREHOUSE_ENTRIES[1:]:
    PPO_VARIANTS.update(ppo_neighbours(_entry, WAREHOUSE_OFFERS))


def warehouse_neighbours(entry: str, offers: dict[str, dict[str, Any]] = WAREHOUSE_OFFERS) -> tuple[str, ...]:
    """The names of ``offers`` applied to one learner's RWARE ``entry`` (COMA's or a PPO learner's), in
    the offers' order (round 31's by default)."""
    return tuple(coma_neighbours(entry, offers) if entry in VARIANTS else ppo_neighbours(entry, offers))


def warehouse_arms() -> tuple[str, ...]:
    """Round 31's arms: each learner's RWARE entry followed by its neighbours."""
    return tuple(name for entry in WAREHOUSE_ENTRIES for name in (entry, *warehouse_neighbours(entry)))


def screen_first(table: str, task: str, candidates: tuple[str, ...]) -> str:
    """The candidate a screen's table ranks first on ``task``: the best validation return as the table
    prints it, ties broken by the training return at the end (the sampled policy's, which moves where the
    most likely actions deliver nothing), then by the order of ``candidates`` (the offers' fixed order)."""
    scores: dict[str, tuple[float, float]] = {}
    for line in table.splitlines():
        cells = [cell.strip() for cell in line.split("|")[1:-1]]
        # report_phase's columns: 0 task, 1 variant, 4 validation return, 10 training return first / lowest / last
        if len(cells) > 10 and cells[0] == task and cells[1] in candidates:
            scores[cells[1]] = (float(cells[4]), float(cells[10].split("/")[-1]))
    missing = [name for name in candidates if name not in scores]
    if missing:
        raise ValueError(f"the screen's table has no row for {missing[0]!r} on {task}")
    return max(candidates, key=lambda name: (*scores[name], -candidates.index(name)))


#: Round 32: the neighbour of each learner's RWARE entry that round 31's table ranks first
#: (:func:`screen_first`), on two more validation seeds beside its entry, whether or not it beat the entry
#: on the first (COMA's: the raw advantage, every COMA arm at 0.00 and it alone at 0.1 in training; MAPPO's:
#: clip 0.05, 0.64 against 0.00; IPPO's: learning rate 7e-4, 2.28 against 0.00).
WAREHOUSE_CONFIRMS = ("minibatch_86_adv_raw", "mappo_clip_0.05", "ippo_lr_7e-4")


def warehouse_confirm_arms() -> tuple[str, ...]:
    """Round 32's arms: each learner's RWARE entry followed by its neighbour that round 31 ranked first."""
    pairs = zip(WAREHOUSE_ENTRIES, WAREHOUSE_CONFIRMS, strict=True)
    return tuple(name for pair in pairs for name in pair)


#: Round 33, a screen on RWARE's first validation seed after round 32 (whose logs show COMA's critic
#: explaining none of its targets unless the actor stays uniform): each learner's entry with a longer trace,
#: alone and with its value's targets standardised, two runs each. COMA's trace decay goes from its
#: default 0.8 (a delivery's reward reaches about 5 steps back) to MAPPO's 0.95 (about 17), with its
#: standardised critic (``normalize_q``, in COMA's entries on three other tasks); the PPO learners'
#: GAE lambda from 0.95 to 0.99, with SB3's reward normalisation (round 12's ``mappo_norm_reward``).
TRACE_OFFERS: dict[str, dict[str, dict[str, Any]]] = {
    "coma": {"lambda_95": {"td_lambda": 0.95}, "lambda_95_q_norm": {"td_lambda": 0.95, "normalize_q": True}},
    "ppo": {
        "gae_0.99": BUDGET_OFFERS["gae_0.99"],
        "gae_0.99_norm_reward": {**BUDGET_OFFERS["gae_0.99"], **PPO_VARIANTS["mappo_norm_reward"][1]},
    },
}
#: The RWARE entries since round 32, which round 33 starts from (COMA's kept its entry).
WAREHOUSE_TRACE_ENTRIES = (WAREHOUSE_ENTRIES[0], *WAREHOUSE_CONFIRMS[1:])
WAREHOUSE_TRACE_ROUND = coma_neighbours(WAREHOUSE_TRACE_ENTRIES[0], TRACE_OFFERS["coma"])
VARIANTS.update(WAREHOUSE_TRACE_ROUND)
for _entry in WAREHOUSE_TRACE_ENTRIES[1:]:
    PPO_VARIANTS.update(ppo_neighbours(_entry, TRACE_OFFERS["ppo"]))


def warehouse_trace_arms() -> tuple[str, ...]:
    """Round 33's arms: each learner's RWARE entry followed by its two trace neighbours."""
    return tuple(
        name
        for entry in WAREHOUSE_TRACE_ENTRIES
        for name in (entry, *warehouse_neighbours(entry, TRACE_OFFERS["coma" if entry in VARIANTS else "ppo"]))
    )


def screen_order(table: str, task: str, candidates: tuple[str, ...]) -> tuple[str, ...]:
    """``candidates`` in the order a screen's table ranks them on ``task`` (:func:`screen_first`'s rule)."""
    left, order = list(candidates), []
    while left:
        order.append(screen_first(table, task, tuple(left)))
        left.remove(order[-1])
    return tuple(order)


#: Round 34, RWARE's second screen on its first validation seed: four new arms for every learner, each its
#: next guesses. MAPPO and IPPO, whose round 32 confirmed a change, take their confirmed entry with the next
#: four offers in round 31's order (:func:`screen_order`, leaving out an offer of the setting the entry
#: already changed): the second ring of two-change offers. COMA, whose screen found no arm that delivers,
#: takes the settings its Foraging-5x5 entry was tuned to on the other sparse-reward grid task (rounds 2, 9,
#: 21 and 24: the baseline scored by the critic of collection time, a standardised critic, trace decay 0.95,
#: three actor layers, clip 0.1); the same with the clip 0.05 of simple_spread's entry and MAPPO's RWARE
#: entry; that with MAPPO's return (``advantage="v_return"``, bootstrapped with ``V_i(s)``); and, as a
#: diagnosis, round 11's probe on it: ``V_i(s)`` itself as the baseline, so that the last two differ in the
#: counterfactual baseline alone (does it remove the few deliveries' signal?).
WAREHOUSE_RING_OFFERS: dict[str, tuple[str, ...]] = {
    "mappo_clip_0.05": ("lr_7e-4", "epochs_15", "epochs_5", "adv_raw"),
    "ippo_lr_7e-4": ("clip_0.05", "ent_0.05", "clip_0.1", "adv_raw"),
}
WAREHOUSE_FORAGING = "minibatch_86_before_lambda_95_q_norm_pi_64x3_clip_0.1"
WAREHOUSE_RING_ROUND = coma_neighbours(
    "minibatch_86_before_lambda_95_q_norm_pi_64x3", {"clip_0.05": {"clip_range": 0.05}}
)
_ring_clip = next(iter(WAREHOUSE_RING_ROUND))
VARIANTS.update(WAREHOUSE_RING_ROUND)
WAREHOUSE_RING_ROUND.update(coma_neighbours(_ring_clip, {"v_return": {"advantage": "v_return"}}))
_ring_return = f"{_ring_clip}_v_return"
#: Round 34's probe (not a COMA): ``_ring_return``'s settings with ``V_i(s)`` itself as the baseline.
WAREHOUSE_PROBE = f"{_ring_clip}_v_baseline"
WAREHOUSE_RING_ROUND[WAREHOUSE_PROBE] = dict(WAREHOUSE_RING_ROUND[_ring_return])
PROBES[WAREHOUSE_PROBE] = "StateValueBaselineCOMA"
VARIANTS.update(WAREHOUSE_RING_ROUND)


def _ring_offers(offers: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """Round 31's offers of these names, in the given order."""
    return {name: WAREHOUSE_OFFERS[name] for name in offers}


def _ring_arms(offers_by_entry: dict[str, tuple[str, ...]]) -> tuple[str, ...]:
    """Each PPO learner's RWARE entry followed by its neighbours of ``offers_by_entry[entry]``."""
    return tuple(
        name
        for entry, offers in offers_by_entry.items()
        for name in (entry, *warehouse_neighbours(entry, _ring_offers(offers)))
    )


for _entry, _offers in WAREHOUSE_RING_OFFERS.items():
    PPO_VARIANTS.update(ppo_neighbours(_entry, _ring_offers(_offers)))


def warehouse_ring_arms() -> tuple[str, ...]:
    """Round 34's arms: each learner's RWARE entry since round 32 followed by its four new arms."""
    return (WAREHOUSE_TRACE_ENTRIES[0], WAREHOUSE_FORAGING, *WAREHOUSE_RING_ROUND, *_ring_arms(WAREHOUSE_RING_OFFERS))


#: Round 36, on RWARE's first validation seed: round 34's probe delivered (0.88) where its COMA twin, the
#: same run but for the counterfactual baseline, did not (0.00). The baseline sums the critic's ``Q`` over the
#: agent's own actions, and a plain head fits only the taken action's output per sample: COMA's arm is that
#: twin with a dueling critic (``policy_kwargs: {dueling_critic: true}``), whose baseline mostly reads a value
#: that every sample fits. MAPPO and IPPO take the next offer of their ring (round 34's rule): one run each.
WAREHOUSE_DUELING = f"{_ring_return}_dueling"
WAREHOUSE_DUELING_ROUND: dict[str, dict[str, Any]] = {
    WAREHOUSE_DUELING: {
        **VARIANTS[_ring_return],
        "policy_kwargs": {**VARIANTS[_ring_return]["policy_kwargs"], "dueling_critic": True},
    }
}
VARIANTS.update(WAREHOUSE_DUELING_ROUND)
WAREHOUSE_DUELING_OFFERS: dict[str, tuple[str, ...]] = {
    "mappo_clip_0.05": ("ent_0.05",),
    "ippo_lr_7e-4": ("epochs_15",),
}
for _entry, _offers in WAREHOUSE_DUELING_OFFERS.items():
    PPO_VARIANTS.update(ppo_neighbours(_entry, _ring_offers(_offers)))


def warehouse_dueling_arms() -> tuple[str, ...]:
    """Round 36's arms: COMA's dueling critic beside its probe twin, and each PPO entry's next ring offer."""
    coma = (WAREHOUSE_TRACE_ENTRIES[0], _ring_return, WAREHOUSE_PROBE, WAREHOUSE_DUELING)
    return (*coma, *_ring_arms(WAREHOUSE_DUELING_OFFERS))


def warehouse_ring_candidates(entry: str) -> tuple[str, ...]:
    """The new arms that rounds 34 and 36 flew beside one learner's RWARE ``entry``, in the rounds' order."""
    learner = learner_of(entry)
    flown = dict.fromkeys((*warehouse_ring_arms(), *warehouse_dueling_arms()))  # round 36 flies two of 34's again
    return tuple(name for name in flown if name != entry and learner_of(name) == learner)


#: Round 37: the first two of each learner's new arms of rounds 34 and 36 (:func:`screen_order` over both
#: tables), on the two other validation seeds beside its entry: four runs per learner. COMA's first is round
#: 34's probe, which no config can take (it is not a COMA): flown to see whether the dueling critic, its
#: second, does on three seeds what the probe's baseline does.
WAREHOUSE_RING_CONFIRMS: dict[str, tuple[str, str]] = {
    "minibatch_86": (WAREHOUSE_PROBE, WAREHOUSE_DUELING),
    "mappo_clip_0.05": ("mappo_lr_7e-4_clip_0.05", "mappo_clip_0.05_ent_0.05"),
    "ippo_lr_7e-4": ("ippo_lr_7e-4_clip_0.1", "ippo_lr_7e-4_clip_0.05"),
}


def warehouse_ring_confirm_arms() -> tuple[str, ...]:
    """Round 37's arms: each learner's RWARE entry followed by the two arms it confirms."""
    return tuple(name for entry, pair in WAREHOUSE_RING_CONFIRMS.items() for name in (entry, *pair))


#: Foraging-5x5's budget (issue #45, item 3): before these rounds COMA had 36 validation runs there, MAPPO
#: 16 and IPPO 14. Round 35 screens each PPO entry's eight one-change offers off its own axis on the first
#: validation seed; round 38 flies the first ``k`` of them in the screen's order (:func:`screen_order`) on
#: the two other seeds beside the entry, ``k`` filling the learner's runs up to COMA's: 16 + 8 + 2 * 6 and
#: 14 + 8 + 2 * 7.
FORAGING_SCREENS: tuple[tuple[str, int], ...] = (("mappo_epochs_15", 8), ("ippo_lr_7e-4", 8))
FORAGING_CONFIRM_COUNTS = {"mappo_epochs_15": 6, "ippo_lr_7e-4": 7}
for _entry, _count in FORAGING_SCREENS:
    PPO_VARIANTS.update(entry_neighbours(_entry, _count))


def foraging_budget_arms() -> tuple[str, ...]:
    """Round 35's arms: each PPO learner's Foraging-5x5 entry followed by the neighbours it screens."""
    return tuple(name for entry, count in FORAGING_SCREENS for name in (entry, *entry_neighbours(entry, count)))


#: Round 38: the first ``FORAGING_CONFIRM_COUNTS[entry]`` of each entry's round-35 neighbours in its table's
#: order (:func:`screen_order`), on the two other validation seeds beside the entry.
FORAGING_CONFIRMS: dict[str, tuple[str, ...]] = {
    "mappo_epochs_15": (
        "mappo_clip_0.1_epochs_15",
        "mappo_lr_7e-4_epochs_15",
        "mappo_epochs_15_batch_128",
        "mappo_epochs_15_gae_0.99",
        "mappo_epochs_15_ent_0",
        "mappo_epochs_15_batch_1024",
    ),
    "ippo_lr_7e-4": (
        "ippo_lr_7e-4_batch_128",
        "ippo_ent_0_lr_7e-4",
        "ippo_lr_7e-4_clip_0.1",
        "ippo_lr_7e-4_batch_1024",
        "ippo_lr_7e-4_gae_0.99",
        "ippo_lr_7e-4_epochs_15",
        "ippo_lr_7e-4_epochs_5",
    ),
}


def foraging_budget_confirm_arms() -> tuple[str, ...]:
    """Round 38's arms: each PPO learner's Foraging-5x5 entry followed by the neighbours it confirms."""
    return tuple(name for entry, confirms in FORAGING_CONFIRMS.items() for name in (entry, *confirms))


#: simple_spread's budget (issue #45, item 3): before round 39 COMA had 117 validation runs there, MAPPO 38
#: and IPPO 12. A first ring on the task's whole budget (where its entries were last chosen: rounds 25 to 27)
#: flies every one-change offer of each PPO entry off the entry's own axis (:data:`BUDGET_OFFERS`) on all
#: three validation seeds, since on this task a ranking by one seed has reversed on three (IPPO's 15 epochs,
#: docs/coma_study/ippo_choice_round.md): MAPPO's entry (clip 0.05) eight offers, 24 runs; IPPO's (the
#: MAPPO paper's MPE settings, never flown at the whole budget) ten offers and itself, 33 runs.
SPREAD_ENTRIES = ("mappo_clip_0.05", "ippo")
#: Round 40, the second ring: each learner's best arm of round 39 that was not yet a centre (:func:`screen_first`
#: over its ring, the entry listed first), which round 39 made the learner's entry: MAPPO's 15 epochs (6
#: offers off its two axes, 18 runs), IPPO's clip 0.05 (8 offers, 24 runs). Flown as round 39 was (--tasks
#: simple_spread_full --seeds 3); the rings go on until each learner's runs reach COMA's.
SPREAD_RING_2_CENTRES = ("mappo_clip_0.05_epochs_15", "ippo_clip_0.05")
#: Round 41, the third ring, by the same rule over rounds 39 and 40 (spread_ring_2_round.md): MAPPO's centre
#: stayed its best arm (-36.78; no offer of round 40 beat it), so its next is the best arm not yet a centre,
#: no entropy bonus on top of its entry (-37.34; 5 offers, 15 runs); IPPO's is round 40's winner, its entry
#: since then, clip 0.05 with 15 epochs (-38.37 against -42.88, ahead on every seed; 6 offers, 18 runs).
SPREAD_RING_3_CENTRES = ("mappo_clip_0.05_epochs_15_ent_0", "ippo_clip_0.05_epochs_15")


def spread_ring_arms(centres: tuple[str, ...]) -> tuple[str, ...]:
    """A ring's arms on simple_spread: each PPO learner's centre followed by all its off-axis offers."""
    return tuple(name for centre in centres for name in (centre, *entry_neighbours(centre, len(BUDGET_OFFERS))))


for _centre in (*SPREAD_ENTRIES, *SPREAD_RING_2_CENTRES, *SPREAD_RING_3_CENTRES):  # a later ring finds a name
    PPO_VARIANTS.update(entry_neighbours(_centre, len(BUDGET_OFFERS)))

#: Round 42, the last ring: it fills each PPO learner's runs up to COMA's in one round (a ring a round would
#: need several more). Its centres are each learner's arms over rounds 39 to 41 in their ranking
#: (:func:`screen_order` over the three tables, entry first) that were not yet centres; each brings its
#: off-axis offers that no ring flew, in :data:`BUDGET_OFFERS`' order, and the last centre's offers stop at
#: the first that brings the learner's runs to COMA's (three seeds an arm). Values: how many new arms.
SPREAD_FILL: tuple[tuple[str, int], ...] = (
    ("mappo_clip_0.05_ent_0", 6),
    ("mappo_clip_0.05_epochs_15_ent_0_gae_0.99", 2),
    ("ippo_clip_0.05_epochs_15_gae_0.99", 5),
    ("ippo_clip_0.05_epochs_15_ent_0", 4),
    ("ippo_clip_0.05_gae_0.99", 1),
)


def _ring_flown() -> set[str]:
    """The arms that rounds 39 to 41 flew on simple_spread's whole budget."""
    rings = (SPREAD_ENTRIES, SPREAD_RING_2_CENTRES, SPREAD_RING_3_CENTRES)
    return {name for centres in rings for name in spread_ring_arms(centres)}


def fill_offers(centre: str, count: int, flown: set[str]) -> dict[str, tuple[str, dict[str, Any]]]:
    """The first ``count`` off-axis neighbours of ``centre`` that are not in ``flown``, in the offers' order."""
    fresh = {name: arm for name, arm in entry_neighbours(centre, len(BUDGET_OFFERS)).items() if name not in flown}
    return dict(list(fresh.items())[:count])


def spread_fill_arms() -> tuple[str, ...]:
    """Round 42's arms: each fill centre followed by its new neighbours (an arm a centre before it brought
    is not brought again)."""
    flown, arms = _ring_flown(), []
    for centre, count in SPREAD_FILL:
        new = fill_offers(centre, count, flown)
        flown |= new.keys()
        arms += [centre, *new]
    return tuple(arms)


for _centre, _count in SPREAD_FILL:
    PPO_VARIANTS.update(entry_neighbours(_centre, len(BUDGET_OFFERS)))

#: Round 43, Foraging-5x5 at its whole budget (``lbf_full``, three validation seeds): COMA's entry there
#: misses MAPPO's zero seed spread by one evaluation episode on the reported seeds, and its validation mean
#: (0.99, at the study's half budget) is one hundredth below MAPPO's. COMA's arm is the change with a reason
#: on a sparse-reward grid: the dueling critic head, which made COMA deliver on RWARE (round 36; the
#: counterfactual baseline then reads a value that every sample fits). MAPPO and IPPO take the same number of
#: runs: their best other arm over Foraging-5x5's tables (:func:`screen_order`), at the whole budget. Each
#: learner flies its entry and one arm: six runs each, so the budget stays equal.
FORAGING_WHOLE_ENTRIES = (WAREHOUSE_FORAGING, "mappo_epochs_15", "ippo_lr_7e-4_batch_128")
FORAGING_DUELING = f"{WAREHOUSE_FORAGING}_dueling"
VARIANTS[FORAGING_DUELING] = {
    **VARIANTS[WAREHOUSE_FORAGING],
    "policy_kwargs": {**VARIANTS[WAREHOUSE_FORAGING]["policy_kwargs"], "dueling_critic": True},
}
FORAGING_WHOLE_ARMS = (FORAGING_DUELING, "mappo_clip_0.1_epochs_15", "ippo_lr_7e-4")


def foraging_whole_arms() -> tuple[str, ...]:
    """Round 43's arms: each learner's Foraging-5x5 entry followed by its one arm."""
    return tuple(name for pair in zip(FORAGING_WHOLE_ENTRIES, FORAGING_WHOLE_ARMS, strict=True) for name in pair)


ARMS = (*VARIANTS, *PPO_VARIANTS)
#: Each round is one table: the variants it flies (a variant's runs are shared by the rounds that fly it).
ROUNDS: dict[str, tuple[str, ...]] = {
    "study": (
        *[
            v
            for v in VARIANTS
            if not any(
                v in r
                for r in (
                    CRITIC_ROUND,
                    BASELINE_ROUND,
                    GAE_ROUND,
                    ENTROPY_ROUND,
                    FIT_ROUND,
                    TIME_LIMIT_ROUND,
                    MONTE_CARLO_ROUND,
                    MINIBATCH_ROUND,
                    STATE_VALUE_ROUND,
                    STEP_ROUND,
                    ACTOR_STEP_ROUND,
                    VALUE_FIT_ROUND,
                    ACTOR_DEPTH_ROUND,
                    ENTROPY_HOLD_ROUND,
                    SCALE_ROUND,
                    LATE_STEP_ROUND,
                    CLOCK_ROUND,
                    CLOCK_DEPTH_ROUND,
                    FORAGING_DEPTH_ROUND,
                    REFERENCE_CLOCK_ROUND,
                    FORAGING_CLOCK_ROUND,
                    LATE_DEPTH_ROUND,
                    CLOCK_STEP_ROUND,
                    LATE_STEP_CLIP_ROUND,
                    SMALL_CLIP_ROUND,
                    WAREHOUSE_ROUND,
                    WAREHOUSE_TRACE_ROUND,
                    WAREHOUSE_RING_ROUND,
                    WAREHOUSE_DUELING_ROUND,
                    PROBES,
                )
            )
        ],
        REFERENCE,
    ),
    "critic_round": ("rollout_1024_epochs_10", *CRITIC_ROUND, REFERENCE),
    "baseline_round": (*(name for twin in BASELINE_ROUND for name in (twin.removesuffix("_before"), twin)), REFERENCE),
    "gae_round": ("rollout_1024_epochs_10", *GAE_ROUND, REFERENCE),
    "entropy_round": ("rollout_1024_epochs_10_before", *ENTROPY_ROUND, REFERENCE),
    "fit_round": ("rollout_1024_epochs_10_before", *FIT_ROUND, REFERENCE),
    # the choice between the two best variants on simple_spread, on three validation seeds (--seeds 3)
    "choice_round": ("rollout_1024_epochs_10_before", "before_lambda_95_q_norm"),
    "monte_carlo_round": ("rollout_1024_epochs_10_before", "before_lambda_1", *MONTE_CARLO_ROUND, REFERENCE),
    # the simple_spread entry against the entry the unstudied tasks took by mean rank, on the tasks that
    # took it (--tasks simple_reference,lbf,lbf_8x8 --seeds 3): does round 6's choice carry over?
    "transfer_round": ("minibatch_86", "before_lambda_95_q_norm"),
    "minibatch_round": ("minibatch_86", "before_lambda_95_q_norm", "minibatch_86_before", *MINIBATCH_ROUND),
    # MAPPO's and IPPO's own first rounds on simple_spread (--tasks simple_spread): the entry and seven changes
    "mappo_round": (REFERENCE, *(f"{REFERENCE}_{name}" for name in PPO_CHANGES)),
    "ippo_round": ("ippo", *(f"ippo_{name}" for name in PPO_CHANGES)),
    # MAPPO's value normalisation beside the paper's settings and the entry, on three seeds, on
    # simple_spread (--tasks simple_spread --seeds 3) and on simple_reference (--tasks simple_reference)
    "mappo_value_norm_round": (REFERENCE, "mappo_clip_0.1", "mappo_norm_reward"),
    "mappo_reference_value_norm_round": (REFERENCE, "mappo_lr_1e-4", "mappo_norm_reward"),
    # the choice between MAPPO's entry and the two variants ahead of it in its round, on three seeds
    "mappo_choice_round": (REFERENCE, "mappo_epochs_15", "mappo_clip_0.1"),
    # the same choice on Foraging-5x5 (--tasks lbf --seeds 3): the three variants ahead there
    "mappo_foraging_choice_round": (REFERENCE, "mappo_epochs_15", "mappo_lr_7e-4", "mappo_ent_0"),
    # the same choice on simple_reference (--tasks simple_reference --seeds 3) and Foraging-8x8
    # (--tasks lbf_8x8 --seeds 3): the variants ahead of the entry there in MAPPO's round
    "mappo_reference_choice_round": (REFERENCE, "mappo_batch_1024", "mappo_epochs_5", "mappo_lr_1e-4"),
    "mappo_foraging_8x8_choice_round": (REFERENCE, "mappo_lr_7e-4", "mappo_epochs_15"),
    # the choice between IPPO's entry and the variant ahead of it in its round, on three seeds
    "ippo_choice_round": ("ippo", "ippo_epochs_15"),
    # IPPO's share of the other tasks' tuning budget: its round there (--tasks lbf,simple_reference,lbf_8x8
    # --seeds 1), then on three seeds the variants ahead of its entry on each (--tasks <task> --seeds 3)
    "ippo_foraging_choice_round": ("ippo", "ippo_lr_7e-4", "ippo_epochs_15"),
    "ippo_reference_choice_round": ("ippo", "ippo_ent_0", "ippo_lr_7e-4", "ippo_batch_1024"),
    "ippo_foraging_8x8_choice_round": ("ippo", "ippo_lr_7e-4"),
    # simple_spread's entry against its return bootstrapped with V(s), on three seeds (--seeds 3)
    "state_value_round": (
        "before_lambda_95_q_norm",
        *STATE_VALUE_ROUND,
        "before_lambda_95_q_norm_v_baseline",
        REFERENCE,
        "mappo_clip_0.1",
    ),
    # how COMA's trainer steps (round 12), beside the entry and round 11's probe, on three seeds
    "step_round": (
        "before_lambda_95_q_norm",
        "before_lambda_95_q_norm_v_baseline",
        *STEP_ROUND,
        REFERENCE,
        "mappo_clip_0.1",
    ),
    # the actor's step size (round 13), beside the entry and MAPPO, on three seeds (--seeds 3)
    "actor_step_round": ("before_lambda_95_q_norm", *ACTOR_STEP_ROUND, REFERENCE, "mappo_clip_0.1"),
    # round 12's probe with V fitted as SB3's PPO fits MAPPO's (round 14), on three seeds (--seeds 3)
    "value_fit_round": (
        "before_lambda_95_q_norm",
        "before_lambda_95_q_norm_v_baseline_ppo_steps",
        *VALUE_FIT_ROUND,
        REFERENCE,
    ),
    # the entry with MAPPO's actor depth (round 15), on three seeds (--seeds 3)
    "actor_depth_round": ("before_lambda_95_q_norm", *ACTOR_DEPTH_ROUND, REFERENCE, "mappo_pi_64x2"),
    # the entry against round 3's entry (the two best of simple_spread's validation runs on seed 1000 at
    # half the budget; the latter's return dips least early), at the whole budget
    # (--tasks simple_spread_full --seeds 3)
    "whole_budget_round": ("before_lambda_95_q_norm", "rollout_1024_epochs_10_before"),
    # COMA's entry against MAPPO at COMA's actor depth (round 15's twin), at the whole budget
    # (--tasks simple_spread_full --seeds 3): the benchmark's comparison with actors of equal depth
    "whole_budget_depth_round": ("before_lambda_95_q_norm", "mappo_pi_64x2"),
    # a larger entropy bonus for the entry (round 16), on three seeds (--tasks simple_spread --seeds 3)
    "entropy_hold_round": ("before_lambda_95_q_norm", *ENTROPY_HOLD_ROUND, REFERENCE, "mappo_norm_reward"),
    # PopArt and the entry without the time-limit bootstrap (round 17), on three seeds (--seeds 3)
    "scale_round": ("before_lambda_95_q_norm", *SCALE_ROUND, REFERENCE),
    # COMA's share of simple_reference's tuning budget (round 18, --tasks simple_reference --seeds 3):
    # the entry's actor step at MAPPO's choice there (learning rate 1e-4) and at PPO's clip 0.1
    "reference_step_round": (
        "before_lambda_95_q_norm",
        *ACTOR_STEP_ROUND,
        REFERENCE,
        "mappo_lr_1e-4",
    ),
    # the late updates (round 19), at the whole budget: smaller (both learning rates annealed linearly
    # to 0) or three times as many (12 minibatches a rollout, as PPO takes under MAPPO), beside the
    # entry and MAPPO at COMA's depth (--tasks simple_spread_full --seeds 3)
    "late_step_round": (
        "before_lambda_95_q_norm",
        *LATE_STEP_ROUND,
        "minibatch_86_before_lambda_95_q_norm",
        "mappo_pi_64x2",
    ),
    # the critic's clock (round 20), with and without the time-limit bootstrap, beside the entry and
    # round 17's arm without either, on three seeds (--tasks simple_spread --seeds 3)
    "clock_round": (
        "before_lambda_95_q_norm",
        "before_lambda_95_q_norm_no_time_limit_bootstrap",
        "before_lambda_95_q_norm_clock_25",
        "before_lambda_95_q_norm_clock_25_bootstrap",
        REFERENCE,
    ),
    # round 20's clock at the whole budget, where the entry's gap to MAPPO is made by its early fall
    # (--tasks simple_spread_full --seeds 3), beside the entry and MAPPO at COMA's depth
    "clock_whole_budget_round": (
        "before_lambda_95_q_norm",
        "before_lambda_95_q_norm_clock_25",
        "minibatch_86_before_lambda_95_q_norm_clock_25",
        "mappo_pi_64x2",
    ),
    # round 20's entry with MAPPO's actor depth (round 21), at the whole budget (--tasks simple_spread_full
    # --seeds 3), beside the entry and MAPPO at COMA's depth
    "clock_depth_round": ("minibatch_86_before_lambda_95_q_norm_clock_25", *CLOCK_DEPTH_ROUND, "mappo_pi_64x2"),
    # the same third layer on Foraging-5x5's entry (--tasks lbf --seeds 3), beside MAPPO's entry there
    "foraging_depth_round": ("minibatch_86_before_lambda_95_q_norm", *FORAGING_DEPTH_ROUND, "mappo_epochs_15"),
    # the clock on simple_reference's entry (--tasks simple_reference --seeds 3), beside MAPPO's entry
    "reference_clock_round": (
        "before_lambda_95_q_norm_lr_1e-4",
        *REFERENCE_CLOCK_ROUND,
        "mappo_lr_1e-4",
    ),
    # the clock on the Foraging entries (--tasks lbf --seeds 3 flies the first pair, --tasks lbf_8x8 the
    # second), beside MAPPO's entry there
    "foraging_clock_round": (
        "minibatch_86_before_lambda_95_q_norm",
        "minibatch_86_before_lambda_95_q_norm_clock_50",
        "mappo_epochs_15",
    ),
    "foraging_8x8_clock_round": ("minibatch_86_before", "minibatch_86_before_clock_50", "mappo_lr_7e-4"),
    # round 21's third actor layer on simple_reference's entry (--tasks simple_reference --seeds 3) and on
    # Foraging-8x8's (--tasks lbf_8x8 --seeds 3), each beside its entry and MAPPO's entry there
    "reference_depth_round": (
        "before_lambda_95_q_norm_lr_1e-4_clock_25",
        "before_lambda_95_q_norm_lr_1e-4_clock_25_pi_64x3",
        "mappo_lr_1e-4",
    ),
    "foraging_8x8_depth_round": ("minibatch_86_before", "minibatch_86_before_pi_64x3", "mappo_lr_7e-4"),
    # MAPPO's clip on simple_spread's entry (round 23), at the whole budget (--tasks simple_spread_full
    # --seeds 3), beside the entry and MAPPO's own entry (the benchmark's MAPPO until round 26)
    "clock_step_round": (
        "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3",
        *CLOCK_STEP_ROUND,
        "mappo_clip_0.1",
    ),
    # round 23's clip on the other tasks' entries (round 24), each beside its entry and MAPPO's entry there:
    # --tasks simple_reference, lbf and lbf_8x8 (each --seeds 3) fly the three rounds below
    "reference_clip_round": (
        "before_lambda_95_q_norm_lr_1e-4_clock_25",
        "before_lambda_95_q_norm_lr_1e-4_clock_25_clip_0.1",
        "mappo_lr_1e-4",
    ),
    "foraging_clip_round": (
        "minibatch_86_before_lambda_95_q_norm_pi_64x3",
        "minibatch_86_before_lambda_95_q_norm_pi_64x3_clip_0.1",
        "mappo_epochs_15",
    ),
    "foraging_8x8_clip_round": ("minibatch_86_before", "minibatch_86_before_clip_0.1", "mappo_lr_7e-4"),
    # MAPPO's entry with 32 minibatches or 15 epochs (round 25), at the whole budget (--tasks
    # simple_spread_full --seeds 3), beside MAPPO's and COMA's entries
    "mappo_whole_budget_round": (
        "mappo_clip_0.1",
        *MAPPO_WHOLE_BUDGET_ROUND,
        "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.1",
    ),
    # MAPPO's actor step (round 26), at the whole budget (--tasks simple_spread_full --seeds 3)
    "mappo_step_round": (
        "mappo_clip_0.1",
        *MAPPO_STEP_ROUND,
        "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.1",
    ),
    # round 26's smaller clip offered to COMA's entry (round 27), at the whole budget (--tasks
    # simple_spread_full --seeds 3), beside both entries and MAPPO with the same clip
    "small_clip_round": (
        "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.1",
        *SMALL_CLIP_ROUND,
        "mappo_clip_0.1",
        "mappo_clip_0.05",
    ),
    # the PPO learners' share of the budget (round 28), screened on one seed beside their entries: --tasks
    # simple_reference or lbf_8x8 --seeds 1
    "reference_budget_round": budget_arms("simple_reference"),
    "foraging_8x8_budget_round": budget_arms("lbf_8x8"),
    # round 28's first on its seed, beside its entry, on three seeds (round 29): --tasks simple_reference --seeds 3
    "reference_budget_confirm_round": confirm_arms("simple_reference"),
    "foraging_8x8_budget_confirm_round": confirm_arms("lbf_8x8"),  # --tasks lbf_8x8 --seeds 3
    # round 30: each learner's RWARE entry, which no round had flown (--tasks rware_tiny)
    "warehouse_round": WAREHOUSE_ENTRIES,
    "warehouse_screen_round": warehouse_arms(),  # round 31: --tasks rware_tiny (seed 1000)
    "warehouse_confirm_round": warehouse_confirm_arms(),  # round 32: --tasks rware_tiny --seeds 3
    "warehouse_trace_round": warehouse_trace_arms(),  # round 33: --tasks rware_tiny (seed 1000)
    "warehouse_ring_round": warehouse_ring_arms(),  # round 34: --tasks rware_tiny (seed 1000)
    "foraging_budget_round": foraging_budget_arms(),  # round 35: --tasks lbf (seed 1000)
    "warehouse_dueling_round": warehouse_dueling_arms(),  # round 36: --tasks rware_tiny (seed 1000)
    "warehouse_ring_confirm_round": warehouse_ring_confirm_arms(),  # round 37: --tasks rware_tiny --seeds 3
    "foraging_budget_confirm_round": foraging_budget_confirm_arms(),  # round 38: --tasks lbf --seeds 3
    "spread_budget_round": spread_ring_arms(SPREAD_ENTRIES),  # round 39: --tasks simple_spread_full --seeds 3
    "spread_ring_2_round": spread_ring_arms(SPREAD_RING_2_CENTRES),  # round 40: the same
    "spread_ring_3_round": spread_ring_arms(SPREAD_RING_3_CENTRES),  # round 41: the same
    "spread_fill_round": spread_fill_arms(),  # round 42: the same (reported in 0.21.0)
    "foraging_whole_round": foraging_whole_arms(),  # round 43: --tasks lbf_full --seeds 3
    "time_limit_round": (
        *(name for twin in TIME_LIMIT_ROUND for name in (twin.removesuffix("_no_time_limit_bootstrap"), twin)),
        REFERENCE,
    ),
}
#: Joint steps per study run (a third to a half of the benchmark's budget: enough to rank the variants).
STUDY_STEPS = {"simple_spread": 150_000, "lbf": 100_000, "simple_reference": 150_000, "lbf_8x8": 150_000}
#: Study tasks flown at the benchmark's whole budget (key: the task's with this suffix), for a choice
#: between variants that half the budget ranks close: on simple_spread the benchmark's curves of COMA
#: and MAPPO part after 150k joint steps (COMA gains little more, MAPPO keeps rising).
WHOLE_BUDGET_SUFFIX = "_full"
STUDY_STEPS[f"simple_spread{WHOLE_BUDGET_SUFFIX}"] = TASKS["simple_spread"].joint_steps
#: RWARE flies its whole budget: at it, the benchmark's COMA and MAPPO deliver nothing on any reported
#: seed and IPPO's training return only starts to rise in the last third (docs/training.md, round 30).
STUDY_STEPS["rware_tiny"] = TASKS["rware_tiny"].joint_steps
#: Foraging-5x5 at its whole budget (round 43): the reported seeds' one missed episode is at 200k steps.
STUDY_STEPS[f"lbf{WHOLE_BUDGET_SUFFIX}"] = TASKS["lbf"].joint_steps
#: The tasks of rounds 1 and 2 (``--tasks`` default); the others are flown when a round names them.
FIRST_TASKS = ("simple_spread", "lbf")
#: First training seed of the study (validation seeds; the benchmark reports seeds 0, 1, ...).
VALIDATION_TRAIN_SEED = 1000
#: First env seed of the validation episodes (the benchmark's evaluation starts at 100_000).
VALIDATION_EVAL_SEED = 200_000
VALIDATION_EPISODES = 50
#: What the report and the figure read from each run's progress.csv.
DIAGNOSTICS = ("train/explained_variance", "train/advantage_std", "train/entropy", "train/critic_loss")
#: SB3's mean episode return of the last 100 training episodes, per agent row (sampled actions).
TRAINING_RETURN = "rollout/ep_rew_mean"


def _dip(progress: dict[str, np.ndarray]) -> tuple[float, float, float]:
    """The training return at the first update, its lowest over the first half, and at the end:
    a critic that misleads the actor shows as a fall before the rise (docs/training.md)."""
    values = progress[TRAINING_RETURN][np.isfinite(progress[TRAINING_RETURN])]
    if values.size == 0:
        return (float("nan"),) * 3
    return float(values[0]), float(values[: max(1, values.size // 2)].min()), float(values[-1])


def learner_of(variant: str) -> str:
    """Which learner flies ``variant``: ``coma`` or the PPO learner that :data:`PPO_VARIANTS` names."""
    return PPO_VARIANTS[variant][0] if variant in PPO_VARIANTS else "coma"


def ppo_settings(variant: str) -> dict[str, Any]:
    """The constructor arguments (policy included) of a PPO learner's study variant."""
    learner, change = PPO_VARIANTS[variant]
    return {"policy": PPO_POLICIES[learner], **MAPPO_PAPER_MPE, **change}


#: What a whole-budget task's name adds to its benchmark task's name.
WHOLE_BUDGET_LABEL = " (whole budget)"


def study_task(key: str) -> Task:
    """The benchmark's task of a study key, trained for the study's steps; a whole-budget key names
    its task apart (``simple_spread (whole budget)``), so that its table rows and records stay apart."""
    base = TASKS[key.removesuffix(WHOLE_BUDGET_SUFFIX)]
    if key == base.key:
        return dataclasses.replace(base, joint_steps=STUDY_STEPS[key])
    return dataclasses.replace(base, key=key, name=f"{base.name}{WHOLE_BUDGET_LABEL}", joint_steps=STUDY_STEPS[key])


def run_variant(task_key: str, variant: str, seed: int, folder: Path) -> dict[str, Any]:
    """Train one (task, variant, seed), logging SB3's CSV to ``folder``; score it on validation episodes."""
    import torch as th
    from stable_baselines3.common.logger import configure

    from sb3_coma import COMA
    from sb3_coma.app.zoo_marl import preprocess_schedules

    th.set_num_threads(1)
    task = study_task(task_key)
    start = time.perf_counter()
    learner = learner_of(variant)
    if learner != "coma":
        model, venv, recorder = _trainee(learner, task, seed, ppo_settings(variant))
    else:
        from sb3_coma.experiments import coma_probes

        venv, recorder = _vec_env(task, seed, learner)
        algorithm = getattr(coma_probes, PROBES[variant]) if variant in PROBES else COMA
        settings = preprocess_schedules(copy.deepcopy(VARIANTS[variant]))  # "lin_<x>" as the zoo reads it
        model = algorithm("MlpPolicy", venv, seed=seed, device="cpu", **settings)
    model.set_logger(configure(str(folder), ["csv"]))
    model.learn(_joint_to_learn(learner, task, recorder.n_agents))
    venv.close()
    returns = evaluate_team_return(task, learner, model, VALIDATION_EPISODES, seed=VALIDATION_EVAL_SEED)
    return {
        "task": task.name,
        "variant": variant,
        "seed": seed,
        "joint_steps": task.joint_steps,
        "validation_return": float(np.mean(returns)),
        "curve": recorder.episodes[:: max(1, len(recorder.episodes) // 400)],
        "seconds": time.perf_counter() - start,
    }


def _job(args: tuple[str, str, int, str]) -> str:
    task_key, variant, seed, out = args
    name = f"{task_key}-{variant}-{seed}"
    runs = Path(out) / "runs"
    with tempfile.TemporaryDirectory(dir=runs, prefix=f".{name}.") as staging:
        record = run_variant(task_key, variant, seed, Path(staging))
        Path(staging, "progress.csv").replace(runs / f"{name}.csv")
    atomic_write_text(runs / f"{name}.json", json.dumps(record))
    return name


def train_phase(out: Path, tasks: list[str], seeds: int, workers: int, arms: tuple[str, ...] = ARMS) -> None:
    """Every missing (task, variant, seed) record of ``arms``, ``workers`` at a time."""
    runs = out / "runs"
    runs.mkdir(parents=True, exist_ok=True)
    todo = [
        (task, variant, VALIDATION_TRAIN_SEED + k, str(out))
        for k in range(seeds)  # every variant's first seed first: a first picture early
        for task in tasks
        for variant in arms
        if not (runs / f"{task}-{variant}-{VALIDATION_TRAIN_SEED + k}.json").exists()
    ]
    for task, variant, seed, _ in todo:  # staging folders of runs that an interruption cut short
        for stale in runs.glob(f".{task}-{variant}-{seed}.*"):
            shutil.rmtree(stale)
    print(f"train: {len(todo)} runs to do", flush=True)
    with ProcessPoolExecutor(max_workers=workers) as pool:
        for name in pool.map(_job, todo):
            print(f"  done {name}", flush=True)


def _progress(path: Path) -> dict[str, np.ndarray]:
    """A run's progress.csv as columns (steps under ``time/total_timesteps``)."""
    with path.open() as f:
        rows = list(csv.DictReader(f))
    keys = ("time/total_timesteps", TRAINING_RETURN, *DIAGNOSTICS)
    return {k: np.array([float(r[k]) if r.get(k) not in (None, "") else np.nan for r in rows]) for k in keys}


def _late(values: np.ndarray) -> float:
    """The mean over the last tenth of training (diagnostics are noisy update to update)."""
    tail = values[-max(1, len(values) // 10) :]
    return float(np.nanmean(tail)) if np.isfinite(tail).any() else float("nan")


class TableWouldShrink(ValueError):
    """A round's table lists rows whose records this folder does not hold (run records stay out of git)."""


def _rows_without_records(table: Path, records: list[dict[str, Any]]) -> list[tuple[str, str]]:
    """(task, variant) rows of an existing ``table`` that ``records`` cannot write again: a report
    made on another machine is not overwritten by a smaller one."""
    if not table.exists():
        return []
    have = {(r["task"], r["variant"]) for r in records}
    rows = [line.split("|")[1:3] for line in table.read_text().splitlines() if line.startswith("| ")]
    listed = [(task.strip(), variant.strip()) for task, variant in rows if task.strip() not in ("task", "---")]
    return [row for row in listed if row not in have]


def report_phase(out: Path, seeds: int, round_name: str = "study") -> str:
    """``<round>.md`` and ``<round>.png`` from the records in ``out`` of the round's arms and the first
    ``seeds`` validation seeds (the same seeds for every arm, whatever else the folder holds),
    written, not typed."""
    arms = ROUNDS[round_name]
    wanted = range(VALIDATION_TRAIN_SEED, VALIDATION_TRAIN_SEED + seeds)
    records = [json.loads(p.read_text()) for p in sorted((out / "runs").glob("*.json"))]
    records = [r for r in records if r["seed"] in wanted and r["variant"] in arms]
    lost = _rows_without_records(out / f"{round_name}.md", records)
    if lost:
        raise TableWouldShrink(
            f"{out / f'{round_name}.md'} has rows whose records are not in {out / 'runs'} "
            f"(first: {lost[0][0]} / {lost[0][1]}): train them (--phases train) or pass another --out"
        )
    lines = [
        "# Why COMA trails MAPPO: one change at a time",
        "",
        "Generated by `python -m sb3_coma.experiments.coma_study` (do not edit). Every variant is the library's",
        "COMA with the settings its name gives; same tasks, same validation training seeds for every variant",
        f"(from {VALIDATION_TRAIN_SEED}), scored on {VALIDATION_EPISODES} validation episodes (env seeds from "
        f"{VALIDATION_EVAL_SEED}, most likely",
        "actions): nothing here uses the benchmark's reported seeds. Diagnostics: mean over the last tenth of",
        "training of what COMA logs per update (explained variance of the critic's Q against its TD(lambda)",
        "targets, the standard deviation of the counterfactual advantage, the policy's entropy, the critic's loss:",
        "in standardised units for the `q_norm` variants; `-`: not logged by MAPPO). Training return: SB3's mean",
        "return per agent of the last 100 training episodes (sampled actions) at the first update, its lowest over",
        "the first half of training, and at the end. Train minutes: wall time on a machine shared with other jobs,",
        "not a speed figure (docs/marl_benchmark/results.md has those).",
        "",
        "| task | variant | settings | seeds | validation return | per seed | explained variance | advantage std | "
        "entropy | critic loss | training return: first / lowest in first half / last | train minutes |",
        "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for task in sorted({r["task"] for r in records}):
        for variant in arms:
            runs = [r for r in records if r["task"] == task and r["variant"] == variant]
            if not runs:
                continue
            key = next(k for k in STUDY_STEPS if study_task(k).name == task)
            diag = [_progress(out / "runs" / f"{key}-{variant}-{r['seed']}.csv") for r in runs]
            late = {d: np.mean([_late(p[d]) for p in diag]) for d in DIAGNOSTICS}
            finals = [r["validation_return"] for r in runs]
            shown_late = {d: "-" if np.isnan(v) else f"{v:.3g}" for d, v in late.items()}
            dip = " / ".join(f"{np.mean(v):.1f}" for v in zip(*(_dip(p) for p in diag)))
            shown = ", ".join(f"{k}={v}" for k, v in VARIANTS.get(variant, {}).items()) or "defaults"
            if variant in PROBES:
                shown = f"probe, not COMA: {PROBES[variant]} (V_i(s) as the baseline), {shown}"
            learner = learner_of(variant)
            if learner != "coma":
                changed = "".join(f", {k}={v}" for k, v in PPO_VARIANTS[variant][1].items())
                shown = f"not COMA: {learner.upper()} with the MAPPO paper's MPE settings{changed}"
            lines.append(
                f"| {task} | {variant} | {shown} | {len(runs)} | {np.mean(finals):.2f} | "
                f"{', '.join(f'{f:.2f}' for f in finals)} | {shown_late['train/explained_variance']} | "
                f"{shown_late['train/advantage_std']} | {shown_late['train/entropy']} | {shown_late['train/critic_loss']} | "
                f"{dip} | {np.mean([r['seconds'] for r in runs]) / 60:.1f} |"
            )
    text = "\n".join(lines) + "\n"
    atomic_write_text(out / f"{round_name}.md", text)
    if records:
        _plot(records, out, arms, out / f"{round_name}.png")
    return text


def tuning_runs(folder: Path) -> dict[tuple[str, str], int]:
    """Validation runs per (learner, task) that the round tables in ``folder`` report (the tables are in
    git, the run records are not): a variant counts once per task, with the most seeds any table shows."""
    seeds: dict[tuple[str, str], int] = {}
    for table in sorted(folder.glob("*.md")):
        for line in table.read_text().splitlines():
            cells = [cell.strip() for cell in line.split("|")[1:-1]]
            if len(cells) > 3 and cells[3].isdigit() and (cells[1] in VARIANTS or cells[1] in PPO_VARIANTS):
                seeds[(cells[0], cells[1])] = max(seeds.get((cells[0], cells[1]), 0), int(cells[3]))
    runs: dict[tuple[str, str], int] = {}
    for (name, variant), count in seeds.items():
        task = name.removesuffix(WHOLE_BUDGET_LABEL)  # a whole-budget run is a run on its task
        runs[(learner_of(variant), task)] = runs.get((learner_of(variant), task), 0) + count
    return runs


def _plot(records: list[dict[str, Any]], out: Path, arms: tuple[str, ...], figure: Path) -> None:
    """Team return and the diagnostics against joint steps, one row per task, mean over seeds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tasks = sorted({r["task"] for r in records})
    panels = ("team return", *DIAGNOSTICS)
    fig, axes = plt.subplots(len(tasks), len(panels), figsize=(4.2 * len(panels), 3.4 * len(tasks)), squeeze=False)
    colours = plt.get_cmap("tab10")
    for row, task in zip(axes, tasks):
        key = next(k for k in STUDY_STEPS if study_task(k).name == task)
        for i, variant in enumerate(arms):
            runs = [r for r in records if r["task"] == task and r["variant"] == variant]
            if not runs:
                continue
            steps = np.concatenate([[s for s, _ in r["curve"]] for r in runs])
            values = np.concatenate([[v for _, v in r["curve"]] for r in runs])
            order = np.argsort(steps)
            window = max(1, len(order) // 8)  # about 50 of the recorded episodes
            smooth = np.convolve(values[order], np.ones(window) / window, mode="valid")
            colour = "black" if variant == REFERENCE else colours(i)  # tab10 has ten colours, one per variant
            every = max(1, len(smooth) // 100)  # 100 points a line are enough for the eye and keep the file small
            row[0].plot(
                steps[order][window - 1 :: every],
                smooth[::every],
                color=colour,
                label=variant,
                lw=2 if variant == REFERENCE else 1,
            )
            for ax, diag in zip(row[1:], DIAGNOSTICS if learner_of(variant) == "coma" else ()):  # COMA's own logs
                progress = [_progress(out / "runs" / f"{key}-{variant}-{r['seed']}.csv") for r in runs]
                n = min(len(p[diag]) for p in progress)
                with warnings.catch_warnings():  # an update no seed logged (the first row: no update yet) stays NaN
                    warnings.simplefilter("ignore", RuntimeWarning)
                    mean = np.nanmean([p[diag][:n] for p in progress], 0)
                span = max(1, n // 30)  # updates per plotted point: the mean of each span (noisy update to update)
                cut = n - n % span
                ax.plot(
                    progress[0]["time/total_timesteps"][:cut:span],
                    mean[:cut].reshape(-1, span).mean(1),
                    color=colours(i),
                    lw=1,
                )
        for ax, title in zip(row, panels):
            ax.set(title=f"{task}: {title.removeprefix('train/')}", xlabel="joint env steps")
    axes[0][0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    save_palette_png(fig, figure, dpi=72)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    from uav_ipp.config import count_value

    parser = argparse.ArgumentParser(
        prog="python -m sb3_coma.experiments.coma_study", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--out", type=Path, default=Path("docs/coma_study"), help="folder of records, table and figure")
    parser.add_argument("--phases", default="train,report", help="comma-separated: train, report")
    parser.add_argument("--tasks", default=",".join(FIRST_TASKS), help=f"comma-separated of {sorted(STUDY_STEPS)}")
    parser.add_argument("--seeds", type=count_value, default=1, help="validation training seeds per variant")
    parser.add_argument("--workers", type=count_value, default=2, help="runs trained side by side")
    parser.add_argument(
        "--round", default="study", help=f"which table: {', '.join(ROUNDS)} (written as <round>.md and .png)"
    )
    args = parser.parse_args(argv)
    phases, tasks = args.phases.split(","), args.tasks.split(",")
    for name, given, known in (
        ("phase", phases, ("train", "report")),
        ("task", tasks, tuple(STUDY_STEPS)),
        ("round", [args.round], tuple(ROUNDS)),
    ):
        bad = [g for g in given if g not in known]
        if bad:
            print(f"error: unknown {name} {bad[0]!r}; choose from {', '.join(known)}", file=sys.stderr)
            return 2
    args.out.mkdir(parents=True, exist_ok=True)
    if "train" in phases:
        train_phase(args.out, tasks, args.seeds, args.workers, ROUNDS[args.round])
    if "report" in phases:
        try:
            print(report_phase(args.out, args.seeds, args.round))
        except TableWouldShrink as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
