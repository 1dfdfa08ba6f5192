"""The compiled batched dynamics (envs.physics.numba_kernel), checked against Pinocchio and the
Pinocchio loop.

Two paths everywhere: the kernel's ABA and gravity against ``pin.aba`` /
``pin.computeGeneralizedGravity`` row by row, its plane check against ur5kin.link_heights and
the brute-force mesh check of test_env_dynamics, its tool position against ur5kin.fk, and whole
control steps against PinocchioDynamics (Pinocchio in a Python loop, numpy stops).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from arm_geometry import brute_force_heights, pinocchio_rows, random_states

import envs
import ur5kin
from envs.physics import make_dynamics, numba_kernel
from envs.physics.model import ChainModel, ur5_chain
from envs.physics.pinocchio_loop import PinocchioDynamics
from envs.spec import TaskSpec
from envs.task import action_bounds

numba = pytest.importorskip("numba")  # the fast path is optional

F32_ACCEL_RTOL = 1e-4
"""Bound of float32 accelerations: ``|a32 - a| <= F32_ACCEL_RTOL (1 + |a|_max)`` rad/s^2 per
batch, ``|a|_max`` the batch's largest float64 acceleration (measured 4e-6 on random states:
float32's 6e-8 rounding times the mass matrix's conditioning)."""

F32_STEP_ATOL = 1e-4
"""Bound (rad) of float32 joint angles against float64 ones after 5 free control steps
(measured 1e-5)."""


def test_aba_is_pinocchios_in_float64():
    q, v, tau = random_states(200, seed=0)
    reference = pinocchio_rows(pin.aba, q, v, tau)
    np.testing.assert_allclose(numba_kernel.aba(q, v, tau), reference, rtol=1e-9, atol=1e-9)


def test_aba_in_float32_within_the_stated_bound():
    q, v, tau = random_states(200, seed=1)
    reference = pinocchio_rows(pin.aba, q, v, tau)
    a32 = numba_kernel.aba(q, v, tau, dtype=np.float32)
    assert a32.dtype == np.float32
    assert np.abs(a32 - reference).max() <= F32_ACCEL_RTOL * (1.0 + np.abs(reference).max())


def test_gravity_torque_is_pinocchios():
    q, _, _ = random_states(200, seed=2)
    reference = pinocchio_rows(pin.computeGeneralizedGravity, q)
    chain = ur5_chain()
    R, acc, force, g = np.empty((6, 3, 3)), np.empty((7, 6)), np.empty((6, 6)), np.empty_like(q)
    for qb, gb in zip(q, g, strict=True):  # the kernel's g(q), one row at a time
        numba_kernel.placements(qb, chain.rotation, chain.axis, R)
        numba_kernel._gravity_torque(R, chain.translation, chain.axis, chain.inertia,
                                     chain.gravity, acc, force, gb)
    np.testing.assert_allclose(g, reference, rtol=1e-9, atol=1e-9)


def test_the_chain_is_read_from_pinocchio():
    model = ur5kin.load_model()
    heavier = pin.Model(model)
    heavier.inertias[3] = pin.Inertia(2.0 * model.inertias[3].mass, model.inertias[3].lever,
                                      2.0 * model.inertias[3].inertia)
    chain = ChainModel.from_pinocchio(heavier)
    np.testing.assert_array_equal(chain.inertia[2], heavier.inertias[3].matrix())
    np.testing.assert_array_equal(chain.translation[1], model.jointPlacements[2].translation)
    damped = pin.Model(model)
    damped.damping = np.full(6, 0.1)
    with pytest.raises(ValueError, match="damping"):
        ChainModel.from_pinocchio(damped)


def test_plane_heights_are_regions_and_the_meshes():
    q = np.random.default_rng(3).uniform(-np.pi, np.pi, (300, 6))
    heights = numba_kernel.link_heights(q, 0.5)
    np.testing.assert_allclose(heights, ur5kin.link_heights(q, 0.5)[:, 1:], atol=1e-12)
    np.testing.assert_allclose(heights[:40].min(axis=1), brute_force_heights(q[:40], 0.5),
                               atol=1e-9)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match=r"\(B, 6\)"):
        numba_kernel.aba(np.zeros((2, 5)), np.zeros((2, 5)), np.zeros((2, 5)))
    with pytest.raises(ValueError, match="dtype"):
        numba_kernel.aba(np.zeros((2, 6)), np.zeros((2, 6)), np.zeros((2, 6)), dtype=np.float16)
    with pytest.raises(ValueError, match="num_copies"):
        numba_kernel.NumbaDynamics(TaskSpec(), 0)
    with pytest.raises(ValueError, match="dynamics must be one of"):
        make_dynamics(TaskSpec(), 2, "mujoco")
    with pytest.raises(ValueError, match="dynamics='fast' is now dynamics='numba'"):
        make_dynamics(TaskSpec(), 2, "fast")
    for removed in ("torch", "torch-cuda"):
        with pytest.raises(ValueError, match=f"dynamics='{removed}' was removed .*StackReach"):
            make_dynamics(TaskSpec(), 2, removed)
    with pytest.raises(ValueError, match="runs on the CPU only"):
        make_dynamics(TaskSpec(), 2, "pinocchio", device="cuda")
    with pytest.raises(ValueError, match=r"numba's CUDA kernel, envs.physics.numba_cuda, was "
                                         r"removed: the training program"):
        make_dynamics(TaskSpec(), 2, "numba", device="cuda:0")
    assert isinstance(make_dynamics(TaskSpec(), 2, "numba"), numba_kernel.NumbaDynamics)
    assert isinstance(make_dynamics(TaskSpec(), 2, "pinocchio"), PinocchioDynamics)


# ------------------------------------------------------------------ whole control steps
def run_both(task: TaskSpec, commands: np.ndarray, start: np.ndarray | None = None,
             dtype: str = "float64") -> tuple[dict, dict]:
    """Step PinocchioDynamics and NumbaDynamics through ``commands (T, B, n)``; both logs."""
    B = commands.shape[1]
    pair = (PinocchioDynamics(task, B), numba_kernel.NumbaDynamics(task, B, dtype=dtype))
    logs: tuple[dict, dict] = ({}, {})
    for dyn, log in zip(pair, logs, strict=True):
        if start is not None:
            dyn.reset(start)
        tool = np.zeros((B, 3))
        for command in commands:
            dyn.step(command)
            for key in ("q", "v", "acceleration", "contact", "limit_stop"):
                log.setdefault(key, []).append(np.array(getattr(dyn, key), dtype=float))
            log.setdefault("tool", []).append(dyn.tool_positions(tool).copy())
    return tuple({k: np.array(v) for k, v in log.items()} for log in logs)


def assert_same_steps(ref: dict, fast: dict, atol: float) -> None:
    np.testing.assert_array_equal(fast["contact"], ref["contact"])
    np.testing.assert_array_equal(fast["limit_stop"], ref["limit_stop"])
    np.testing.assert_allclose(fast["q"], ref["q"], atol=atol)
    np.testing.assert_allclose(fast["v"], ref["v"], atol=atol / 1e-3)  # v = w / h
    np.testing.assert_allclose(fast["acceleration"], ref["acceleration"], atol=atol / 2e-5)
    np.testing.assert_allclose(fast["tool"], ref["tool"], atol=atol)


@pytest.mark.parametrize(("mode", "n_joints", "gravity_compensation"),
                         [("position", 3, True), ("velocity", 6, True), ("torque", 2, True),
                          ("torque", 3, False)])
def test_control_steps_are_armdynamics(mode, n_joints, gravity_compensation):
    task = TaskSpec(region="unconstrained", n_joints=n_joints, control_mode=mode,
                    gravity_compensation=gravity_compensation)
    low, high = action_bounds(task)
    commands = np.random.default_rng(4).uniform(low, high, (40, 16, n_joints))
    ref, fast = run_both(task, commands)
    assert ref["contact"].any()  # random commands drive the arm into the plane
    assert_same_steps(ref, fast, atol=1e-9)


def test_joint_limit_stops_are_armdynamics():
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode="velocity")
    low, high = action_bounds(task)
    model = ur5kin.load_model()
    start = np.tile(np.asarray(task.start_q), (8, 1))
    start[:, 0] = np.linspace(-1.0, 1.0, 8) * (model.upperPositionLimit[0] - 0.05)
    commands = np.zeros((10, 8, 3))
    commands[:, :, 0] = np.where(start[:, 0] > 0, high[0], low[0])[None]  # into the end stop
    ref, fast = run_both(task, commands, start=start)
    assert ref["limit_stop"].any()
    assert_same_steps(ref, fast, atol=1e-9)


def test_float32_steps_within_the_stated_bound():
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode="torque")
    commands = np.zeros((5, 4, 3))  # the arm held by gravity compensation, free of contacts
    commands[:, :, 0] = 20.0
    ref, fast = run_both(task, commands, dtype="float32")
    assert not ref["contact"].any()
    assert np.abs(fast["q"] - ref["q"]).max() <= F32_STEP_ATOL


# ------------------------------------------------------------------ the batched env
def rollout(env: envs.BatchedReach, steps: int, seed: int) -> np.ndarray:
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    space = env.action_space
    log = [obs["observation"]]
    for _ in range(steps):
        obs, reward, *_ = env.step(rng.uniform(space.low, space.high))
        log += [obs["observation"], obs["achieved_goal"], reward[:, None]]
    return np.concatenate(log, axis=1)


def test_batched_env_takes_the_fast_path_and_matches_the_reference():
    task = TaskSpec(region="unconstrained", n_joints=3)
    fast = envs.BatchedReach(8, task)
    assert isinstance(fast._core.dynamics, numba_kernel.NumbaDynamics)
    reference = envs.BatchedReach(8, task, dynamics="pinocchio")
    assert isinstance(reference._core.dynamics, PinocchioDynamics)
    first = rollout(fast, 30, seed=5)
    np.testing.assert_array_equal(rollout(envs.BatchedReach(8, task), 30, seed=5), first)
    np.testing.assert_allclose(first, rollout(reference, 30, seed=5), atol=1e-6)


def test_threads_do_not_change_the_result():
    task = TaskSpec(region="unconstrained", n_joints=3)
    low, high = action_bounds(task)
    commands = np.random.default_rng(6).uniform(low, high, (10, 12, 3))
    logs = []
    for threads in (1, min(2, numba.config.NUMBA_NUM_THREADS)):
        dyn = numba_kernel.NumbaDynamics(task, 12, threads=threads)
        for command in commands:
            dyn.step(command)
        logs.append(np.concatenate([dyn.q, dyn.v, dyn.acceleration]))
    np.testing.assert_array_equal(logs[1], logs[0])
    with pytest.raises(ValueError, match="threads"):
        numba_kernel.NumbaDynamics(task, 2, threads=0)

