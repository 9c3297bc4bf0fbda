"""Every command that takes a list of maps takes each map once (one rule, ``map_list``)."""

from __future__ import annotations

import pytest

from sb3_coma.cli import main


def test_ag_weighting_refuses_a_map_listed_twice(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["ag-weighting", "--env", "env1,env1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["sb3-coma ag-weighting: error: --env 'env1,env1' lists the map 'env1' twice: give each map once"]
