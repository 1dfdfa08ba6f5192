"""analysis.sensitivity: units and commands, status, --collect, the verdicts on hand-made run
folders against hand-computed intervals, and one tiny real unit trained and reported."""

from __future__ import annotations

import csv
import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from cli_tools import run_module
from scipy import stats

from analysis import sensitivity as sens
from analysis.report import Verdict
from analysis.sweep import Unit, busy
from ddpg_her.run import RunFolder
from envs.spec import TaskSpec

BUDGET = 1000
T65 = stats.t.ppf(0.825, 4)
"""Student-t quantile of a two-sided 65 % interval over 5 seeds."""


def _write_run(folder: Path, region: str, joints: int, seed: int, final: float,
               upto: int = BUDGET, planned: int = BUDGET, after: float | None = None,
               extra_task: dict | None = None) -> None:
    """A run folder through the trainer's own writer: evaluations every 100 episodes up to
    ``upto``, half of ``final`` successes per 100 at the first and ``final`` from the second on
    (so from 600 episodes on, the last 5 sessions' mean is ``final``), then (``after``) one more
    row beyond."""
    task = TaskSpec(region=region, n_joints=joints, **(extra_task or {})).to_dict()
    f = RunFolder(folder)
    f.write_spec({"format": "ddpg_her-run-1", "env_id": "UR5Reach-v0",
                  "env_kwargs": {"region": region, "n_joints": joints}, "task": task,
                  "seed": seed, "agent": {"episodes": planned, "gamma": 0.98}})
    episodes = list(range(100, upto + 1, 100))
    values = [round(final / 2) if e == 100 else round(final) for e in episodes]
    if after is not None:
        episodes.append(upto + 200)
        values.append(round(after))
    f.write_eval([{"episode": e, "successes": v, "tests": 100, "mean_return": 0.0,
                   "mean_final_distance_m": 0.1, "env_steps": e * 100, "wall_s": 1.0}
                  for e, v in zip(episodes, values, strict=True)])


def _hand_welch(a, b) -> float:
    """The two-sided Welch p-value from its formula (Welch-Satterthwaite degrees of freedom)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    t = (a.mean() - b.mean()) / np.sqrt(va + vb)
    dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    return float(2 * stats.t.sf(abs(t), dof))


def _hand_t(values) -> tuple[float, float, float]:
    """The paper's 65 % Student-t interval of the mean, by scipy (clipped to 0-100)."""
    m = float(np.mean(values))
    if len(values) < 2:
        return m, m, m
    low, high = stats.t.interval(0.65, len(values) - 1, loc=m, scale=stats.sem(values))
    return m, max(low, 0.0), min(high, 100.0)


# --- units, commands and status -----------------------------------------------------------------

def test_dry_run_lists_every_reading_and_setting_with_its_command(tmp_path: Path) -> None:
    proc = run_module("analysis.sensitivity", "--dry-run", "--out", str(tmp_path), "--threads", "1",
                      "--reading", "tau01=--tau 0.01")
    lines = proc.stdout.strip().splitlines()
    has_contact = "contact_model" in {f.name for f in dataclasses.fields(TaskSpec)}
    readings = ["ours", "actor_penalty", *(["compliant"] if has_contact else []),
                "gauss02_nowarmup", "lillicrap_nets", "tau01"]
    assert len(lines) == len(readings) * len(sens.SETTINGS) * 5
    if not has_contact:
        assert "reading compliant: this code's TaskSpec has no field contact_model" in proc.stderr
    for reading in readings:
        for region, joints in sens.SETTINGS:
            mine = [ln for ln in lines if f" {tmp_path / reading / f'{region}-j{joints}'}/s" in ln]
            assert [ln.split()[0] for ln in mine] == ["new"] * 5, (reading, region, joints)
            cmd = mine[0].split("<- python ")[1].split()
            expect = {"ours": [], "tau01": ["--tau", "0.01"], **{
                k: list(v.args) for k, v in sens.READINGS.items()}}[reading]
            at = cmd.index("--out")
            assert cmd[at - len(expect):at] == expect and cmd[at - len(expect) - 2] == "--episodes"
            assert cmd[at + 1] == f"{tmp_path / reading / f'{region}-j{joints}'}/s{{seed}}"
            assert cmd[cmd.index("--seeds") + 1:cmd.index("--episodes")] == list("01234")
            assert cmd[cmd.index("--episodes") + 1] == "1000"
    assert not (tmp_path / "ours").exists()  # a dry run writes nothing


@pytest.mark.parametrize("args, said", [
    (["--task", "nosuch=1"], "reading mine: this code's TaskSpec has no field nosuch; skipped"),
    (["--task=nosuch=1"], "reading mine: this code's TaskSpec has no field nosuch; skipped"),
    (["--task", "foo"], "ddpg_her.train refuses its command line: python -m ddpg_her.train: "
                        "error: argument --task: expected KEY=VALUE, got 'foo'")])
def test_a_readings_task_field_is_read_as_ddpg_her_train_reads_it(tmp_path: Path, args,
                                                                    said) -> None:
    """Both spellings of --task name a field this code lacks (the reading is skipped); a
    malformed one is train's refusal, not a missing field (one reader: sweep.task_keys)."""
    (tmp_path / "r.json").write_text(json.dumps({"mine": {"args": args}}))
    proc = run_module("analysis.sensitivity", "--setting", "farbox:3", "--dry-run", "--out",
                      str(tmp_path / "o"), "--readings-file", str(tmp_path / "r.json"),
                      check=False)
    assert said in proc.stderr, proc.stderr


def test_a_one_process_dry_run_puts_every_unit_in_one_train_many_process(tmp_path: Path) -> None:
    proc = run_module("analysis.sensitivity", "--dry-run", "--device", "cuda", "--one-process",
                      "--out", str(tmp_path), "--readings", "ours", "actor_penalty",
                      "--setting", "zheight:3")
    lines = proc.stdout.strip().splitlines()
    assert len(lines) == 10
    assert all("<- one process, unit --region zheight --joints 3" in ln for ln in lines)
    assert sum("--task action_penalty_unit=actor --out" in ln for ln in lines) == 5
    assert "in one process: python -m ddpg_her.train_many --plan" in proc.stderr
    assert "--device cuda" in proc.stderr
    assert not (tmp_path / "ours").exists()  # a dry run writes nothing


def test_units_match_the_commands_started_by_hand(tmp_path: Path) -> None:
    """The two units started in the background before this command existed: same folders, same
    training arguments, so the study resumes them as its own."""
    by_hand = ["--region", "zheight", "--joints", "3", "--seeds", "0", "1", "2", "3", "4",
               "--episodes", "1000", "--task", "action_penalty_unit=actor", "--out",
               str(tmp_path / "actor_penalty/zheight-j3/s{seed}"), "--resume", "--no-progress",
               "--threads", "1"]
    units = sens.units_for([sens.READINGS["actor_penalty"]], [("zheight", 3)], 5, tmp_path, 1000)
    assert units[0].command(1, [])[3:3 + len(by_hand)] == by_hand


def test_status_of_done_partial_and_new_units(tmp_path: Path) -> None:
    root = tmp_path / "actor_penalty"
    for seed in range(5):
        _write_run(root / "zheight-j3" / f"s{seed}", "zheight", 3, seed, 50.0)
        _write_run(root / "farbox-j6" / f"s{seed}", "farbox", 6, seed, 50.0,
                   upto=BUDGET if seed else 300)
    units = {u.setting: u for u in sens.units_for(
        [sens.READINGS["actor_penalty"]], [("zheight", 3), ("farbox", 6), ("closebox", 3)], 5,
        tmp_path, BUDGET)}
    assert [units["zheight-j3"].status(s) for s in range(5)] == ["done"] * 5
    assert [units["farbox-j6"].status(s) for s in range(5)] == ["resume"] + ["done"] * 4
    assert [units["closebox-j3"].status(s) for s in range(5)] == ["new"] * 5
    assert [u.pending() for u in units.values()] == [False, True, True]
    assert units["farbox-j6"].episodes_done() == 300 + 4 * BUDGET
    # a larger budget makes the finished unit resumable again
    longer = sens.units_for([sens.READINGS["actor_penalty"]], [("zheight", 3)], 5, tmp_path,
                            1500)
    assert longer[0].status(0) == "resume"
    out = run_module("analysis.sensitivity", "--dry-run", "--out", str(tmp_path), "--readings",
                     "actor_penalty", "--setting", "zheight:3", "--setting", "farbox:6",
                     "--setting", "closebox:3").stdout.splitlines()
    assert [ln.split()[0] for ln in out] == ["done"] * 5 + ["resume"] + ["done"] * 4 + ["new"] * 5


def test_a_unit_another_process_trains_is_busy(tmp_path: Path) -> None:
    unit = Unit("zheight", 3, (0, 1), tmp_path / "actor_penalty", 1000)
    assert not busy(unit)
    # a stand-in for a trainer: it holds the run folder's lock, as ddpg_her.train does
    code = ("import sys, time; from ddpg_her.runfolder import RunFolder; "
            "RunFolder(sys.argv[1]).lock(); print('locked', flush=True); time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(unit.run_dir(0))],
                            stdout=subprocess.PIPE, text=True, cwd=Path(__file__).parent.parent)
    try:
        assert proc.stdout.readline().strip() == "locked"
        assert busy(unit)
        other = Unit("zheight", 3, (0, 1), tmp_path / "ours", 1000)
        assert not busy(other)
    finally:
        proc.kill()
        proc.wait()


def test_readings_from_the_command_line_and_a_file(tmp_path: Path) -> None:
    r = sens.parse_reading("slow=--tau 0.0001 --critic-lr 1e-4")
    assert r.args == ("--tau", "0.0001", "--critic-lr", "1e-4")
    path = tmp_path / "readings.json"
    path.write_text(json.dumps({"her_future": {"args": "--her-strategy future",
                                               "paper": "final", "ours": "future"}}))
    (loaded,) = sens.load_readings(path)
    assert loaded == sens.Reading("her_future", ("--her-strategy", "future"), "final", "future")
    for bad in ("noequals", "bad/name=--tau 1"):
        with pytest.raises(Exception,
                           match=r"NAME=ARGS|name='bad/name' \(expected a name matching"):
            sens.parse_reading(bad)
    proc = run_module("analysis.sensitivity", "--dry-run", "--readings", "nope", check=False)
    assert proc.returncode == 2 and "unknown reading(s) ['nope']" in proc.stderr
    proc = run_module("analysis.sensitivity", "--dry-run", "--reading", "ours=--tau 1", check=False)
    assert proc.returncode == 2 and "built in with other arguments" in proc.stderr
    sens.write_reading(tmp_path, loaded)
    with pytest.raises(ValueError, match="records reading 'her_future'"):
        sens.write_reading(tmp_path, sens.Reading("her_future", ("--her-k", "8")))


@pytest.mark.parametrize(("entry", "match"), [
    # each was read by str(): arguments [1, null] became '1' 'None', a misspelt key vanished
    ({"args": [1, None]}, r"reading 'x': invalid reading: args=\[1, None\] \(expected a list "
                          r"of ddpg_her.train arguments \(strings\)\)"),
    ({"args": "--tau 0.1", "paper": 5}, r"paper=5 \(expected text"),
    ({"args": "--tau 0.1", "paepr": "eq. 2"}, r"unknown reading field\(s\) \['paepr'\]"),
])
def test_a_readings_file_is_checked_as_the_reading_record(tmp_path: Path, entry: dict,
                                                          match: str) -> None:
    path = tmp_path / "readings.json"
    path.write_text(json.dumps({"x": entry}))
    with pytest.raises(ValueError, match=match):
        sens.load_readings(path)
    with pytest.raises(ValueError, match="invalid reading: args="):
        sens.Reading("x", "--tau 0.1")  # a string is not a list of arguments, in the library too


# --- collect --------------------------------------------------------------------------------------

def test_collect_copies_only_spec_and_eval_of_finished_units(tmp_path: Path, monkeypatch,
                                                              capsys) -> None:
    """Each copy is written whole, by the one atomic writer (issue 37, kind 3: it was
    shutil.copy2, which a kill or a full disk leaves cut short)."""
    root, dest = tmp_path / "runs", tmp_path / "dest"
    for seed in range(2):
        run = root / "ours" / "zheight-j3" / f"s{seed}"
        _write_run(run, "zheight", 3, seed, 40.0)
        for junk in ("checkpoints/episode-001000.pt", "buffer/episode-001000.npz", "tb/x"):
            (run / junk).parent.mkdir(parents=True, exist_ok=True)
            (run / junk).write_bytes(b"x")
        _write_run(root / "ours" / "farbox-j6" / f"s{seed}", "farbox", 6, seed, 40.0, upto=500)
    (root / "ours" / "logs").mkdir()
    (root / "ours" / "logs" / "zheight-j3.log").write_text("log")
    from ddpg_her import runfolder

    written, real = [], runfolder.atomic_write
    monkeypatch.setattr(runfolder, "atomic_write", lambda p, d: (written.append(p), real(p, d)))
    assert sens.main(["--collect", str(dest), "--out", str(root), "--seeds", "2", "--readings",
                      "ours", "--setting", "zheight:3", "--setting", "farbox:6"]) == 0
    stderr = capsys.readouterr().err
    assert "copied 1 finished unit(s)" in stderr and "ours/farbox-j6" in stderr
    copied = sorted(p.relative_to(dest).as_posix() for p in dest.rglob("*") if p.is_file())
    # no reading.json at the source (units started by hand): written from the reading
    assert json.loads((dest / "runs/ours/reading.json").read_text())["args"] == []
    assert copied == ["runs/ours/reading.json",
                      *(f"runs/ours/zheight-j3/s{s}/{n}" for s in range(2)
                        for n in ("eval.csv", "spec.json"))]
    for seed in range(2):
        for name in ("eval.csv", "spec.json"):
            assert (dest / f"runs/ours/zheight-j3/s{seed}/{name}").read_bytes() == \
                (root / f"ours/zheight-j3/s{seed}/{name}").read_bytes()
    assert sorted(written) == sorted(dest / "runs" / c for c in
                                     [c.removeprefix("runs/") for c in copied])


# --- the verdicts ---------------------------------------------------------------------------------

FINALS = {
    # reading: {setting: each seed's successes at the budget}
    "holds": {("farbox", 6): [95, 96, 97, 98, 99], ("unconstrained", 3): [40, 42, 44, 46, 48],
              ("zheight", 3): [20, 21, 22, 23, 24], ("closebox", 3): [18, 19, 20, 21, 22],
              ("unconstrained", 2): [95, 96, 97, 98, 99]},
    "fails": {("farbox", 6): [40, 42, 44, 46, 48], ("unconstrained", 3): [60, 62, 64, 66, 68],
              ("zheight", 3): [80, 82, 84, 86, 88], ("closebox", 3): [18, 19, 20, 21, 22],
              ("unconstrained", 2): [50, 52, 54, 56, 58]},
    "noise": {("farbox", 6): [0, 100, 50, 20, 80], ("unconstrained", 3): [40, 42, 44, 46, 48],
              ("zheight", 3): [10, 80, 45, 30, 60], ("unconstrained", 2): [70, 100, 90, 80, 100]},
    "close": {("farbox", 6): [50, 51, 52, 53, 54], ("unconstrained", 3): [40, 41, 42, 43, 44]},
    "lonely": {("zheight", 3): [20, 21, 22, 23, 24], ("closebox", 3): [18, 19, 20, 21, 22]},
    "short": {("farbox", 6): [95, 97, 99], ("unconstrained", 3): [40, 44, 48]},
}
CLAIMS = ("far box easier than the other regions",
          "unconstrained above zheight and closebox",
          "unconstrained 2 joints highly capable",
          "far box near 100 % by 1,000 episodes, 6 joints")
EXPECTED = {  # at 1,000 episodes, claims about the end of training are not judgeable
    "holds": ("YES", "NOT_JUDGEABLE", "NOT_JUDGEABLE", "YES"),
    "fails": ("NO", "NOT_JUDGEABLE", "NOT_JUDGEABLE", "NO"),
    "noise": ("NOISE", "NOT_JUDGEABLE", "NOT_JUDGEABLE", "NO"),  # 1 of 5 seeds reach 90
    "close": ("YES", "NOT_RUN", "NOT_RUN", "NO"),
    "lonely": ("NOT_RUN", "NOT_RUN", "NOT_RUN", "NOT_RUN"),
    "short": ("YES", "NOT_JUDGEABLE", "NOT_RUN", "YES")}


def _synthetic_study(root: Path) -> None:
    for reading, settings in FINALS.items():
        for (region, joints), finals in settings.items():
            for seed, final in enumerate(finals):
                # a row after the budget that would turn every verdict: it must not count
                _write_run(root / reading / f"{region}-j{joints}" / f"s{seed}", region, joints,
                           seed, final, after=100 - final)
    # fewer episodes than the budget: judged at its last evaluation, marked partial
    for seed, final in enumerate([20, 21, 22, 23, 24]):
        _write_run(root / "short" / "zheight-j3" / f"s{seed}", "zheight", 3, seed, final,
                   upto=600)


def test_verdicts_on_hand_made_runs_follow_hand_computed_intervals(tmp_path: Path) -> None:
    _synthetic_study(tmp_path)
    result = sens.report(tmp_path, tmp_path / "out", reps=4000, worth_goals=0)
    assert result.readings == ["ours", "actor_penalty", "compliant", "gauss02_nowarmup",
                               "lillicrap_nets", *sorted(FINALS)]
    cells = {(c.reading, c.setting): c for c in result.cells}
    for reading, settings in FINALS.items():
        for setting, finals in settings.items():
            cell = cells[(reading, setting)]
            assert cell.episode == BUDGET and cell.levels == pytest.approx(finals)
            assert cell.t == pytest.approx(_hand_t(finals))
            # the percentile bootstrap against scipy's (independent resampling)
            ref = stats.bootstrap((np.asarray(finals, float),), np.mean, n_resamples=20_000,
                                  confidence_level=0.65, method="percentile",
                                  random_state=np.random.default_rng(7)).confidence_interval
            assert cell.boot_mean[1:] == pytest.approx((ref.low, ref.high), abs=2.5)
            assert cell.boot_iqm[0] == pytest.approx(stats.trim_mean(finals, 0.25))
    short_z = cells[("short", ("zheight", 3))]
    assert short_z.episode == 600 and short_z.partial == "600 of 1,000 episodes"
    assert short_z.t == pytest.approx(_hand_t([20, 21, 22, 23, 24]))
    assert cells[("short", ("farbox", 6))].partial == "3 of 5 seeds"
    assert not cells[("holds", ("farbox", 6))].partial

    rows = {(r.claim, r.reading): r for r in result.rows}
    for reading, expected in EXPECTED.items():
        for claim, verdict in zip(CLAIMS, expected, strict=True):
            row = rows[(claim, reading)]
            assert row.t is Verdict[verdict], (claim, reading, row.detail_t)
            if verdict != "NOT_RUN":  # these data are clear enough for every interval
                assert row.boot_mean is Verdict[verdict] and row.boot_iqm is Verdict[verdict]
    for reading in ("ours", "actor_penalty", "compliant", "gauss02_nowarmup", "lillicrap_nets"):
        assert all(rows[(c, reading)].t is Verdict.NOT_RUN for c in CLAIMS)
    # Welch's p-value of the comparison, against its formula
    held = FINALS["holds"]
    assert rows[(CLAIMS[0], "holds")].p_value == pytest.approx(
        _hand_welch(held[("farbox", 6)], held[("unconstrained", 3)]))
    assert rows[(CLAIMS[0], "holds")].confounds[0] == "6 vs 3 joints"
    assert rows[(CLAIMS[0], "short")].partial == \
        "farbox 6: 3 of 5 seeds; unconstrained 3: 3 of 5 seeds; zheight 3: 600 of 1,000 episodes"
    assert rows[(CLAIMS[1], "short")].partial == \
        "unconstrained 3: 3 of 5 seeds; zheight 3: 600 of 1,000 episodes"
    assert rows[(CLAIMS[0], "holds")].partial == ""

    with open(tmp_path / "out" / "verdicts.csv") as f:
        table = {(r["claim"], r["reading"]): r for r in csv.DictReader(f)}
    assert len(table) == 13 * len(result.readings)
    assert table[(CLAIMS[0], "holds")]["verdict_t"] == "holds"
    assert float(table[(CLAIMS[0], "holds")]["welch_p"]) == pytest.approx(
        rows[(CLAIMS[0], "holds")].p_value, rel=1e-3)
    assert table[(CLAIMS[0], "fails")]["verdict_bootstrap_iqm"] == "fails"
    assert table[(CLAIMS[0], "noise")]["verdict_t"] == "within noise"
    assert table[(CLAIMS[1], "holds")]["verdict_t"] == "not judgeable"
    assert table[(CLAIMS[0], "compliant")]["verdict_t"] == "not run"
    text = (tmp_path / "out" / "report.md").read_text()
    assert "every claim about where training ends is not judgeable" in text
    row = next(line for line in text.splitlines() if line.startswith(f"| {CLAIMS[0]} | not run"))
    # readings: the 5 built-in ones (not run), then close, fails, holds, lonely, noise, short
    assert row.startswith(f"| {CLAIMS[0]} | not run | not run | not run | not run | not run | "
                          "holds / holds / holds; p ")
    assert row.split(" | ")[7].startswith("fails / fails / fails; p ")
    assert "| holds (partial) / holds / holds; p " in row
    assert "comparisons made" in text and "## Confounds" in text
    assert (tmp_path / "out" / "curves.png").stat().st_size > 1000
    with open(tmp_path / "out" / "curves.csv") as f:
        curve = [r for r in csv.DictReader(f) if r["reading"] == "holds"
                 and r["region"] == "farbox" and r["episode"] == str(BUDGET)]
    assert float(curve[0]["mean_successes"]) == pytest.approx(97.0)


def test_the_worth_reaching_column_uses_the_optimality_diagnostic(tmp_path: Path,
                                                                  monkeypatch) -> None:
    for reading, extra in (("ours", {}), ("actor_penalty", {"action_penalty_unit": "actor"})):
        for seed in range(2):
            _write_run(tmp_path / reading / "zheight-j3" / f"s{seed}", "zheight", 3, seed, 30.0,
                       extra_task=extra)
    result = sens.report(tmp_path, tmp_path / "a", seeds=2, reps=200, worth_goals=0)
    assert all(c.worth is None for c in result.cells)
    assert "worth-reaching diagnostic skipped" in result.text

    calls = []

    @dataclasses.dataclass(frozen=True)
    class FakeResult:
        share_worth: float
        share_worth_ci: tuple[float, float]

    def worth_reaching(task, goals=500, gamma=0.98, seed=0):
        calls.append((task.action_penalty_unit, goals, gamma, seed))
        return FakeResult(0.5 if task.action_penalty_unit == "actor" else 0.25, (0.2, 0.6))

    import analysis.optimality

    monkeypatch.setattr(analysis.optimality, "worth_reaching", worth_reaching)
    result = sens.report(tmp_path, tmp_path / "b", seeds=2, reps=200, worth_goals=10,
                         boot_seed=3)
    assert sorted(calls) == [("actor", 10, 0.98, 3), ("command", 10, 0.98, 3)]
    worth = {c.reading: c.worth for c in result.cells}
    assert worth == {"ours": (25.0, 20.0, 60.0), "actor_penalty": (50.0, 20.0, 60.0)}
    with open(tmp_path / "b" / "finals.csv") as f:
        assert {r["reading"]: r["worth_reaching"] for r in csv.DictReader(f)} == \
            {"ours": "25", "actor_penalty": "50"}
    assert (tmp_path / "b" / "worth_reaching.png").stat().st_size > 1000


# --- a real unit, end to end ----------------------------------------------------------------------

def test_a_tiny_study_trains_resumes_collects_and_reports(tmp_path: Path) -> None:
    root = tmp_path / "runs"
    toy = ["--env-id", "toy_goal_env:ToyReach-v0", "--hidden-sizes", "16", "16",
           "--eval-every", "2", "--eval-episodes", "2", "--updates-per-episode", "2"]

    def study(*more: str) -> subprocess.CompletedProcess:
        return run_module("analysis.sensitivity", "--out", str(root), "--seeds", "2",
                          "--episodes", "4", "--setting", "box:2", "--readings", "ours", "cheap",
                          "--reading", "cheap=--task action_cost=0.01", "--threads", "1", *more,
                          "--", *toy)

    first = study()
    assert "0 of 2 units already finished" in first.stderr
    for reading in ("ours", "cheap"):
        for seed in (0, 1):
            run = json.loads((root / reading / "box-j2" / f"s{seed}" / "spec.json").read_text())
            assert run["task"]["action_cost"] == (0.01 if reading == "cheap" else 0.05)
            assert run["seed"] == seed and run["agent"]["episodes"] == 4
    assert json.loads((root / "cheap" / "reading.json").read_text())["args"] == \
        ["--task", "action_cost=0.01"]
    log = (root / "cheap" / "logs" / "box-j2.log").read_text()
    assert "2 of 2 units already finished" in study().stderr
    assert (root / "cheap" / "logs" / "box-j2.log").read_text() == log  # nothing re-ran

    study("--collect", str(tmp_path / "dest"))
    assert len(list((tmp_path / "dest" / "runs").rglob("eval.csv"))) == 4
    proc = run_module("analysis.sensitivity", "report", str(tmp_path / "dest" / "runs"),
                      "--out", str(tmp_path / "report"), "--episodes", "4", "--seeds", "2",
                      "--reps", "200", "--worth-goals", "0")
    assert "| cheap | box 2 | 2 | 4 |" in proc.stdout
    for name in ("report.md", "verdicts.csv", "finals.csv", "curves.csv", "curves.png"):
        assert (tmp_path / "report" / name).exists(), name
    assert "--task action_cost=0.01" in (tmp_path / "report" / "report.md").read_text()


def test_the_report_is_reproducible_and_its_bootstrap_seed_matters(tmp_path: Path) -> None:
    """Issue 23: the same runs and --bootstrap-seed give the same bytes, another seed other
    bootstrap intervals (the resampling once drew from numpy's global generator)."""
    _synthetic_study(tmp_path / "runs")
    files = ("report.md", "finals.csv", "verdicts.csv", "curves.csv")

    def made(name: str, seed: int) -> dict[str, bytes]:
        sens.report(tmp_path / "runs", tmp_path / name, reps=500, boot_seed=seed,
                    worth_goals=0)
        return {f: (tmp_path / name / f).read_bytes() for f in files}

    first = made("a", 0)
    np.random.seed(12345)  # noqa: NPY002 (the global generator must not matter)
    assert made("b", 0) == first
    other = made("c", 1)
    assert other["finals.csv"] != first["finals.csv"]
    assert other["curves.csv"] == first["curves.csv"]  # no bootstrap in the curves


def test_a_run_counts_for_the_reading_its_spec_records(tmp_path: Path, monkeypatch) -> None:
    """Issue 23: a run in a reading's folder that was trained under another reading is refused,
    naming it; a folder of an unknown reading must not mix choices."""
    root = tmp_path / "runs"
    for seed in range(2):
        _write_run(root / "ours" / "zheight-j3" / f"s{seed}", "zheight", 3, seed, 20.0)
        _write_run(root / "actor_penalty" / "zheight-j3" / f"s{seed}", "zheight", 3, seed, 30.0,
                   extra_task={"action_penalty_unit": "actor"})
    assert set(sens.group_runs(root)) == {"ours", "actor_penalty"}
    # a choice whose default changed since older runs: runs of either time count for 'ours'
    from analysis.readings import CHOICES

    changed = tuple((n, sec, f, "compliant" if f == "contact_model" else before)
                    for n, sec, f, before in CHOICES)
    monkeypatch.setattr(sens, "CHOICES", changed)
    assert set(sens.group_runs(root)) == {"ours", "actor_penalty"}
    monkeypatch.undo()
    stray = root / "ours" / "zheight-j3" / "s2"
    _write_run(stray, "zheight", 3, 2, 60.0, extra_task={"action_penalty_unit": "actor"})
    with pytest.raises(ValueError, match=re.escape(
            f"{stray}: its spec.json records task.action_penalty_unit = actor where the reading "
            "has command")):
        sens.group_runs(root)
    proc = run_module("analysis.sensitivity", "report", str(root), "--out",
                      str(tmp_path / "out"), "--worth-goals", "0", check=False)
    assert proc.returncode == 2 and f"{stray}: its spec.json records" in proc.stderr
    assert "Traceback" not in proc.stderr and not (tmp_path / "out").exists()
    stray.rename(root / "mine-s2")  # out of the reading's folder: fine again
    mixed = root / "mine" / "zheight-j3"
    _write_run(mixed / "s0", "zheight", 3, 0, 20.0)
    _write_run(mixed / "s1", "zheight", 3, 1, 20.0, extra_task={"contact_model": "compliant"})
    with pytest.raises(ValueError, match=r"reading folder .*mine mixes runs trained under "
                                         r"other choices \(ground contact: stop in"):
        sens.group_runs(root)


def test_a_switch_in_a_reading_is_read_as_the_field_it_turns_on(tmp_path):
    """``--batch-norm`` (a switch, no value) sets ``agent.batch_norm``: a run trained under
    `lillicrap_nets` is that reading's run and not the defaults', checked against the spec.json
    that ``ddpg_her.train`` itself writes for the reading's arguments."""
    import toy_goal_env

    from ddpg_her.train import main as train

    reading = sens.READINGS["lillicrap_nets"]
    assert sens.reading_settings(reading)[("agent", "batch_norm")] == "True"
    out = tmp_path / "run"
    assert train(["--env-id", f"toy_goal_env:{toy_goal_env.ENV_ID}", "--region", "box",
                  "--episodes", "1", "--eval-every", "1", "--eval-episodes", "1",
                  "--hidden-sizes", "8", "8", "--no-progress",
                  "--no-tensorboard", *reading.args, "--out", str(out)]) == 0
    spec = json.loads((out / "spec.json").read_text())
    assert spec["agent"]["batch_norm"] is True
    assert sens.reading_mismatches(reading, spec) == []
    assert sens.reading_mismatches(sens.READINGS["ours"], spec) != []


@pytest.mark.parametrize("text", ["{", '{"args": []}', '{"name": "x", "args": [1], "k": 2}'])
def test_a_malformed_reading_file_is_refused_naming_it(tmp_path: Path, text: str) -> None:
    """A reading.json that is not a reading record was skipped without a word, so its runs
    were reported without their choices."""
    root = tmp_path / "runs"
    _write_run(root / "mine" / "zheight-j3" / "s0", "zheight", 3, 0, 20.0)
    (root / "mine" / "reading.json").write_text(text)
    proc = run_module("analysis.sensitivity", "report", str(root), "--out",
                      str(tmp_path / "out"), "--worth-goals", "0", check=False)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
    assert f"{root / 'mine' / 'reading.json'}: not a reading record" in proc.stderr
    assert not (tmp_path / "out").exists()
