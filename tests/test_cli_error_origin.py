"""A command's generic ``USER_ERRORS`` (plain ValueError / TypeError) are printed as one line only
when one of our own checks raised them; a failure inside a dependency keeps its traceback."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_coma import cli
from sb3_coma.cli.commands import ablation
from sb3_coma.coma.validation import check_device


def test_a_check_of_ours_is_one_line(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    def bad_input(args: object) -> int:
        check_device("warp-drive")  # one of our checks: a plain ValueError naming the value
        return 0

    monkeypatch.setattr(ablation, "run", bad_input)
    assert cli.main(["ablation"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("sb3-coma ablation: error: device 'warp-drive'") and "\n" not in err


def test_a_failure_inside_a_dependency_keeps_its_traceback(monkeypatch: pytest.MonkeyPatch) -> None:
    def bug(args: object) -> int:
        return int(np.zeros(-1).sum())  # numpy's ValueError, raised in C under our call

    monkeypatch.setattr(ablation, "run", bug)
    with pytest.raises(ValueError, match="negative dimensions"):
        cli.main(["ablation"])
