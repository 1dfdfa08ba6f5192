"""analysis: run discovery, statistics, curves, report and the sweep, on tiny toy-env runs."""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_tools import run_module
from scipy import stats

from analysis import curves, report, runs, sweep
from analysis.paper import CLAIMS, PAPER_GRID

TOY = ["--env-id", "toy_goal_env:ToyReach-v0", "--eval-every", "2", "--eval-episodes", "4",
       "--hidden-sizes", "8", "8", "--updates-per-episode", "2"]


@pytest.mark.parametrize("fmt", [None, 999, "sb3-run-1"], ids=["no_format", "number", "other"])
def test_readers_refuse_a_spec_that_is_not_a_ddpg_her_run(tmp_path, capsys, fmt):
    """Issue 37, kind 6 (found by benchmarks/reliability_probe.py): summary, ddpg_her.load and
    replay read a spec.json without a ddpg_her ``format`` as a run, while curves and report
    skip it: every reader now refuses it through RunFolder.read_spec, naming the file."""
    from ddpg_her.runfolder import RunFolder
    from ddpg_her.summary import main as summary_main

    _fake_run(tmp_path / "s0", "farbox", 3, 0, [10, 20])
    spec_path = tmp_path / "s0" / "spec.json"
    spec = json.loads(spec_path.read_text())
    spec.pop("format") if fmt is None else spec.update(format=fmt)
    spec_path.write_text(json.dumps(spec))
    with pytest.raises(runs.RunFolderError, match=rf"{spec_path} is not a ddpg_her run"):
        RunFolder(tmp_path / "s0").read_spec()
    with pytest.raises(SystemExit) as stop:
        summary_main([str(tmp_path / "s0")])
    assert stop.value.code == 2
    assert f"{spec_path} is not a ddpg_her run" in capsys.readouterr().err


@pytest.mark.parametrize("episodes", ["0", "-1"])
def test_summary_refuses_a_projection_to_no_episodes(tmp_path, capsys, episodes):
    """Issue 37, kind 7 (found by benchmarks/reliability_probe.py): ``--project-to -1`` printed
    a projected wall time for -1 episodes (a negative time) and exited 0."""
    from ddpg_her.summary import main as summary_main

    _fake_run(tmp_path / "s0", "farbox", 3, 0, [10, 20])
    with pytest.raises(SystemExit) as stop:
        summary_main([str(tmp_path / "s0"), "--project-to", episodes])
    assert stop.value.code == 2
    assert f"argument --project-to: {episodes} (expected an integer >= 1)" in \
        capsys.readouterr().err


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


def _checks(root: Path) -> dict[str, report.Check]:
    summaries = {k: report.summarise(v)
                 for k, v in runs.group_by_setting(runs.find_runs([root])).items()}
    return {c.claim: c for c in report.judge_claims({k: s.curves for k, s in summaries.items()})}


def test_report_summarises_and_checks_the_papers_claims(tmp_path: Path) -> None:
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
    # the level is each seed's mean over its last 5 (here: all 3) sessions, not the last one
    assert far.final[0] == pytest.approx(np.mean([60, 95, 97]) + 0.5)
    assert far.first_high == (200, 200)
    checks = {c.claim: c for c in report.judge_claims({k: s.curves for k, s in summaries.items()})}
    assert [c.claim for c in checks.values()] == [c.name for c in CLAIMS]
    easier = checks["far box easier than the other regions"]
    assert easier.verdict is report.Verdict.YES
    assert easier.confounds[0].startswith("another start pose")
    # 300 episodes: every claim about where training ends is not judgeable, nor is 1,000
    for claim in CLAIMS:
        if claim.at_end:
            assert checks[claim.name].verdict in (report.Verdict.NOT_JUDGEABLE,
                                                  report.Verdict.NOT_RUN), claim.name
    assert checks["unconstrained 2 joints highly capable"].verdict is \
        report.Verdict.NOT_JUDGEABLE
    assert checks["far box near 100 % by 1,000 episodes, 3 joints"].verdict is \
        report.Verdict.NOT_JUDGEABLE
    out = run_module("analysis.report", str(tmp_path), "--out", str(tmp_path / "r.md")).stdout
    assert "| farbox | 3 | 2 | 300 | 84.5" in out and "nearly 100 %" in out
    assert "Budget: 300 training episodes per run (1.5% of the paper's 20,000), 2 seeds" in out
    assert "4 of the paper's 11 settings." in out
    assert "is **not judgeable** when the runs end below the paper's 20,000 episodes" in out
    assert "| unconstrained 2 joints highly capable | \"DDPG succeeds in learning a highly " \
           "capable policy for 2 joint control\" (IV-A, Fig. 2) | not judgeable | - |" in out
    assert "2 comparisons made (1 of them on claims judgeable here)" in out
    assert (tmp_path / "r.md").read_text() == out


def _hand_welch(a, b) -> float:
    """The two-sided Welch p-value from its formula (Welch-Satterthwaite degrees of freedom)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    t = (a.mean() - b.mean()) / np.sqrt(va + vb)
    dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    return float(2 * stats.t.sf(abs(t), dof))


def _plateau(tmp_path: Path, region: str, joints: int, levels, sessions: int = 200,
             rise: int = 10) -> None:
    """5 seeds that climb over ``rise`` sessions to their level, then hold it (+- 1)."""
    for seed, level in enumerate(levels):
        curve = [round(level * min(1.0, (i + 1) / rise)) + (i % 2 if level < 100 else 0)
                 for i in range(sessions)]
        _fake_run(tmp_path / f"{region}-j{joints}" / f"s{seed}", region, joints, seed, curve,
                  episodes=100 * sessions)


def test_every_claim_judged_at_the_papers_budget_as_the_paper_says(tmp_path: Path) -> None:
    """Runs of 20,000 episodes shaped as the paper describes them: every claim holds; the
    p-values are Welch's formula's; at 19,900 episodes the claims about the end are not
    judgeable."""
    unc = {3: [38, 40, 42, 39, 41], 4: [37, 40, 41, 40, 43], 6: [34, 37, 39, 40, 38]}
    for n, levels in unc.items():
        _plateau(tmp_path, "unconstrained", n, levels)
    _plateau(tmp_path, "unconstrained", 2, [95, 96, 97, 98, 96])
    for region in ("zheight", "closebox"):
        _plateau(tmp_path, region, 3, [19, 20, 21, 20, 22])
        _plateau(tmp_path, region, 6, [18, 20, 21, 22, 19], rise=40)  # slower to converge
    _plateau(tmp_path, "farbox", 3, [100] * 5)
    _plateau(tmp_path, "farbox", 6, [100, 100, 100, 100, 30])  # one run never learns
    checks = _checks(tmp_path)
    for claim in CLAIMS[:-2]:
        assert checks[claim.name].verdict is report.Verdict.YES, checks[claim.name]
    assert checks[CLAIMS[-2].name].verdict is report.Verdict.NOT_RUN  # no 1.0 m far box
    assert checks[CLAIMS[-1].name].verdict is report.Verdict.NOT_JUDGEABLE  # no success maps
    # Welch p of "unconstrained above zheight and closebox": per joint count, the weakest
    # unconstrained against the strongest constrained setting (each seed's mean over its last 5
    # sessions: +0.6 from the +-1 pattern); the closest pair (6 joints) decides
    level = lambda levels: [v + 0.6 for v in levels]  # noqa: E731
    got = checks["unconstrained above zheight and closebox"]
    assert "weakest of the first: unconstrained 6" in got.detail
    assert got.p_value == pytest.approx(_hand_welch(level(unc[6]), level([18, 20, 21, 22, 19])))
    assert got.p_value < 1e-4
    assert "another start pose" in got.confounds[0]
    assert checks["far box easier than the other regions"].p_value == pytest.approx(
        _hand_welch([100] * 4 + [30.6], level(unc[6])), rel=1e-6)
    short = tmp_path / "short"
    for n, levels in unc.items():
        _plateau(short, "unconstrained", n, levels, sessions=199)
    checks = _checks(short)
    for claim in CLAIMS:
        if claim.at_end and claim.name.startswith("unconstrained 3"):
            assert checks[claim.name].verdict is report.Verdict.NOT_JUDGEABLE
            assert "end at 19,900 episodes, below the paper's 20,000" in checks[claim.name].detail


@pytest.mark.parametrize(("seeds_3", "seeds_6", "v3", "v6"), [
    ([100] * 5, [100] * 4 + [50], "YES", "YES"),
    ([100] * 4 + [85], [100] * 3 + [50, 50], "NO", "NO"),
])
def test_far_box_by_1000_counts_the_runs_as_the_paper_does(tmp_path: Path, seeds_3, seeds_6,
                                                           v3, v6) -> None:
    """"all independent runs in the 3 joint case, and ... 4 of 5 runs in the 6 joint case":
    a seed counts when a session by episode 1,000 hits 90; later sessions do not count."""
    _plateau(tmp_path, "farbox", 3, seeds_3, sessions=12)
    _plateau(tmp_path, "farbox", 6, seeds_6, sessions=12, rise=10)
    checks = _checks(tmp_path)
    assert checks["far box near 100 % by 1,000 episodes, 3 joints"].verdict is report.Verdict[v3]
    assert checks["far box near 100 % by 1,000 episodes, 6 joints"].verdict is report.Verdict[v6]
    assert f"{sum(s >= 90 for s in seeds_6)} of 5 seeds hit >= 90" in \
        checks["far box near 100 % by 1,000 episodes, 6 joints"].detail
    late = tmp_path / "late"  # 90 first hit at episode 1,100: too late for the claim
    for seed in range(5):
        _fake_run(late / f"s{seed}", "farbox", 3, seed, [95] * 12 if seed else [0] * 10 + [95] * 2)
    assert _checks(late)["far box near 100 % by 1,000 episodes, 3 joints"].verdict is \
        report.Verdict.NO


def test_a_level_is_the_mean_of_the_last_five_sessions(tmp_path: Path) -> None:
    """One bad last session does not decide a level: [50 x 6, 0] is 40, not 0."""
    _fake_run(tmp_path / "s0", "unconstrained", 3, 0, [50] * 6 + [0])
    (summary,) = (report.summarise(v)
                  for v in runs.group_by_setting(runs.find_runs([tmp_path])).values())
    assert summary.final[0] == pytest.approx(40.0)


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


def test_report_says_fails_when_an_ordering_fails(tmp_path: Path) -> None:
    _fake_run(tmp_path / "a", "farbox", 3, 0, [30])
    _fake_run(tmp_path / "b", "unconstrained", 3, 0, [40])
    checks = _checks(tmp_path)
    assert checks["far box easier than the other regions"].verdict is report.Verdict.NO
    assert checks["unconstrained 2 joints highly capable"].verdict is report.Verdict.NOT_RUN


@pytest.mark.parametrize(("high", "low", "verdict"), [
    ([30, 32, 34], [10, 11, 12], "YES"),     # intervals apart
    ([10, 11, 12], [30, 32, 34], "NO"),      # apart, the other way round
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
    got = {c.claim: c for c in report.judge_claims({k: s.curves for k, s in summaries.items()})}[
        "far box easier than the other regions"]
    assert got.verdict is report.Verdict[verdict]
    assert "missing: farbox 3, unconstrained 3" in got.detail
    assert got.p_value == pytest.approx(_hand_welch(high, low))
    assert got.confounds[0] == "6 vs 5 joints" and "inside the far box" in got.confounds[2]


def test_the_penalty_free_pose_lies_in_every_region_as_the_report_says() -> None:
    import ur5kin
    from regions.registry import DEFAULT_BASE_HEIGHT, get

    tool = np.asarray(ur5kin.fk_world(np.zeros(6), DEFAULT_BASE_HEIGHT))
    np.testing.assert_allclose(tool, report.ZERO_POSE_TOOL, atol=5e-4)
    for name in ("unconstrained", "zheight", "closebox", "farbox"):
        assert get(name).contains(tool.reshape(1, 3))[0], name
    volume = {name: get(name).volume for name in ("zheight", "closebox", "farbox")}
    assert min(volume, key=volume.get) == "farbox"


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

    first = run_module(*args(4)).stderr.strip().splitlines()[-1]
    for seed in (0, 1):
        assert runs.read_run(tmp_path / "box-j2" / f"s{seed}").finished
    assert first == f"sweep: 2 of 2 runs finished in {tmp_path}; look at them: python -m " \
        f"analysis.curves {tmp_path} --out {tmp_path / 'curves.png'} && python -m " \
        f"analysis.report {tmp_path}"  # the summary, and the commands to look
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
    """Opt-in on every device until a GPU run measures it (the --one-process help)."""
    parser = argparse.ArgumentParser()
    sweep.add_execution_arguments(parser, Path("runs"))
    assert parser.parse_args(["--device", "cuda"]).one_process is False
    assert parser.parse_args([]).one_process is False
    assert parser.parse_args(["--device", "cuda", "--one-process"]).one_process is True
    assert parser.parse_args(["--device", "cuda", "--no-one-process"]).one_process is False
    assert parser.parse_args(["--device", "cuda", "--ray-address", "a"]).one_process is False
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


_EVAL_HEADER = ["episode", "successes", "tests", "mean_return", "mean_final_distance_m",
                "env_steps", "wall_s"]


@pytest.mark.parametrize(("bad_row", "message"), [
    (["200", "101", "100", "-1", "0.2", "20000", "1"], "successes is 101, expected 0 to tests"),
    (["200", "-250", "100", "-1", "0.2", "20000", "1"], "successes is -250"),
    (["200", "0", "0", "-1", "0.2", "20000", "1"], "tests is 0, expected at least 1"),
    (["200", "many", "100", "-1", "0.2", "20000", "1"], "successes is 'many', expected a whole"),
    (["200", "5", "100", "n/a", "0.2", "20000", "1"], "mean_return is 'n/a', expected a number"),
    (["100", "5", "100", "-1", "0.2", "20000", "1"], "episode is 100, expected more than the "
                                                      "row before \\(100\\)"),
])
def test_an_eval_row_that_cannot_be_is_an_error_in_every_tool(tmp_path: Path, capsys, bad_row,
                                                              message) -> None:
    """analysis.report, analysis.curves and ddpg_her.summary read eval.csv through one reader
    (RunFolder.read_eval); each refuses the impossible row, naming the folder and the line."""
    from analysis import curves
    from ddpg_her import summary

    run = tmp_path / "runs" / "s0"
    _fake_run(run, "farbox", 3, 0, [40])
    with open(run / "eval.csv", "a", newline="") as f:
        csv.writer(f).writerow(bad_row)
    for tool, argv in ((report.main, [str(tmp_path / "runs")]),
                       (curves.main, [str(tmp_path / "runs"), "--out", str(tmp_path / "c.png")]),
                       (summary.main, [str(run)])):
        with pytest.raises(SystemExit) as exit_:
            tool(argv)
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert f"{run / 'eval.csv'} line 3: " in err and "cannot be trusted" in err, err
        assert re.search(message, err), err
    assert not (tmp_path / "c.png").exists()


def test_readers_name_a_run_of_another_format_and_an_empty_eval_csv(tmp_path, capsys):
    """Issue 37, kind 6: curves, report and summary read a run folder of another format
    version without a word (--resume refuses it), and an empty eval.csv read as no session."""
    from analysis import curves
    from ddpg_her.summary import main as summary_main

    _fake_run(tmp_path / "other" / "s0", "farbox", 3, 0, [10, 20])
    spec = json.loads((tmp_path / "other" / "s0" / "spec.json").read_text())
    (tmp_path / "other" / "s0" / "spec.json").write_text(
        json.dumps({**spec, "format": "ddpg_her-run-2"}))
    with pytest.raises(runs.RunFolderError, match="format 'ddpg_her-run-2', written by another "
                                                  "version of this code"):
        runs.read_run(tmp_path / "other" / "s0")
    _fake_run(tmp_path / "empty" / "s0", "farbox", 3, 0, [10])
    (tmp_path / "empty" / "s0" / "eval.csv").write_text("")
    with pytest.raises(runs.RunFolderError, match=r"eval\.csv is empty, not even its header"):
        runs.read_run(tmp_path / "empty" / "s0")
    for folder in ("other", "empty"):
        for main, args in ((curves.main, [str(tmp_path / folder), "--out",
                                          str(tmp_path / f"{folder}.png")]),
                           (summary_main, [str(tmp_path / folder / "s0")])):
            code = None
            try:
                code = main(args)
            except SystemExit as stop:
                code = stop.code
            err = capsys.readouterr().err
            assert code not in (0, None) and ("ddpg_her-run-2" in err or "is empty" in err), \
                (folder, main, err)


def test_runs_that_differ_beyond_their_seed_are_compared_not_pooled(tmp_path: Path, capsys
                                                                     ) -> None:
    """Issue 41/43: two user regions (a box and a mesh) are two groups compared by the rule;
    runs of one setting that differ in their algorithm are refused unless pooled, and pooling
    says what differs. The verdict and p-value are checked against scipy's Welch test and
    the Student-t intervals computed here (the reference)."""
    box, mesh = [[10, 60, 90, 95, 96, 97, 98, 99], [20, 70, 92, 94, 95, 95, 96, 97],
                 [15, 65, 88, 93, 97, 96, 95, 98]], [[5, 10, 20, 25, 30, 30, 31, 32],
                                                     [3, 12, 18, 22, 28, 29, 33, 30],
                                                     [4, 9, 15, 26, 27, 31, 30, 29]]
    for seed, s in enumerate(box):
        _fake_run(tmp_path / "mine" / f"s{seed}", "box:0.3,0.7,-0.2,0.2,0,0.5", 3, seed, s)
    for seed, s in enumerate(mesh):
        _fake_run(tmp_path / "theirs" / f"s{seed}", "mesh:shelf.stl", 3, seed, s)
    out = tmp_path / "cmp.md"
    assert report.main(["--groups", f"box={tmp_path / 'mine'}", f"mesh={tmp_path / 'theirs'}",
                        "--out", str(out)]) == 0
    text = out.read_text()
    level = [np.mean(x[-5:]) for x in box], [np.mean(x[-5:]) for x in mesh]
    p = stats.ttest_ind(*level, equal_var=False).pvalue
    assert f"| {report.p_text(p)} |" in text
    (m_a, lo_a, hi_a), (m_b, lo_b, hi_b) = (runs.mean_ci(np.array(v), 0.65, runs.PERCENT)
                                            for v in level)
    assert lo_a > hi_b  # the reference: the intervals are apart, box above
    assert f"| box {m_a:.1f} [{lo_a:.1f}, {hi_a:.1f}] | mesh {m_b:.1f} [{lo_b:.1f}, " \
           f"{hi_b:.1f}] | holds |" in text
    assert str(tmp_path / "mine" / "s0") in text  # every row names its runs
    # one setting, two algorithms: refused, then compared by algorithm, then pooled with a note
    for seed, s in enumerate(box):
        _fake_run(tmp_path / "algos" / "td3" / f"s{seed}", "farbox", 3, seed, s,
                  agent={"algo": "td3"})
        _fake_run(tmp_path / "algos" / "ddpg" / f"s{seed}", "farbox", 3, seed, mesh[seed],
                  agent={"algo": "ddpg"})
    capsys.readouterr()
    for module in (report, curves):
        with pytest.raises(SystemExit) if module is report else contextlib.nullcontext():
            module.main([str(tmp_path / "algos"), "--out", str(tmp_path / "x.png")])
    err = capsys.readouterr().err
    assert "not pooled: farbox 3: agent.algo (\"ddpg\" / \"td3\")" in err
    with open(tmp_path / "x.csv") as f:  # curves drew them apart, each labelled
        labels = {r["group"] for r in csv.DictReader(f)}
    assert labels == {'farbox 3 (agent.algo="ddpg")', 'farbox 3 (agent.algo="td3")'}
    assert report.main([str(tmp_path / "algos"), "--group-by", "algorithm"]) == 0
    assert "| algorithm td3 | farbox 3 | 3 | 96.1 [95.5, 96.6] |" in capsys.readouterr().out
    assert report.main([str(tmp_path / "algos"), "--pool"]) == 0
    assert "note: farbox 3: pools 6 runs that differ in agent.algo" in capsys.readouterr().err


def test_summary_names_runs_by_folder_and_projects_a_short_multi_seed_run(tmp_path: Path
                                                                          ) -> None:
    """Issue 43: two runs of seed 0 were both "seed 0", and a run of two sessions projected
    nan. Its wall clock here is i - 1 s at session i (episode 100 i): 1 s per 100 episodes,
    so 20,000 episodes take 1 + 198 s, 0.055 h."""
    from ddpg_her.summary import summarize

    for name in ("a", "b"):
        for seed in (0, 1):
            _fake_run(tmp_path / name / f"s{seed}", "farbox", 3, seed, [3, 40])
    table = summarize([str(tmp_path / "a"), str(tmp_path / "b" / "s0")], 20_000)
    assert f"| {tmp_path / 'a' / 's0'} (seed 0) | {tmp_path / 'a' / 's1'} (seed 1) | " \
           f"{tmp_path / 'b' / 's0'} (seed 0) |" in table
    rows = [line for line in table.splitlines() if line.startswith(f"| {tmp_path}")]
    assert len(rows) == 3 and all(line.endswith("| 0.1 |") for line in rows), rows
