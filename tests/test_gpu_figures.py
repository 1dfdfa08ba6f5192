"""benchmarks.gpu_figures: stage 2 of a GPU window writes one JSON with every figure, and a
figure that fails is recorded with its error instead of ending the stage."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from benchmarks import gpu_figures

ROOT = Path(__file__).resolve().parent.parent


def test_the_dry_run_writes_every_figure_the_grid_episode_first(tmp_path):
    out = tmp_path / "figures.json"
    run = subprocess.run([sys.executable, "-m", "benchmarks.gpu_figures", "--dry-run",
                          "--out", str(out), "--note", "a test"], cwd=ROOT,
                         capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(out.read_text())
    figures = result["figures"]
    assert list(figures) == ["grid_episode", *gpu_figures.FIGURES]
    failed = {k: v["error"] for k, v in figures.items() if "error" in v}
    assert not failed, failed
    assert result["note"] == "a test"
    assert figures["bandwidth"]["gb_per_s"] > 0
    assert figures["kernel_in_graph"]["rows"][0]["eager_us_per_step"] > 0
    assert [r["name"] for r in figures["updates"]["rows"]] == [
        "today 3-joint eager", "padded 6-joint float32 eager", "padded 6-joint tf32 eager"]
    assert [(r["in_dim"], r["act_dim"]) for r in figures["updates"]["rows"]] == [
        (15, 3), (24, 6), (24, 6)]  # 3 joints: 9 + 3 + 3; padded to 6: 18 + 3 + 3
    grid = figures["grid_episode"]
    assert grid["ms_per_grid_episode"] > 0 and grid["startup_s"] > 0
    assert grid["path"] == "program" and grid["window"] is True
    assert grid["test_session_ms"] > 0 and grid["save_ms"] > 0
    # first and alone: it ended before the next figure began
    assert grid["window_s"][1] <= figures["bandwidth"]["window_s"][0]
    assert result["dry_run"] and result["goals"]["host_syncs_per_episode"] == 0
    headline = result["summary"]
    assert headline["ms_per_grid_episode"] == grid["ms_per_grid_episode"]
    assert headline["save_ms"] == grid["save_ms"]
    assert headline["update_ms padded 6-joint tf32 eager"] == \
        figures["updates"]["rows"][2]["ms_per_update"]
    assert headline["kernel_in_graph_eager_us_per_step_at_3"] > 0
    assert not any("numba" in key for key in headline)


def test_a_failing_figure_is_recorded_and_the_rest_go_on(monkeypatch):
    def broken(ctx):
        raise RuntimeError("no such kernel")

    monkeypatch.setitem(gpu_figures.FIGURES, "bandwidth", broken)
    ctx = gpu_figures.Context("cpu", gpu_figures.DRY, True, time.perf_counter())
    figure = gpu_figures.run_figure("bandwidth", ctx)
    assert figure["error"] == "RuntimeError: no such kernel"
    assert figure["seconds"] >= 0 and len(figure["window_s"]) == 2


def test_the_summary_of_failed_figures_is_empty_not_an_error():
    figures = {"grid_episode": {"error": "timed out"}, "kernel_in_graph": {"error": "x"},
               "updates": {"rows": [{"name": "today 3-joint graph", "error": "y"}]}}
    headline = gpu_figures.summary(figures)
    assert headline["ms_per_grid_episode"] is None and headline["copy_gb_per_s"] is None
    assert headline["update_ms today 3-joint graph"] is None
