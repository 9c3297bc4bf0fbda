"""The centralised critic: its action channel, Q(s, u_-i, .) independence of u_i, the baseline."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch as th
from coma_fakes import make_fake_vec_env, one_torch_thread  # noqa: F401 (autouse fixture)

from sb3_coma.coma import COMA
from sb3_coma.coma.targets import counterfactual_advantage
from sb3_coma.uav.policies import critic_input, other_actions_map
from uav_ipp import layout

SMALL = dict(features_extractor_kwargs=dict(channels=(8, 16, 16), features_dim=32))


def footprints(cells: list[list[tuple[int, int]]]) -> th.Tensor:
    """(B, N, 11, 11) footprint maps with 1.0 at each agent's (row, col) and a 0.5 visit trail."""
    fp = th.zeros(len(cells), len(cells[0]), 11, 11)
    for b, row in enumerate(cells):
        for n, (y, x) in enumerate(row):
            fp[b, n, 0, :] = 0.5
            fp[b, n, y, x] = 1.0
    return fp


def test_other_actions_map_marks_other_agents_only() -> None:
    fp = footprints([[(1, 2), (5, 7), (9, 0)]])
    actions = th.tensor([[0, 3, 5]])
    amap = other_actions_map(fp, actions)
    assert amap.shape == (1, 3, 11, 11)
    # Agent 0 sees agents 1 and 2: (3+1)/6 at (5,7) and (5+1)/6 at (9,0), nothing at its own cell.
    expected0 = th.zeros(11, 11)
    expected0[5, 7], expected0[9, 0] = 4 / 6, 1.0
    assert th.allclose(amap[0, 0], expected0)
    assert amap[0, 1, 1, 2].item() == pytest.approx(1 / 6)  # agent 0's action 0 is not "nothing"
    assert amap[0, 1, 5, 7].item() == 0.0
    assert amap[0, 2].count_nonzero() == 2
    # Visit trails (0.5) are not positions.
    assert amap[0, 0, 0].count_nonzero() == 0


def test_critic_input_stacks_twelve_channels() -> None:
    local, state = th.rand(4, 2, 8, 11, 11), th.rand(4, 2, 3, 11, 11)
    local[:, :, layout.FOOTPRINT] = 0.0
    local[:, 0, layout.FOOTPRINT, 0, 0] = 1.0
    local[:, 1, layout.FOOTPRINT, 3, 3] = 1.0
    x = critic_input(local, state, th.tensor([[1, 2]] * 4))
    assert x.shape == (4, 2, layout.CRITIC_CHANNELS, 11, 11)
    assert th.equal(x[:, :, :8], local) and th.equal(x[:, :, 8:11], state)
    assert x[0, 0, 11, 3, 3].item() == pytest.approx(3 / 6)
    assert x[0, 1, 11, 0, 0].item() == pytest.approx(2 / 6)


def _cbam_model(**policy_kwargs: object) -> COMA:
    """A small CBAM COMA on the fake world: 2 copies, 3 UAVs, one rollout of 4 steps."""
    return COMA(
        "CBAMPolicy",
        make_fake_vec_env(n_envs=2, n_agents=3, seed=0),
        batch_size=8,
        n_steps=4,
        seed=0,
        policy_kwargs={**SMALL, **policy_kwargs},
    )


@pytest.fixture(scope="module")
def model() -> COMA:
    return _cbam_model()


def joint_obs(model: COMA) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    obs = model.env.reset()
    joint = model._grouped(obs)
    return joint["local"].float(), joint["state"].float(), joint["action_mask"].float()


def test_own_action_does_not_change_own_q_row(model: COMA) -> None:
    local, state, _ = joint_obs(model)
    base = th.tensor([[0, 1, 2], [3, 4, 5]])
    with th.no_grad():
        q = model.policy.q_values({"local": local}, state, base)
        for i in range(3):
            for u in range(6):
                changed = base.clone()
                changed[:, i] = u
                q2 = model.policy.q_values({"local": local}, state, changed)
                assert th.equal(q2[:, i], q[:, i]), "agent i's row must ignore u_i"
                if u != base[0, i]:
                    others = [j for j in range(3) if j != i]
                    assert not th.allclose(q2[0, others], q[0, others]), "others' rows see u_i"


def test_baseline_matches_policy_over_valid_actions(model: COMA) -> None:
    local, state, mask = joint_obs(model)
    actions = model.policy.act({"local": local.flatten(0, 1)}, mask.flatten(0, 1)).view(2, 3)
    with th.no_grad():
        q = model.policy.q_values({"local": local}, state, actions)
        probs = model.policy.action_probs({"local": local.flatten(0, 1)}, mask.flatten(0, 1)).view(2, 3, 6)
    adv, base, _q_taken = counterfactual_advantage(q, actions, probs)
    for e in range(2):
        for i in range(3):
            valid = [u for u in range(6) if mask[e, i, u] > 0.5]
            total = sum(probs[e, i, u] for u in valid)
            expected = sum(probs[e, i, u] / total * q[e, i, u] for u in valid)
            assert base[e, i].item() == pytest.approx(expected.item(), abs=1e-5)
            assert adv[e, i].item() == pytest.approx((q[e, i, actions[e, i]] - expected).item(), abs=1e-5)
    assert (probs[mask < 0.5] == 0).all()


def test_target_sync_copies_the_critic(model: COMA) -> None:
    policy = model.policy
    with th.no_grad():
        for p in policy.critic.parameters():
            p.add_(1.0)
    policy.sync_target()
    for t, c in zip(policy.critic_target.parameters(), policy.critic.parameters()):
        assert th.equal(t, c)
    assert not any(p.requires_grad for p in policy.critic_target.parameters())


@pytest.fixture(scope="module")
def dueling_model() -> COMA:
    return _cbam_model(dueling_critic=True)


def test_a_dueling_uav_critic_is_its_value_plus_the_centred_deviations(dueling_model: COMA) -> None:
    """The generic option on the world's spatial critic: one more output, ``Q = W + D - mean_u D``; agent
    ``i``'s row still ignores ``u_i``, and under the uniform policy the baseline is ``W`` itself."""
    critic = dueling_model.policy.critic
    assert critic.head.out_features == 7 and dueling_model.policy.critic_target.dueling
    local, state, _ = joint_obs(dueling_model)
    actions = th.tensor([[0, 1, 2], [3, 4, 5]])
    with th.no_grad():
        q = dueling_model.policy.q_values({"local": local}, state, actions)
        out = critic.head(critic.features_extractor(critic_input(local, state, actions).flatten(0, 1))).view(2, 3, 7)
        changed = actions.clone()
        changed[:, 0] = 5
        assert th.equal(dueling_model.policy.q_values({"local": local}, state, changed)[:, 0], q[:, 0])
    assert th.allclose(q, out[..., :1] + out[..., 1:] - out[..., 1:].mean(dim=-1, keepdim=True), atol=1e-6)
    _adv, baseline, _taken = counterfactual_advantage(q, actions, th.full((2, 3, 6), 1 / 6))
    assert th.allclose(baseline, out[..., 0], atol=1e-5)


def test_a_dueling_uav_critic_is_saved_with_the_model_and_a_plain_one_stays_plain(
    dueling_model: COMA, model: COMA, tmp_path: Path
) -> None:
    for trained, dueling in ((dueling_model, True), (model, False)):
        trained.save(tmp_path / "m.zip")
        loaded = COMA.load(tmp_path / "m.zip", device="cpu")
        assert loaded.policy.dueling_critic is dueling and loaded.policy.critic.head.out_features == 6 + dueling
        for a, b in zip(loaded.policy.critic.parameters(), trained.policy.critic.parameters()):
            assert th.equal(a, b)


def test_a_dueling_critic_that_is_not_a_flag_is_refused_by_name() -> None:
    with pytest.raises(ValueError, match=r"dueling_critic='no': must be true or false"):
        _cbam_model(dueling_critic="no")
