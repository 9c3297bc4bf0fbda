"""What the RL part adds: each shipped warm-started model against its own DAgger clone, AG and
(where shipped) COMA from scratch, on the same unseen test missions.

    python -m sb3_coma.experiments.attribution --out docs/learners/attribution.md \\
        env1=runs/clones/env1_s2 env2=runs/clones/env2_s2 env3=runs/clones/env3_s1 \\
        --pair env3=runs/recipe/ft_A/finetuned.zip,runs/recipe/clone_v2/clone.zip

Each ``MAP=RUN`` names the run folder of the map's shipped command re-run up to its warm start
(``sb3-coma train --env MAP --seed S --timesteps 1 --run-dir RUN``, S the shipped seed): its
``warm_start.zip`` is the clone the shipped model was fine-tuned from (the DAgger record's
agreement is compared with the one ``models.json`` recorded, to say whether it is the same clone).
Rows per map: "COMA (oracle warm start)" (the shipped model), "oracle clone (DAgger)" (that clone),
AG, and for env3 "COMA from scratch" (the shipped ``env3-sendfuse-cbam`` arm: same inputs, no
teacher), and with ``--pair`` a fine-tuned model next to the exact clone it started from (a
re-run warm start need not give the shipped run's clone bit for bit: the note says). Verdicts: paired differences on shared missions, the standard error clustered by scene,
Holm over the whole table (``sb3_coma.stats.paired``). These are test missions: the output
reports and chooses nothing. ``--out`` gets the Markdown (atomically) and a JSON twin.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from sb3_coma.app import pretrained as pt
from sb3_coma.app.arguments import add_missions_argument
from sb3_coma.app.evaluation import Method, Missions, fly, parallel_evaluation
from sb3_coma.app.roles import TEST_SPLIT_NOTE
from sb3_coma.common.checkpoints import atomic_write_text
from sb3_coma.common.evaluation import EvaluationResult
from sb3_coma.stats.paired import PairedDifference, holm_adjust, paired_difference, paired_markdown

#: Row names of the three learners, as every generated table spells them.
WARM_LABEL = pt.WARM_START_TITLE
CLONE_LABEL = "oracle clone (DAgger)"
SCRATCH_LABEL = "COMA from scratch"
#: The shipped model without a teacher that has the same inputs as the map's own model.
SCRATCH_MODELS = {"env3": "env3-sendfuse-cbam"}
#: Rows of ``--pair``: a fine-tuned model and its own clone, bit for bit the one it started from.
PAIR_LABELS = ("recipe run: COMA (oracle warm start)", "recipe run: its own clone")
METRICS = ("f1", "entropy")
MISSIONS = 50


def _clone_record(run: Path, name: str) -> str:
    """One line: is the run's clone the one the shipped model started from (same DAgger agreement)?"""
    recorded = pt.read_manifest()["models"][name].get("warm_start", {}).get("agreement")
    today = json.loads((run / "warm_start.json").read_text()).get("agreement")
    if recorded is None or today is None:
        return f"{name}: no DAgger agreement recorded to compare"
    same = abs(float(recorded) - float(today)) < 1e-9
    verdict = "the same clone" if same else "a re-run of the warm start that differs from the shipped run's"
    return f"{name}: DAgger agreement {float(today):.6f} here, {float(recorded):.6f} recorded: {verdict}"


def fly_map(name: str, run: Path, missions: int, pair: tuple[str, str] | None = None) -> dict[str, EvaluationResult]:
    """Every row of one map on the same ``missions`` unseen missions (``pair``: a fine-tuned model
    and the very clone it was fine-tuned from, e.g. a recipe run of ``sb3-coma study dagger``)."""
    unseen = Missions(env=name, protocol="unseen", count=missions)
    methods = [
        Method(WARM_LABEL, name),
        Method(CLONE_LABEL, str(run / "warm_start.zip"), fusion="sendfuse"),
        Method("ag", "ag"),
    ]
    if name in SCRATCH_MODELS:
        methods.append(Method(SCRATCH_LABEL, SCRATCH_MODELS[name]))
    if pair is not None:
        methods += [Method(label, model, fusion="sendfuse") for label, model in zip(PAIR_LABELS, pair)]
    return {method.label: fly(method, unseen) for method in methods}


def comparisons(flown: dict[str, EvaluationResult]) -> list[tuple[str, str]]:
    """The pairs of a map: what fine-tuning adds (warm start - clone), each against AG, and the
    warm start against COMA from scratch."""
    pairs = [(WARM_LABEL, CLONE_LABEL), (WARM_LABEL, "ag"), (CLONE_LABEL, "ag")]
    if SCRATCH_LABEL in flown:
        pairs += [(WARM_LABEL, SCRATCH_LABEL), (SCRATCH_LABEL, "ag")]
    if PAIR_LABELS[0] in flown:
        pairs += [PAIR_LABELS]
    return pairs


def report(results: dict[str, dict[str, EvaluationResult]], notes: list[str]) -> tuple[str, list[dict[str, Any]]]:
    """The Markdown (means per row, then the paired verdicts, one Holm family) and its JSON rows."""
    keys = [(env, a, b, m) for env, flown in results.items() for a, b in comparisons(flown) for m in METRICS]
    diffs: list[PairedDifference] = holm_adjust(
        [paired_difference(results[env][a], results[env][b], m) for env, a, b, m in keys]
    )
    lines = ["| map | method | F1 @100% | entropy @100% |", "| --- | --- | ---: | ---: |"]
    for env, flown in results.items():
        for label, res in flown.items():
            f1, entropy = res.f1[:, -1], res.entropy[:, -1]
            lines.append(
                f"| {env} | {label} | {f1.mean():.4f} ± {f1.std():.4f} | {entropy.mean():.4f} ± {entropy.std():.4f} |"
            )
    missions = next(iter(next(iter(results.values())).values())).n_trials
    text = (
        f"{missions} unseen missions per map (split test, random starts, env seeds 0..{missions - 1}), moderate "
        f"noise, final step of the budget, argmax actions; {TEST_SPLIT_NOTE}.\n\n"
        + "\n".join(f"- {note}" for note in notes)
        + "\n\nMean ± std over missions:\n\n"
        + "\n".join(lines)
        + "\n\nPaired (a - b on the same missions; standard error clustered by scene, Holm over this table):\n\n"
        + paired_markdown(diffs, [env for env, _, _, _ in keys], adjust=False)
    )
    rows = [
        {"env": env, **{k: v for k, v in d.as_dict().items() if k != "per_scene"}} for (env, *_), d in zip(keys, diffs)
    ]
    return text, rows


def _pairs(specs: Sequence[str]) -> dict[str, tuple[str, str]] | None:
    """``--pair MAP=FINETUNED,CLONE`` values by map; ``None`` when one is malformed or names no file."""
    pairs: dict[str, tuple[str, str]] = {}
    for spec in specs:
        name, _, files = spec.partition("=")
        tuned, _, clone = files.partition(",")
        if not (name and Path(tuned).is_file() and Path(clone).is_file()):
            return None
        pairs[name] = (tuned, clone)
    return pairs


def main(argv: Sequence[str] | None = None) -> int:
    """Fly every map's rows, print the tables, write them with ``--out``."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", nargs="+", help="MAP=RUN: the run folder holding the map's warm_start.zip")
    add_missions_argument(parser, MISSIONS, "row (unseen missions)")
    parser.add_argument(
        "--pair",
        action="append",
        default=[],
        metavar="MAP=FINETUNED.zip,CLONE.zip",
        help="also a fine-tuned model and the exact clone it started from (rows and a paired verdict)",
    )
    parser.add_argument("--out", help="also write the Markdown here (and the verdicts as JSON beside it)")
    args = parser.parse_args(argv)
    specs = [spec.split("=", 1) for spec in args.runs]
    bad = next((spec for spec in specs if len(spec) != 2 or not (Path(spec[1]) / "warm_start.zip").is_file()), None)
    if bad is not None:
        print(f"attribution: {'='.join(bad)!r} is not MAP=RUN with RUN/warm_start.zip", file=sys.stderr)
        return 2
    pairs = _pairs(args.pair)
    if pairs is None:
        print(f"attribution: --pair {args.pair!r}: each must be MAP=FINETUNED.zip,CLONE.zip (files)", file=sys.stderr)
        return 2
    notes = [_clone_record(Path(run), name) for name, run in specs]
    with parallel_evaluation("auto"):
        results = {name: fly_map(name, Path(run), args.missions, pairs.get(name)) for name, run in specs}
    text, rows = report(results, notes)
    print(text)
    if args.out:
        command = "python -m sb3_coma.experiments.attribution " + " ".join(argv if argv is not None else sys.argv[1:])
        out = Path(args.out)
        atomic_write_text(out, f"<!-- generated by: {command} -->\n\n{text}")
        atomic_write_text(out.with_suffix(".json"), json.dumps({"command": command, "verdicts": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
