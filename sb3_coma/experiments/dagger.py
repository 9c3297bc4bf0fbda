"""DAgger from the clairvoyant oracle, optional COMA fine-tuning, and a paired unseen comparison.

    python -m sb3_coma.experiments.dagger --env env3 --rounds 8 --missions 128 --out runs/dagger_env3
    python -m sb3_coma.experiments.dagger --env env3 --from runs/dagger_env3/clone.zip \\
        --finetune 18000 --kl 1.0 --out runs/dagger_env3_ft
    python -m sb3_coma.experiments.dagger --env env3 --from runs/dagger_env3/clone.zip \\
        --finetune 18000 --kl 1.0 --set n_epochs=10 --out runs/dagger_env3_ft_epochs_10

Builds the model of the map's config entry (``zoo_configs/coma.yml``: the same networks, inputs
and settings as ``sb3-coma train``), clones the oracle into its actor with
:func:`sb3_coma.uav.imitation.clone_teacher` (or loads a clone with ``--from``), optionally
fine-tunes it with COMA for ``--finetune`` joint steps under a KL pull toward the clone that
decays to zero over the first half (``kl_coef=--kl``), then flies the model, AG and the oracle on
the same ``--missions-eval`` missions (``--split``: the validation missions by default, on which
recipes are chosen; ``--split test`` reports only) and prints the paired verdicts (scene-clustered t test, Holm over the table). Writes ``clone.zip`` or
``finetuned.zip`` and ``report.json`` into ``--out``. ``--set NAME=VALUE`` changes one of COMA's
constructor arguments for the fine-tuning (the same clone fine-tuned two ways is a paired comparison
of the two settings: issue #45, docs/training.md). ``--dueling-critic`` gives the fine-tuning the
dueling critic head (``policy_kwargs`` ``dueling_critic``): with ``--from`` a fresh one replaces the
clone's, the actor and its optimizer state kept, so the same clone can be fine-tuned with either head.
"""

from __future__ import annotations

import argparse
import inspect
import json
import sys
import time
from pathlib import Path
from typing import Any

import torch as th

from sb3_coma.app.arguments import set_value
from sb3_coma.app.evaluation import evaluate
from sb3_coma.app.roles import TEST_SPLIT_NOTE, add_split_argument, protocol_for_split
from sb3_coma.app.training import build_model, make_training_env, plan_run, record_env_options
from sb3_coma.baselines import make_planner
from sb3_coma.coma import COMA
from sb3_coma.coma.validation import check_coma_arguments
from sb3_coma.stats.paired import holm_adjust, paired_difference
from sb3_coma.uav.imitation import clone_teacher
from uav_ipp.config import count_or_none_value, count_value, seed_value


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command-line options (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="env3")
    parser.add_argument("--rounds", type=count_value, default=8, help="DAgger rounds")
    parser.add_argument("--missions", type=count_value, default=128, help="missions per DAgger round")
    parser.add_argument("--from", dest="source", default=None, help="a clone to fine-tune instead of cloning")
    parser.add_argument(
        "--finetune", type=count_or_none_value, default=0, help="COMA joint steps after cloning (0: none)"
    )
    parser.add_argument("--kl", type=float, default=1.0, help="starting weight of the KL pull while fine-tuning")
    parser.add_argument(
        "--kl-fraction", type=float, default=0.5, help="share of the fine-tuning over which the pull decays"
    )
    parser.add_argument(
        "--lr", type=float, default=None, help="actor learning rate of the fine-tuning (default: the config's)"
    )
    parser.add_argument(
        "--critic-warmup",
        type=float,
        default=0.0,
        help="fraction of the fine-tuning during which only the critic learns (actor learning rate 0)",
    )
    parser.add_argument(
        "--missions-eval", type=count_value, default=None, help="missions of the comparison (default: the protocol's)"
    )
    add_split_argument(parser)
    parser.add_argument("--seed", type=seed_value, default=0)
    parser.add_argument(
        "--observation", choices=("v2", "v3"), default=None, help="env option observation (default: the config's)"
    )
    parser.add_argument(
        "--set",
        dest="settings",
        action="append",
        type=set_value,
        default=[],
        metavar="NAME=VALUE",
        help="a COMA constructor argument of the fine-tuning, e.g. --set n_epochs=10 (repeatable)",
    )
    parser.add_argument(
        "--dueling-critic",
        action="store_true",
        help="the fine-tuning's critic has a dueling head (policy_kwargs dueling_critic): with --from, a fresh "
        "one takes the place of the clone's, which DAgger never trains; else the clone is built with it",
    )
    parser.add_argument("--out", required=True, help="output folder")
    args = parser.parse_args(argv)
    try:
        args.settings = coma_settings(dict(args.settings))
    except (TypeError, ValueError) as exc:
        parser.error(f"--set: {exc}")
    return args


#: COMA's arguments that ``--set`` may not change: the run's identity and objects, set by the command.
_NOT_SETTINGS = frozenset(
    {"self", "policy", "env", "seed", "device", "verbose", "tensorboard_log", "_init_setup_model"}
    | {"learning_rate", "kl_coef", "kl_fraction"}  # --lr, --kl and --kl-fraction
    | {"policy_kwargs"}  # the networks are the clone's
)


def coma_settings(pairs: dict[str, Any]) -> dict[str, Any]:
    """``pairs`` checked as COMA constructor arguments: each name one of them, each value one COMA
    accepts (checked with COMA's own rules against its defaults), so a typo fails before the clone
    is loaded and not as an attribute that nothing reads."""
    parameters = inspect.signature(COMA.__init__).parameters
    unknown = sorted(set(pairs) - (set(parameters) - _NOT_SETTINGS))
    if unknown:
        raise ValueError(
            f"{unknown[0]!r} is not a COMA argument this command can set "
            "(--lr, --kl and --kl-fraction set theirs; the networks are the clone's)"
        )
    defaults = {name: p.default for name, p in parameters.items() if p.default is not inspect.Parameter.empty}
    check_coma_arguments(defaults | pairs)
    return pairs


def config_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """What the command changes in the map's config entry: the observation, the clone's critic head (a
    clone loaded with ``--from`` has its own networks) and the ``--set`` settings."""
    overrides: dict[str, Any] = {"env_kwargs.observation": args.observation} if args.observation else {}
    if args.dueling_critic and not args.source:
        overrides["policy_kwargs.dueling_critic"] = True
    return overrides | args.settings


def with_dueling_critic(model: COMA) -> COMA:
    """``model`` with a fresh dueling critic in place of its own, its actor and the actor's optimizer
    state kept: the same clone fine-tuned with either critic is then a paired comparison of the two
    heads (DAgger trains only the actor, so the clone's own critic is as untrained as the fresh one)."""
    old = model.policy
    settings = old._get_constructor_parameters() | {"dueling_critic": True}
    settings.update(lr_schedule=model.lr_schedule, critic_lr_schedule=model.critic_lr_schedule)
    new = type(old)(**settings).to(model.device)
    new.actor.load_state_dict(old.actor.state_dict())
    new.optimizer.load_state_dict(old.optimizer.state_dict())
    model.policy = new
    model.policy_kwargs = {**model.policy_kwargs, "dueling_critic": True}
    return model


def _clone(args: argparse.Namespace, plan: Any, venv: Any) -> tuple[COMA, dict[str, Any]]:
    if args.source:
        custom = {"learning_rate": args.lr} if args.lr else {}
        loaded = COMA.load(
            args.source,
            env=venv,
            device="cpu",
            kl_coef=args.kl,
            kl_fraction=args.kl_fraction,
            **custom,
            **args.settings,
        )
        return (with_dueling_critic(loaded) if args.dueling_critic else loaded), {}
    model = build_model(plan, venv, device="cpu")
    model.kl_coef, model.kl_fraction = args.kl, args.kl_fraction
    tic = time.perf_counter()
    report = clone_teacher(model, make_planner("oracle", venv, seed=args.seed), args.missions, args.rounds)
    return model, {"dagger_rounds": report.rounds, "dagger_s": round(time.perf_counter() - tic, 1)}


def _compare(path: Path, env: str, missions: int | None, split: str) -> dict[str, Any]:
    """The model, AG and the oracle on the same missions of ``split``; paired verdicts against AG."""
    protocol = protocol_for_split(split)
    results = {
        name: evaluate(name, env=env, protocol=protocol, n_trials=missions, record=0)
        for name in (str(path), "ag", "oracle")
    }
    finals = {name: {m: float(getattr(r, m)[:, -1].mean()) for m in ("f1", "entropy")} for name, r in results.items()}
    diffs = holm_adjust([paired_difference(results[str(path)], results["ag"], m) for m in ("f1", "entropy")])
    note = {"note": TEST_SPLIT_NOTE} if split == "test" else {}
    verdicts = [{k: v for k, v in d.as_dict().items() if k != "per_scene"} for d in diffs]
    return {"protocol": protocol, **note, "missions": results["ag"].n_trials, "finals": finals, "vs_ag": verdicts}


def main(argv: list[str] | None = None) -> int:
    """Clone (or load), fine-tune if asked, compare, write the report."""
    args = parse_args(argv)
    th.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    plan = plan_run(env=args.env, seed=args.seed, device="cpu", overrides=config_overrides(args) or None)
    venv = make_training_env(plan.cfg, seed=args.seed, workers=1)  # the oracle reads the env's state
    model, record = _clone(args, plan, venv)
    record_env_options(model, plan.cfg.world)
    name = "clone.zip"
    if args.finetune > 0:
        model.set_reference_actor()
        model.hold_actor(args.critic_warmup)  # saved with the model, as train() does
        tic = time.perf_counter()
        model.learn(args.finetune)
        record["finetune_s"], name = round(time.perf_counter() - tic, 1), "finetuned.zip"
    model.save(out / name)
    venv.close()
    record.update(vars(args), comparison=_compare(out / name, args.env, args.missions_eval, args.split))
    (out / "report.json").write_text(json.dumps(record, indent=2) + "\n")
    print(json.dumps(record["comparison"], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
