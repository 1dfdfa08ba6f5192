"""benchmarks/gpu_grid.sh: the window's script refuses what it cannot do, starts no grid before
the training program exists, and (slow) runs all three stages on the CPU."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCRIPT = ROOT / "benchmarks" / "gpu_grid.sh"


def run(*args: str, tmp_path: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PY": sys.executable, "RUNS": str(tmp_path / "runs"),
           "OUT": str(tmp_path / "out")}
    env.pop("NUMBA_ENABLE_CUDASIM", None)
    return subprocess.run(["bash", str(SCRIPT), *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_the_script_parses_and_says_how_to_use_it(tmp_path):
    assert subprocess.run(["bash", "-n", str(SCRIPT)]).returncode == 0
    usage = run(tmp_path=tmp_path)
    assert usage.returncode == 2
    for word in ("CARRY", ".devsite.tgz", "window 3", "stage 1, smoke", "stage 2, figures",
                 "stage 3, grid", "dry"):
        assert word in usage.stdout, word


def test_a_part_is_a_joint_count(tmp_path):
    bad = run("grid", "7", tmp_path=tmp_path)
    assert bad.returncode == 2 and "part J is a joint count 2-6 or 'all'; got 7" in bad.stderr


def test_stage_3_starts_nothing_before_the_program_exists(tmp_path):
    usage = subprocess.run([sys.executable, "-m", "analysis.sweep", "--help"], cwd=ROOT,
                           capture_output=True, text=True, timeout=120).stdout
    if "--program" in usage:
        pytest.skip("analysis.sweep has --program: stage 3 starts it")
    out = run("grid", "3", tmp_path=tmp_path)
    assert out.returncode == 0, out.stderr
    assert "lists no --program yet" in out.stdout
    assert not (tmp_path / "runs" / "grid.pid").exists()
    packed = run("collect", tmp_path=tmp_path)
    assert packed.returncode == 0 and "nothing to pack" in packed.stdout


@pytest.mark.slow
def test_the_dry_run_runs_every_stage_on_the_cpu(tmp_path):
    dry = run("dry", tmp_path=tmp_path, timeout=900)
    assert dry.returncode == 0, dry.stdout[-3000:] + dry.stderr[-3000:]
    for line in ("stage 1 done", "stage 2 done", "stage 3: started pid",
                 "the grid finished, status 0", "files would come back"):
        assert line in dry.stdout, line
