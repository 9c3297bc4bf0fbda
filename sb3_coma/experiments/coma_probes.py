"""Probes of the COMA study: COMA's trainer with one part swapped for MAPPO's, to measure what that
part costs on a task. A probe is not a COMA and not an option of the library; it lives with the
experiment that flies it (docs/training.md, round 11).
"""

from __future__ import annotations

from typing import Any

import torch as th

from sb3_coma import COMA


class StateValueBaselineCOMA(COMA):
    """COMA's trainer with MAPPO's advantage: the TD(lambda) return bootstrapped with the state value
    ``V_i(s)`` minus ``V_i(s)`` itself, where COMA subtracts the counterfactual baseline
    ``sum_u' pi(u'|o_i) Q(s, (u_-i, u'))``. Rollout, critic fitting, actor epochs, clipping and
    entropy bonus stay COMA's, so beside ``advantage="v_return"`` the two runs differ in the baseline
    alone. Needs ``advantage="v_return"`` (which builds ``V``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if kwargs.get("advantage") != "v_return":
            raise ValueError(f"StateValueBaselineCOMA needs advantage='v_return', got {kwargs.get('advantage')!r}")
        super().__init__(*args, **kwargs)
        self._collection_values: th.Tensor | None = None

    def _state_value_returns(self) -> tuple[th.Tensor, th.Tensor] | None:
        scored = super()._state_value_returns()
        self._collection_values = None if scored is None else scored[0]
        return scored

    def _advantages(self, data: dict[str, Any], q_all: th.Tensor, returns: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        _counterfactual, old_log_prob = super()._advantages(data, q_all, returns)
        assert self._collection_values is not None  # train() scores V before the advantages
        return returns - self._collection_values, old_log_prob
