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
import shlex
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
