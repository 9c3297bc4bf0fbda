"""RESULTS.md from a ``sb3_coma.experiments.reproduce`` run: every table, every verdict, a paste-ready paragraph.

Nothing here measures anything: it formats what the run measured. Verdicts ("A beats B", "tie")
are read from paired differences on shared missions (``sb3_coma.common.paired``) and never from means.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_coma.common.paired import TIE_SE, PairedDifference, paired_markdown
from sb3_coma.experiments.ag_weighting import VALIDATION_MISSIONS, VALIDATION_SEED, VALIDATION_SPLIT

#: The comparisons the README paragraph states, when both methods were flown.
_KEY_BASELINE_PAIRS = (("ag-k2", "ag"), ("ag-k3", "ag"), ("ag", "lawnmower"), ("ag", "random"))
_NAMES = {
    "ag": "AG",
    "ag-k2": "AG look-ahead 2",
    "ag-k3": "AG look-ahead 3",
    "lawnmower": "the lawnmower",
    "random": "random",
    "coma": "COMA",
    "ippo": "IPPO",
    "mappo": "MAPPO",
}


#: Planners of the generalisation table (listed after the models).
PLANNER_NAMES: tuple[str, ...] = ("ag", "lawnmower", "random")


def _name(label: str) -> str:
    return _NAMES.get(label, label)


# ---------------------------------------------------------------------------------------------
# small tables
# ---------------------------------------------------------------------------------------------
def acceptance_markdown(accept: dict[str, dict[str, Any]]) -> str:
    lines = [
        "| Env | COMA F1 @100% | best baseline F1 | COMA entropy @100% | best baseline entropy | beats all on F1 "
        "(paired) | beats all on entropy (paired) | ties or losses |",
        "| --- | ---: | --- | ---: | --- | :---: | :---: | --- |",
    ]
    for env, a in accept.items():
        c = a["coma"]
        not_won = [
            f"{b} ({m}: {d[m]['verdict']})"
            for b, d in a.get("paired", {}).items()
            for m in ("f1", "entropy")
            if d[m]["verdict"] != "coma better"
        ]
        lines.append(
            f"| {env} | {c['f1']:.4f} ± {c['f1_std']:.4f} | {a['best_f1_baseline']} {a['best_f1']:.4f} | "
            f"{c['entropy']:.4f} ± {c['entropy_std']:.4f} | {a['best_entropy_baseline']} {a['best_entropy']:.4f} | "
            f"{'yes' if a['beats_f1'] else 'NO'} | {'yes' if a['beats_entropy'] else 'NO'} | "
            f"{', '.join(not_won) or '-'} |"
        )
    return "\n".join(lines) + "\n"


def paired_table(rows: Sequence[tuple[str, PairedDifference]], title: str = "Env") -> str:
    """``(group, difference)`` rows: a, b, metric, missions, means, a - b ± s.e., verdict."""

    return paired_markdown([d for _, d in rows], [g for g, _ in rows], first_title=title)


def generalisation_markdown(gen: list[dict[str, Any]]) -> str:
    lines = ["| model (trained on) | evaluated on | F1 @100% | entropy @100% |", "| --- | --- | ---: | ---: |"]
    for g in sorted(gen, key=lambda g: (g["model"] in PLANNER_NAMES, g["model"], g["target"])):
        own = " (own map)" if g["model"] == g["target"] else ""
        lines.append(
            f"| {g['model']}{own} | {g['target']} | {g['f1']:.4f} ± {g['f1_std']:.4f} | "
            f"{g['entropy']:.4f} ± {g['entropy_std']:.4f} |"
        )
    return "\n".join(lines) + "\n"


def prior_markdown(rows: list[dict[str, Any]]) -> str:
    lines = [
        "| Env | untrained prior F1 | trained F1 | untrained prior entropy | trained entropy | prior weights "
        "(class, plain): start -> trained |",
        "| --- | ---: | ---: | ---: | ---: | --- |",
    ]
    for r in rows:
        p, t = r["prior"], r["trained"]
        lines.append(
            f"| {r['env']} | {p['f1']:.4f} ± {p['f1_std']:.4f} | {t['f1']:.4f} ± {t['f1_std']:.4f} | "
            f"{p['entropy']:.4f} ± {p['entropy_std']:.4f} | {t['entropy']:.4f} ± {t['entropy_std']:.4f} | "
            f"{r['weights_start']} -> {r['weights_trained']} |"
        )
    if not rows:
        lines.append("| (no model with a gain prior) | | | | | |")
    return "\n".join(lines) + "\n"


def ablation_verdict(a: dict[str, Any]) -> str:
    others = ", ".join(f"{k} {v:.4f}" for k, v in a["entropy"].items() if k != a["full"])
    full = a["entropy"].get(a["full"])
    head = (
        f"Under {a['noise']} noise, entropy at 100 % (means): {a['full']} "
        f"{'n/a' if full is None else f'{full:.4f}'} vs {others}."
    )
    if a["met"] is None:
        head += " Not every arm was evaluated, so the ablation criterion cannot be checked."
    else:
        head += (
            " By the means (the paper's criterion) the full model is at least as good as every ablation on entropy."
            if a["met"]
            else " By the means the full model is NOT at least as good as every ablation on entropy."
        )
    paired = [d for d in a.get("paired", []) if d.get("noise") == a["noise"]]
    if paired:
        head += (
            " Paired on the same missions: "
            + "; ".join(f"vs {d['b']} {d['diff']:+.4f} ± {d['se']:.4f} ({d['verdict']})" for d in paired)
            + "."
        )
    return head


# ---------------------------------------------------------------------------------------------
# verdict sentences (the README paragraph)
# ---------------------------------------------------------------------------------------------
_FAMILIES = {"global": ("f1", "entropy"), "team": ("team_f1", "team_entropy")}
_PROTOCOL_NAMES = {"paper": "Table I", "unseen": "unseen missions"}


def _short(c: Any, family: str) -> str:
    """What a comparison's two paired differences of one family say: "AG better on both",
    "tie on both", "F1 tie, entropy AG better"."""
    wf, we = (c.diffs[m].winner for m in _FAMILIES[family])
    if wf == we:
        return "tie on both" if wf is None else f"{_name(wf)} better on both"
    return (
        f"F1 {'tie' if wf is None else _name(wf) + ' better'}, entropy {'tie' if we is None else _name(we) + ' better'}"
    )


def _cells(results: Sequence[Any], a: str, b: str) -> list[tuple[str, str, Any]]:
    """(protocol, env, comparison) of ``a`` vs ``b`` in every protocol result that flew both."""
    out = []
    for r in results:
        for c in r.comparisons():
            if (c.a, c.b) == (a, b):
                out.append((r.protocol.name, c.env, c))
    return out


def baseline_sentence(results: Sequence[Any]) -> str:
    """AG vs the lawnmower and random: one sentence, with the exceptions named."""
    parts = []
    for b in ("lawnmower", "random"):
        cells = _cells(results, "ag", b)
        if not cells:
            continue
        exceptions = [
            f"{_PROTOCOL_NAMES.get(p, p)} {env}{'' if fam == 'global' else ' team metrics'}: {_short(c, fam)}"
            for p, env, c in cells
            for fam in _FAMILIES
            if _short(c, fam) != "AG better on both"
        ]
        parts.append(f"{_name(b)}" + (f" (except {'; '.join(exceptions)})" if exceptions else ""))
    if not parts:
        return ""
    where = "every map under " + ("both protocols" if len(results) > 1 else f"the {results[0].protocol.name} protocol")
    return f"AG beats {' and '.join(parts)} on F1 and entropy, global and team metrics, on {where}."


def lookahead_sentence(results: Sequence[Any]) -> str:
    """How often AG with look-ahead 2 / 3 beats, loses to or ties greedy AG."""
    counts = {fam: {"better": 0, "worse": 0, "tie": 0} for fam in _FAMILIES}
    n_maps = set()
    for k in ("ag-k2", "ag-k3"):
        for _, env, c in _cells(results, k, "ag"):
            n_maps.add(env)
            for fam, metrics in _FAMILIES.items():
                for m in metrics:
                    w = c.diffs[m].winner
                    counts[fam]["tie" if w is None else ("better" if w == k else "worse")] += 1
    total = sum(counts["global"].values())
    if not total:
        return ""
    g, t = counts["global"], counts["team"]
    ratios = []
    for k in ("ag-k2", "ag-k3"):
        pairs = [
            (r.results[(env, k)].planning_time_ms.mean(), r.results[(env, "ag")].planning_time_ms.mean())
            for r in results
            for env in r.methods
            if (env, k) in r.results and (env, "ag") in r.results
        ]
        if pairs:
            ratios.append(f"{sum(a for a, _ in pairs) / max(sum(b for _, b in pairs), 1e-12):.1f}x (k={k[-1]})")
    return (
        f"AG with look-ahead 2 or 3 against greedy AG: better in {g['better']}, worse in {g['worse']}, tied in "
        f"{g['tie']} of {total} comparisons on the global map (2 depths x {len(n_maps)} maps x {len(results)} "
        f"protocols x F1 / entropy); better in {t['better']}, worse in {t['worse']}, tied in {t['tie']} on the "
        f"team metrics" + (f"; its planning time per decision is {' and '.join(ratios)} AG's" if ratios else "") + "."
    )


def model_sentence(results: Sequence[Any], label: str) -> str:
    """A learned model's own rows vs AG, per protocol and map."""
    by_protocol: dict[str, list[str]] = {}
    for p, env, c in _cells(results, label, "ag"):
        glob, team = _short(c, "global"), _short(c, "team")
        by_protocol.setdefault(p, []).append(f"{env} {glob}" + ("" if team == glob else f" (team metrics: {team})"))
    if not by_protocol:
        return ""
    return (
        f"{_name(label)} vs AG: "
        + "; ".join(f"{_PROTOCOL_NAMES.get(p, p)}: {', '.join(v)}" for p, v in by_protocol.items())
        + "."
    )


def key_pairs(result: Any) -> list[tuple[str, str]]:
    """The comparisons the paragraph states: each learned model's own row vs AG, then AG's."""
    labels = {m.label for ms in result.methods.values() for m in ms}
    learned = [
        lab
        for lab in dict.fromkeys(m.label for ms in result.methods.values() for m in ms if m.learned)
        if "[" not in lab
    ]  # the map's own models, not the other ablation arms
    return [(m, "ag") for m in learned if "ag" in labels] + [p for p in _KEY_BASELINE_PAIRS if set(p) <= labels]


def readme_paragraph(run: Any) -> str:
    """The paragraph for README's results section: only verdicts the paired tests support."""
    s = run.summary
    results = [r for r in (run.paper, run.unseen) if r is not None]
    missions = " and ".join(
        f"{r.n_trials} {'seeded trials (Table I, split paper)' if r.protocol.name == 'paper' else 'unseen missions (split test, random starts)'}"
        for r in results
    )
    parts = [
        f"From `{s['command_line']}` ({s['date'][:10]}, `{s['noise']}` noise, {missions} per method): every "
        f"verdict is a paired difference on shared missions at 100 % of the budget (± standard error; within "
        f"{TIE_SE:g} standard errors it is a tie); the tables are in docs/RESULTS.md. AG plans with the entropy "
        f"weighting chosen per map on validation missions ({', '.join(f'{e} {w}' for e, w in s['ag_weighting'].items())})."
    ]
    parts += [baseline_sentence(results), lookahead_sentence(results)]
    learned = list(dict.fromkeys(a for r in results for a, b in key_pairs(r) if b == "ag" and not a.startswith("ag")))
    outdated = sorted({m.note for ms in run.methods.values() for m in ms if m.learned and m.note})
    for label in learned:
        parts.append(model_sentence(results, label))
    if outdated and learned:
        parts.append(
            "The COMA rows are the shipped models, which are outdated on this world ("
            + "; ".join(outdated)
            + "): they are those models' numbers, not what COMA reaches once retrained."
        )
    if run.sweep is not None:
        parts.append(sweep_sentence(run.sweep))
    return " ".join(p for p in parts if p)


def sweep_sentence(sweep: Any) -> str:
    """How the arms fare against the reference (AG) across the sweep, from the paired columns."""
    counts = {m: {"arm": 0, "ref": 0, "tie": 0} for m in ("entropy", "team_entropy")}
    arms = [a for a in sweep.arms if a != sweep.reference]
    for point in sweep.points:
        for arm in arms:
            if (arm, point) not in sweep.results:
                continue
            for m in counts:
                d = sweep.vs_reference(arm, point, m)
                counts[m]["tie" if d.winner is None else ("arm" if d.winner == arm else "ref")] += 1
    head = (
        f"Noise sweep ({sweep.env}, {sweep.n_missions} shared missions per setting, {len(sweep.points)} settings "
        f"of sigma, a_low, drop probability and decoder)"
    )
    if not arms:
        return f"{head}: {_name(sweep.reference)} only."
    e, t = counts["entropy"], counts["team_entropy"]
    n = sum(e.values())
    return (
        f"{head}, each trained arm ({', '.join(arms)}) minus {_name(sweep.reference)}: global entropy better at "
        f"{e['arm']}, worse at {e['ref']}, tied at {e['tie']} of {n} arm-settings; team entropy better at "
        f"{t['arm']}, worse at {t['ref']}, tied at {t['tie']}."
    )


# ---------------------------------------------------------------------------------------------
# the page
# ---------------------------------------------------------------------------------------------
def _models_section(run: Any) -> list[str]:
    lines = [
        "## Models",
        "",
        "| Env | method | source | fusion | actions | status | joint steps | training wall-clock (s) | retrain "
        "command |",
        "| --- | --- | --- | --- | --- | --- | ---: | ---: | --- |",
    ]
    for env, src in run.sources.items():
        wall = "n/a" if src.train_wall_s is None else f"{float(src.train_wall_s):.1f}"
        acts = "argmax" if src.deterministic else "sampled (seeded)"
        note = next((m.note for m in run.methods.get(env, []) if m.label == "coma"), "")
        lines.append(
            f"| {env} | coma | {src.source if src.source == 'shipped' else 'trained by this run'} | "
            f"{src.fusion} | {acts} | {note or 'current'} | {src.timesteps} | {wall} | `{src.command}` |"
        )
        for m in run.methods.get(env, []):
            if m.learned and m.label != "coma":
                info = getattr(m.policy, "pretrained_info", {}) or {}
                lines.append(
                    f"| {env} | {m.label} | shipped | {m.fusion} | "
                    f"{'argmax' if m.deterministic in (None, True) else 'sampled (seeded)'} | "
                    f"{m.note or 'current'} | {info.get('timesteps', 'n/a')} | "
                    f"{info.get('train_wall_s', 'n/a')} | `{info.get('command', '')}` |"
                )
    if len(lines) == 4:
        lines.append("| (none) | | | | | baseline rows only | | | |")
    learned = {m.kind for ms in run.methods.values() for m in ms if m.learned}
    missing = [k.upper() for k in ("ippo", "mappo") if k not in learned]
    lines += [
        "",
        "Hyperparameters: `zoo_configs/coma.yml`; how they were chosen: `docs/training.md` (history: `docs/tuning_log.md`)."
        + (
            f" No {' / '.join(missing)} models are shipped yet, so they have no rows (they get rows as soon as "
            'models.json lists them with `"algo": "ippo"` / `"mappo"`).'
            if missing
            else ""
        ),
        "",
    ]
    return lines


def _ag_section(run: Any) -> list[str]:

    w = run.summary["ag_weighting"]
    return [
        "## AG's entropy weighting (chosen on validation missions)",
        "",
        "AG scores moves by expected information gain under the class-weighted (`class`, ipp-marl's) or the plain "
        f"binary entropy (`plain`). The default per map family is the one that won on {VALIDATION_MISSIONS} "
        f"validation missions per weighting (split `{VALIDATION_SPLIT}`, env seeds {VALIDATION_SEED}.."
        f"{VALIDATION_SEED + VALIDATION_MISSIONS - 1}, never the test split nor Table I's missions), measured "
        "by `sb3-coma ag-weighting` and recorded with its numbers in "
        "`sb3_coma.baselines.adaptive_gain.WEIGHTING_BY_MAP`: "
        + ", ".join(f"{e} `{v}`" for e, v in w.items())
        + ". Every AG row below (look-ahead ones too) uses it.",
        "",
    ]


def _protocol_section(result: Any, title: str, extra: Sequence[str] = ()) -> list[str]:
    return [
        f"## {title}",
        "",
        result.describe() + ". Mean ± std over the missions; best mean of each map in bold; "
        '"ms per UAV decision" is the planning time `evaluate` measures (batched over the missions).',
        "",
        "At 100 % of the budget, all four metrics:",
        "",
        result.final_table(),
        "",
        "Global map (the paper's metrics):",
        "",
        result.table("global"),
        "",
        "Team metrics (each UAV's own map M_i, averaged over UAVs):",
        "",
        result.table("team"),
        "",
        f"Paired verdicts at 100 % (a − b ± standard error over the shared missions; the method in brackets is "
        f'better, "tie" when |a − b| is within {TIE_SE:g} standard errors):',
        "",
        result.verdict_table(),
        "",
        *extra,
    ]


def results_markdown(run: Any, figures: Sequence[Path], base: Path) -> str:
    """The RESULTS.md report of a run (figure paths relative to ``base``)."""
    s = run.summary
    lines = [
        "# Results",
        "",
        f"Generated by `{s['command_line']}` on {s['date']} (Python {s['python']}, {s['machine']}, CPU, one torch "
        f"thread) in {s['wall_s']:.0f} s. 4 UAVs, budget 15, channel noise `{s['noise']}`. Every number on this page "
        'is measured by that command and every "A beats B" is a paired test on shared missions; regenerate it '
        "with `sb3-coma reproduce` (shipped models) or `sb3-coma reproduce --train` (retrain first).",
        "",
        "## Paragraph for README's results section",
        "",
        "> " + readme_paragraph(run),
        "",
        *_models_section(run),
        *_ag_section(run),
    ]
    if run.paper is not None:
        acc = s.get("acceptance", {})
        verdict = all(a["beats_all"] for a in acc.values()) if acc else False
        lines += _protocol_section(
            run.paper,
            "Table I (paper protocol)",
            [
                "### Acceptance: COMA vs every baseline at 100 % of the budget (paired)",
                "",
                acceptance_markdown(acc),
                "",
                (
                    "**Verdict: COMA beats every baseline on both F1 and entropy on every evaluated environment (paired "
                    "tests).**"
                )
                if verdict
                else "**Verdict: COMA does NOT beat every baseline on both metrics everywhere (paired tests); see the NO cells "
                "above.**",
                "",
            ],
        )
    lines += [
        "## What training adds: the untrained gain prior vs the trained model (100 % budget)",
        "",
        "The shipped actor adds a learned mix of each action's expected information gain to its logits "
        '(docs/training.md, "Gain prior"). "untrained prior" flies the same model with that mix at its '
        "starting weights and the network's own term removed, argmax actions: the greedy planner the "
        "training starts from.",
        "",
        prior_markdown(s.get("untrained_prior", [])),
        "",
    ]
    if s.get("ablation"):
        lines += [
            "## Ablation: SenDFuse x CBAM under three noise levels (env3)",
            "",
            "The paper's Table II / Fig. 4. SenDFuse+CBAM is the env3 model above; the other three arms are the "
            "shipped models `env3-sendfuse-cnn`, `env3-mean-cbam`, `env3-mean-cnn`; each flown with the fusion "
            "it was trained with, the Table I missions, argmax actions, at every noise level. Best of each "
            "noise level in bold. More in docs/ABLATION.md.",
            "",
            run.sections.get("ablation", ""),
            "",
            "The full model minus each other arm, entropy at 100 %, paired on the same missions:",
            "",
            run.sections.get("ablation_paired", ""),
            "",
            f"**{ablation_verdict(s['ablation'])}**",
            "",
        ]
    if run.sections.get("paired"):
        lines += [
            "## A paired check on more missions",
            "",
            "Each pair of methods flies the same paper-split missions, more of them than Table I, and the "
            f"per-mission difference is averaged: ± is its standard error, and a difference within {TIE_SE:g} "
            "standard errors is called a tie (`sb3_coma.common.paired`; `--wide-trials`).",
            "",
            run.sections["paired"],
            "",
        ]
    if run.unseen is not None:
        lines += _protocol_section(run.unseen, "Unseen protocol (split test, random starts)")
    if run.sweep is not None:
        sw = run.sweep
        lines += [
            "## Noise sweep",
            "",
            f"`sb3-coma noise-sweep`: {sw.env}, {sw.n_missions} shared missions per setting (split "
            f"`{sw.env_options.get('split')}`, env seeds {sw.seed}..{sw.seed + sw.n_missions - 1}, random starts), "
            f"{len(sw.points)} settings: one axis at a time around the moderate preset (sigma 0.02, a_low 0.8, "
            "no drops), each under both decoders. Values at 100 % of the budget, mean ± standard error; the "
            f"last two columns are the arm minus {_name(sw.reference)} on the same missions (paired). The "
            "global map never passes through the channel, so noise moves it only through the decisions; the "
            "team metrics read the UAVs' own maps, which the channel feeds.",
            "",
            sweep_sentence(sw),
            "",
            run.sections.get("noise_sweep", ""),
            "",
        ]
    lines += [
        "## Generalisation (100 % budget)",
        "",
        "Each env's model flown on the other maps and on a fresh env1 star layout (`map_seed=7`; env1's default "
        "is 0), same trials and noise; baselines on the fresh layout for reference.",
        "",
        generalisation_markdown(s.get("generalisation", [])),
        "",
    ]
    if run.sections.get("latency"):
        lines += [
            "## Deployment latency and cost (per UAV decision, batch of one, one thread)",
            "",
            "What one UAV computes on board per step (`sb3_coma.experiments.costs`): the fusion of the maps it received "
            "(own + 3 received, all valid: the worst case) and the actor, in PyTorch and in ONNX Runtime "
            "(`sb3-coma export`'s graphs); AG with look-ahead k = 1, 2, 3 (`planner.predict` on one mission / "
            "number of UAVs). Medians of repeated calls; the machine is shared, so these are upper bounds.",
            "",
            run.sections["latency"],
            "",
        ]
    if run.skipped:
        lines += ["## Skipped", ""] + [f"* {what}: {why}" for what, why in run.skipped.items()] + [""]
    if figures:
        lines += ["## Figures", ""]
        for f in figures:
            lines += [f"![{Path(f).stem}]({os.path.relpath(f, base)})", ""]
    return "\n".join(lines) + "\n"
