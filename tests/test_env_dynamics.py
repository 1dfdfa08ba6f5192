"""The arm's physics (envs.physics.pinocchio_loop), checked against Pinocchio and first principles.

The plane checks use ``arm_geometry.brute_force_heights``: Pinocchio's geometry placements (oMg)
applied to the URDF's collision meshes, with none of ur5kin.collision's closed forms.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from arm_geometry import brute_force_heights
from stepping import record

import ur5kin
from envs.physics.model import height_lipschitz
from envs.physics.pinocchio_loop import PinocchioDynamics
from envs.spec import TaskSpec

H = 1e-3  # s, the default substep


def run(dyn: PinocchioDynamics, commands: np.ndarray) -> dict[str, np.ndarray]:
    """Step through ``commands (T, B, n)``; the state after each step, stacked."""
    return record(dyn, commands, ("q", "v", "acceleration", "contact", "limit_stop"))


def test_time_scaled_model_gives_pinocchios_dynamics():
    dyn = PinocchioDynamics(TaskSpec())
    base = ur5kin.load_model()
    data = base.createData()
    rng = np.random.default_rng(0)
    for _ in range(20):
        q, v, tau = rng.uniform(-3, 3, 6), rng.uniform(-3, 3, 6), rng.uniform(-50, 50, 6)
        a = pin.aba(base, data, q, v, tau).copy()
        a_scaled = pin.aba(dyn.model, dyn.data, q, H * v, H * H * tau) / H**2
        np.testing.assert_allclose(a_scaled, a, rtol=1e-9, atol=1e-9)
        g = pin.computeGeneralizedGravity(base, data, q).copy()
        g_scaled = pin.computeGeneralizedGravity(dyn.model, dyn.data, q) / H**2
        np.testing.assert_allclose(g_scaled, g, rtol=1e-12, atol=1e-12)


def test_pd_gains_are_stable_on_the_coupled_arm():
    # semi-implicit Euler on the PD loop linearised at rest: (q, u = h v) -> A (q, u)
    task, model = TaskSpec(), ur5kin.load_model()
    data = model.createData()
    kp, kd, eye = np.diag(task.kp), np.diag(task.kd), np.eye(6)
    radii = []
    for q in np.random.default_rng(1).uniform(-np.pi, np.pi, (500, 6)):
        M = pin.crba(model, data, q)
        M_inv = np.linalg.inv(np.triu(M) + np.triu(M, 1).T)
        du_dq, du_du = -H * H * M_inv @ kp, eye - H * M_inv @ kd
        A = np.block([[eye + du_dq, du_du], [du_dq, du_du]])
        radii.append(np.abs(np.linalg.eigvals(A)).max())
    assert max(radii) < 0.99  # 0.986 measured: every mode decays by >= 1 % per millisecond


@pytest.mark.parametrize("mode", ["position", "torque"])
def test_a_held_pose_stays_still(mode):
    task = TaskSpec(region="zheight", n_joints=3, control_mode=mode)
    dyn = PinocchioDynamics(task)
    start = np.asarray(task.start_q)
    hold = start[None, :3] if mode == "position" else np.zeros((1, 3))
    log = run(dyn, np.repeat(hold[None], 100, axis=0))
    assert np.abs(log["q"] - start).max() < 1e-9
    assert np.abs(log["v"]).max() < 1e-9
    assert not log["contact"].any()


def test_without_gravity_compensation_the_arm_falls_at_pinocchios_rate():
    task = TaskSpec(region="unconstrained", n_joints=6, control_mode="torque",
                    gravity_compensation=False)
    dyn = PinocchioDynamics(task)
    q0 = np.asarray(task.start_q)  # all zeros: the arm stretched horizontally
    model = ur5kin.load_model()
    data = model.createData()
    M = pin.crba(model, data, q0)
    a0 = np.linalg.solve(np.triu(M) + np.triu(M, 1).T,
                         -pin.computeGeneralizedGravity(model, data, q0))
    tool_z0 = ur5kin.fk(q0)[2]
    dyn.step(np.zeros((1, 6)))
    assert dyn.q[0, 1] > 0.0  # a positive shoulder lift lowers the arm in this URDF
    assert ur5kin.fk(dyn.q[0])[2] < tool_z0
    # the mean acceleration over 20 ms stays within 2 % of the initial one (crba + gravity)
    np.testing.assert_allclose(dyn.acceleration[0, 1:3], a0[1:3], rtol=0.02)


def test_a_free_arm_conserves_energy():
    start = (0.0, -1.2, 0.6, 0.3, 0.2, 0.1)
    task = TaskSpec(region="unconstrained", n_joints=6, control_mode="torque",
                    gravity_compensation=False, start_q=start)
    dyn = PinocchioDynamics(task)
    model = ur5kin.load_model()
    data = model.createData()

    def energy(q: np.ndarray, v: np.ndarray) -> tuple[float, float]:
        kinetic = pin.computeKineticEnergy(model, data, q, v)
        return kinetic + pin.computePotentialEnergy(model, data, q), kinetic

    e0, _ = energy(np.asarray(start), np.zeros(6))
    log = run(dyn, np.zeros((6, 1, 6)))  # 0.12 s of free fall
    assert not (log["contact"].any() or log["limit_stop"].any())
    assert np.all(np.abs(log["v"]) < ur5kin.velocity_limits())  # no velocity clip either
    energies = [energy(q[0], v[0]) for q, v in zip(log["q"], log["v"], strict=True)]
    kinetic = max(k for _, k in energies)
    assert kinetic > 1.0  # J: the arm really fell
    drift = max(abs(e - e0) for e, _ in energies)
    assert drift < 0.01 * kinetic


@pytest.mark.parametrize(("region", "n_joints"), [("unconstrained", 3), ("zheight", 3),
                                                  ("unconstrained", 6)])
def test_a_commanded_pose_is_tracked_within_an_episode(region, n_joints):
    task = TaskSpec(region=region, n_joints=n_joints)
    rng = np.random.default_rng(7)
    errors = []
    for _ in range(16):
        target = rng.uniform(-np.pi, np.pi, (1, n_joints))
        log = run(PinocchioDynamics(task), np.repeat(target[None], 100, axis=0))
        if log["contact"].any() or log["limit_stop"].any():
            continue  # the straight path went through the plane: nothing to track
        errors.append(np.abs(log["q"][-1, 0, :n_joints] - target[0]).max())
        assert np.abs(log["v"][-1]).max() < 1e-3
    assert len(errors) >= 3
    assert max(errors) < 1e-3  # rad after 2 s; measured <= 1e-4


def test_velocity_mode_tracks_a_commanded_velocity():
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode="velocity")
    log = run(PinocchioDynamics(task), np.repeat(np.array([[[1.0, 0.0, 0.0]]]), 10, axis=0))
    np.testing.assert_allclose(log["v"][-1, 0, :3], [1.0, 0.0, 0.0], atol=1e-3)
    # the pan joint follows a first-order lag of time constant I / kd: after t = 0.2 s at
    # 1 rad/s it trails by tau (1 - exp(-t / tau)) rad
    model = ur5kin.load_model()
    inertia = pin.crba(model, model.createData(), np.asarray(task.start_q))[0, 0]
    tau = inertia / task.kd[0]
    expected = 0.2 - tau * (1.0 - np.exp(-0.2 / tau))
    np.testing.assert_allclose(log["q"][-1, 0, 0], expected, atol=3e-3)


@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_velocities_stay_within_the_urdf_limits(mode):
    task = TaskSpec(region="unconstrained", n_joints=6, control_mode=mode)
    dyn = PinocchioDynamics(task)
    from envs.task import action_bounds

    low, high = action_bounds(task)
    log = run(dyn, np.random.default_rng(3).uniform(low, high, (150, 1, 6)))
    assert np.all(np.abs(log["v"]) <= ur5kin.velocity_limits() + 1e-12)
    assert np.all(np.isfinite(log["q"])) and np.all(np.isfinite(log["acceleration"]))


def test_the_plane_stops_the_arm_dead():
    task = TaskSpec(region="zheight", n_joints=3)
    dyn = PinocchioDynamics(task)
    down = np.array([[[0.0, 1.2, 0.3]]])  # lowers the arm into the plane
    log = run(dyn, np.repeat(down, 60, axis=0))
    hits = np.flatnonzero(log["contact"][:, 0])
    assert hits.size > 0
    assert np.all(log["v"][hits] == 0.0)
    heights = brute_force_heights(log["q"][:, 0], task.base_height)
    assert heights.min() >= -1e-9
    assert heights[hits].min() < 0.03  # m: it stopped right at the plane


def test_the_screen_never_changes_the_answer():
    task = TaskSpec(region="unconstrained", n_joints=6)
    commands = np.random.default_rng(4).uniform(-np.pi, np.pi, (300, 1, 6))
    screened = run(PinocchioDynamics(task), commands)
    exact = PinocchioDynamics(task)
    exact._plane_screen = np.full(6, np.inf)  # every step gets the exact clearance check
    checked = run(exact, commands)
    assert screened["contact"].any()
    for key, value in screened.items():
        np.testing.assert_array_equal(value, checked[key], err_msg=key)


def test_the_clearance_bound_holds():
    # |z_k(q') - z_k(q)| <= |q' - q| @ R[:, k] for the lowest point of every moving link
    R = height_lipschitz()
    rng = np.random.default_rng(5)
    q = rng.uniform(-np.pi, np.pi, (4000, 6))
    q2 = q + rng.uniform(-0.1, 0.1, q.shape)
    dz = np.abs(ur5kin.link_heights(q2, 0.1) - ur5kin.link_heights(q, 0.1))[:, 1:]
    bound = np.abs(q2 - q) @ R
    assert np.all(dz <= bound + 1e-12)
    assert (dz / np.maximum(bound, 1e-12)).max() > 0.3  # and it is not vacuous


@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_batched_copies_match_single_copies(mode):
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode=mode)
    from envs.task import action_bounds

    low, high = action_bounds(task)
    commands = np.random.default_rng(6).uniform(low, high, (120, 4, 3))
    batch = run(PinocchioDynamics(task, 4), commands)
    assert batch["contact"].any()
    for i in range(4):
        one = run(PinocchioDynamics(task), commands[:, i : i + 1])
        np.testing.assert_array_equal(one["contact"][:, 0], batch["contact"][:, i])
        np.testing.assert_allclose(one["q"][:, 0], batch["q"][:, i], atol=1e-9)
        np.testing.assert_allclose(one["v"][:, 0], batch["v"][:, i], atol=1e-7)


def test_joint_limits_stop_the_arm():
    task = TaskSpec(region="zheight", n_joints=3, control_mode="velocity")
    dyn = PinocchioDynamics(task)
    log = run(dyn, np.repeat(np.array([[[0.0, 0.0, 3.0]]]), 40, axis=0))  # elbow to +pi
    stops = np.flatnonzero(log["limit_stop"][:, 0])
    assert stops.size > 0
    assert log["q"][:, 0, 2].max() <= np.pi
    assert log["q"][stops[0], 0, 2] > np.pi - 0.1
    assert np.all(log["v"][stops, 0] == 0.0)


def test_reset_refuses_a_pose_in_the_plane():
    dyn = PinocchioDynamics(TaskSpec())
    with pytest.raises(ValueError, match="below the plane"):
        dyn.reset(np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0]))
