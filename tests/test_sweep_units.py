"""Issue 23 on the studies that train units (analysis.sweep, and analysis.sensitivity through
the same helpers): a dry run refuses what a real run could not start, and the progress bar
never ends at 100 % over a failed unit."""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis import sweep


@pytest.mark.parametrize("settings, extra, message", [
    (["nosuch:3"], [], "nosuch-j3: region 'nosuch': cannot read region 'nosuch'"),
    (["farbox:3"], ["--bogus"], "farbox-j3: ddpg_her.train refuses its command line: "
                                "python -m ddpg_her.train: error: unrecognized arguments: "
                                "--bogus"),
    (["farbox:3"], ["--gamma", "nan"], "farbox-j3: invalid agent configuration: gamma=nan"),
    (["farbox:3", "farbox:3"], [], "farbox-j3 s0, farbox-j3 s0 would all train in"),
])
def test_a_dry_run_refuses_units_that_could_not_start(tmp_path, capsys, settings, extra,
                                                      message):
    args = [a for s in settings for a in ("--setting", s)]
    with pytest.raises(SystemExit) as exit_:
        sweep.main([*args, "--episodes", "200", "--seeds", "1", "--out", str(tmp_path),
                    "--dry-run", *(["--", *extra] if extra else [])])
    assert exit_.value.code == 2
    out = capsys.readouterr()
    assert message in out.err and "nothing was started" in out.err, out.err
    assert out.out == ""


def test_a_dry_run_of_good_units_lists_them(tmp_path, capsys):
    assert sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "2", "--out",
                       str(tmp_path), "--dry-run"]) == 0
    assert [line.split()[0] for line in capsys.readouterr().out.splitlines()] == ["new"] * 2


def test_the_progress_bar_does_not_end_at_100_percent_over_a_failed_unit(tmp_path: Path):
    ok = sweep.Unit("farbox", 3, (0, 1), tmp_path / "a", 10)
    bad = sweep.Unit("zheight", 3, (0, 1), tmp_path / "b", 10)
    bar = sweep.EpisodeBar([ok, bad], "training")
    try:
        bar.end(ok)
        bar.end(bad, failed=True)
        assert bar.bar.n == ok.episodes_total < bar.bar.total
        assert "2/2 units, 1 FAILED" in bar.bar.postfix
    finally:
        bar.close()


def test_train_many_refuses_two_runs_on_one_folder_before_anything_starts(tmp_path):
    from cli_tools import run_module

    folder = tmp_path / "one"
    for extra in (["--dry-run"], []):
        proc = run_module("ddpg_her.train_many",
                          f"--unit=--region farbox --seeds 0 --episodes 100 --out {folder}",
                          f"--unit=--region zheight --seeds 0 --episodes 100 --out {folder}",
                          *extra, check=False, timeout=120)
        assert proc.returncode == 2, proc.stderr
        assert f"two runs would write one run folder {folder}" in proc.stderr
        assert not folder.exists()
