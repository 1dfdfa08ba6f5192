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


def test_the_progress_bar_of_a_resumed_sweep_starts_at_the_episodes_already_done(tmp_path):
    """A sweep resumed to a larger budget shows its finished episodes at once, and its rate and
    time left count only what this process trains (tqdm's ``initial``), not those episodes."""
    import shutil

    run = Path(__file__).parents[1] / "results/paper_long/runs/unconstrained-j3/s0"
    unit = sweep.Unit("unconstrained", 3, (0,), tmp_path, 100_000)
    shutil.copytree(run, unit.run_dir(0))
    done = unit.episodes_done()
    assert done >= 1000  # the committed run's episodes, whatever stage it is at
    bar = sweep.EpisodeBar([unit], "training")
    try:
        assert bar.bar.initial == bar.bar.n == done
        assert bar.bar.format_dict["rate"] is None  # nothing trained yet: no rate
        assert f"{done}/100000" in str(bar.bar)
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


def test_the_projection_of_a_trainer_whose_clock_is_linear_is_exact():
    """A run whose clock is start-up + t per episode + s per test session (one every 100):
    its first two eval rows project its wall time at every budget exactly."""
    start, per_episode, per_session, every = 7.0, 0.25, 3.0, 100

    def wall(episode: int) -> float:
        return start + per_episode * episode + per_session * (episode // every)

    rows = [(every, wall(every)), (2 * every, wall(2 * every))]
    for budget in (200, 1_000, 20_000):
        assert sweep.projected_seconds(rows, every, budget) == pytest.approx(wall(budget))
    for bad in ([rows[0]], [rows[1], rows[0]], [(every, 5.0), (2 * every, 4.0)]):
        with pytest.raises(ValueError, match="eval rows at episodes 100 and 200"):
            sweep.projected_seconds(bad, every, 1_000)


def test_makespan_is_the_order_of_run_local_on_its_workers():
    assert sweep.makespan([3, 3, 2, 2, 2], 2) == 7  # 3|3, then 2->5, 2->5, 2->7
    assert sweep.makespan([5, 1, 1, 1], 2) == 5
    assert sweep.makespan([4, 2, 1], 1) == 7
    assert sweep.makespan([4, 2, 1], 8) == 4
    assert sweep.makespan([], 3) == 0.0


TINY = ["--", "--eval-every", "2", "--eval-episodes", "2", "--warmup-episodes", "1",
        "--hidden-sizes", "8", "8", "--updates-per-episode", "2", "--batch-size", "16"]


def test_a_projection_times_the_real_command_and_leaves_nothing_behind(tmp_path, capsys,
                                                                        monkeypatch):
    import tempfile

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    out = tmp_path / "runs"
    args = ["--setting", "farbox:3", "--episodes", "20", "--seeds", "1", "--out", str(out),
            "--threads", "1"]
    assert sweep.main([*args, "--dry-run", "--project", *TINY]) == 0
    printed = capsys.readouterr()
    line = next(s for s in printed.out.splitlines() if s.startswith("projected wall time:"))
    assert float(line.split()[3]) > 0
    assert "first 4 episodes of each" in line
    assert "farbox-j3" in printed.err and "20 episodes left" in printed.err
    assert not out.exists() and list(scratch.iterdir()) == []
    assert sweep.main([*args, *TINY]) == 0  # the real run, then nothing is left to project
    capsys.readouterr()
    assert sweep.main([*args, "--dry-run", "--project", *TINY]) == 0
    assert "every unit has finished" in capsys.readouterr().err


@pytest.mark.parametrize("flags, message", [
    (["--project"], "--project is part of a dry run: add --dry-run"),
    (["--project", "--dry-run", "--ray-address", "local"], "not on a Ray cluster"),
])
def test_a_projection_is_refused_where_it_cannot_time_the_run(tmp_path, capsys, flags,
                                                             message):
    with pytest.raises(SystemExit) as exit_:
        sweep.main(["--setting", "farbox:3", "--out", str(tmp_path), *flags])
    assert exit_.value.code == 2 and message in capsys.readouterr().err
