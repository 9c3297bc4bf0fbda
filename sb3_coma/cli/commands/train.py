"""``sb3-coma train``: train COMA into a run folder (config, TensorBoard, checkpoints, metrics, model)."""

from __future__ import annotations

import argparse
import math
import signal
import sys
from pathlib import Path

from sb3_coma.app.arguments import add_threads_argument, set_value
from sb3_coma.cli import UserError, set_threads
from uav_ipp.config import count_value, integer_type, seed_value

# The trainer, its config and the checks import torch and rl_zoo3: the functions below import
# them, so that building the parser (``--help``) does not.

NAME = "train"
HELP = "train COMA on a map into a run folder (resume with --resume RUN_DIR)"
DESCRIPTION = (
    "Train COMA (SenDFuse + CBAM by default) with the rl-zoo style config zoo_configs/coma.yml. "
    "A run folder receives config.yml, TensorBoard logs (tb/), checkpoints/, metrics.csv (one row "
    "per mission) and model.zip. Ctrl-C or SIGTERM saves a checkpoint before exiting; "
    "--resume RUN_DIR continues with the same timestep count and optimiser state, in the same world "
    "(a change of it is refused unless --allow-change); one process trains in a run folder at a time. "
    "Timesteps are joint steps (one per env copy per step): the paper's 1200 missions x 15 = 18000."
)


def _joint_steps(text: str) -> int:
    """argparse type of the joint-step counts: a whole number, also written ``3.6e4``."""
    from sb3_coma.app.config import written_number
    from sb3_coma.coma.validation import check_total_timesteps

    value = written_number(text.strip())
    try:
        number: float = value if isinstance(value, float) else int(value)
    except ValueError:
        number = math.nan  # not a number at all
    if isinstance(number, float) and not number.is_integer():  # nan included
        problem = (
            f"{text!r} is not a whole number of joint steps" if number == number else f"invalid whole number: {text!r}"
        )
    elif number < 1:
        return int(number)  # the count's own rule (app.config.checked_count) names the flag
    else:
        try:
            return check_total_timesteps(number, "the value")
        except ValueError as exc:
            problem = str(exc)
    raise argparse.ArgumentTypeError(problem)


#: The count flags and the ``train()`` argument whose rule each follows.
_COUNT_FLAGS = (
    ("timesteps", "total_timesteps"),
    ("n_envs", "n_envs"),
    ("save_freq", "save_freq"),
    ("eval_freq", "eval_freq"),
    ("eval_missions", "eval_missions"),
)


def _add_change_option(parser: argparse.ArgumentParser) -> None:
    """``--allow-change``: a resume in another world or layout is refused unless the user says so."""
    parser.add_argument(
        "--allow-change",
        action="store_true",
        help="with --resume: accept a change of the run's world or layout (env_kwargs, n_envs: a config.yml "
        "edited since the run started, or --n-envs) instead of refusing it; the change is recorded in config.yml",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    _add_run_arguments(parser)
    _add_schedule_arguments(parser)


def _add_run_arguments(parser: argparse.ArgumentParser) -> None:
    """What to train: threads, map, config and variant, length, seed, resume, run folder, copies, overrides."""
    add_threads_argument(parser)
    parser.add_argument(
        "--env",
        default=None,
        help="map: env1, env2, env3 or a gymnasium id (default env3; with --resume the run's own); or a "
        "third-party PettingZoo task: simple_spread, simple_reference, the LBF / RWARE ids of "
        "zoo_configs/marl/coma.yml, or package.module:factory",
    )
    parser.add_argument(
        "--config", default=None, metavar="YAML", help="rl-zoo style hyperparameter file (default zoo_configs/coma.yml)"
    )
    parser.add_argument(
        "--variant", default=None, help="a name from the config's 'variants' (e.g. mean-cnn); see --list-variants"
    )
    parser.add_argument("--list-variants", action="store_true", help="print the config's variants and exit")
    parser.add_argument(
        "--timesteps",
        type=_joint_steps,
        default=None,
        metavar="N",
        help="total joint steps to reach (default: the config's n_timesteps)",
    )
    parser.add_argument(
        "--seed", type=seed_value, default=None, help="seed of model and env (default: random, recorded)"
    )
    parser.add_argument(
        "--resume",
        default=None,
        metavar="PATH",
        help="continue a run folder (its newest checkpoint) or a checkpoint .zip",
    )
    _add_change_option(parser)
    parser.add_argument(
        "--fork",
        action="store_true",
        help="with --resume of a checkpoint older than its run's newest model: continue from it in a new "
        "run folder that records the run as its parent (in place it would fork the run's history: refused)",
    )
    parser.add_argument(
        "--run-dir",
        default=None,
        metavar="DIR",
        help="run folder (default runs/<env id>[-<variant>]_<n>; never reuses a non-empty folder)",
    )
    parser.add_argument("--n-envs", type=count_value, default=None, help="env copies (default: the config's n_envs)")
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        type=set_value,
        default=[],
        metavar="KEY=VALUE",
        help="override a config key (YAML value), dots reach into mappings: "
        "--set batch_size=256 --set env_kwargs.noise=loud (repeatable)",
    )


def _add_schedule_arguments(parser: argparse.ArgumentParser) -> None:
    """Checkpoints, validations, the test split, device, progress bar and verbosity."""
    parser.add_argument(
        "--save-freq",
        type=_joint_steps,
        default=None,
        metavar="N",
        help="joint steps between checkpoints (default: a tenth of the run; 0: none)",
    )
    parser.add_argument(
        "--eval-freq",
        type=_joint_steps,
        default=0,
        metavar="N",
        help="joint steps between evaluations (0: none; best model -> best_model.zip)",
    )
    parser.add_argument(
        "--eval-missions",
        type=count_value,
        default=None,
        help="missions per evaluation (default: the validation protocol's, 4 per train scene: env3 48, env2 36)",
    )
    parser.add_argument(
        "--eval-seed",
        type=seed_value,
        default=None,
        metavar="SEED",
        help="env seed of the validation missions, the same at every evaluation "
        "(default 1000: disjoint from the test seeds 0..n-1 of evaluate/reproduce)",
    )
    parser.add_argument(
        "--allow-test-split",
        action="store_true",
        help="train on split 'test' (env_kwargs.split=test) on purpose: those are the unseen protocol's "
        "missions, on which every verdict is measured; recorded in the run's config.yml",
    )
    parser.add_argument("--device", default="auto", help="torch device (auto, cpu, cuda)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument(
        "-v",
        "--verbose",
        type=integer_type(0, 2),
        default=1,
        choices=(0, 1, 2),
        help="0 quiet, 1 run information (default), 2 also SB3's training tables",
    )


def _check_paths(args: argparse.Namespace) -> None:
    """Path names the run would print or record (config.yml) but could not, and a --resume zip that
    is a shipped model failing its SHA-256: refused before any work (the run folder's location is
    checked by train() before anything is built)."""
    from sb3_coma.app.config import path_name_problem
    from sb3_coma.app.pretrained import verify_shipped_file

    for flag, value in (("--config", args.config), ("--resume", args.resume), ("--run-dir", args.run_dir)):
        problem = None if value is None else path_name_problem(value)
        if problem is not None:
            raise UserError(f"{flag} {value!r}: {problem}")
    if args.resume is not None and Path(args.resume).is_file():
        verify_shipped_file(args.resume)  # a PretrainedError: one line (cli.user_errors)


def _overrides(args: argparse.Namespace) -> dict[str, object]:
    """``--set`` pairs plus ``--allow-test-split`` (the config loader checks the split against it)."""
    from sb3_coma.app.config import ALLOW_TEST_SPLIT

    overrides = dict(args.overrides)
    if args.allow_test_split:
        if args.resume is not None:
            raise UserError(
                "--allow-test-split is ignored with --resume: the run continues with its own config.yml, "
                "which records whether it trains on split 'test'"
            )
        overrides[f"env_kwargs.{ALLOW_TEST_SPLIT}"] = True
    return overrides


#: The options of a run in the UAV world that a third-party task's run (rl-zoo3's lifecycle) has not.
_WORLD_ONLY_FLAGS = (
    ("variant", "--variant"),
    ("list_variants", "--list-variants"),
    ("resume", "--resume"),
    ("allow_change", "--allow-change"),
    ("fork", "--fork"),
    ("eval_missions", "--eval-missions"),
    ("eval_seed", "--eval-seed"),
    ("allow_test_split", "--allow-test-split"),
)


def _train_task(args: argparse.Namespace) -> int:
    """COMA on a third-party PettingZoo task (``--env simple_spread`` or ``package.module:factory``)
    through the zoo's training: config ``zoo_configs/marl/coma.yml``, run folder
    ``<--run-dir or runs>/coma/<task>_<n>``."""
    from sb3_coma.app.zoo import train_marl_task

    used = [flag for dest, flag in _WORLD_ONLY_FLAGS if getattr(args, dest)]
    if used:
        raise UserError(f"{used[0]} is an option of the UAV world's runs, not of a third-party task ({args.env})")
    dotted = [key for key in dict(args.overrides) if "." in key]
    if dotted:
        raise UserError(f"--set {dotted[0]}: a task's entry is overridden key by key (no dotted keys)")
    hyperparams = dict(args.overrides) | ({} if args.n_envs is None else {"n_envs": args.n_envs})
    train_marl_task(
        args.env,
        config=args.config,
        timesteps=args.timesteps,
        seed=args.seed,
        log_folder=args.run_dir or "runs",
        hyperparams=hyperparams,
        eval_freq=args.eval_freq,
        save_freq=args.save_freq,
        device=args.device,
        verbose=args.verbose,
        progress=not args.no_progress,
    )
    return 0


def run(args: argparse.Namespace) -> int:
    from sb3_coma.app import training
    from sb3_coma.app.config import checked_count, default_config_path, list_variants
    from sb3_coma.app.marl_tasks import is_marl_task_id
    from sb3_coma.app.training import TrainingInterrupted

    set_threads(args.threads)
    _check_paths(args)
    if args.env is not None and is_marl_task_id(args.env):
        return _train_task(args)
    try:
        if args.list_variants:
            variants = list_variants(args.config or default_config_path())
            if not variants:
                print("(no variants defined)")
            for name, overrides in variants.items():
                print(f"{name}: {overrides or '(the config as it is)'}")
            return 0
        for flag, key in _COUNT_FLAGS:
            if getattr(args, flag) is not None:  # train()'s rule, naming the flag
                checked_count(key, getattr(args, flag), f"--{flag.replace('_', '-')}")
        training.train(
            env=args.env,
            config=args.config,
            variant=args.variant,
            total_timesteps=args.timesteps,
            seed=args.seed,
            run_dir=args.run_dir,
            resume=args.resume,
            overrides=_overrides(args),
            n_envs=args.n_envs,
            save_freq=args.save_freq,
            eval_freq=args.eval_freq,
            eval_missions=args.eval_missions,
            eval_seed=args.eval_seed,
            progress_bar=not args.no_progress,
            device=args.device,
            verbose=args.verbose,
            allow_change=args.allow_change,
            fork=args.fork,
        )
    except TrainingInterrupted as exc:
        if args.verbose < 1:  # train() already said it otherwise
            print(
                f"sb3-coma train: interrupted at {exc.num_timesteps} joint steps; resume with: "
                f"sb3-coma train --resume {exc.run_dir}",
                file=sys.stderr,
            )
        return 128 + int(exc.signum) if exc.signum in (signal.SIGINT, signal.SIGTERM) else 130
    return 0
