"""Issue 23 on the studies that train units (analysis.sweep, and analysis.sensitivity through
the same helpers): a dry run refuses what a real run could not start, and the progress bar
never ends at 100 % over a failed unit."""

from __future__ import annotations

from pathlib import Path

import pytest

from analysis import sweep


@pytest.mark.parametrize("settings, extra, message", [
    (["nosuch:3"], [], "nosuch-j3: cannot read region 'nosuch'"),
    (["farbox:3"], ["--bogus"], "farbox-j3: ddpg_her.train refuses its command line: "
                                "python -m ddpg_her.train: error: unrecognized arguments: "
                                "--bogus"),
    (["farbox:3"], ["--gamma", "nan"], "farbox-j3: invalid agent configuration: gamma=nan"),
    (["farbox:3", "farbox:3"], [], "farbox-j3 s0 and farbox-j3 s0 would all train in"),
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
        assert ("region=farbox, n_joints=3 seed=0 and region=zheight, n_joints=3 seed=0 would "
                f"all train in {folder.resolve()}; give each unit its own --out") in proc.stderr
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


def test_the_quick_model_is_exact_for_a_trainer_whose_clock_is_linear():
    """A process whose clock is r per rollout (an episode of its agents, training or test) and
    u per update: the two rows of the quick projection's timed process give back r and u, and
    the model then gives the trainer's wall time at any budget and start, exactly (the same
    reference clock as the test above, written out episode by episode)."""
    r, u, start = 0.8, 0.01, 5.0

    def wall(episodes, warmup, every, tests, updates, done=0):
        return sum(r + (updates * u if e >= warmup else 0.0) + (tests * r if (e + 1) % every == 0
                   else 0.0) for e in range(done, episodes))

    rows = [wall(1, 1, 1, 1, sweep.QUICK_UPDATES), wall(2, 1, 1, 1, sweep.QUICK_UPDATES)]
    costs = sweep.EpisodeCosts.of_rows(rows, start)
    assert (costs.rollout, costs.update) == (pytest.approx(r), pytest.approx(u))
    from ddpg_her import AgentConfig

    for episodes, warmup, every, tests, updates, done in [(20_000, 100, 100, 100, 100, 0),
                                                          (3_000, 0, 50, 10, 40, 0),
                                                          (1_000, 100, 100, 100, 100, 400),
                                                          (1_000, 100, 100, 100, 100, 50)]:
        config = AgentConfig(episodes=episodes, warmup_episodes=warmup, eval_every=every,
                             eval_episodes=tests, updates_per_episode=updates)
        assert costs.seconds(config, done) == pytest.approx(
            wall(episodes, warmup, every, tests, updates, done))


def test_the_quick_projection_times_its_layouts_one_at_a_time(tmp_path, capsys, monkeypatch):
    """With --workers 2, the 2 timed episodes of a layout ran beside the next layout's start-up
    and the last layout ran alone, so the quick model priced a 6-joint unit below a 3-joint one
    (9,034 s against 15,996 s at 3,000 episodes): each layout is timed alone, and only the
    projection of the real run is scheduled on the workers."""
    import subprocess
    import sys
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    started: list[subprocess.Popen] = []
    overlaps: list[int] = []

    def fake_start(command, log_path, threads, cwd=None):  # 2 eval rows, 1 s and 3 s of clock
        out, seeds = command[command.index("--out") + 1], command[command.index("--seeds") + 1]
        rows = "episode,successes,tests,mean_return,mean_final_distance_m,env_steps,wall_s\n" \
               "1,0,1,-1.0,0.5,100,1.0\n2,0,1,-1.0,0.5,200,3.0\n"
        script = (f"import pathlib, time; time.sleep(0.3); p = pathlib.Path({out!r}.format("
                  f"seed={seeds})); p.mkdir(parents=True); (p / 'eval.csv').write_text({rows!r})")
        overlaps.append(sum(p.poll() is None for p in started))
        started.append(subprocess.Popen([sys.executable, "-c", script]))
        Path(log_path).parent.mkdir(parents=True, exist_ok=True)
        return started[-1], open(log_path, "a")  # run_local closes it

    monkeypatch.setattr(sweep, "start_unit", fake_start)
    assert sweep.main(["--setting", "farbox:3", "--setting", "farbox:6", "--episodes", "200",
                       "--seeds", "1", "--out", str(tmp_path / "runs"), "--workers", "2",
                       "--dry-run", "--project"]) == 0
    assert overlaps == [0, 0]
    printed = capsys.readouterr()
    # rollout 0.5 s, update (3 - 2) / 25 s: 200 + 2 x 100 rollouts + 100 x 100 updates per unit
    seconds = 400 * 0.5 + 100 * 100 * 1.0 / sweep.QUICK_UPDATES
    assert printed.err.count(f"{seconds:10.0f} s of training") == 2
    total = float(next(s for s in printed.out.splitlines()
                       if s.startswith("projected wall time:")).split()[3])
    assert seconds <= total < 1.5 * seconds  # the two units side by side on the 2 workers


def test_a_killed_projections_folder_is_deleted_by_the_next(tmp_path, monkeypatch):
    import subprocess
    import sys
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    ended = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                           capture_output=True, text=True, check=True).stdout.strip()
    dead = tmp_path / f"{sweep.PROJECTION_PREFIX}{ended}-abc"
    live = tmp_path / f"{sweep.PROJECTION_PREFIX}1-abc"  # init's: alive
    for folder in (dead, live):
        (folder / "unit0").mkdir(parents=True)
    mine = sweep.projection_folder()
    assert not dead.exists() and live.exists() and mine.exists()


def test_a_projection_times_the_real_command_and_leaves_nothing_behind(tmp_path, capsys,
                                                                        monkeypatch):
    import tempfile

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    out = tmp_path / "runs"
    args = ["--setting", "farbox:3", "--episodes", "20", "--seeds", "1", "--out", str(out),
            "--threads", "1"]
    assert sweep.main([*args, "--dry-run", "--project", *TINY]) == 0  # quick
    printed = capsys.readouterr()
    line = next(s for s in printed.out.splitlines() if s.startswith("projected wall time:"))
    assert float(line.split()[3]) > 0 and "to 20 episodes" in line
    assert "timed on 2 episodes of each of 1 process layout(s)" in line
    assert "farbox-j3" in printed.err and "20 episodes left" in printed.err
    assert "(full)" not in printed.out
    assert not out.exists() and list(scratch.iterdir()) == []
    assert sweep.main([*args, "--dry-run", "--project", "full", *TINY]) == 0
    printed = capsys.readouterr()
    line = next(s for s in printed.out.splitlines() if s.startswith("projected wall time (f"))
    assert float(line.split()[4]) > 0 and "first 4 episodes of each" in line
    assert "training the first 2 test intervals of each of 1 unit(s) costs about" in printed.err
    assert not out.exists() and list(scratch.iterdir()) == []
    assert sweep.main([*args, *TINY]) == 0  # the real run, then nothing is left to project
    capsys.readouterr()
    assert sweep.main([*args, "--dry-run", "--project", *TINY]) == 0
    assert "every unit has finished" in capsys.readouterr().err


def test_a_projection_that_cannot_start_says_why(tmp_path, capsys, monkeypatch):
    """Without a GPU, --device cuda: the process's own refusal, not a path to a deleted log."""
    import tempfile

    import torch

    if torch.cuda.is_available():
        pytest.skip("a CUDA device is here: the projection would run")
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    with pytest.raises(SystemExit, match=r"failed .each process's last line above"):
        sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "1", "--out",
                    str(tmp_path / "runs"), "--device", "cuda", "--dry-run", "--project"])
    err = capsys.readouterr().err
    assert "projection: farbox-j3: " in err and "no CUDA device" in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flags, message", [
    (["--project"], "--project is part of a dry run: add --dry-run"),
    (["--project", "--dry-run", "--ray-address", "local"], "not on a Ray cluster"),
])
def test_a_projection_is_refused_where_it_cannot_time_the_run(tmp_path, capsys, flags,
                                                             message):
    with pytest.raises(SystemExit) as exit_:
        sweep.main(["--setting", "farbox:3", "--out", str(tmp_path), *flags])
    assert exit_.value.code == 2 and message in capsys.readouterr().err


@pytest.mark.parametrize("extra, flag", [
    (["--region", "zheight"], "--region"), (["--out", "elsewhere"], "--out"),
    (["--seeds", "7"], "--seeds"), (["--episodes", "9"], "--episodes"),
    (["--joints", "6"], "--joints"), (["--reg", "zheight"], "--reg"),
    (["--out=elsewhere"], "--out"), (["--threads", "4"], "--threads"),
    (["--task", "region=zheight"], "--task region=..."),
])
def test_a_study_refuses_what_follows_dash_dash_where_it_sets_the_flag_itself(
        tmp_path, capsys, extra, flag):
    """Issue 37, kind 2: argparse lets the last flag win, so ``-- --region zheight`` trained
    z-height into farbox-j3 and ``-- --out X`` trained into X while the sweep counted its own
    folder; both the dry run and the real run (the same check) refuse, naming the flag."""
    for dry in (["--dry-run"], []):
        with pytest.raises(SystemExit) as exit_:
            sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "1", "--out",
                        str(tmp_path), *dry, "--", *extra])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert f"farbox-j3: {flag} " in err and "the study sets it" in err, err
    assert not any(tmp_path.iterdir()) and not Path("elsewhere").exists()


def test_a_study_refuses_what_follows_dash_dash_where_a_reading_sets_it(tmp_path, capsys):
    """Issue 37, kind 2, for the studies of readings: ``-- --algo sac`` would train SAC in the
    td3 folder; ``-- --task action_penalty_unit=command`` would undo the actor_penalty reading;
    a reading of one's own may not move the unit's folder either."""
    from analysis import algorithms, sensitivity

    cases = [
        (algorithms.main, ["--algos", "td3", "--", "--algo", "sac"],
         "td3/farbox-j3: --algo after --: the unit's reading sets it (--algo td3)"),
        (algorithms.main, ["--algos", "sac", "--", "--exploration-rate", "0.1"],
         "sac/farbox-j3: --exploration-rate after --: the unit's reading sets it"),
        (sensitivity.main, ["--readings", "actor_penalty", "--", "--task",
                            "action_penalty_unit=command"],
         "actor_penalty/farbox-j3: --task action_penalty_unit=... after --: the unit's "
         "reading sets it"),
        (sensitivity.main, ["--reading", "moved=--out elsewhere", "--readings", "moved"],
         "moved/farbox-j3: --out in its reading's arguments: the study sets it"),
    ]
    for main, args, message in cases:
        with pytest.raises(SystemExit) as exit_:
            main(["--setting", "farbox:3", "--out", str(tmp_path), "--dry-run", *args])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert message in err, err


def test_what_follows_dash_dash_that_the_study_leaves_open_still_passes(tmp_path, capsys):
    assert sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "1", "--out",
                       str(tmp_path), "--dry-run", "--", "--tau", "0.01", "--no-tensorboard",
                       "--task", "action_weight=0.5"]) == 0
    out = capsys.readouterr().out
    assert "--tau 0.01 --no-tensorboard --task action_weight=0.5" in out
    # the study's own process options are not passed-through ones
    assert sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "1", "--out",
                       str(tmp_path), "--dry-run", "--env-backend", "batched", "--one-process",
                       "--", "--tau", "0.01"]) == 0
    assert sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "1", "--out",
                       str(tmp_path), "--dry-run", "--env-backend", "batched"]) == 0
    assert capsys.readouterr().out.rstrip().endswith("--env-backend batched")


@pytest.mark.parametrize("extra", [["--no-tensorboard"], ["--no-progress"], ["--device", "cpu"]])
def test_one_process_refuses_a_process_flag_after_dash_dash_before_starting(tmp_path, capsys,
                                                                          extra):
    """Issue 37, kind 2: with --one-process every unit goes into one ddpg_her.train_many plan,
    which refuses a unit that sets a flag of the process; the sweep passed ``-- --no-tensorboard``
    through its dry run and its own checks, and train_many refused it after the sweep started."""
    for dry in (["--dry-run"], []):
        with pytest.raises(SystemExit) as exit_:
            sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "1", "--out",
                        str(tmp_path), "--one-process", *dry, "--", *extra])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert f"{extra[0]} after --: a flag of the training process" in err, err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("address, message", [
    ("127.0.0.1:1", "no Ray cluster answers at 127.0.0.1:1"),
    ("ray://127.0.0.1:1", "no Ray cluster answers at 127.0.0.1:1"),
    ("nohost", "expected 'local', 'auto', HOST:PORT or ray://HOST:PORT"),
    ("127.0.0.1:99999", "a port in 1..65535"),
])
def test_a_ray_address_with_no_cluster_is_refused_in_one_line_before_ray_starts(
        tmp_path, capsys, address, message):
    """Issue 37, kind 4: --ray-address 127.0.0.1:6999 with no cluster hung over 120 s in
    ray.init, and other bad addresses ended in Ray's tracebacks."""
    import time

    start = time.perf_counter()
    with pytest.raises(SystemExit) as exit_:
        sweep.main(["--setting", "farbox:3", "--episodes", "200", "--seeds", "1", "--out",
                    str(tmp_path), "--ray-address", address])
    assert exit_.value.code == 2 and time.perf_counter() - start < 60
    err = capsys.readouterr().err
    assert f"--ray-address {address}: " in err and message in err, err
    assert "Traceback" not in err
