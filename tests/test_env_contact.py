"""The ground-contact models of envs.physics.pinocchio_loop (TaskSpec.contact_model), against
independent checks.

The references here share no code with envs.physics.pinocchio_loop.PlaneContact: link heights come
from ur5kin.link_heights (the closed-form clearance kernel) or from Pinocchio's geometry placements
(test_env_dynamics.brute_force_heights), point Jacobians from ur5kin.link_poses' closed form.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from arm_geometry import brute_force_heights
from stepping import record

import ur5kin
from envs.gains import CONTACT_MIN_EFFECTIVE_MASS, contact_stability_violations
from envs.physics.model import link_hulls
from envs.physics.pinocchio_loop import PinocchioDynamics, PlaneContact
from envs.spec import TaskSpec
from ur5kin.closed_form import JOINT_AXES

COMPLIANT = {"contact_model": "compliant"}


def run(dyn: PinocchioDynamics, commands: np.ndarray) -> dict[str, np.ndarray]:
    """Step through ``commands (T, B, n)``; the state after each step, stacked."""
    return record(dyn, commands, ("q", "v", "contact", "limit_stop", "depth_stop"))


def contact_states(task: TaskSpec, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``count`` configurations ``(count, 6)`` rad with some link 0.5-15 mm below the plane, and
    random velocities ``(count, 6)`` rad/s."""
    rng = np.random.default_rng(seed)
    found = []
    while len(found) < count:
        q = rng.uniform(-np.pi, np.pi, (4000, 6))
        low = ur5kin.link_heights(q, task.base_height)[:, 1:].min(axis=1) - task.plane_margin
        found.extend(q[(low < -0.0005) & (low > -0.015)])
    return np.array(found[:count]), rng.uniform(-2.0, 2.0, (count, 6))


def closed_form_torque(task: TaskSpec, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The contact torque (N m) of the module docstring's equations, in closed form:
    ur5kin.link_poses for the links, ``axis_j x (p - o_j)`` for the point Jacobians."""
    poses = ur5kin.link_poses(q)[1:7]  # moving links in base_link
    tau = np.zeros(6)
    level = task.plane_margin - task.base_height
    for k, hull in enumerate(link_hulls()):
        rotation, origin = poses[k, :3, :3], poses[k, :3, 3]
        world = hull @ rotation.T + origin
        i = int(np.argmin(world[:, 2]))
        depth = level - world[i, 2]
        if depth <= 0.0:
            continue
        J = np.zeros((3, 6))
        for j in range(k + 1):  # joints 1..k+1 move link k+1
            axis = poses[j, :3, :3] @ JOINT_AXES[j]
            J[:, j] = np.cross(axis, world[i] - poses[j, :3, 3])
        u = J @ v
        normal = max(task.contact_stiffness * depth - task.contact_damping * u[2], 0.0)
        speed = np.hypot(u[0], u[1])
        drag = min(task.contact_friction * normal, task.contact_damping * speed)
        tangent = -drag * u[:2] / speed if speed > 0 else np.zeros(2)
        tau += J.T @ np.array([tangent[0], tangent[1], normal])
    return tau


def contact_torque(contact: PlaneContact, task: TaskSpec, q: np.ndarray, v: np.ndarray
                   ) -> np.ndarray:
    """PlaneContact's torque in N m (it works in h^2-scaled units with w = h v)."""
    h = task.sim_dt
    out = np.zeros(6)
    contact.torque(q, h * v, [1, 2, 3, 4, 5, 6], out)
    return out / h**2


def test_the_contact_torque_matches_a_closed_form_jacobian():
    task = TaskSpec(**COMPLIANT, contact_friction=0.6)
    contact = PlaneContact(task, ur5kin.load_model())
    qs, vs = contact_states(task, 40, seed=0)
    for q, v in zip(qs, vs, strict=True):
        np.testing.assert_allclose(contact_torque(contact, task, q, v),
                                   closed_form_torque(task, q, v), rtol=1e-9, atol=1e-6)


def test_the_elastic_torque_is_minus_the_potentials_gradient():
    # without damping and friction, tau = -dU/dq with U = k/2 sum_k depth_k^2, the depths from
    # ur5kin.link_heights (the clearance kernel: no Jacobian, no Pinocchio)
    task = TaskSpec(**COMPLIANT, contact_damping=0.0, contact_friction=0.0)
    contact = PlaneContact(task, ur5kin.load_model())

    def potential(q: np.ndarray) -> float:
        depth = np.maximum(task.plane_margin - ur5kin.link_heights(q, task.base_height)[1:], 0)
        return 0.5 * task.contact_stiffness * float(depth @ depth)

    qs, _ = contact_states(task, 30, seed=1)
    eps = 1e-7
    for q in qs:
        gradient = np.array([(potential(q + eps * e) - potential(q - eps * e)) / (2 * eps)
                             for e in np.eye(6)])
        tau = contact_torque(contact, task, q, np.zeros(6))
        np.testing.assert_allclose(tau, -gradient, rtol=1e-4, atol=1e-3 * np.abs(gradient).max())
        assert np.abs(tau).max() > 1.0  # N m: a real contact


def test_damping_and_friction_only_take_power():
    # v . tau <= 0 for the damping and friction part: U's own power is -dU/dt
    task = TaskSpec(**COMPLIANT)
    contact = PlaneContact(task, ur5kin.load_model())
    elastic = PlaneContact(task.replace(contact_damping=0.0, contact_friction=0.0),
                           ur5kin.load_model())
    qs, vs = contact_states(task, 40, seed=2)
    for q, v in zip(qs, vs, strict=True):
        dissipative = (contact_torque(contact, task, q, v)
                       - contact_torque(elastic, task, q, np.zeros(6)))
        assert v @ dissipative <= 1e-9


def test_the_smallest_effective_mass_bounds_a_fresh_sample():
    model = ur5kin.load_model()
    data = model.createData()
    hulls = link_hulls()
    smallest = np.inf
    for q in np.random.default_rng(11).uniform(-np.pi, np.pi, (400, 6)):
        pin.computeJointJacobians(model, data, q)
        M = pin.crba(model, data, q)
        M_inv = np.linalg.inv(np.triu(M) + np.triu(M, 1).T)
        for k in range(2, 7):
            rotation, origin = data.oMi[k].rotation, data.oMi[k].translation
            i = int(np.argmin(hulls[k - 1] @ rotation[2]))
            J6 = pin.getJointJacobian(model, data, k, pin.LOCAL_WORLD_ALIGNED)
            J = J6[:3] - pin.skew(rotation @ hulls[k - 1][i]) @ J6[3:]
            smallest = min(smallest, *(1.0 / (row @ M_inv @ row) for row in J))
        assert np.isfinite(origin).all()
    assert CONTACT_MIN_EFFECTIVE_MASS <= smallest < 1.5 * CONTACT_MIN_EFFECTIVE_MASS


def test_the_default_contact_is_stable_with_the_pd_on_the_coupled_arm():
    # the substep map linearised in contact: stiffness kp + k Jz^T Jz, damping kd + c J^T J
    # (normal damping and the friction's viscous slope), at each link's deepest point
    task = TaskSpec(**COMPLIANT)
    h, model = task.sim_dt, ur5kin.load_model()
    data, hulls, eye = model.createData(), link_hulls(), np.eye(6)
    assert not contact_stability_violations(task.contact_stiffness, task.contact_damping, h)
    radii = []
    for q in np.random.default_rng(12).uniform(-np.pi, np.pi, (150, 6)):
        pin.computeJointJacobians(model, data, q)
        M = pin.crba(model, data, q)
        M_inv = np.linalg.inv(np.triu(M) + np.triu(M, 1).T)
        for k in range(3, 7):
            rotation = data.oMi[k].rotation
            i = int(np.argmin(hulls[k - 1] @ rotation[2]))
            J6 = pin.getJointJacobian(model, data, k, pin.LOCAL_WORLD_ALIGNED)
            J = J6[:3] - pin.skew(rotation @ hulls[k - 1][i]) @ J6[3:]
            stiffness = np.diag(task.kp) + task.contact_stiffness * np.outer(J[2], J[2])
            damping = np.diag(task.kd) + task.contact_damping * J.T @ J
            du_dq, du_du = -h * h * M_inv @ stiffness, eye - h * M_inv @ damping
            A = np.block([[eye + du_dq, du_du], [du_dq, du_du]])
            radii.append(np.abs(np.linalg.eigvals(A)).max())
    assert max(radii) < 1.0


def test_an_unstable_contact_is_refused():
    task = TaskSpec(**COMPLIANT, contact_stiffness=5e7)
    with pytest.raises(ValueError, match="contact is unstable"):
        PinocchioDynamics(task)


def energy(q: np.ndarray, v: np.ndarray, task: TaskSpec) -> tuple[float, float]:
    """Total energy (J): kinetic + gravity (Pinocchio) + the contact springs' k d^2 / 2 (depths
    from Pinocchio's geometry placements), and the kinetic part."""
    model = ur5kin.load_model()
    data = model.createData()
    kinetic = pin.computeKineticEnergy(model, data, q, v)
    potential = pin.computePotentialEnergy(model, data, q)
    depth = max(task.plane_margin - brute_force_heights(q[None], task.base_height)[0], 0.0)
    return kinetic + potential + 0.5 * task.contact_stiffness * depth**2, kinetic


DROP_START = (0.0, 0.2, -0.2, -1.8, -1.3, 0.0)
"""A free arm released at rest, its links 4-9 cm above the plane: it falls onto it, slower
than the URDF velocity limits (whose per-joint clip is not energy-conserving)."""


def test_a_dropped_arm_never_gains_energy_and_comes_to_rest():
    task = TaskSpec(region="unconstrained", n_joints=6, control_mode="torque",
                    gravity_compensation=False, start_q=DROP_START, **COMPLIANT)
    dyn = PinocchioDynamics(task)
    log = run(dyn, np.zeros((150, 1, 6)))  # 3 s, no motor torque at all
    assert log["contact"].any() and not (log["limit_stop"].any() or log["depth_stop"].any())
    assert np.all(np.abs(log["v"]) < 0.9 * ur5kin.velocity_limits())  # no velocity clip
    energies = [energy(np.asarray(DROP_START), np.zeros(6), task)]
    energies += [energy(q[0], v[0], task) for q, v in zip(log["q"], log["v"], strict=True)]
    total = np.array([e for e, _ in energies])
    kinetic = np.array([k for _, k in energies])
    assert kinetic.max() > 2.0  # J: it really fell
    # no step gains more than 1 mJ (the integrator's error; measured 5e-6 J)
    assert np.diff(total).max() < 1e-3
    assert total[-1] < total[0] - kinetic.max()  # the plane took the fall's energy
    assert kinetic[-1] < 1e-3  # J: at rest on the plane
    heights = brute_force_heights(log["q"][-10:, 0], task.base_height)
    assert np.all(np.abs(heights) < 0.005)  # m: lying on it, neither floating nor sunk


@pytest.mark.parametrize(("region", "n_joints"), [("zheight", 3), ("unconstrained", 3),
                                                  ("unconstrained", 6), ("farbox", 2)])
def test_no_link_ends_a_step_deeper_than_the_bound(region, n_joints):
    # random position commands; the bound made tight enough that the fallback is exercised
    for depth, seed in ((0.02, 0), (0.002, 1)):
        task = TaskSpec(region=region, n_joints=n_joints, contact_max_depth=depth, **COMPLIANT)
        dyn = PinocchioDynamics(task, 8)
        commands = np.random.default_rng(seed).uniform(-np.pi, np.pi, (120, 8, n_joints))
        log = run(dyn, commands)
        heights = ur5kin.link_heights(log["q"], task.base_height)[..., 1:].min(axis=-1)
        assert heights.min() >= task.plane_margin - depth - 1e-12
        assert np.all(log["v"][log["depth_stop"]] == 0.0)
        if depth == 0.02:
            assert heights.min() > -0.01  # m: the force alone keeps links within 1 cm
            assert not log["depth_stop"].any()
            assert region == "farbox" or log["contact"].mean() > 0.05
        elif region != "farbox":
            assert log["depth_stop"].any()  # the bound acted


def tool_track(contact_model: str) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    task = TaskSpec(region="zheight", n_joints=3, contact_model=contact_model)
    # pan 1.5 rad sideways to a pose whose wrist is 2 mm into the plane, from the start that
    # the lift and elbow bring down onto it first
    log = run(PinocchioDynamics(task), np.repeat(np.array([[[1.5, -0.6, 2.2]]]), 60, axis=0))
    tool = ur5kin.fk(log["q"][:, 0]) + np.array([0.0, 0.0, task.base_height])
    return tool, log


def test_the_compliant_arm_slides_along_the_plane_where_the_stop_sticks():
    tool, log = tool_track("compliant")
    _, stuck_log = tool_track("stop")
    assert log["contact"].sum() > 10 and stuck_log["contact"].sum() > 10
    assert log["q"][-1, 0, 0] > 1.45  # rad: it got to the commanded pan angle ...
    assert stuck_log["q"][-1, 0, 0] < 0.5  # ... which the stop model is far from
    sliding = log["contact"][:, 0]
    # m: measured 0.40 with the wrists locked (0.55 when the PD holds them and they swing)
    assert np.linalg.norm(np.diff(tool[sliding][:, :2], axis=0), axis=1).sum() > 0.3
    assert np.all(tool[sliding][:, 2] < 0.05)  # m: along the plane, not lifted over it


@pytest.mark.parametrize("mode", ["position", "torque"])
def test_batched_copies_match_single_copies_in_contact(mode):
    task = TaskSpec(region="zheight", n_joints=3, control_mode=mode, **COMPLIANT)
    from envs.task import action_bounds

    low, high = action_bounds(task)
    commands = np.random.default_rng(6).uniform(low, high, (100, 4, 3))
    batch = run(PinocchioDynamics(task, 4), commands)
    # measured 0.015 (torque) to 0.4 (position) with the wrists locked; 0.04 to 0.4 under pd
    assert batch["contact"].mean() > 0.01
    for i in range(4):
        one = run(PinocchioDynamics(task), commands[:, i : i + 1])
        np.testing.assert_array_equal(one["contact"][:, 0], batch["contact"][:, i])
        np.testing.assert_allclose(one["q"][:, 0], batch["q"][:, i], atol=1e-9)
        np.testing.assert_allclose(one["v"][:, 0], batch["v"][:, i], atol=1e-7)


def test_the_screens_never_change_the_compliant_answer():
    task = TaskSpec(region="unconstrained", n_joints=6, **COMPLIANT)
    commands = np.random.default_rng(4).uniform(-np.pi, np.pi, (150, 1, 6))
    screened = run(PinocchioDynamics(task), commands)
    exact = PinocchioDynamics(task)
    # every link of every substep gets the exact force test: the clearance bounds say nothing
    exact._plane_screen = np.full(6, np.inf)
    exact._lipschitz = np.full((6, 6), 1e9)  # m/rad
    checked = run(exact, commands)
    assert screened["contact"].any()
    for key in ("q", "v", "contact", "depth_stop"):
        np.testing.assert_array_equal(screened[key], checked[key], err_msg=key)


def test_the_stop_model_ignores_the_compliant_fields():
    commands = np.random.default_rng(8).uniform(-np.pi, np.pi, (100, 3, 3))
    plain = run(PinocchioDynamics(TaskSpec(region="zheight"), 3), commands)
    other = TaskSpec(region="zheight", contact_stiffness=1e4, contact_damping=10.0,
                     contact_friction=0.0, contact_max_depth=0.5)
    tuned = run(PinocchioDynamics(other, 3), commands)
    assert plain["contact"].any()
    for key, value in plain.items():
        np.testing.assert_array_equal(value, tuned[key], err_msg=key)
    assert not tuned["depth_stop"].any()


@pytest.mark.parametrize(("field", "value"), [("contact_model", "soft"),
                                              ("contact_stiffness", 0.0),
                                              ("contact_damping", -1.0),
                                              ("contact_friction", float("nan")),
                                              ("contact_max_depth", 0.0)])
def test_bad_contact_fields_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        TaskSpec(**{field: value})


@pytest.mark.parametrize("n_joints", [3, 6])
def test_velocities_stay_within_the_urdf_limits_in_contact(n_joints):
    task = TaskSpec(region="zheight", n_joints=n_joints, **COMPLIANT)
    commands = np.random.default_rng(9).uniform(-np.pi, np.pi, (150, 4, n_joints))
    log = run(PinocchioDynamics(task, 4), commands)
    assert log["contact"].mean() > 0.1
    assert np.all(np.abs(log["v"]) <= ur5kin.velocity_limits())
