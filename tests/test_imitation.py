"""DAgger from a teacher planner into COMA's actor, and the decaying KL pull toward the clone."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

import uav_ipp
from sb3_coma import COMA
from sb3_coma.baselines import make_planner
from sb3_coma.uav.imitation import DaggerCheckpoint, DaggerInterrupted, clone_teacher

SMALL = {"features_extractor_kwargs": {"features_dim": 32, "channels": [8, 16, 16]}, "gain_inputs": True}


def _model(seed: int = 0, **kwargs) -> COMA:
    venv = uav_ipp.make_vec_env("env1", n_envs=2, fusion="mean", seed=seed, split="train", start="random")
    return COMA("UavCnnPolicy", venv, seed=seed, n_steps=8, batch_size=8, policy_kwargs=SMALL, **kwargs)


def _agreement_with(model: COMA, teacher, missions: int = 2) -> float:
    venv = model.env
    venv.seed(123)
    hits, total = 0, 0
    for _ in range(missions // 2):
        obs = venv.reset()
        for _ in range(15):
            target, _ = teacher.predict(obs)
            mine, _ = model.predict(obs, deterministic=True)
            hits += int((mine == target).sum())
            total += target.size
            obs, *_ = venv.step(target)
    return hits / total


def test_dagger_moves_the_actor_toward_the_teacher():
    model = _model()
    teacher = make_planner("oracle", model.env, seed=0)
    before = _agreement_with(model, teacher)
    report = clone_teacher(model, teacher, missions_per_round=4, rounds=2, epochs=6, batch_size=64, seed=1)
    after = _agreement_with(model, teacher)
    assert [r["beta"] for r in report.rounds] == [1.0, 0.5]
    assert report.rounds[-1]["states"] == 2 * 4 * 15 * 4  # rounds x missions x steps x UAVs
    assert after > before + 0.1, (before, after)
    assert 0.0 <= report.agreement <= 1.0


def test_dagger_clones_at_its_own_rate_and_restores_the_models():
    """A model configured to fine-tune slowly (here not at all) still clones, and keeps its rate."""
    model = _model()
    for g in model.policy.optimizer.param_groups:
        g["lr"] = 0.0
    before = [p.detach().clone() for p in model.policy.actor.parameters()]
    clone_teacher(model, make_planner("oracle", model.env, seed=0), missions_per_round=2, rounds=1, epochs=1)
    assert any(not th.equal(a, b) for a, b in zip(before, model.policy.actor.parameters()))
    assert all(g["lr"] == 0.0 for g in model.policy.optimizer.param_groups)


def test_dagger_is_deterministic_for_a_seed():
    weights = []
    for _ in range(2):
        model = _model(seed=3)
        clone_teacher(
            model, make_planner("oracle", model.env, seed=0), missions_per_round=2, rounds=1, epochs=1, seed=5
        )
        weights.append(th.cat([p.flatten() for p in model.policy.actor.parameters()]))
    assert th.equal(weights[0], weights[1])


def test_kl_weight_decays_to_zero_and_is_off_without_a_reference():
    model = _model(kl_coef=2.0, kl_fraction=0.5)
    model._current_progress_remaining = 1.0
    assert model._kl_weight() == 0.0  # no reference yet
    model.set_reference_actor()
    assert model._kl_weight() == 2.0
    model._current_progress_remaining = 0.75
    assert np.isclose(model._kl_weight(), 1.0)
    model._current_progress_remaining = 0.4
    assert model._kl_weight() == 0.0


def _same_weights(a: th.nn.Module, b: th.nn.Module) -> bool:
    return all(th.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values()))


def test_the_kl_reference_and_the_actor_hold_are_saved_with_the_model(tmp_path):
    """Both are the recipe of a warm-started run: a model loaded to continue training keeps them (#35)."""
    model = _model(kl_coef=1.0)
    model.set_reference_actor()
    with th.no_grad():
        for p in model.policy.actor.parameters():
            p.add_(0.1)  # the actor moves on, the reference stays
    model.hold_actor(0.25)
    model.save(tmp_path / "m.zip")
    loaded = COMA.load(tmp_path / "m.zip", device="cpu")
    assert loaded.reference_actor is not None and not any(p.requires_grad for p in loaded.reference_actor.parameters())
    assert _same_weights(loaded.reference_actor, model.reference_actor)
    assert not _same_weights(loaded.reference_actor, loaded.policy.actor)
    assert loaded.critic_warmup == 0.25 and loaded.lr_schedule(0.8) == 0.0 and loaded.lr_schedule(0.7) == 3e-4
    loaded._current_progress_remaining = 1.0
    assert loaded._kl_weight() == 1.0
    plain = _model()
    plain.save(tmp_path / "plain.zip")
    again = COMA.load(tmp_path / "plain.zip", device="cpu")
    assert again.reference_actor is None and again.critic_warmup == 0.0
    plain.set_parameters(str(tmp_path / "m.zip"))  # parameters with a reference give the model one
    assert plain.reference_actor is not None and _same_weights(plain.reference_actor, model.reference_actor)
    with pytest.raises(ValueError, match=r"critic_warmup=1\.0"):
        model.hold_actor(1.0)


def test_dagger_stopped_and_continued_from_its_checkpoint_gives_the_same_clone(tmp_path):
    """Stopped after round 1 (the round in progress dropped), continued from the checkpoint by a
    fresh model: the clone, the report and the optimiser's own rate are an unbroken run's (#36)."""
    args = {"missions_per_round": 2, "rounds": 2, "epochs": 1, "batch_size": 64, "seed": 1}

    def fresh() -> COMA:
        return _model(learning_rate=1e-5)  # its own rate, restored after cloning at 3e-4

    unbroken = fresh()
    full = clone_teacher(
        unbroken, make_planner("oracle", unbroken.env), checkpoint=DaggerCheckpoint(tmp_path / "a"), **args
    )
    stopped, done = fresh(), []
    with pytest.raises(DaggerInterrupted) as info:
        clone_teacher(
            stopped,
            make_planner("oracle", stopped.env),
            checkpoint=DaggerCheckpoint(tmp_path / "b"),
            on_round=done.append,
            stop=lambda: bool(done),
            **args,
        )
    assert info.value.rounds_done == 1
    assert sorted(p.name for p in (tmp_path / "b").iterdir()) == ["round_0.npz", "state.pt"]
    resumed = fresh()
    report = clone_teacher(
        resumed, make_planner("oracle", resumed.env), checkpoint=DaggerCheckpoint(tmp_path / "b"), **args
    )
    assert report.rounds == full.rounds
    assert _same_weights(resumed.policy.actor, unbroken.policy.actor)
    assert all(g["lr"] == 1e-5 for g in resumed.policy.optimizer.param_groups)
    with pytest.raises(ValueError, match=r"other settings.*missions_per_round"):
        clone_teacher(
            fresh(),
            make_planner("oracle", unbroken.env),
            checkpoint=DaggerCheckpoint(tmp_path / "b"),
            **{**args, "missions_per_round": 4},
        )


def test_kl_pull_keeps_the_fine_tuned_actor_near_its_reference():
    def divergence(kl_coef: float) -> float:
        """Mean KL(reference || fine-tuned) over the last rollout's states."""
        model = _model(seed=2, kl_coef=kl_coef, kl_fraction=1.0)
        model.set_reference_actor()
        model.learn(64)
        data = model.rollout_buffer.joint_steps()
        obs = {k: data["obs"][k].flatten(0, 1) for k in ("local", "action_gain")}
        mask = data["mask"].flatten(0, 1)
        with th.no_grad():
            ref = th.log_softmax(model.policy.masked_logits(obs, mask, actor=model.reference_actor), -1)
            now = th.log_softmax(model.policy.masked_logits(obs, mask), -1)
        return float((ref.exp() * (ref - now)).sum(-1).mean())

    assert divergence(10.0) < 0.5 * divergence(0.0)


def test_bad_arguments_name_the_value():
    model = _model()
    teacher = make_planner("oracle", model.env)
    with pytest.raises(ValueError, match="rounds=0"):
        clone_teacher(model, teacher, rounds=0)
    with pytest.raises(ValueError, match="kl_coef"):
        _model(kl_coef=-1.0)


def test_dagger_experiment_command_writes_a_model_and_a_paired_report(tmp_path):
    import json

    from sb3_coma.experiments import dagger

    out = tmp_path / "d"
    argv = ["--env", "env1", "--rounds", "1", "--missions", "8", "--missions-eval", "2", "--out", str(out)]
    assert dagger.main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    assert (out / "clone.zip").is_file() and report["dagger_rounds"][0]["states"] == 8 * 15 * 4
    assert {"f1", "entropy"} == {d["metric"] for d in report["comparison"]["vs_ag"]}
    assert set(report["comparison"]["finals"]) == {str(out / "clone.zip"), "ag", "oracle"}
    # the same clone fine-tuned with one of COMA's settings changed: the saved model carries it
    tuned = tmp_path / "t"
    argv = ["--env", "env1", "--from", str(out / "clone.zip"), "--finetune", "256", "--missions-eval", "2"]
    argv += ["--set", "n_epochs=1", "--set", "advantage_before_critic_update=true", "--set", "n_steps=40"]
    assert dagger.main([*argv, "--out", str(tuned)]) == 0
    model = COMA.load(tuned / "finetuned.zip", device="cpu")
    assert model.n_epochs == 1 and model.advantage_before_critic_update is True
    assert model.n_steps == 40 and model.num_timesteps == 40 * 8  # one rollout of 40 steps x 8 copies
    # the same clone with a fresh dueling critic: its actor and the actor's optimizer state are the clone's
    clone = COMA.load(out / "clone.zip", device="cpu")
    swapped = dagger.with_dueling_critic(COMA.load(out / "clone.zip", device="cpu"))
    assert swapped.policy.dueling_critic and swapped.policy.critic.head.out_features == clone.action_space.n + 1
    for a, b in zip(swapped.policy.actor.state_dict().values(), clone.policy.actor.state_dict().values()):
        assert th.equal(a, b)
    moments = [state["exp_avg"] for state in clone.policy.optimizer.state_dict()["state"].values()]
    kept = [state["exp_avg"] for state in swapped.policy.optimizer.state_dict()["state"].values()]
    assert moments and all(th.equal(a, b) for a, b in zip(kept, moments, strict=True))
    dueling = tmp_path / "u"
    argv = ["--env", "env1", "--from", str(out / "clone.zip"), "--finetune", "40", "--missions-eval", "2"]
    assert dagger.main([*argv, "--set", "n_steps=5", "--dueling-critic", "--out", str(dueling)]) == 0
    assert COMA.load(dueling / "finetuned.zip", device="cpu").policy.dueling_critic


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("n_epoch=3", "'n_epoch' is not a COMA argument"),
        ("seed=3", "'seed' is not a COMA argument"),
        ("policy_kwargs={}", "the networks are the clone's"),
        ("kl_coef=2", "--kl"),
        ("n_epochs=0", "n_epochs must be >= 1, got 0"),
        ("n_epochs", "expected KEY=VALUE"),
    ],
)
def test_dagger_refuses_a_setting_coma_has_not_in_one_line(setting, message, capsys):
    from sb3_coma.experiments import dagger

    with pytest.raises(SystemExit) as stop:
        dagger.parse_args(["--out", "x", "--set", setting])
    assert stop.value.code == 2 and message in capsys.readouterr().err


def test_dagger_builds_a_new_clone_with_the_dueling_critic_and_keeps_a_loaded_clones_networks():
    from sb3_coma.experiments import dagger

    new = dagger.parse_args(["--out", "x", "--dueling-critic", "--set", "n_epochs=3"])
    assert dagger.config_overrides(new) == {"policy_kwargs.dueling_critic": True, "n_epochs": 3}
    loaded = dagger.parse_args(["--out", "x", "--from", "c.zip", "--dueling-critic", "--observation", "v3"])
    assert dagger.config_overrides(loaded) == {"env_kwargs.observation": "v3"}  # swapped after loading
