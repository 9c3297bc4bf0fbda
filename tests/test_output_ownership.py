"""What a staged output may touch (``sb3_coma.app.outputs.staged_output``, 0.3.0): only what an
sb3-coma run wrote.

* a folder next to ``--out`` that is merely *named* like a staging folder (no marker inside) is
  never deleted, even when it carries this process's pid;
* an ``--out`` holding files that no sb3-coma manifest lists is refused with one line before any
  work, and those files stay byte for byte (they used to be deleted when their names matched the
  command's file patterns);
* an ``--out`` that cannot be renamed (a mount point: ``EBUSY``/``EXDEV``, simulated) still ends
  with the results in place, entry by entry; when that fails too, the finished results stay in
  the staging folder, which the one-line error names and later runs never delete;
* run folders and outputs with a control character, no name of their own or a leading dot are
  refused, naming the value with ``repr()``.
"""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path

import pytest
from staging_helpers import dead_pid, siblings, snapshot, write_run

from sb3_coma import cli
from sb3_coma.app import outputs
from sb3_coma.app.config import TrainingError
from sb3_coma.app.outputs import OutputFolderError, manifest_name, staged_output
from sb3_coma.app.runs import check_run_dir, claim_run_dir

#: The patterns ``evaluate`` passes as ``own=`` (they used to decide what was deleted).
EVALUATE_PATTERNS = ("table.*", "per_step.csv", "planning_time.*", "curves_*.png", "mission_*", "training_reward.png")


def users_folder(folder: Path) -> None:
    """What a user keeps in a folder: a spreadsheet and a figure named like evaluate's, a runs/ tree."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "table.csv").write_text("my spreadsheet")
    (folder / "mission_plot.png").write_text("my figure")
    (folder / "runs" / "exp1").mkdir(parents=True)
    (folder / "runs" / "exp1" / "model.zip").write_text("my model")


# ----------------------------------------------------------------------------- look-alike folders
def test_a_folder_only_named_like_staging_survives(tmp_path):
    """Old code: ``out.partial-<dead pid>`` and ``out.old-<dead pid>`` were deleted by their names,
    and ``out.partial-<own pid>`` was emptied to make the staging folder."""
    target = tmp_path / "out"
    write_run(target, "evaluate", {"table.md": "old"})
    pid = dead_pid()
    lookalikes = [target.with_name(f"out.partial-{pid}"), target.with_name(f"out.old-{pid}")]
    lookalikes.append(target.with_name(f"out.partial-{os.getpid()}"))
    for folder in lookalikes:
        users_folder(folder)
    before = {folder.name: snapshot(folder) for folder in lookalikes}
    lines: list[str] = []
    with staged_output(target, command="evaluate", own=EVALUATE_PATTERNS, say=lines.append) as stage:
        assert stage not in lookalikes
        (stage / "table.md").write_text("new")
    assert (target / "table.md").read_text() == "new"
    assert {folder.name: snapshot(folder) for folder in lookalikes} == before
    assert sorted(siblings(target)) == sorted(folder.name for folder in lookalikes)
    assert len(lines) == 3 and all(line.startswith("left ") and "did not mark it" in line for line in lines)


# ----------------------------------------------------------------------------- foreign files in --out
@pytest.mark.parametrize("with_manifest", [False, True], ids=["no-manifest", "manifest-of-evaluate"])
def test_files_the_command_did_not_write_are_refused_up_front_and_survive(tmp_path, with_manifest):
    """Old code: without a manifest the user's ``table.csv`` and ``mission_plot.png`` matched
    evaluate's patterns and were deleted; with one, the command ran and mixed them in."""
    target = tmp_path / "out"
    if with_manifest:
        write_run(target, "evaluate", {"table.md": "evaluate's"})
    users_folder(target)
    before = snapshot(target)
    worked = False
    with (
        pytest.raises(OutputFolderError) as info,
        staged_output(target, command="evaluate", own=EVALUATE_PATTERNS, say=pytest.fail),
    ):
        worked = True  # never: the refusal comes before the work
    message = str(info.value)
    assert not worked and "\n" not in message
    assert message.startswith(f"--out {target} is not empty") and "pass an empty or new folder" in message
    assert "'table.csv'" in message and "'runs'" in message
    assert snapshot(target) == before and siblings(target) == []


def test_evaluate_into_a_users_folder_is_one_line_before_any_mission(tmp_path, monkeypatch, capsys):
    from sb3_coma.app import evaluation as ev

    def never(*args, **kwargs):
        raise AssertionError("no mission is flown for a refused --out")

    out = tmp_path / "res"
    users_folder(out)
    before = snapshot(out)
    monkeypatch.setattr(ev, "evaluate", never)
    rc = cli.main(["evaluate", "--methods", "random", "--env", "env1", "--trials", "1", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"sb3-coma evaluate: error: --out {out} is not empty") and "empty or new folder" in err[0]
    assert snapshot(out) == before and siblings(out) == []


def test_an_output_of_sb3_coma_inside_out_counts_as_sb3_comas(tmp_path):
    """``noise-sweep --out results/sweep`` inside ``reproduce --out results``: rerunning either is
    allowed, and the other's output is kept."""
    target = tmp_path / "results"
    write_run(target, "reproduce", {"table.md": "old", "figures/a.png": "png"})
    write_run(target / "sweep", "noise-sweep", {"noise_sweep.md": "sweep"})
    with staged_output(target, command="reproduce") as stage:
        (stage / "table.md").write_text("new")
    assert (target / "table.md").read_text() == "new" and not (target / "figures").exists()
    assert (target / "sweep" / "noise_sweep.md").read_text() == "sweep"
    (target / "sweep" / "mine.txt").write_text("the user's")  # now the folder inside is not all sb3-coma's
    with pytest.raises(OutputFolderError, match="'sweep'"), staged_output(target, command="reproduce"):
        pytest.fail("refused before the work starts")


# ----------------------------------------------------------------------------- --out is a mount point
def immovable(monkeypatch, target: Path, code: int, exchange: bool) -> None:
    """Make ``target`` behave like a mount point: it cannot be renamed nor exchanged (``code``).
    ``exchange=False``: a system without ``renameat2``, so the rename aside is what fails."""
    real = os.path.realpath(target)
    rename = os.rename

    def no_exchange(a, b):
        if not exchange:
            return False
        raise OSError(code, os.strerror(code), str(b))

    def guarded_rename(src, dst, *args, **kwargs):
        if os.path.realpath(src) == real:
            raise OSError(code, os.strerror(code), str(src))
        return rename(src, dst, *args, **kwargs)

    monkeypatch.setattr(outputs, "_exchange", no_exchange)
    monkeypatch.setattr(os, "rename", guarded_rename)


@pytest.mark.parametrize(
    ("code", "exchange"),
    [(errno.EBUSY, True), (errno.EXDEV, True), (errno.EBUSY, False)],
    ids=["busy", "xdev", "aside"],
)
def test_a_mount_point_out_ends_with_the_results_in_place(tmp_path, monkeypatch, code, exchange):
    """Old code: the swap raised after all the work and the staging folder was deleted with it."""
    target = tmp_path / "volume"
    write_run(target, "reproduce", {"table.md": "old", "figures/a.png": "old png", "summary.json": "{}"})
    write_run(target, "noise-sweep", {"noise_sweep.md": "another command's"})
    immovable(monkeypatch, target, code, exchange)
    with staged_output(target, command="reproduce") as stage:
        (stage / "table.md").write_text("new")
        (stage / "figures").mkdir()
        (stage / "figures" / "b.png").write_text("new png")
        (stage / "runs" / "env1").mkdir(parents=True)
        (stage / "runs" / "env1" / "model.zip").write_text("the trained model")
    assert (target / "table.md").read_text() == "new"
    assert sorted(p.name for p in (target / "figures").iterdir()) == ["b.png"]
    assert (target / "runs" / "env1" / "model.zip").read_text() == "the trained model"
    assert not (target / "summary.json").exists()  # the command's own old entry, gone
    assert (target / "noise_sweep.md").read_text() == "another command's"
    manifest = json.loads((target / manifest_name("reproduce")).read_text())
    assert manifest["complete"] is True and manifest["entries"] == ["figures", "runs", "table.md"]
    names = sorted(p.name for p in target.iterdir())
    assert names == sorted(
        [manifest_name("noise-sweep"), manifest_name("reproduce"), "figures", "noise_sweep.md", "runs", "table.md"]
    )
    assert siblings(target) == []


def test_a_failed_commit_keeps_the_finished_results_and_names_them(tmp_path, monkeypatch):
    """The entry-by-entry fallback fails too: one line saying where the results are; the staging
    folder is kept, a later run leaves it alone (one line) and moves it in once --out is gone.
    Old code: a traceback, and the trained model deleted with every result."""
    target = tmp_path / "volume"
    write_run(target, "reproduce", {"table.md": "old"})
    write_run(target, "export", {"actor.onnx": "export's"})
    before = snapshot(target)
    immovable(monkeypatch, target, errno.EBUSY, exchange=True)
    replace = os.replace

    def broken_replace(src, dst, *args, **kwargs):
        if os.path.dirname(os.path.realpath(dst)) == os.path.realpath(target):
            raise OSError(errno.EIO, os.strerror(errno.EIO), str(dst))
        return replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OutputFolderError) as info, staged_output(target, command="reproduce") as stage:
        (stage / "table.md").write_text("new")
        (stage / "runs").mkdir()
        (stage / "runs" / "model.zip").write_text("the trained model")
    message = str(info.value)
    assert "\n" not in message and message.endswith(f"the finished results are kept in {stage}")
    assert message.startswith(f"--out {target} could not be put in place")
    assert stage.is_dir() and (stage / "runs" / "model.zip").read_text() == "the trained model"
    assert (stage / "table.md").read_text() == "new" and not (stage / "actor.onnx").exists()
    assert json.loads((stage / manifest_name("reproduce")).read_text())["complete"] is True
    assert {k: v for k, v in snapshot(target).items() if not k.endswith(".tmp")} == before
    monkeypatch.undo()

    lines: list[str] = []  # the next run does not delete the finished results
    with pytest.raises(RuntimeError), staged_output(target, command="reproduce", say=lines.append):
        raise RuntimeError("a run that fails")
    assert lines == [
        f"left {stage} as it is: it holds the finished output of an earlier run that was not put into {target}"
    ]
    assert (stage / "runs" / "model.zip").read_text() == "the trained model"

    target.rename(tmp_path / "moved_away")  # once --out is missing, they are moved in
    with pytest.raises(RuntimeError), staged_output(target, command="reproduce", say=lines.append):
        raise RuntimeError("fails again")
    assert (target / "runs" / "model.zip").read_text() == "the trained model"
    assert siblings(target) == ["moved_away"] and not (target / outputs.STAGING_MARKER).exists()


def test_a_disk_full_commit_keeps_the_results_with_one_line(tmp_path, monkeypatch):
    from sb3_coma.common.checkpoints import DiskFullError

    target = tmp_path / "out"
    write_run(target, "evaluate", {"table.md": "old"})

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(outputs, "_exchange", full)
    with pytest.raises(DiskFullError) as info, staged_output(target, command="evaluate") as stage:
        (stage / "table.md").write_text("new")
    assert "\n" not in str(info.value) and str(info.value).startswith("the disk is full")
    assert str(stage) in str(info.value) and (stage / "table.md").read_text() == "new"
    assert (target / "table.md").read_text() == "old"


# ----------------------------------------------------------------------------- names
BAD_NAMES = ["runs/a\nb", "runs/a\tb", "runs/\x1bx", ".", "..", "runs/..", "runs/.hidden", ".hidden"]


@pytest.mark.parametrize("name", BAD_NAMES)
def test_bad_run_folder_names_are_refused_naming_the_value(tmp_path, monkeypatch, name):
    """Old code: ``--run-dir .`` trained into a hidden ``._2``, a newline made a folder nobody can type."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(TrainingError) as info:
        check_run_dir(name)
    assert str(info.value).startswith(f"run folder {name!r} ") and "\n" not in str(info.value)
    with pytest.raises(TrainingError):
        claim_run_dir(name, "UavIpp-Env1-v0")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["res\nults", "a\tb/out", ".results", "sub/.results"])
def test_bad_out_names_are_refused_naming_the_value(tmp_path, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OutputFolderError) as info, staged_output(name, command="evaluate"):
        pytest.fail("refused before the work starts")
    assert str(info.value).startswith(f"--out {name!r} ") and "\n" not in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_plain_names_are_accepted(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("runs/my-run", "runs/a.b", "runs/./x", "results/run1/"):
        check_run_dir(name)
    assert outputs.folder_name_problem("results/run.1") is None


def test_a_second_writer_of_one_out_is_refused_up_front(tmp_path: Path) -> None:
    """One writer per --out (#36): a command whose --out another process is writing stops before
    any work, naming that process; the first one's results land untouched."""
    import subprocess
    import sys
    import textwrap

    target = tmp_path / "results"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(
                f"""
                import sys
                from sb3_coma.app.outputs import staged_output
                with staged_output({str(target)!r}, command="evaluate") as out:
                    (out / "table.md").write_text("first")
                    print("ready", flush=True)
                    sys.stdin.readline()
                """
            ),
        ],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "ready"
        refused = rf"--out .*results is being written by pid {holder.pid}"
        with pytest.raises(OutputFolderError, match=refused), staged_output(target, command="evaluate") as out:
            (out / "table.md").write_text("second")
    finally:
        assert holder.stdin is not None
        holder.stdin.write("\n")
        holder.stdin.close()
        holder.wait(timeout=60)
    assert holder.returncode == 0
    assert (target / "table.md").read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]  # the lock file went with its writer
    with staged_output(target, command="evaluate") as out:  # free again
        (out / "table.md").write_text("third")
    assert (target / "table.md").read_text() == "third"
