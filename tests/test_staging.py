"""Staged outputs (``sb3_coma.app.outputs.staged_output``): a multi-file output replaces its
``--out`` as a whole or not at all.

Unit tests of the context manager (an exception or SIGTERM inside leaves the target untouched;
success replaces it, keeps other commands' files, drops the command's own old ones; a target
holding files no manifest lists is refused before any work; stale staging folders of dead runs,
recognised by their marker, are cleaned with one line; the fallback swap and its crash recovery),
the CLI's SIGTERM exit status, and a real ``sb3-coma reproduce --quick`` killed with SIGKILL while it
writes into a folder that holds a finished run: afterwards that folder is the old run, byte for byte.
More on what an output may touch: ``tests/test_output_ownership.py``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from staging_helpers import dead_pid, mark, siblings, snapshot, write_run

from sb3_coma import cli
from sb3_coma.app import outputs
from sb3_coma.app.outputs import (
    FolderLock,
    OutputFolderError,
    OutputInterrupted,
    manifest_name,
    staged_output,
)

REPO = Path(__file__).resolve().parent.parent


# ----------------------------------------------------------------------------- the context manager
def test_an_exception_inside_leaves_the_target_untouched(tmp_path):
    target = tmp_path / "out"
    write_run(target, "evaluate", {"table.md": "old", "figures/a.png": "old png"})
    before = snapshot(target)
    with pytest.raises(RuntimeError, match="boom"), staged_output(target, command="evaluate") as stage:
        assert stage.parent == target.parent and stage.name.startswith("out.partial-")
        (stage / "table.md").write_text("new")
        raise RuntimeError("boom")
    assert snapshot(target) == before
    assert siblings(target) == []  # the staging folder is gone


def test_success_replaces_the_target_and_keeps_files_of_others(tmp_path):
    target = tmp_path / "out"
    write_run(target, "evaluate", {"table.md": "old", "mission_env1_ag.gif": "old gif"})
    # 0.3.0: a file that no sb3-coma manifest lists (the user's) is never replaced nor carried:
    # the command is refused before any work and the file stays as it was
    (target / "notes.txt").write_text("the user's")
    with (
        pytest.raises(OutputFolderError, match="pass an empty or new folder"),
        staged_output(target, command="evaluate"),
    ):
        pytest.fail("refused before the work starts")
    assert (target / "notes.txt").read_text() == "the user's" and siblings(target) == []
    write_run(target, "export", {"notes.txt": "the user's"})  # written by another command: kept
    write_run(target / "noise_sweep", "noise-sweep", {"noise_sweep.md": "another command's"})  # an output inside
    with staged_output(target, command="evaluate") as stage:
        (stage / "table.md").write_text("new")
    assert (target / "table.md").read_text() == "new"
    assert not (target / "mission_env1_ag.gif").exists()  # the old run's own file: not mixed in
    assert (target / "notes.txt").read_text() == "the user's"
    assert (target / "noise_sweep" / "noise_sweep.md").read_text() == "another command's"
    manifest = json.loads((target / manifest_name("evaluate")).read_text())
    assert manifest["complete"] is True and manifest["entries"] == ["table.md"]
    assert not (target / outputs.STAGING_LOCK).exists()
    assert siblings(target) == []


def test_a_new_target_is_made_and_a_folder_without_manifest_is_refused_and_kept(tmp_path):
    target = tmp_path / "deep" / "out"
    with staged_output(target, command="noise-sweep", own=("noise_sweep.*",)) as stage:
        (stage / "noise_sweep.md").write_text("first")
    assert (target / "noise_sweep.md").read_text() == "first"
    legacy = tmp_path / "legacy"  # written before outputs had a manifest
    legacy.mkdir()
    (legacy / "noise_sweep.png").write_text("old figure")
    (legacy / "mine.txt").write_text("keep")
    # 0.3.0: names matching ``own`` no longer make files the command's (they were deleted): without
    # a manifest nothing in the folder is sb3-coma's, so the command is refused and all of it stays
    with (
        pytest.raises(
            OutputFolderError, match=r"holds what no sb3-coma command wrote there \('mine.txt', 'noise_sweep.png'\)"
        ),
        staged_output(legacy, command="noise-sweep", own=("noise_sweep.*",)),
    ):
        pytest.fail("refused before the work starts")
    assert sorted(p.name for p in legacy.iterdir()) == ["mine.txt", "noise_sweep.png"]
    assert (legacy / "noise_sweep.png").read_text() == "old figure" and siblings(legacy) == ["deep"]


def test_sigterm_inside_raises_and_leaves_the_target_untouched(tmp_path):
    target = tmp_path / "out"
    write_run(target, "reproduce", {"summary.json": "{}"})
    before = snapshot(target)
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(OutputInterrupted) as info, staged_output(target, command="reproduce") as stage:
        (stage / "summary.json").write_text('{"new": 1}')
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises before this ends
    assert info.value.signum == signal.SIGTERM
    assert str(info.value) == f"stopped by SIGTERM: --out {target} was not written (its previous content is untouched)"
    assert snapshot(target) == before and siblings(target) == []
    assert signal.getsignal(signal.SIGTERM) == previous


def test_a_stale_staging_folder_is_removed_with_one_line_and_a_live_one_is_left(tmp_path):
    target = tmp_path / "out"
    write_run(target, "evaluate", {"table.md": "old"})
    pid = dead_pid()
    stale = target.with_name(f"out.partial-{pid}")
    write_run(stale, "evaluate", {"table.md": "half"}, complete=False)
    mark(stale, target, pid)
    killed = target.with_name("out.partial-1")  # its lock file is free: the writer died (pid 1 lives on)
    killed.mkdir()
    (killed / outputs.STAGING_LOCK).write_text("{}")
    mark(killed, target, 1)
    live = target.with_name("out.partial-2")  # its lock is held: a run writing right now
    live.mkdir()
    mark(live, target, 2)
    lines: list[str] = []
    with FolderLock(live, outputs.STAGING_LOCK), staged_output(target, command="evaluate", say=lines.append) as stage:
        (stage / "table.md").write_text("new")
    assert (target / "table.md").read_text() == "new"
    assert siblings(target) == ["out.partial-2"]
    assert len(lines) == 2 and all("the unfinished output of an interrupted run" in line for line in lines)
    assert str(stale) in " ".join(lines) and "starting clean" in lines[0]


def test_the_fallback_swap_and_its_crash_recovery(tmp_path, monkeypatch):
    """Without renameat2: rename the old folder aside, rename the new one in. A crash between the
    two is finished by the next run: a complete staging folder is moved in, or the old one back."""
    monkeypatch.setattr(outputs, "_exchange", lambda a, b: False)
    target = tmp_path / "out"
    write_run(target, "evaluate", {"table.md": "old"})
    with staged_output(target, command="evaluate") as stage:
        (stage / "table.md").write_text("new")
    assert (target / "table.md").read_text() == "new" and siblings(target) == []

    pid = dead_pid()  # crashed after "old aside", before "new in": the new one is complete
    mark(target, target, pid, role="retired")  # written into the old output before it is set aside
    target.rename(target.with_name(f"out.old-{pid}"))
    write_run(target.with_name(f"out.partial-{pid}"), "evaluate", {"table.md": "newer"})
    mark(target.with_name(f"out.partial-{pid}"), target, pid)
    lines: list[str] = []
    with pytest.raises(RuntimeError), staged_output(target, command="evaluate", say=lines.append):
        raise RuntimeError("this run fails; the recovery before it stands")
    assert (target / "table.md").read_text() == "newer" and siblings(target) == []
    assert any("moved" in line for line in lines)

    mark(target, target, pid, role="retired")
    target.rename(target.with_name(f"out.old-{pid}"))  # only the old one is left: it comes back
    with pytest.raises(RuntimeError), staged_output(target, command="evaluate", say=lines.append):
        raise RuntimeError("fails too")
    assert (target / "table.md").read_text() == "newer" and siblings(target) == []
    assert any("restored" in line for line in lines)


def test_the_current_folder_and_files_are_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for where in (".", str(tmp_path), str(tmp_path.parent)):
        with (
            pytest.raises(OutputFolderError, match="is the current folder or holds it"),
            staged_output(where, command="evaluate"),
        ):
            pass
    (tmp_path / "a_file").write_text("x")
    with pytest.raises(OutputFolderError, match="is a file, not a folder"), staged_output("a_file", command="export"):
        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


# ----------------------------------------------------------------------------- the CLI
def test_sigterm_during_evaluate_is_exit_143_with_one_line(tmp_path, monkeypatch, capsys):
    from sb3_coma.app import evaluation as ev

    def killed(*args, **kwargs):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)

    out = tmp_path / "res"
    write_run(out, "evaluate", {"table.md": "old"})
    before = snapshot(out)
    monkeypatch.setattr(ev, "evaluate", killed)
    rc = cli.main(["evaluate", "--methods", "random", "--env", "env1", "--trials", "1", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 143, err
    assert err == [
        f"sb3-coma evaluate: stopped by SIGTERM: --out {out} was not written (its previous content is untouched)"
    ]
    assert snapshot(out) == before and siblings(out) == []


# ----------------------------------------------------------------------------- SIGKILL mid reproduce
def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["OMP_NUM_THREADS"] = "1"
    env["MKL_NUM_THREADS"] = "1"
    return env


def test_sigkill_mid_reproduce_leaves_the_previous_results_untouched(tmp_path):
    out = tmp_path / "res"
    write_run(out, "reproduce", {"table.md": "the finished run", "summary.json": '{"wall_s": 1}', "figures/x.png": "x"})
    write_run(out / "noise_sweep", "noise-sweep", {"noise_sweep.md": "sweep"})  # another command's output inside
    before = snapshot(out)
    command = [sys.executable, "-m", "sb3_coma.cli", "reproduce", "--quick", "--baselines-only", "--env", "env1"]
    command += ["--out", str(out), "--no-docs", "--no-plots", "--no-generalisation", "--no-ablation", "--no-costs"]
    command += ["--sweep-missions", "0", "--wide-trials", "0"]  # the paper protocol, then the unseen one
    log = (tmp_path / "reproduce.log").open("wb")
    proc = subprocess.Popen(command, cwd=tmp_path, env=_env(), stdout=log, stderr=subprocess.STDOUT)
    staging = out.with_name(f"res.partial-{proc.pid}")
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None and not (staging / "table.md").exists():
            time.sleep(0.005)
        assert proc.poll() is None, (
            f"reproduce ended before it could be killed:\n{(tmp_path / 'reproduce.log').read_text()}"
        )
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
    assert proc.returncode == -signal.SIGKILL
    assert snapshot(out) == before  # the old run, untouched: nothing of the killed one mixed in
    assert (staging / "table.md").exists()  # what the killed run had written stayed aside

    lines: list[str] = []  # the next run says so in one line and starts clean
    with staged_output(out, command="reproduce", say=lines.append) as stage:
        (stage / "table.md").write_text("the next run")
    assert lines == [f"removed {staging}: the unfinished output of an interrupted run (pid {proc.pid}); starting clean"]
    assert (out / "table.md").read_text() == "the next run" and (out / "noise_sweep" / "noise_sweep.md").exists()
    assert not (out / "summary.json").exists() and siblings(out) == ["reproduce.log"]


def test_full_disk_inside_a_staged_output_is_one_line_and_leaves_nothing(tmp_path):
    """ENOSPC while writing: DiskFullError (one line, exit 1 in the CLI), the staging folder is
    gone and the previous output untouched."""
    import errno

    from sb3_coma.app.outputs import staged_output
    from sb3_coma.common.checkpoints import DiskFullError

    target = tmp_path / "out"
    write_run(target, "evaluate", {"old.txt": "old"})  # 0.3.0: a folder without a manifest is refused up front
    with (
        pytest.raises(DiskFullError, match="disk is full") as info,
        staged_output(target, command="evaluate", say=lambda _: None) as staging,
    ):
        (staging / "table.csv").write_text("partial")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert "\n" not in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert (target / "old.txt").read_text() == "old" and not (target / "table.csv").exists()
