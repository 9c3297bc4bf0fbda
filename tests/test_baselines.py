"""Baseline planners: random, lawnmower (NL) and adaptive gain (AG)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

import uav_ipp
from sb3_coma.baselines import PLANNERS, make_planner, plan_team, planner_class
from sb3_coma.baselines.adaptive_gain import heard_matrix, strip_sums
from sb3_coma.baselines.lawnmower import axis_ranges, best_lanes, union_length
from sb3_coma.baselines.navigation import best_move, distance_field
from sb3_coma.baselines.oracle import OTHER_WEIGHT, clairvoyant_density
from uav_ipp import layout
from uav_ipp.gain import gain_density
from uav_ipp.ipp_env import ACTION_DELTAS


@pytest.fixture(scope="module")
def geometry():
    return uav_ipp.make_env("env1").geometry


@pytest.fixture(scope="module")
def flips(geometry):
    cfg = geometry.config
    return np.array([cfg.flip_probability[a] for a in cfg.altitudes])


def _cell_centres(geometry):
    c = (np.arange(geometry.grid) + 0.5) * geometry.cell
    return np.meshgrid(c, c)  # X, Y in metres, indexed [row=y, col=x]


def _strip_sums(geometry, belief, flips, weighting="class"):
    """(A, S, S) gain of one reading per level summed over every gain strip cell (brute force)."""
    out = np.zeros((len(flips), geometry.n_strips, geometry.n_strips))
    strip = geometry.strip_of_cell
    for level, q in enumerate(flips):
        np.add.at(out[level], (strip[:, None], strip[None, :]), gain_density(belief, q, weighting))
    return out


def _ag(sums, pos, mask, discount=0.5, lookahead=1, geometry=None):
    """Run the AG kernel on one team; return (actions, scores)."""
    n = pos.shape[0]
    actions, scores = np.zeros(n, np.int64), np.zeros((n, 6))
    plan_team(
        np.ascontiguousarray(sums),
        pos,
        mask,
        np.zeros((11, 11), bool),
        ACTION_DELTAS,
        geometry.footprint_strips,
        discount,
        lookahead,
        np.zeros((n, 6)),
        np.ones((n, n), bool),
        scores,
        actions,
    )
    return actions, scores


def _brute_gain(geometry, belief, flips, target, weighting="class"):
    fp = geometry.footprint(*(int(v) for v in target))
    return gain_density(belief[fp.r0 : fp.r1, fp.c0 : fp.c1], flips[target[2]], weighting).sum()


def _fly(method, name="env1", n_envs=1, seed=0, **options):
    """Fly one batch of missions; return the planner, every (mask, action) pair and the last infos."""
    venv = uav_ipp.make_vec_env(name, n_envs=n_envs, fusion="mean", seed=seed, **options)
    planner = make_planner(method, venv, seed=seed)
    obs = venv.reset()
    pairs, infos = [], None
    budget = venv.get_attr("config", indices=[0])[0].budget
    for _ in range(budget):
        actions, state = planner.predict(obs, deterministic=True)
        assert state is None and actions.shape == (venv.num_envs,)
        pairs.append((obs[layout.KEY_MASK].copy(), actions))
        obs, _, _, infos = venv.step(actions)
    venv.close()
    return planner, pairs, infos


def _all_valid(pairs):
    return all(mask[np.arange(len(a)), a].all() for mask, a in pairs)


# ------------------------------------------------------------------ registry
def test_registry_and_errors():
    assert set(PLANNERS) == {"random", "lawnmower", "ag", "oracle"}
    assert planner_class("NL").name == "lawnmower"
    venv = uav_ipp.make_vec_env("env1", n_envs=1, budget=2)
    with pytest.raises(ValueError, match=r"unknown baseline 'greedy'.*ag.*lawnmower.*random"):
        make_planner("greedy", venv)
    with pytest.raises(ValueError, match="altitude"):
        make_planner("lawnmower", venv, altitude=7.0)
    with pytest.raises(ValueError, match="discount"):
        make_planner("ag", venv, discount=2.0)
    with pytest.raises(ValueError, match="unexpected keyword"):
        make_planner("random", venv, speed=3)
    planner = make_planner("ag", venv)
    with pytest.raises(ValueError, match="whole"):
        planner.predict({k: v[:0] for k, v in venv.reset().items()} | {layout.KEY_MASK: np.ones((8, 6), np.int8)})


# ------------------------------------------------------------------ random
def test_random_is_valid_uniform_and_seeded():
    venv = uav_ipp.make_vec_env("env1", n_envs=1, budget=2)
    obs = venv.reset()
    mask = np.tile(np.array([[1, 0, 1, 1, 0, 1]], np.int8), (4, 1))
    obs = dict(obs, action_mask=mask)
    a = make_planner("random", venv, seed=3)
    b = make_planner("random", venv, seed=3)
    draws = np.concatenate([a.predict(obs)[0] for _ in range(500)])
    assert np.array_equal(draws, np.concatenate([b.predict(obs)[0] for _ in range(500)]))
    counts = np.bincount(draws, minlength=6)
    assert counts[[1, 4]].sum() == 0
    assert counts[[0, 2, 3, 5]].min() > 0.2 * len(draws)  # 0.25 each in expectation


# ------------------------------------------------------------------ lawnmower
def test_best_lanes_is_optimal(geometry):
    for level in range(3):
        ranges = axis_ranges(geometry, level)
        for n in (1, 2, 4):
            best = max(union_length(ranges, c) for c in itertools.combinations(range(len(ranges)), n))
            assert union_length(ranges, best_lanes(ranges, n)) == best


def test_lawnmower_covers_field_within_budget(geometry):
    planner, pairs, infos = _fly("lawnmower")
    assert _all_valid(pairs)
    assert planner.altitude == 10.0 and planner.lanes_per_uav == 1  # footprint 11.5 m vs strip 12.5 m
    ranges = planner.ranges
    best_x = union_length(ranges, planner.lanes) / geometry.grid  # best possible with 4 lanes at 10 m
    assert best_x == max(union_length(ranges, c) for c in itertools.combinations(range(11), 4)) / geometry.grid
    # each lane is swept end to end (the sweep covers y fully), so coverage reaches the lanes' best
    assert infos[0]["coverage"] >= best_x - 0.01


def test_lawnmower_reaches_lanes_at_sweep_altitude():
    venv = uav_ipp.make_vec_env("env1", n_envs=1, seed=0)
    planner = make_planner("lawnmower", venv)
    obs = venv.reset()
    for _ in range(6):
        obs, *_ = venv.step(planner.predict(obs)[0])
    pos = venv.env_method("positions_m", indices=[0])[0]
    lanes_m = {x * 5.0 for x in planner.lanes}
    assert set(pos[:, 0]) == lanes_m and np.all(pos[:, 2] == planner.altitude)


def test_navigation_avoids_no_fly_and_masks():
    no_fly = np.zeros((11, 11), dtype=bool)
    no_fly[5, 0:10] = True  # a wall along y = 25 m with a gap at x = 50 m
    field = distance_field(no_fly, 3, (0, 10, 1))
    assert np.isinf(field[:, 5, :10]).all()
    assert field[1, 0, 0] == 10 + 10 + 10  # around the wall through the gap at x index 10
    pos = np.array([0, 0, 1])
    assert best_move(pos, field, np.ones(6, bool)) == 4  # +x towards the gap
    mask = np.ones(6, bool)
    mask[4] = False  # the planned move is masked: take the valid move that gets closest
    assert best_move(pos, field, mask) == 3  # +y: as close to the plan as +x was


def test_lawnmower_respects_masks_and_keeps_moving_on_env3():
    """env3 has no-fly columns: UAVs detour around them and around each other, never deadlock."""
    from sb3_coma.app.evaluation import evaluate

    _, pairs, _ = _fly("lawnmower", "env3", budget=8)
    assert _all_valid(pairs)
    traj = evaluate("lawnmower", env="env3", n_trials=1, seed=0).trajectories[0]
    for u in range(traj.shape[1]):
        columns = {tuple(p) for p in traj[:, u, :2]}
        assert len(columns) >= traj.shape[0] // 2  # mostly new columns: sweeping, not waiting


# ------------------------------------------------------------------ adaptive gain
def test_gain_density_matches_definition():
    p, q = np.array([0.5, 0.7, 0.3]), 0.265

    def h(x):
        return -(x * np.log2(x) + (1 - x) * np.log2(1 - x))

    p1 = p * (1 - q) / (p * (1 - q) + (1 - p) * q)
    p0 = p * q / (p * q + (1 - p) * (1 - q))
    mi = h(p) - ((p * (1 - q) + (1 - p) * q) * h(p1) + (p * q + (1 - p) * (1 - q)) * h(p0))
    assert np.allclose(gain_density(p, q, "plain"), mi)
    assert np.all(gain_density(p, q, "plain") > 0)
    # class weighting: unknown (0.5) is worth half, believed-not-valuable cells can cost
    assert np.isclose(gain_density(0.5, q, "class"), 0.5 - 0.5 * h(1 - q))
    assert gain_density(0.3, 0.01, "class") < 0
    per_alt = [gain_density(0.5, q) for q in (0.01, 0.265, 0.375)]
    assert np.all(np.diff(per_alt) < 0)  # low = more informative
    with pytest.raises(ValueError, match="weighting"):
        gain_density(p, q, "none")


def test_footprint_gains_match_brute_force(geometry, flips):
    rng = np.random.default_rng(0)
    belief = rng.uniform(0.2, 0.8, (geometry.grid, geometry.grid))
    sums = _strip_sums(geometry, belief, flips)
    pos = np.array([[5, 5, 1]])
    _, scores = _ag(sums[None], pos, np.ones((1, 6), bool), geometry=geometry)
    for a in range(6):
        target = pos[0] + ACTION_DELTAS[a]
        assert np.isclose(scores[0, a], _brute_gain(geometry, belief, flips, target), rtol=1e-9)
    # footprints are exact unions of strips: the strip rectangle holds exactly the footprint's cells
    for k, level in itertools.product(range(11), range(3)):
        s0, s1 = geometry.footprint_strips[k, level]
        r0, r1 = geometry.footprint_ranges[k, level]
        assert geometry.strip_cells[s0:s1].sum() == r1 - r0


def test_ag_picks_highest_gain_action(geometry, flips):
    X, Y = _cell_centres(geometry)
    belief = np.full(X.shape, 0.5)
    belief[(np.abs(X - 35) < 5) & (np.abs(Y - 25) < 5)] = 0.7  # a likely-valuable patch east
    belief[X < 20] = 0.3  # believed not valuable west: reading it only costs
    sums = _strip_sums(geometry, belief, flips)[None]
    pos = np.array([[5, 5, 1]])  # (25, 25) at 10 m
    mask = np.ones((1, 6), bool)
    actions, scores = _ag(sums, pos, mask, geometry=geometry)
    gains = [_brute_gain(geometry, belief, flips, pos[0] + d) for d in ACTION_DELTAS]
    assert actions[0] == int(np.argmax(gains)) == 4  # +x, towards the patch
    mask[0, 4] = False
    actions, scores = _ag(sums, pos, mask, geometry=geometry)
    assert actions[0] == int(np.argmax(np.where(mask[0], gains, -np.inf)))
    assert scores[0, 4] == -np.inf


def test_ag_discount_separates_two_uavs(geometry, flips):
    X, Y = _cell_centres(geometry)
    belief = np.full(X.shape, 0.5)
    belief[(np.abs(X - 25) < 4) & (np.abs(Y - 25) < 4)] = 0.7  # one valuable-looking patch between them
    sums = np.stack([_strip_sums(geometry, belief, flips)] * 2)
    pos = np.array([[4, 5, 1], [6, 5, 1]])  # x = 20 m and 30 m at 10 m, both next to the patch
    mask = np.ones((2, 6), bool)

    def overlap(discount):
        actions, _ = _ag(sums, pos, mask, discount=discount, geometry=geometry)
        assert actions[0] == 4  # the first UAV takes the patch (+x)
        assert actions[1] != 1  # ... and its column is never taken again (would hover)
        boxes = []
        for u in range(2):
            fp = geometry.footprint(*(int(v) for v in pos[u] + ACTION_DELTAS[actions[u]]))
            box = np.zeros((geometry.grid, geometry.grid), bool)
            box[fp.r0 : fp.r1, fp.c0 : fp.c1] = True
            boxes.append(box)
        return (boxes[0] & boxes[1]).sum()

    assert overlap(0.0) > 0
    assert overlap(1.0) < 0.5 * overlap(0.0)


def test_lookahead_one_is_ag_and_deeper_search_sees_further(geometry, flips):
    rng = np.random.default_rng(1)
    belief = rng.uniform(0.3, 0.7, (geometry.grid, geometry.grid))
    sums = np.stack([_strip_sums(geometry, belief, flips)] * 3)
    pos = np.array([[2, 2, 2], [8, 2, 1], [5, 8, 0]])
    mask = np.ones((3, 6), bool)
    mask[0, 0] = mask[2, 5] = False  # top / bottom altitude
    greedy, greedy_scores = _ag(sums, pos, mask, geometry=geometry)
    same, same_scores = _ag(sums, pos, mask, lookahead=1, geometry=geometry)
    np.testing.assert_array_equal(greedy, same)
    np.testing.assert_array_equal(greedy_scores, same_scores)
    _, deep = _ag(sums, pos, mask, lookahead=2, geometry=geometry)
    allowed = np.isfinite(greedy_scores)
    assert np.all(deep[allowed] > greedy_scores[allowed])  # a second footprint adds gain
    # a two-step value is at most twice the best single footprint reachable
    assert deep[0].max() <= 2 * greedy_scores.max() + 1e-9


def test_lookahead_planner_flies_valid_and_reports_bad_options():
    planner, _pairs, _infos = _fly("ag", n_envs=1, budget=3)
    assert planner.lookahead == 1
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=0, budget=3)
    deep = make_planner("ag", venv, seed=0, lookahead=2, weighting="plain")
    obs = venv.reset()
    for _ in range(3):
        actions, _ = deep.predict(obs)
        assert obs[layout.KEY_MASK][np.arange(len(actions)), actions].all()
        obs, *_ = venv.step(actions)
    for bad in ({"lookahead": 0}, {"lookahead": 9}, {"lookahead": 1.5}, {"weighting": "none"}, {"discount": 2}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            make_planner("ag", venv, **bad)


def test_ag_end_to_end_valid_and_seeded():
    _, pairs_a, infos_a = _fly("ag", n_envs=2, budget=5)
    _, pairs_b, infos_b = _fly("ag", n_envs=2, budget=5)
    assert _all_valid(pairs_a)
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(pairs_a, pairs_b))
    assert infos_a[0]["f1"] == infos_b[0]["f1"]


# ---------------------------------------------------------------------------------------------
# what AG knows of its teammates, and the clairvoyant oracle (upper references)
# ---------------------------------------------------------------------------------------------
def _fly_final(planner_name, seed=3, **kwargs):
    """Final (f1, entropy, team_entropy, actions) of one env1 mission with a planner."""
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=seed, split="test", start="random")
    planner = make_planner(planner_name, venv, seed=seed, **kwargs)
    obs, actions = venv.reset(), []
    for _ in range(15):
        act, _ = planner.predict(obs)
        actions.append(act.copy())
        obs, _, _dones, infos = venv.step(act)
    venv.close()
    return infos[0]["f1"], infos[0]["entropy"], np.stack(actions)


def test_strip_sums_match_the_brute_force_sum():
    env = uav_ipp.make_env("env1")
    rng = np.random.default_rng(0)
    density = rng.random((env.config.grid, env.config.grid))
    fast = strip_sums(density, env.geometry)
    slow = np.zeros_like(fast)
    strip = env.geometry.strip_of_cell
    np.add.at(slow, (strip[:, None], strip[None, :]), density)
    np.testing.assert_allclose(fast, slow, rtol=1e-10)


def test_heard_matrix_follows_the_range():
    pos = np.array([[0.0, 0.0, 10.0], [20.0, 0.0, 10.0], [50.0, 0.0, 10.0]])
    heard = heard_matrix(pos, 25.0)
    assert heard.tolist() == [[True, True, False], [True, True, False], [False, False, True]]


def test_comm_only_ag_equals_shared_ag_with_unlimited_range_and_differs_when_out_of_range():
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=3, split="test", start="random", comm_range=1e9)
    a = make_planner("ag", venv, seed=3, knowledge="comm")
    b = make_planner("ag", venv, seed=3, knowledge="shared")
    obs = venv.reset()
    for _ in range(5):
        act_a, _ = a.predict(obs)
        act_b, _ = b.predict(obs)
        np.testing.assert_array_equal(act_a, act_b)
        obs, *_ = venv.step(act_a)
    venv.close()
    # with no range at all no UAV hears another: claims are ignored, so the plans differ somewhere
    venv = uav_ipp.make_vec_env("env1", n_envs=1, fusion="mean", seed=3, split="test", start="random", comm_range=0.0)
    deaf, full = make_planner("ag", venv, seed=3, knowledge="comm"), make_planner("ag", venv, seed=3)
    obs = venv.reset()
    differs = False
    for _ in range(15):
        act_d, _ = deaf.predict(obs)
        act_f, _ = full.predict(obs)
        differs |= bool((act_d != act_f).any())
        obs, *_ = venv.step(act_f)
    venv.close()
    assert differs


def test_oracle_density_prefers_truly_valuable_cells():
    belief = np.full((2, 2), 0.5)
    truth = np.array([[True, False], [False, False]])
    d = clairvoyant_density(belief, truth, 0.1)
    assert d[0, 0] > 0 and np.isclose(d[0, 1], OTHER_WEIGHT * d[0, 0])
    # a noiseless reading of a cell at p = 0.5 removes its whole bit
    assert np.isclose(clairvoyant_density(belief, truth, 0.0)[0, 0], 1.0)


@pytest.mark.parametrize("planner, kwargs", [("oracle", {}), ("ag", {"knowledge": "central"})])
def test_central_scores_by_table_lookup_equal_the_per_cell_formula(planner, kwargs):
    """The oracle and central AG look each cell's score up by its stored log-odds: the strip sums
    they plan with equal those of the formula applied to ``global_belief`` cell by cell."""
    venv = uav_ipp.make_vec_env("env1", n_envs=2, seed=3)
    p = make_planner(planner, venv, seed=0, **kwargs)
    obs = venv.reset()
    p.reset()
    for _ in range(3):
        actions, _ = p.predict(obs, deterministic=True)
        obs, *_ = venv.step(actions)
    sums = p._team_sums(2)
    for c in range(2):
        belief = venv.env_method("global_belief", indices=[c * p.n_agents])[0]
        truth = venv.get_attr("ground_truth", indices=[c * p.n_agents])[0].valuable
        for level, q in enumerate(p._levels_flip()):
            if planner == "oracle":
                density = clairvoyant_density(belief, np.asarray(truth, dtype=bool), q)
            else:
                density = gain_density(belief, q, p.weighting)
            np.testing.assert_array_equal(sums[c][0, level], strip_sums(density, p.geometry))
            np.testing.assert_array_equal(sums[c][-1, level], sums[c][0, level])
    venv.close()


def test_oracle_and_central_ag_are_references_that_beat_ag_on_average():
    f1 = {name: [] for name in ("ag", "central", "oracle")}
    ent = {name: [] for name in f1}
    for seed in range(4):
        for name, planner, kwargs in (
            ("ag", "ag", {}),
            ("central", "ag", {"knowledge": "central"}),
            ("oracle", "oracle", {}),
        ):
            f, e, _ = _fly_final(planner, seed=seed, **kwargs)
            f1[name].append(f)
            ent[name].append(e)
    assert np.mean(ent["oracle"]) < np.mean(ent["ag"])
    assert np.mean(f1["oracle"]) > np.mean(f1["ag"])
