"""COMA for Stable-Baselines3: the algorithm, its generic policies, joint-step buffer and targets.

Nothing here knows a world: the UAV world's policies live in :mod:`sb3_coma.uav` and reach
``COMA("CBAMPolicy", ...)`` through the ``sb3_coma.policies`` entry points (:mod:`.plugins`).
"""

from sb3_coma.coma.buffer import JointRolloutBuffer
from sb3_coma.coma.coma import COMA
from sb3_coma.coma.policies import CnnPolicy, COMAPolicy, MlpPolicy, MultiInputPolicy
from sb3_coma.coma.targets import counterfactual_advantage, counterfactual_baseline, td_lambda_targets

__all__ = [
    "COMA",
    "COMAPolicy",
    "CnnPolicy",
    "JointRolloutBuffer",
    "MlpPolicy",
    "MultiInputPolicy",
    "counterfactual_advantage",
    "counterfactual_baseline",
    "td_lambda_targets",
]
