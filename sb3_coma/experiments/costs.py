"""Deployment cost: the time of one UAV's decision, alone (batch of one) on one CPU thread.

What a UAV computes on board at each step, timed as medians over ``repeats`` calls after a warm-up:

* a trained model: the **fusion** of the maps it received (own map + N - 1 received on the
  44 x 44 comm grid, all valid: the worst case) into its 8th local channel, then the **actor**
  (masked argmax). PyTorch: ``SenDFuseNet.fuse`` (or the naive mean) + the lattice projection, and
  ``model.predict`` on one observation; ONNX Runtime (when ``sb3_coma.app.export`` and onnxruntime
  import): the two graphs ``sb3-coma export`` writes, fusion then actor;
* AG with look-ahead k = 1, 2, 3: ``planner.predict`` on a one-mission vec env divided by the
  number of UAVs (AG plans a team in one call), after a few random moves.

Torch runs with ``torch.set_num_threads(1)`` (restored afterwards), ONNX Runtime with one intra-op
thread; the numba AG kernels are single-threaded. ``benchmarks/decision_latency.py`` is the
stand-alone version of the model rows with a per-node ONNX profile.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

import uav_ipp
from sb3_coma.app.export import export_onnx, onnx_feeds, onnx_session
from sb3_coma.baselines import make_planner
from sb3_coma.baselines.adaptive_gain import default_weighting
from sb3_coma.common.timing import one_thread, time_call, torch_fusion
from uav_ipp import layout


@dataclass(frozen=True)
class CostRow:
    """One line of the cost table: ms per UAV decision (median, 90th percentile)."""

    what: str
    env: str
    backend: str
    ms: float | None
    p90_ms: float | None = None
    note: str = ""

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _observation(
    env: str, fusion: str, seed: int = 0, moves: int = 3, **env_options: Any
) -> tuple[Any, dict[str, np.ndarray]]:
    """A vec env of one mission after a few random moves (every link up), and UAV 0's observation."""

    venv = uav_ipp.make_vec_env(env, n_envs=1, fusion=fusion, seed=seed, comm_range=float("inf"), **env_options)
    obs = venv.reset()
    rng = np.random.default_rng(seed)
    for _ in range(moves):
        assert isinstance(obs, dict)  # the vec envs of uav_ipp.make_vec_env have Dict observations
        actions = np.array([rng.choice(np.flatnonzero(m > 0.5)) for m in obs[layout.KEY_MASK]])
        obs, *_ = venv.step(actions)
    assert isinstance(obs, dict)
    return venv, obs


def model_costs(
    label: str, model: Any, env: str, fusion: str, repeats: int = 200, onnx: bool = True, **env_options: Any
) -> list[CostRow]:
    """PyTorch (and ONNX Runtime) rows of one trained model (module docstring)."""

    venv, obs = _observation(env, fusion, **env_options)
    config = venv.get_attr("config", indices=[0])[0]
    venv.close()
    keys = list(getattr(model.policy.observation_space, "spaces", obs).keys())
    one = {k: np.ascontiguousarray(obs[k][:1]) for k in keys if k in obs}
    n, comm, lattice = int(config.n_uavs), int(config.comm_grid), int(config.lattice)
    rows = []
    with one_thread():
        fuse = torch_fusion(fusion, n, comm, lattice)
        fusion_ms = time_call(fuse, repeats)
        actor_ms = time_call(lambda: model.predict(one, deterministic=True), repeats)

        def both() -> Any:
            fuse()
            return model.predict(one, deterministic=True)

        total = time_call(both, repeats)
    rows += [
        CostRow(f"{label}: fusion ({fusion})", env, "PyTorch", *fusion_ms),
        CostRow(f"{label}: actor (model.predict)", env, "PyTorch", *actor_ms),
        CostRow(f"{label}: fusion + actor", env, "PyTorch", *total),
    ]
    if not onnx:
        return rows
    try:
        with tempfile.TemporaryDirectory(prefix="sb3_coma_cost_") as folder:
            paths = export_onnx(model, Path(folder), fusion=fusion, verify=False)
            actor, fusion_s = onnx_session(paths["actor"]), onnx_session(paths["fusion"])
        rng = np.random.default_rng(0)
        fusion_feeds = {
            "received": rng.random((1, n, comm, comm), dtype=np.float32),
            "received_valid": np.ones((1, n), dtype=np.float32),
        }
        fusion_feeds = onnx_feeds(fusion_s, fusion_feeds)
        raw_local = one[layout.KEY_LOCAL][:, :-1].astype(np.float32)
        actor_feeds = onnx_feeds(actor, one)

        def ort_both() -> Any:
            _, channel = fusion_s.run(None, fusion_feeds)
            local = np.concatenate([raw_local, channel[:, None].astype(np.float32)], axis=1)
            return actor.run(None, {**actor_feeds, "local": local.astype(actor_feeds["local"].dtype)})

        rows += [
            CostRow(
                f"{label}: fusion ({fusion})",
                env,
                "ONNX Runtime",
                *time_call(lambda: fusion_s.run(None, fusion_feeds), repeats),
            ),
            CostRow(f"{label}: actor", env, "ONNX Runtime", *time_call(lambda: actor.run(None, actor_feeds), repeats)),
            CostRow(f"{label}: fusion + actor", env, "ONNX Runtime", *time_call(ort_both, repeats)),
        ]
    except Exception as exc:  # onnx / onnxruntime missing or an export failure: say so, keep the table
        rows.append(
            CostRow(
                f"{label}: fusion + actor",
                env,
                "ONNX Runtime",
                None,
                None,
                f"unavailable ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})",
            )
        )
    return rows


def ag_cost(
    env: str, lookahead: int = 1, weighting: str | None = None, repeats: int = 50, **env_options: Any
) -> CostRow:
    """AG's ms per UAV decision with ``lookahead`` (default weighting: the map family's)."""

    venv, obs = _observation(env, "mean", **env_options)
    weighting = weighting or default_weighting(venv.get_attr("config", indices=[0])[0].map_name)
    planner = make_planner("ag", venv, seed=0, lookahead=lookahead, weighting=weighting)
    n = int(venv.n_agents)
    median, p90 = time_call(lambda: planner.predict(obs, deterministic=True), repeats, warmup=3)
    venv.close()
    label = "AG" if lookahead == 1 else f"AG, look-ahead k={lookahead}"
    return CostRow(f"{label} ({weighting})", env, "numba", median / n, p90 / n)


def decision_costs(
    models: Mapping[str, tuple[Any, ...]],
    envs: Sequence[str] = ("env3",),
    lookaheads: Sequence[int] = (1, 2, 3),
    repeats: int = 200,
    log: Callable[[str], None] | None = None,
    onnx: bool = True,
    **env_options: Any,
) -> list[CostRow]:
    """The cost table: ``models`` maps a label to ``(model, fusion)`` or ``(model, fusion, env)``
    (timed on that env, default ``envs[0]``), then AG for every look-ahead on every map of ``envs``."""
    rows: list[CostRow] = []
    for label, (model, fusion, *where) in models.items():
        if log:
            log(f"cost: {label} (PyTorch{', ONNX' if onnx else ''}) ...")
        rows += model_costs(
            label, model, where[0] if where else envs[0], fusion, repeats=repeats, onnx=onnx, **env_options
        )
    for env in envs:
        for k in lookaheads:
            if log:
                log(f"cost: AG k={k} on {env} ...")
            rows.append(ag_cost(env, k, repeats=max(repeats // 4, 5), **env_options))
    return rows


def costs_markdown(rows: Sequence[CostRow]) -> str:
    lines = [
        "| What | Env | Backend | ms per UAV decision (median) | p90 (ms) | note |",
        "| --- | --- | --- | ---: | ---: | --- |",
    ]
    for r in rows:
        ms = "n/a" if r.ms is None else f"{r.ms:.3f}"
        p90 = "" if r.p90_ms is None else f"{r.p90_ms:.3f}"
        lines.append(f"| {r.what} | {r.env} | {r.backend} | {ms} | {p90} | {r.note} |")
    return "\n".join(lines) + "\n"
