"""Non-learned planners with the same ``predict`` interface as a trained COMA model.

``make_planner(name, venv, seed=..., **kwargs)`` builds one of :data:`PLANNERS`:

* ``random``: uniform over valid actions;
* ``lawnmower``: the paper's NL, a non-adaptive boustrophedon strip sweep;
* ``ag``: adaptive gain, greedy (or ``lookahead=k`` steps) expected information gain from each
  UAV's own belief, with a discount on cells that other UAVs are about to cover; ``knowledge``
  says what a UAV knows of its teammates (``shared`` positions, ``comm`` only, or ``central``:
  one planner over the global belief, an upper reference);
* ``oracle``: clairvoyant greedy planner that knows the ground truth (the upper reference).
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from .adaptive_gain import AdaptiveGainPlanner, plan_team
from .base import Planner
from .lawnmower import LawnmowerPlanner
from .oracle import OraclePlanner
from .random_planner import RandomPlanner

PLANNERS: dict[str, type[Planner]] = {
    RandomPlanner.name: RandomPlanner,
    LawnmowerPlanner.name: LawnmowerPlanner,
    AdaptiveGainPlanner.name: AdaptiveGainPlanner,
    OraclePlanner.name: OraclePlanner,
}
#: Other spellings users reach for (the paper's labels).
ALIASES: dict[str, str] = {"nl": "lawnmower", "adaptive_gain": "ag", "adaptive-gain": "ag"}


def planner_class(name: str) -> type[Planner]:
    """The planner class of a name or alias; ``ValueError`` listing the choices otherwise."""
    key = str(name).strip().lower()
    key = ALIASES.get(key, key)
    if key not in PLANNERS:
        raise ValueError(f"unknown baseline {name!r}; choose one of {sorted(PLANNERS)}")
    return PLANNERS[key]


def make_planner(name: str, venv: VecEnv, seed: int | None = None, **kwargs: Any) -> Planner:
    """Build the named planner for ``venv`` (an ``uav_ipp.make_vec_env`` vec env)."""
    cls = planner_class(name)
    try:
        return cls(venv, seed=seed, **kwargs)
    except TypeError as exc:
        if "unexpected keyword" in str(exc):
            raise ValueError(f"baseline {cls.name!r}: {exc}") from None
        raise


__all__ = [
    "ALIASES",
    "PLANNERS",
    "AdaptiveGainPlanner",
    "LawnmowerPlanner",
    "OraclePlanner",
    "Planner",
    "RandomPlanner",
    "make_planner",
    "plan_team",
    "planner_class",
]
