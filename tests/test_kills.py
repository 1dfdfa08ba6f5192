"""Issue 37, kind 1: a SIGKILL at any moment of a run's writes, then the same command (with
--resume), gives the uninterrupted run's eval.csv to the last digit (wall clock aside), for
``ddpg_her.train``, ``ddpg_her.train --seeds`` and a ``ddpg_her.train_many`` stack.

Each case runs real processes on the toy goal env (tests/kill_at.py cuts them); a test session
every 2 of 6 episodes, so checkpoints at episodes 2, 4 and 6 and the first save is cut too. The
kill of a study's parent process (analysis.sweep, and its --one-process) is the last test.
"""

from __future__ import annotations

import csv
import json
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from cli_tools import ROOT, TESTS, child_env

pytestmark = pytest.mark.xdist_group("test_kills")
"""Under pytest-xdist one worker runs this module, so that each kind's uninterrupted runs
(`reference`) are trained once."""

TOY = ["--env-id", "toy_goal_env:ToyReach-v0", "--region", "box", "--joints", "2",
       "--episodes", "6", "--eval-every", "2", "--eval-episodes", "2", "--hidden-sizes", "8",
       "8", "--updates-per-episode", "2", "--warmup-episodes", "1", "--batch-size", "8",
       "--buffer-size", "200"]
"""The runs' task and agent: learning from episode 2, checkpoints at 2, 4 and 6."""

PROCESS = ["--resume", "--no-progress", "--no-tensorboard", "--threads", "1"]


def command(kind: str, root: Path) -> tuple[str, list[str], list[Path]]:
    """(module, arguments, run folders) of one kind of run below ``root``."""
    if kind == "train":
        return "ddpg_her.train", [*TOY, "--out", str(root / "run"), *PROCESS], [root / "run"]
    if kind == "seeds":
        return ("ddpg_her.train", [*TOY, "--seeds", "0", "1", "--out", str(root / "s{seed}"),
                                   *PROCESS], [root / "s0", root / "s1"])
    plan = root / "plan.json"
    units = [[*TOY, "--seeds", str(s), "--out", str(root / f"u{s}" / "s{seed}")] for s in (0, 1)]
    root.mkdir(parents=True, exist_ok=True)
    plan.write_text(json.dumps({"units": units}))
    return ("ddpg_her.train_many", ["--plan", str(plan), *PROCESS],
            [root / "u0" / "s0", root / "u1" / "s1"])


def run(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *argv], capture_output=True, text=True, cwd=ROOT,
                          env=child_env(), timeout=600)


def eval_rows(folder: Path) -> list[dict[str, str]]:
    with open(folder / "eval.csv", newline="") as f:
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[str, list[list[dict[str, str]]]]:
    """Each kind's uninterrupted eval rows, per run folder."""
    out = {}
    for kind in ("train", "seeds", "many"):
        module, args, folders = command(kind, tmp_path_factory.mktemp(kind))
        done = run(["-m", module, *args])
        assert done.returncode == 0, done.stderr
        out[kind] = [eval_rows(f) for f in folders]
        assert all(len(rows) == 3 for rows in out[kind])
    return out


CASES = [
    ("train", [("ckpt_tmp", 1)]), ("train", [("chunk_tmp", 1)]),
    ("train", [("before_ckpt", 1)]), ("train", [("after_ckpt", 1)]),
    ("train", [("after_row", 1)]), ("train", [("ckpt_tmp", 2)]),
    ("train", [("after_row", 2), ("prune", 1)]),
    ("seeds", [("before_ckpt", 2)]), ("seeds", [("ckpt_tmp", 2)]),
    ("seeds", [("after_ckpt", 3)]), ("seeds", [("chunk_tmp", 4), ("prune", 2)]),
    ("many", [("before_ckpt", 2)]), ("many", [("after_ckpt", 3)]),
]
"""(kind of run, kills one after the other): each kill is (moment, N) of tests/kill_at.py; the
same command with --resume then finishes the run. N counts the matching writes of all the
process's folders (with two seeds, N = 2 is the second seed's first checkpoint)."""


@pytest.mark.parametrize("kind, kills", CASES,
                         ids=[f"{k}-" + "+".join(f"{m}{n}" for m, n in ks) for k, ks in CASES])
def test_a_kill_at_any_moment_resumes_to_the_uninterrupted_bytes(tmp_path, reference, kind,
                                                                 kills):
    module, args, folders = command(kind, tmp_path)
    for moment, n in kills:
        killed = run([str(TESTS / "kill_at.py"), moment, str(n), module, *args])
        assert killed.returncode == -signal.SIGKILL, (moment, n, killed.stderr[-3000:])
    done = run(["-m", module, *args])
    assert done.returncode == 0, done.stderr[-3000:]
    assert [eval_rows(f) for f in folders] == reference[kind]
    debris = [p for f in folders for p in f.rglob(".*.tmp*")]
    assert debris == []


# --- the kill of a study's parent process ------------------------------------------------------

SWEEP = ["--setting", "box:2", "--seeds", "1", "--episodes", "6", "--threads", "1", "--",
         *TOY[:2], *TOY[8:], "--no-tensorboard"]
"""analysis.sweep arguments of one unit: the toy run above (the sweep sets its setting, seeds and
budget itself)."""

PAUSE = '''import os
if os.environ.get("KILLS_PAUSE_MARKER"):
    import time
    from ddpg_her import runfolder
    save = runfolder.RunFolder.save_checkpoint
    def paused(self, *args, **kwargs):
        save(self, *args, **kwargs)
        with open(os.environ["KILLS_PAUSE_MARKER"], "w") as f:
            f.write(str(os.getpid()))
        time.sleep(300)
    runfolder.RunFolder.save_checkpoint = paused
'''
"""A sitecustomize for the killed sweep's processes: its training process stops for 300 s after
its first checkpoint (before that checkpoint's eval.csv row), its pid in the marker file."""


def sweep_args(root: Path, one_process: bool) -> list[str]:
    """The sweep's command line (``--no-tensorboard`` is train_many's own flag, which a unit
    may not set: the one-process sweep's unit goes without it)."""
    units = SWEEP[SWEEP.index("--"):]
    if one_process:
        units.remove("--no-tensorboard")
    return ["-m", "analysis.sweep", *SWEEP[:SWEEP.index("--")], "--out", str(root),
            *(["--one-process"] if one_process else []), *units]


def alive(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie (ended, waiting to be reaped)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError):
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc; prctl is Linux's")
@pytest.mark.parametrize("one_process", [False, True], ids=["sweep", "one-process"])
def test_a_killed_sweep_leaves_no_orphan_and_resumes_to_the_uninterrupted_bytes(
        tmp_path, one_process):
    assert TOY[2:8] == ["--region", "box", "--joints", "2", "--episodes", "6"]
    """Issue 37, kind 1, the study's parent: SIGKILL the sweep while its training process is
    in the middle of its run (held after its first checkpoint). The training process must die
    with it: an orphan trained on, holding its folder's lock, so the sweep run again left the
    unit to it and ended at once. The same command then finishes, to the uninterrupted sweep's
    eval.csv (wall clock aside), with no temporary file left."""
    import os
    import time

    reference = run(sweep_args(tmp_path / "reference", one_process))
    assert reference.returncode == 0, reference.stderr[-3000:]
    folder = Path("box-j2") / "s0"
    expected = eval_rows(tmp_path / "reference" / folder)
    assert len(expected) == 3

    hook, marker = tmp_path / "hook", tmp_path / "paused"
    hook.mkdir()
    (hook / "sitecustomize.py").write_text(PAUSE)
    env = child_env()
    env["PYTHONPATH"] = os.pathsep.join([str(hook), env["PYTHONPATH"]])
    env["KILLS_PAUSE_MARKER"] = str(marker)
    root = tmp_path / "killed"
    sweep = subprocess.Popen([sys.executable, *sweep_args(root, one_process)], cwd=ROOT, env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    child = None
    try:
        deadline = time.monotonic() + 300
        while not (marker.exists() and marker.read_text()):
            assert sweep.poll() is None and time.monotonic() < deadline, "no checkpoint came"
            time.sleep(0.2)
        child = int(marker.read_text())
        assert child != sweep.pid and alive(child)
        sweep.send_signal(signal.SIGKILL)
        assert sweep.wait(timeout=60) == -signal.SIGKILL
        deadline = time.monotonic() + 20
        while alive(child) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not alive(child), "the sweep's training process outlived it (an orphan)"
    finally:
        if sweep.poll() is None:
            sweep.kill()
        if child is not None and alive(child):
            os.kill(child, signal.SIGKILL)
    done = run(sweep_args(root, one_process))
    assert done.returncode == 0, done.stderr[-3000:]
    assert eval_rows(root / folder) == expected
    assert [p for p in root.rglob(".*.tmp*")] == []
