"""COMA for Stable-Baselines3: the algorithm, its policies, joint-step buffer and targets."""

from sb3_coma.coma.buffer import JointRolloutBuffer
from sb3_coma.coma.coma import COMA
from sb3_coma.coma.policies import CBAMPolicy, CnnPolicy, COMAPolicy, critic_input, other_actions_map
from sb3_coma.coma.targets import counterfactual_advantage, counterfactual_baseline, td_lambda_targets

__all__ = [
    "COMA",
    "CBAMPolicy",
    "COMAPolicy",
    "CnnPolicy",
    "JointRolloutBuffer",
    "counterfactual_advantage",
    "counterfactual_baseline",
    "critic_input",
    "other_actions_map",
    "td_lambda_targets",
]
