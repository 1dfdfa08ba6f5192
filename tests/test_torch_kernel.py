"""The vectorised torch dynamics (envs.physics.torch_kernel), checked against Pinocchio and the
numba path.

Two paths everywhere: the batched ABA and gravity against ``pin.aba`` /
``pin.computeGeneralizedGravity`` row by row, the plane check against ur5kin.link_heights, the
tool position against ur5kin.fk, and whole control steps (plane contacts and joint-limit stops
included) against envs.physics.numba_kernel.NumbaDynamics, or against PinocchioDynamics (the
Pinocchio reference that NumbaDynamics is tested against) where numba is missing, as on the GPU
machine. Every test runs on the CPU, and again on CUDA where torch sees a GPU.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from arm_geometry import pinocchio_rows, random_states
from stepping import record

import ur5kin
from envs.physics import numba_kernel
from envs.physics.model import ChainModel
from envs.physics.pinocchio_loop import PinocchioDynamics
from envs.spec import TaskSpec
from envs.task import action_bounds

torch = pytest.importorskip("torch")
torch_kernel = pytest.importorskip("envs.physics.torch_kernel")

DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="torch sees no CUDA device")])]

F32_ACCEL_RTOL = 1e-4
"""Bound of float32 accelerations: ``|a32 - a| <= F32_ACCEL_RTOL (1 + |a|_max)`` rad/s^2 per
batch, ``|a|_max`` the batch's largest float64 acceleration (the numba path's bound; measured
2e-4 rad/s^2 at |a|_max = 1,900, i.e. 1e-7 relative)."""

F32_STEP_ATOL = 1e-4
"""Bound (rad) of float32 joint angles against float64 ones after 5 free control steps (the
numba path's bound)."""

HELD_START = (0.0, -np.pi / 4, np.pi / 2, 0.4, -0.6, 0.8)
"""A start pose (rad) whose held joints are not at zero, so that holding them is tested."""

STEP_KEYS = ("q", "v", "acceleration", "contact", "limit_stop", "tool")


def host(x) -> np.ndarray:
    return x.detach().cpu().numpy()


@pytest.mark.parametrize("device", DEVICES)
def test_aba_is_pinocchios_in_float64(device):
    q, v, tau = random_states(200, seed=0)
    reference = pinocchio_rows(pin.aba, q, v, tau)
    a = torch_kernel.aba(q, v, tau, device=device)
    assert a.dtype == torch.float64 and a.device.type == device
    np.testing.assert_allclose(host(a), reference, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("device", DEVICES)
def test_aba_in_float32_within_the_stated_bound(device):
    q, v, tau = random_states(200, seed=1)
    reference = pinocchio_rows(pin.aba, q, v, tau)
    a32 = torch_kernel.aba(q, v, tau, device=device, dtype="float32")
    assert a32.dtype == torch.float32
    assert np.abs(host(a32) - reference).max() <= F32_ACCEL_RTOL * (1.0 + np.abs(reference).max())


@pytest.mark.parametrize("device", DEVICES)
def test_gravity_torque_is_pinocchios(device):
    q, _, _ = random_states(200, seed=2)
    reference = pinocchio_rows(pin.computeGeneralizedGravity, q)
    np.testing.assert_allclose(host(torch_kernel.generalized_gravity(q, device=device)), reference,
                               rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("device", DEVICES)
def test_a_changed_pinocchio_model_is_followed(device):
    """The chain is read from Pinocchio: a heavier link and rotor inertia (the UR5's armature
    is zero, so the default model cannot tell a dropped armature term) show in the ABA."""
    model = ur5kin.load_model()
    changed = pin.Model(model)
    changed.inertias[3] = pin.Inertia(2.0 * model.inertias[3].mass, model.inertias[3].lever,
                                      2.0 * model.inertias[3].inertia)
    changed.armature = np.linspace(0.05, 0.3, 6)
    chain = torch_kernel.TorchChain.from_chain(ChainModel.from_pinocchio(changed), device,
                                               torch.float64)
    q, v, tau = random_states(50, seed=10)
    data = changed.createData()
    reference = np.array([pin.aba(changed, data, *row).copy() for row in zip(q, v, tau,
                                                                           strict=True)])
    q_t, v_t, tau_t = (torch.as_tensor(x, device=device) for x in (q, v, tau))
    X = torch_kernel.motion_transforms(torch_kernel.placements(q_t, chain), chain)
    np.testing.assert_allclose(host(torch_kernel.articulated_body(X, v_t, tau_t, chain)), reference,
                               rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("device", DEVICES)
def test_plane_heights_and_tool_are_ur5kins(device):
    q = np.random.default_rng(3).uniform(-np.pi, np.pi, (300, 6))
    heights = torch_kernel.link_heights(q, 0.5, device=device)
    np.testing.assert_allclose(host(heights), ur5kin.link_heights(q, 0.5)[:, 1:], atol=1e-12)
    chain, _ = torch_kernel._ur5_models(device, torch.float64)
    R = torch_kernel.placements(torch.as_tensor(q, device=device), chain)
    model = ur5kin.load_model()
    tool = model.frames[model.getFrameId(ur5kin.TOOL_FRAME)].placement.translation
    world = torch_kernel.tool_position(R, chain, torch.as_tensor(tool, device=device), 0.5)
    np.testing.assert_allclose(host(world), ur5kin.to_world(ur5kin.fk(q), 0.5), atol=1e-12)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match=r"\(B, 6\)"):
        torch_kernel.aba(np.zeros((2, 5)), np.zeros((2, 5)), np.zeros((2, 5)))
    with pytest.raises(ValueError, match="dtype"):
        torch_kernel.aba(np.zeros((2, 6)), np.zeros((2, 6)), np.zeros((2, 6)), dtype="float16")
    with pytest.raises(ValueError, match="num_copies"):
        torch_kernel.TorchDynamics(TaskSpec(), 0)
    with pytest.raises(ValueError, match="stop contact model"):
        torch_kernel.TorchDynamics(TaskSpec(contact_model="compliant"), 2)
    dyn = torch_kernel.TorchDynamics(TaskSpec(n_joints=3), 2)
    with pytest.raises(ValueError, match=r"\(2, 3\)"):
        dyn.step(np.zeros((2, 4)))
    q = np.random.default_rng(8).uniform(-np.pi, np.pi, (50, 6))
    q[:, 3:] = dyn.task.start_q[3:]  # joints 4-6 are locked at their start angles
    low = q[ur5kin.link_heights(q, dyn.task.base_height).min(axis=1) < dyn.task.plane_margin]
    with pytest.raises(ValueError, match="below the plane margin"):
        dyn.reset(low[0])
    with pytest.raises(ValueError, match=r"locked at their start angles"):
        dyn.reset(np.full(6, 0.1))


# ------------------------------------------------------------------ whole control steps
def reference(task: TaskSpec, num_copies: int):
    """The numba path (float64) where numba is installed, else PinocchioDynamics."""
    if numba_kernel.available():
        return numba_kernel.NumbaDynamics(task, num_copies)
    return PinocchioDynamics(task, num_copies)


class OnHost:
    """A dynamics object seen through numpy (``record`` reads its arrays and ``tool``)."""

    def __init__(self, dyn) -> None:
        self.dyn = dyn

    def step(self, command: np.ndarray) -> None:
        self.dyn.step(command)

    def __getattr__(self, name: str) -> np.ndarray:
        if name == "tool":
            return tool_of(self.dyn)
        value = getattr(self.dyn, name)
        return host(value) if isinstance(value, torch.Tensor) else np.array(value)


def tool_of(dyn) -> np.ndarray:
    """tool0's world positions ``(B, 3)`` m of any of the dynamics, as numpy."""
    if isinstance(dyn, torch_kernel.TorchDynamics):
        return host(dyn.tool_positions())
    return dyn.tool_positions(np.zeros((dyn.num_copies, 3)))


def run_both(task: TaskSpec, commands: np.ndarray, start: np.ndarray | None = None,
             device: str = "cpu", dtype: str = "float64") -> tuple[dict, dict]:
    """Step the reference and TorchDynamics through ``commands (T, B, n)``; both logs."""
    B = commands.shape[1]
    logs = []
    for dyn in (reference(task, B), torch_kernel.TorchDynamics(task, B, device=device,
                                                              dtype=dtype)):
        if start is not None:
            dyn.reset(start)
        logs.append(record(OnHost(dyn), commands, STEP_KEYS))
    return logs[0], logs[1]


def assert_same_steps(ref: dict, got: dict, atol: float) -> None:
    np.testing.assert_array_equal(got["contact"], ref["contact"])
    np.testing.assert_array_equal(got["limit_stop"], ref["limit_stop"])
    np.testing.assert_allclose(got["q"], ref["q"], atol=atol)
    np.testing.assert_allclose(got["v"], ref["v"], atol=atol / 1e-3)  # v = w / h
    np.testing.assert_allclose(got["acceleration"], ref["acceleration"], atol=atol / 2e-5)
    np.testing.assert_allclose(got["tool"], ref["tool"], atol=atol)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize(("mode", "n_joints", "gravity_compensation", "start_q"),
                         [("position", 3, True, None), ("velocity", 6, True, None),
                          ("torque", 2, True, None), ("torque", 3, False, None),
                          ("position", 5, True, None), ("position", 2, True, HELD_START)])
def test_control_steps_are_the_numba_kernels(mode, n_joints, gravity_compensation, start_q, device):
    task = TaskSpec(region="unconstrained", n_joints=n_joints, control_mode=mode,
                    gravity_compensation=gravity_compensation, start_q=start_q)
    low, high = action_bounds(task)
    commands = np.random.default_rng(4).uniform(low, high, (40, 16, n_joints))
    ref, got = run_both(task, commands, device=device)
    assert ref["contact"].any()  # random commands drive the arm into the plane
    assert_same_steps(ref, got, atol=1e-9)


@pytest.mark.parametrize("device", DEVICES)
def test_joint_limit_stops_are_the_numba_kernels(device):
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode="velocity")
    low, high = action_bounds(task)
    model = ur5kin.load_model()
    start = np.tile(np.asarray(task.start_q), (8, 1))
    start[:, 0] = np.linspace(-1.0, 1.0, 8) * (model.upperPositionLimit[0] - 0.05)
    commands = np.zeros((10, 8, 3))
    commands[:, :, 0] = np.where(start[:, 0] > 0, high[0], low[0])[None]  # into the end stop
    ref, got = run_both(task, commands, start=start, device=device)
    assert ref["limit_stop"].any() and not ref["limit_stop"].all()
    assert_same_steps(ref, got, atol=1e-9)


@pytest.mark.parametrize("device", DEVICES)
def test_float32_steps_within_the_stated_bound(device):
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode="torque")
    commands = np.zeros((5, 4, 3))  # the arm held by gravity compensation, free of contacts
    commands[:, :, 0] = 20.0
    ref, got = run_both(task, commands, device=device, dtype="float32")
    assert not ref["contact"].any()
    assert np.abs(got["q"] - ref["q"]).max() <= F32_STEP_ATOL


@pytest.mark.parametrize("device", DEVICES)
def test_reset_of_some_copies_is_fastdyns(device):
    task = TaskSpec(region="unconstrained", n_joints=3)
    low, high = action_bounds(task)
    commands = np.random.default_rng(7).uniform(low, high, (6, 5, 3))
    pose = np.asarray(task.start_q) + np.array([0.3, -0.2, 0.1, 0.0, 0.0, 0.0])
    pair = (reference(task, 5), torch_kernel.TorchDynamics(task, 5, device=device))
    mask = np.array([True, False, True, False, False])
    for d in pair:
        for command in commands[:3]:
            d.step(command)
        d.reset(pose, mask)
        d.reset(np.asarray(task.start_q), 3)
    assert not host(pair[1].v)[mask].any() and not host(pair[1].contact)[mask].any()
    np.testing.assert_allclose(host(pair[1].q), pair[0].q, atol=1e-12)
    np.testing.assert_allclose(tool_of(pair[1]), tool_of(pair[0]), atol=1e-12)
    for d in pair:
        for command in commands[3:]:
            d.step(command)
    np.testing.assert_allclose(host(pair[1].q), pair[0].q, atol=1e-9)
    np.testing.assert_allclose(host(pair[1].v), pair[0].v, atol=1e-6)


def test_compile_modes_are_checked():
    with pytest.raises(ValueError, match="compile must be"):
        torch_kernel.TorchDynamics(TaskSpec(), 2, compile="fastest")
    with pytest.raises(ValueError, match="cuda_graph=True needs a CUDA device"):
        torch_kernel.TorchDynamics(TaskSpec(), 2, cuda_graph=True)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA device")
def test_cuda_graph_steps_are_the_eager_ones():
    task = TaskSpec(region="unconstrained", n_joints=3)
    low, high = action_bounds(task)
    commands = np.random.default_rng(11).uniform(low, high, (12, 16, 3))
    eager = torch_kernel.TorchDynamics(task, 16, device="cuda")
    graphed = torch_kernel.TorchDynamics(task, 16, device="cuda", cuda_graph=True)
    contacts = 0
    for t, command in enumerate(commands):
        if t == 6:  # a reset between replays writes the same storage the graph reads
            for d in (eager, graphed):
                d.reset(np.asarray(task.start_q), np.arange(0, 16, 2))
        for d in (eager, graphed):
            d.step(torch.as_tensor(command, device="cuda"))
        for key in ("q", "v", "acceleration", "contact", "limit_stop"):
            np.testing.assert_allclose(host(getattr(graphed, key)), host(getattr(eager, key)),
                                       atol=1e-9, err_msg=key)
        contacts += int(host(eager.contact).sum())
    assert contacts > 0
    np.testing.assert_allclose(host(graphed.tool_positions()), host(eager.tool_positions()),
                               atol=1e-12)


@pytest.mark.slow  # torch.compile of the substep: ~2 min on a loaded two-core CPU
@pytest.mark.parametrize("device", DEVICES)
def test_compiled_steps_are_the_eager_ones(device):
    task = TaskSpec(region="unconstrained", n_joints=3)
    low, high = action_bounds(task)
    commands = np.random.default_rng(9).uniform(low, high, (4, 8, 3))
    eager = torch_kernel.TorchDynamics(task, 8, device=device)
    compiled = torch_kernel.TorchDynamics(task, 8, device=device, compile=True)
    for command in commands:
        eager.step(command)
        compiled.step(command)
        np.testing.assert_allclose(host(compiled.q), host(eager.q), atol=1e-12)
        np.testing.assert_array_equal(host(compiled.contact), host(eager.contact))
