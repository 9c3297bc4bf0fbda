"""The three roles of the missions (#35): the validation protocol covers every train scene equally,
flies the same missions whoever flies them, and the comparing studies default to it."""

from __future__ import annotations

import argparse
import collections
import importlib
from pathlib import Path

import numpy as np
import pytest

import uav_ipp
from sb3_coma.app.roles import SPLIT_CHOICES, TEST_SPLIT_NOTE, add_split_argument, protocol_for_split
from sb3_coma.common.evaluation import PROTOCOLS, VALIDATION_SEED, validation_missions
from uav_ipp.config import ConfigError, IppConfig
from uav_ipp.maps import split_scenes
from uav_ipp.maps.scenes import pick

FAST = {"budget": 2, "split": "train", "start": "random", "mission_from_seed": True}


def _scene_after_reset(env: uav_ipp.UavIppEnv, seed: int | None = None) -> str:
    env.reset(seed=seed)
    return env.ground_truth.name


def test_a_seed_names_its_mission_and_unseeded_resets_continue_the_sequence() -> None:
    scenes = split_scenes("env3", "train")
    env = uav_ipp.make_env("env3", **FAST)
    name = _scene_after_reset(env, 1000)
    index, _ = pick(1000, len(scenes))
    assert name.startswith(f"env3/train/{scenes[index].key}/")
    env.mission_stride = 3
    follower = _scene_after_reset(env)  # an auto-reset: mission 1003
    assert follower == _scene_after_reset(uav_ipp.make_env("env3", **FAST), 1003)


def test_without_the_option_maps_are_drawn_as_before() -> None:
    options = {k: v for k, v in FAST.items() if k != "mission_from_seed"}
    a = _scene_after_reset(uav_ipp.make_env("env3", **options), 1000)
    b = _scene_after_reset(uav_ipp.make_env("env3", **FAST), 1000)
    assert a != b  # the drawn map of seed 1000 is another mission than mission 1000


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_mission_from_seed_must_be_a_bool(value: object) -> None:
    with pytest.raises(ConfigError, match="mission_from_seed"):
        IppConfig.from_options("env3", split="train", mission_from_seed=value).validate()


def test_mission_from_seed_refused_on_the_paper_split() -> None:
    with pytest.raises(ConfigError, match="mission_from_seed=True: False with split='paper'"):
        IppConfig.from_options("env3", mission_from_seed=True).validate()


def test_validation_missions_cover_every_train_scene_four_times() -> None:
    assert (validation_missions("env2"), validation_missions("env3"), validation_missions("env1")) == (36, 48, 48)
    for env in ("env2", "env3"):
        n = len(split_scenes(env, "train"))
        keys = [
            split_scenes(env, "train")[pick(VALIDATION_SEED + k, n)[0]].key for k in range(validation_missions(env))
        ]
        assert set(collections.Counter(keys).values()) == {4}
    proto = PROTOCOLS["validation"]
    assert proto.first_seed == VALIDATION_SEED >= 1000 > 49  # apart from the reporting seeds 0..49
    assert proto.env_options() == {"split": "train", "start": "random", "mission_from_seed": True}
    assert PROTOCOLS["unseen"].env_options() == {"split": "test", "start": "random"}


def _flown_scenes(n_envs: int, missions: int, workers: int = 1) -> list[str]:
    """Scenes a vec env of ``n_envs`` copies flies in ``missions`` missions after ``seed(1000)``,
    in mission order (copy e's k-th mission is mission 1000 + e + k * n_envs)."""
    venv = uav_ipp.make_vec_env("env3", n_envs=n_envs, workers=workers, fusion="mean", **FAST)
    venv.seed(VALIDATION_SEED)
    venv.reset()
    by_mission: dict[int, str] = {}
    n_agents = venv.get_attr("n_agents")[0]
    rows = venv.num_envs
    for k in range(missions // n_envs):
        names = venv.get_attr("ground_truth")
        for e in range(n_envs):
            by_mission[e + k * n_envs] = names[e * n_agents].name
        for _ in range(FAST["budget"]):
            venv.step(np.zeros(rows, dtype=np.int64))
    venv.close()
    return [by_mission[m] for m in sorted(by_mission)]


def test_the_same_missions_whatever_the_number_of_copies_and_workers() -> None:
    one = _flown_scenes(1, 8)
    assert _flown_scenes(4, 8) == one
    assert _flown_scenes(4, 8, workers=2) == one
    fresh = [_scene_after_reset(uav_ipp.make_env("env3", **FAST), VALIDATION_SEED + m) for m in range(8)]
    assert one == fresh


def test_the_evaluation_front_door_flies_the_validation_missions() -> None:
    from sb3_coma.app.evaluation import evaluate

    result = evaluate("random", env="env3", protocol="validation", budget=2, record=0)
    assert (result.n_trials, result.seed) == (48, VALIDATION_SEED)
    assert set(collections.Counter(result.scenes).values()) == {4}
    assert len(set(result.scenes)) == 12


def test_roles_test_split_says_it_reports_only(capsys: pytest.CaptureFixture[str]) -> None:
    assert SPLIT_CHOICES[0] == "validation"
    assert protocol_for_split("validation") == "validation"
    assert capsys.readouterr().out == ""
    assert protocol_for_split("test") == "unseen"
    assert TEST_SPLIT_NOTE in capsys.readouterr().out
    parser = argparse.ArgumentParser()
    add_split_argument(parser)
    assert parser.parse_args([]).split == "validation"


#: Every study that compares variants to pick one: it must fly validation missions by default.
COMPARING_STUDIES = ("dagger", "learners_paired", "ippo_vs_ag", "budget_sweep")


@pytest.mark.parametrize("study", COMPARING_STUDIES)
def test_comparing_studies_fly_validation_missions_by_default(study: str) -> None:
    module = importlib.import_module(f"sb3_coma.experiments.{study}")
    source = Path(str(module.__file__)).read_text(encoding="utf-8")
    assert "add_split_argument(" in source, f"{study} has no --split (validation by default)"
    assert 'protocol="unseen"' not in source and 'split="test"' not in source, f"{study} hard-codes the test split"


def test_checkpoint_validation_flies_the_validation_protocols_missions() -> None:
    """``sb3-coma train --eval-freq``'s eval env is the validation protocol's: mission_from_seed on
    the config's train split, so checkpoints are chosen on the missions evaluate(protocol="validation") flies."""
    from sb3_coma.app.config import eval_copies, load_config, make_validation_env

    cfg = load_config("env1", overrides={"env_kwargs.n_uavs": 2, "env_kwargs.budget": 2})
    assert cfg.env_kwargs.get("split") == "train"
    venv = make_validation_env(cfg, 8, VALIDATION_SEED)
    try:
        assert venv.num_envs == eval_copies(8) * 2
        config = venv.get_attr("config")[0]
        assert config.mission_from_seed and config.split == "train" and config.start_rule == "random"
    finally:
        venv.close()
