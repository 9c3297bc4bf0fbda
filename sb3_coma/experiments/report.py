"""RESULTS.md from a ``sb3_coma.experiments.reproduce`` run: every table, every verdict, a paste-ready paragraph.

Nothing here measures anything: it formats what the run measured. Verdicts ("A beats B", "tie",
"one scene: no verdict") are read from paired differences on shared missions, clustered by scene and
Holm-corrected per table (``sb3_coma.stats.paired``, docs/statistics.md), and never from means.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from sb3_coma.app.pretrained import WARM_START_TITLE
from sb3_coma.app.roles import AG_WEIGHTING_MISSIONS, AG_WEIGHTING_SEED, AG_WEIGHTING_SPLIT
from sb3_coma.stats.paired import NO_VERDICT, PairedDifference, p_text, paired_markdown

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


#: How every verdict on the page is reached (docs/statistics.md), for the sentences that say so.
RULE = (
    "± is the CR2 standard error clustered by scene (missions of one scene are not independent); the method "
    "named is better when a two-sided t test with Bell-McCaffrey degrees of freedom (at most scenes − 1) gives "
    'p < 0.05 after Holm\'s correction over its table, "tie" otherwise, and "one scene: no verdict" when '
    "every mission shares one scene (± is then over the noise draws of that one mission; docs/statistics.md)"
)


#: The title of the map's own model when it was warm-started from the oracle: the RL part is a
#: fine-tuning of a behaviour clone, and every generated sentence and table says so.
WARM_TITLE = WARM_START_TITLE


def _name(label: str, titles: Mapping[str, str] | None = None) -> str:
    return (titles or {}).get(label) or _NAMES.get(label, label)


def teacher_missions(info: Mapping[str, Any]) -> int:
    """Teacher-labelled missions a model saw before COMA (its DAgger warm start: rounds x missions)."""
    spec = info.get("warm_start") or {}
    return int(spec.get("rounds", 0) or 0) * int(spec.get("missions", 0) or 0) if isinstance(spec, Mapping) else 0


def model_titles(run: Any) -> dict[str, str]:
    """``{"coma": WARM_TITLE}`` when every map's own model was warm-started, else nothing."""
    warm = [teacher_missions(src.info) > 0 for src in run.sources.values()]
    return {"coma": WARM_TITLE} if warm and all(warm) else {}


def _dict_cell(d: dict[str, Any]) -> str:
    """``a - b ± s.e., p (verdict)`` from ``PairedDifference.as_dict()``; with one scene the plain
    s.e. and what it is over (dicts written before the clustered test: the plain s.e.)."""
    se = d.get("se_clustered", d["se"])
    if d["verdict"] == NO_VERDICT or se is None or se != se:
        return f"{d['diff']:+.4f} ± {d['se']:.4f} over {d.get('unit', 'missions')} ({d['verdict']})"
    return f"{d['diff']:+.4f} ± {se:.4f}, p {p_text(float(d.get('p_holm', d.get('p_value', 'nan'))))} ({d['verdict']})"


def _verdict_word(d: PairedDifference, titles: Mapping[str, str] | None = None) -> str:
    """The verdict in words: "AG better", "tie" or "no verdict" (one scene)."""
    if d.verdict == NO_VERDICT:
        return "no verdict"
    return "tie" if d.winner is None else f"{_name(d.winner, titles)} better"


def _has_verdicts(result: Any) -> bool:
    """Whether any comparison of a protocol result could be tested (more than one scene)."""
    return any(d.df >= 1 for c in result.comparisons() for d in c.diffs.values())


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
        head += " Paired on the same missions: " + "; ".join(f"vs {d['b']} {_dict_cell(d)}" for d in paired) + "."
    return head


# ---------------------------------------------------------------------------------------------
# verdict sentences (the README paragraph)
# ---------------------------------------------------------------------------------------------
_FAMILIES = {"global": ("f1", "entropy"), "team": ("team_f1", "team_entropy")}
_PROTOCOL_NAMES = {"paper": "Table I", "unseen": "unseen missions"}


def _short(c: Any, family: str, titles: Mapping[str, str] | None = None) -> str:
    """What a comparison's two paired differences of one family say: "AG better on both",
    "tie on both", "F1 tie, entropy AG better", "no verdict on both" (one scene)."""
    wf, we = (_verdict_word(c.diffs[m], titles) for m in _FAMILIES[family])
    return f"{wf} on both" if wf == we else f"F1 {wf}, entropy {we}"


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
    counts = {fam: {"better": 0, "worse": 0, "tie": 0, "none": 0} for fam in _FAMILIES}
    n_maps = set()
    for k in ("ag-k2", "ag-k3"):
        for _, env, c in _cells(results, k, "ag"):
            n_maps.add(env)
            for fam, metrics in _FAMILIES.items():
                for m in metrics:
                    d = c.diffs[m]
                    w = "none" if d.verdict == NO_VERDICT else ("tie" if d.winner is None else d.winner)
                    counts[fam][w if w in ("none", "tie") else ("better" if w == k else "worse")] += 1
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
    none = f", no verdict (one scene) in {g['none']}" if g["none"] else ""
    return (
        f"AG with look-ahead 2 or 3 against greedy AG: better in {g['better']}, worse in {g['worse']}, tied in "
        f"{g['tie']}{none} of {total} comparisons on the global map (2 depths x {len(n_maps)} maps x {len(results)} "
        f"protocols x F1 / entropy); better in {t['better']}, worse in {t['worse']}, tied in {t['tie']} on the "
        f"team metrics" + (f"; its planning time per decision is {' and '.join(ratios)} AG's" if ratios else "") + "."
    )


def model_sentence(results: Sequence[Any], label: str, titles: Mapping[str, str] | None = None) -> str:
    """A learned model's own rows vs AG, per protocol and map."""
    by_protocol: dict[str, list[str]] = {}
    for p, env, c in _cells(results, label, "ag"):
        glob, team = _short(c, "global", titles), _short(c, "team", titles)
        by_protocol.setdefault(p, []).append(f"{env} {glob}" + ("" if team == glob else f" (team metrics: {team})"))
    if not by_protocol:
        return ""
    return (
        f"{_name(label, titles)} vs AG: "
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
        f"verdict is a paired difference on shared missions at 100 % of the budget ({RULE}); the tables are in "
        f"docs/RESULTS.md. AG plans with the entropy weighting chosen per map on validation missions "
        f"({', '.join(f'{e} {w}' for e, w in s['ag_weighting'].items())})."
    ]
    untested = [r for r in results if not _has_verdicts(r)]
    results = [r for r in results if _has_verdicts(r)]
    parts += [
        f"{_PROTOCOL_NAMES.get(r.protocol.name, r.protocol.name)} has one scene per map (its missions are noise "
        "draws of one mission), so it gives no verdict: its numbers describe that mission only."
        for r in untested
    ]
    if not results:
        return " ".join(parts)
    parts += [baseline_sentence(results), lookahead_sentence(results)]
    learned = list(dict.fromkeys(a for r in results for a, b in key_pairs(r) if b == "ag" and not a.startswith("ag")))
    outdated = sorted({m.note for ms in run.methods.values() for m in ms if m.learned and m.note})
    titles = model_titles(run)
    for label in learned:
        parts.append(model_sentence(results, label, titles))
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
    """How the arms fare against the reference (AG) across the sweep, from the paired columns
    (Holm-adjusted over the sweep's table, ``NoiseSweepResult.paired``)."""
    counts = {m: {"arm": 0, "ref": 0, "tie": 0, "none": 0} for m in ("entropy", "team_entropy")}
    arms = [a for a in sweep.arms if a != sweep.reference]
    for (arm, _, m), d in sweep.paired().items():
        if arm in arms and m in counts:
            w = "none" if d.verdict == NO_VERDICT else ("tie" if d.winner is None else d.winner)
            counts[m][w if w in ("none", "tie") else ("arm" if w == arm else "ref")] += 1
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
        f"{t['arm']}, worse at {t['ref']}, tied at {t['tie']}"
        + (f" (no verdict, one scene, at {e['none']} and {t['none']})" if e["none"] or t["none"] else "")
        + "."
    )


# ---------------------------------------------------------------------------------------------
# the page
# ---------------------------------------------------------------------------------------------
def _models_section(run: Any) -> list[str]:
    lines = [
        "## Models",
        "",
        "| Env | method | source | fusion | actions | status | teacher-labelled missions | COMA joint steps | "
        "training wall-clock (s) | retrain command |",
        "| --- | --- | --- | --- | --- | --- | ---: | ---: | ---: | --- |",
    ]
    for env, src in run.sources.items():
        wall = "n/a" if src.train_wall_s is None else f"{float(src.train_wall_s):.1f}"
        acts = "argmax" if src.deterministic else "sampled (seeded)"
        note = next((m.note for m in run.methods.get(env, []) if m.label == "coma"), "")
        taught = teacher_missions(src.info)
        lines.append(
            f"| {env} | {WARM_TITLE if taught else 'coma'} | "
            f"{src.source if src.source == 'shipped' else 'trained by this run'} | "
            f"{src.fusion} | {acts} | {note or 'current'} | {taught} | {src.timesteps} | {wall} | `{src.command}` |"
        )
        for m in run.methods.get(env, []):
            if m.learned and m.label != "coma":
                info = getattr(m.policy, "pretrained_info", {}) or {}
                lines.append(
                    f"| {env} | {m.label} | shipped | {m.fusion} | "
                    f"{'argmax' if m.deterministic in (None, True) else 'sampled (seeded)'} | "
                    f"{m.note or 'current'} | {teacher_missions(info)} | {info.get('timesteps', 'n/a')} | "
                    f"{info.get('train_wall_s', 'n/a')} | `{info.get('command', '')}` |"
                )
    if len(lines) == 4:
        lines.append("| (none) | | | | | baseline rows only | | | | |")
    learned = {m.kind for ms in run.methods.values() for m in ms if m.learned}
    missing = [k.upper() for k in ("ippo", "mappo") if k not in learned]
    lines += [
        "",
        "Hyperparameters: `zoo_configs/coma.yml`; how they were chosen: `docs/training.md` (history: `docs/tuning_log.md`)."
        + (
            f" No {' / '.join(missing)} models are shipped (they would take the shipped models past their 15 MB "
            "budget), so they have no rows here: COMA against IPPO and MAPPO with the same inputs, three seeds "
            "each, selected by the same validation rule, is in `docs/learners/` (rows here as soon as "
            'models.json lists them with `"algo": "ippo"` / `"mappo"`).'
            if missing
            else ""
        ),
        "",
    ]
    return lines


def _mean_std(values: Sequence[float]) -> str:
    if len(values) < 2:
        return "n/a (one seed)"
    mean = sum(values) / len(values)
    std = (sum((v - mean) ** 2 for v in values) / (len(values) - 1)) ** 0.5
    return f"{mean:.4f} ± {std:.4f}"


def seeds_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The seed-spread table: per shipped learner, the shipped seed's unseen result next to the
    mean ± sample std over every seed trained for it (rows from ``models.json``)."""
    out = [
        "| model | seeds trained | shipped | F1 (shipped) | F1 over seeds | entropy (shipped) | entropy over seeds |",
        "| --- | --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        metrics = r["metrics"]
        shipped = metrics.get(r["shipped"], {})
        cells = []
        for key in ("f1", "entropy"):
            cells.append(f"{shipped[key]:.4f}" if key in shipped else "not recorded")
            cells.append(_mean_std([m[key] for m in metrics.values()]) if metrics else "not recorded")
        out.append(
            f"| {r['model']} | {len(r['candidates'])} ({', '.join(c.split()[-1] for c in r['candidates'])}) | "
            f"{r['shipped']} | {cells[0]} | {cells[1]} | {cells[2]} | {cells[3]} |"
        )
    return "\n".join(out)


def _seeds_section(run: Any) -> list[str]:
    rows = run.summary.get("seed_spread")
    if not rows:
        return []
    missions = max((r["missions"] or 0) for r in rows)
    return [
        "## Seed spread and selection (shipped models)",
        "",
        "Every shipped model is the best of its seeds on the validation missions (split train, env seeds 1000+; "
        "the test split chose nothing). The unseen-protocol result of each seed's selected checkpoint "
        f"({missions} test missions, final F1 / entropy of the global belief, argmax) is recorded when the model "
        "ships (`python -m sb3_coma.experiments.ship_models`, models.json `seeds_unseen`); the shipped seed's "
        "column is flown from the shipped file itself (half precision), as every other table flies it "
        "(`ship_models --rescore`; the other seeds' full-precision checkpoints are as recorded, their run folders "
        "being gone); ± is the sample standard deviation over seeds. A model trained with one seed has no "
        "spread: its verdicts carry no seed-to-seed variance.",
        "",
        seeds_markdown(rows),
        "",
    ]


def _ag_section(run: Any) -> list[str]:

    w = run.summary["ag_weighting"]
    return [
        "## AG's entropy weighting (chosen on validation missions)",
        "",
        "AG scores moves by expected information gain under the class-weighted (`class`, ipp-marl's) or the plain "
        f"binary entropy (`plain`). The default per map family is the one that won on {AG_WEIGHTING_MISSIONS} "
        f"validation missions per weighting (split `{AG_WEIGHTING_SPLIT}`, env seeds {AG_WEIGHTING_SEED}.."
        f"{AG_WEIGHTING_SEED + AG_WEIGHTING_MISSIONS - 1}, never the test split nor Table I's missions), measured "
        "by `sb3-coma ag-weighting` and recorded with its numbers in "
        "`sb3_coma.baselines.adaptive_gain.WEIGHTING_BY_MAP`: "
        + ", ".join(f"{e} `{v}`" for e, v in w.items())
        + ". Every AG row below (look-ahead ones too) uses it.",
        "",
    ]


def _protocol_section(result: Any, title: str, extra: Sequence[str] = (), scenes: bool = False) -> list[str]:
    """One protocol's tables and verdicts; ``scenes``: also the per-scene breakdown (unseen protocol)."""
    breakdown = [
        "Scene by scene (each map's first comparison, entropy at 100 %): a verdict rests on the scenes, "
        "not on the number of missions.",
        "",
        result.scene_table(),
        "",
    ]
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
        f"Paired verdicts at 100 % (a − b over the shared missions, p after Holm's correction over this table; {RULE}):",
        "",
        result.verdict_table(),
        "",
        *(breakdown if scenes else []),
        *extra,
    ]


#: Said under Table I: its env2 / env3 map is the paper's scene, which our splits count as a train scene.
TABLE_I_CAVEAT = (
    "Caveat: Table I's env2 and env3 map is the paper's scene, which is a *train* scene of the splits the "
    "models learn on (the shipped scene is never a test scene), and env1's paper star is one layout: these "
    "rows compare with the paper, they are not an unseen test; the unseen protocol below is."
)


def _acceptance_verdict(acc: dict[str, dict[str, Any]]) -> str:
    """The bold line under the acceptance table: beats every baseline, does not, or (one scene per
    map, every paired verdict "no verdict") cannot be told on Table I's missions."""
    if acc and all(a["beats_all"] for a in acc.values()):
        return "**Verdict: COMA beats every baseline on both F1 and entropy on every evaluated environment (paired tests).**"
    verdicts = [d[m]["verdict"] for a in acc.values() for d in a.get("paired", {}).values() for m in d]
    if verdicts and all(v == NO_VERDICT for v in verdicts):
        return (
            "**No verdict: Table I flies one mission per map (its trials are noise draws of it), so the paired "
            "test has one scene; the unseen protocol below is where the verdicts are.**"
        )
    return (
        "**Verdict: COMA does NOT beat every baseline on both metrics everywhere (paired tests); see the NO cells "
        "above.**"
    )


def _paper_section(run: Any) -> list[str]:
    """Table I's tables and verdicts, then the acceptance table and its verdict."""
    acc = run.summary.get("acceptance", {})
    return _protocol_section(
        run.paper,
        "Table I (paper protocol)",
        [
            TABLE_I_CAVEAT,
            "",
            "### Acceptance: COMA vs every baseline at 100 % of the budget (paired)",
            "",
            acceptance_markdown(acc),
            "",
            _acceptance_verdict(acc),
            "",
        ],
    )


def _ablation_section(run: Any) -> list[str]:
    """The env3 ablation table, the full model minus each arm (paired) and the verdict sentence."""
    return [
        "## Ablation: SenDFuse x CBAM under three noise levels (env3)",
        "",
        "The paper's Table II / Fig. 4. The four arms are the shipped models `env3-sendfuse-cbam`, "
        "`env3-sendfuse-cnn`, `env3-mean-cbam` and `env3-mean-cnn`, all trained by COMA from scratch with one "
        "recipe (the `scratch` variant of `zoo_configs/coma.yml`; the warm-started env3 model would compare the "
        "warm start, not the fusion and the extractor); each flown with the fusion it was trained with, the "
        "unseen protocol's missions, argmax actions, at every noise level. Best of each noise level in bold. "
        "More in docs/ABLATION.md.",
        "",
        run.sections.get("ablation", ""),
        "",
        "The full model minus each other arm, entropy at 100 %, paired on the same missions:",
        "",
        run.sections.get("ablation_paired", ""),
        "",
        f"**{ablation_verdict(run.summary['ablation'])}**",
        "",
    ]


def _paired_check_section(run: Any) -> list[str]:
    """``--wide-trials``: more paper-split missions, which are still one scene per map."""
    return [
        "## A paired check on more missions",
        "",
        "Each pair of methods flies the same paper-split missions, more of them than Table I, and the "
        f"per-mission difference is averaged ({RULE}; `sb3_coma.stats.paired`; `--wide-trials`). The paper "
        "split is one scene per map, so these are noise draws of one mission: the numbers describe that "
        "mission, and no verdict can generalise beyond it.",
        "",
        run.sections["paired"],
        "",
    ]


def _sweep_section(run: Any) -> list[str]:
    """The noise sweep: its settings, the sentence of verdicts and the table."""
    sw = run.sweep
    return [
        "## Noise sweep",
        "",
        f"`sb3-coma noise-sweep`: {sw.env}, {sw.n_missions} shared missions per setting (split "
        f"`{sw.env_options.get('split')}`, env seeds {sw.seed}..{sw.seed + sw.n_missions - 1}, random starts), "
        f"{len(sw.points)} settings: one axis at a time around the moderate preset (sigma 0.02, a_low 0.8, "
        "no drops), each under both decoders. Values at 100 % of the budget, mean ± standard error over the "
        f"missions; the last two columns are the arm minus {_name(sw.reference)} on the same missions (paired: "
        "± clustered by scene, p Holm-adjusted over the whole table, docs/statistics.md). The "
        "global map never passes through the channel, so noise moves it only through the decisions; the "
        "team metrics read the UAVs' own maps, which the channel feeds.",
        "",
        sweep_sentence(sw),
        "",
        run.sections.get("noise_sweep", ""),
        "",
    ]


def _prior_section(rows: Any) -> list[str]:
    """What training adds over the greedy planner it starts from (models with a gain prior only)."""
    return [
        "## What training adds: the untrained gain prior vs the trained model (100 % budget)",
        "",
        "This actor adds a learned mix of each action's expected information gain to its logits "
        '(docs/training.md, "Gain prior"). "untrained prior" flies the same model with that mix at its '
        "starting weights and the network's own term removed, argmax actions: the greedy planner the "
        "training starts from.",
        "",
        prior_markdown(rows),
        "",
    ]


def _user_maps_section(table: str) -> list[str]:
    """The models on a user's own photos, read as a user reads them."""
    return [
        "## A user's own map",
        "",
        "Ten Landsat-8 colour crops that no model trained on (2.4 km at 30 m; env3 trains on Sentinel-2 "
        "scenes, env2 on the Landsat thermal band), read as a user reads a photo: `map_path=` and the "
        "`threshold` rule (`python -m sb3_coma.experiments.user_maps`, images and provenance in "
        "`sb3_coma/experiments/user_map_images/`). Each image is one scene: mission k of image i is env "
        "seed 5i + k, random starts; ± clustered by image, Holm over the four comparisons.",
        "",
        table,
        "",
    ]


def _latency_section(table: str) -> list[str]:
    """What one UAV computes on board per decision, and what it costs."""
    return [
        "## Deployment latency and cost (per UAV decision, batch of one, one thread)",
        "",
        "What one UAV computes on board per step (`sb3_coma.experiments.costs`): the fusion of the maps it received "
        "(own + 3 received, all valid: the worst case) and the actor, in PyTorch and in ONNX Runtime "
        "(`sb3-coma export`'s graphs); AG with look-ahead k = 1, 2, 3 (`planner.predict` on one mission / "
        "number of UAVs). Medians of repeated calls; the machine is shared, so these are upper bounds.",
        "",
        table,
        "",
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
        *_seeds_section(run),
        *_ag_section(run),
    ]
    if run.paper is not None:
        lines += _paper_section(run)
    if s.get("untrained_prior"):  # only models with a gain prior in their logits have this row
        lines += _prior_section(s["untrained_prior"])
    if s.get("ablation"):
        lines += _ablation_section(run)
    if run.sections.get("paired"):
        lines += _paired_check_section(run)
    if run.unseen is not None:
        lines += _protocol_section(run.unseen, "Unseen protocol (split test, random starts)", scenes=True)
    if run.sweep is not None:
        lines += _sweep_section(run)
    lines += [
        "## Generalisation (100 % budget)",
        "",
        "Each env's model flown on the other maps and on a fresh env1 star layout (`map_seed=7`; env1's default "
        "is 0), same trials and noise; baselines on the fresh layout for reference.",
        "",
        generalisation_markdown(s.get("generalisation", [])),
        "",
    ]
    if run.sections.get("user_maps"):
        lines += _user_maps_section(run.sections["user_maps"])
    if run.sections.get("latency"):
        lines += _latency_section(run.sections["latency"])
    if run.skipped:
        lines += ["## Skipped", ""] + [f"* {what}: {why}" for what, why in run.skipped.items()] + [""]
    if figures:
        lines += ["## Figures", ""]
        for f in figures:
            lines += [f"![{Path(f).stem}]({os.path.relpath(f, base)})", ""]
    return "\n".join(lines) + "\n"
