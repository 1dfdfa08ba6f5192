"""analysis: run discovery, statistics, curves, report and the sweep, on tiny toy-env runs."""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_tools import run_module
from scipy import stats

from analysis import report, runs, sweep
from analysis.paper import PAPER_GRID

TOY = ["--env-id", "toy_goal_env:ToyReach-v0", "--eval-every", "2", "--eval-episodes", "4",
       "--hidden-sizes", "8", "8", "--updates-per-episode", "2"]


def _fake_run(folder: Path, region: str, joints: int, seed: int, successes: list[int],
              episodes: int = 10_000, task: dict | None = None, agent: dict | None = None
              ) -> None:
    """A run folder as ddpg_her.train writes it (spec.json, eval.csv), with chosen successes;
    ``task`` / ``agent``: fields of those spec sections (absent: a run from before them)."""
    folder.mkdir(parents=True)
    spec = {"format": "ddpg_her-run-1", "env_id": "UR5Reach-v0",
            "env_kwargs": {"region": region, "n_joints": joints}, "seed": seed,
            "agent": {"episodes": episodes, **(agent or {})}}
    if task is not None:
        spec["task"] = task
    (folder / "spec.json").write_text(json.dumps(spec))
    with open(folder / "eval.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "successes", "tests", "mean_return", "mean_final_distance_m",
                    "env_steps", "wall_s"])
        for i, s in enumerate(successes):
            w.writerow([100 * (i + 1), s, 100, -1.0, 0.2, 100 * (i + 1) * 100, i])


def test_mean_ci_matches_student_t() -> None:
    values = np.array([[10.0, 50.0], [20.0, 55.0], [40.0, 65.0], [30.0, 60.0]])
    mean, low, high = runs.mean_ci(values, 0.65)
    half = stats.t.ppf(0.825, 3) * values.std(axis=0, ddof=1) / 2.0
    np.testing.assert_allclose(mean, [25.0, 57.5])
    np.testing.assert_allclose(high - mean, half)
    np.testing.assert_allclose(mean - low, half)
    _, low, high = runs.mean_ci(np.array([[0.0], [0.0], [30.0]]), 0.65, runs.PERCENT)
    assert low[0] == 0.0 and high[0] <= 100.0
    with pytest.raises(ValueError, match="level"):
        runs.mean_ci(values, 1.5)


def test_report_summarises_and_checks_the_papers_orderings(tmp_path: Path) -> None:
    curves = {("farbox", 3): [60, 95, 97], ("unconstrained", 3): [20, 35, 40],
              ("zheight", 3): [10, 15, 20], ("unconstrained", 2): [80, 92, 95]}
    for (region, joints), curve in curves.items():
        for seed in range(2):
            _fake_run(tmp_path / f"{region}-j{joints}" / f"s{seed}", region, joints, seed,
                      [s + seed for s in curve])
    found = runs.find_runs([tmp_path])
    assert len(found) == 8 and all(not r.finished for r in found)
    summaries = {k: report.summarise(v) for k, v in runs.group_by_setting(found).items()}
    far = summaries[("farbox", 3)]
    assert far.final[0] == pytest.approx(97.5) and far.first_high == (200, 200)
    checks = {claim: verdict for claim, verdict, _ in report.ordering_checks(summaries)}
    assert checks["farbox far above unconstrained (3-6 joints)"] is report.Verdict.YES
    assert checks["unconstrained (3-6 joints) above zheight and closebox"] is report.Verdict.YES
    assert checks["2 joints high (unconstrained)"] is report.Verdict.YES
    out = run_module("analysis.report", str(tmp_path), "--out", str(tmp_path / "r.md")).stdout
    assert "| farbox | 3 | 2 | 300 | 97.5" in out and "nearly 100 %" in out
    assert "Budget: 300 training episodes per run (1.5% of the paper's 20,000), 2 seeds" in out
    assert "4 of the paper's 11 settings." in out
    assert (tmp_path / "r.md").read_text() == out


def test_report_states_the_reading_of_the_unstated_choices(tmp_path: Path) -> None:
    """Each choice as the runs' spec.json has it; a field missing from an older run reads as
    what such runs did (rad^2, stop); mixed readings are named and flagged."""
    _fake_run(tmp_path / "a", "farbox", 3, 0, [90], task={"action_penalty_unit": "actor",
              "contact_model": "stop"}, agent={"exploration_rate": 0.2, "warmup_episodes": 0})
    _fake_run(tmp_path / "b", "unconstrained", 3, 0, [40])
    summaries = {k: report.summarise(v)
                 for k, v in runs.group_by_setting(runs.find_runs([tmp_path])).items()}
    old = summaries[("unconstrained", 3)].choices[0]
    assert old["action penalty's unit"] == "command" and old["ground contact"] == "stop"
    assert old["warm-up episodes"] == "100"
    text = "\n".join(report.reading_lines(summaries))
    assert "| action penalty's unit | **command** (unconstrained 3); **actor** (farbox 3) |" in text
    assert "| ground contact | stop |" in text
    assert "| warm-up episodes | **100** (unconstrained 3); **0** (farbox 3) |" in text
    assert "These runs mix readings" in text
    same = {("farbox", 3): summaries[("farbox", 3)]}
    text = "\n".join(report.reading_lines(same))
    assert "| action penalty's unit | actor |" in text and "mix readings" not in text
    assert "## The reading of the paper's unstated choices" in report.render(same, 0.65)


def test_report_says_no_when_an_ordering_fails(tmp_path: Path) -> None:
    _fake_run(tmp_path / "a", "farbox", 3, 0, [30])
    _fake_run(tmp_path / "b", "unconstrained", 3, 0, [40])
    summaries = {k: report.summarise(v)
                 for k, v in runs.group_by_setting(runs.find_runs([tmp_path])).items()}
    verdicts = {claim: verdict for claim, verdict, _ in report.ordering_checks(summaries)}
    assert verdicts["farbox far above unconstrained (3-6 joints)"] is report.Verdict.NO
    assert verdicts["2 joints high (unconstrained)"] is report.Verdict.NOT_RUN


@pytest.mark.parametrize(("high", "low", "verdict"), [
    ([30, 32, 34], [10, 11, 12], "YES"),     # intervals apart, means 21 apart
    ([10, 11, 12], [30, 32, 34], "NO"),      # apart, the other way round
    ([20, 22, 24], [10, 11, 12], "NO"),      # apart, but not the 20 the claim needs
    ([0, 30, 60], [10, 11, 12], "NOISE"),    # the intervals overlap
])
def test_report_verdicts_follow_the_confidence_intervals(tmp_path: Path, high, low,
                                                         verdict) -> None:
    for seed, (h, lo) in enumerate(zip(high, low, strict=True)):
        _fake_run(tmp_path / f"far{seed}", "farbox", 6, seed, [h])
        _fake_run(tmp_path / f"unc{seed}", "unconstrained", 5, seed, [lo])
    summaries = {k: report.summarise(v)
                 for k, v in runs.group_by_setting(runs.find_runs([tmp_path])).items()}
    # the independent reference: scipy's Student-t interval of the same successes
    (h_low, h_high), (l_low, l_high) = (
        stats.t.interval(0.65, 2, loc=np.mean(v), scale=stats.sem(v)) for v in (high, low))
    assert summaries[("farbox", 6)].final[1:] == pytest.approx((h_low, h_high))
    assert summaries[("unconstrained", 5)].final[1:] == pytest.approx((l_low, l_high))
    claim, got, detail = report.ordering_checks(summaries)[0]
    assert claim.startswith("farbox far above") and got is report.Verdict[verdict]
    assert "missing: farbox 3, unconstrained 3" in detail


def test_curves_writes_figure_and_the_plotted_numbers(tmp_path: Path) -> None:
    for seed, curve in enumerate([[10, 20], [30, 40], [20, 60]]):
        _fake_run(tmp_path / f"s{seed}", "farbox", 3, seed, curve)
    run_module("analysis.curves", str(tmp_path), "--out", str(tmp_path / "fig" / "c.png"))
    assert (tmp_path / "fig" / "c.png").stat().st_size > 1000
    with open(tmp_path / "fig" / "c.csv") as f:
        rows = list(csv.DictReader(f))
    assert [float(r["mean_successes"]) for r in rows] == [20.0, 40.0]
    half = stats.t.ppf(0.825, 2) * 10.0 / np.sqrt(3)
    assert float(rows[0]["ci_high"]) == pytest.approx(20.0 + half, abs=1e-3)


def test_commands_fail_clearly_without_runs(tmp_path: Path) -> None:
    for module in ("analysis.curves", "analysis.report"):
        proc = run_module(module, str(tmp_path / "missing"), check=False)
        assert proc.returncode == 2 and "does not exist" in proc.stderr
        proc = run_module(module, str(tmp_path), check=False)
        assert proc.returncode == 2 and "no run with evaluations" in proc.stderr


def test_sweep_dry_run_lists_the_papers_55_runs(tmp_path: Path) -> None:
    proc = run_module("analysis.sweep", "--grid", "paper", "--dry-run", "--out", str(tmp_path))
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 55 == len(PAPER_GRID) * 5
    assert sum("farbox " in line and "joints=6" in line for line in lines) == 5
    assert all(line.startswith("new") for line in lines)
    # the env backend reaches every training process: each unit's command, or the one process
    per = run_module("analysis.sweep", "--setting", "farbox:3", "--env-backend", "batched",
                     "--dry-run", "--out", str(tmp_path)).stdout.splitlines()
    assert len(per) == 5 and all(line.endswith("--env-backend batched") for line in per)
    one = run_module("analysis.sweep", "--grid", "paper", "--one-process", "--env-backend",
                     "batched", "--dry-run", "--out", str(tmp_path)).stderr
    assert "ddpg_her.train_many --plan" in one and one.rstrip().endswith("--env-backend batched")


def test_sweep_runs_skips_finished_and_resumes(tmp_path: Path) -> None:
    def args(episodes: int) -> list[str]:
        return ["analysis.sweep", "--setting", "box:2", "--seeds", "2", "--episodes",
                str(episodes), "--out", str(tmp_path), "--workers", "1", "--", *TOY]

    run_module(*args(4))
    for seed in (0, 1):
        assert runs.read_run(tmp_path / "box-j2" / f"s{seed}").finished
    log = (tmp_path / "logs" / "box-j2.log").read_text()
    again = run_module(*args(4)).stderr
    assert "1 of 1 settings already finished" in again
    assert (tmp_path / "logs" / "box-j2.log").read_text() == log  # nothing re-ran
    run_module(*args(6))
    run = runs.read_run(tmp_path / "box-j2" / "s0")
    assert run.finished and run.episode.tolist() == [2, 4, 6]  # resumed: no row lost or repeated


def _eval_without_wall(folder: Path) -> list[list[str]]:
    with open(folder / "eval.csv", newline="") as f:
        return [row[:-1] for row in csv.reader(f)]


def test_sweep_in_one_process_writes_the_runs_one_process_per_setting_writes(tmp_path: Path
                                                                             ) -> None:
    """Two joint counts (two stacks) in one ddpg_her.train_many process, resumed, against the
    same sweep run one process per setting: every eval.csv the same but for wall_s."""
    def args(root: Path, episodes: int, *mode: str) -> list[str]:
        return ["analysis.sweep", "--setting", "box:2", "--setting", "box:3", "--seeds", "2",
                "--episodes", str(episodes), "--out", str(root), *mode, "--", *TOY]

    one, per = tmp_path / "one", tmp_path / "per"
    dry = run_module(*args(one, 2, "--one-process", "--dry-run"))
    assert all("<- one process, unit --region box" in ln for ln in dry.stdout.splitlines())
    assert "ddpg_her.train_many --plan" in dry.stderr
    run_module(*args(one, 2, "--one-process"))
    assert runs.read_run(one / "box-j3" / "s1").finished
    run_module(*args(one, 4, "--one-process"))
    run_module(*args(per, 4, "--no-one-process"))
    for setting in ("box-j2", "box-j3"):
        for seed in (0, 1):
            table = _eval_without_wall(one / setting / f"s{seed}")
            assert [row[0] for row in table[1:]] == ["2", "4"]  # resumed: nothing lost
            assert table == _eval_without_wall(per / setting / f"s{seed}")
    log = (one / "logs" / "one-process.log").read_text()
    assert log.count("ddpg_her.train_many --plan") == 2 and "4 agents" in log
    again = run_module(*args(one, 4, "--one-process")).stderr
    assert "2 of 2 settings already finished" in again


LOCK_HOLDER = ("import sys, time; from ddpg_her.runfolder import RunFolder; "
               "RunFolder(sys.argv[1]).lock(); print('locked', flush=True); time.sleep(60)")
"""A stand-in for a trainer: holds the lock of the run folder argv[1] (as `Trainer` does)."""


def test_a_unit_whose_folder_another_process_holds_is_busy(tmp_path: Path) -> None:
    unit = sweep.Unit("box", 2, (0, 1), tmp_path, 10)
    assert not sweep.busy(unit)
    proc = subprocess.Popen([sys.executable, "-c", LOCK_HOLDER, str(unit.run_dir(1))],
                            stdout=subprocess.PIPE, text=True, cwd=Path(__file__).parent.parent)
    try:
        assert proc.stdout.readline().strip() == "locked"
        assert sweep.busy(unit)
        assert not sweep.busy(sweep.Unit("box", 3, (0,), tmp_path, 10))
    finally:
        proc.kill()
        proc.wait()
    assert not sweep.busy(unit)  # the holder has ended: its lock is stale


def test_one_process_is_opt_in_and_contradicts_ray_and_workers() -> None:
    """Opt-in on every device until a GPU run measures it (see sweep.one_process)."""
    parser = argparse.ArgumentParser()
    sweep.add_execution_arguments(parser, Path("runs"))
    assert not sweep.one_process(parser.parse_args(["--device", "cuda"]))
    assert not sweep.one_process(parser.parse_args([]))
    assert sweep.one_process(parser.parse_args(["--device", "cuda", "--one-process"]))
    assert not sweep.one_process(parser.parse_args(["--device", "cuda", "--no-one-process"]))
    assert not sweep.one_process(parser.parse_args(["--device", "cuda", "--ray-address", "a"]))
    for bad in (["--one-process", "--ray-address", "auto"], ["--one-process", "--workers", "2"]):
        with pytest.raises(SystemExit), contextlib.redirect_stderr(io.StringIO()):
            sweep.check_execution_arguments(parser, parser.parse_args(bad))


@pytest.mark.slow
def test_sweep_on_a_local_ray_instance(tmp_path: Path) -> None:
    """Slow: Ray's start-up alone takes 35 s on a quiet machine, 262 s on a loaded one."""
    pytest.importorskip("ray")
    proc = run_module("analysis.sweep", "--setting", "box:2", "--setting", "box:3", "--seeds", "1",
                      "--episodes", "2", "--out", str(tmp_path), "--ray-address", "local",
                      "--threads", "1", "--", *TOY, timeout=1200)
    # 35 s on a quiet machine; 262 s with four trainers on its two cores (Ray's start-up)
    assert proc.returncode == 0, proc.stderr
    for joints in (2, 3):
        assert runs.read_run(tmp_path / f"box-j{joints}" / "s0").finished


def test_parse_setting_rejects_bad_text() -> None:
    assert sweep.parse_setting("box:0,1,0,1,0,1:3") == ("box:0,1,0,1,0,1", 3)
    for bad in ("farbox", "farbox:7", ":3", "farbox:x"):
        with pytest.raises(Exception, match="REGION:JOINTS"):
            sweep.parse_setting(bad)


def test_success_map_bins_against_a_hand_count() -> None:
    from analysis.success_map import bin_successes

    goals = np.array([[0.05, 0.05, 0.75], [0.06, 0.02, 0.71], [0.15, -0.05, 0.79],
                      [0.12, -0.08, 0.72]])
    reached = np.array([True, False, True, True])
    m = bin_successes("r", goals, reached, cell=0.1)
    np.testing.assert_allclose(m.x_edges, [0.0, 0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(m.y_edges, [-0.1, 0.0, 0.1], atol=1e-12)
    np.testing.assert_array_equal(m.goals, [[0, 2], [2, 0]])
    np.testing.assert_array_equal(m.successes, [[0, 1], [2, 0]])
    assert m.rate[0, 1] == 0.5 and np.isnan(m.rate[0, 0])


def test_slice_goals_come_from_the_tasks_sampler_within_the_slice() -> None:
    from analysis.success_map import slice_goals
    from envs.spec import TaskSpec

    task = TaskSpec(region="unconstrained", n_joints=3)
    goals = slice_goals(task, 200, (0.7, 0.8), seed=3)
    assert goals.shape == (200, 3)
    assert np.all((goals[:, 2] >= 0.7) & (goals[:, 2] <= 0.8))
    np.testing.assert_array_equal(goals, slice_goals(task, 200, (0.7, 0.8), seed=3))


def test_success_map_cli_on_a_tiny_run(tmp_path: Path) -> None:
    run_module("ddpg_her.train", "--region", "unconstrained", "--joints", "3", "--episodes", "2",
               "--eval-every", "2", "--eval-episodes", "2", "--hidden-sizes", "8", "8",
               "--out", str(tmp_path / "run"), "--no-progress", "--threads", "1")
    out = tmp_path / "map.png"
    run_module("analysis.success_map", str(tmp_path / "run"), str(tmp_path / "run"),
               "--goals", "60",
               "--batch", "30", "--out", str(out), "--no-progress")
    assert out.stat().st_size > 1000
    with open(out.with_suffix(".csv")) as f:
        rows = list(csv.DictReader(f))
    labels = {r["run"] for r in rows}
    assert len(labels) == 1  # the same run twice gives the same label and the same map
    assert sum(int(r["goals"]) for r in rows) == 120
    first = [r["successes"] for r in rows[: len(rows) // 2]]
    assert first == [r["successes"] for r in rows[len(rows) // 2 :]]  # same goals, same policy
    bad = run_module("analysis.success_map", str(tmp_path / "nothing"), check=False)
    assert bad.returncode == 2 and "not a run folder" in bad.stderr
