"""ur5kin against independent references: Pinocchio, UR's DH parameters, finite differences."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import ur5kin
from ur5kin import closed_form

ANGLE = st.floats(-np.pi, np.pi, allow_nan=False, allow_infinity=False)
CONFIGS = arrays(np.float64, st.tuples(st.integers(1, 16), st.just(6)), elements=ANGLE)
CONFIG = arrays(np.float64, (6,), elements=ANGLE)


def pinocchio_reference(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """tool0 pose, link poses and Jacobian of one configuration, from a fresh Pinocchio Data."""
    model = ur5kin.load_model()
    data = model.createData()
    frame = model.getFrameId("tool0")
    pin.forwardKinematics(model, data, q)
    pin.updateFramePlacements(model, data)
    links = np.array([data.oMi[i].homogeneous for i in range(model.njoints)])
    jac = pin.computeFrameJacobian(model, data, q, frame, pin.LOCAL_WORLD_ALIGNED)
    return data.oMf[frame].homogeneous.copy(), links, jac


def dh_position(q: np.ndarray) -> np.ndarray:
    """tool0 position from UR's published DH parameters (an independent description)."""
    d = [0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823]
    a = [0.0, -0.425, -0.39225, 0.0, 0.0, 0.0]
    alpha = [np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0]
    t = np.eye(4)
    for i in range(6):
        ct, st_ = np.cos(q[i]), np.sin(q[i])
        ca, sa = np.cos(alpha[i]), np.sin(alpha[i])
        t = t @ np.array([
            [ct, -st_ * ca, st_ * sa, a[i] * ct],
            [st_, ct * ca, -ct * sa, a[i] * st_],
            [0.0, sa, ca, d[i]],
            [0.0, 0.0, 0.0, 1.0],
        ])
    return t[:3, 3]


@settings(max_examples=60, deadline=None)
@given(CONFIGS)
def test_closed_form_equals_pinocchio(q: np.ndarray) -> None:
    pos = closed_form.position(q)
    poses = closed_form.link_poses(q)
    jac = closed_form.jacobian_from_poses(poses)
    for i in range(len(q)):
        tool, links, ref_jac = pinocchio_reference(q[i])
        np.testing.assert_allclose(pos[i], tool[:3, 3], rtol=0, atol=1e-10)
        np.testing.assert_allclose(poses[i, -1], tool, rtol=0, atol=1e-10)
        np.testing.assert_allclose(poses[i, :7], links, rtol=0, atol=1e-10)
        np.testing.assert_allclose(jac[i], ref_jac, rtol=0, atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(CONFIG)
def test_public_functions_agree_on_single_and_batched_paths(q: np.ndarray) -> None:
    batch = np.stack([q, -q])
    np.testing.assert_allclose(ur5kin.fk(q), ur5kin.fk(batch)[0], atol=1e-12)
    np.testing.assert_allclose(ur5kin.fk_pose(q), ur5kin.fk_pose(batch)[0], atol=1e-12)
    np.testing.assert_allclose(ur5kin.jacobian(q), ur5kin.jacobian(batch)[0], atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(CONFIG)
def test_matches_ur_dh_parameters_after_half_turn_about_z(q: np.ndarray) -> None:
    flip = np.diag([-1.0, -1.0, 1.0])
    np.testing.assert_allclose(ur5kin.fk(q), flip @ dh_position(q), atol=1e-10)


def test_known_configurations() -> None:
    g = ur5kin.geometry()
    # The URDF writes pi/2 as 1.57079632679, so exact closed-form values hold to ~1e-11 only.
    zero = ur5kin.fk(np.zeros(6))
    np.testing.assert_allclose(
        zero, [g.upper_arm + g.forearm, g.lateral + g.wrist_3, g.d1 - g.wrist_2], atol=1e-9)
    # docs/design.md's constrained start: tool0 near (0.51, 0.19) m, 0.05 m above base_link.
    start = ur5kin.fk([0.0, -np.pi / 4, np.pi / 2, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(start, [0.51, 0.19, 0.05], atol=0.01)
    # A negative shoulder lift raises the arm.
    assert ur5kin.fk([0, -0.5, 0, 0, 0, 0])[2] > zero[2] + 0.1


@pytest.mark.parametrize("shape", [(6,), (5, 6), (2, 3, 6)])
def test_batch_shapes(shape: tuple[int, ...]) -> None:
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, shape)
    assert ur5kin.fk(q).shape == (*shape[:-1], 3)
    assert ur5kin.fk_pose(q).shape == (*shape[:-1], 4, 4)
    assert ur5kin.jacobian(q).shape == (*shape[:-1], 6, 6)
    assert ur5kin.link_poses(q).shape == (*shape[:-1], 8, 4, 4)


def test_numpy_chunking_preserves_order() -> None:
    q = np.random.default_rng(1).uniform(-np.pi, np.pi, (closed_form.CHUNK * 2 + 7, 6))
    expected = closed_form.position(q)
    np.testing.assert_array_equal(ur5kin.fk(q), expected)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 1e-5)])
def test_torch_path_matches_numpy(dtype: torch.dtype, tol: float) -> None:
    q = np.random.default_rng(2).uniform(-np.pi, np.pi, (64, 6))
    qt = torch.from_numpy(q).to(dtype)
    for func in (ur5kin.fk, ur5kin.fk_pose, ur5kin.jacobian, ur5kin.link_poses):
        out = func(qt)
        assert isinstance(out, torch.Tensor) and out.dtype == dtype
        np.testing.assert_allclose(out.double().numpy(), func(q), atol=tol)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
def test_torch_path_on_cuda() -> None:
    q = torch.rand(128, 6, dtype=torch.float64, device="cuda") * 6 - 3
    np.testing.assert_allclose(ur5kin.fk(q).cpu().numpy(), ur5kin.fk(q.cpu().numpy()), atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(CONFIG)
def test_jacobian_equals_finite_differences_of_fk_pose(q: np.ndarray) -> None:
    h = 1e-6
    jac = ur5kin.jacobian(q)
    pose = ur5kin.fk_pose(q)
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = h
        plus, minus = ur5kin.fk_pose(q + dq), ur5kin.fk_pose(q - dq)
        linear = (plus[:3, 3] - minus[:3, 3]) / (2 * h)
        # Angular velocity from dR R^T, which is skew-symmetric [w]x.
        skew = (plus[:3, :3] - minus[:3, :3]) / (2 * h) @ pose[:3, :3].T
        angular = np.array([skew[2, 1], skew[0, 2], skew[1, 0]])
        np.testing.assert_allclose(jac[:3, j], linear, atol=1e-7)
        np.testing.assert_allclose(jac[3:, j], angular, atol=1e-7)


def _contains_config(solutions: np.ndarray, q: np.ndarray, tol: float) -> bool:
    return bool(len(solutions)) and bool(
        (np.abs(ur5kin.wrap(solutions - q)).max(axis=-1) < tol).any()
    )


@settings(max_examples=150, deadline=None)
@given(CONFIG)
def test_ik_solutions_reproduce_pose_and_include_source(q: np.ndarray) -> None:
    pose = ur5kin.fk_pose(q)
    solutions = ur5kin.ik(pose)
    assert 1 <= len(solutions) <= 8
    assert np.all(np.abs(solutions) <= np.pi + 1e-12)
    for s in solutions:
        np.testing.assert_allclose(ur5kin.fk_pose(s), pose, atol=1e-8)
    # Away from the wrist, elbow and shoulder singularities the source is one of the solutions.
    g = ur5kin.geometry()
    wrist3 = pose[:3, 3] - g.wrist_3 * (pose[:3, :3] @ np.asarray(g.tool_rotation).T)[:, 1]
    assume(abs(np.sin(q[4])) > 1e-3 and abs(np.sin(q[2])) > 1e-3)
    assume(np.hypot(wrist3[0], wrist3[1]) > g.lateral + 1e-3)
    assert _contains_config(solutions, q, 1e-6)


@pytest.mark.parametrize("q5", [0.0, np.pi, 1e-9])
def test_ik_wrist_singularity_returns_family_members(q5: float) -> None:
    q = np.array([0.3, -1.0, 1.2, 0.4, q5, 0.7])
    pose = ur5kin.fk_pose(q)
    solutions = ur5kin.ik(pose)
    assert len(solutions) >= 1
    assert len(solutions) <= 8
    for s in solutions:
        np.testing.assert_allclose(ur5kin.fk_pose(s), pose, atol=1e-8)
    # The pan branch of the source keeps the wrist singular (the other pan sees it tilted);
    # along that family only c + cos(q5) q6 is fixed, with c = pi + q2 + q3 + q4.
    solutions = solutions[np.abs(ur5kin.wrap(solutions[:, 0] - q[0])) < 1e-8]
    assert len(solutions) >= 1 and np.all(np.abs(np.sin(solutions[:, 4])) < 1e-6)
    invariant = ur5kin.wrap(np.pi + solutions[:, 1:4].sum(axis=1) + np.cos(q5) * solutions[:, 5])
    expected = ur5kin.wrap(np.pi + q[1:4].sum() + np.cos(q5) * q[5])
    np.testing.assert_allclose(ur5kin.wrap(invariant - expected), 0.0, atol=1e-8)


def test_ik_elbow_singularity_gives_one_solution_per_branch() -> None:
    q = np.array([0.2, -0.7, 0.0, 0.5, 1.1, -0.3])  # straight elbow: both elbow signs coincide
    solutions = ur5kin.ik(ur5kin.fk_pose(q))
    assert _contains_config(solutions, q, 1e-6)
    assert len(solutions) == len(np.unique(np.round(solutions, 6), axis=0))


@pytest.mark.parametrize("xyz", [(2.0, 0.0, 0.3), (0.0, 0.0, 1.5), (0.01, 0.0, 0.3)])
def test_ik_out_of_reach_is_empty(xyz: tuple[float, float, float]) -> None:
    pose = np.eye(4)
    pose[:3, 3] = xyz
    assert ur5kin.ik(pose).shape == (0, 6)


@settings(max_examples=60, deadline=None)
@given(CONFIG)
def test_ik_position_recovers_joints_1_to_3(q: np.ndarray) -> None:
    target = ur5kin.fk(q)
    solutions, valid = ur5kin.ik_position(target, q[3:])
    assert valid.any()
    np.testing.assert_allclose(ur5kin.fk(solutions[valid]), np.broadcast_to(
        target, (int(valid.sum()), 3)), atol=1e-8)
    np.testing.assert_allclose(solutions[valid][:, 3:], np.broadcast_to(
        ur5kin.wrap(q[3:]), (int(valid.sum()), 3)), atol=1e-12)
    assume(abs(np.sin(q[2])) > 1e-3)
    assert _contains_config(solutions[valid], q, 1e-6)


def test_ik_position_batched_and_unreachable() -> None:
    rng = np.random.default_rng(3)
    q = rng.uniform(-np.pi, np.pi, (50, 6))
    solutions, valid = ur5kin.ik_position(ur5kin.fk(q), q[:, 3:])
    assert solutions.shape == (50, 4, 6) and valid.shape == (50, 4)
    assert valid.any(axis=1).all()
    far, far_valid = ur5kin.ik_position([3.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    assert not far_valid.any() and np.isnan(far).all()


def test_subchain_moves_only_the_first_joints() -> None:
    start_q = np.array([0.0, -np.pi / 4, np.pi / 2, 0.3, -0.2, 0.1])
    chain = ur5kin.SubChain(3, start_q)
    head = np.array([[0.1, -0.5, 0.9], [0.4, -1.0, 1.5]])
    full = chain.full(head)
    np.testing.assert_array_equal(full[:, :3], head)
    np.testing.assert_array_equal(full[:, 3:], np.broadcast_to(start_q[3:], (2, 3)))
    np.testing.assert_allclose(chain.fk(head), ur5kin.fk(full))
    np.testing.assert_allclose(chain.jacobian(head), ur5kin.jacobian(full)[..., :3])
    with pytest.raises(ValueError, match="n_joints"):
        ur5kin.SubChain(7, start_q)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        chain.full(np.zeros(4))


def test_world_transform_is_pinocchio_with_the_base_lifted() -> None:
    # second path: Pinocchio's own placement of base_link at (0, 0, h) in a world frame
    h = 0.37
    model = ur5kin.load_model()
    data = model.createData()
    frame = model.getFrameId(ur5kin.TOOL_FRAME)
    world_M_base = pin.SE3(np.eye(3), np.array([0.0, 0.0, h]))
    q = np.random.default_rng(11).uniform(-np.pi, np.pi, (20, 6))
    expected = []
    for qi in q:
        pin.framesForwardKinematics(model, data, qi)
        expected.append((world_M_base * data.oMf[frame]).translation)
    np.testing.assert_allclose(ur5kin.fk_world(q, h), expected, atol=1e-12)
    np.testing.assert_allclose(ur5kin.to_base(ur5kin.fk_world(q, h), h), ur5kin.fk(q),
                               atol=1e-12)
    out = ur5kin.fk(q)
    assert ur5kin.to_world(out, h, out=out) is out
    np.testing.assert_allclose(out, expected, atol=1e-12)
    with pytest.raises(ValueError, match="base_height"):
        ur5kin.to_world(out, -0.1)


@pytest.mark.parametrize("func", [ur5kin.fk, ur5kin.fk_pose, ur5kin.jacobian, ur5kin.link_poses])
def test_bad_joint_input_raises(func) -> None:
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 6\).*got shape \(5,\)"):
        func(np.zeros(5))
    with pytest.raises(ValueError, match=r"finite.*q\[1, 2\] = nan"):
        func(np.where(np.arange(12).reshape(2, 6) == 8, np.nan, 0.0))
    with pytest.raises(ValueError, match="inf"):
        func([0, 0, np.inf, 0, 0, 0])
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 6\)"):
        func(torch.zeros(3, 4))
    with pytest.raises(ValueError, match="finite"):
        func(torch.full((6,), float("nan")))


def test_bad_pose_input_raises() -> None:
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 4, 4\)"):
        ur5kin.ik(np.eye(3))
    skewed = np.eye(4)
    skewed[0, 1] = 0.5
    with pytest.raises(ValueError, match="rigid transform"):
        ur5kin.ik(skewed)
    mirrored = np.diag([1.0, 1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="det"):
        ur5kin.ik(mirrored)
    bottom = np.eye(4)
    bottom[3, 0] = 1.0
    with pytest.raises(ValueError, match="last row"):
        ur5kin.ik(bottom)
    with pytest.raises(ValueError, match="one pose"):
        ur5kin.ik(np.stack([np.eye(4), np.eye(4)]))
    with pytest.raises(ValueError, match="finite"):
        ur5kin.ik(np.full((4, 4), np.nan))


def test_model_is_found_through_the_installed_package() -> None:
    path = ur5kin.urdf_path()
    assert path.name == "ur5_robot.urdf" and path.is_file()
    mesh = ur5kin.resolve_package_uri(
        "package://example-robot-data/robots/ur_description/meshes/ur5/collision/base.stl")
    assert mesh.is_file()
    np.testing.assert_allclose(ur5kin.effort_limits(), [150, 150, 150, 28, 28, 28])
    with pytest.raises(ValueError, match="package://example-robot-data/"):
        ur5kin.resolve_package_uri("file:///tmp/x.stl")


def test_geometry_rejects_a_model_of_another_layout() -> None:
    model = pin.Model(ur5kin.load_model())
    placement = model.jointPlacements[3]
    placement.translation = placement.translation + np.array([0.05, 0.0, 0.0])
    model.jointPlacements[3] = placement
    with pytest.raises(RuntimeError, match="joint 3 placement"):
        ur5kin.UR5Geometry.from_model(model)


ROOT = Path(__file__).resolve().parents[1]


def _run_module(*args: str) -> subprocess.CompletedProcess:
    """``python -m`` from the repository root (benchmarks/ is not an installed package)."""
    return subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True,
                          timeout=120, check=True, cwd=ROOT)


def test_bench_cli_reports_every_path_against_the_loop() -> None:
    out = json.loads(_run_module("benchmarks.fk_paths", "--n", "3000", "--rounds", "1",
                                 "--json").stdout)
    paths = {p["name"]: p for p in out["paths"]}
    assert paths["pinocchio python loop"]["ratio_to_loop"] == pytest.approx(1.0)
    assert {"numpy closed form (float64)", "torch cpu float64", "torch cpu float32"} <= set(paths)
    assert all(p["max_error_m"] < 1e-5 and p["configs_per_s"] > 0 for p in out["paths"])


def test_bench_cli_rejects_bad_flags() -> None:
    proc = subprocess.run([sys.executable, "-m", "benchmarks.fk_paths", "--n", "0"],
                          capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert proc.returncode == 2 and "--n" in proc.stderr


def test_demo_cli_runs() -> None:
    out = subprocess.run([sys.executable, str(ROOT / "examples" / "ur5kin_tour.py"), "--batch",
                          "1000"], capture_output=True, text=True, timeout=120, check=True).stdout
    assert "constrained start" in out and "IK of a random pose" in out
