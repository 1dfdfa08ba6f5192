"""The joints the agent does not control (n+1..6): locked at their start angles, or PD-held.

Two paths everywhere: each backend's locked dynamics against an independent solve of the full
model's free block (Pinocchio's CRBA and RNEA), the backends against each other, and the held
angles against their start values, exactly.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import ur5kin
from envs.physics import numba_kernel
from envs.physics.pinocchio_loop import PinocchioDynamics
from envs.spec import TaskSpec
from envs.task import task_sampler

BACKENDS = {"pinocchio": PinocchioDynamics, "numba": numba_kernel.NumbaDynamics}


def free_block_reference(q: np.ndarray, v: np.ndarray, tau: np.ndarray, free: int
                         ) -> np.ndarray:
    """``a (B, 6)``: ``M_ff a_f = tau_f - h_f(q, v)`` with the full model's mass matrix and
    bias forces (CRBA, RNEA), 0 for the locked joints: the arm with joints free+1..6 held."""
    model = ur5kin.load_model()
    data = model.createData()
    out = np.zeros_like(q)
    for b in range(len(q)):
        M = pin.crba(model, data, q[b])
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.rnea(model, data, q[b], v[b], np.zeros(6))
        out[b, :free] = np.linalg.solve(M[:free, :free], tau[b, :free] - h[:free])
    return out


def random_state(free: int, seed: int, count: int = 40
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (count, 6))
    v = rng.normal(0.0, 1.5, (count, 6))
    v[:, free:] = 0.0  # locked joints do not move
    tau = rng.normal(0.0, 30.0, (count, 6))
    return q, v, tau


@pytest.mark.parametrize("free", [2, 3, 4, 5, 6])
def test_locked_aba_of_the_kernels_is_the_full_models_free_block(free):
    q, v, tau = random_state(free, seed=free)
    ref = free_block_reference(q, v, tau, free)
    np.testing.assert_allclose(numba_kernel.aba(q, v, tau, free=free), ref, rtol=0, atol=1e-9)
    assert np.all(numba_kernel.aba(q, v, tau, free=free)[:, free:] == 0.0)


@pytest.mark.parametrize("num_copies", [1, 3])
@pytest.mark.parametrize("n", [2, 3, 5])
def test_locked_aba_of_the_pinocchio_loop_is_the_full_models_free_block(n, num_copies):
    # The loop's own kernel (Pinocchio's reduced model at the start pose) in its time-scaled
    # units: w = h v, tau and gravity scaled by h^2, so it returns h^2 a (envs.physics.model).
    task = TaskSpec(region="zheight", n_joints=n)
    dyn = PinocchioDynamics(task, num_copies)
    h = task.sim_dt
    q, v, tau = random_state(n, seed=10 + n, count=num_copies)
    q[:, n:] = task.start_q[n:]  # welded where the task starts them
    ref = free_block_reference(q, v, tau, n)
    rows = (q[0], h * v[0], h * h * tau[0]) if num_copies == 1 else (q, h * v, h * h * tau)
    got = np.array(dyn._accel(*rows)).reshape(num_copies, 6) / (h * h)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
    assert np.all(got[:, n:] == 0.0)


def rollout(dyn, commands: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``q (T, B, 6)`` and ``contact (T, B)`` over the commands ``(T, B, n)``."""
    qs, contacts = [], []
    for command in commands:
        dyn.step(command)
        qs.append(np.array(dyn.q, dtype=float))
        contacts.append(np.array(dyn.contact))
    return np.array(qs), np.array(contacts)


@pytest.mark.parametrize("backend", sorted(BACKENDS))
@pytest.mark.parametrize(("region", "n"), [("unconstrained", 3), ("zheight", 3), ("farbox", 2),
                                           ("closebox", 5)])
def test_locked_joints_never_move_over_long_random_rollouts_with_contacts(backend, region, n):
    task = TaskSpec(region=region, n_joints=n)
    commands = np.random.default_rng(3).uniform(-np.pi, np.pi, (250, 4, n))
    q, contact = rollout(BACKENDS[backend](task, 4), commands)
    assert contact.sum() > 20  # the plane stopped the arm many times
    assert np.abs(q[..., :n] - np.asarray(task.start_q)[:n]).max() > 0.5  # rad: the rest moved
    np.testing.assert_array_equal(q[..., n:], np.broadcast_to(task.start_q[n:], q[..., n:].shape))


def test_locked_joints_never_move_under_the_compliant_contact():
    task = TaskSpec(region="zheight", n_joints=3, contact_model="compliant")
    dyn = PinocchioDynamics(task, 3)
    commands = np.random.default_rng(4).uniform(-np.pi, np.pi, (150, 3, 3))
    q, contact = rollout(dyn, commands)
    assert contact.sum() > 20
    np.testing.assert_array_equal(q[..., 3:], 0.0)


def test_pd_held_joints_give_way_where_locked_ones_do_not():
    # the defect the field fixes, measured on the same commands
    commands = np.random.default_rng(5).uniform(-np.pi, np.pi, (150, 4, 3))
    swing = {}
    for held in ("pd", "locked"):
        task = TaskSpec(region="zheight", n_joints=3, held_joints=held)
        q, _ = rollout(numba_kernel.NumbaDynamics(task, 4), commands)
        swing[held] = np.abs(q[..., 3:]).max()
    assert swing["pd"] > 0.3  # rad
    assert swing["locked"] == 0.0


@pytest.mark.parametrize("held", ["locked", "pd"])
def test_backends_agree_step_for_step(held):
    task = TaskSpec(region="closebox", n_joints=4, held_joints=held)
    commands = np.random.default_rng(6).uniform(-np.pi, np.pi, (120, 3, 4))
    (qp, cp), (qn, cn) = (rollout(BACKENDS[b](task, 3), commands) for b in ("pinocchio", "numba"))
    assert cp.sum() > 5
    np.testing.assert_array_equal(cp, cn)
    np.testing.assert_allclose(qp, qn, rtol=0, atol=1e-9)


@pytest.mark.parametrize(("region", "n", "sampler"), [("zheight", 3, "joint"),
                                                      ("farbox", 2, "joint"),
                                                      ("closebox", 4, "cartesian")])
def test_a_sampled_goal_is_reached_by_its_configuration_with_the_held_joints_at_the_start(
        region, n, sampler):
    task = TaskSpec(region=region, n_joints=n, goal_sampler=sampler)
    batch = task_sampler(task).sample(40, np.random.default_rng(7))
    np.testing.assert_array_equal(batch.q[:, n:],
                                  np.broadcast_to(task.start_q[n:], batch.q[:, n:].shape))
    np.testing.assert_allclose(ur5kin.fk_world(batch.q, task.base_height), batch.goals,
                               rtol=0, atol=1e-9)
    # the locked arm commanded to the configuration's controlled angles gets there (goals
    # whose straight joint-space path the plane blocks stop short: measured 35-60 % of these
    # low goals are not blocked)
    dyn = numba_kernel.NumbaDynamics(task, len(batch.q))
    contact = np.zeros(len(batch.q), dtype=bool)
    for _ in range(task.max_episode_steps):
        dyn.step(batch.q[:, :n])
        contact |= dyn.contact
    tool = dyn.tool_positions(np.empty((len(batch.q), 3)))
    reached = np.linalg.norm(tool - batch.goals, axis=1) <= task.success_radius
    assert np.all(reached[~contact])
    assert (~contact).mean() > 0.25


def test_a_reset_that_moves_a_locked_joint_is_refused():
    task = TaskSpec(region="zheight", n_joints=3)
    moved = np.array(task.start_q)
    moved[4] += 0.1
    for backend in BACKENDS.values():
        with pytest.raises(ValueError, match=r"joints 4\.\.6 are locked at their start angles"):
            backend(task, 2).reset(moved)
    PinocchioDynamics(task.replace(held_joints="pd"), 2).reset(moved)  # pd takes any pose
    with pytest.raises(ValueError, match=r"free=0 \(expected an integer in 1\.\.6"):
        numba_kernel.aba(np.zeros((1, 6)), np.zeros((1, 6)), np.zeros((1, 6)), free=0)
    with pytest.raises(ValueError, match="zero velocity"):
        numba_kernel.aba(np.zeros((1, 6)), np.ones((1, 6)), np.zeros((1, 6)), free=3)


def test_held_joints_is_a_checked_recorded_field():
    assert TaskSpec().held_joints == "locked"
    with pytest.raises(ValueError,
                       match=r"held_joints='welded' \(expected one of \['locked', 'pd'\]"):
        TaskSpec(held_joints="welded")
    record = TaskSpec(region="farbox").to_dict()
    assert record["held_joints"] == "locked"
    assert TaskSpec.from_record(record) == TaskSpec(region="farbox")
    # a record written before the field existed was trained with the PD hold
    del record["held_joints"]
    assert TaskSpec.from_record(record).held_joints == "pd"
    assert TaskSpec.from_dict(record).held_joints == "locked"  # new input: today's default


def test_the_env_reads_an_old_record_as_pd_and_keeps_locked_joints_still():
    import gymnasium

    import envs  # noqa: F401  (registers UR5Reach-v0)

    record = TaskSpec(region="zheight").to_dict()
    del record["held_joints"]
    old = gymnasium.make("UR5Reach-v0", task=record)
    assert old.unwrapped.task.held_joints == "pd"
    env = gymnasium.make("UR5Reach-v0", region="zheight")
    assert env.unwrapped.task.held_joints == "locked"
    env.reset(seed=0)
    start = env.unwrapped.joint_angles
    rng = np.random.default_rng(0)
    for _ in range(300):
        _, _, terminated, truncated, _ = env.step(rng.uniform(-np.pi, np.pi, 3))
        np.testing.assert_array_equal(env.unwrapped.joint_angles[3:], start[3:])
        if terminated or truncated:
            env.reset()
