"""The numba-CUDA backend (envs.physics.numba_cuda) against the CPU numba kernel.

Two paths: the same step body compiled for a GPU thread (one kernel launch per control step)
and for the CPU batch loop (:class:`envs.physics.numba_kernel.NumbaDynamics`), stepped in
lockstep through random commands, plane contacts, joint-limit stops, resets of some copies and
both ``held_joints`` modes. The checks (``check_*``) run twice: under numba's CUDA simulator
(``NUMBA_ENABLE_CUDASIM=1``, in a subprocess: the variable must be set before numba.cuda is
imported) on any machine, and in this process on a real GPU where numba sees one. The
simulator runs the kernel as Python, slowly: a handful of copies and steps per check.
"""

from __future__ import annotations

import inspect
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ur5kin
from envs.physics import make_dynamics, numba_cuda, numba_kernel
from envs.spec import TaskSpec
from envs.task import action_bounds

numba = pytest.importorskip("numba")  # the fast paths are optional

ROOT = Path(__file__).resolve().parent.parent

STATE = ("q", "w", "v", "acceleration", "height_bound", "contact", "limit_stop", "tool")
"""What the lockstep compares after every step: the protocol's arrays and the integrator's
state (``w`` rad per substep, ``height_bound`` m)."""

F64_ATOL = 1e-9
"""Bound of a float64 GPU rollout against the CPU kernel's: q (rad), w (rad per substep), tool
and height bounds (m); v and acceleration are w times 1/h and 1/(h dt) (1e3 and 5e4 here), so
their bounds are scaled alike. The simulator gives 0; a GPU may fuse multiply-adds."""

F32_Q_ATOL = 1e-6
"""Bound (rad) of the float32 kernel's joint angles against the float64 CPU kernel's over 5
contact-free control steps that move each joint by up to 0.2 rad (measured 5e-8 under the
simulator, as the CPU kernel's own float32: float32's 6e-8 rounding, hardly amplified)."""

F32_TOOL_ATOL = 1e-6
"""Bound (m) of the float32 kernel's tool positions in the same steps (measured 1.2e-7)."""


def cuda_available() -> bool:
    """Whether numba sees a GPU (or its simulator) in this process."""
    try:
        from numba import cuda
    except ImportError:
        return False
    return cuda.is_available()


# ------------------------------------------------------------------ the lockstep
def lockstep(task: TaskSpec, commands: np.ndarray, dtype: str = "float64",
             start: np.ndarray | None = None, resets: dict | None = None,
             on_device: tuple[int, ...] = ()) -> tuple[dict, dict]:
    """Step NumbaDynamics (float64, the CPU) and NumbaCudaDynamics (``dtype``) through
    ``commands (T, B, n)``; both logs of :data:`STATE` after every step, ``(T, B, ...)``.

    ``start (B, 6)`` rad: every copy's configuration before the first step; ``resets`` maps a
    step index to ``(q, index)``, a reset of both before that step; the commands of the steps
    in ``on_device`` reach the GPU as device arrays (no upload in ``step``)."""
    from numba import cuda

    B = commands.shape[1]
    cpu = numba_kernel.NumbaDynamics(task, B)
    gpu = numba_cuda.NumbaCudaDynamics(task, B, dtype=dtype, threads_per_block=2)
    logs: tuple[dict, dict] = ({}, {})
    for dyn in (cpu, gpu):
        if start is not None:
            dyn.reset(start)
    for t, command in enumerate(commands):
        for dyn, log in zip((cpu, gpu), logs, strict=True):
            if resets and t in resets:
                dyn.reset(*resets[t])
            given = command
            if dyn is gpu and t in on_device:
                given = cuda.to_device(command.astype(dtype))
            dyn.step(given)
            for key in STATE:
                log.setdefault(key, []).append(np.array(getattr(dyn, key)))
    return tuple({k: np.array(v) for k, v in log.items()} for log in logs)


def assert_same_rollout(cpu: dict, gpu: dict, atol: float = F64_ATOL) -> float:
    """Stop flags equal, the rest within ``atol`` (scaled for v and acceleration); returns the
    largest difference of q (rad)."""
    np.testing.assert_array_equal(gpu["contact"], cpu["contact"])
    np.testing.assert_array_equal(gpu["limit_stop"], cpu["limit_stop"])
    for key in ("q", "w", "height_bound", "tool"):
        np.testing.assert_allclose(gpu[key], cpu[key], rtol=0, atol=atol, err_msg=key)
    np.testing.assert_allclose(gpu["v"], cpu["v"], rtol=0, atol=atol * 1e3)
    np.testing.assert_allclose(gpu["acceleration"], cpu["acceleration"], rtol=0,
                               atol=atol * 5e4)
    return float(np.abs(gpu["q"] - cpu["q"]).max())


def random_commands(task: TaskSpec, steps: int, copies: int, seed: int) -> np.ndarray:
    """Commands ``(steps, copies, n)`` uniform in 1.5 times the action box, clipped to it (a
    third of them at a bound), the shoulder of the first two copies driven down: into the
    plane."""
    low, high = action_bounds(task)
    rng = np.random.default_rng(seed)
    commands = rng.uniform(1.5 * low, 1.5 * high, (steps, copies, task.n_joints))
    commands = commands.clip(low, high)
    commands[:, :2, 1] = high[1]
    return commands


# ------------------------------------------------------------------ the checks
def check_locked_joints_rollout_equals_the_cpu_kernel() -> str:
    # held_joints="locked" (joints 4..6 out of the dynamics), contacts, a reset of two copies
    # mid-rollout, and the last command handed over as a device array
    task = TaskSpec(region="unconstrained", n_joints=3, held_joints="locked")
    commands = random_commands(task, 5, 4, seed=0)
    other = np.array(task.start_q)
    other[:3] += (0.3, -0.2, 0.4)
    cpu, gpu = lockstep(task, commands, resets={3: (other, [1, 2])}, on_device=(4,))
    assert cpu["contact"].any(), "no contact: the check misses the plane"
    np.testing.assert_array_equal(gpu["q"][:, :, 3:],
                                  np.broadcast_to(task.start_q[3:], gpu["q"][:, :, 3:].shape))
    np.testing.assert_array_equal(gpu["w"][:, :, 3:], 0.0)
    return f"max |dq| {assert_same_rollout(cpu, gpu):.1e} rad"


def check_pd_held_joints_rollout_equals_the_cpu_kernel() -> str:
    # held_joints="pd": the PD holds joints 3..6 at their start (the elbow's at pi/2, a torque
    # of its own), and they give way (they move)
    task = TaskSpec(region="zheight", n_joints=2, control_mode="velocity", held_joints="pd")
    assert task.start_q[2] != 0.0
    cpu, gpu = lockstep(task, random_commands(task, 4, 4, seed=1))
    assert np.abs(gpu["q"][-1, :, 2:] - task.start_q[2:]).max() > 1e-6, "held joints still"
    return f"max |dq| {assert_same_rollout(cpu, gpu):.1e} rad"


def check_joint_limit_stops_equal_the_cpu_kernel() -> str:
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode="velocity")
    low, high = action_bounds(task)
    limit = float(ur5kin.load_model().upperPositionLimit[0])
    start = np.tile(np.asarray(task.start_q), (4, 1))
    start[:, 0] = np.array([-1.0, -0.5, 0.5, 1.0]) * (limit - 0.02)
    commands = np.zeros((3, 4, 3))
    commands[:, :, 0] = np.where(start[:, 0] > 0, high[0], low[0])  # into the end stop
    cpu, gpu = lockstep(task, commands, start=start)
    assert cpu["limit_stop"].any(), "no limit stop: the check misses them"
    return f"max |dq| {assert_same_rollout(cpu, gpu):.1e} rad"


def check_torque_control_of_six_joints_equals_the_cpu_kernel() -> str:
    # no held joint (free = 6), torque control without gravity compensation: the arm falls
    task = TaskSpec(region="zheight", n_joints=6, control_mode="torque",
                    gravity_compensation=False)
    cpu, gpu = lockstep(task, random_commands(task, 3, 3, seed=2))
    return f"max |dq| {assert_same_rollout(cpu, gpu):.1e} rad"


def check_float32_within_the_stated_bound() -> str:
    task = TaskSpec(region="unconstrained", n_joints=3, control_mode="position")
    rng = np.random.default_rng(5)  # targets with the shoulder up: free of contacts
    commands = rng.uniform((-1.0, -1.2, -0.5), (1.0, -0.4, 0.5), (5, 3, 3))
    cpu, gpu = lockstep(task, commands, dtype="float32")
    assert gpu["q"].dtype == np.float32
    assert not cpu["contact"].any() and not gpu["contact"].any()
    assert np.abs(cpu["q"][-1]).max() > 0.1, "the arm hardly moved: the check is too easy"
    error = float(np.abs(gpu["q"] - cpu["q"]).max())
    tool = float(np.abs(gpu["tool"] - cpu["tool"]).max())
    assert error <= F32_Q_ATOL and tool <= F32_TOOL_ATOL, (error, tool)
    return f"max |dq| {error:.1e} rad, |dtool| {tool:.1e} m"


def check_mirror_off_and_pull() -> str:
    task = TaskSpec(region="unconstrained", n_joints=3)
    command = random_commands(task, 1, 2, seed=3)[0]
    mirrored = numba_cuda.NumbaCudaDynamics(task, 2)
    quiet = numba_cuda.NumbaCudaDynamics(task, 2, mirror=False)
    before = quiet.q.copy()
    for dyn in (mirrored, quiet):
        dyn.step(command)
    np.testing.assert_array_equal(quiet.q, before)  # the host copy waits for pull()
    quiet.pull()
    for key in ("q", "v", "acceleration", "contact", "limit_stop", "tool"):
        np.testing.assert_array_equal(getattr(quiet, key), getattr(mirrored, key), key)
    return "ok"


def check_bad_inputs_are_refused() -> str:
    from numba import cuda

    task = TaskSpec(region="unconstrained", n_joints=3)
    dyn = numba_cuda.NumbaCudaDynamics(task, 2)
    with pytest.raises(ValueError, match=r"command must be \(2, 3\)"):
        dyn.step(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="float64"):
        dyn.step(cuda.to_device(np.zeros((2, 3), np.float32)))
    with pytest.raises(ValueError, match="below the plane margin"):
        dyn.reset(np.array([0.0, 1.5, 0.0, 0.0, 0.0, 0.0]), [0])
    with pytest.raises(ValueError, match="locked"):
        dyn.reset(np.array([0.0, -1.0, 1.0, 0.3, 0.0, 0.0]))
    for kwargs, match in ((dict(num_copies=0), "num_copies"),
                          (dict(threads_per_block=0), "threads_per_block"),
                          (dict(dtype="float16"), "dtype"), (dict(device="cuda:x"), "cuda:N")):
        with pytest.raises(ValueError, match=match):
            numba_cuda.NumbaCudaDynamics(task, **{"num_copies": 2, **kwargs})
    with pytest.raises(ValueError, match="stop contact"):
        numba_cuda.NumbaCudaDynamics(TaskSpec(contact_model="compliant"), 2)
    assert isinstance(make_dynamics(task, 2, "numba", device="cuda"),
                      numba_cuda.NumbaCudaDynamics)
    return "ok"


def check_the_batched_env_steps_on_the_kernel() -> str:
    # the seam end to end: BatchedReach(dynamics="numba", device="cuda") reads the host mirrors
    import envs

    task = TaskSpec(region="unconstrained", n_joints=3)
    logs = []
    for device in ("cuda", "cpu"):
        env = envs.BatchedReach(3, task, dynamics="numba", device=device)
        kind = numba_cuda.NumbaCudaDynamics if device == "cuda" else numba_kernel.NumbaDynamics
        assert isinstance(env._core.dynamics, kind)
        obs, _ = env.reset(seed=4)
        rng = np.random.default_rng(4)
        log = [obs["observation"]]
        for _ in range(3):
            obs, reward, *_ = env.step(rng.uniform(env.action_space.low, env.action_space.high))
            log += [obs["observation"], obs["achieved_goal"], reward[:, None]]
        logs.append(np.concatenate(log, axis=1))
    np.testing.assert_allclose(logs[0], logs[1], rtol=0, atol=1e-6)
    return f"max |d obs| {np.abs(logs[0] - logs[1]).max():.1e}"


CHECKS = (check_locked_joints_rollout_equals_the_cpu_kernel,
          check_pd_held_joints_rollout_equals_the_cpu_kernel,
          check_joint_limit_stops_equal_the_cpu_kernel,
          check_torque_control_of_six_joints_equals_the_cpu_kernel,
          check_float32_within_the_stated_bound, check_mirror_off_and_pull,
          check_the_batched_env_steps_on_the_kernel, check_bad_inputs_are_refused)

SIMULATOR = """
import sys
sys.path.insert(0, "tests")
import test_numba_cuda as t
for check in t.CHECKS:
    print(check.__name__, check(), flush=True)
"""


# ------------------------------------------------------------------ the tests
def run_python(code: str, **env: str) -> subprocess.CompletedProcess:
    """``python -c code`` from the repository root, with ``env`` added to the environment."""
    return subprocess.run([sys.executable, "-c", code], env={**os.environ, **env}, cwd=ROOT,
                          capture_output=True, text=True)


def test_every_check_under_the_cuda_simulator():
    probe = run_python("from numba import cuda; assert cuda.is_available()",
                       NUMBA_ENABLE_CUDASIM="1")
    if probe.returncode:
        pytest.skip(f"numba's CUDA simulator does not start here: {probe.stderr[-300:]}")
    run = run_python(SIMULATOR, NUMBA_ENABLE_CUDASIM="1")
    assert run.returncode == 0, run.stdout + run.stderr[-4000:]
    for check in CHECKS:
        assert f"{check.__name__} " in run.stdout, run.stdout


@pytest.mark.gpu
@pytest.mark.skipif(not cuda_available(), reason="numba sees no CUDA device")
@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__.removeprefix("check_"))
def test_every_check_on_the_gpu(check):
    check()


PTX = """
import re, sys, types
import numba.cuda.dispatcher as dispatcher
from numba import cuda
try:
    from numba.cuda.cudadrv.error import NvvmSupportError
except ImportError:  # another numba-cuda layout: skip nothing
    NvvmSupportError = ()
from envs.physics import numba_cuda
from envs.spec import TaskSpec

# without a GPU, the device functions compile for a stand-in device (compile_ptx's cc is the
# kernel's alone; its callees ask the current device)
if not cuda.is_available():
    dispatcher.get_current_device = lambda: types.SimpleNamespace(compute_capability=(8, 0))
task = TaskSpec(region="unconstrained", n_joints=3)
try:
    ptx, _ = cuda.compile_ptx(numba_cuda.kernels("float32").step.py_func,
                              numba_cuda.step_signature(task, "float32"), cc=(8, 0))
except NvvmSupportError as err:
    print("SKIP", err)
    sys.exit(3)
for line in ptx.splitlines():
    if re.search(r"\\.f64\\b", line):
        print(line.strip())
"""

LIBDEVICE_SINF = (r"\.reg \.f64 %fd<\d+>;", r"cvt\.rn\.f64\.s64 %fd\d+, %rd\d+;",
                  r"mul\.f64 %fd\d+, %fd\d+, 0d3BF921FB54442D19;",
                  r"cvt\.rn\.f32\.f64 %f\d+, %fd\d+;")
"""The float64 lines of libdevice's ``sinf``/``cosf`` themselves: the Payne-Hanek reduction of
arguments beyond 1e5 rad (an integer times pi/2 2^-64 in float64), a branch our angles never
take. Any other float64 line of the float32 kernel is ours."""


def test_the_float32_kernel_has_no_float64_arithmetic():
    # numba types a float literal as float64: a literal left in the step body, or a float64
    # scalar argument, turns float32 arithmetic into float64 on the GPU (slow on most GPUs)
    run = run_python(PTX, NUMBA_ENABLE_CUDASIM="0")
    if run.returncode == 3:
        pytest.skip(f"numba.cuda.compile_ptx needs libNVVM (the CUDA toolkit): {run.stdout}")
    assert run.returncode == 0, run.stderr[-4000:]
    lines = [" ".join(line.split()) for line in run.stdout.splitlines()]
    ours = [line for line in lines
            if not any(re.fullmatch(pattern, line) for pattern in LIBDEVICE_SINF)]
    assert not ours, f"{len(ours)} float64 lines of {len(lines)}:\n" + "\n".join(ours[:20])


def test_make_dynamics_says_why_without_a_gpu():
    if cuda_available():
        pytest.skip("numba sees a GPU: the refusal is for machines without one")
    with pytest.raises(ValueError, match="numba sees no CUDA GPU"):
        make_dynamics(TaskSpec(), 2, "numba", device="cuda")
    with pytest.raises(ValueError, match="'cuda' or 'cuda:N'"):
        make_dynamics(TaskSpec(), 2, "numba", device="cuda0")
    with pytest.raises(ValueError, match="runs on the CPU only"):
        make_dynamics(TaskSpec(), 2, "pinocchio", device="cuda")


def test_the_model_arguments_follow_the_kernels_parameters():
    parameters = list(inspect.signature(numba_cuda._fused_step).parameters)
    after_tool = parameters[parameters.index("tool") + 1 :]
    assert list(numba_cuda.model_arguments(TaskSpec(), "float32")) == after_tool
    signature = numba_cuda.step_signature(TaskSpec(), "float32")
    assert len(signature) == len(parameters)
    assert all("float64" not in str(t) for t in signature), signature

