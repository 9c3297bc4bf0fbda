"""``sb3-coma --version`` names the installed release (the one ``sb3_coma.__version__`` says)."""

from __future__ import annotations

import pytest

import sb3_coma
from sb3_coma.cli import main


def test_version_flag_prints_the_installed_version(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"sb3-coma {sb3_coma.__version__}"
