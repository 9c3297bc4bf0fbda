"""``sb3-coma --help`` and ``sb3-coma VERB --help`` start in well under a second (issue #37).

The parser is built by importing every command module, so those modules (and ``sb3_coma`` itself,
whose ``__init__`` runs before any submodule) import at module level only what their options need;
torch, Stable-Baselines3, rl_zoo3, onnx and matplotlib are imported inside ``run``. The check is on
``sys.modules`` in a fresh interpreter, not on a clock: a timing assertion would fail on a busy
machine and pass on a fast one for the wrong reason.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: Packages whose import costs seconds; none may be loaded to print help.
HEAVY = ("torch", "stable_baselines3", "rl_zoo3", "onnx", "onnxruntime", "matplotlib")


def _loaded_after(code: str) -> list[str]:
    """Top-level packages of ``HEAVY`` that ``code`` leaves in ``sys.modules`` (fresh interpreter)."""
    probe = f"{code}\nimport sys\nprint(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))\n"
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    return eval(result.stdout.strip().splitlines()[-1])  # a printed list of str


def _help_code(argv: list[str]) -> str:
    """Python that runs ``sb3-coma ARGV`` (a --help) with its output swallowed."""
    return (
        "import contextlib, io\n"
        "from sb3_coma.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "    try:\n"
        f"        main({argv!r})\n"
        "    except SystemExit as exc:\n"
        "        assert exc.code == 0, exc.code\n"
        "assert 'usage: sb3-coma' in out.getvalue()\n"
    )


def _verbs() -> list[str]:
    from sb3_coma.cli import build_parser

    return sorted(build_parser()[1])


def test_top_level_help_loads_no_heavy_package() -> None:
    assert _loaded_after(_help_code(["--help"])) == []


def test_building_the_parser_loads_no_heavy_package() -> None:
    assert _loaded_after("from sb3_coma.cli import build_parser\nbuild_parser()") == []


@pytest.mark.parametrize("verb", _verbs())
def test_verb_help_loads_no_heavy_package(verb: str) -> None:
    assert _loaded_after(_help_code([verb, "--help"])) == []


def test_import_sb3_coma_loads_no_torch_and_serves_every_name() -> None:
    """The package's names are served on first use (PEP 562): all of them still resolve."""
    code = "import sb3_coma\nassert sorted(sb3_coma._LAZY) == sorted(n for n in sb3_coma.__all__ if n != '__version__')"
    assert _loaded_after(code) == []
    import sb3_coma

    assert all(getattr(sb3_coma, name) is not None for name in sb3_coma.__all__)
    assert set(sb3_coma.__all__) <= set(dir(sb3_coma))
    from sb3_coma.coma import COMA

    assert sb3_coma.COMA is COMA


def test_user_errors_are_still_one_line_and_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    """The error classes are imported once a command fails, not with the parser: a user error of
    any of their modules is still one line and exit status 2."""
    from sb3_coma.cli import UserError, main, user_errors
    from sb3_coma.common.checkpoints import CheckpointError
    from uav_ipp import ConfigError

    assert {UserError, CheckpointError, ConfigError} <= set(user_errors())
    assert main(["demo", "--noise", "thunder"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sb3-coma demo: error: ") and "thunder" in err[0], err


def test_the_defaults_written_for_help_are_the_libraries_own() -> None:
    """Two option defaults are read without their heavy modules: they must not drift."""
    import uav_ipp
    from sb3_coma.cli.commands import default_map
    from sb3_coma.cli.commands.pretrain_sendfuse import PRETRAIN_DEFAULTS
    from sb3_coma.sendfuse.pretrain import PretrainConfig

    assert default_map() == uav_ipp.DEFAULT_MAP
    config = PretrainConfig()
    assert vars(PRETRAIN_DEFAULTS) == {name: getattr(config, name) for name in vars(PRETRAIN_DEFAULTS)}
