"""The world travels typed: env options are resolved once at the config edge into a ``WorldSpec``
(an ``IppConfig`` valid by construction), and the env builders below take it as it is."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import yaml
from tiny_runs import ENV, tiny_entry

import uav_ipp
from sb3_coma.app import config as app_config
from sb3_coma.app.config import TrainingError, load_config, make_validation_env, resolve_world
from sb3_coma.app.training import train
from uav_ipp import ConfigError, IppConfig

pytestmark = pytest.mark.usefixtures("tmp_cwd")


@pytest.fixture
def counted(monkeypatch: pytest.MonkeyPatch) -> Counter:
    """Count the calls of the three option parsers and of the world's in-process vec-env builder."""
    import uav_ipp.api as world_api

    calls: Counter = Counter()

    def counting(name: str, fn: Any) -> Any:
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            calls[name] += 1
            return fn(*args, **kwargs)

        return wrapper

    from_options = IppConfig.from_options.__func__  # type: ignore[attr-defined]
    monkeypatch.setattr(app_config, "split_env_kwargs", counting("split", app_config.split_env_kwargs))
    monkeypatch.setattr(
        IppConfig,
        "from_options",
        classmethod(counting("from_options", lambda cls, *a, **k: from_options(cls, *a, **k))),
    )
    monkeypatch.setattr(IppConfig, "validate", counting("validate", IppConfig.validate))
    monkeypatch.setattr(world_api, "_make_vec_env", counting("build", world_api._make_vec_env))
    return calls


def test_one_small_train_run_resolves_the_world_once(counted: Counter, tmp_path: Path) -> None:
    """Training env + validation env: the options are split and parsed once, and each distinct
    config (training, validation missions) is checked once, at its construction."""
    entry = {**tiny_entry(), "n_timesteps": 16, "env_kwargs": {**tiny_entry()["env_kwargs"], "split": "train"}}
    config = tmp_path / "tiny.yml"
    config.write_text(yaml.safe_dump({ENV: entry}))
    train(
        env=ENV,
        config=config,
        seed=0,
        run_dir=tmp_path / "run",
        progress_bar=False,
        verbose=0,
        eval_freq=8,
        eval_missions=2,
        save_freq=10**9,
    )
    assert counted["build"] == 2  # the training env and the validation env
    assert counted["split"] == 1
    assert counted["from_options"] == 1
    assert counted["validate"] == 2  # the training config and its validation-missions copy


def test_a_config_is_checked_when_it_is_built() -> None:
    with pytest.raises(ConfigError, match="n_uavs=0"):
        IppConfig(n_uavs=0)
    with pytest.raises(ConfigError, match="budget=-1"):
        IppConfig().replace(budget=-1)


def test_the_vec_env_takes_a_resolved_config_and_refuses_options_beside_it() -> None:
    config = IppConfig.from_options("env1", n_uavs=2, budget=4)
    venv = uav_ipp.make_vec_env(config, n_envs=2, fusion="mean", seed=3)
    try:
        assert venv.num_envs == 4  # 2 copies x 2 UAVs
    finally:
        venv.close()
    assert uav_ipp.make_env(config).config is config
    with pytest.raises(ConfigError, match=r"options \['budget'\] given with an IppConfig"):
        uav_ipp.make_vec_env(config, budget=5)


def test_the_world_record_is_every_option_resolved() -> None:
    world = resolve_world(ENV, {"fusion": "mean", "n_uavs": 2, "budget": 4}, "here")
    record = world.record()
    assert record["map"] == "env1" and record["fusion"] == "mean" and record["fusion_kwargs"] == {}
    assert record["n_uavs"] == 2 and record["budget"] == 4 and record["noise"] == "moderate"
    assert world.n_agents == 2
    with pytest.raises(TrainingError, match=r"^here: env_kwargs: .*budget=0"):
        resolve_world(ENV, {"budget": 0}, "here")


def test_the_validation_env_flies_the_validation_protocol(tmp_path: Path) -> None:
    entry = {**tiny_entry(), "env_kwargs": {**tiny_entry()["env_kwargs"], "split": "train"}}
    config = tmp_path / "tiny.yml"
    config.write_text(yaml.safe_dump({ENV: entry}))
    cfg = load_config(ENV, config)
    assert cfg.world.config.split == "train" and not cfg.world.config.mission_from_seed
    venv = make_validation_env(cfg, 2, 1000)
    try:
        copies = venv.get_attr("config")
        assert all(c.mission_from_seed and c.split == "train" for c in copies)
    finally:
        venv.close()
