"""Issue 23 on the analysis commands' outputs: every path that cannot be written is a usage
error naming it and why, before any computing, and what is written is reported by its real
name."""

from __future__ import annotations

import importlib
import os
import subprocess
from pathlib import Path

import pytest

COMMANDS = {
    "analysis.curves": ("--out", ["RUNS"]),
    "analysis.success_map": ("--out", ["RUNS"]),
    "analysis.region_volumes": ("--plot", ["--regions", "farbox", "--joints", "3",
                                           "--samples", "1000"]),
}
"""The commands that write a figure (and data files beside it): the flag naming it, and
arguments that would otherwise run (RUNS: a folder, never read when the output is refused)."""


def usage_error(capsys, module: str, args: list[str]) -> str:
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit) as exit_:
        main(args)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return err


def command(module: str, out: Path, tmp_path: Path) -> list[str]:
    flag, args = COMMANDS[module]
    return [str(tmp_path) if a == "RUNS" else a for a in args] + [flag, str(out)]


@pytest.mark.parametrize("module", sorted(COMMANDS))
def test_a_figure_path_that_is_a_folder_is_refused_not_written_beside(tmp_path, capsys,
                                                                      module):
    folder = tmp_path / "figs"
    folder.mkdir()
    err = usage_error(capsys, module, command(module, folder, tmp_path))
    assert f"{folder} is a folder; give a figure file, e.g. {folder / 'figure.png'}" in err
    assert not (tmp_path / "figs.png").exists()


@pytest.mark.parametrize("module", sorted(COMMANDS))
def test_a_figure_suffix_matplotlib_cannot_write_is_refused_up_front(tmp_path, capsys,
                                                                     module):
    err = usage_error(capsys, module, command(module, tmp_path / "fig.xyz", tmp_path))
    assert "matplotlib cannot write '.xyz' files; use one of" in err and ".png" in err


@pytest.mark.parametrize("module", sorted(COMMANDS))
def test_a_figure_under_a_file_is_refused_up_front(tmp_path, capsys, module):
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    err = usage_error(capsys, module, command(module, blocker / "fig.png", tmp_path))
    assert f"{blocker / 'fig.png'}: {blocker} is a file, not a folder" in err


@pytest.mark.parametrize("module", sorted(COMMANDS))
def test_a_figure_on_a_read_only_file_system_is_refused_up_front(tmp_path, capsys, module):
    point = tmp_path / "ro"
    point.mkdir()
    if os.geteuid() != 0:
        pytest.skip("a read-only file system needs a mount, which needs root")
    try:
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k,ro", "tmpfs", str(point)],
                       check=True, capture_output=True, timeout=30)
    except (OSError, subprocess.CalledProcessError) as err:
        pytest.skip(f"cannot mount a tmpfs here ({err})")
    try:
        err = usage_error(capsys, module, command(module, point / "fig.png", tmp_path))
        assert f"cannot write in {point} (a read-only file system)" in err
    finally:
        subprocess.run(["umount", str(point)], capture_output=True, timeout=30)


def test_a_figure_path_without_suffix_is_written_and_reported_as_png(tmp_path, capsys):
    """It was written as fig.png and reported as fig."""
    from test_run_faults import CLI

    from analysis.curves import main as curves
    from ddpg_her.train import main as train

    run = tmp_path / "runs" / "run"
    assert train([*CLI, "--episodes", "2", "--out", str(run)]) == 0
    capsys.readouterr()
    assert curves([str(tmp_path / "runs"), "--out", str(tmp_path / "fig")]) == 0
    assert f"-> {tmp_path / 'fig.png'} and {tmp_path / 'fig.csv'}" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.csv", "fig.png", "runs"]


@pytest.mark.parametrize("where", ["a file", "under a file"])
def test_optimality_out_that_cannot_be_a_folder_is_refused_up_front(tmp_path, capsys, where):
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    out = blocker if where == "a file" else blocker / "out"
    err = usage_error(capsys, "analysis.optimality",
                      ["--settings", "zheight:3", "--goals", "5", "--out", str(out)])
    assert str(blocker) in err and ("is a file" in err), err


def test_a_voxel_resolution_that_cannot_fit_is_refused_up_front(capsys):
    """--resolution 1e-5 sampled the workspace, then failed allocating 2.4 PiB."""
    err = usage_error(capsys, "analysis.region_volumes",
                      ["--regions", "farbox", "--joints", "3", "--samples", "1000",
                       "--resolution", "0.00001"])
    assert "--resolution 1e-05 m: the workspace's voxel grids would need about" in err
    assert "GiB of memory available" in err


# --- issue 37, kind 3: outputs checked before work, written by the one atomic writer ---------

@pytest.mark.parametrize("module, args", [
    ("analysis.sweep", ["--setting", "farbox:3", "--episodes", "200", "--seeds", "1"]),
    ("analysis.sensitivity", ["--setting", "farbox:3", "--readings", "ours"]),
    ("analysis.algorithms", ["--setting", "farbox:3", "--algos", "td3"]),
])
def test_a_study_root_under_a_file_is_refused_before_any_unit_starts(tmp_path, capsys, module,
                                                                     args):
    """The root went to RunFolder and mkdir as a NotADirectoryError traceback."""
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    err = usage_error(capsys, module, [*args, "--out", str(blocker / "runs")])
    assert f"--out {blocker / 'runs' / 'logs'}: {blocker} is a file, not a folder" in err


def test_sensitivity_collect_and_report_check_their_folders_up_front(tmp_path, capsys):
    from analysis import sensitivity

    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    err = usage_error(capsys, "analysis.sensitivity",
                      ["--setting", "farbox:3", "--readings", "ours", "--out",
                       str(tmp_path / "runs"), "--collect", str(blocker / "c")])
    assert f"--collect {blocker / 'c' / 'runs'}: {blocker} is a file" in err
    with pytest.raises(SystemExit) as exit_:
        sensitivity.main(["report", str(tmp_path), "--out", str(blocker / "r")])
    assert exit_.value.code == 2
    assert f"--out {blocker / 'r'}: {blocker} is a file" in capsys.readouterr().err


def test_every_output_goes_through_the_one_atomic_writer(tmp_path, monkeypatch):
    """analysis.outputs writes by ddpg_her.runfolder.atomic_write (fsync, then a move), and a
    write that fails keeps the old file and leaves no temporary file, Ctrl-C included."""
    import errno

    from analysis import outputs
    from ddpg_her import runfolder

    calls = []
    real = runfolder.atomic_write
    monkeypatch.setattr(runfolder, "atomic_write", lambda p, d: (calls.append(p), real(p, d)))
    target = tmp_path / "report.md"
    outputs.write_text(target, "old")
    assert calls == [target] and target.read_text() == "old"

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(runfolder.os, "fsync", full)
    with pytest.raises(outputs.OutputError, match="No space left on device"):
        outputs.write_text(target, "new")
    assert target.read_text() == "old" and sorted(tmp_path.iterdir()) == [target]

    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(runfolder.os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        runfolder.atomic_write(target, b"new")
    assert target.read_text() == "old" and sorted(tmp_path.iterdir()) == [target]


def test_report_checks_its_out_before_reading_any_run(tmp_path, capsys):
    """analysis.report read every run first and then sent an --out under a file to mkdir's
    traceback; with no runs it said only that there were none."""
    blocker = tmp_path / "blocker"
    blocker.write_text("x")
    for root in (tmp_path / "no-runs-here", tmp_path):
        err = usage_error(capsys, "analysis.report", [str(root), "--out", str(blocker / "r.md")])
        assert f"--out {blocker / 'r.md'}: {blocker} is a file, not a folder" in err, err
    err = usage_error(capsys, "analysis.report", [str(tmp_path), "--out", str(tmp_path)])
    assert f"--out {tmp_path} is a folder, expected a file" in err


def test_report_on_a_full_disk_keeps_the_previous_report(tmp_path, capsys, monkeypatch):
    """analysis.report wrote with Path.write_text: a full disk left the report cut short."""
    import errno

    from test_analysis import _fake_run

    from analysis import report
    from ddpg_her import runfolder

    _fake_run(tmp_path / "runs" / "farbox-j3" / "s0", "farbox", 3, 0, [40, 60])
    out = tmp_path / "out" / "report.md"
    assert report.main([str(tmp_path / "runs"), "--out", str(out)]) == 0
    previous = out.read_text()
    assert "farbox" in previous and previous == capsys.readouterr().out

    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(runfolder.os, "fsync", full)
    _fake_run(tmp_path / "runs" / "farbox-j3" / "s1", "farbox", 3, 1, [50, 70])
    with pytest.raises(SystemExit) as exit_:
        report.main([str(tmp_path / "runs"), "--out", str(out), "--force"])
    assert exit_.value.code == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and str(out) in err and "No space left on device" in err
    assert out.read_text() == previous
    assert sorted(p.name for p in out.parent.iterdir()) == ["report.md"]


def test_a_plan_file_is_written_whole(tmp_path, monkeypatch):
    from ddpg_her import runfolder, units

    calls = []
    real = runfolder.atomic_write
    monkeypatch.setattr(runfolder, "atomic_write", lambda p, d: (calls.append(p), real(p, d)))
    units.write_plan(tmp_path / "logs" / "plan.json", [["--region", "farbox"]])
    assert calls == [tmp_path / "logs" / "plan.json"]
    assert units.read_plan(tmp_path / "logs" / "plan.json") == [["--region", "farbox"]]


@pytest.mark.parametrize("command, out", [("report", "report.md"), ("curves", "curves.png")])
def test_a_writer_replaces_another_output_only_with_force(tmp_path, capsys, command, out):
    """Issue 41: the same output again is written (nothing changes); a different one (a run
    added) is refused naming the file, exit 2, nothing written; --force replaces it."""
    import importlib

    from test_analysis import _fake_run

    main = importlib.import_module(f"analysis.{command}").main
    runs, out = tmp_path / "runs", tmp_path / "out" / out
    _fake_run(runs / "farbox-j3" / "s0", "farbox", 3, 0, [40, 60])
    assert main([str(runs), "--out", str(out)]) == 0
    first = out.read_bytes()
    assert main([str(runs), "--out", str(out)]) == 0 and out.read_bytes() == first
    _fake_run(runs / "farbox-j3" / "s1", "farbox", 3, 1, [50, 70])
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        main([str(runs), "--out", str(out)])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "would replace" in err and str(out) in err, err
    assert "give --force" in err and out.read_bytes() == first
    assert main([str(runs), "--out", str(out), "--force"]) == 0 and out.read_bytes() != first


@pytest.mark.parametrize("failure", [OSError(28, "No space left on device"), KeyboardInterrupt()])
def test_a_write_failing_halfway_puts_back_the_files_written_before_it(
        tmp_path, capsys, monkeypatch, failure):
    """curves' figure was replaced and its CSV kept when the CSV's write failed (a full disk,
    Ctrl-C): a figure and a table of different runs. Now both stay as they were."""
    from test_analysis import _fake_run

    from analysis import curves
    from ddpg_her import runfolder

    runs, out = tmp_path / "runs", tmp_path / "out" / "c.png"
    _fake_run(runs / "farbox-j3" / "s0", "farbox", 3, 0, [40, 60])
    assert curves.main([str(runs), "--out", str(out)]) == 0
    before = {p: p.read_bytes() for p in out.parent.iterdir()}
    _fake_run(runs / "farbox-j3" / "s1", "farbox", 3, 1, [50, 70])
    real = runfolder.atomic_write

    def failing(path, data):
        if path.suffix == ".csv":
            raise runfolder.write_failure(path, failure) if isinstance(failure, OSError) \
                else failure
        real(path, data)

    monkeypatch.setattr(runfolder, "atomic_write", failing)
    capsys.readouterr()
    with pytest.raises((SystemExit, KeyboardInterrupt)) as exc:
        curves.main([str(runs), "--out", str(out), "--force"])
    assert {p: p.read_bytes() for p in out.parent.iterdir()} == before
    if isinstance(failure, OSError):
        err = capsys.readouterr().err
        assert exc.value.code == 1 and "No space left" in err and err.count("\n") == 1, err


def test_an_output_that_cannot_be_read_is_one_line(tmp_path, capsys, monkeypatch):
    """The replace check reads the file there to compare it: an unreadable one (another user's,
    mode 600) was a PermissionError traceback; now one line naming it, nothing written."""
    import errno
    import pathlib

    from test_analysis import _fake_run

    from analysis import report

    _fake_run(tmp_path / "runs" / "farbox-j3" / "s0", "farbox", 3, 0, [40, 60])
    out = tmp_path / "report.md"
    out.write_text("another user's report\n")
    real = pathlib.Path.read_bytes

    def unreadable(self):
        if self == out:
            raise PermissionError(errno.EACCES, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(pathlib.Path, "read_bytes", unreadable)
    with pytest.raises(SystemExit) as exc:
        report.main([str(tmp_path / "runs"), "--out", str(out)])
    err = capsys.readouterr().err
    assert exc.value.code == 1 and str(out) in err and "Permission denied" in err, err
    assert "Traceback" not in err and out.read_text() == "another user's report\n"
