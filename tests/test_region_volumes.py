"""Workspace coverage statistics and the ``python -m analysis.region_volumes`` study."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest

import regions
from analysis import region_volumes
from regions import (
    CONSTRAINED_START,
    UNCONSTRAINED_START,
    CartesianSampler,
    CoverageRow,
    VoxelWorkspace,
    coverage_row,
    sample_workspace,
)

H = regions.DEFAULT_BASE_HEIGHT


def test_voxel_estimate_of_a_known_ball_converges() -> None:
    # Uniform points in a ball of radius 0.5: the estimate brackets the true volume and its
    # error bar shrinks with the voxel edge (enough points per voxel at every step).
    rng = np.random.default_rng(0)
    direction = rng.normal(size=(2_000_000, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    points = direction * 0.5 * rng.random((len(direction), 1)) ** (1 / 3)
    truth = 4 / 3 * math.pi * 0.5**3
    errors = []
    for edge in (0.2, 0.1, 0.05):
        vox = VoxelWorkspace.from_points(points, edge)
        assert abs(vox.volume - truth) <= vox.error
        errors.append(vox.error)
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] / truth < 0.25


def test_voxel_covered_volume_of_an_aligned_box_is_exact() -> None:
    # A full grid of points: every voxel of [0, 1]^3 at edge 0.1 occupied.
    axis = (np.arange(10) + 0.5) * 0.1
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    vox = VoxelWorkspace.from_points(points, 0.1)
    interior = 8**3 * 1e-3
    assert vox.volume == pytest.approx(interior + 0.5 * (1.0 - interior))
    covered, error = vox.covered(regions.Box((0, 1), (0, 1), (0, 1)))
    assert covered == pytest.approx(vox.volume) and error == pytest.approx(vox.error)
    half, _ = vox.covered(regions.Box((0, 0.5), (0, 1), (0, 1)))
    assert 0 < half < covered


def test_workspace_volume_agrees_with_an_independent_ik_estimate() -> None:
    # Two paths to the 3-joint workspace volume: voxel occupancy of joint-space samples, and
    # the Cartesian sampler's reachable fraction of the reach ball above the plane (IK).
    ball = regions.get("unconstrained")
    batch = CartesianSampler(ball, 3, UNCONSTRAINED_START).sample(
        5000, np.random.default_rng(0))
    ik_volume = batch.reachable_fraction * ball.volume
    ws = sample_workspace(3, UNCONSTRAINED_START, H, 400_000, np.random.default_rng(1))
    vox = VoxelWorkspace.from_points(ws.goals[ws.clear], 0.05)
    assert abs(vox.volume - ik_volume) <= vox.error
    assert vox.error < 0.2 * vox.volume


def test_workspace_estimate_converges_as_voxels_shrink() -> None:
    # Samples grow like edge^-3 (the same samples per voxel); the estimate's interval shrinks
    # and each step stays within the previous step's interval.
    previous = None
    for edge, count in ((0.1, 50_000), (0.07, 145_773), (0.05, 400_000)):
        ws = sample_workspace(3, UNCONSTRAINED_START, H, count, np.random.default_rng(2))
        vox = VoxelWorkspace.from_points(ws.goals[ws.clear], edge)
        if previous is not None:
            assert vox.error < previous.error
            assert abs(vox.volume - previous.volume) <= previous.error
        previous = vox


def test_coverage_rows_agree_with_the_samplers() -> None:
    ws = sample_workspace(3, CONSTRAINED_START, H, 200_000, np.random.default_rng(3))
    vox = VoxelWorkspace.from_points(ws.goals[ws.clear], 0.05)
    farbox = regions.get("farbox")
    row = coverage_row(farbox, ws, vox)
    assert row.region == "farbox" and row.joints == 3 and row.start_q == CONSTRAINED_START
    assert row.region_volume_m3 == pytest.approx(0.128)
    assert row.start_inside
    assert 0 < row.covered_volume_m3 <= row.workspace_volume_m3
    assert row.workspace_fraction == pytest.approx(row.covered_volume_m3 / row.workspace_volume_m3)
    # Acceptance two ways: the row's count and the joint-space sampler's proposals.
    batch = regions.JointSpaceSampler(farbox, 3, CONSTRAINED_START).sample(
        1000, np.random.default_rng(4))
    assert row.goal_acceptance == pytest.approx(batch.acceptance, rel=0.2)
    # Covered volume two ways: voxels inside the box, and the box volume times the Cartesian
    # sampler's reachable fraction.
    cart = CartesianSampler(farbox, 3, CONSTRAINED_START).sample(3000, np.random.default_rng(5))
    assert abs(row.covered_volume_m3 - cart.reachable_fraction * 0.128) <= \
        row.covered_volume_error_m3 + 0.01
    # The start's tool0 is 0 m from itself: the distance is from there, and positive.
    assert 0.1 < row.mean_goal_distance_m < 0.9
    assert set(row.json_row()) == set(CoverageRow.JSON_KEYS)


def test_two_joint_workspace_is_flagged_as_a_surface() -> None:
    ws = sample_workspace(2, CONSTRAINED_START, H, 100_000, np.random.default_rng(6))
    coarse = VoxelWorkspace.from_points(ws.goals[ws.clear], 0.1)
    fine = VoxelWorkspace.from_points(ws.goals[ws.clear], 0.05)
    row = coverage_row(regions.get("zheight"), ws, fine)
    assert row.workspace_is_surface
    assert fine.volume < 0.6 * coarse.volume  # a shell: it thins with the voxels
    assert fine.error > 0.9 * fine.volume  # nearly no interior voxel: the bar spans ~0 too


def test_coverage_row_refuses_a_start_the_samples_do_not_hold() -> None:
    ws = sample_workspace(2, CONSTRAINED_START, H, 1000, np.random.default_rng(0))
    vox = VoxelWorkspace.from_points(ws.goals[ws.clear], 0.1)
    with pytest.raises(ValueError, match="held"):
        coverage_row(regions.get("farbox"), ws, vox, UNCONSTRAINED_START)
    # Joints 1..n may differ: the samples do not depend on them.
    row = coverage_row(regions.get("farbox"), ws, vox, (1.0, 0.5, *CONSTRAINED_START[2:]))
    assert row.start_q[0] == 1.0


def test_json_row_turns_nan_into_null() -> None:
    row = CoverageRow("r", 3, (0.0,) * 6, 1.0, True, 1.0, 0.1, 0.0, 0.0, 0.0, 0.0, math.nan,
                      False, 0.05, 10, False)
    assert json.loads(json.dumps(row.json_row()))["mean_goal_distance_m"] is None


def test_study_rows_use_the_paper_starts() -> None:
    settings = region_volumes.Settings(regions=("unconstrained", "farbox"), joints=(3,),
                                       samples=20_000, resolution=0.1)
    study = region_volumes.run_study(settings, progress=False)
    starts = {row.region: row.start_q for row in study.rows}
    assert starts == {"unconstrained": UNCONSTRAINED_START, "farbox": CONSTRAINED_START}
    assert all(row.start_inside for row in study.rows)
    table = region_volumes.format_table(study, settings)
    assert "constrained" in table and "zero" in table


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "analysis.region_volumes", *args],
                          capture_output=True, text=True, timeout=120, check=False)


def test_cli_json_smoke() -> None:
    result = _run("--json", "--samples", "20000", "--resolution", "0.1", "--joints", "2", "3",
                  "--regions", "farbox", "unconstrained", "box:0.3,0.7,-0.2,0.2,0,0.5")
    assert result.returncode == 0, result.stderr
    rows = json.loads(result.stdout)
    assert len(rows) == 6
    for row in rows:
        assert list(row) == list(CoverageRow.JSON_KEYS)
    assert {row["region"] for row in rows} == {"farbox", "unconstrained",
                                               "box:0.3,0.7,-0.2,0.2,0,0.5"}


def test_cli_plot_writes_figure_and_data(tmp_path) -> None:
    out = tmp_path / "regions.png"
    result = _run("--samples", "20000", "--resolution", "0.1", "--joints", "3",
                  "--regions", "farbox", "zheight", "--plot", str(out))
    assert result.returncode == 0, result.stderr
    assert "farbox" in result.stdout
    assert out.stat().st_size > 10_000
    data = json.loads(out.with_suffix(".json").read_text())
    assert set(data["outlines"]) == {"farbox", "zheight"}
    assert out.with_suffix(".csv").read_text().startswith("held_joints_rad,x_m")


def test_cli_help_and_bad_flags() -> None:
    result = _run("--help")
    assert result.returncode == 0
    for flag in ("--regions", "--joints", "--samples", "--seed", "--resolution",
                 "--base-height", "--json", "--plot", "--start"):
        assert flag in result.stdout
    bad = _run("--regions", "nowhere")
    assert bad.returncode == 2 and "cannot read region 'nowhere'" in bad.stderr
    bad = _run("--joints", "7")
    assert bad.returncode == 2 and "--joints" in bad.stderr


def test_a_negative_seed_is_refused_naming_it(capsys) -> None:
    """Issue 37, kind 7 (found by benchmarks/reliability_probe.py): ``--seed -1`` ended in
    numpy's "expected non-negative integer" traceback after the flags were accepted."""
    from analysis import region_volumes

    with pytest.raises(SystemExit) as stop:
        region_volumes.main(["--regions", "farbox", "--samples", "1000", "--seed", "-1"])
    assert stop.value.code == 2
    assert "--seed: -1 (expected an integer >= 0" in capsys.readouterr().err
