"""COMA on envs that are not the UAV world, through the route every SB3 user takes
(``make_marl_vec_env`` over a PettingZoo ``ParallelEnv``), and the boundary between the algorithm
and the world (that the UAV world trains as it did: tests/test_uav_training_fingerprint.py)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from pettingzoo import ParallelEnv
from stable_baselines3.common.vec_env import DummyVecEnv
from test_architecture import ROOT, imports_of

from sb3_coma import COMA, make_marl_vec_env
from sb3_coma.coma.policies import one_hot_others
from sb3_coma.common.joint import actor_observation_space

FAST = {"n_steps": 16, "batch_size": 16, "n_epochs": 1, "n_critic_epochs": 1}


def _spread(**kwargs: Any) -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=False, **kwargs)


def _roundtrip(model: COMA, venv: Any, tmp_path: Path) -> None:
    """save -> load -> the same deterministic actions on the same observations."""
    obs = venv.reset()
    before, _ = model.predict(obs, deterministic=True)
    model.save(tmp_path / "model.zip")
    loaded = COMA.load(tmp_path / "model.zip", env=venv, device="cpu")
    after, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(before, after)
    assert loaded.state_source == model.state_source and loaded.n_agents == model.n_agents


def test_mlp_policy_on_simple_spread_trains_saves_loads_predicts(tmp_path: Path) -> None:
    venv = make_marl_vec_env(_spread, n_envs=2, seed=0)
    model = COMA("MlpPolicy", venv, seed=0, device="cpu", **FAST)
    assert model.state_source == "env" and model.n_agents == 3
    model.learn(160)
    assert model.num_timesteps == 160  # joint steps
    _roundtrip(model, venv, tmp_path)


def test_load_with_n_steps_sets_the_rollout_length(tmp_path: Path) -> None:
    """``COMA.load(path, n_steps=...)`` sizes the rollouts as the constructor's ``n_steps`` does."""
    venv = make_marl_vec_env(_spread, n_envs=2, seed=0)
    COMA("MlpPolicy", venv, seed=0, device="cpu", **FAST).save(tmp_path / "model.zip")
    loaded = COMA.load(tmp_path / "model.zip", env=venv, device="cpu", n_steps=24)
    assert loaded.n_steps == 24 and loaded.rollout_buffer.n_steps == 24
    loaded.learn(48)
    assert loaded.num_timesteps == 48  # one rollout of 24 steps x 2 copies


def test_mlp_critic_input_sizes_follow_the_state_source() -> None:
    """COMA's critic input: state + own observation (18) + one-hot id (3) + others' one-hot actions (3 x 5)."""
    for state, width in (("env", 54), ("concat", 3 * 18)):
        model = COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=1, seed=0, state=state), device="cpu", **FAST)
        assert model.state_source == state
        assert model.policy.critic.mlp[0].in_features == width + 18 + 3 + 3 * 5


def test_level_based_foraging_through_the_gymnasium_adapter(tmp_path: Path) -> None:
    gymnasium = pytest.importorskip("gymnasium")
    pytest.importorskip("lbforaging")
    from sb3_coma.common.gymnasium_marl import GymnasiumMultiAgentToParallel

    def lbf() -> ParallelEnv:
        return GymnasiumMultiAgentToParallel(gymnasium.make("Foraging-5x5-2p-1f-coop-v3", disable_env_checker=True))

    venv = make_marl_vec_env(lbf, n_envs=2, seed=1)
    model = COMA("MlpPolicy", venv, seed=0, device="cpu", **FAST)
    assert model.state_source == "concat" and model.n_agents == 2
    model.learn(160)
    _roundtrip(model, venv, tmp_path)


def test_cnn_policy_on_image_observations(tmp_path: Path) -> None:
    """PettingZoo's cooperative pong, reduced to 36 x 36 x 2 grey frames with SuperSuit; SB3's
    image transpose wrapper sits between the env and COMA and forwards the contract."""
    pytest.importorskip("pygame")
    import supersuit as ss
    from pettingzoo.butterfly import cooperative_pong_v6

    def pong() -> ParallelEnv:
        env = cooperative_pong_v6.parallel_env(max_cycles=40)
        return ss.frame_stack_v1(ss.resize_v1(ss.color_reduction_v0(env, "full"), 36, 36), 2)

    venv = make_marl_vec_env(pong, n_envs=1, seed=0, state="concat")
    model = COMA(
        "CnnPolicy",
        venv,
        seed=0,
        device="cpu",
        policy_kwargs={"features_extractor_kwargs": {"features_dim": 32}},
        **FAST,
    )
    assert type(model.policy.actor.features_extractor).__name__ == "NatureCNN"
    model.learn(48)
    _roundtrip(model, model.get_env(), tmp_path)


class MaskedLine(ParallelEnv):
    """Two agents on a line of 5 cells; actions 0 left, 1 stay, 2 right; moving off the line is
    masked (``action_mask`` key of a Dict observation, PettingZoo's convention, or infos). The
    team is paid when both stand on cell 4. Counts masked actions taken anyway."""

    metadata: ClassVar[dict[str, Any]] = {"name": "masked_line_v0", "render_modes": []}

    def __init__(self, mask_in: str = "obs") -> None:
        self.possible_agents = ["a0", "a1"]
        self.render_mode = None
        self.mask_in = mask_in
        self.invalid = 0
        box = spaces.Box(0.0, 1.0, (5,), np.float32)
        self._obs_space = (
            spaces.Dict({"observation": box, "action_mask": spaces.MultiBinary(3)}) if mask_in == "obs" else box
        )

    def observation_space(self, agent: str) -> spaces.Space:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space:
        return spaces.Discrete(3)

    def _mask(self, agent: str) -> np.ndarray:
        pos = self.pos[agent]
        return np.array([pos > 0, True, pos < 4], dtype=np.int8)

    def _obs(self) -> tuple[dict[str, Any], dict[str, Any]]:
        obs, infos = {}, {}
        for agent in self.agents:
            line = np.zeros(5, np.float32)
            line[self.pos[agent]] = 1.0
            obs[agent] = {"observation": line, "action_mask": self._mask(agent)} if self.mask_in == "obs" else line
            infos[agent] = {"action_mask": self._mask(agent)} if self.mask_in == "info" else {}
        return obs, infos

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        self.agents = list(self.possible_agents)
        self.pos = {agent: 0 for agent in self.agents}
        self.t = 0
        return self._obs()

    def step(self, actions: dict[str, int]) -> tuple[dict, dict, dict, dict, dict]:
        for agent, action in actions.items():
            if not self._mask(agent)[action]:
                self.invalid += 1
                continue
            self.pos[agent] += int(action) - 1
        self.t += 1
        reward = float(all(pos == 4 for pos in self.pos.values()))
        obs, infos = self._obs()
        done = self.t >= 8
        rewards = {agent: reward for agent in self.agents}
        flags = {agent: False for agent in self.agents}
        truncs = {agent: done for agent in self.agents}
        if done:
            self.agents = []
        return obs, rewards, flags, truncs, infos


@pytest.mark.parametrize("mask_in", ["obs", "info"])
def test_masked_actions_are_never_taken(mask_in: str) -> None:
    """Masks from an ``action_mask`` observation key or from sb3-contrib's ``action_masks()``."""
    envs: list[MaskedLine] = []

    def make() -> MaskedLine:
        envs.append(MaskedLine(mask_in))
        return envs[-1]

    venv = make_marl_vec_env(make, n_envs=2, seed=0)
    model = COMA("MlpPolicy", venv, seed=0, device="cpu", exploration_initial_eps=0.5, **FAST)
    assert actor_observation_space(venv.observation_space) == spaces.Box(0.0, 1.0, (5,), np.float32)
    model.learn(200)
    assert sum(env.invalid for env in envs) == 0
    if mask_in == "info":
        obs = venv.reset()
        masks = np.stack(venv.env_method("action_masks"))
        actions, _ = model.predict(obs, action_masks=masks, deterministic=True)
        assert all(masks[row, a] for row, a in enumerate(actions))


def test_an_env_without_masks_trains_as_with_all_valid_masks_bit_for_bit() -> None:
    """Without masks COMA masks nothing (as SB3's PPO), which must change no number: the same
    weights as a run whose every step came with an all-ones mask (the path before 0.19.0)."""
    trained = []
    for all_ones in (False, True):
        venv = make_marl_vec_env(_spread, n_envs=2, seed=0)
        model = COMA("MlpPolicy", venv, seed=0, device="cpu", exploration_initial_eps=0.3, **FAST)
        if all_ones:
            width = int(model.action_space.n)
            model._masks = lambda obs, env=None, n=width: np.ones((len(obs), n), dtype=np.float32)  # type: ignore[method-assign]
        model.learn(64)
        assert (model.rollout_buffer.time_major()["mask"] is None) is not all_ones
        trained.append(model.policy.state_dict())
    assert trained[0].keys() == trained[1].keys()
    for key in trained[0]:
        assert th.equal(trained[0][key], trained[1][key]), key


def test_bad_masks_are_named() -> None:
    model = COMA("MlpPolicy", make_marl_vec_env(lambda: MaskedLine("info"), n_envs=1, seed=0), device="cpu", **FAST)
    obs = model.get_env().reset()
    with pytest.raises(ValueError, match=r"shape \(rows, 3\)"):
        model.predict(obs, action_masks=np.ones((2, 4)))
    with pytest.raises(ValueError, match=r"rows \[1\] allow no action"):
        model.predict(obs, action_masks=np.array([[1, 1, 1], [0, 0, 0]]))


def test_bad_envs_and_policies_get_one_clear_line() -> None:
    pendulum = DummyVecEnv([lambda: __import__("gymnasium").make("Pendulum-v1")])
    pendulum.n_agents = 1  # type: ignore[attr-defined]
    with pytest.raises(ValueError, match=r"COMA needs Discrete actions per agent, got Box"):
        COMA("MlpPolicy", pendulum)
    with pytest.raises(ValueError, match=r"does not expose `n_agents`"):
        COMA("MlpPolicy", DummyVecEnv([lambda: __import__("gymnasium").make("CartPole-v1")]))
    spread = make_marl_vec_env(_spread, n_envs=1, seed=0)
    with pytest.raises(
        ValueError, match=r"UAV policies .* need .*Discrete\(6\).*use MlpPolicy, CnnPolicy or MultiInputPolicy"
    ):
        COMA("CBAMPolicy", spread)
    with pytest.raises(ValueError, match=r"unknown policy alias 'MLPPolicy'.*'MlpPolicy'"):
        COMA("MLPPolicy", spread)
    with pytest.raises(ValueError, match=r"need Discrete actions per agent, got Box.*'agent_0'"):
        make_marl_vec_env(lambda: _spread_continuous(), n_envs=1)


def _spread_continuous() -> ParallelEnv:
    pytest.importorskip("mpe2")
    from mpe2 import simple_spread_v3

    return simple_spread_v3.parallel_env(N=3, max_cycles=25, continuous_actions=True)


def test_others_actions_are_one_hot_with_the_agents_own_zeroed() -> None:
    actions = th.tensor([[0, 2, 1]])
    others = one_hot_others(actions, 3).view(1, 3, 3, 3)
    for i in range(3):
        assert others[0, i, i].sum() == 0  # agent i's own action never enters its row
        for j in range(3):
            if j != i:
                assert others[0, i, j].argmax() == actions[0, j] and others[0, i, j].sum() == 1


def test_the_algorithm_imports_nothing_from_the_world() -> None:
    found = [imp for path in sorted((ROOT / "sb3_coma" / "coma").glob("*.py")) for imp in imports_of(path)]
    assert found, "the walker saw no imports at all"
    assert not [
        str(imp) for imp in found if imp.target.split(".")[0] == "uav_ipp" or imp.target.startswith("sb3_coma.uav")
    ]


def test_import_sb3_coma_loads_neither_the_world_nor_rl_zoo3() -> None:
    code = (
        "import sys, sb3_coma; "
        "print([m for m in ('numba', 'uav_ipp', 'uav_ipp.kernels', 'uav_ipp.maps', 'rl_zoo3', 'sb3_coma.app') "
        "if m in sys.modules])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_learn_leaves_no_empty_folder_in_the_temp_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """SB3 makes an ``SB3-<timestamp>`` folder for a stdout-only logger; COMA's logger has none."""
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    model = COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=1, seed=0), device="cpu", verbose=1, **FAST)
    model.learn(32)
    model.learn(32, reset_num_timesteps=False)
    assert not list(tmp_path.glob("SB3-*"))
    assert model.logger.name_to_value is not None  # the logger still records


def test_a_string_is_not_a_bool() -> None:
    """``normalize_advantage="false"`` would be truthy: refused with one line naming the value."""
    venv = make_marl_vec_env(_spread, n_envs=1, seed=0)
    with pytest.raises(ValueError, match=r"normalize_advantage must be True or False, got 'false'"):
        COMA("MlpPolicy", venv, normalize_advantage="false")  # type: ignore[arg-type]


@pytest.mark.parametrize("value", [1e100, 10**10 + 1, 0, 2.5, "100"])
def test_joint_step_totals_outside_the_sensible_range_are_named(value: Any) -> None:
    """One rule for ``learn()``, the config's ``n_timesteps`` and ``--timesteps``: 1 .. 1e10."""
    from sb3_coma.coma.validation import check_total_timesteps

    model = COMA("MlpPolicy", make_marl_vec_env(_spread, n_envs=1, seed=0), device="cpu", **FAST)
    with pytest.raises(ValueError, match=r"total_timesteps must be a whole number of joint steps from 1 to 1e\+10"):
        model.learn(value)
    assert check_total_timesteps(3.6e4) == 36_000


def test_cli_and_config_take_the_same_bound(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    from sb3_coma.app.config import TrainingError, validate_entry
    from sb3_coma.cli import main

    assert main(["train", "--timesteps", "1e100", "--run-dir", str(tmp_path / "run")]) == 2
    (last,) = capsys.readouterr().err.strip().splitlines()  # one error line (sb3_coma.cli)
    assert last.endswith(
        "argument --timesteps: the value must be a whole number of joint steps from 1 to 1e+10, got 1e+100"
    )
    assert not (tmp_path / "run").exists()
    with pytest.raises(TrainingError, match=r"n_timesteps must be a whole number of joint steps from 1 to 1e\+10"):
        validate_entry({"n_timesteps": 1e100}, "coma.yml: UavIpp-Env1-v0")
