"""Issue #44, the "numbers" class of bad input: flags where numbers go, numpy scalars, CLI counts.

Three facts make a bare ``isinstance`` check wrong both ways: ``bool`` is a subclass of ``int``
(``True`` would pass as 1), numpy's scalars are no subclasses of ``int`` / ``float`` (except
``np.float64``), and ``np.bool_`` is not a ``bool``. The rules (docs/design.md, "How a user's
input travels"; ``sb3_coma.common.numbers`` and the world's own copy in ``uav_ipp.config``):

* a Python ``bool`` or ``np.bool_`` where a number is expected is refused with the entry point's
  documented error type (docs/errors.md) and a message naming the value;
* a numpy scalar of the right kind is accepted like the Python number and stored as one, so a
  saved model, a config record or a result's options stay plain JSON / YAML;
* every integer option of ``sb3-coma`` and of the studies is checked by argparse at parse time
  (``sb3_coma.app.arguments.integer_type``): ``sb3_coma.cli.main`` returns 2 with one stderr line.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import inspect
import io
import json
import re
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from gymnasium import spaces
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import uav_ipp
from sb3_coma.app.arguments import workers_value
from sb3_coma.common import numbers
from uav_ipp import ConfigError, IppConfig
from uav_ipp import config as world_config
from uav_ipp.config import SEED_MAX, count_or_none_value, count_value, integer_type, seed_value

ROOT = Path(__file__).resolve().parent.parent
FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
#: True and False, as Python and as numpy flags.
FLAGS = st.sampled_from([True, False, np.True_, np.False_])
TINY_WORLD = {"n_uavs": 2, "budget": 2}


def _named(value: Any) -> str:
    """How a message names a flag: ``True`` (a numpy flag is stored, and named, as the bool it holds)."""
    return repr(bool(value))


# =============================================================================== the predicates
@pytest.mark.parametrize("module", [numbers, world_config], ids=["sb3_coma", "uav_ipp"])
def test_the_predicates_of_both_packages(module: Any) -> None:
    wholes = [3, -2, np.int64(3), np.uint8(7), np.int32(-1)]
    reals = [*wholes, 2.5, float("inf"), np.float32(0.5), np.float64(0.5), np.float16(1)]
    flags = [True, False, np.True_, np.False_]
    junk = ["3", None, [1], 3j, object()]
    assert all(module.is_whole(v) for v in wholes)
    assert not any(module.is_whole(v) for v in [*flags, 2.5, np.float32(2), *junk])
    assert all(module.is_real(v) for v in reals)
    assert not any(module.is_real(v) for v in [*flags, *junk])
    assert all(module.is_flag(v) for v in flags)
    assert not any(module.is_flag(v) for v in [0, 1, np.int64(1), 1.0, "True", None])
    for value, python in ((np.int64(3), int), (np.float32(0.5), float), (np.True_, bool)):
        assert type(module.plain(value)) is python and module.plain(value) == value
    assert module.plain("x") == "x" and module.plain(None) is None


# =============================================================================== the world
INTEGER_OPTIONS = ("n_uavs", "budget", "grid", "lattice", "comm_grid", "map_seed")
REAL_OPTIONS = (
    "field_size", "fov_deg", "comm_range", "drop_probability", "alpha_low", "sigma", "alpha", "beta",
    "start_altitude",
)  # fmt: skip
FLAG_OPTIONS = ("mission_from_seed", "action_gain")


@FAST
@given(name=st.sampled_from(INTEGER_OPTIONS + REAL_OPTIONS), flag=FLAGS)
def test_a_flag_is_no_env_number(name: str, flag: Any) -> None:
    """``IppConfig.from_options`` (``make_env``, ``make_vec_env``): a ConfigError naming the option and the flag."""
    with pytest.raises(ConfigError) as info:
        IppConfig.from_options("env1", **{name: flag})
    message = str(info.value)
    assert message.startswith("invalid option ") and name.split("_")[0] in message and _named(flag) in message


@pytest.mark.parametrize(
    "options",
    [
        {"altitudes": [True, 2, 3]},
        {"flip_probability": {5: True, 10: 0.2, 15: 0.3}},
        {"start_positions": [(10, 10, True)]},
    ],
)
def test_a_flag_is_no_number_in_a_list_option(options: dict[str, Any]) -> None:
    with pytest.raises(ConfigError, match=rf"invalid option {next(iter(options))}="):
        IppConfig.from_options("env1", n_uavs=1, **options)


def test_numpy_scalars_are_env_options_and_stored_as_python_numbers() -> None:
    given = {
        "n_uavs": np.int64(2), "budget": np.int32(3), "grid": np.int64(493), "map_seed": np.uint8(0),
        "fov_deg": np.float32(60.0), "comm_range": np.float32(25.0), "drop_probability": np.float64(0.25),
        "alpha_low": np.float32(0.5), "start_altitude": np.float64(15.0), "action_gain": np.False_,
        "altitudes": np.array([5.0, 10.0, 15.0]), "flip_probability": {np.float32(a): np.float32(q) for a, q in
                                                                        ((5, 0.01), (10, 0.25), (15, 0.375))},
    }  # fmt: skip
    env = uav_ipp.make_env("env1", **given)
    config = env.config
    for name in given:
        value = getattr(config, name)
        assert not isinstance(value, np.generic), (name, type(value))
    assert type(config.n_uavs) is int and type(config.fov_deg) is float and config.action_gain is False
    assert all(type(a) is float for a in config.altitudes)
    json.dumps(dataclasses.asdict(config))  # a record that JSON (and so YAML) can hold
    split = IppConfig.from_options("env1", split="train", mission_from_seed=np.True_)
    assert split.mission_from_seed is True


@pytest.mark.parametrize("flag", [True, np.False_])
@pytest.mark.parametrize("name", ["mission_from_seed", "action_gain"])
def test_flag_options_take_numpy_flags_only_as_flags(name: str, flag: Any) -> None:
    assert getattr(IppConfig.from_options("env1", split="train", **{name: flag}), name) is bool(flag)
    with pytest.raises(ConfigError, match=rf"{name}=1\b"):
        IppConfig.from_options("env1", split="train", **{name: 1})


@pytest.mark.parametrize("name", ["n_envs", "seed"])
@pytest.mark.parametrize("flag", [True, np.True_])
def test_make_vec_env_refuses_a_flag_as_copies_or_seed(name: str, flag: Any) -> None:
    with pytest.raises(ConfigError, match=rf"invalid option {name}={re.escape(repr(flag))}"):
        uav_ipp.make_vec_env("env1", fusion="mean", **{name: flag}, **TINY_WORLD)


def test_make_vec_env_takes_numpy_counts_and_seeds() -> None:
    venv = uav_ipp.make_vec_env("env1", n_envs=np.int64(2), seed=np.int64(3), fusion="mean", **TINY_WORLD)
    try:
        assert venv.num_envs == 4 and type(venv.num_envs) is int
        venv.reset()
    finally:
        venv.close()


def test_reset_refuses_a_flag_seed() -> None:
    env = uav_ipp.make_env("env1", **TINY_WORLD)
    with pytest.raises(ConfigError, match=r"reset seed=True"):
        env.reset(seed=True)
    env.reset(seed=np.int64(4))


# =============================================================================== make_marl_vec_env
def _parallel_env() -> Any:
    return uav_ipp.make_env("env1", **TINY_WORLD)


@pytest.mark.parametrize("name", ["n_envs", "seed"])
@pytest.mark.parametrize("flag", [True, np.True_])
def test_make_marl_vec_env_refuses_a_flag(name: str, flag: Any) -> None:
    from sb3_coma import make_marl_vec_env

    with pytest.raises(ValueError, match=rf"{name} must be .*, got {re.escape(repr(flag))}"):
        make_marl_vec_env(_parallel_env, **{name: flag})


def test_make_marl_vec_env_takes_numpy_integers() -> None:
    from sb3_coma import make_marl_vec_env

    venv = make_marl_vec_env(_parallel_env, n_envs=np.int64(1), seed=np.int64(0))
    assert venv.num_envs == 2
    venv.close()


# =============================================================================== COMA's arguments
def _coma_defaults() -> dict[str, Any]:
    from sb3_coma import COMA

    return {
        name: p.default for name, p in inspect.signature(COMA.__init__).parameters.items() if p.default is not p.empty
    }


def _checked_names() -> list[str]:
    from sb3_coma.coma import validation

    return [name for names, _, _ in validation._ARGUMENT_RULES for name in names]


@FAST
@given(data=st.data(), flag=FLAGS)
def test_a_flag_is_no_coma_number(data: st.DataObject, flag: Any) -> None:
    """``check_coma_arguments`` (what ``COMA(...)`` runs first): a count is a TypeError ("must be an
    int"), a rate or a seed a ValueError, each naming the argument and the flag."""
    from sb3_coma.coma import validation

    numeric = [n for n in _checked_names() if not isinstance(_coma_defaults()[n], (bool, str))]
    name = data.draw(st.sampled_from(numeric))
    with pytest.raises((TypeError, ValueError)) as info:
        validation.check_coma_arguments({**_coma_defaults(), name: flag})
    assert type(info.value) is (TypeError if name in validation._COUNTS else ValueError)
    assert str(info.value).startswith(f"{name} must ") and repr(flag) in str(info.value)


@pytest.fixture(scope="module")
def venv():
    v = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", **TINY_WORLD)
    yield v
    v.close()


SMALL_POLICY = {"features_extractor_kwargs": {"features_dim": 16, "channels": [4, 4, 4]}}


def test_coma_takes_numpy_scalars_and_saves_python_numbers(venv: Any, tmp_path: Path) -> None:
    from sb3_coma import COMA

    model = COMA(
        "UavCnnPolicy",
        venv,
        n_steps=np.int64(4),
        batch_size=np.int32(4),
        gamma=np.float32(0.5),
        learning_rate=np.float64(1e-3),
        ent_coef=np.float32(0.25),
        normalize_advantage=np.False_,
        seed=np.int64(3),
        policy_kwargs=SMALL_POLICY,
        device="cpu",
    )
    stored = {
        "n_steps": model.n_steps, "batch_size": model.batch_size, "gamma": model.gamma, "ent_coef": model.ent_coef,
        "normalize_advantage": model.normalize_advantage, "seed": model.seed, "learning_rate": model.learning_rate,
    }  # fmt: skip
    assert {k: type(v) for k, v in stored.items()} == {
        "n_steps": int, "batch_size": int, "gamma": float, "ent_coef": float, "normalize_advantage": bool,
        "seed": int, "learning_rate": float,
    }  # fmt: skip
    model.save(tmp_path / "model.zip")
    with zipfile.ZipFile(tmp_path / "model.zip") as archive:
        data = json.loads(archive.read("data"))
    assert data["gamma"] == 0.5 and data["batch_size"] == 4 and data["normalize_advantage"] is False
    assert data["seed"] == 3


@pytest.mark.parametrize(
    "policy_kwargs, named",
    [
        ({"correction_bound": True}, "correction_bound=True"),
        ({"gain_prior": True}, "gain_prior=True"),
        ({"gain_prior": [True, 0.0, 0.0]}, "gain_prior=[True, 0.0, 0.0]"),
        ({"gain_prior": 5, "gain_prior_speed": np.True_}, "gain_prior_speed=np.True_"),
        ({"gain_inputs": 1}, "gain_inputs=1"),
        ({"features_extractor_kwargs": {"features_dim": True}}, "features_dim must be an integer >= 1, got True"),
    ],
)
def test_the_uav_policy_refuses_flags_as_numbers(venv: Any, policy_kwargs: dict[str, Any], named: str) -> None:
    from sb3_coma import COMA

    with pytest.raises(ValueError) as info:
        COMA("UavCnnPolicy", venv, batch_size=8, policy_kwargs=policy_kwargs, device="cpu")
    assert named in str(info.value)


def test_the_uav_policy_takes_numpy_scalars(venv: Any) -> None:
    from sb3_coma import COMA

    kwargs = {
        **SMALL_POLICY, "gain_prior": np.float32(2.0), "gain_prior_speed": np.int64(50),
        "correction_bound": np.float32(3.0), "gain_inputs": np.True_,
    }  # fmt: skip
    policy = COMA("UavCnnPolicy", venv, batch_size=8, policy_kwargs=kwargs, device="cpu").policy
    assert policy.gain_prior == 2.0 and type(policy.gain_prior) is float and policy.gain_inputs is True
    assert type(policy.gain_prior_speed) is float and type(policy.correction_bound) is float


# =============================================================================== extractors
BOX = spaces.Box(0.0, 1.0, (8, 11, 11), dtype=np.float32)


@pytest.mark.parametrize(
    "name, value",
    [("features_dim", True), ("features_dim", np.True_), ("reduction", False), ("gate_bias", True), ("residual", 1)],
)
def test_extractors_refuse_flags_as_numbers_and_numbers_as_flags(name: str, value: Any) -> None:
    from sb3_coma.common.extractors import CBAMExtractor

    with pytest.raises(ValueError, match=rf"{name} must be .*, got {re.escape(repr(value))}"):
        CBAMExtractor(BOX, **{name: value})


def test_extractors_take_numpy_scalars() -> None:
    from sb3_coma.common.extractors import CBAMExtractor, CnnExtractor

    cbam = CBAMExtractor(
        BOX, features_dim=np.int64(16), channels=(np.int64(4), 4, 4), reduction=np.int32(2),
        gate_bias=np.float32(0.5), residual=np.True_,
    )  # fmt: skip
    assert type(cbam.features_dim) is int and cbam.features_dim == 16
    assert type(CnnExtractor(BOX, features_dim=np.int64(8)).features_dim) is int


# =============================================================================== callbacks
@pytest.mark.parametrize(
    "build, named",
    [
        (lambda c, p: c.EpisodeMetricsCallback(window=True), "window must be an integer >= 1, got True"),
        (lambda c, p: c.JointCheckpointCallback(np.True_, p), "save_freq must be an integer >= 1, got np.True_"),
        (lambda c, p: c.JointCheckpointCallback(8, p, keep_last=True), "keep_last must be an integer >= 1 or None"),
        (lambda c, p: c.StopOnTargetCallback(window=False), "window must be an integer >= 1, got False"),
        (lambda c, p: c.StopOnTargetCallback(threshold=True), "threshold must be a number, got True"),
        (lambda c, p: c.StopOnTargetCallback(min_missions=True), "min_missions must be an integer >= 1 or None"),
        (lambda c, p: c.ProgressLinesCallback(every=True), "every must be a fraction in (0, 1], got True"),
        (lambda c, p: c.MissionEvalCallback(None, eval_freq=True), "eval_freq must be an integer >= 1, got True"),
        (lambda c, p: c.MissionEvalCallback(None, n_eval_missions=np.True_), "n_eval_missions must be an integer"),
        (lambda c, p: c.MissionEvalCallback(None, eval_seed=True), "eval_seed must be an integer or None, got True"),
    ],
)
def test_callbacks_refuse_flags_as_counts(build: Any, named: str, tmp_path: Path) -> None:
    from sb3_coma.common import callbacks

    with pytest.raises(ValueError) as info:
        build(callbacks, tmp_path)
    assert named in str(info.value)


def test_callbacks_take_numpy_counts(tmp_path: Path) -> None:
    from sb3_coma.common import callbacks

    checkpoints = callbacks.JointCheckpointCallback(np.int64(8), tmp_path, keep_last=np.int64(2))
    assert (type(checkpoints.save_freq), type(checkpoints.keep_last)) == (int, int)
    assert type(callbacks.EpisodeMetricsCallback(window=np.int64(5)).window) is int
    stop = callbacks.StopOnTargetCallback(threshold=np.float32(0.5), window=np.int64(4), min_missions=np.int64(2))
    assert (type(stop.threshold), type(stop.window), type(stop.min_missions)) == (float, int, int)
    assert type(callbacks.ProgressLinesCallback(every=np.float32(0.5)).every) is float


# =============================================================================== baselines
@pytest.mark.parametrize(
    "name, options, named",
    [
        ("random", {"seed": True}, "random seed=True"),
        ("ag", {"seed": np.True_}, "seed=np.True_"),
        ("ag", {"lookahead": True}, "ag lookahead=True"),
        ("ag", {"discount": np.False_}, "ag discount=np.False_"),
        ("lawnmower", {"lanes_per_uav": np.True_}, "lawnmower lanes_per_uav=np.True_"),
        ("lawnmower", {"altitude": True}, "lawnmower altitude=True"),
    ],
)
def test_baselines_refuse_flags_as_numbers(venv: Any, name: str, options: dict[str, Any], named: str) -> None:
    from sb3_coma.baselines import make_planner

    with pytest.raises(ValueError) as info:
        make_planner(name, venv, **options)
    assert named in str(info.value)


def test_baselines_take_numpy_scalars(venv: Any) -> None:
    from sb3_coma.baselines import make_planner

    ag = make_planner("ag", venv, seed=np.int64(3), discount=np.float32(0.5), lookahead=np.int64(2))
    assert (type(ag.seed), type(ag.discount), type(ag.lookahead)) == (int, float, int)
    mower = make_planner("lawnmower", venv, altitude=np.float32(15.0), lanes_per_uav=np.int64(1))
    assert (mower.altitude, mower.lanes_per_uav) == (15.0, 1) and type(mower.lanes_per_uav) is int
    ag.reset(seed=np.int64(5))
    assert type(ag.seed) is int
    with pytest.raises(ValueError, match="seed=True"):
        ag.reset(seed=True)


# =============================================================================== SenDFuse
@pytest.mark.parametrize(
    "build, named",
    [
        (lambda s: s.SenDFuseConfig(grid_size=True), "got True"),
        (lambda s: s.SenDFuseConfig(channels=(True, 4, 4)), "got (True, 4, 4)"),
        (lambda s: s.SenDFuseLoss(win_size=np.True_), "win_size must be a positive odd int, got np.True_"),
        (lambda s: s.SenDFuseLoss(w_mse=True), "w_mse must be a finite number >= 0, got True"),
    ],
)
def test_sendfuse_refuses_flags_as_numbers(build: Any, named: str) -> None:
    import sb3_coma.sendfuse as sendfuse

    with pytest.raises(ValueError) as info:
        build(sendfuse)
    assert named in str(info.value)


@pytest.mark.parametrize(
    "field, value", [("samples", True), ("epochs", np.True_), ("seed", True), ("seed", -1), ("lr", True)]
)
def test_pretraining_options_refuse_flags_and_bad_seeds(field: str, value: Any) -> None:
    from sb3_coma.sendfuse.pretrain import PretrainConfig

    with pytest.raises(ValueError, match=rf"--{field} must be .*, got {re.escape(repr(value))}"):
        PretrainConfig(**{field: value}).validate()


def test_generate_pairs_refuses_a_flag_count() -> None:
    from sb3_coma.sendfuse.data import generate_pairs

    with pytest.raises(ValueError, match=r"n_samples must be a positive int, got True"):
        generate_pairs(True)


def test_the_fusion_alpha_is_no_flag() -> None:
    with pytest.raises(ConfigError, match=r"fusion_kwargs alpha=True"):
        uav_ipp.make_vec_env("env1", fusion="sendfuse", fusion_kwargs={"alpha": True}, **TINY_WORLD)
    from sb3_coma.sendfuse import SenDFuseConfig, SenDFuseNet

    net = SenDFuseNet.from_config(SenDFuseConfig(grid_size=np.int64(8), channels=(4, 4, 4)))
    assert type(net.grid_size) is int
    with pytest.raises(ValueError, match=r"alpha must be a number in \[0, 1\], got np.True_"):
        SenDFuseNet.from_config(net.config, fusion_alpha=np.True_)


def test_sendfuse_takes_numpy_scalars_and_records_python_numbers() -> None:
    from sb3_coma.sendfuse import SenDFuseConfig, SenDFuseLoss
    from sb3_coma.sendfuse.pretrain import PretrainConfig

    config = SenDFuseConfig(grid_size=np.int64(44), channels=(np.int64(4), np.int32(4), 4))
    assert json.dumps(config.as_dict()) == '{"grid_size": 44, "channels": [4, 4, 4]}'
    assert type(SenDFuseLoss(win_size=np.int64(5), w_mse=np.float32(0.5)).win_size) is int
    PretrainConfig(samples=np.int64(8), seed=np.uint32(3), lr=np.float32(1e-3)).validate()


# =============================================================================== evaluate()
@pytest.mark.parametrize("name", ["n_trials", "seed", "n_envs", "record", "workers"])
@pytest.mark.parametrize("flag", [True, np.True_])
def test_evaluate_refuses_a_flag_count_or_seed(name: str, flag: Any) -> None:
    from sb3_coma import evaluate

    options = {"n_trials": 1, **{name: flag}}
    with pytest.raises(ValueError, match=rf"{name}={re.escape(repr(flag))}: must be an integer"):
        evaluate("random", env="env1", **options, **TINY_WORLD)


def test_evaluate_takes_numpy_scalars_and_records_python_numbers() -> None:
    from sb3_coma import evaluate

    result = evaluate(
        "random", env="env1", n_trials=np.int64(1), seed=np.int64(3), n_envs=np.int32(1), record=np.int64(0),
        workers=np.int64(1), n_uavs=np.int64(2), budget=np.int64(2), drop_probability=np.float32(0.5),
    )  # fmt: skip
    assert (result.n_trials, result.seed) == (1, 3) and (type(result.n_trials), type(result.seed)) == (int, int)
    assert json.dumps(result.env_options)  # a result's record holds Python numbers only
    assert type(result.env_options["n_uavs"]) is int and type(result.env_options["drop_probability"]) is float


# =============================================================================== checkpoint files
def test_a_checkpoint_whose_step_count_is_a_flag_is_corrupt(venv: Any, tmp_path: Path) -> None:
    from sb3_coma import COMA
    from sb3_coma.common.checkpoints import CheckpointError, validate_checkpoint

    good = tmp_path / "good.zip"
    COMA("UavCnnPolicy", venv, batch_size=8, policy_kwargs=SMALL_POLICY, device="cpu").save(good)
    assert validate_checkpoint(good).num_timesteps == 0
    bad = tmp_path / "flag.zip"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as out:
        for member in src.namelist():
            data = src.read(member)
            if member == "data":
                data = json.dumps({**json.loads(data), "num_timesteps": True}).encode()
            out.writestr(member, data)
    with pytest.raises(CheckpointError, match=r"'num_timesteps' of its 'data' member is True"):
        validate_checkpoint(bad)


# =============================================================================== the CLI's integer options
def _subparsers() -> dict[str, argparse.ArgumentParser]:
    from sb3_coma.cli import build_parser

    parser, _ = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def _parsers() -> dict[str, argparse.ArgumentParser]:
    from sb3_coma.app import zoo

    return {**{f"sb3-coma {k}": v for k, v in _subparsers().items()}, "zoo train": zoo.train_parser(),
            "zoo enjoy": zoo.enjoy_parser()}  # fmt: skip


@pytest.mark.parametrize("name", sorted(_parsers()))
def test_no_option_of_a_parser_is_a_plain_int(name: str) -> None:
    """Every integer option has a type that names the bad value and what is allowed."""
    plain = [a.option_strings for a in _parsers()[name]._actions if a.type is int]
    assert not plain, f"{name}: {plain} use type=int (use sb3_coma.app.arguments.integer_type)"


def test_no_study_parser_takes_a_plain_int() -> None:
    """The studies build their parsers inside main(): their sources name no ``type=int``."""
    sources = [
        *sorted((ROOT / "sb3_coma" / "experiments").rglob("*.py")),
        ROOT / "sb3_coma" / "sendfuse" / "__main__.py",
    ]
    offenders = [
        f"{path.relative_to(ROOT)}:{number}"
        for path in sources
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if re.search(r"\btype=int\b", line)
    ]
    assert not offenders


def _integer_options() -> list[tuple[str, str, Any]]:
    """(parser, option, type) of every option typed by ``integer_type`` (and ``--workers``)."""
    out = []
    for name, parser in _parsers().items():
        for action in parser._actions:
            if action.option_strings and getattr(action.type, "__name__", "") in ("integer", "workers_value"):
                out.append((name, max(action.option_strings, key=len), action.type))
    return out


def test_the_integer_options_are_many() -> None:
    assert len(_integer_options()) >= 60


def _accepts(kind: Any, text: str) -> Any:
    try:
        return kind(text)
    except argparse.ArgumentTypeError as exc:
        return exc


@FAST
@given(value=st.integers(-(2**40), 2**40))
def test_the_argparse_types_over_integers(value: int) -> None:
    expected = {
        count_value: value >= 1,
        count_or_none_value: value >= 0,
        seed_value: 0 <= value <= SEED_MAX,
        integer_type(None): True,
        integer_type(1, sentinels={-1: "default", -2: "off"}): value >= 1 or value in (-1, -2),
        integer_type(0, 2): 0 <= value <= 2,
    }
    for kind, ok in expected.items():
        got = _accepts(kind, f" {value}" if value % 3 == 0 else str(value))
        if ok:
            assert got == value and type(got) is int
        else:
            assert isinstance(got, argparse.ArgumentTypeError) and str(got).endswith(f"got {value}")
            assert str(got).startswith("must be ")


def _is_integer_text(text: str) -> bool:
    try:
        int(text.strip())
    except ValueError:
        return False
    return True


@FAST
@given(text=st.one_of(st.text(max_size=8), st.sampled_from(["1.5", "1e3", "0x10", "True", "", " ", "--1", "inf"])))
def test_the_argparse_types_over_junk(text: str) -> None:
    for kind in (count_value, count_or_none_value, seed_value, integer_type(None), workers_value):
        got = _accepts(kind, text)
        if kind is workers_value and text == "auto":
            assert got == "auto"
        elif _is_integer_text(text):
            assert isinstance(got, (int, argparse.ArgumentTypeError))
        else:
            assert isinstance(got, argparse.ArgumentTypeError) and repr(text) in str(got), (kind, text, got)


def run_cli(argv: list[str]) -> tuple[int, list[str]]:
    from sb3_coma import cli

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        rc = cli.main(argv)
    return rc, err.getvalue().strip().splitlines()


def test_demo_seed_minus_one_is_one_line_exit_2() -> None:
    rc, lines = run_cli(["demo", "--seed", "-1"])
    assert rc == 2 and len(lines) == 1, lines
    assert lines[0] == "sb3-coma demo: error: argument --seed: must be an integer from 0 to 4294967295, got -1"


@pytest.mark.parametrize("bad", ["-1", "0", "x", "1.5", "True"])
def test_every_integer_option_of_sb3_coma_refuses_junk_in_one_line(bad: str) -> None:
    """Each command's integer options, each given a bad value: exit 2 and one line naming the flag and
    the value, at parse time (no command runs)."""
    seen = 0
    for parser, option, kind in _integer_options():
        if not parser.startswith("sb3-coma ") or not isinstance(_accepts(kind, bad), argparse.ArgumentTypeError):
            continue
        command = parser.removeprefix("sb3-coma ")
        rc, lines = run_cli([command, option, bad])
        assert rc == 2 and len(lines) == 1, (command, option, lines)
        assert lines[0].startswith(f"sb3-coma {command}: error: argument ") and option in lines[0]
        assert bad in lines[0], lines[0]
        seen += 1
    assert seen >= 10


def test_documented_sentinels_still_parse() -> None:
    from sb3_coma.app import zoo

    args = zoo.train_parser().parse_args(
        [
            "--seed",
            "-1",
            "-n",
            "-1",
            "--log-interval",
            "-2",
            "--eval-freq",
            "-1",
            "--save-freq",
            "0",
            "--num-threads",
            "-1",
        ]
    )
    assert (args.seed, args.n_timesteps, args.log_interval, args.eval_freq, args.num_threads) == (-1, -1, -2, -1, -1)
    assert zoo.enjoy_parser().parse_args(["--exp-id", "-1"]).exp_id == -1
    subs = _subparsers()
    assert subs["reproduce"].parse_args(["--unseen-missions", "0", "--wide-trials", "0"]).unseen_missions == 0
    assert subs["evaluate"].parse_args(["--workers", "auto", "--seed", str(SEED_MAX)]).seed == SEED_MAX
    with pytest.raises(SystemExit), contextlib.redirect_stderr(io.StringIO()):
        zoo.train_parser().parse_args(["--seed", "-2"])


def test_help_still_exits_0(capsys: pytest.CaptureFixture[str]) -> None:
    from sb3_coma import cli

    with pytest.raises(SystemExit) as stop:
        cli.main(["demo", "--help"])
    assert stop.value.code == 0 and "--seed" in capsys.readouterr().out
