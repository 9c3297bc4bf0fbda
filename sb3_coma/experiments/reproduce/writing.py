"""Steps 11 and 12 of ``reproduce``: the figures, then ``summary.json`` and ``RESULTS.md``.

These steps measure nothing: they turn the earlier steps' results into files (and, with
``docs``, the docs copy and README's results block), so everything in them was measured by the
same run.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import shutil
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sb3_coma.app import pretrained as pt
from sb3_coma.baselines.adaptive_gain import default_weighting
from sb3_coma.common.checkpoints import write_between_markers
from sb3_coma.experiments import plots as pl
from sb3_coma.experiments import report
from sb3_coma.experiments.reproduce.options import ABLATION_ENV, DEFAULT_ENVS, Folders, ReproduceOptions
from sb3_coma.experiments.reproduce.results import LoadedModels, RunRecord

#: README's results block lies between these markers; ``reproduce`` writes it, nobody pastes it.
README_MARKERS = ("<!-- results:start (written by sb3-coma reproduce) -->", "<!-- results:end -->")


def figures_step(
    opts: ReproduceOptions, loaded: LoadedModels, protocols: Sequence[Any], ablation: Any, sweep: Any, out: Path
) -> list[Path]:
    """Metric curves per protocol (``protocols``: the paper one, then the unseen one or ``None``),
    training reward, ablation, noise sweep; returns the figure files."""
    if not opts.plots:
        return []
    fig_dir = out / "figures"
    figures: list[Path] = []
    paper, unseen = protocols
    grids = [("paper", paper, "table1_curves.png", f"{opts.trials} trials")]
    if unseen is not None:
        grids.append(("unseen", unseen, "unseen_curves.png", f"{unseen.n_trials} missions"))
    for name, protocol, file, count in grids:
        results = {
            env: [protocol.result(env, m.label) for m in ms if (env, m.label) in protocol.results]
            for env, ms in loaded.methods.items()
        }
        title = f"{name} protocol: F1 and entropy vs step, noise {opts.noise}, {count}"
        titles = report.model_titles(loaded)  # "COMA (oracle warm start)" where the map's models were warm-started
        labels = {env: [titles.get(r.method, r.method) for r in rs] for env, rs in results.items()}
        figures.append(pl.plot_metric_grid(results, fig_dir / file, title=title, labels=labels))
    curves = {
        env: pl.TrainingCurve(np.arange(1, len(s.training_curve) + 1), np.asarray(s.training_curve), s.source)
        for env, s in loaded.sources.items()
        if s.training_curve
    }
    if curves:
        figures.append(pl.plot_training_reward(curves, fig_dir / "training_reward.png"))
    if ablation is not None and ablation.results:
        title = f"{ABLATION_ENV}: F1 and entropy vs step per noise level"
        figures.append(pl.plot_metric_grid(ablation.by_noise(), fig_dir / "ablation_curves.png", title=title))
        title = f"{ABLATION_ENV}: ablation at 100 % of the budget"
        figures.append(pl.plot_ablation(dict(ablation.results), fig_dir / "ablation_bars.png", title=title))
    if sweep is not None and sweep.results:
        figures.append(pl.plot_noise_sweep(sweep, fig_dir / "noise_sweep.png"))
    return figures


def seed_spread_rows() -> list[dict[str, Any]]:
    """Per shipped model: its seeds and their unseen results as ``ship_models`` recorded them."""
    rows = []
    for name, entry in pt.read_manifest()["models"].items():
        spread = entry.get("seeds_unseen") or {}
        rows.append(
            {
                "model": name,
                "shipped": f"seed {entry['seed']}",
                "candidates": sorted(entry["selection"]["candidates"], key=lambda c: int(c.split()[-1])),
                "missions": spread.get("missions"),
                "metrics": spread.get("metrics", {}),
            }
        )
    return rows


def write_results(
    opts: ReproduceOptions,
    folders: Folders,
    record: RunRecord,
    figures: Sequence[Path],
    timings: Mapping[str, float],
    started: float,
    say: Callable[[str], None],
) -> dict[str, Any]:
    """summary.json, RESULTS.md (and the docs copy with its figures); returns the summary."""
    out = folders.staging
    summary = {**record.summary, **_run_facts(opts, record, timings, started)}
    record = dataclasses.replace(record, summary=summary)
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=_jsonable) + "\n")
    (out / "RESULTS.md").write_text(report.results_markdown(record, figures, out))
    if opts.docs is not None:
        _write_docs(Path(opts.docs), record, figures, say)
    if "acceptance" in summary:
        say(report.acceptance_markdown(summary["acceptance"]))
    if summary.get("ablation"):
        say(report.ablation_verdict(summary["ablation"]))
    say(
        f"wrote {folders.target or out}/ (table.md, team_table.md, paper_verdicts.md, acceptance.md, unseen_*.md, "
        f"noise_sweep.md, generalisation.md, latency.md, summary.json, RESULTS.md) in {summary['wall_s']} s"
    )
    return summary


def _run_facts(
    opts: ReproduceOptions, record: RunRecord, timings: Mapping[str, float], started: float
) -> dict[str, Any]:
    """The summary's last keys: how the run was made (command, machine, options, models), what it
    skipped and how long each step took."""
    return {
        "command": _command(opts),
        "command_line": command_line(opts),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "python": sys.version.split()[0],
        "machine": f"{platform.machine()} {platform.processor() or ''}".strip(),
        "trials": opts.trials,
        "seed": opts.seed,
        "noise": opts.noise,
        "envs": list(opts.env_names),
        "ag_weighting": _ag_weightings(opts.env_names),
        "seed_spread": [] if opts.train else seed_spread_rows(),
        "models": {
            env: {
                "source": s.source,
                "fusion": s.fusion,
                "command": s.command,
                "train_wall_s": s.train_wall_s,
                "timesteps": s.timesteps,
                "deterministic": s.deterministic,
                "note": next((m.note for m in record.methods.get(env, []) if m.label == "coma"), ""),
            }
            for env, s in record.sources.items()
        },
        "skipped": dict(record.skipped),
        "step_seconds": dict(timings),
        "wall_s": round(time.perf_counter() - started, 1),
    }


def _write_docs(docs: Path, record: RunRecord, figures: Sequence[Path], say: Callable[[str], None]) -> None:
    """The docs copy of RESULTS.md with its figures next to it, and README's results block."""
    fig_docs = docs.parent / "figures"
    fig_docs.mkdir(parents=True, exist_ok=True)
    for f in figures:
        shutil.copyfile(f, fig_docs / f.name)
    docs.write_text(report.results_markdown(record, [fig_docs / f.name for f in figures], docs.parent))
    say(f"wrote {docs}")
    readme = docs.parent.parent / "README.md"
    if write_readme_block(readme, report.readme_paragraph(record)):
        say(f"wrote the results block of {readme}")


def write_readme_block(readme: Path, text: str) -> bool:
    """Replace what lies between :data:`README_MARKERS` in ``readme`` by ``text`` (atomically);
    ``False`` when the file or its markers are missing (nothing is written then)."""
    return write_between_markers(readme, README_MARKERS, text)


def _jsonable(value: Any) -> Any:
    """JSON for the numpy numbers and arrays the results carry."""
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return float(value)


def _ag_weightings(env_names: Sequence[str]) -> dict[str, str]:
    """The AG weighting each map's AG rows flew with (validated per map)."""
    return {env: default_weighting(env) for env in env_names}


def _command(opts: ReproduceOptions) -> str:
    """The short command of the run (its mode flags only)."""
    return " ".join(
        ["sb3-coma reproduce"]
        + (["--train"] if opts.train else [])
        + (["--quick"] if opts.quick else [])
        + (["--record"] if opts.record and not opts.train else [])
    )


def command_line(o: ReproduceOptions) -> str:
    """The ``sb3-coma reproduce`` command line that gives these options."""
    parts = [_command(o)]
    defaults = ReproduceOptions()
    for name, flag in (
        ("unseen_missions", "--unseen-missions"),
        ("sweep_missions", "--sweep-missions"),
        ("wide_trials", "--wide-trials"),
    ):
        if not o.quick and getattr(o, name) != getattr(defaults, name):
            parts.append(f"{flag} {getattr(o, name)}")
    if list(o.env_names) != list(DEFAULT_ENVS):
        parts.append(f"--env {','.join(o.env_names)}")
    if o.trials != defaults.trials and not o.quick:
        parts.append(f"--trials {o.trials}")
    return " ".join(parts)
