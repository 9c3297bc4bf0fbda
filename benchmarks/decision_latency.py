"""Per-decision latency on one core: PyTorch vs ONNX Runtime, actor alone and actor + fusion, and AG.

Run: ``python benchmarks/decision_latency.py [--model env3] [--repeats 500] [--profile]``

One decision is one UAV alone (batch of one), as on board: its fusion of the maps it received
(4 UAVs: its own map + 3 received, all valid, the worst case) into the 8th local channel, then
the actor's masked argmax. Torch runs on one thread (``torch.set_num_threads(1)``), ONNX Runtime
with ``intra_op_num_threads=1``. Rows:

* PyTorch actor: the policy's actor + masking as a module call (what ``actor.onnx`` holds);
  ``model.predict`` adds SB3's observation handling on top;
* PyTorch actor + SenDFuse: ``SenDFuseNet.fuse`` + lattice projection + the actor;
* ONNX Runtime actor, and ONNX Runtime fusion + actor (``sb3-coma export``'s two files);
* AG: ``planner.predict(obs)`` on a 1-copy vec env divided by the number of UAVs (AG plans all
  UAVs of a team in one call), timed in a child process: a planner that fails, even one that
  crashes the interpreter, is reported as "AG: unavailable (reason)".

Figures are medians over ``--repeats`` calls after a warm-up (wall and thread-CPU time: on a
shared machine other processes inflate wall time, the thread's CPU time much less). No timing is
asserted. ``--profile`` adds ONNX Runtime's per-node profile of the fusion graph, grouped by
network stage and by operator, to show where its time goes.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime
import torch

import uav_ipp
from sb3_coma import COMA, load_pretrained
from sb3_coma.app.export import ActorGraph, export_onnx, fusion_wrapper, onnx_feeds, onnx_session
from sb3_coma.sendfuse.network import tune_cpu_allocator
from uav_ipp import layout
from uav_ipp.geometry import overlap_matrix


def _model(name: str) -> tuple[Any, str]:
    """The shipped model (real weights, gain prior), else a fresh SenDFuse CBAM model of the same size."""
    try:
        return load_pretrained(name), f"shipped model {name!r}"
    except Exception as exc:  # any failure: the cost does not depend on the weights
        venv = uav_ipp.make_vec_env("env3", n_envs=1, fusion="sendfuse", seed=0)
        return COMA("CBAMPolicy", venv, seed=0, device="cpu"), f"fresh CBAM model ({type(exc).__name__}: {exc})"


def _one_decision(env: str, seed: int = 0) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], Any]:
    """UAV 0's raw and fused observation after a few random steps with every link up (comm_range inf)."""
    raw_env = uav_ipp.make_vec_env(env, n_envs=1, fusion="none", seed=seed, comm_range=float("inf"))
    rng = np.random.default_rng(seed)
    obs = raw_env.reset()
    for _ in range(5):
        obs, *_ = raw_env.step(np.array([rng.choice(np.flatnonzero(m > 0.5)) for m in obs[layout.KEY_MASK]]))
    raw_env.close()
    raw = {k: np.ascontiguousarray(v[:1]) for k, v in obs.items()}
    fused_env = uav_ipp.make_vec_env(env, n_envs=1, fusion="sendfuse", seed=seed, comm_range=float("inf"))
    wrapper = fusion_wrapper(fused_env)
    return raw, wrapper.observations(dict(raw)), wrapper


def _time(fn: Callable[[], Any], repeats: int, warmup: int = 30) -> tuple[float, float, float, float]:
    """(median, p10, p90 wall ms, median thread-CPU ms) of ``fn``."""
    for _ in range(warmup):
        fn()
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.thread_time()
        fn()
        cpu.append((time.thread_time() - c0) * 1e3)
        wall.append((time.perf_counter() - w0) * 1e3)
    wall.sort()
    return statistics.median(wall), wall[len(wall) // 10], wall[len(wall) * 9 // 10], statistics.median(cpu)


def _row(label: str, t: tuple[float, float, float, float]) -> None:
    print(f"{label:<44} {t[0]:>8.3f} {t[1]:>8.3f} {t[2]:>8.3f} {t[3]:>9.3f}")


def _ag_in_process(env: str, repeats: int) -> None:
    """AG's time per UAV decision, or why it cannot be timed in this checkout."""
    try:
        # imported here, inside the guard: a planner mid-change costs this row, not the benchmark
        from sb3_coma.baselines import make_planner

        venv = uav_ipp.make_vec_env(env, n_envs=1, fusion="mean", seed=0)
        planner = make_planner("ag", venv, seed=0)
        obs = venv.reset()
        n = int(venv.get_attr("n_agents", indices=[0])[0])
        t = _time(lambda: planner.predict(obs, deterministic=True), max(repeats // 5, 20), warmup=5)
        venv.close()
        _row(f"AG (planner.predict / {n} UAVs)", (t[0] / n, t[1] / n, t[2] / n, t[3] / n))
    except Exception as exc:  # the planner API may be in flux; report, do not fail
        print(f"AG: unavailable ({type(exc).__name__}: {exc})")


def _ag(env: str, repeats: int) -> None:
    """:func:`_ag_in_process` in a child process, so that even a planner that crashes the
    interpreter (a numba kernel mid-change) costs this benchmark one line, not its results."""
    argv = [sys.executable, str(Path(__file__).resolve()), "--ag-only", "--env", env, "--repeats", str(repeats)]
    try:
        done = subprocess.run(argv, capture_output=True, text=True, timeout=600)
    except subprocess.TimeoutExpired:
        print("AG: unavailable (no answer within 600 s)")
        return
    lines = done.stdout.strip().splitlines()
    if done.returncode == 0 and lines:
        print(lines[-1])
        return
    why = f"signal {-done.returncode}" if done.returncode < 0 else f"exit status {done.returncode}"
    last = (done.stderr.strip().splitlines() or [""])[-1]
    print(f"AG: unavailable (the planner's process ended with {why}{': ' + last if last else ''})")


def _stage(node: str) -> str:
    """The module a graph node came from (``enc1``, ``dec1_2``, ``cnn.2`` ...); nodes traced from
    plain functions (pooling, the attention fusion, upsampling, masks) carry no module scope."""
    parts = [p for p in node.removeprefix("fused ").split("/") if p]  # ORT's fused nodes keep the first name
    if len(parts) < 2:
        return "no module (pool, attention, upsample, masks, layout)"
    parts = [p for p in parts[:-1] if p not in ("actor", "features_extractor", "cnn")] or parts[:1]
    return parts[0]


def _profile(path: Path, feeds: dict[str, np.ndarray], repeats: int) -> None:
    """ONNX Runtime's own per-node timing of ``path``, summed by network stage and by operator."""
    options = onnxruntime.SessionOptions()
    options.intra_op_num_threads = 1
    options.inter_op_num_threads = 1
    options.enable_profiling = True
    options.profile_file_prefix = str(path.with_suffix(""))
    session = onnxruntime.InferenceSession(str(path), sess_options=options, providers=["CPUExecutionProvider"])
    for _ in range(repeats):
        session.run(None, feeds)
    events = json.loads(Path(session.end_profiling()).read_text())
    by_stage: dict[str, float] = defaultdict(float)
    by_op: dict[str, float] = defaultdict(float)
    for e in events:
        if e.get("cat") != "Node" or not e.get("name", "").endswith("_kernel_time"):
            continue
        by_stage[_stage(e["name"][: -len("_kernel_time")])] += e["dur"] / 1e3 / repeats
        by_op[e["args"].get("op_name", "?")] += e["dur"] / 1e3 / repeats
    total = sum(by_op.values())
    nodes = sum(1 for e in events if e.get("cat") == "Node" and e.get("name", "").endswith("_kernel_time")) // repeats
    print(
        f"\nONNX Runtime profile of {path.name}: {nodes} kernels, {total:.3f} ms of kernel time per call "
        "(profiling itself adds time)"
    )
    for title, table in (("by stage", by_stage), ("by operator", by_op)):
        print(
            f"  {title}: "
            + ", ".join(
                f"{k} {v:.3f} ms ({100 * v / total:.0f}%)" for k, v in sorted(table.items(), key=lambda kv: -kv[1])[:8]
            )
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="env3", help="shipped model name (default env3)")
    parser.add_argument("--env", default="env3", help="map the observation comes from")
    parser.add_argument("--repeats", type=int, default=500)
    parser.add_argument("--profile", action="store_true", help="ONNX Runtime per-node profile of the fusion")
    parser.add_argument("--tune-malloc", action="store_true", help="sendfuse.network.tune_cpu_allocator() first")
    parser.add_argument("--ag-only", action="store_true", help=argparse.SUPPRESS)  # the AG child process
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    if args.ag_only:
        _ag_in_process(args.env, args.repeats)
        return 0
    with tempfile.TemporaryDirectory(prefix="decision_latency_") as folder:
        return _run(args, Path(folder))


def _run(args: argparse.Namespace, out: Path) -> int:
    """Export the model into ``out``, time every row, print the table (and the profiles)."""
    if args.tune_malloc:
        tune_cpu_allocator()
    model, which = _model(args.model)
    raw, obs, wrapper = _one_decision(args.env)
    paths = export_onnx(model, out, fusion="sendfuse")
    actor_session, fusion_session = onnx_session(paths["actor"]), onnx_session(paths["fusion"])
    actor_names = [i.name for i in actor_session.get_inputs()]

    actor = ActorGraph(model.policy.actor).eval()
    t_obs = {k: torch.from_numpy(v) for k, v in obs.items()}
    t_raw_local = torch.from_numpy(raw[layout.KEY_LOCAL])
    t_received = torch.from_numpy(raw[layout.KEY_RECEIVED])
    t_valid = torch.from_numpy(raw[layout.KEY_RECEIVED_VALID] > 0.5)
    network, alpha = wrapper.network, wrapper.alpha
    # the fused map's projection onto the lattice, built as FusionWrapper builds it
    comm, lattice = raw[layout.KEY_RECEIVED].shape[-1], raw[layout.KEY_LOCAL].shape[-1]
    to_lattice = torch.from_numpy(overlap_matrix(comm, float(lattice - 1), lattice))
    rest = [t_obs[k] for k in actor_names[1:]]

    def torch_actor() -> Any:
        with torch.inference_mode():
            return actor(t_obs[layout.KEY_LOCAL], *rest)

    def torch_fusion() -> torch.Tensor:
        with torch.inference_mode():
            fused = network.fuse(t_received, t_valid, alpha=alpha)
            return torch.clamp(to_lattice @ fused @ to_lattice.T, 0.0, 1.0)

    def torch_both() -> Any:
        with torch.inference_mode():
            local = torch.cat([t_raw_local, torch_fusion()[:, None]], dim=1)
            return actor(local, *rest)

    actor_feeds = onnx_feeds(actor_session, obs)  # in the dtypes the model was trained with
    fusion_feeds = {"received": raw[layout.KEY_RECEIVED], "received_valid": raw[layout.KEY_RECEIVED_VALID]}

    def ort_both() -> Any:
        _, channel = fusion_session.run(None, fusion_feeds)
        local = np.concatenate([raw[layout.KEY_LOCAL], channel[:, None]], axis=1)
        return actor_session.run(None, {**actor_feeds, "local": local})

    # the timed pipelines decide alike
    want = int(model.predict(obs, deterministic=True)[0][0])
    assert int(ort_both()[1][0]) == want == int(torch_both()[1][0])
    np.testing.assert_allclose(ort_both()[0], torch_both()[0].numpy(), atol=1e-4)

    n_valid = int(raw[layout.KEY_RECEIVED_VALID].sum())
    print(
        f"{which}; one UAV of {args.env} (own map + {n_valid - 1} received, all valid), 1 thread, "
        f"{args.repeats} calls; torch {torch.__version__}, onnxruntime {onnxruntime.__version__}"
    )
    print(f"{'per decision (ms)':<44} {'median':>8} {'p10':>8} {'p90':>8} {'CPU med':>9}")
    _row("PyTorch actor (module call)", _time(torch_actor, args.repeats))
    _row("PyTorch actor (model.predict)", _time(lambda: model.predict(obs, deterministic=True), args.repeats))
    _row("PyTorch SenDFuse fusion", _time(torch_fusion, args.repeats))
    _row("PyTorch actor + SenDFuse fusion", _time(torch_both, args.repeats))
    _row("ONNX Runtime actor", _time(lambda: actor_session.run(None, actor_feeds), args.repeats))
    _row("ONNX Runtime SenDFuse fusion", _time(lambda: fusion_session.run(None, fusion_feeds), args.repeats))
    _row("ONNX Runtime actor + SenDFuse fusion", _time(ort_both, args.repeats))
    _ag(args.env, args.repeats)
    if args.profile:
        _profile(paths["fusion"], fusion_feeds, args.repeats)
        _profile(paths["actor"], actor_feeds, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
