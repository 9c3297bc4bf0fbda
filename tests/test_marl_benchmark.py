"""The learner benchmark (sb3_coma.experiments.marl_benchmark) and the COMA study: configs, verdicts,
a quick end-to-end run that resumes, and small records."""

from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

import pytest

from sb3_coma.experiments import coma_study, marl_benchmark
from sb3_coma.experiments.marl_benchmark import TASKS, TRAINED, learner_settings, seed_paired_verdict


def _records(values: dict[int, float], learner: str) -> list[dict[str, Any]]:
    return [{"seed": seed, "final_return": value, "learner": learner} for seed, value in values.items()]


def test_every_learner_has_settings_for_every_task() -> None:
    for learner in TRAINED:
        for task in TASKS.values():
            settings = learner_settings(learner, task)
            assert "policy" in settings, (learner, task.name)
    assert learner_settings("mappo", TASKS["lbf"])["policy"] == "CentralValuePolicy"


def test_a_task_without_settings_is_named(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    (tmp_path / "coma.yml").write_text("simple_spread: {policy: MlpPolicy}\n")
    import sb3_coma.app.config

    monkeypatch.setattr(sb3_coma.app.config, "default_config_path", lambda name: tmp_path / Path(name).name)
    with pytest.raises(ValueError, match=r"has no entry 'rware-tiny-2ag-v2'; it has \['simple_spread'\]"):
        learner_settings("coma", TASKS["rware_tiny"])


def test_the_verdict_is_paired_by_seed_and_a_tie_is_a_tie() -> None:
    mappo = _records({0: -45.0, 1: -47.0, 2: -43.0}, "mappo")
    # one seed better, one worse: the interval holds 0
    assert seed_paired_verdict(_records({0: -44.0, 1: -48.0, 2: -43.0}, "coma"), mappo).endswith("tie")
    # better on every seed by about 5, whatever the seeds' own spread: paired, so COMA better
    assert seed_paired_verdict(_records({0: -40.0, 1: -42.2, 2: -37.9}, "coma"), mappo).endswith("COMA better")
    assert seed_paired_verdict(_records({0: -50.0, 1: -52.1, 2: -48.2}, "coma"), mappo).endswith("MAPPO better")
    assert "fewer than 2" in seed_paired_verdict(_records({0: -40.0}, "coma"), mappo)


@pytest.mark.slow
def test_a_quick_run_writes_the_table_and_resumes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--quick", "--tasks", "simple_spread,lbf", "--out", str(tmp_path), "--phases", "train,report"]
    assert marl_benchmark.main([*argv, "--workers", "1"]) == 0
    runs = sorted((tmp_path / "runs").glob("*.json"))
    assert [p.name for p in runs] == [
        f"{task}-{learner}-0.json" for task in ("lbf", "simple_spread") for learner in sorted(marl_benchmark.LEARNERS)
    ]
    assert max(p.stat().st_size for p in runs) < 20_000  # small enough to keep in git
    record = json.loads((tmp_path / "runs" / "simple_spread-coma-0.json").read_text())
    assert record["joint_steps"] == marl_benchmark.QUICK_STEPS and len(record["episode_returns"]) == 4
    assert len(record["curve"]) == marl_benchmark.CURVE_POINTS
    table = (tmp_path / "results.md").read_text()
    for learner in ("COMA", "MAPPO", "IPPO", "RANDOM"):
        assert f"| simple_spread | {learner} | 1 | " in table
    assert "## COMA against MAPPO" in table and (tmp_path / "curves.png").exists()
    capsys.readouterr()
    assert marl_benchmark.main([*argv, "--workers", "1"]) == 0  # nothing left to train
    assert "train: 0 runs to do" in capsys.readouterr().out
    # a real run into the quick run's folder: refused before any training, nothing overwritten
    before = {p.name: p.read_bytes() for p in runs}
    real = ["--tasks", "simple_spread", "--learners", "random", "--seeds", "1", "--phases", "train"]
    assert marl_benchmark.main([*real, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "simple_spread-" in err[0] and "this run asks" in err[0] and "another --out" in err[0]
    assert {p.name: p.read_bytes() for p in sorted((tmp_path / "runs").glob("*.json"))} == before


def test_an_unknown_task_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert marl_benchmark.main(["--tasks", "pong"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"error: unknown task 'pong'; choose from {', '.join(TASKS)}"
    ]


def test_the_study_never_uses_the_reported_seeds() -> None:
    """Variants are chosen on validation seeds and episodes; the benchmark reports seeds 0.. and
    episodes from its own evaluation seed."""
    assert coma_study.VALIDATION_TRAIN_SEED >= 100 and coma_study.VALIDATION_EVAL_SEED != marl_benchmark.EVAL_SEED
    assert coma_study.VARIANTS["library"] == {} and "paper" in coma_study.VARIANTS
    for key in coma_study.STUDY_STEPS:  # each study task is a benchmark task, for part or all of its budget
        task = coma_study.study_task(key)
        base = TASKS[key.removesuffix(coma_study.WHOLE_BUDGET_SUFFIX)]
        assert task.maker is base.maker and task.joint_steps <= base.joint_steps


def test_a_whole_budget_task_is_its_benchmark_task_named_apart_and_counted_as_it(tmp_path: Path) -> None:
    whole = coma_study.study_task("simple_spread_full")
    half = coma_study.study_task("simple_spread")
    assert whole.joint_steps == TASKS["simple_spread"].joint_steps == 2 * half.joint_steps
    assert whole.name == "simple_spread (whole budget)" and whole.key == "simple_spread_full"
    (tmp_path / "runs").mkdir()
    for task, steps in (("simple_spread", half), ("simple_spread_full", whole)):
        name = f"{task}-before_lambda_95_q_norm-{coma_study.VALIDATION_TRAIN_SEED}"
        record = {"task": steps.name, "variant": "before_lambda_95_q_norm", "seed": coma_study.VALIDATION_TRAIN_SEED}
        record |= {"validation_return": -50.0, "seconds": 60.0, "curve": [[0, -60.0], [1000, -50.0]]}
        (tmp_path / "runs" / f"{name}.json").write_text(json.dumps(record))
        (tmp_path / "runs" / f"{name}.csv").write_text("time/total_timesteps,rollout/ep_rew_mean\n1,-20\n")
    text = coma_study.report_phase(tmp_path, 1, "whole_budget_round")
    assert "| simple_spread | before_lambda_95_q_norm |" in text
    assert "| simple_spread (whole budget) | before_lambda_95_q_norm |" in text
    # the budget counts runs per task: the whole-budget run is one more on simple_spread
    assert coma_study.tuning_runs(tmp_path) == {("coma", "simple_spread"): 2}


def test_a_record_of_other_settings_is_refused_before_training(tmp_path: Path) -> None:
    """Resuming reuses a kept record only while its learner's config entry is unchanged."""
    task = TASKS["simple_spread"]
    runs = tmp_path / "runs"
    runs.mkdir()
    record = {
        "learner": "coma",
        "joint_steps": task.joint_steps,
        "episode_returns": [0.0] * marl_benchmark.EVAL_EPISODES,
    }
    (runs / "simple_spread-coma-0.json").write_text(json.dumps(record | {"settings": learner_settings("coma", task)}))
    marl_benchmark.check_kept_records(runs, [task], marl_benchmark.EVAL_EPISODES)  # the same settings: kept
    stale = learner_settings("coma", task) | {"batch_size": 7}
    (runs / "simple_spread-coma-0.json").write_text(json.dumps(record | {"settings": stale}))
    with pytest.raises(marl_benchmark.RecordMismatch, match=r"'batch_size': 7.*the config now gives"):
        marl_benchmark.check_kept_records(runs, [task], marl_benchmark.EVAL_EPISODES)


def test_each_study_round_reports_only_its_own_arms(tmp_path: Path) -> None:
    """Round 2 (critic_round) is its own table: round 1's variants stay out of it, and a variant
    both rounds fly (the round's baseline) is read from the same records."""
    (tmp_path / "runs").mkdir()
    curve = [[0, -60.0], [1000, -50.0]]
    for variant in ("paper", "rollout_1024_epochs_10", "minibatch_86"):
        record = {
            "task": "simple_spread",
            "variant": variant,
            "seed": coma_study.VALIDATION_TRAIN_SEED,
            "settings": coma_study.VARIANTS[variant],
            "validation_return": -50.0,
            "seconds": 60.0,
            "curve": curve,
        }
        name = f"simple_spread-{variant}-{coma_study.VALIDATION_TRAIN_SEED}"
        (tmp_path / "runs" / f"{name}.json").write_text(json.dumps(record))
        columns = ("time/total_timesteps", *coma_study.DIAGNOSTICS)
        (tmp_path / "runs" / f"{name}.csv").write_text(",".join(columns) + "\n" + ",".join(["1"] * len(columns)) + "\n")
    assert set(coma_study.ROUNDS["critic_round"]) >= {"rollout_1024_epochs_10", "minibatch_86"}
    text = coma_study.report_phase(tmp_path, 1, "critic_round")
    assert "| simple_spread | minibatch_86 |" in text and "| simple_spread | rollout_1024_epochs_10 |" in text
    assert "| simple_spread | paper |" not in text and (tmp_path / "critic_round.md").read_text() == text
    assert "| simple_spread | paper |" in coma_study.report_phase(tmp_path, 1, "study")


def test_the_summary_says_each_verdict_and_the_bar(tmp_path: Path) -> None:
    records = [
        *({"task": "t", **r} for r in _records({0: -44.0, 1: -48.0, 2: -43.0}, "coma")),
        *({"task": "t", **r} for r in _records({0: -45.0, 1: -47.0, 2: -43.0}, "mappo")),
        {"task": "t", "seed": 0, "final_return": -80.0, "learner": "random"},
    ]
    speed = {"tasks": {"t": {"ratio": 1.25}, "u": {"ratio": 0.9}}}
    text = marl_benchmark.summary_paragraph(records, speed)
    assert "t (3 seeds): COMA -45.00, MAPPO -45.00, COMA minus MAPPO +0.00" in text and ": tie" in text
    assert "within MAPPO's seed spread (or above) on 1 of 1 tasks (t)" in text and "t +35.00" in text
    assert "Both (within the spread and above random) on 1 of 1 (t)." in text
    below_random = [r | {"final_return": -40.0} if r["learner"] == "random" else r for r in records]
    assert "Both (within the spread and above random) on 0 of 1." in marl_benchmark.summary_paragraph(
        below_random, speed
    )
    assert "0.90 to 1.25 on 2 tasks" in text
    readme = tmp_path / "README.md"
    start, end = marl_benchmark.README_MARKERS
    readme.write_text(f"# head\n{start}\nold text\n{end}\ntail\n")
    marl_benchmark.write_readme_block(readme, text)
    assert readme.read_text() == f"# head\n{start}\n{text}\n{end}\ntail\n"
    readme.write_text("no markers\n")
    with pytest.raises(ValueError, match="no <!-- marl-benchmark:start"):
        marl_benchmark.write_readme_block(readme, text)


def test_the_readme_quotes_the_benchmark_as_its_records_give_it() -> None:
    """README's paragraph is the one the report writes from the records in git: never typed."""
    root = Path(__file__).resolve().parents[1]
    out = root / "docs" / "marl_benchmark"
    readme = (root / "README.md").read_text(encoding="utf-8")
    start, end = marl_benchmark.README_MARKERS
    quoted = readme.split(start, 1)[1].split(end, 1)[0].strip()
    assert quoted == marl_benchmark.summary_paragraph(marl_benchmark._records(out), marl_benchmark._speed(out))
    assert quoted in (out / "results.md").read_text(encoding="utf-8")


def test_a_report_never_shrinks_a_table_made_from_records_this_folder_lacks(tmp_path: Path) -> None:
    """Run records stay out of git: on a fresh machine a report of one task must not overwrite the
    round's table of two tasks made elsewhere."""
    (tmp_path / "runs").mkdir()
    table = tmp_path / "critic_round.md"
    table.write_text("| task | variant |\n| --- | --- |\n| Foraging-5x5-2p-1f-coop-v3 | minibatch_86 |\n")
    with pytest.raises(coma_study.TableWouldShrink, match="first: Foraging-5x5-2p-1f-coop-v3 / minibatch_86"):
        coma_study.report_phase(tmp_path, 1, "critic_round")
    assert "minibatch_86" in table.read_text()  # untouched
    assert coma_study.main(["--out", str(tmp_path), "--phases", "report", "--round", "critic_round"]) == 2


def test_round_17_changes_one_setting_of_the_entry_per_variant() -> None:
    """PopArt and the entry without the time-limit bootstrap, each beside the entry it changes."""
    entry = coma_study.VARIANTS["before_lambda_95_q_norm"]
    changed = {
        name: {key for key in {*settings, *entry} if settings.get(key) != entry.get(key)}
        for name, settings in coma_study.SCALE_ROUND.items()
    }
    assert changed == {
        "before_lambda_95_q_norm_popart": {"normalize_q"},
        "before_lambda_95_q_norm_no_time_limit_bootstrap": {"bootstrap_time_limits"},
    }
    assert coma_study.SCALE_ROUND["before_lambda_95_q_norm_popart"]["normalize_q"] == "popart"
    assert {"before_lambda_95_q_norm", coma_study.REFERENCE} <= set(coma_study.ROUNDS["scale_round"])
    assert not set(coma_study.SCALE_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_20_gives_the_entrys_critic_the_clock_with_and_without_the_bootstrap() -> None:
    """The clock of MPE's 25-step episodes on simple_spread's entry (the time-aware arm drops the
    time-limit bootstrap) and on simple_reference's; each beside the entry it changes and MAPPO."""
    entry = coma_study.VARIANTS["before_lambda_95_q_norm"]
    clock = {"critic_time_feature": 25}
    expected = {
        "before_lambda_95_q_norm_clock_25": entry | clock | {"bootstrap_time_limits": False},
        "before_lambda_95_q_norm_clock_25_bootstrap": entry | clock,
        "minibatch_86_before_lambda_95_q_norm_clock_25": coma_study.VARIANTS["minibatch_86_before_lambda_95_q_norm"]
        | clock
        | {"bootstrap_time_limits": False},
    }
    assert expected == coma_study.CLOCK_ROUND
    reference = coma_study.VARIANTS["before_lambda_95_q_norm_lr_1e-4"]
    expected_reference = {
        "before_lambda_95_q_norm_lr_1e-4_clock_25": reference | clock | {"bootstrap_time_limits": False}
    }
    assert expected_reference == coma_study.REFERENCE_CLOCK_ROUND
    assert {"before_lambda_95_q_norm", "before_lambda_95_q_norm_no_time_limit_bootstrap", coma_study.REFERENCE} <= set(
        coma_study.ROUNDS["clock_round"]
    )
    assert {"before_lambda_95_q_norm_lr_1e-4", "mappo_lr_1e-4"} <= set(coma_study.ROUNDS["reference_clock_round"])
    assert "mappo_pi_64x2" in coma_study.ROUNDS["clock_whole_budget_round"]
    assert not {*coma_study.CLOCK_ROUND, *coma_study.REFERENCE_CLOCK_ROUND} & set(coma_study.ROUNDS["study"])


def test_round_21_gives_the_clocked_entry_mappos_actor_depth_and_nothing_else() -> None:
    entry = coma_study.VARIANTS["minibatch_86_before_lambda_95_q_norm_clock_25"]
    deeper = coma_study.CLOCK_DEPTH_ROUND["minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3"]
    assert deeper == entry | {"policy_kwargs": {"net_arch": {"pi": [64, 64, 64], "qf": [128, 128]}}}
    assert {"minibatch_86_before_lambda_95_q_norm_clock_25", "mappo_pi_64x2"} <= set(
        coma_study.ROUNDS["clock_depth_round"]
    )
    assert not set(coma_study.CLOCK_DEPTH_ROUND) & set(coma_study.ROUNDS["study"])
    foraging = coma_study.VARIANTS["minibatch_86_before_lambda_95_q_norm"]
    expected = {"minibatch_86_before_lambda_95_q_norm_pi_64x3": foraging | {"policy_kwargs": deeper["policy_kwargs"]}}
    assert expected == coma_study.FORAGING_DEPTH_ROUND
    assert not set(coma_study.FORAGING_DEPTH_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_22_gives_the_other_tasks_entries_the_third_layer_and_nothing_else() -> None:
    """simple_reference's and Foraging-8x8's entries with round 21's third actor layer, each beside its
    entry and MAPPO's entry on that task."""
    deeper = {"policy_kwargs": {"net_arch": {"pi": [64, 64, 64], "qf": [128, 128]}}}
    entries = ("before_lambda_95_q_norm_lr_1e-4_clock_25", "minibatch_86_before")
    assert {f"{e}_pi_64x3": coma_study.VARIANTS[e] | deeper for e in entries} == coma_study.LATE_DEPTH_ROUND
    assert {entries[0], "mappo_lr_1e-4"} <= set(coma_study.ROUNDS["reference_depth_round"])
    assert {entries[1], "mappo_lr_7e-4"} <= set(coma_study.ROUNDS["foraging_8x8_depth_round"])
    assert not set(coma_study.LATE_DEPTH_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_23_gives_the_entry_mappos_clip_beside_mappos_own_entry() -> None:
    entry = "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3"
    assert {f"{entry}_clip_0.1": coma_study.VARIANTS[entry] | {"clip_range": 0.1}} == coma_study.CLOCK_STEP_ROUND
    arms = coma_study.ROUNDS["clock_step_round"]
    assert entry in arms and "mappo_clip_0.1" in arms
    # MAPPO's simple_spread entry of that round (round 26 has since moved it to clip 0.05)
    assert coma_study.ppo_settings("mappo_clip_0.1") == coma_study.ppo_settings("mappo") | {"clip_range": 0.1}
    assert not set(coma_study.CLOCK_STEP_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_24_gives_each_other_tasks_entry_the_clip_beside_its_entry_and_mappos() -> None:
    rounds = {
        "reference_clip_round": ("before_lambda_95_q_norm_lr_1e-4_clock_25", "mappo_lr_1e-4"),
        "foraging_clip_round": ("minibatch_86_before_lambda_95_q_norm_pi_64x3", "mappo_epochs_15"),
        "foraging_8x8_clip_round": ("minibatch_86_before", "mappo_lr_7e-4"),
    }
    for name, (entry, mappo) in rounds.items():
        assert coma_study.ROUNDS[name] == (entry, f"{entry}_clip_0.1", mappo)
        assert coma_study.LATE_STEP_CLIP_ROUND[f"{entry}_clip_0.1"] == coma_study.VARIANTS[entry] | {"clip_range": 0.1}
    assert len(coma_study.LATE_STEP_CLIP_ROUND) == len(rounds)
    assert not set(coma_study.LATE_STEP_CLIP_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_25_offers_mappos_entry_more_actor_steps_as_round_20_gave_coma() -> None:
    entry = coma_study.ppo_settings("mappo_clip_0.1")
    assert coma_study.ppo_settings("mappo_clip_0.1_batch_96") == entry | {"batch_size": 96}
    rollout_rows = entry["n_steps"] * marl_benchmark.N_ENVS * 3  # the copies of simple_spread's 3 agents
    assert rollout_rows % 96 == 0 and rollout_rows // 96 > rollout_rows // entry["batch_size"] == 12
    assert coma_study.ppo_settings("mappo_clip_0.1_epochs_15") == entry | {"n_epochs": 15}
    arms = coma_study.ROUNDS["mappo_whole_budget_round"]
    assert {"mappo_clip_0.1", *coma_study.MAPPO_WHOLE_BUDGET_ROUND} <= set(arms)
    assert [coma_study.learner_of(a) for a in arms] == ["mappo", "mappo", "mappo", "coma"]


def test_round_26_moves_mappos_actor_step_one_way_each() -> None:
    paper = coma_study.ppo_settings("mappo")
    assert coma_study.ppo_settings("mappo_clip_0.05") == paper | {"clip_range": 0.05}
    assert coma_study.ppo_settings("mappo_clip_0.1_lr_7e-4") == paper | {"clip_range": 0.1, "learning_rate": 7e-4}
    assert {"mappo_clip_0.1", *coma_study.MAPPO_STEP_ROUND} <= set(coma_study.ROUNDS["mappo_step_round"])


def test_round_27_offers_coma_the_clip_round_26_offered_mappo() -> None:
    entry = coma_study.VARIANTS["minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.1"]
    assert {
        "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.05": entry | {"clip_range": 0.05}
    } == coma_study.SMALL_CLIP_ROUND
    assert {"mappo_clip_0.05", "mappo_clip_0.1"} <= set(coma_study.ROUNDS["small_clip_round"])
    assert not set(coma_study.SMALL_CLIP_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_28_screens_one_change_neighbours_of_each_ppo_entry() -> None:
    for task, screens in coma_study.BUDGET_SCREENS.items():
        arms = coma_study.budget_arms(task)
        assert len(arms) == len(set(arms)) == sum(1 + count for _, count in screens)
        for entry, count in screens:
            learner, change = coma_study.PPO_VARIANTS[entry]
            neighbours = coma_study.entry_neighbours(entry, count)
            assert len(neighbours) == count and {entry, *neighbours} <= set(arms)
            for owner, settings in neighbours.values():
                added = {key: value for key, value in settings.items() if key not in change}
                assert owner == learner and len(added) == 1 and settings | change == settings
                assert added in coma_study.BUDGET_OFFERS.values()


def test_a_neighbour_flown_under_another_name_keeps_that_name() -> None:
    """Foraging-8x8's MAPPO entry (lr 7e-4) with clip 0.1 is round 26's simple_spread arm: one setting, one name."""
    neighbours = coma_study.entry_neighbours("mappo_lr_7e-4", 2)
    assert list(neighbours) == ["mappo_lr_7e-4_clip_0.05", "mappo_clip_0.1_lr_7e-4"]
    assert neighbours["mappo_clip_0.1_lr_7e-4"] == coma_study.PPO_VARIANTS["mappo_clip_0.1_lr_7e-4"]
    assert "mappo_lr_1e-4_lr_7e-4" not in coma_study.entry_neighbours("mappo_lr_1e-4", 10)  # its own axis is skipped


def test_round_29_flies_each_entrys_first_neighbour_beside_it() -> None:
    for task, screens in coma_study.BUDGET_SCREENS.items():
        arms = coma_study.confirm_arms(task)
        assert arms[::2] == tuple(entry for entry, _ in screens)
        for (entry, count), best in zip(screens, arms[1::2]):
            assert best in coma_study.entry_neighbours(entry, count)


def test_round_29s_neighbours_are_those_round_28s_tables_rank_first() -> None:
    """The confirmations are read off the screen's tables in git by one rule, not typed by hand."""
    study = Path(__file__).resolve().parents[1] / "docs" / "coma_study"
    for task, table in (("simple_reference", "reference_budget_round"), ("lbf_8x8", "foraging_8x8_budget_round")):
        text = (study / f"{table}.md").read_text()
        for (entry, count), best in zip(coma_study.BUDGET_SCREENS[task], coma_study.BUDGET_CONFIRMS[task], strict=True):
            assert (
                coma_study.screen_first(text, TASKS[task].name, tuple(coma_study.entry_neighbours(entry, count)))
                == best
            )


def test_round_32_confirms_what_round_31s_table_ranks_first_beside_each_entry() -> None:
    text = (Path(__file__).resolve().parents[1] / "docs" / "coma_study" / "warehouse_screen_round.md").read_text()
    for entry, best in zip(coma_study.WAREHOUSE_ENTRIES, coma_study.WAREHOUSE_CONFIRMS, strict=True):
        assert coma_study.screen_first(text, TASKS["rware_tiny"].name, coma_study.warehouse_neighbours(entry)) == best
    arms = coma_study.ROUNDS["warehouse_confirm_round"]
    assert arms[::2] == coma_study.WAREHOUSE_ENTRIES and arms[1::2] == coma_study.WAREHOUSE_CONFIRMS


def test_round_33_offers_every_rware_entry_a_longer_trace_alone_and_with_standardised_targets() -> None:
    arms = coma_study.ROUNDS["warehouse_trace_round"]
    assert arms[::3] == coma_study.WAREHOUSE_TRACE_ENTRIES == ("minibatch_86", "mappo_clip_0.05", "ippo_lr_7e-4")
    coma = coma_study.VARIANTS["minibatch_86"]
    assert [coma_study.VARIANTS[name] for name in arms[1:3]] == [
        coma | {"td_lambda": 0.95},
        coma | {"td_lambda": 0.95, "normalize_q": True},
    ]
    for k, entry in enumerate(arms[3::3], start=1):
        base = coma_study.ppo_settings(entry)
        longer, scaled = (coma_study.ppo_settings(name) for name in arms[3 * k + 1 : 3 * k + 3])
        assert longer == base | {"gae_lambda": 0.99}
        assert scaled == longer | {"normalize": {"norm_obs": False, "norm_reward": True}}
    assert not set(coma_study.WAREHOUSE_TRACE_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_34_rings_are_the_next_offers_in_round_31s_order_and_comas_foraging_settings() -> None:
    """The PPO learners' two-change arms are read off round 31's table by one rule (the next four offers
    after the confirmed one, skipping the confirmed setting); COMA's are its tuned Foraging-5x5 entry, that
    entry with clip 0.05, that with MAPPO's return, and round 11's probe on it (the baseline alone differs);
    every learner gets four new arms beside its entry."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "coma_study" / "warehouse_screen_round.md").read_text()
    for entry, offers in coma_study.WAREHOUSE_RING_OFFERS.items():
        learner = coma_study.learner_of(entry)
        ranked = coma_study.screen_order(text, TASKS["rware_tiny"].name, coma_study.warehouse_neighbours(learner))
        offer_of = {name: name.removeprefix(f"{learner}_") for name in ranked}
        assert entry == ranked[0]  # round 32 confirmed the screen's first
        changed = set(coma_study.WAREHOUSE_OFFERS[offer_of[entry]])
        following = [
            offer_of[name] for name in ranked[1:] if not set(coma_study.WAREHOUSE_OFFERS[offer_of[name]]) & changed
        ]
        assert offers == tuple(following[:4])
        ring = coma_study.warehouse_neighbours(entry, {offer: coma_study.WAREHOUSE_OFFERS[offer] for offer in offers})
        for name, offer in zip(ring, offers, strict=True):
            assert coma_study.ppo_settings(name) == coma_study.ppo_settings(entry) | coma_study.WAREHOUSE_OFFERS[offer]
    arms = coma_study.ROUNDS["warehouse_ring_round"]
    assert arms[::5] == coma_study.WAREHOUSE_TRACE_ENTRIES
    assert len(arms) == len(set(arms)) == 15
    assert [coma_study.learner_of(name) for name in arms] == ["coma"] * 5 + ["mappo"] * 5 + ["ippo"] * 5
    foraging = coma_study.VARIANTS[arms[1]]
    assert foraging == coma_study.VARIANTS[CHOSEN["lbf"][0]]
    assert coma_study.VARIANTS[arms[2]] == foraging | {"clip_range": 0.05}
    assert (
        coma_study.VARIANTS[arms[3]]
        == coma_study.VARIANTS[arms[4]]
        == foraging | {"clip_range": 0.05, "advantage": "v_return"}
    )
    assert [name in coma_study.PROBES for name in arms[:5]] == [False] * 4 + [True]
    assert not set(coma_study.WAREHOUSE_RING_ROUND) & set(coma_study.ROUNDS["study"])


def test_round_35_screens_every_offer_off_each_ppo_foraging_entrys_axis() -> None:
    """Foraging-5x5's budget: each PPO learner's entry (the benchmark's) with all eight one-change offers
    that do not touch the setting it already changes, and confirmations that fill its runs up to COMA's."""
    arms = coma_study.ROUNDS["foraging_budget_round"]
    entries = tuple(entry for entry, _ in coma_study.FORAGING_SCREENS)
    # the benchmark's entries before round 38 (MAPPO's stays; IPPO's took a neighbour: CHOSEN)
    assert entries == ("mappo_epochs_15", "ippo_lr_7e-4") == tuple(coma_study.FORAGING_CONFIRM_COUNTS)
    assert CHOSEN["lbf"][1] == entries[0] and CHOSEN["lbf"][2] in coma_study.FORAGING_CONFIRMS[entries[1]]
    assert arms[::9] == entries and len(arms) == len(set(arms)) == 18
    for k, (entry, count) in enumerate(coma_study.FORAGING_SCREENS):
        base = coma_study.ppo_settings(entry)
        axis = set(coma_study.PPO_VARIANTS[entry][1])
        off_axis = [offer for offer in coma_study.BUDGET_OFFERS.values() if not set(offer) & axis]
        assert count == len(off_axis) == 8
        assert [coma_study.ppo_settings(name) for name in arms[9 * k + 1 : 9 * (k + 1)]] == [base | o for o in off_axis]
        assert {coma_study.learner_of(name) for name in arms[9 * k : 9 * (k + 1)]} == {coma_study.learner_of(entry)}
    # the runs before round 35 (MAPPO 16, IPPO 14), its screen and two more seeds for each confirmed arm: COMA's 36
    assert 16 + 8 + 2 * coma_study.FORAGING_CONFIRM_COUNTS["mappo_epochs_15"] == 36
    assert 14 + 8 + 2 * coma_study.FORAGING_CONFIRM_COUNTS["ippo_lr_7e-4"] == 36


def test_round_36_gives_comas_probe_twin_a_dueling_critic_and_every_ppo_entry_its_next_ring_offer() -> None:
    arms = coma_study.ROUNDS["warehouse_dueling_round"]
    twin, probe, dueling = arms[1:4]
    assert arms[0] == coma_study.WAREHOUSE_TRACE_ENTRIES[0] and dueling == coma_study.WAREHOUSE_DUELING
    assert probe in coma_study.PROBES and twin not in coma_study.PROBES and dueling not in coma_study.PROBES
    assert coma_study.VARIANTS[twin] == coma_study.VARIANTS[probe]  # only the probe's baseline differs
    settings = dict(coma_study.VARIANTS[dueling])
    assert settings.pop("policy_kwargs") == {**coma_study.VARIANTS[twin]["policy_kwargs"], "dueling_critic": True}
    assert settings == {k: v for k, v in coma_study.VARIANTS[twin].items() if k != "policy_kwargs"}
    text = (Path(__file__).resolve().parents[1] / "docs" / "coma_study" / "warehouse_screen_round.md").read_text()
    for (entry, (offer,)), (pair_entry, neighbour) in zip(
        coma_study.WAREHOUSE_DUELING_OFFERS.items(), zip(arms[4::2], arms[5::2]), strict=True
    ):
        learner = coma_study.learner_of(entry)
        ranked = coma_study.screen_order(text, TASKS["rware_tiny"].name, coma_study.warehouse_neighbours(learner))
        axis = set(coma_study.PPO_VARIANTS[entry][1])
        ring = [n.removeprefix(f"{learner}_") for n in ranked[1:] if not set(coma_study.PPO_VARIANTS[n][1]) & axis]
        assert ring[4] == offer and (*coma_study.WAREHOUSE_RING_OFFERS[entry], offer) == tuple(ring[:5])
        assert pair_entry == entry
        assert coma_study.ppo_settings(neighbour) == coma_study.ppo_settings(entry) | coma_study.WAREHOUSE_OFFERS[offer]
    assert coma_study.WAREHOUSE_DUELING not in coma_study.ROUNDS["study"]
    assert set(coma_study.WAREHOUSE_DUELING_ROUND) == {coma_study.WAREHOUSE_DUELING}


def test_round_37_confirms_the_first_two_new_arms_of_rounds_34_and_36_beside_each_entry() -> None:
    study = Path(__file__).resolve().parents[1] / "docs" / "coma_study"
    text = "\n".join((study / f"{name}.md").read_text() for name in ("warehouse_ring_round", "warehouse_dueling_round"))
    arms = coma_study.ROUNDS["warehouse_ring_confirm_round"]
    assert arms[::3] == tuple(coma_study.WAREHOUSE_RING_CONFIRMS) == coma_study.WAREHOUSE_TRACE_ENTRIES
    for entry, pair in coma_study.WAREHOUSE_RING_CONFIRMS.items():
        candidates = coma_study.warehouse_ring_candidates(entry)
        assert len(candidates) == len(set(candidates)) == 5 and entry not in candidates
        assert coma_study.screen_order(text, TASKS["rware_tiny"].name, candidates)[:2] == pair
    assert coma_study.WAREHOUSE_RING_CONFIRMS["minibatch_86"][0] in coma_study.PROBES  # flown, never taken


def test_round_38_confirms_the_first_of_round_35s_table_that_fill_each_budget() -> None:
    text = (Path(__file__).resolve().parents[1] / "docs" / "coma_study" / "foraging_budget_round.md").read_text()
    arms = coma_study.ROUNDS["foraging_budget_confirm_round"]
    start = 0
    for entry, count in coma_study.FORAGING_SCREENS:
        confirms = coma_study.FORAGING_CONFIRMS[entry]
        ranked = coma_study.screen_order(text, TASKS["lbf"].name, tuple(coma_study.entry_neighbours(entry, count)))
        assert confirms == ranked[: coma_study.FORAGING_CONFIRM_COUNTS[entry]]
        assert arms[start : start + 1 + len(confirms)] == (entry, *confirms)
        start += 1 + len(confirms)
    assert start == len(arms)


def test_round_39_flies_every_off_axis_offer_of_each_ppo_entry_on_simple_spreads_whole_budget() -> None:
    arms = coma_study.ROUNDS["spread_budget_round"]
    mappo, ippo = coma_study.SPREAD_ENTRIES
    assert coma_study.PPO_VARIANTS[mappo][1] == {"clip_range": 0.05}  # the entry since round 26
    assert coma_study.PPO_VARIANTS[ippo][1] == {}  # the MAPPO paper's MPE settings
    mappo_arms = coma_study.entry_neighbours(mappo, len(coma_study.BUDGET_OFFERS))
    ippo_arms = coma_study.entry_neighbours(ippo, len(coma_study.BUDGET_OFFERS))
    assert arms == (mappo, *mappo_arms, ippo, *ippo_arms)
    assert len(mappo_arms) == 8 and len(ippo_arms) == 10  # MAPPO's two clip offers are its entry's axis
    assert all("clip_range" not in change or change["clip_range"] == 0.05 for _, change in mappo_arms.values())
    assert len({json.dumps(change, sort_keys=True) for _, change in mappo_arms.values()}) == 8
    # every arm on the three validation seeds: MAPPO 38 + 8 * 3 runs, IPPO 12 + 11 * 3 (its entry's first
    # whole-budget runs count: runs at 150k joint steps are other runs)
    folder = Path(__file__).resolve().parents[1] / "docs" / "coma_study"
    later = tuple(path.name for path in folder.glob("spread_*.md") if path.name != "spread_budget_round.md")
    runs = _runs_without(folder, later)
    task = TASKS["simple_spread"].name
    assert (runs[("mappo", task)], runs[("ippo", task)], runs[("coma", task)]) == (62, 45, 117)
    # its choices, round 40's centres, are each ring's first (the entry listed first: it keeps a tie)
    text = (folder / "spread_budget_round.md").read_text()
    name = coma_study.study_task("simple_spread_full").name
    firsts = [
        coma_study.screen_first(text, name, (entry, *offers))
        for entry, offers in ((mappo, mappo_arms), (ippo, ippo_arms))
    ]
    assert tuple(firsts) == coma_study.SPREAD_RING_2_CENTRES


def _runs_without(folder: Path, later: tuple[str, ...]) -> dict[tuple[str, str], int]:
    """:func:`coma_study.tuning_runs` over the round tables in ``folder`` but the ``later`` ones."""
    with tempfile.TemporaryDirectory() as until:
        for path in folder.glob("*.md"):
            if path.name not in later:
                shutil.copy(path, until)
        return coma_study.tuning_runs(Path(until))


def test_round_40s_centres_are_round_39s_firsts_and_its_arms_all_new() -> None:
    """The second ring: each learner's best arm of the first that was not yet a centre, and every offer off
    the centre's axes, none of them in the first ring."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "coma_study" / "spread_budget_round.md").read_text()
    name = coma_study.study_task("simple_spread_full").name
    ring_1 = coma_study.ROUNDS["spread_budget_round"]
    for entry, centre in zip(coma_study.SPREAD_ENTRIES, coma_study.SPREAD_RING_2_CENTRES, strict=True):
        learner = coma_study.learner_of(entry)
        mine = tuple(arm for arm in ring_1 if coma_study.learner_of(arm) == learner)
        assert mine[0] == entry and coma_study.screen_first(text, name, mine) == centre != entry
    arms = coma_study.ROUNDS["spread_ring_2_round"]
    assert arms == coma_study.spread_ring_arms(coma_study.SPREAD_RING_2_CENTRES)
    new = [arm for arm in arms if arm not in coma_study.SPREAD_RING_2_CENTRES]
    assert len(new) == 6 + 8 and not set(new) & set(ring_1)  # MAPPO's centre has two axes, IPPO's one


def test_round_40_chose_the_benchmarks_entries_and_round_41s_centres_by_the_ring_rule() -> None:
    """Round 40's firsts are the benchmark's entries (MAPPO's centre kept its place, IPPO took 15 epochs);
    round 41's centres are each learner's best arm over rounds 39 and 40 not yet a centre; the runs so far
    are read off the tables (MAPPO 62 + 6 * 3, IPPO 45 + 8 * 3; COMA's 117)."""
    folder = Path(__file__).resolve().parents[1] / "docs" / "coma_study"
    ring_2 = (folder / "spread_ring_2_round.md").read_text()
    both = (folder / "spread_budget_round.md").read_text() + "\n" + ring_2
    name = coma_study.study_task("simple_spread_full").name
    arms = coma_study.ROUNDS["spread_budget_round"] + coma_study.ROUNDS["spread_ring_2_round"]
    centres = {*coma_study.SPREAD_ENTRIES, *coma_study.SPREAD_RING_2_CENTRES}
    for i, (centre, third) in enumerate(zip(coma_study.SPREAD_RING_2_CENTRES, coma_study.SPREAD_RING_3_CENTRES)):
        learner = coma_study.learner_of(centre)
        ring = tuple(arm for arm in coma_study.ROUNDS["spread_ring_2_round"] if coma_study.learner_of(arm) == learner)
        assert ring[0] == centre and coma_study.screen_first(ring_2, name, ring) == ENTRIES_0_19["simple_spread"][i]
        mine = tuple(dict.fromkeys(arm for arm in arms if coma_study.learner_of(arm) == learner))
        assert coma_study.screen_first(both, name, tuple(a for a in mine if a not in centres)) == third
    assert ENTRIES_0_19["simple_spread"][0] == coma_study.SPREAD_RING_2_CENTRES[0]  # MAPPO's entry stays
    assert ENTRIES_0_19["simple_spread"][1] == coma_study.SPREAD_RING_3_CENTRES[1]  # IPPO's winner is its next centre
    runs = _runs_without(folder, ("spread_ring_3_round.md", "spread_fill_round.md"))
    task = TASKS["simple_spread"].name
    assert (runs[("mappo", task)], runs[("ippo", task)], runs[("coma", task)]) == (80, 69, 117)
    new = [arm for arm in coma_study.ROUNDS["spread_ring_3_round"] if arm not in coma_study.SPREAD_RING_3_CENTRES]
    assert len(new) == 5 + 6 and not set(new) & set(arms)


#: MAPPO's and IPPO's simple_spread entries after round 40 (0.19.0), the incumbents of rounds 41 and 42.
ENTRIES_0_19 = {"simple_spread": ("mappo_clip_0.05_epochs_15", "ippo_clip_0.05_epochs_15")}


def _best_over_rings(rings: tuple[str, ...]) -> tuple[str, str]:
    """MAPPO's and IPPO's best arm on simple_spread's whole budget over the ``rings``' tables, each
    learner's 0.19.0 entry listed first so that it keeps a tie (:func:`coma_study.screen_first`)."""
    folder = Path(__file__).resolve().parents[1] / "docs" / "coma_study"
    tables = "\n".join((folder / f"{ring}.md").read_text() for ring in rings)
    name = coma_study.study_task("simple_spread_full").name
    best = []
    for learner, incumbent in zip(("mappo", "ippo"), ENTRIES_0_19["simple_spread"], strict=True):
        arms = (incumbent, *(arm for ring in rings for arm in coma_study.ROUNDS[ring]))
        mine = tuple(dict.fromkeys(arm for arm in arms if coma_study.learner_of(arm) == learner))
        best.append(coma_study.screen_first(tables, name, mine))
    return best[0], best[1]


def test_round_41_kept_mappos_entry_and_gave_ippo_its_best_arm_over_three_rings() -> None:
    """After the third ring each entry is the learner's best arm over rounds 39 to 41, the incumbent listed
    first (MAPPO's stays; IPPO's takes GAE lambda 0.99, ahead on the mean)."""
    rings = ("spread_budget_round", "spread_ring_2_round", "spread_ring_3_round")
    assert _best_over_rings(rings) == CHOSEN["simple_spread"][1:]
    mappo_0_19, ippo_0_19 = ENTRIES_0_19["simple_spread"]
    assert CHOSEN["simple_spread"][1] == mappo_0_19 and CHOSEN["simple_spread"][2] != ippo_0_19


FILL_TABLE = Path(__file__).resolve().parents[1] / "docs" / "coma_study" / "spread_fill_round.md"


@pytest.mark.skipif(not FILL_TABLE.exists(), reason="round 42 (spread_fill_round) has not reported yet")
def test_round_42_leaves_each_learner_its_best_arm_over_the_four_rings_and_comas_budget() -> None:
    """The entries after the last ring are each learner's best arm over rounds 39 to 42 (the incumbent first,
    so that it keeps a tie), and every learner has COMA's runs on simple_spread, up to an arm's seeds over."""
    rings = ("spread_budget_round", "spread_ring_2_round", "spread_ring_3_round", "spread_fill_round")
    assert _best_over_rings(rings) == CHOSEN["simple_spread"][1:]
    folder = FILL_TABLE.parent
    runs = coma_study.tuning_runs(folder)
    task = TASKS["simple_spread"].name
    for learner in ("mappo", "ippo"):
        assert 0 <= runs[(learner, task)] - runs[("coma", task)] < 3, learner


def test_round_42s_centres_follow_the_ranking_and_fill_each_budget_to_comas() -> None:
    """The fill ring: each learner's centres are its best arms over rounds 39 to 41 not yet centres, in
    order; every arm they bring is new on the task; the last centre's offers stop where the learner's runs
    reach COMA's (three seeds an arm)."""
    folder = Path(__file__).resolve().parents[1] / "docs" / "coma_study"
    rings = ("spread_budget_round", "spread_ring_2_round", "spread_ring_3_round")
    tables = "\n".join((folder / f"{ring}.md").read_text() for ring in rings)
    name = coma_study.study_task("simple_spread_full").name
    flown = [arm for ring in rings for arm in coma_study.ROUNDS[ring]]
    centres = {*coma_study.SPREAD_ENTRIES, *coma_study.SPREAD_RING_2_CENTRES, *coma_study.SPREAD_RING_3_CENTRES}
    before = _runs_without(folder, ("spread_fill_round.md",))
    task = TASKS["simple_spread"].name
    arms = coma_study.ROUNDS["spread_fill_round"]
    earlier = "\n".join(path.read_text() for path in folder.glob("*.md") if path.name != "spread_fill_round.md")
    rows = {line.split("|")[2].strip() for line in earlier.splitlines() if line.startswith(f"| {name} |")}
    for learner in ("mappo", "ippo"):
        mine = tuple(dict.fromkeys(arm for arm in flown if coma_study.learner_of(arm) == learner))
        ranking = [arm for arm in coma_study.screen_order(tables, name, mine) if arm not in centres]
        fill = [(centre, count) for centre, count in coma_study.SPREAD_FILL if coma_study.learner_of(centre) == learner]
        assert [centre for centre, _ in fill] == ranking[: len(fill)]
        new = [arm for arm in arms if coma_study.learner_of(arm) == learner and arm not in dict(fill)]
        assert len(new) == sum(count for _, count in fill) == len(set(new)) and not set(new) & rows
        short = before[("coma", task)] - before[(learner, task)]
        assert 0 <= 3 * len(new) - short < 3, learner


def test_round_43_flies_each_foraging_entry_and_one_arm_at_the_whole_budget() -> None:
    """COMA's arm is its entry with the dueling critic and nothing else; MAPPO's and IPPO's are their best
    other arms over Foraging-5x5's earlier tables; every learner flies two arms, so the budget stays equal."""
    assert coma_study.study_task("lbf_full").joint_steps == TASKS["lbf"].joint_steps
    entries, arms = coma_study.FORAGING_WHOLE_ENTRIES, coma_study.FORAGING_WHOLE_ARMS
    assert coma_study.ROUNDS["foraging_whole_round"] == tuple(x for pair in zip(entries, arms) for x in pair)
    coma_entry, coma_arm = coma_study.VARIANTS[entries[0]], coma_study.VARIANTS[arms[0]]
    assert coma_arm["policy_kwargs"] == {**coma_entry["policy_kwargs"], "dueling_critic": True}
    assert {k: v for k, v in coma_arm.items() if k != "policy_kwargs"} == {
        k: v for k, v in coma_entry.items() if k != "policy_kwargs"
    }
    folder = Path(__file__).resolve().parents[1] / "docs" / "coma_study"
    tables = "\n".join(p.read_text() for p in sorted(folder.glob("*.md")) if p.name != "foraging_whole_round.md")
    name = coma_study.study_task("lbf").name
    rows = [line.split("|")[2].strip() for line in tables.splitlines() if line.startswith(f"| {name} |")]
    for entry, arm in zip(entries[1:], arms[1:], strict=True):  # the entry first, so that it keeps a tie
        learner = coma_study.learner_of(entry)
        mine = tuple(
            dict.fromkeys(r for r in (entry, *rows) if r in coma_study.ARMS and coma_study.learner_of(r) == learner)
        )
        assert coma_study.screen_order(tables, name, mine)[:2] == (entry, arm), learner
    assert [coma_study.learner_of(a) for a in arms] == [coma_study.learner_of(e) for e in entries]


WHOLE_FORAGING_TABLE = Path(__file__).resolve().parents[1] / "docs" / "coma_study" / "foraging_whole_round.md"


@pytest.mark.skipif(not WHOLE_FORAGING_TABLE.exists(), reason="round 43 (foraging_whole_round) has not reported yet")
def test_round_43_leaves_each_learner_the_arm_its_whole_budget_ranks_first() -> None:
    """Foraging-5x5's entries after round 43 are each learner's first of (entry, arm) on the whole-budget table
    (:func:`coma_study.screen_first`, the entry listed first)."""
    table = WHOLE_FORAGING_TABLE.read_text()
    name = coma_study.study_task("lbf_full").name
    pairs = zip(coma_study.FORAGING_WHOLE_ENTRIES, coma_study.FORAGING_WHOLE_ARMS, strict=True)
    assert tuple(coma_study.screen_first(table, name, pair) for pair in pairs) == CHOSEN["lbf"]


def test_a_screens_order_is_its_first_again_and_again() -> None:
    def row(variant: str, validation: str, last: str) -> str:
        return f"| T | {variant} | s | 1 | {validation} | {validation} | 0 | - | - | - | 0.0 / 0.0 / {last} | 1.0 |"

    table = "\n".join(
        [row("a", "0.00", "0.1"), row("b", "0.00", "0.3"), row("c", "0.20", "0.0"), row("d", "0.00", "0.1")]
    )
    assert coma_study.screen_order(table, "T", ("a", "b", "c", "d")) == ("c", "b", "a", "d")
    assert coma_study.screen_order(table, "T", ("d", "a")) == ("d", "a")


def test_a_screen_ranks_by_validation_then_training_return_then_offer_order() -> None:
    def row(variant: str, validation: str, last: str) -> str:
        return f"| T | {variant} | s | 1 | {validation} | {validation} | 0 | - | - | - | 0.0 / 0.0 / {last} | 1.0 |"

    table = "\n".join(
        [row("a", "0.00", "0.1"), row("b", "0.00", "0.3"), row("c", "0.00", "0.3"), row("d", "-0.01", "9")]
    )
    assert coma_study.screen_first(table, "T", ("a", "b", "c", "d")) == "b"
    assert coma_study.screen_first(table, "T", ("c", "b")) == "c"
    with pytest.raises(ValueError, match="'e'"):
        coma_study.screen_first(table, "T", ("a", "e"))


def test_the_budget_rounds_rwares_and_foraging_5x5s_give_every_learner_the_same_budget() -> None:
    """Counted from the round tables in git, as the benchmark's results count it."""
    runs = coma_study.tuning_runs(Path(__file__).resolve().parents[1] / "docs" / "coma_study")
    for key in (*coma_study.BUDGET_SCREENS, "rware_tiny", "lbf"):
        task = TASKS[key].name
        assert runs[("mappo", task)] == runs[("ippo", task)] == runs[("coma", task)], task


def test_round_30_flies_each_learners_rware_entry_at_its_whole_budget() -> None:
    """The entries as they were before round 30: COMA's (round 2's Foraging-5x5 entry, which rounds 31 to 33
    kept and round 37 replaced) and the PPO learners' MAPPO-paper settings (which round 32 changed)."""
    assert coma_study.study_task("rware_tiny").joint_steps == TASKS["rware_tiny"].joint_steps
    coma, *ppo = coma_study.WAREHOUSE_ENTRIES
    assert coma_study.VARIANTS[coma] == {"n_steps": 128, "batch_size": 86, "n_epochs": 10}
    assert [coma_study.PPO_VARIANTS[name] for name in ppo] == [("mappo", {}), ("ippo", {})]
    assert coma_study.ROUNDS["warehouse_round"] == coma_study.WAREHOUSE_ENTRIES


def test_round_31_gives_every_learner_the_same_offers_on_rware() -> None:
    """The same first offers, in the same order, applied to each learner's entry: an equal budget."""
    arms = coma_study.ROUNDS["warehouse_screen_round"]
    offers = list(coma_study.WAREHOUSE_OFFERS.values())
    assert offers[:5] == list(coma_study.BUDGET_OFFERS.values())[:5]
    assert len(arms) == len(set(arms)) == 3 * (1 + len(offers))
    for k, entry in enumerate(coma_study.WAREHOUSE_ENTRIES):
        block = arms[k * (1 + len(offers)) : (k + 1) * (1 + len(offers))]
        assert block[0] == entry and {coma_study.learner_of(a) for a in block} == {coma_study.learner_of(entry)}
        base = coma_study.VARIANTS[entry] if k == 0 else coma_study.ppo_settings(entry)
        for name, offer in zip(block[1:], offers, strict=True):
            settings = coma_study.VARIANTS[name] if k == 0 else coma_study.ppo_settings(name)
            assert settings == base | offer and settings != base
    assert not set(coma_study.WAREHOUSE_ROUND) & set(coma_study.ROUNDS["study"])


#: The study variant each studied task's COMA entry took (its comment in zoo_configs/marl/coma.yml says
#: which round chose it), MAPPO's and IPPO's.
CHOSEN = {
    "simple_spread": (
        "minibatch_86_before_lambda_95_q_norm_clock_25_pi_64x3_clip_0.05",
        "mappo_clip_0.05_epochs_15",
        "ippo_clip_0.05_epochs_15_gae_0.99",
    ),
    "simple_reference": ("before_lambda_95_q_norm_lr_1e-4_clock_25", "mappo_lr_1e-4", "ippo_ent_0_batch_128"),
    "lbf": ("minibatch_86_before_lambda_95_q_norm_pi_64x3_clip_0.1", "mappo_epochs_15", "ippo_lr_7e-4_batch_128"),
    "lbf_8x8": ("minibatch_86_before", "mappo_lr_7e-4", "ippo_ent_0_lr_7e-4"),
    "rware_tiny": (coma_study.WAREHOUSE_DUELING, "mappo_lr_7e-4_clip_0.05", "ippo_lr_7e-4"),
}


@pytest.mark.parametrize("task", sorted(CHOSEN))
def test_a_studied_tasks_benchmark_entries_are_the_study_variants_validation_chose(task: str) -> None:
    """The benchmark trains exactly what the study measured on the validation seeds: a hand edit of a
    config that no study variant matches would report a learner nobody chose."""
    coma, mappo, ippo = CHOSEN[task]
    entry = learner_settings("coma", TASKS[task])
    assert entry.pop("policy") == "MlpPolicy" and entry == coma_study.VARIANTS[coma]
    assert learner_settings("mappo", TASKS[task]) == coma_study.ppo_settings(mappo)
    assert learner_settings("ippo", TASKS[task]) == coma_study.ppo_settings(ippo)


@pytest.mark.parametrize("learner", ["coma", "mappo"])
def test_an_entrys_linear_schedule_trains_as_the_zoo_reads_it(learner: str) -> None:
    """The benchmark and the study build a model from an entry as rl-zoo3 does: ``lin_<x>`` is its
    linear schedule from x to 0 (COMA's critic rate too), a number stays that number."""
    task = TASKS["simple_spread"]
    settings = learner_settings(learner, task) | {"learning_rate": "lin_3e-4"}
    if learner == "coma":
        settings["critic_learning_rate"] = "lin_1e-3"
    model, venv, _ = marl_benchmark._trainee(learner, task, 0, settings)
    venv.close()
    assert model.lr_schedule(1.0) == pytest.approx(3e-4) and model.lr_schedule(0.25) == pytest.approx(7.5e-5)
    if learner == "coma":
        assert model.critic_lr_schedule(0.5) == pytest.approx(5e-4)
    assert settings["learning_rate"] == "lin_3e-4"  # the caller's entry is not rewritten


def test_a_study_variant_with_a_linear_schedule_is_the_entry_with_both_rates_annealed() -> None:
    entry = coma_study.VARIANTS["before_lambda_95_q_norm"]
    annealed = coma_study.LATE_STEP_ROUND["before_lambda_95_q_norm_lin_lr"]
    assert annealed == entry | {"learning_rate": "lin_3e-4", "critic_learning_rate": "lin_1e-3"}
    assert {"before_lambda_95_q_norm", "mappo_pi_64x2"} <= set(coma_study.ROUNDS["late_step_round"])


def test_a_ppo_learners_variant_changes_the_mappo_papers_settings_and_nothing_else(tmp_path: Path) -> None:
    """MAPPO's tuning round (issue #45, item 2): each arm is the MAPPO paper's MPE settings with one
    change, fixed in the study (not read from the zoo entry, which the study's own choice may change);
    the report names the learner and the change."""
    assert coma_study.learner_of("mappo_lr_7e-4") == "mappo" and coma_study.learner_of("minibatch_86") == "coma"
    arms = coma_study.ROUNDS["mappo_round"]
    assert arms[0] == coma_study.REFERENCE and all(coma_study.learner_of(a) == "mappo" for a in arms)
    assert all(coma_study.learner_of(a) == "ippo" for a in coma_study.ROUNDS["ippo_round"])
    task = TASKS["simple_spread"]
    model, venv, _ = marl_benchmark._trainee("mappo", task, 0, coma_study.ppo_settings("mappo_epochs_5"))
    paper = coma_study.MAPPO_PAPER_MPE
    assert model.n_epochs == 5 and paper["n_epochs"] == 10
    assert model.batch_size == paper["batch_size"] and model.n_steps == paper["n_steps"]
    assert model.clip_range(1.0) == 0.2  # SB3's default: the zoo entry's own clipping does not leak in
    assert type(model.policy).__name__ == "CentralValuePolicy" and model.get_vec_normalize_env() is None
    venv.close()
    # the value-normalisation arm: SB3's VecNormalize on the rewards alone, the paper's settings otherwise
    model, venv, _ = marl_benchmark._trainee("mappo", task, 0, coma_study.ppo_settings("mappo_norm_reward"))
    normalizer = model.get_vec_normalize_env()
    assert normalizer is venv and normalizer.norm_reward and not normalizer.norm_obs
    assert model.n_epochs == paper["n_epochs"] and model.clip_range(1.0) == 0.2
    venv.close()
    (tmp_path / "runs").mkdir()
    name = f"simple_spread-mappo_epochs_5-{coma_study.VALIDATION_TRAIN_SEED}"
    record = {"task": "simple_spread", "variant": "mappo_epochs_5", "seed": coma_study.VALIDATION_TRAIN_SEED}
    record |= {"validation_return": -47.0, "seconds": 60.0, "curve": [[0, -60.0], [1000, -50.0]]}
    (tmp_path / "runs" / f"{name}.json").write_text(json.dumps(record))
    (tmp_path / "runs" / f"{name}.csv").write_text("time/total_timesteps,rollout/ep_rew_mean\n1,-20\n")
    text = coma_study.report_phase(tmp_path, 1, "mappo_round")
    assert (
        "| simple_spread | mappo_epochs_5 | not COMA: MAPPO with the MAPPO paper's MPE settings, n_epochs=5 |" in text
    )
    assert "n_epochs=5 | 1 | -47.00 |" in text


def test_the_tuning_budget_is_counted_from_the_round_tables(tmp_path: Path) -> None:
    """Each learner's validation runs per task, from the tables in git: a variant flown by two rounds
    counts once, with the most seeds either shows; a row of no known variant counts for nothing."""
    head = "| task | variant | settings | seeds | validation return |\n| --- | --- | --- | --- | --- |\n"
    (tmp_path / "study.md").write_text(
        head + "| simple_spread | paper | x | 1 | -60 |\n| simple_spread | mappo | x | 1 | -47 |\n"
    )
    (tmp_path / "later_round.md").write_text(
        head
        + "| simple_spread | paper | x | 3 | -60 |\n| simple_spread | mappo_lr_7e-4 | x | 1 | -46 |\n"
        + "| simple_spread | no_such_variant | x | 9 | -1 |\n| lbf | paper | x | seeds | -1 |\n"
    )
    assert coma_study.tuning_runs(tmp_path) == {("coma", "simple_spread"): 3, ("mappo", "simple_spread"): 2}
    text = marl_benchmark.tuning_paragraph(tmp_path)
    assert "COMA: simple_spread 3; MAPPO: simple_spread 2; IPPO: none." in text
    assert "The budget is NOT equal across learners on simple_spread;" in text
    for learner, seeds in (("mappo", 1), ("ippo", 3)):
        (tmp_path / f"{learner}_round.md").write_text(
            head + f"| simple_spread | {learner}_lr_1e-4 | x | {seeds} | -50 |\n| lbf | paper | x | 2 | 0.5 |\n"
        )
    text = marl_benchmark.tuning_paragraph(tmp_path)
    assert "COMA: lbf 2, simple_spread 3; MAPPO: simple_spread 3; IPPO: simple_spread 3." in text
    assert "The budget is NOT equal across learners on lbf (equal on simple_spread);" in text


def test_a_budget_one_arm_apart_is_called_equal_to_within_one_arm_and_a_missing_learner_is_not() -> None:
    """The rings fill a budget three runs (one arm's seeds) at a time: counts fewer than three apart are equal
    to within one arm, said as such; three apart, or a learner with no runs, is unequal."""
    verdict = marl_benchmark._budget_verdict
    assert verdict({"a": [5, 5, 5]}) == "The budget is equal across learners on every task"
    assert verdict({"a": [5, 5, 5], "b": [117, 119, 117]}) == (
        "The budget is equal across learners on every task, to within one arm of 3 validation seeds on b (exactly on a)"
    )
    assert verdict({"b": [117, 119, 117]}).endswith("to within one arm of 3 validation seeds on b")
    assert verdict({"a": [5, 5, 5], "b": [117, 119, 117], "c": [117, 120, 117]}) == (
        "The budget is NOT equal across learners on c (equal on a; to within one arm of 3 validation seeds on b)"
    )
    assert verdict({"c": [2, 0, 2]}) == "The budget is NOT equal across learners on c"


def test_an_entrys_normalize_key_is_read_as_rl_zoo_reads_it() -> None:
    split = marl_benchmark.split_normalize
    entry = {"policy": "MlpPolicy", "n_epochs": 10}
    assert split(entry) == (entry, None)
    assert split({**entry, "normalize": False}) == (entry, None)
    assert split({**entry, "normalize": True}) == (entry, {})
    as_zoo_writes_it = "{'norm_obs': False, 'norm_reward': True}"
    assert split({**entry, "normalize": as_zoo_writes_it}) == (entry, {"norm_obs": False, "norm_reward": True})
    as_an_expression = "dict(norm_obs=False, norm_reward=True)"  # the other form rl-zoo3's own comment shows
    assert split({**entry, "normalize": as_an_expression}) == (entry, {"norm_obs": False, "norm_reward": True})
    # the discount of the normaliser's running return is the learner's own
    with_gamma = {**entry, "gamma": 0.95, "normalize": {"norm_obs": False}}
    assert split(with_gamma) == ({**entry, "gamma": 0.95}, {"norm_obs": False, "gamma": 0.95})
    assert with_gamma["normalize"] == {"norm_obs": False}  # the caller's entry is left as it was


def test_a_normalized_entry_trains_on_scaled_rewards_and_is_scored_on_the_envs_own() -> None:
    from stable_baselines3.common.vec_env import VecNormalize

    task = marl_benchmark.dataclasses.replace(TASKS["simple_spread"], joint_steps=256)
    settings = {"policy": "CentralValuePolicy", "n_steps": 32, "batch_size": 64, "normalize": True}
    model, venv, recorder = marl_benchmark._trainee("mappo", task, 0, settings)
    assert isinstance(venv, VecNormalize) and model.get_vec_normalize_env() is venv
    model.learn(256 * recorder.n_agents)
    assert venv.ret_rms.count > 1 and venv.obs_rms["state"].count > 1  # the statistics were fitted
    assert all(ret < 0 for _, ret in recorder.episodes)  # the recorder sees MPE's own (negative) rewards
    statistics = venv.obs_rms["state"].mean.copy()
    returns = marl_benchmark.evaluate_team_return(task, "mappo", model, episodes=2, seed=7)
    assert len(returns) == 2 and all(ret < 0 for ret in returns)
    # scoring froze a copy of the statistics: the model's own are untouched, and still training
    assert (venv.obs_rms["state"].mean == statistics).all() and venv.training and venv.norm_reward
    venv.close()


def test_the_tables_word_on_actor_depth_holds_for_the_benchmarks_entries() -> None:
    """results.md says COMA's and IPPO's actors have two 64-unit tanh layers, COMA's on simple_spread
    and Foraging-5x5 three (round 21), and MAPPO's one more than two."""
    from torch import nn

    def hidden_layers(model: Any) -> list[int]:
        policy = model.policy
        if hasattr(policy, "actor"):  # COMA: its actor network, less the output head
            modules = [m for m in policy.actor.modules() if isinstance(m, nn.Linear)][:-1]
        else:  # SB3's PPO: the actor's extractor, then its MlpExtractor branch
            modules = [
                m
                for part in (policy.pi_features_extractor, policy.mlp_extractor.policy_net)
                for m in part.modules()
                if isinstance(m, nn.Linear)
            ]
        return [m.out_features for m in modules]

    cases = (
        ("coma", "simple_reference", [64, 64]),
        ("coma", "simple_spread", [64, 64, 64]),
        ("coma", "lbf", [64, 64, 64]),
        ("ippo", "simple_spread", [64, 64]),
        ("mappo", "simple_spread", [64, 64, 64]),
    )
    for learner, task_key, expected in cases:
        model, venv, _ = marl_benchmark._trainee(learner, TASKS[task_key], 0)
        assert hidden_layers(model) == expected, (learner, task_key)
        venv.close()
    assert "but COMA's on simple_spread and Foraging-5x5 have\nthree" in marl_benchmark.HEADER
    assert "reads its keys\nthrough one more than two" in marl_benchmark.HEADER
