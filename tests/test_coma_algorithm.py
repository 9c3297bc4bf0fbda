"""COMA as an SB3 algorithm: joint-step counting, logging, save/load, seeding, argument errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th
from coma_fakes import (
    FakeUavVecEnv,
    capture_logger,
    make_fake_vec_env,
    obs_space,
    one_torch_thread,  # noqa: F401 (autouse fixture)
)
from gymnasium import spaces

from sb3_coma.coma import COMA
from sb3_coma.uav.policies import CBAMPolicy, UavCnnPolicy

SMALL = dict(features_extractor_kwargs=dict(channels=(8, 16, 16), features_dim=32))
FAST = dict(batch_size=16, n_steps=8, learning_rate=1e-3, critic_learning_rate=1e-3, policy_kwargs=SMALL)


def make(policy: str = "UavCnnPolicy", seed: int = 0, n_envs: int = 2, n_agents: int = 2, **kwargs) -> COMA:
    args = {**FAST, **kwargs}
    return COMA(policy, make_fake_vec_env(n_envs=n_envs, n_agents=n_agents, seed=seed), seed=seed, **args)


def test_timesteps_are_joint_steps_and_logs_are_written() -> None:
    model = make(
        exploration_initial_eps=0.5,
        exploration_final_eps=0.1,
        exploration_fraction=0.5,
        target_update_interval=1,
        n_critic_epochs=1,
    )
    logger, out = capture_logger()
    model.set_logger(logger)
    model.learn(3 * 16)  # 3 rollouts of 8 steps x 2 copies
    assert model.n_copies == 2 and model.n_agents == 2 and model.env.num_envs == 4
    assert model.num_timesteps == 48  # not 96 agent steps
    assert model.rollout_buffer.obs["local"].shape[:3] == (8, 2, 2)
    last = out.dumps[-1]
    for key in (
        "train/critic_loss",
        "train/actor_loss",
        "train/q_mean",
        "train/advantage_mean",
        "train/advantage_std",
        "train/explained_variance",
        "train/epsilon",
        "train/entropy",
        "train/target_updates",
        "rollout/ep_rew_mean",
        "rollout/ep_f1",
        "rollout/ep_entropy",
    ):
        assert key in last, key
    assert last["time/total_timesteps"] == 48
    assert last["rollout/ep_len_mean"] == 6  # budget of the fake env, counted once per mission
    eps = out.series("train/epsilon")
    assert eps[0] > eps[-1] >= 0.1
    # SB3 dumps before each train(): the last dump shows the previous update.
    assert 0 < last["train/target_updates"] == model._n_target_updates - 1
    assert np.isfinite(last["train/critic_loss"]) and np.isfinite(last["train/actor_loss"])


def test_default_n_steps_is_32_stretched_to_fill_one_batch_per_rollout() -> None:
    model = COMA("CBAMPolicy", make_fake_vec_env(n_envs=3, n_agents=2), batch_size=10, policy_kwargs=SMALL)
    assert model.n_steps == 32  # the default, already more than ceil(10 / 3 copies)
    assert isinstance(model.policy, CBAMPolicy)
    # the library defaults are the measured settings that learn (docs/training.md)
    assert model.learning_rate == 3e-4 and model.critic_learning_rate == 1e-3
    assert model.gamma == 0.99 and model.td_lambda == 0.8
    assert (model.n_epochs, model.clip_range, model.advantage) == (4, 0.2, "return")
    assert COMA("UavCnnPolicy", make_fake_vec_env(n_envs=1), batch_size=512, policy_kwargs=SMALL).n_steps == 512
    assert COMA("UavCnnPolicy", make_fake_vec_env(n_envs=3), batch_size=200, policy_kwargs=SMALL).n_steps == 67


def test_target_update_interval_is_honoured() -> None:
    model = make(n_critic_epochs=3, target_update_interval=2)  # 1 minibatch x 3 epochs per rollout
    model.learn(32)
    assert model._n_critic_updates == 6 and model._n_target_updates == 3


def test_predict_is_per_agent_and_masked() -> None:
    model = make()
    venv = model.env
    obs = venv.reset()
    rng = np.random.default_rng(0)
    for _ in range(30):
        obs["action_mask"] = (rng.random((4, 6)) < 0.3).astype(np.float32)
        obs["action_mask"][np.arange(4), rng.integers(0, 6, 4)] = 1.0
        for deterministic in (True, False):
            actions, _ = model.predict(obs, deterministic=deterministic)
            assert actions.shape == (4,)
            assert (obs["action_mask"][np.arange(4), actions] == 1).all()
    single = {k: v[0] for k, v in obs.items()}
    action, _ = model.predict(single, deterministic=True)
    assert np.ndim(action) == 0


def test_training_never_sends_invalid_actions() -> None:
    model = make(exploration_initial_eps=0.5, exploration_final_eps=0.5)
    model.learn(64)
    assert model.env.venv.invalid_actions == 0


def test_same_seed_same_training_curve() -> None:
    runs = []
    for _ in range(2):
        model = make(seed=7, exploration_initial_eps=0.3, ent_coef=0.01)
        logger, out = capture_logger()
        model.set_logger(logger)
        model.learn(64)
        losses = (out.series("train/critic_loss"), out.series("train/actor_loss"))
        runs.append((*losses, model.policy.parameters_to_vector()))
    assert runs[0][0] == runs[1][0] and runs[0][1] == runs[1][1]
    assert np.array_equal(runs[0][2], runs[1][2])
    other = make(seed=8)
    other.learn(64)
    assert not np.array_equal(other.policy.parameters_to_vector(), runs[0][2])


def test_save_load_round_trip_and_continue(tmp_path: Path) -> None:
    model = make("CBAMPolicy", n_critic_epochs=2, target_update_interval=3)
    model.learn(48)
    path = tmp_path / "coma.zip"
    model.save(path)

    env = make_fake_vec_env(seed=1)
    loaded = COMA.load(path, env=env)
    assert type(loaded.policy) is CBAMPolicy
    assert loaded.n_agents == 2 and loaded.batch_size == 16 and loaded.target_update_interval == 3
    assert loaded._n_critic_updates == model._n_critic_updates

    obs = env.reset()
    a1, _ = model.predict(obs, deterministic=True)
    a2, _ = loaded.predict(obs, deterministic=True)
    assert np.array_equal(a1, a2)
    joint = model._grouped(obs)
    state = model._joint_state(joint, None)
    actions = th.as_tensor(a1).view(2, 2)
    with th.no_grad():
        for target in (False, True):
            assert th.equal(
                model.policy.q_values(joint, state, actions, target=target),
                loaded.policy.q_values(joint, state, actions, target=target),
            )
    for name in ("optimizer", "critic_optimizer"):
        saved = getattr(model.policy, name).state_dict()
        restored = getattr(loaded.policy, name).state_dict()
        assert saved["param_groups"][0]["lr"] == restored["param_groups"][0]["lr"]
        for key, st in saved["state"].items():
            assert th.equal(st["exp_avg"], restored["state"][key]["exp_avg"])

    before = loaded.policy.parameters_to_vector()
    loaded.learn(32, reset_num_timesteps=False)
    assert loaded.num_timesteps == 48 + 32
    assert not np.array_equal(before, loaded.policy.parameters_to_vector())

    # Prediction-only load without an env.
    bare = COMA.load(path)
    a3, _ = bare.predict(obs, deterministic=True)
    assert np.array_equal(a1, a3)


@pytest.mark.parametrize("removed", [dict(tau=0.5), dict(prior_kl_coef=0.1), dict(temperature_final=0.25)])
def test_removed_arguments_are_refused_for_new_models(removed: dict) -> None:
    with pytest.raises(TypeError, match=next(iter(removed))):
        make(**removed)
    with pytest.raises(TypeError, match="critic_gain"):
        make(policy_kwargs={**SMALL, "critic_gain": False})


def test_policy_save_load(tmp_path: Path) -> None:
    model = make("UavCnnPolicy")
    model.policy.save(tmp_path / "policy.pt")
    policy = UavCnnPolicy.load(tmp_path / "policy.pt")
    obs = model.env.reset()
    assert np.array_equal(model.predict(obs, deterministic=True)[0], policy.predict(obs, deterministic=True)[0])


class TestErrors:
    def test_env_without_n_agents(self) -> None:
        with pytest.raises(ValueError, match="n_agents"):
            COMA("CBAMPolicy", FakeUavVecEnv(n_agents=None))

    def test_num_envs_not_a_multiple(self) -> None:
        with pytest.raises(ValueError, match="num_envs=5 is not a multiple of n_agents=2"):
            COMA("CBAMPolicy", FakeUavVecEnv(n_envs=2, n_agents=2, num_envs=5))

    def test_not_a_vec_env(self) -> None:
        with pytest.raises(TypeError, match="VecEnv"):
            COMA("CBAMPolicy", "UavIpp-Env1-v0")

    @pytest.mark.parametrize(
        ("space", "match"),
        [
            (obs_space(drop_key="state"), r"need observation\['state'\]"),
            (obs_space(drop_key="action_mask"), r"need observation\['action_mask'\]"),
            (
                obs_space(local_shape=(7, 11, 11)),
                r"shape \(8, H, W\) or, observation v3, \(41, H, W\); got \(7, 11, 11\).*fusion",
            ),
            (obs_space(state_shape=(3, 9, 9)), r"'state'.*\(3, 11, 11\), got \(3, 9, 9\)"),
            (spaces.Box(0.0, 1.0, (8, 11, 11)), "need a Dict observation"),
        ],
    )
    def test_bad_observation_space(self, space: spaces.Space, match: str) -> None:
        with pytest.raises(ValueError, match=match):
            COMA("CBAMPolicy", FakeUavVecEnv(observation_space=space))

    @pytest.mark.parametrize(
        ("action_space", "observation_space", "match"),
        [
            # COMA's own check: the mask has 6 entries, the action space 5
            (spaces.Discrete(5), None, r"one entry per action of Discrete\(5\)"),
            (spaces.Box(-1.0, 1.0, (6,)), None, r"Discrete actions per agent, got Box"),
            # a consistent mask, but the UAV policies need the 6 moves
            (
                spaces.Discrete(5),
                spaces.Dict({**obs_space().spaces, "action_mask": spaces.Box(0.0, 1.0, (5,))}),
                r"Discrete\(6\), got Discrete\(5\)",
            ),
        ],
    )
    def test_bad_action_space(
        self, action_space: spaces.Space, observation_space: spaces.Space | None, match: str
    ) -> None:
        with pytest.raises(ValueError, match=match):
            COMA("CBAMPolicy", FakeUavVecEnv(action_space=action_space, observation_space=observation_space))

    @pytest.mark.parametrize(
        ("kwargs", "error", "match"),
        [
            (dict(batch_size=64, n_steps=8), ValueError, r"batch_size=64 .*\(n_steps=8 x 2 env copies = 16"),
            (dict(learning_rate=0.0), ValueError, "learning_rate must be a finite positive number, got 0.0"),
            (dict(critic_learning_rate=-1e-4), ValueError, "critic_learning_rate must be a finite positive number"),
            (dict(learning_rate=lambda _: 0.0), ValueError, "learning_rate must be a finite positive number"),
            (dict(gamma=1.5), ValueError, r"gamma must lie in \[0, 1\], got 1.5"),
            (dict(td_lambda=-0.1), ValueError, r"td_lambda must lie in \[0, 1\], got -0.1"),
            (dict(batch_size=0), ValueError, "batch_size must be >= 1, got 0"),
            (dict(n_steps=2.5), TypeError, "n_steps must be an int"),
            (dict(target_update_interval=0), ValueError, "target_update_interval"),
            (dict(exploration_initial_eps=2.0), ValueError, "exploration_initial_eps"),
            (dict(exploration_fraction=0.0), ValueError, "exploration_fraction"),
            (dict(ent_coef=-1.0), ValueError, "ent_coef"),
            (dict(max_grad_norm=0.0), ValueError, "max_grad_norm"),
        ],
    )
    def test_bad_hyperparameters(self, kwargs: dict, error: type, match: str) -> None:
        args = {"batch_size": 8, "n_steps": 8, **kwargs}
        with pytest.raises(error, match=match):
            COMA("CBAMPolicy", FakeUavVecEnv(), **args)

    def test_unknown_policy_alias(self) -> None:
        with pytest.raises(ValueError, match=r"unknown policy alias 'NoSuchPolicy'.*CBAMPolicy"):
            COMA("NoSuchPolicy", FakeUavVecEnv())
        with pytest.raises(TypeError, match="COMAPolicy subclass"):
            COMA(dict, FakeUavVecEnv())


@pytest.mark.parametrize(("truncate", "bootstrap"), [(False, True), (True, True), (True, False)])
def test_time_limit_truncation_is_bootstrapped(
    truncate: bool, bootstrap: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A truncated mission adds gamma * V(terminal state) to its last reward; a terminated one does
    not, nor a truncated one with ``bootstrap_time_limits=False``."""
    venv = FakeUavVecEnv(n_envs=2, n_agents=2, budget=3, truncate=truncate)
    model = COMA(
        "UavCnnPolicy",
        venv,
        batch_size=12,
        n_steps=6,
        gamma=0.5,
        seed=0,
        policy_kwargs=SMALL,
        bootstrap_time_limits=bootstrap,
    )
    rewards_seen: list[np.ndarray] = []
    original_step = venv.step_wait

    def recording_step():
        out = original_step()
        rewards_seen.append(out[1].copy())
        return out

    monkeypatch.setattr(venv, "step_wait", recording_step)
    monkeypatch.setattr(
        model,
        "_expected_target_values",
        lambda obs, masks, states, time_left=None: th.full((len(obs["local"]) // 2, 2), 3.0),
    )
    monkeypatch.setattr(model, "train", lambda: None)
    model.learn(12)
    stored = model.rollout_buffer.rewards.reshape(6, 4)
    env_rewards = np.stack(rewards_seen)
    bonus = np.zeros_like(env_rewards)
    if truncate and bootstrap:
        bonus[[2, 5]] = 0.5 * 3.0  # missions end after steps 3 and 6
    assert np.allclose(stored, env_rewards + bonus)
    assert model.rollout_buffer.dones.reshape(6, 4)[[2, 5]].all()


@pytest.mark.filterwarnings("ignore:rich is experimental")
def test_progress_bar_counts_joint_steps(monkeypatch: pytest.MonkeyPatch) -> None:
    from sb3_coma.coma.progress import JointStepProgressBar

    bars: list[JointStepProgressBar] = []
    original = JointStepProgressBar._on_training_end

    def keep(self: JointStepProgressBar) -> None:
        bars.append(self)
        original(self)

    monkeypatch.setattr(JointStepProgressBar, "_on_training_end", keep)
    make().learn(32, progress_bar=True)
    assert bars and bars[0].pbar.n == bars[0].pbar.total == 32  # not 64 agent steps


@pytest.mark.parametrize("kind", ["return", "q"])
def test_advantage_is_the_chosen_term_minus_the_counterfactual_baseline(kind: str) -> None:
    model = make(advantage=kind)
    model.learn(16)  # fills the rollout buffer
    data = model.rollout_buffer.joint_steps()
    actions = data["actions"]
    gen = th.Generator().manual_seed(0)
    q_all = th.randn(*actions.shape, 6, generator=gen)
    targets = th.randn(*actions.shape, generator=gen)
    advantage, old_log_prob = model._advantages(data, q_all, targets)
    with th.no_grad():
        rows = {key: value.flatten(0, 1) for key, value in data["obs"].items()}
        logits = model.policy.masked_logits(rows, data["mask"].flatten(0, 1))
    probs = th.softmax(logits, -1).view(*actions.shape, 6)
    baseline = (probs * q_all).sum(-1)
    first = targets if kind == "return" else q_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    th.testing.assert_close(advantage, first - baseline)
    th.testing.assert_close(old_log_prob.exp(), probs.gather(-1, actions.unsqueeze(-1)).squeeze(-1))
    assert (probs[data["mask"] == 0] == 0).all()  # the baseline runs over valid actions only


def test_clipped_and_plain_actor_updates_train() -> None:
    """The logged clip fraction is the share of ratios outside ``[1 - clip, 1 + clip]``: exactly 0
    for the policy that collected the rollout, the known share when some ratios are moved out on
    purpose, > 0 once the actor itself is changed, and always 0 without clipping."""
    for clip in (0.2, None):
        model = make(clip_range=clip, n_epochs=3)
        logger, out = capture_logger()
        model.set_logger(logger)
        model.learn(48)
        clip_fraction = out.series("train/clip_fraction")
        assert len(clip_fraction) >= 2 and all(0.0 <= c <= 1.0 for c in clip_fraction)
        if clip is None:
            assert all(c == 0.0 for c in clip_fraction)

        # The actor loss on the last rollout, against the policy that would have collected it.
        data = model.rollout_buffer.joint_steps()
        n_joint = data["actions"].shape[0]
        idx = th.arange(n_joint)
        advantage = th.randn(data["actions"].shape, generator=th.Generator().manual_seed(0))
        with th.no_grad():
            q_all = th.zeros(*data["actions"].shape, model.policy.n_actions)
            _, old_log_prob = model._advantages(data, q_all, th.zeros(data["actions"].shape))
            assert model._actor_loss(data, idx, advantage, old_log_prob)[2] == 0.0  # unchanged: ratio 1

            # Ratios moved on purpose: exp(-log 1.5) = 0.67 (outside) on the first joint steps,
            # exp(-log 1.1) = 0.91 (inside) on the next ones, 1 on the rest.
            shifted = old_log_prob.clone()
            shifted[: n_joint // 4] += np.log(1.5)
            shifted[n_joint // 4 : n_joint // 2] += np.log(1.1)
            expected = (n_joint // 4) / n_joint if clip is not None else 0.0
            assert model._actor_loss(data, idx, advantage, shifted)[2] == pytest.approx(expected)
            assert clip is None or expected > 0.0

            # The policy changed on purpose (noise of std 0.5 on every actor weight, far more than
            # the 0.01-scale action head holds): its ratios leave the band.
            gen = th.Generator().manual_seed(1)
            for param in model.policy.actor.parameters():
                param.add_(0.5 * th.randn(param.shape, generator=gen))
            changed = model._actor_loss(data, idx, advantage, old_log_prob)[2]
        if clip is None:
            assert changed == 0.0
        else:
            assert 0.0 < changed <= 1.0, changed


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"advantage": "ppo"}, "advantage"),
        ({"clip_range": 0}, "clip_range"),
        ({"clip_range": True}, "clip_range"),
        ({"clip_range": lambda progress: -0.1}, "clip_range must be None, a positive number or a schedule of one"),
        ({"n_epochs": 0}, "n_epochs"),
    ],
)
def test_bad_actor_update_options(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        make(**kwargs)


def test_the_clip_range_may_be_a_schedule_as_ppos(tmp_path: Path) -> None:
    """rl-zoo3 reads an entry's ``clip_range`` (``0.1``, ``lin_0.2``) as a schedule of the remaining
    progress: COMA clips with its value at each update, logs it and saves it."""
    from rl_zoo3.utils import SimpleLinearSchedule

    model = make(clip_range=SimpleLinearSchedule(0.2), n_epochs=2)
    logger, out = capture_logger()
    model.set_logger(logger)
    model.learn(48)
    # three rollouts of 16 joint steps; each update's clip is logged before the next rollout
    assert out.series("train/clip_range") == pytest.approx([0.2 * 2 / 3, 0.2 / 3])
    model._current_progress_remaining = 0.5
    assert model._clip_range_now() == pytest.approx(0.1)
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", device="cpu")
    loaded._current_progress_remaining = 0.25
    assert loaded._clip_range_now() == pytest.approx(0.05)
    assert make(clip_range=None)._clip_range_now() is None


def test_the_zoos_schedules_keep_comas_plain_gradient_and_make_its_rates_schedules() -> None:
    from sb3_coma.app.zoo_marl import preprocess_schedules

    read = preprocess_schedules({"clip_range": None, "learning_rate": 1e-3, "critic_learning_rate": "lin_1e-3"})
    assert read["clip_range"] is None and read["learning_rate"](0.5) == 1e-3
    assert read["critic_learning_rate"](0.5) == pytest.approx(5e-4)
    clipped = preprocess_schedules({"clip_range": 0.1})["clip_range"]
    assert make(clip_range=clipped)._clip_range_now() == pytest.approx(0.1)  # COMA takes rl-zoo3's constant


def test_predict_checks_the_observation_at_the_api_boundary() -> None:
    model = make()
    obs = model.env.reset()
    model.predict(obs, deterministic=True)
    bad = dict(obs)
    bad["local"] = obs["local"].copy()
    bad["local"][0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="'local' holds NaN or inf"):
        model.predict(bad)
    with pytest.raises(ValueError, match="lacks 'action_mask'"):
        model.predict({k: v for k, v in obs.items() if k != "action_mask"})
    with pytest.raises(TypeError, match="observation dict"):
        model.predict(obs["local"])


def test_adam_takes_its_fused_kernel_unless_the_caller_chose_an_implementation() -> None:
    from sb3_coma.coma.policies import optimizer_implementation

    assert optimizer_implementation(th.optim.Adam, {"eps": 1e-5}) == {"eps": 1e-5, "fused": True}
    assert optimizer_implementation(th.optim.Adam, {"foreach": False}) == {"foreach": False}
    assert optimizer_implementation(th.optim.Adam, {"fused": False}) == {"fused": False}
    assert optimizer_implementation(th.optim.RMSprop, {}) == {}
    model = make("MlpPolicy", policy_kwargs={})
    for name in ("optimizer", "critic_optimizer"):
        assert getattr(model.policy, name).param_groups[0]["fused"] is True
    assert model.policy.optimizer_kwargs == {}  # what is saved is what the caller passed
    chosen = make("MlpPolicy", policy_kwargs={"optimizer_kwargs": {"foreach": True}})
    assert chosen.policy.optimizer.param_groups[0]["fused"] in (None, False)
    assert chosen.policy.optimizer.param_groups[0]["foreach"] is True


def test_the_fused_adam_steps_as_the_looped_one_with_the_callers_settings() -> None:
    """The same update on the same gradients (up to float rounding), the caller's ``eps`` kept.
    Whole trainings are not compared: a rounding difference flips a sampled action sooner or later."""
    kwargs = {"eps": 1e-3, "betas": (0.8, 0.9)}
    fused = make("MlpPolicy", policy_kwargs={"optimizer_kwargs": kwargs})
    looped = make("MlpPolicy", policy_kwargs={"optimizer_kwargs": {**kwargs, "fused": False}})
    looped.policy.load_state_dict(fused.policy.state_dict())
    generator = th.Generator().manual_seed(0)
    for _ in range(3):
        gradients = [th.randn(p.shape, generator=generator) * 1e-2 for p in fused.policy.actor.parameters()]
        for model in (fused, looped):
            for parameter, gradient in zip(model.policy.actor.parameters(), gradients):
                parameter.grad = gradient.clone()
            model.policy.optimizer.step()
    for a, b in zip(fused.policy.actor.parameters(), looped.policy.actor.parameters()):
        assert th.allclose(a, b, rtol=0, atol=1e-6)
    start = make("MlpPolicy", policy_kwargs={"optimizer_kwargs": kwargs}).policy.actor.parameters()
    assert any(not th.equal(a, b) for a, b in zip(fused.policy.actor.parameters(), start))
