"""Attribution (#35): the warm-started model is named as one, its clone is a row of its own, and
the Models table counts the teacher-labelled missions."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from result_fakes import fake_result

from sb3_coma.app.pretrained import WARM_START_TITLE
from sb3_coma.experiments import attribution, report
from sb3_coma.experiments.ship_models import model_title


def test_the_report_has_every_row_and_each_pair_once() -> None:
    rng = np.random.default_rng(0)
    scenes = [f"s{i % 4}" for i in range(16)]
    base = rng.uniform(0.6, 0.8, 16)
    flown = {
        attribution.WARM_LABEL: fake_result(attribution.WARM_LABEL, list(base + 0.02), scenes),
        attribution.CLONE_LABEL: fake_result(attribution.CLONE_LABEL, list(base + 0.019), scenes),
        "ag": fake_result("ag", list(base), scenes),
        attribution.SCRATCH_LABEL: fake_result(attribution.SCRATCH_LABEL, list(base - 0.01), scenes),
    }
    text, rows = attribution.report({"env3": flown}, ["env3: a note"])
    assert attribution.WARM_LABEL == WARM_START_TITLE == "COMA (oracle warm start)"
    assert "test split: reporting only" in text and "- env3: a note" in text
    for label in flown:
        assert f"| env3 | {label} |" in text
    pairs = [(r["a"], r["b"], r["metric"]) for r in rows]
    assert len(pairs) == len(set(pairs)) == 5 * 2  # 5 comparisons x (F1, entropy)
    assert (attribution.WARM_LABEL, attribution.CLONE_LABEL, "f1") in pairs
    warm_vs_clone = next(
        r for r in rows if (r["a"], r["b"], r["metric"]) == (attribution.WARM_LABEL, attribution.CLONE_LABEL, "f1")
    )
    assert abs(warm_vs_clone["diff"] - 0.001) < 1e-9
    assert all("p_holm" in r for r in rows)


def test_without_a_scratch_model_the_map_has_three_pairs() -> None:
    flown = {attribution.WARM_LABEL: None, attribution.CLONE_LABEL: None, "ag": None}
    assert len(attribution.comparisons(flown)) == 3  # type: ignore[arg-type]
    flown.update(dict.fromkeys(attribution.PAIR_LABELS))
    assert attribution.comparisons(flown)[-1] == attribution.PAIR_LABELS  # type: ignore[arg-type]


def test_teacher_missions_and_titles() -> None:
    warm = {"warm_start": {"teacher": "oracle", "rounds": 8, "missions": 128}}
    assert report.teacher_missions(warm) == 1024
    assert report.teacher_missions({}) == 0 and report.teacher_missions({"warm_start": None}) == 0
    assert model_title(warm) == WARM_START_TITLE and model_title({}) == "COMA"
    run = SimpleNamespace(sources={"env1": SimpleNamespace(info=warm), "env3": SimpleNamespace(info=warm)})
    assert report.model_titles(run) == {"coma": WARM_START_TITLE}
    run.sources["env2"] = SimpleNamespace(info={})  # a quick run trains without the teacher: plain "COMA"
    assert report.model_titles(run) == {}


def test_table_one_says_its_map_is_a_train_scene() -> None:
    assert "train* scene" in report.TABLE_I_CAVEAT and "not an unseen test" in report.TABLE_I_CAVEAT
