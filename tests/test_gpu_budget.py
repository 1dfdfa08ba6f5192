"""The launch budget of the training program's bodies (issue 42) does not rise: the GPU path's
bodies (the fused step kernels, counted under Triton's interpreter) of a one-agent stack
counted now against results/grid_program/gpu_budget_guard.json, counted by the same code
(`benchmarks.gpu_budget`, its settings recorded there).

A body's launch count does not depend on the agents' number or their networks' widths, only on
the code path and the goal draw's passes: the acting episode's count is the grid's (one pass
at 1, 4 or 55 copies), so the committed 3-joint part's guards the grid's rollout budget."""

from __future__ import annotations

import importlib
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import gpu_budget

RESULTS = Path(__file__).parents[1] / "results" / "grid_program"


@pytest.fixture(scope="module")
def guard():
    return json.loads((RESULTS / "gpu_budget_guard.json").read_text())


def test_the_rollout_meets_its_budget_on_the_gpu_path(guard):
    """Rollout + store within issue 42's 1,500 launches per grid episode, in the committed
    counts of the 3-joint part and of the guard's stack (the same code path)."""
    part = json.loads((RESULTS / "gpu_budget_part3.json").read_text())
    assert part["path"] == guard["path"] == "fused"
    assert part["rollout_store"] <= 1500 and guard["rollout_store"] <= 1500


def test_no_body_launches_more_than_its_committed_budget(tmp_path, guard, monkeypatch):
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    import ddpg_her.program_kernels as kernels

    importlib.reload(kernels)
    program = gpu_budget.build(guard["part"], guard["seeds"], shlex.split(guard["unit_args"]),
                               tmp_path, fused=True)
    try:
        bodies = gpu_budget.count_bodies(program)
    finally:
        program.close()
    over = {name: (bodies[name]["launches"], body["launches"])
            for name, body in guard["bodies"].items()
            if bodies[name]["launches"] > body["launches"]}
    assert not over, f"bodies over their committed launch budget (now, budget): {over}"


def test_the_fused_kernels_spill_nothing_for_sm90():
    """Every kernel of ddpg_her.program_kernels (the step's and the update's) compiled for
    sm_90 by Triton's own compiler, in a child process without the interpreter: ptxas reports
    no spill (the update's tiles are sized for this: 4,096 elements spilled the normalisation's
    240 B)."""
    env = {**os.environ, "TRITON_INTERPRET": "0", "TRITON_ALWAYS_COMPILE": "1"}
    run = subprocess.run([sys.executable, "-c", "import json; from benchmarks.gpu_budget import "
                          "fused_figures; print(json.dumps(fused_figures(90)))"],
                         env=env, capture_output=True, text=True, timeout=600, check=True)
    figures = json.loads(run.stdout.strip().splitlines()[-1])
    assert {"update_head_critic", "update_adam", "update_normalize", "settle"} <= set(figures)
    spilled = {name: f for name, f in figures.items()
               if f["spill_store_bytes"] or f["spill_load_bytes"]}
    assert not spilled, spilled
