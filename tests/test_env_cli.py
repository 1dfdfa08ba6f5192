"""Subprocess smoke runs of the env's command lines: the benchmark and the animation example."""

from __future__ import annotations

import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]


def run(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout, check=False)


def test_bench_help_explains_every_flag():
    out = run("-m", "benchmarks.env_steps", "--help")
    assert out.returncode == 0, out.stderr
    for flag in ("--steps", "--rounds", "--num-envs", "--region", "--joints",
                 "--control-mode", "--peer", "--seed", "--json", "--reference", "--sync",
                 "--threads", "--batched"):
        assert flag in out.stdout


def test_bench_runs_and_prints_json():
    out = run("-m", "benchmarks.env_steps", "--steps", "40", "--rounds", "1", "--num-envs", "2",
              "--peer", "none", "--json")
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    rows = {row["env"]: row for row in result["results"]}
    assert rows["UR5Reach-v0"]["steps_per_s"] > 0
    assert rows["BatchedReach (N=2)"]["steps_per_s"] > 0
    assert rows["BatchedReach (N=2, pinocchio)"]["ratio_to_single"] > 0
    assert result["substeps_per_step"] == 20 and result["peer"] is None
    assert result["task"]["control_mode"] == "position"


def test_animation_example_writes_a_gif(tmp_path):
    script = str(ROOT / "examples" / "animate_episode.py")
    assert run(script, "--help").returncode == 0
    target = tmp_path / "episode.gif"
    out = run(script, "--region", "zheight", "--joints", "3", "--steps", "3", "--out",
              str(target))
    assert out.returncode == 0, out.stderr
    assert target.stat().st_size > 1000
    assert target.read_bytes()[:6] in (b"GIF87a", b"GIF89a")


def test_contact_study_runs_and_prints_json():
    out = run("-m", "analysis.contact", "--help")
    assert out.returncode == 0, out.stderr
    for flag in ("--region", "--joints", "--goals", "--steps", "--rounds", "--friction",
                 "--seed", "--json"):
        assert flag in out.stdout
    out = run("-m", "analysis.contact", "--goals", "8", "--steps", "30", "--rounds", "1",
              "--json")
    assert out.returncode == 0, out.stderr
    rows = {row["contact_model"]: row for row in json.loads(out.stdout)["rows"]}
    assert set(rows) == {"stop", "compliant"}
    assert rows["stop"]["deepest"] == 0.0 and rows["stop"]["depth_stops"] == 0.0
    assert 0.0 <= rows["compliant"]["reached"] <= 1.0 and rows["compliant"]["steps_per_s"] > 0
