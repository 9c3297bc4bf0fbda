"""``sb3-coma study NAME``: every study of ``sb3_coma.experiments`` runs from the one CLI (#34)."""

from __future__ import annotations

import importlib
import pkgutil

import pytest

import sb3_coma.experiments as experiments
from sb3_coma import cli
from sb3_coma.cli.commands.study import STUDIES

#: Modules with a ``main`` that run under another verb (``sb3-coma reproduce`` ...), not ``study``.
OWN_VERBS = {"reproduce", "noise_sweep", "ablation", "ag_weighting"}


def test_every_study_with_a_main_is_listed_and_every_listed_one_has_a_main() -> None:
    runnable = set()
    for info in pkgutil.iter_modules(experiments.__path__):
        module = importlib.import_module(f"{experiments.__name__}.{info.name}")
        if callable(getattr(module, "main", None)):
            runnable.add(info.name)
    assert set(STUDIES) == runnable - OWN_VERBS


def test_an_unknown_study_is_one_line_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["study", "nope"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "unknown study 'nope'" in err and "dagger" in err


def test_a_study_takes_its_own_options(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        cli.main(["study", "budget_sweep", "--help"])
    assert stop.value.code == 0
    assert "--split {validation,test}" in capsys.readouterr().out
