"""Maintainer tool: pick the shipped COMA models from training runs, on validation missions only.

What it does: each shipped model is trained with one or more seeds, every run with
``--eval-freq`` and ``--eval-missions``: its ``best_model.zip`` is its best checkpoint on the
validation missions (split train, env seeds 1000+, re-seeded at every evaluation, never the test
split). This tool reads each run's ``eval/evaluations.npz``, keeps the run whose best validation
return is highest, re-saves that ``best_model.zip`` into ``sb3_coma/pretrained/`` in compact form
(no Adam moments, no target critic, half precision: ~1.4 MB) and writes its ``models.json``
entry (through ``sb3_coma.app.model_manifest``, the manifest's one writer): checksum, the exact
command, the validation scores of every candidate, training wall-clock and curve, and the seed
spread: every candidate's selected checkpoint flown on the unseen protocol (the same 50 test
missions as ``sb3-coma reproduce``), so tables can give the shipped seed's result next to the
mean +- std over seeds. Those test metrics are recorded after the
choice and never enter it. Test metrics of the shipped model itself are added afterwards by
``sb3-coma reproduce --record``.

    python -m sb3_coma.experiments.ship_models env1=runs/env1_s0,runs/env1_s1 \\
        env3-mean-cnn=shipped,runs/meancnn_s1,runs/meancnn_s2 ...
    python -m sb3_coma.experiments.ship_models --rescore env1 env2 env3   # shipped seeds from the shipped files

``shipped`` stands for the model shipped today under that name (its run folder may be gone), and
a ``.zip`` path for a model whose run folder is gone (e.g. an earlier shipped file out of git):
such a candidate is scored by flying it on today's validation missions, never by the score
recorded when it was trained (the env's random streams may have changed since; scores measured
under different streams do not compare). The shipped one stays, file and entry, if it wins; a
bare zip cannot be shipped (no run folder records how it was trained).

A name ``envN`` ships the model of that map; ``env3-{fusion}-{extractor}`` an ablation arm.
"""

from __future__ import annotations

import io
import json
import sys
import tempfile
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_coma import COMA
from sb3_coma.app import pretrained as pt
from sb3_coma.app.evaluation import evaluate
from sb3_coma.app.model_manifest import ModelEntry, ModelFields, as_entry, update_models
from sb3_coma.app.runs import curve_from_metrics
from sb3_coma.app.selection import run_command, validation_best
from sb3_coma.app.validation_flights import load_trained, model_validation_return
from sb3_coma.common.evaluation import PROTOCOLS
from uav_ipp import WORLD_VERSION


def run_length(run: Path) -> int:
    """Joint steps the run trained for (its last evaluation)."""
    return int(np.load(run / "eval" / "evaluations.npz")["timesteps"][-1])


#: A candidate spelt ``shipped``: the model shipped today under that name (its run folder may be
#: long gone), scored by flying it on today's validation missions (:func:`validation_return`).
SHIPPED = "shipped"


#: How a shipped model is chosen among its candidates (recorded with every ``selection`` entry).
SELECTION_RULE = (
    "highest mean return on the run's validation missions (split train, env seeds 1000+, argmax; never the "
    "test split), over every evaluation of every seed except those while a warm-started actor is still the "
    "clone (its critic warm-up)"
)


def _selection(scores: dict[str, tuple[float, int]]) -> dict[str, Any]:
    """The ``selection`` entry: the rule and every candidate's validation score, by seed label."""
    return {
        "rule": SELECTION_RULE,
        "candidates": {
            label: {"best_validation_return": round(v, 4), "at_joint_steps": t} for label, (v, t) in scores.items()
        },
    }


#: What ``seeds_unseen`` flies: the file that ships, not the checkpoint it is made from.
SCORED_FORM = "each seed in its shipped form (pretrained.save_for_shipping: half precision, no target critic)"


def seed_spread(
    models: dict[str, Path], env: str, fusion: str, missions: int = PROTOCOLS["unseen"].n_trials
) -> dict[str, Any]:
    """The ``seeds_unseen`` entry: each seed's selected model on the unseen protocol (final F1 and
    entropy of the global belief, mean over ``missions`` test missions, argmax actions), each flown
    in the form it would ship in (:func:`shipped_form`), so the shipped seed's numbers are the
    shipped file's (half precision moves a few argmax decisions: env3's seed 1 flew 0.7592 / 0.4388
    as a full-precision checkpoint and 0.7601 / 0.4373 as the shipped file)."""
    metrics = {}
    with tempfile.TemporaryDirectory(prefix="ship_models-") as folder:
        for label, path in models.items():
            flown = shipped_form(path, Path(folder), label)
            result = evaluate(str(flown), env=env, fusion=fusion, protocol="unseen", n_trials=missions, record=0)
            metrics[label] = {
                "f1": round(float(result.f1[:, -1].mean()), 4),
                "entropy": round(float(result.entropy[:, -1].mean()), 4),
            }
    return {
        "protocol": "unseen",
        "missions": missions,
        "noise": "moderate",
        "scored": SCORED_FORM,
        "metrics": metrics,
    }


def shipped_form(path: Path, folder: Path, label: str) -> Path:
    """The checkpoint at ``path`` saved as :func:`ship` would ship it, in ``folder``."""
    model = COMA.load(str(path), device="cpu")
    return folder / pt.save_for_shipping(model, f"{label.replace(' ', '_')}.zip", directory=folder)["file"]


def rescore_shipped_seed(name: str, missions: int = PROTOCOLS["unseen"].n_trials) -> dict[str, Any]:
    """Today's ``seeds_unseen`` of shipped model ``name`` with its shipped seed re-flown from the
    shipped file itself (the other seeds' run folders may be gone: their numbers stay as recorded,
    and ``scored`` says which form each was flown in)."""
    entry = pt.read_manifest()["models"][name]
    spread = dict(entry["seeds_unseen"])
    label = f"seed {entry['seed']}"
    result = evaluate(
        str(pt.model_path(name)),
        env=entry["env"],
        fusion=entry["fusion"],
        protocol="unseen",
        n_trials=missions,
        record=0,
    )
    metrics = dict(spread["metrics"])
    metrics[label] = {
        "f1": round(float(result.f1[:, -1].mean()), 4),
        "entropy": round(float(result.entropy[:, -1].mean()), 4),
    }
    others = [other for other in metrics if other != label]
    form = {label: "the shipped file", **{other: "full-precision checkpoint (as recorded)" for other in others}}
    if spread.get("scored") == SCORED_FORM:
        form = {key: "shipped form" for key in metrics}
    return {**spread, "metrics": metrics, "scored": form}


def _file_candidate(name: str, spec: str) -> tuple[str, tuple[float, int], Path, dict[str, Any] | None]:
    """(seed label, validation score flown today, model file, manifest entry or ``None``) of a
    candidate without a run folder: ``shipped`` (today's shipped ``name``) or a model zip."""
    entry = pt.read_manifest()["models"][name] if spec == SHIPPED else None
    path = pt.model_path(name) if spec == SHIPPED else Path(spec)
    model, options = load_trained(path)
    if entry is not None:
        seed = int(entry["seed"])
        steps = int(entry["selection"]["candidates"][f"seed {seed}"]["at_joint_steps"])
    else:
        seed, steps = int(model.seed or 0), int(model.num_timesteps)
    return f"seed {seed}", (model_validation_return(model, options), steps), path, entry


def _flag_value(command: str, flag: str) -> str | None:
    """The value of ``flag`` in a command line, spelt ``--flag V`` or ``--flag=V``; ``None`` without it."""
    words = command.split()
    for i, word in enumerate(words):
        if word == flag and i + 1 < len(words):
            return words[i + 1]
        if word.startswith(flag + "="):
            return word.split("=", 1)[1]
    return None


def shipped_file_name(name: str) -> str:
    """The file a shipped model ``name`` is saved as (``env3-mean-cnn`` -> ``coma_env3_mean_cnn.zip``)."""
    return f"coma_{name.replace('-', '_')}.zip"


def _entry_of_run(name: str, chosen: Path) -> dict[str, Any]:
    """The manifest entry of a run's ``best_model.zip``, saved into the shipped folder."""
    command, info = run_command(chosen)
    model, env_options = load_trained(chosen / "best_model.zip")
    fusion = env_options["fusion"]
    extractor = "cnn" if model.policy.features_extractor_class.__name__.startswith("Cnn") else "cbam"
    wall = (chosen / "model.zip").stat().st_mtime - (chosen / "config.yml").stat().st_mtime
    entry = {
        **pt.save_for_shipping(model, shipped_file_name(name)),
        "env": info["env"].split("-")[1].lower(),
        "fusion": fusion,
        "extractor": extractor,
        "actor_inputs": "8 local channels + on-board gains" if model.policy.gain_inputs else "8 local channels",
        "variant": info["variant"],
        "world": WORLD_VERSION,
        "seed": int(info["seed"]),
        "deterministic": True,
        "timesteps": int(model.num_timesteps),
        "command": command,
        "config": "zoo_configs/coma.yml",
        "model_file_of_run": "best_model.zip",
        "train_wall_s": round(wall, 1),
        "train_wall_note": f"wall-clock of that command (whole run, warm start included, {run_length(chosen)} "
        "joint steps of COMA) on 2 CPU cores shared with the other trainings of the round",
        "shipped_form": "compact: no Adam moments, no target critic, half-precision weights (pretrained.save_for_shipping)",
        "training_curve": curve_from_metrics(chosen / "metrics.csv"),
        "env_options": env_options,
    }
    steps = _flag_value(command, "--timesteps")
    if steps is not None:  # reproduce --train retrains as long (reproduce.shipped_timesteps)
        entry["train_timesteps"] = int(steps)
    if name == f"{entry['env']}-{fusion}-{extractor}":  # an arm of the ablation, not another actor of the map
        entry["ablation_arm"] = [fusion, extractor]
    warm = chosen / "warm_start.json"
    if warm.is_file():  # "COMA (oracle warm start)": the teacher and what the clone learnt
        record = json.loads(warm.read_text())
        entry["warm_start"] = {k: v for k, v in record.items() if k != "rounds_record"}
    entry["title"] = model_title(entry)
    return entry


def model_title(entry: dict[str, Any]) -> str:
    """What tables call a shipped model: :data:`~sb3_coma.app.pretrained.WARM_START_TITLE` for a
    warm-started one (the RL part fine-tunes a clone of the oracle), else "COMA"."""
    return pt.WARM_START_TITLE if entry.get("warm_start") else "COMA"


def _members(data: bytes) -> dict[str, Any]:
    """An SB3 zip's members, ``data`` parsed without ``policy_class`` (SB3 writes reprs with memory
    addresses there, so two saves of one model differ in it and nowhere else)."""
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members: dict[str, Any] = {n: archive.read(n) for n in archive.namelist()}
    record = json.loads(members.pop("data"))
    record.pop("policy_class", None)
    return {**members, "data": record}


def _same_model(a: bytes, b: bytes) -> bool:
    """Whether two files are saves of one model (:func:`_members` equal); ``False`` for a non-zip."""
    try:
        return _members(a) == _members(b)
    except (zipfile.BadZipFile, KeyError, ValueError):
        return False


def _keep_same_file(name: str, save: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """Run ``save`` (which writes the shipped file of ``name`` and returns its entry); when it wrote
    the same model as the file it replaced, put the old bytes back: git history keeps every
    shipped file for ever, and a re-selection that keeps a model must not add a copy of it."""
    target = pt.pretrained_dir() / shipped_file_name(name)
    before = target.read_bytes() if target.is_file() else None
    entry = save()
    if before is not None and _same_model(before, target.read_bytes()):
        target.write_bytes(before)
        entry.update(sha256=pt.sha256_file(target), size_bytes=len(before))
    return entry


def ship(name: str, runs: Sequence[Path | str]) -> dict[str, Any]:
    """Ship the best of ``runs`` (by validation return) as model ``name``; returns its manifest
    entry. A run spelt :data:`SHIPPED` is today's shipped model, kept (file and entry) if it wins."""
    scores: dict[str, tuple[float, int]] = {}
    files: dict[str, Path] = {}
    folders: dict[str, Path] = {}
    current: dict[str, Any] | None = None
    for run in runs:
        if str(run) == SHIPPED or str(run).endswith(".zip"):
            label, score, files[label], entry = _file_candidate(name, str(run))
            current = entry if entry is not None else current
        else:
            folder = Path(run)
            label, score = f"seed {run_command(folder)[1]['seed']}", validation_best(folder)
            files[label], folders[label] = folder / "best_model.zip", folder
        if label in scores:
            raise ValueError(f"{name}: two candidates of {label}")
        scores[label] = score
    best = max(scores, key=lambda label: scores[label][0])
    _, options = load_trained(next(iter(files.values())))  # the candidates are seeds of one setting
    spread = seed_spread(files, options["map"], options["fusion"])
    if best in folders:  # flown before: saving the winner replaces today's shipped file
        entry = _keep_same_file(name, lambda: _entry_of_run(name, folders[best]))
    elif current is not None and files[best] == pt.model_path(name):
        entry = dict(current)
    else:
        raise ValueError(f"{name}: the best candidate, {files[best]}, has no run folder to ship it from")
    entry["selection"] = _selection(scores)
    entry["seeds_unseen"] = spread
    return entry


def main(argv: Sequence[str] | None = None) -> int:
    """Ship every ``NAME=RUN[,RUN...]`` and rewrite ``models.json``; status 2 (and the usage) without any."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv:
        print(__doc__)
        return 2
    manifest = pt.read_manifest()
    if argv[0] == "--rescore":  # the shipped seeds' numbers from the shipped files themselves
        rescored: dict[str, ModelFields] = {}
        for name in argv[1:]:
            spread = rescore_shipped_seed(name)
            rescored[name] = {"seeds_unseen": spread, "title": model_title(manifest["models"][name])}
            print(f"{name}: {spread['metrics']}")
        update_models(rescored)
        return 0
    shipped: dict[str, ModelEntry] = {}
    for spec in argv:
        name, runs = spec.split("=", 1)
        entry = as_entry(name, ship(name, runs.split(",")))
        old = manifest["models"].get(name, {})
        shipped[name] = entry
        print(
            f"{name}: {entry['command']} -> {entry['file']} ({entry['size_bytes']} bytes); "
            f"candidates {entry['selection']['candidates']}" + (" (replaced)" if old else "")
        )
    update_models(shipped, replace=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
