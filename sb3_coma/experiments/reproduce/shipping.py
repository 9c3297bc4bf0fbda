"""Step 10 of ``reproduce``: ``--ship`` and ``--record``, the run's only writes outside ``out``.

Both change ``models.json`` through its one writer (``sb3_coma.app.model_manifest``): ``--ship``
replaces a retrained map's whole entry (and its zip), ``--record`` adds the measured Table I
numbers to the entries of the shipped models the table flew.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

from sb3_coma.app import pretrained as pt
from sb3_coma.app.model_manifest import ModelEntry, ModelFields, update_models
from sb3_coma.experiments.reproduce.options import ReproduceOptions
from sb3_coma.experiments.reproduce.results import ModelSource
from sb3_coma.experiments.reproduce.training import shipped_seed, variant_for
from uav_ipp import WORLD_VERSION


def ship_or_record(
    opts: ReproduceOptions,
    sources: Mapping[str, ModelSource],
    paper_results: Sequence[Any],
    say: Callable[[str], None],
) -> None:
    """With ``ship``: the retrained zips into sb3_coma/pretrained; with ``record``: the measured
    Table I numbers of the shipped models into models.json."""
    if opts.ship:
        ship_retrained(sources, paper_results, say)
    elif opts.record and not opts.train:
        record_metrics(paper_results, say)


def _metrics_entry(res: Any) -> ModelFields:
    """A result row's numbers as an entry records them, with the missions that measured them."""
    return {
        "metrics": {k: round(v, 4) for k, v in res.summary().items()},
        "metrics_note": f"measured by sb3-coma reproduce: {res.n_trials} trials, env seeds "
        f"{res.seed}..{res.seed + res.n_trials - 1}, noise {res.env_options.get('noise')}, "
        f"fusion {res.fusion}",
    }


def _manifest_name(env: str, method: str) -> str | None:
    """The shipped model a result row flew: ``coma`` -> ``env``, ``coma[paper-actor]`` ->
    ``env-paper-actor`` (``app.rows.shipped_label`` the other way); ``None`` for a baseline."""
    if method == "coma":
        return env
    if method.startswith("coma[") and method.endswith("]"):
        return f"{env}-{method[5:-1]}"
    return None


def record_metrics(results: Sequence[Any], say: Callable[[str], None] = print) -> None:
    """Store the measured metrics of the shipped models in ``models.json``."""
    models = pt.read_manifest()["models"]
    changes: dict[str, ModelFields] = {}
    for res in results:
        name = _manifest_name(res.env, res.method)
        if name is not None and name in models:
            changes[name] = {**changes.get(name, {}), **_metrics_entry(res)}
    say(f"recorded metrics in {update_models(changes)}")


def ship_retrained(sources: Mapping[str, ModelSource], results: Sequence[Any], say: Callable[[str], None]) -> None:
    """Each retrained map model saved into sb3_coma/pretrained in its compact form, its entry
    (what retrains it, how long it took, its Table I numbers) replacing the shipped one."""
    directory = pt.pretrained_dir()
    directory.mkdir(parents=True, exist_ok=True)
    entries: dict[str, ModelEntry] = {}
    for env, src in sources.items():
        res = next(r for r in results if r.env == env and r.method == "coma")
        files = pt.save_for_shipping(src.model, f"coma_{env}.zip", directory)
        entries[env] = {
            "file": files["file"],
            "sha256": files["sha256"],
            "size_bytes": files["size_bytes"],
            "env": env,
            "fusion": src.fusion,
            "variant": variant_for(env, src.fusion),
            "seed": shipped_seed(env),
            "deterministic": src.deterministic,
            "timesteps": src.timesteps,
            "command": src.command,
            "train_wall_s": round(float(src.train_wall_s or 0), 1),
            **_metrics_entry(res),
            "training_curve": src.training_curve,
            "world": WORLD_VERSION,
        }
        say(f"shipped {directory / entries[env]['file']}")
    update_models(entries, replace=True)
