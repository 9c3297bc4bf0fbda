"""IPPO and MAPPO on SB3's own ``PPO``: the learned baselines a user would pick instead of COMA.

:func:`make_ippo` / :func:`make_mappo` take any multi-agent vec env (``sb3_coma.make_marl_vec_env``
or the UAV world's ``uav_ipp.make_vec_env``); :mod:`.central_value` is MAPPO's value function on
the global state for any env, :mod:`.mappo` the UAV world's masked CNN policies and the factories.
Beside :mod:`sb3_coma.coma`, not under it: the two algorithms share only :mod:`sb3_coma.common`.
"""

from sb3_coma.mappo.central_value import KEY_AGENT_ID, CentralStateVecEnv, CentralValuePolicy, KeysExtractor
from sb3_coma.mappo.mappo import (
    DEFAULT_PPO_KWARGS,
    IPPOPolicy,
    MAPPOPolicy,
    MapsExtractor,
    MaskedActorCriticPolicy,
    make_ippo,
    make_mappo,
    missions_of,
    timesteps_for_missions,
)

__all__ = [
    "DEFAULT_PPO_KWARGS",
    "KEY_AGENT_ID",
    "CentralStateVecEnv",
    "CentralValuePolicy",
    "IPPOPolicy",
    "KeysExtractor",
    "MAPPOPolicy",
    "MapsExtractor",
    "MaskedActorCriticPolicy",
    "make_ippo",
    "make_mappo",
    "missions_of",
    "timesteps_for_missions",
]
