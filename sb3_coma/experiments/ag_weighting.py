"""Which entropy weighting AG plans with on each map family, chosen on validation missions only.

AG (``sb3_coma.baselines.AdaptiveGainPlanner``) scores a move by the expected information gain
of its footprint, measured either with ipp-marl's class-weighted entropy (``"class"``) or with the
plain binary entropy (``"plain"``). Neither is better everywhere, so the default is chosen per map
family, the way a user tuning AG would: on *validation* missions. :func:`pick_ag_weighting` flies
both weightings on the same ``split="train"`` missions with env seeds from
:data:`VALIDATION_SEED` (disjoint from the seeds 0..49 that the paper and unseen protocols report
and from the training runs' checkpoint-validation seeds 1000..1019), never on ``split="test"`` nor
on the paper's fixed mission, and picks by a paired test (``sb3_coma.stats.paired``):

1. the weighting with the lower valuable-cell entropy of the global map at 100 % of the budget,
   when the paired difference is significant by the scene-clustered t test (docs/statistics.md);
2. else the one with the higher F1, by the same rule;
3. else (a tie on both) ``"class"``, ipp-marl's choice.

The result is recorded by hand in ``sb3_coma.baselines.adaptive_gain.WEIGHTING_BY_MAP`` with the
command and numbers in a comment; ``sb3-coma ag-weighting`` reruns the measurement.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from sb3_coma.app.roles import AG_WEIGHTING_MISSIONS, AG_WEIGHTING_SEED, AG_WEIGHTING_SPLIT
from sb3_coma.common.numbers import is_whole

#: The picker's validation missions (``sb3_coma.app.roles``, where the report reads them too):
#: first env seed (seeds VALIDATION_SEED .. + n - 1), missions per weighting and map, split.
VALIDATION_SEED = AG_WEIGHTING_SEED
VALIDATION_MISSIONS = AG_WEIGHTING_MISSIONS
VALIDATION_SPLIT = AG_WEIGHTING_SPLIT
#: Keys of ``env_options`` the picker sets itself.
_FIXED = ("split",)

# The evaluation, the paired test and the world's gain module (torch, numba) are imported by
# pick_ag_weighting: ``sb3-coma ag-weighting --help`` reads the constants above without them.


def _at_least(value: object, least: int) -> bool:
    """Whether ``value`` is an integer (not a bool) of at least ``least``."""
    return is_whole(value) and value >= least


def validation_options(noise: str = "moderate", **env_options: Any) -> dict[str, Any]:
    """The env options of the validation missions: ``split="train"`` plus ``noise`` and the rest.

    Takes no ``split`` of its own: the point of the picker is never to look at test missions
    (:func:`pick_ag_weighting` refuses one, naming it, before it gets here)."""
    assert not any(k in env_options for k in _FIXED), sorted(env_options)
    return {**env_options, "split": VALIDATION_SPLIT, "noise": noise}


@dataclass
class WeightingChoice:
    """What :func:`pick_ag_weighting` measured on one map family and what it chose."""

    env: str
    choice: str
    reason: str
    missions: int
    seed: int
    env_options: dict[str, Any]
    #: weighting -> {"f1": mean, "entropy": mean, "team_f1": mean, "team_entropy": mean} at 100 %
    means: dict[str, dict[str, float]] = field(default_factory=dict)
    #: metric -> paired difference "plain" - "class" (``sb3_coma.stats.paired.PairedDifference.as_dict()``)
    paired: dict[str, dict[str, Any]] = field(default_factory=dict)

    def comment(self) -> str:
        """One line for the constant's comment: the numbers behind the choice."""
        m = self.means
        e = self.paired.get("entropy", {})
        f = self.paired.get("f1", {})
        return (
            f"{self.env}: {self.choice!r} ({self.reason}); entropy class {m['class']['entropy']:.4f} / "
            f"plain {m['plain']['entropy']:.4f} (plain - class {e.get('diff', float('nan')):+.4f} ± "
            f"{e.get('se', float('nan')):.4f}), F1 class {m['class']['f1']:.4f} / plain {m['plain']['f1']:.4f} "
            f"(plain - class {f.get('diff', float('nan')):+.4f} ± {f.get('se', float('nan')):.4f}); "
            f"{self.missions} missions, split {self.env_options.get('split')!r}, seeds "
            f"{self.seed}..{self.seed + self.missions - 1}, noise {self.env_options.get('noise')!r}"
        )

    def as_dict(self) -> dict[str, Any]:
        return {
            "env": self.env,
            "choice": self.choice,
            "reason": self.reason,
            "missions": self.missions,
            "seed": self.seed,
            "env_options": dict(self.env_options),
            "means": self.means,
            "paired": self.paired,
        }


def _decide(paired: Mapping[str, Any]) -> tuple[str, str]:
    """(choice, reason) from the paired differences "plain" - "class" (module docstring's rule)."""
    for metric in ("entropy", "f1"):
        d = paired[metric]
        if d.winner is not None:
            winner = "plain" if d.verdict == "plain better" else "class"
            return winner, (
                f"{metric} {winner} better by {abs(d.diff):.4f} ± {d.se_clustered:.4f} (scene-clustered, p {d.p_value:.3g})"
            )
    return "class", "tie on entropy and F1: ipp-marl's class weighting"


def _check_pick_inputs(n_missions: Any, seed: Any, env_options: dict[str, Any]) -> None:
    """One rule, one raise: both counts an integer from its least value, the split the picker's own."""
    fixed = [k for k in _FIXED if k in env_options]
    needs = (
        (_at_least(n_missions, 2), f"n_missions={n_missions!r}: a paired test needs an integer >= 2"),
        (
            _at_least(seed, VALIDATION_SEED),
            f"seed={seed!r}: validation seeds start at {VALIDATION_SEED} (below are the seeds the protocols "
            "and the training's checkpoint validation use)",
        ),
        (
            not fixed,
            f"pick_ag_weighting chooses on split={VALIDATION_SPLIT!r} validation missions; "
            f"do not pass {', '.join(fixed)}= (got {', '.join(repr(env_options[k]) for k in fixed)})",
        ),
    )
    problem = next((message for ok, message in needs if not ok), None)
    if problem is not None:
        raise ValueError(problem)


def pick_ag_weighting(
    name: str,
    n_missions: int = VALIDATION_MISSIONS,
    seed: int = VALIDATION_SEED,
    noise: str = "moderate",
    lookahead: int = 1,
    log: Callable[[str], None] | None = None,
    evaluate: Callable[..., Any] | None = None,
    **env_options: Any,
) -> WeightingChoice:
    """Fly AG with each weighting on the same validation missions of map ``name`` and pick one.

    :param name: map family (``"env1"``, ``"env2"``, ``"env3"``) or anything ``evaluate`` takes
    :param n_missions: validation missions per weighting (>= 2 for a paired test)
    :param seed: first env seed; must be >= :data:`VALIDATION_SEED` so the missions stay disjoint
        from the seeds the protocols report
    :param evaluate: the evaluation function (default ``sb3_coma.common.evaluation.evaluate``; tests pass
        a recorder)
    :param env_options: other env options (``budget``, ``n_uavs`` ...); ``split`` is refused
    """
    from sb3_coma.stats.paired import paired_difference
    from uav_ipp.gain import WEIGHTINGS

    if evaluate is None:
        from sb3_coma.app.evaluation import evaluate as evaluate_method

        evaluate = evaluate_method
    _check_pick_inputs(n_missions, seed, env_options)
    options = validation_options(noise=noise, **env_options)
    results = {}
    for weighting in WEIGHTINGS:
        if log:
            log(
                f"ag weighting {weighting!r} on {name}: {n_missions} validation missions (split "
                f"{options['split']!r}, seeds {seed}..{seed + n_missions - 1}) ..."
            )
        results[weighting] = evaluate(
            "ag",
            env=name,
            n_trials=n_missions,
            seed=seed,
            record=0,
            label=weighting,
            planner_kwargs={"weighting": weighting, "lookahead": lookahead},
            **options,
        )
    means = {
        w: {
            m: float(getattr(r, m)[:, -1].mean())
            for m in ("f1", "entropy", "team_f1", "team_entropy")
            if getattr(r, m, None) is not None
        }
        for w, r in results.items()
    }
    paired = {m: paired_difference(results["plain"], results["class"], m) for m in ("entropy", "f1")}
    choice, reason = _decide(paired)
    return WeightingChoice(
        env=str(name),
        choice=choice,
        reason=reason,
        missions=n_missions,
        seed=seed,
        env_options=options,
        means=means,
        paired={m: d.as_dict() for m, d in paired.items()},
    )
