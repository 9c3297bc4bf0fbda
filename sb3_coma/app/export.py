"""ONNX export of a trained COMA model for on-board use: the actor and the fusion network.

A UAV flying a trained model needs two things at each decision, and nothing else of the
training stack (no SB3, no critic, no env):

1. the **fusion** that turns the maps it received over the channel into the 8th channel of its
   local observation (``uav_ipp.fusion``: SenDFuse or the naive mean, then the projection from the
   communication grid to the 11 x 11 lattice);
2. the **actor**: CBAM/CNN trunk + action head (+ the gain prior when the model has one), with
   invalid actions masked, and the argmax.

:func:`export_onnx` writes both as ONNX graphs plus a JSON file that names every input and
output (shape, dtype, meaning) and records the environment options the model was trained with,
because an actor is only valid on observations built with those options (number of UAVs,
communication grid, noise, fusion). Deployment, per UAV and step::

    fused = fusion.run(None, {"received": r, "received_valid": v})   # fused_channel (1, 11, 11)
    local = concat(raw_local (1, 7, 11, 11), fused_channel[:, None])  # (1, 8, 11, 11)
    # observation v3: concat(raw_local[:, :7], fused_channel[:, None], raw_local[:, 7:])  (1, 41, 11, 11)
    logits, action = actor.run(None, {"local": local, "action_mask": m[, "action_gain": g]})

**The argmax is inside the actor graph** (output ``action``, int64), next to the masked logits
(output ``logits``: invalid actions set to ``MASKED_LOGIT``, as in
:func:`sb3_coma.common.masking.mask_logits`), so ``action`` is what
``model.predict(obs, deterministic=True)`` returns and a caller that wants to sample takes
``softmax(logits)`` itself. The graphs are built from the model's own modules and masking
functions (not re-implementations), which is why the two agree; ``tests/test_export.py`` checks
it on recorded observations of env1-env3.

The fusion graph is a branch-free form of :meth:`SenDFuseNet.fuse
<sb3_coma.sendfuse.network.SenDFuseNet.fuse>`: PyTorch's version skips empty slots with
data-dependent indexing, which an ONNX graph of fixed shape cannot do, so here every received
slot is encoded and empty ones get fusion weight exactly 0 (same values up to float rounding;
worst-case cost always, which is what an on-board budget has to plan for anyway).

The legacy TorchScript exporter is used (``dynamo=False``): the dynamo exporter needs
``onnxscript`` and gains nothing for these small static graphs.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import torch as th
from torch import nn

from sb3_coma import __version__
from sb3_coma.app.config import TrainingError, load_config, path_name_problem
from sb3_coma.app.methods import is_unknown_name, resolve_method
from sb3_coma.app.pretrained import available, pretrained_dir, sha256_file
from sb3_coma.app.runs import read_run_config, run_folder_of
from sb3_coma.common.checkpoints import training_options
from sb3_coma.common.masking import MASKED_LOGIT, mask_logits
from sb3_coma.common.numbers import is_whole
from sb3_coma.sendfuse.network import UNKNOWN, SenDFuseNet
from sb3_coma.sendfuse.weights import default_weights_path, load_weights
from uav_ipp import IppConfig, layout
from uav_ipp.fusion import FusionWrapper, mean_fusion
from uav_ipp.geometry import overlap_matrix

ACTOR_FILE = "actor.onnx"
FUSION_FILE = "fusion.onnx"
METADATA_FILE = "export.json"
#: Default ONNX opset; the issue asks for >= 17 (LayerNorm-era ops, onnxruntime >= 1.14).
OPSET = 17
MIN_OPSET = 17
FUSIONS = ("mean", "sendfuse")
#: Version of the JSON layout below, so an on-board reader can refuse one it does not know.
METADATA_FORMAT = 1
#: Name of the dynamic leading dimension in the JSON shapes.
BATCH = "batch"
#: Logit of invalid slots inside the fusion's softmaxes. PyTorch uses -inf; a finite value gives
#: the same exact zeros whenever a slot is valid and stays finite (uniform) for a row with no
#: valid received map, whose result is then multiplied by zero instead of turning into NaN.
_FUSION_MASKED = -1.0e30


class ExportError(ValueError):
    """An export input the user can fix: unknown model, unusable output folder, unknown fusion."""


# =========================================================================== the graphs
class ActorGraph(nn.Module):
    """What ``actor.onnx`` computes: ``(local, action_mask[, action_gain]) -> (logits, action)``.

    Wraps the policy's own ``_Actor`` and :func:`mask_logits`, so the graph is the policy's
    deterministic ``predict`` path and nothing else.
    """

    def __init__(self, actor: nn.Module) -> None:
        super().__init__()
        self.actor = actor
        #: The actor reads ``action_gain`` (a gain prior or ``gain_inputs``).
        self.with_prior = bool(getattr(actor, "reads_gain", False))

    def forward(
        self, local: th.Tensor, action_mask: th.Tensor, action_gain: th.Tensor | None = None
    ) -> tuple[th.Tensor, th.Tensor]:
        # Inputs keep the dtypes of the model's observation space (e.g. an int8 mask) and are
        # cast here, as COMAPolicy._predict casts them.
        prior = action_gain.float() if (self.with_prior and action_gain is not None) else None
        logits = mask_logits(self.actor(local.float(), prior), action_mask.float())
        return logits, logits.argmax(dim=-1)


class FusionGraph(nn.Module):
    """What ``fusion.onnx`` computes: ``(received, received_valid) -> (fused, fused_channel)``.

    ``fused`` is the comm-grid map (``FusionWrapper.fuse``), ``fused_channel`` the 8th local
    channel the actor reads (``FusionWrapper.observations``: ``clip(A fused A^T, 0, 1)``).
    ``network=None`` is the naive mean; otherwise the SenDFuse network, fused at ``alpha``.
    """

    to_lattice: th.Tensor  # a registered buffer

    def __init__(
        self, network: SenDFuseNet | None, n_sources: int, to_lattice: np.ndarray, alpha: float | None = None
    ) -> None:
        super().__init__()
        self.network = network
        self.n_sources = int(n_sources)
        self.alpha = float(alpha) if alpha is not None else float(getattr(network, "fusion_alpha", 0.5))
        self.register_buffer("to_lattice", th.as_tensor(np.asarray(to_lattice, dtype=np.float32)))

    def forward(self, received: th.Tensor, received_valid: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        fused = self.fused_map(received, received_valid)
        a = self.to_lattice
        channel = th.clamp(th.matmul(th.matmul(a, fused), a.t()), 0.0, 1.0)
        return fused, channel

    def fused_map(self, received: th.Tensor, received_valid: th.Tensor) -> th.Tensor:
        """``(B, n, R, R), (B, n) -> (B, R, R)``: :func:`uav_ipp.fusion.mean_fusion` or ``SenDFuseNet.fuse``."""
        mask = received_valid > 0.5
        maps = th.where(mask[:, :, None, None], received, th.zeros_like(received))
        count = th.clamp(mask.to(maps.dtype).sum(dim=1), min=1.0)[:, None, None]
        total = maps.sum(dim=1)
        if self.network is None:
            return total / count
        if self.n_sources == 1:
            return th.clamp(total / count, 0.0, 1.0)
        rec, rmask = maps[:, 1:], mask[:, 1:]
        m, r = self.n_sources - 1, rec.shape[-1]
        features = self.network.encode(rec.reshape(-1, 1, r, r))
        fused = [self._fuse_scale(f.reshape(-1, m, *f.shape[1:]), rmask) for f in features]
        correction = self.network.decode(fused)[:, 0]
        observed = (rec != UNKNOWN) & rmask[:, :, None, None]
        weight = observed.to(maps.dtype).sum(dim=1)  # m(p): received maps holding data at p
        return th.clamp((total + weight * correction) / count, 0.0, 1.0)

    def _fuse_scale(self, features: th.Tensor, mask: th.Tensor) -> th.Tensor:
        """:func:`sb3_coma.sendfuse.network.fusion_strategy` on post-ReLU features ``(B, m, C, H, W)``."""
        channel = features.mean(dim=(3, 4)).masked_fill(~mask[:, :, None], _FUSION_MASKED)
        spatial = features.sum(dim=2).masked_fill(~mask[:, :, None, None], _FUSION_MASKED)  # L1: features >= 0
        weights = (
            self.alpha * th.softmax(channel, dim=1)[:, :, :, None, None]
            + (1.0 - self.alpha) * th.softmax(spatial, dim=1)[:, :, None]
        )
        return (weights * features).sum(dim=1)


# =========================================================================== what to export
@dataclass(frozen=True)
class ModelSource:
    """Where a model given by name or path comes from (resolved before anything is loaded)."""

    given: str
    path: Path
    #: manifest entry of a shipped model (``models.json``), else ``None``
    shipped: dict[str, Any] | None = None
    #: ``sb3-coma train`` run folder holding the zip (its ``config.yml``), else ``None``
    run_dir: Path | None = None


def resolve_model_source(name_or_path: str | os.PathLike[str]) -> ModelSource:
    """A model zip path or a shipped model name -> :class:`ModelSource`, with errors naming the value."""
    text = os.fspath(name_or_path)
    problem = path_name_problem(text)  # an empty name, or one that is not text
    method = None
    if problem is None:
        try:  # the evaluation's resolver: a shipped name means the verified package file, as there
            method = resolve_method(text)
        except (ValueError, OSError) as exc:  # a folder, a missing file, a checksum mismatch, not a COMA zip
            available_models = ", ".join(available()) or "none"
            unknown = (
                f"unknown model {text!r}: not a model file and not a shipped model (available: {available_models})"
            )
            problem = unknown if is_unknown_name(text) else str(exc)
    if method is not None and method.source == "planner":
        problem = f"model {text!r} is a baseline planner, not a trained model"
    if method is None or problem is not None:  # one rule: a trained model's file or shipped name
        raise ExportError(f"--model {text!r}: {problem}; pass a COMA model .zip or a shipped model name")
    assert method.path is not None  # a name or a path resolves to a file
    if method.source == "shipped":
        return ModelSource(text, method.path, dict(method.shipped), None)
    return ModelSource(text, method.path, None, run_folder_of(method.path))


def check_out_dir(out_dir: str | os.PathLike[str]) -> Path:
    """The output folder, checked before any work: not a file, and creatable / writable."""
    out = Path(out_dir)
    probe = out
    while not probe.exists() and probe.parent != probe:  # the nearest existing ancestor: where it is made
        probe = probe.parent
    name_problem = path_name_problem(os.fspath(out_dir))  # an empty name, or one that is not text
    problems = (  # in order, the first that applies
        (name_problem is not None, f": {name_problem}; pass the folder to write the ONNX files into"),
        (out.exists() and not out.is_dir(), " is an existing file, not a folder"),
        (probe.exists() and not probe.is_dir(), f" cannot be created: {str(probe)!r} is a file"),
        (
            not os.access(probe, os.W_OK | os.X_OK),
            " is not writable" + ("" if probe == out else f" ({str(probe)!r} is not writable)"),
        ),
    )
    for applies, problem in problems:
        if applies:
            raise ExportError(f"--out {os.fspath(out_dir)!r}{problem}")
    return out


def supported_opsets() -> tuple[int, int]:
    """``(lowest, newest)`` opset an export can write: from :data:`MIN_OPSET` to the newest that both
    onnx (``onnx.defs.onnx_opset_version()``) and torch's TorchScript exporter (``dynamo=False``)
    know, so a bad ``--opset`` is one line up front rather than an exporter traceback."""
    newest = int(onnx.defs.onnx_opset_version())
    exporter = getattr(getattr(th.onnx, "_constants", None), "ONNX_TORCHSCRIPT_EXPORTER_MAX_OPSET", None)
    if isinstance(exporter, int):
        newest = min(newest, exporter)
    return MIN_OPSET, newest


def check_opset(opset: Any, label: str) -> int:
    """``opset`` when :func:`supported_opsets` has it; else :class:`ExportError` naming ``label``
    (``--opset 99`` / ``opset=99``) and the supported range."""
    low, high = supported_opsets()
    if not is_whole(opset) or not low <= opset <= high:
        raise ExportError(
            f"{label}: must be an integer from {low} to {high} (the opsets that onnx {onnx.__version__} and "
            f"torch {th.__version__}'s exporter both write)"
        )
    return int(opset)


def check_fusion_matches(fusion: str | None, settings: Mapping[str, Any] | None, label: str) -> None:
    """Refuse exporting a fusion the model was not trained with: ``export.json`` would claim it,
    and an on-board actor fed another fusion's channel acts on maps it never saw. ``fusion`` is the
    caller's (``None``: the recorded one is used); ``label`` is how the caller named it."""
    known = settings or {}
    recorded = known.get("fusion")
    if fusion is None or recorded not in FUSIONS or fusion == recorded:
        return
    raise ExportError(
        f"{label}: the model was trained with fusion {recorded!r} ({known.get('from', 'its record')}); "
        f"export.json must not claim a fusion it was not trained with: drop the fusion or pass {recorded!r}"
    )


def _jsonable(value: Any) -> Any:
    """JSON-safe copy: mappings get string keys, tuples become lists, non-finite floats strings
    (``"inf"``: JSON has no infinity, and ``comm_range`` may be one), paths and classes strings."""
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else str(float(value))
    if value is None or isinstance(value, str):
        return value
    if isinstance(value, type):
        return f"{value.__module__}.{value.__qualname__}"
    return str(value)


def _config_dict(config: Any) -> dict[str, Any]:
    """Every field of an :class:`uav_ipp.IppConfig` (what the observations were built with)."""
    return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}


def _settings(config: IppConfig, fusion: str, fusion_kwargs: Mapping[str, Any], origin: str) -> dict[str, Any]:
    """The ``env`` block of the JSON: map, fusion, the options that differ from ``IppConfig``'s
    defaults and the full resolved config."""
    resolved = _config_dict(config)
    defaults = _config_dict(IppConfig(map_name=config.map_name))
    return {
        "name": config.map_name,
        "fusion": fusion,
        "fusion_kwargs": dict(fusion_kwargs),
        "options": {k: v for k, v in resolved.items() if k != "map_name" and v != defaults[k]},
        "config": resolved,
        "from": origin,
    }


def _recorded_settings(env_options: Mapping[str, Any] | None, origin: str) -> dict[str, Any] | None:
    """Settings from the env options a model records (``sb3_coma.training_options``)."""
    if not env_options:
        return None
    recorded = dict(env_options)
    name, fusion, fusion_kwargs = recorded.pop("map"), recorded.pop("fusion"), recorded.pop("fusion_kwargs", {})
    return _settings(IppConfig.from_options(name, **recorded), fusion, fusion_kwargs or {}, origin)


def settings_of_source(source: ModelSource) -> dict[str, Any] | None:
    """Training settings recorded for a model: the env options saved in its zip, else its
    ``models.json`` entry (resolved through the config variant it names) or its run folder's
    ``config.yml``; ``None`` when there are none."""
    recorded = _recorded_settings(
        training_options(source.path) if source.path.is_file() else None,
        f"the env options recorded in {source.path.name}",
    )
    if recorded is not None:
        return recorded
    if source.shipped is not None:
        info = source.shipped
        env, variant = str(info["env"]), info.get("variant")
        origin = f"models.json entry {source.given!r}"
        try:
            cfg = load_config(env=env, variant=variant)
            config, fusion, fusion_kwargs = cfg.world.config, cfg.world.fusion, dict(cfg.world.fusion_kwargs)
            origin += f" (variant {variant!r} of {cfg.source})" if variant else f" ({cfg.source})"
        except TrainingError as exc:  # config file gone: the manifest's own fields still hold
            config, fusion, fusion_kwargs = IppConfig(map_name=env), str(info.get("fusion", "sendfuse")), {}
            origin += f"; its config could not be read ({exc}), env options are the defaults"
        return _settings(config, str(info.get("fusion", fusion)), fusion_kwargs, origin)
    if source.run_dir is not None:
        try:
            cfg = read_run_config(source.run_dir)
        except TrainingError:
            return None
        return _settings(cfg.world.config, cfg.world.fusion, cfg.world.fusion_kwargs, f"run config {cfg.source}")
    return None


def fusion_wrapper(venv: Any) -> Any:
    """The :class:`uav_ipp.fusion.FusionWrapper` inside a vec env from ``uav_ipp.make_vec_env``, or ``None``."""
    seen = 0
    while venv is not None and seen < 16:
        if isinstance(venv, FusionWrapper):
            return venv
        venv = getattr(venv, "venv", None) or getattr(venv, "env", None)
        seen += 1
    return None


def settings_of_model(model: Any) -> dict[str, Any] | None:
    """Training settings of a loaded model: the env options it records, a shipped model's
    manifest, else the env attached to it (its ``IppConfig`` and fusion wrapper); ``None`` when
    the model carries none of them."""
    recorded = _recorded_settings(training_options(model), "the env options the model records")
    if recorded is not None:
        return recorded
    info = getattr(model, "pretrained_info", None)
    if isinstance(info, dict) and "env" in info:
        return settings_of_source(
            ModelSource(str(info.get("file", info["env"])), pretrained_dir() / str(info.get("file", "")), info)
        )
    venv = getattr(model, "env", None)
    if venv is None:
        return None
    config = venv.get_attr("config", indices=[0])[0]
    wrapper = fusion_wrapper(venv)
    fusion_kwargs = {"alpha": wrapper.alpha} if getattr(wrapper, "alpha", None) is not None else {}
    return _settings(config, getattr(wrapper, "name", "unknown"), fusion_kwargs, "the env attached to the model")


# =========================================================================== building the graphs
def _actor_graph(model: Any) -> ActorGraph:
    actor = copy.deepcopy(model.policy.actor).cpu().eval()
    return ActorGraph(actor).eval()


def _fusion_graph(model: Any, fusion: str, settings: Mapping[str, Any]) -> tuple[FusionGraph, dict[str, Any]]:
    """The fusion graph for ``fusion`` on this model's env, and what the JSON says about it.

    Uses the network of the model's own env when it has one (exactly what it was evaluated
    with), else the weights the training config names (default: the shipped file)."""
    config = settings["config"]
    comm, lattice, n = int(config["comm_grid"]), int(config["lattice"]), int(config["n_uavs"])
    to_lattice = overlap_matrix(comm, float(lattice - 1), lattice)  # as FusionWrapper builds it
    info: dict[str, Any] = {"kind": fusion}
    if fusion == "mean":
        return FusionGraph(None, n, to_lattice).eval(), info
    wrapper = fusion_wrapper(getattr(model, "env", None))
    if wrapper is not None and getattr(wrapper, "name", None) == "sendfuse":
        network, alpha = wrapper.network, wrapper.alpha
    else:
        kwargs = dict(settings.get("fusion_kwargs") or {})
        network = load_weights(kwargs.get("weights") or default_weights_path(comm), expected_config={"grid_size": comm})
        alpha = kwargs.get("alpha")
    network = copy.deepcopy(network).cpu().to(memory_format=th.contiguous_format).eval()
    graph = FusionGraph(network, n, to_lattice, alpha).eval()
    meta = dict(getattr(network, "weights_metadata", {}) or {})
    info.update(
        alpha=graph.alpha,
        network=dict(network.config.as_dict()),
        parameters=network.num_parameters(),
        weights_sha256=next((v for k, v in meta.items() if k.endswith("sha256")), None),
    )
    return graph, info


def _sample_inputs(model: Any, settings: Mapping[str, Any], batch: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Random but valid inputs of every graph input (tracing and the export-time check)."""
    rng = np.random.default_rng(seed)
    space = model.policy.observation_space
    local = rng.random((batch, *space[layout.KEY_LOCAL].shape)).astype(space[layout.KEY_LOCAL].dtype)
    mask = rng.random((batch, layout.N_ACTIONS)) < 0.6
    mask[np.arange(batch), rng.integers(0, layout.N_ACTIONS, batch)] = True  # at least one valid action
    out = {"local": local, "action_mask": mask.astype(space[layout.KEY_MASK].dtype)}
    if layout.KEY_GAIN in space.spaces:
        gain = rng.random((batch, *space[layout.KEY_GAIN].shape))
        out["action_gain"] = gain.astype(space[layout.KEY_GAIN].dtype)
    config = settings["config"]
    n, r = int(config["n_uavs"]), int(config["comm_grid"])
    received = rng.random((batch, n, r, r), dtype=np.float32)
    received[rng.random(received.shape) < 0.3] = 0.5  # cells where nothing arrived
    valid = (rng.random((batch, n)) < 0.6).astype(np.float32)
    valid[:, 0] = 1.0  # the own map
    if batch > 1:
        valid[0, 1:] = 0.0  # one row that received nothing
    out.update(received=received, received_valid=valid)
    return out


def _io(name: str, shape: tuple[int, ...], dtype: str, meaning: str, **extra: Any) -> dict[str, Any]:
    return {"name": name, "shape": [BATCH, *shape], "dtype": dtype, "meaning": meaning, **extra}


def _local_channel_names() -> list[str]:
    names = ("BUDGET", "AGENT_ID", "ALTITUDE", "FOOTPRINT", "SENSOR", "BELIEF", "BELIEF_ENTROPY", "FUSED")
    return [n.lower() for n in sorted(names, key=lambda n: getattr(layout, n))]


def _export_graph(
    graph: nn.Module, args: tuple[th.Tensor, ...], path: Path, inputs: list[str], outputs: list[str], opset: int
) -> None:
    """``torch.onnx.export`` with a dynamic batch axis, written to a temporary name and moved
    into place, so a failed export never leaves a half-written file under the final name."""
    axes = {name: {0: BATCH} for name in inputs + outputs}
    tmp = path.with_name(path.name + ".tmp")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the legacy exporter's deprecation and tracer notes
        with th.no_grad():
            th.onnx.export(
                graph,
                args,
                str(tmp),
                input_names=inputs,
                output_names=outputs,
                dynamic_axes=axes,
                opset_version=opset,
                dynamo=False,
                do_constant_folding=True,
            )
    onnx.checker.check_model(onnx.load(str(tmp)))
    os.replace(tmp, path)


def onnx_session(path: str | os.PathLike[str], threads: int = 1) -> Any:
    """An onnxruntime CPU session on ``threads`` threads (1: what one on-board core gives)."""
    options = ort.SessionOptions()
    options.intra_op_num_threads = int(threads)
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(str(path), sess_options=options, providers=["CPUExecutionProvider"])


#: onnxruntime's names of the tensor types the graphs use.
_ORT_DTYPES = {
    "tensor(float)": np.float32,
    "tensor(double)": np.float64,
    "tensor(int8)": np.int8,
    "tensor(uint8)": np.uint8,
    "tensor(int64)": np.int64,
    "tensor(bool)": np.bool_,
}


def onnx_feeds(session: Any, arrays: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The session's inputs taken from ``arrays`` (e.g. an observation dict) in the dtypes the graph
    declares: an env whose mask dtype changed since training still feeds the actor correctly."""
    return {i.name: np.ascontiguousarray(arrays[i.name], dtype=_ORT_DTYPES[i.type]) for i in session.get_inputs()}


def _verify(path: Path, feeds: dict[str, np.ndarray], reference: Any, what: str) -> float:
    """Run the file with onnxruntime on ``feeds``, compare with ``reference(*inputs)`` (the PyTorch
    or numpy outputs); return the largest difference of the float outputs."""
    session = onnx_session(path)
    names = [i.name for i in session.get_inputs()]
    got = session.run(None, onnx_feeds(session, feeds))
    worst = 0.0
    for g, w in zip(got, reference(*(feeds[k] for k in names))):
        actions = w.dtype.kind in "iu"
        valid = w > MASKED_LOGIT / 2  # masked logits are one constant; compare the rest
        if actions:  # actions agree exactly or not at all
            diff = 0.0 if np.array_equal(g, w) else math.inf
        else:
            diff = float(np.max(np.abs(g[valid] - w[valid]))) if valid.any() else 0.0
        if not diff <= 1e-4:
            how = "gives other actions than PyTorch" if actions else f"differs from PyTorch by {diff:g}"
            raise RuntimeError(f"ONNX export check failed: {what} {path} {how}")
        worst = max(worst, diff)
    return worst


def _torch_reference(graph: nn.Module) -> Any:
    def run(*arrays: np.ndarray) -> list[np.ndarray]:
        with th.no_grad():
            return [t.numpy() for t in graph(*(th.from_numpy(a) for a in arrays))]

    return run


def fusion_reference(graph: FusionGraph) -> Any:
    """The outputs ``fusion.onnx`` must reproduce, computed the way the env's fusion wrapper does
    (``SenDFuseNet.fuse`` or ``mean_fusion``, then ``clip(A fused A^T, 0, 1)``), not by the graph."""
    a = graph.to_lattice.numpy()

    def run(received: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        if graph.network is None:
            fused = mean_fusion(received, valid)
        else:
            with th.inference_mode():
                fused = graph.network.fuse(
                    th.from_numpy(received), th.from_numpy(valid > 0.5), alpha=graph.alpha
                ).numpy()
        return [fused, np.clip(np.matmul(np.matmul(a, fused), a.T), 0.0, 1.0).astype(np.float32)]

    return run


def export_onnx(
    model: Any,
    out_dir: str | os.PathLike[str],
    *,
    fusion: str | None = None,
    settings: Mapping[str, Any] | None = None,
    source: ModelSource | None = None,
    opset: int = OPSET,
    verify: bool = True,
) -> dict[str, Path]:
    """Write ``actor.onnx``, ``fusion.onnx`` and ``export.json`` for a COMA model into ``out_dir``.

    :param model: a loaded or freshly built ``COMA`` model
    :param out_dir: output folder (created; existing files of these names are replaced)
    :param fusion: ``"sendfuse"`` or ``"mean"``; ``None``: the fusion the model was trained with
        (``settings``, a shipped model's manifest, or the env attached to the model)
    :param settings: training settings as :func:`settings_of_source` returns them; ``None``:
        :func:`settings_of_model`
    :param source: where the model came from (recorded in the JSON)
    :param opset: ONNX opset (>= 17)
    :param verify: run both files with onnxruntime on random valid inputs and compare with
        PyTorch (a failed comparison raises ``RuntimeError`` and nothing is kept)
    :return: ``{"actor": path, "fusion": path, "metadata": path}``. ``fusion.onnx`` is written for
        both fusions: for SenDFuse it holds the network, for the mean a few ops; either way it
        ends in the lattice projection, so on board the pipeline is the same.
    :raises ExportError: unknown fusion, unknown training settings, bad opset or output folder
    """
    check_opset(opset, f"opset={opset!r}")
    out = check_out_dir(out_dir)
    fusion, settings = _resolve_fusion(model, fusion, settings)
    out.mkdir(parents=True, exist_ok=True)

    feeds = _sample_inputs(model, settings, batch=3)
    actor = _actor_graph(model)
    actor_inputs = ["local", "action_mask"] + (["action_gain"] if actor.with_prior else [])
    paths = {"actor": out / ACTOR_FILE, "fusion": out / FUSION_FILE, "metadata": out / METADATA_FILE}
    _export_graph(
        actor,
        tuple(th.from_numpy(feeds[k]) for k in actor_inputs),
        paths["actor"],
        actor_inputs,
        ["logits", "action"],
        opset,
    )
    fusion_graph, fusion_info = _fusion_graph(model, fusion, settings)
    _export_graph(
        fusion_graph,
        (th.from_numpy(feeds["received"]), th.from_numpy(feeds["received_valid"])),
        paths["fusion"],
        ["received", "received_valid"],
        ["fused", "fused_channel"],
        opset,
    )
    checked = _verify_exports(paths, feeds, actor, fusion_graph) if verify else {"done": False}
    metadata = _metadata(model, actor, actor_inputs, fusion_info, settings, source, opset, checked)
    tmp = paths["metadata"].with_name(METADATA_FILE + ".tmp")
    tmp.write_text(json.dumps(_jsonable(metadata), indent=2, allow_nan=False) + "\n")
    os.replace(tmp, paths["metadata"])
    return paths


def _resolve_fusion(model: Any, fusion: str | None, given: Mapping[str, Any] | None) -> tuple[str, dict[str, Any]]:
    """The fusion to export and the training settings with it: ``fusion`` if given (it must agree
    with the settings), else the one the settings record; settings from the model when none are
    given, from its observation space when it recorded none."""
    settings = dict(given) if given is not None else settings_of_model(model)
    check_fusion_matches(fusion, settings, f"fusion={fusion!r}")
    if fusion is None:
        fusion = (settings or {}).get("fusion")
    if fusion not in FUSIONS:  # one rule: a fusion the export knows, given or recorded
        told = fusion is not None and fusion != "unknown"
        raise ExportError(
            f"fusion={fusion!r}: choose one of {', '.join(FUSIONS)}"
            if told
            else "cannot tell which fusion this model was trained with (no shipped-model entry, "
            "run config or env with a fusion wrapper): pass fusion='sendfuse' or 'mean'"
        )
    if settings is None:
        settings = _settings_from_spaces(model, fusion)
    return fusion, {**settings, "fusion": fusion}


def _verify_exports(
    paths: dict[str, Path], feeds: dict[str, np.ndarray], actor: ActorGraph, fusion_graph: FusionGraph
) -> dict[str, Any]:
    """Both files against PyTorch on the sample inputs; on a failed comparison both are deleted."""
    try:
        return {
            "done": True,
            "inputs": "3 random valid rows",
            "actor_max_abs_diff": _verify(paths["actor"], feeds, _torch_reference(actor), "actor"),
            "fusion_max_abs_diff": _verify(paths["fusion"], feeds, fusion_reference(fusion_graph), "fusion"),
        }
    except RuntimeError:
        for path in (paths["actor"], paths["fusion"]):
            path.unlink(missing_ok=True)
        raise


def _settings_from_spaces(model: Any, fusion: str) -> dict[str, Any]:
    """Settings of a model that recorded none: the options its observation space fixes (number of
    UAVs from the saved model, lattice from the maps), everything else the defaults."""
    space = model.policy.observation_space
    options: dict[str, Any] = {}
    n_agents = getattr(model, "n_agents", None)
    if n_agents:
        options["n_uavs"] = int(n_agents)
    lattice = int(space[layout.KEY_LOCAL].shape[-1])
    if lattice != 11:
        options["lattice"] = lattice
    if layout.KEY_GAIN not in space.spaces:
        options["action_gain"] = False
    return _settings(
        IppConfig.from_options("unknown", **options),
        fusion,
        {},
        "not recorded: options implied by the model's observation "
        "space, the rest are defaults (the map does not change the observation layout)",
    )


def _policy_info(model: Any, actor: ActorGraph) -> dict[str, Any]:
    policy = model.policy
    prior = policy.actor.prior_weights  # the exported actor is a copy of this one
    return {
        "class": type(policy).__name__,
        "features_extractor": policy.features_extractor_class.__name__,
        "features_extractor_kwargs": dict(policy.features_extractor_kwargs),
        "gain_prior_weights": None if prior is None else [float(w) for w in prior.detach()],
        "correction_bound": policy.correction_bound,
        "gain_inputs": bool(getattr(policy, "gain_inputs", False)),
        "num_timesteps": int(getattr(model, "num_timesteps", 0)),
        "parameters": sum(p.numel() for p in actor.actor.parameters()),
    }


def _metadata(
    model: Any,
    actor: ActorGraph,
    actor_inputs: list[str],
    fusion_info: dict[str, Any],
    settings: Mapping[str, Any],
    source: ModelSource | None,
    opset: int,
    checked: Mapping[str, Any],
) -> dict[str, Any]:
    """The JSON: every input/output, the env options the observations must be built with, provenance."""
    actor_in = _actor_inputs(model, actor_inputs)
    fusion_block = _fusion_block(fusion_info, settings)
    return {
        "format": METADATA_FORMAT,
        "exported_by": f"sb3-coma {__version__}, torch {th.__version__}",
        "opset": opset,
        "pipeline": "fused_channel = fusion(received, received_valid); local = concat(raw local channels 0-6, "
        "fused_channel, raw local channels 7.. (observation v3 only)); logits, action = actor(local, action_mask[, action_gain])",
        "actor": {
            "file": ACTOR_FILE,
            "inputs": actor_in,
            "outputs": [
                _io(
                    "logits",
                    (layout.N_ACTIONS,),
                    "float32",
                    f"masked logits: invalid actions are {MASKED_LOGIT:g}; softmax gives the policy",
                ),
                _io(
                    "action",
                    (),
                    "int64",
                    "argmax of logits (first on ties): the action model.predict(obs, deterministic=True) returns",
                ),
            ],
            "actions": list(layout.ACTION_NAMES),
            "policy": _policy_info(model, actor),
        },
        "fusion": fusion_block,
        "env": dict(settings),
        "source": _source_info(source),
        "check": dict(checked),
    }


def _actor_inputs(model: Any, actor_inputs: list[str]) -> list[dict[str, Any]]:
    """The actor's inputs in the JSON: ``local``, ``action_mask`` and, when it reads them, ``action_gain``."""
    space = model.policy.observation_space
    local_shape = tuple(space[layout.KEY_LOCAL].shape)

    def dtype(key: str) -> str:
        return str(np.dtype(space[key].dtype))

    actor_in = [
        _io(
            "local",
            local_shape,
            dtype(layout.KEY_LOCAL),
            "the UAV's local maps in [0, 1]; channel 8 (fused) is fusion.onnx's fused_channel",
            channels=_local_channel_names(),
        ),
        _io("action_mask", (layout.N_ACTIONS,), dtype(layout.KEY_MASK), "1 valid, 0 invalid action"),
    ]
    if "action_gain" in actor_inputs:
        actor_in.append(
            _io(
                "action_gain",
                tuple(space[layout.KEY_GAIN].shape),
                dtype(layout.KEY_GAIN),
                "each action's normalised expected information gain (rows: "
                f"{', '.join(layout.GAIN_WEIGHTINGS)}), the env's action_gain observation",
            )
        )
    return actor_in


def _fusion_block(fusion_info: dict[str, Any], settings: Mapping[str, Any]) -> dict[str, Any]:
    """``fusion.onnx`` in the JSON: what the graph holds, its inputs and outputs."""
    config = settings["config"]
    n, r, lattice = int(config["n_uavs"]), int(config["comm_grid"]), int(config["lattice"])
    return {
        "file": FUSION_FILE,
        **fusion_info,
        "inputs": [
            _io(
                "received",
                (n, r, r),
                "float32",
                "slot 0: the UAV's own map; slots 1..: maps received from the other UAVs (0.5 where nothing arrived)",
            ),
            _io("received_valid", (n,), "float32", "1 where a slot holds a map (slot 0 always)"),
        ],
        "outputs": [
            _io("fused", (r, r), "float32", "the fused map on the communication grid"),
            _io(
                "fused_channel",
                (lattice, lattice),
                "float32",
                "the actor's 8th local channel: fused averaged onto the lattice, clipped to [0, 1]",
            ),
        ],
    }


def _source_info(source: ModelSource | None) -> dict[str, Any] | None:
    """Where the model came from: what was given, the file, its SHA-256, whether it is shipped."""
    if source is None:
        return None
    return {
        "given": source.given,
        "path": str(source.path),
        "sha256": sha256_file(source.path) if source.path.is_file() else None,
        "shipped": source.shipped is not None,
    }
