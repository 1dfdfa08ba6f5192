"""benchmarks/gpu_grid.sh: the window's script refuses what it cannot do, and (slow) runs the
window on the CPU: the grid first in window mode choosing its budget, smoke and figures beside
it, the grid packed."""

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
    for word in ("CARRY", ".devsite.tgz", "gpu_grid.sh window", "finish 240", "grid     first",
                 "--window", "--budget-seconds", "20000/10000/5000/2500", "smoke    beside it",
                 "figures  beside it", "dry"):
        assert word in usage.stdout, word


def test_a_part_is_a_joint_count(tmp_path):
    bad = run("grid", "7", tmp_path=tmp_path)
    assert bad.returncode == 2 and "part J is a joint count 2-6 or 'all'; got 7" in bad.stderr


def test_collect_without_a_grid_packs_nothing(tmp_path):
    packed = run("collect", tmp_path=tmp_path)
    assert packed.returncode == 0 and "nothing to pack" in packed.stdout


@pytest.mark.slow
def test_the_dry_run_runs_the_window_on_the_cpu(tmp_path):
    dry = run("dry", tmp_path=tmp_path, timeout=900)
    assert dry.returncode == 0, dry.stdout[-3000:] + dry.stderr[-3000:]
    assert "analysis.sweep --grid paper --program --window --budget-seconds 720  " \
           "--episodes 20000 --device cuda" in dry.stdout
    for line in ("grid: started pid", "smoke done", "figures done", "window budget:",
                 "-> 4 episodes", "the grid finished, status 0", "files would come back"):
        assert line in dry.stdout, line
    # the grid started before smoke and figures
    assert dry.stdout.index("grid: started pid") < dry.stdout.index("smoke (budget")
