"""envs.physics.stack.StackDynamics: B copies of different tasks (n_joints, start pose) in one
kernel call, against the single-task numba kernel copy by copy; the Triton kernel (under
Triton's CPU interpreter) against the numba one."""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys

# the Triton kernel runs on the CPU under Triton's interpreter, chosen when
# envs.physics.triton_kernel is first imported (only this module imports it in the tests)
os.environ.setdefault("TRITON_INTERPRET", "1")

import numpy as np
import pytest
import torch

from envs.physics.model import moving_link_heights
from envs.physics.numba_kernel import NumbaDynamics
from envs.physics.stack import (
    DYNAMICS_FIELDS,
    PER_COPY_FIELDS,
    UNREAD_FIELDS,
    StackDynamics,
)
from envs.spec import TaskSpec

try:
    import triton  # noqa: F401

    HAS_TRITON = True
except ImportError:
    HAS_TRITON = False

needs_triton = pytest.mark.skipif(not HAS_TRITON, reason="triton is not installed (the test "
                                  "extra installs it)")

GRID = [("unconstrained", 2), ("zheight", 3), ("closebox", 6), ("unconstrained", 5),
        ("farbox", 4), ("unconstrained", 6), ("zheight", 6), ("unconstrained", 3)]
"""(region, n_joints) of the stack's copies: 2..6 joints, both start poses (all zeros for
unconstrained, the constrained regions' other)."""

STATE = ("q", "w", "v", "acceleration", "height_bound", "tool", "contact", "limit_stop")

FLOAT32_TOLERANCE = 1e-5
"""Bound (rad, m) of the float32 Triton kernel against the float32 numba kernel over
:func:`test_the_triton_kernel_is_the_numba_kernel`'s steps; the two round differently (numba's
CPU kernel sums float32 arrays with float64 literals)."""


def tasks() -> list[TaskSpec]:
    return [TaskSpec(region=region, n_joints=n) for region, n in GRID]


def commands(rng: np.random.Generator, steps: int, B: int) -> np.ndarray:
    """Position targets ``(steps, B, 6)`` rad held for 40 steps each, within +-8 rad: past the
    joint limits (+-2 pi) and into the plane, so that both stops happen."""
    held = rng.uniform(-8.0, 8.0, (steps // 40 + 1, B, 6))
    return np.repeat(held, 40, axis=0)[:steps]


def test_the_stack_is_numba_dynamics_copy_by_copy():
    # each copy against the single-task kernel of its own task, bit for bit in float64, with
    # masked resets on the way; the entries >= n_b of a command are NaN: they must be ignored
    specs = tasks()
    stack = StackDynamics(specs)
    refs = [NumbaDynamics(task, 1) for task in specs]
    rng = np.random.default_rng(7)
    targets = commands(rng, 400, len(specs))
    stops = np.zeros(2, int)
    for step, target in enumerate(targets):
        command = target.copy()
        for b, task in enumerate(specs):
            command[b, task.n_joints :] = np.nan
        stack.step(torch.from_numpy(command))
        for b, (task, ref) in enumerate(zip(specs, refs, strict=True)):
            ref.step(target[b : b + 1, : task.n_joints])
            for key in STATE:
                assert np.array_equal(getattr(stack, key)[b].numpy(), getattr(ref, key)[0]), \
                    (step, b, key)
        stops += stack.contact.sum().item(), stack.limit_stop.sum().item()
        if step % 50 == 49:
            mask = rng.random(len(specs)) < 0.5
            stack.reset_where(torch.from_numpy(mask))
            for b in np.flatnonzero(mask):
                refs[b].reset(specs[b].start_q, [0])
    assert stops.min() > 0, f"the trajectories must hit the plane and the limits; got {stops}"


def test_reset_where_puts_the_masked_copies_at_their_start():
    specs = tasks()
    stack, fresh = StackDynamics(specs), StackDynamics(specs)
    rng = np.random.default_rng(3)
    for target in commands(rng, 30, len(specs)):
        stack.step(torch.from_numpy(target))
    before = {key: getattr(stack, key).clone() for key in STATE}
    mask = np.arange(len(specs)) % 3 == 0
    stack.reset_where(torch.from_numpy(mask))
    for key in STATE:
        after = getattr(stack, key)
        assert torch.equal(after[mask], getattr(fresh, key)[mask]), key
        assert torch.equal(after[~mask], before[key][~mask]), key
    assert not torch.equal(before["q"][mask], stack.q[mask])  # the copies had moved
    start = np.array([task.start_q for task in specs])
    assert np.array_equal(stack.q[mask].numpy(), start[mask])
    assert np.allclose(stack.height_bound[mask].numpy(),
                       moving_link_heights(start[mask], specs[0].base_height))


def test_copies_keep_their_locked_joints():
    specs = tasks()
    stack = StackDynamics(specs)
    for target in commands(np.random.default_rng(2), 60, len(specs)):
        stack.step(torch.from_numpy(target))
    start = np.array([task.start_q for task in specs])
    for b, task in enumerate(specs):
        assert np.array_equal(stack.q[b, task.n_joints :].numpy(), start[b, task.n_joints :])
        assert not np.array_equal(stack.q[b, : task.n_joints].numpy(),
                                  start[b, : task.n_joints])


# ---------------------------------------------------------------------------- refusals
def test_the_field_lists_partition_the_taskspec():
    names = [f.name for f in dataclasses.fields(TaskSpec)]
    listed = PER_COPY_FIELDS + DYNAMICS_FIELDS + UNREAD_FIELDS
    assert sorted(listed) == sorted(names) and len(set(listed)) == len(listed)


CHANGED = {"base_height": 0.2, "control_mode": "velocity", "control_hz": 100, "sim_hz": 2000,
           "kp": (500.0,) * 6, "kd": (50.0,) * 6, "gravity_compensation": False,
           "plane_margin": 0.01}


@pytest.mark.parametrize("field", sorted(CHANGED))
def test_tasks_that_differ_in_what_the_dynamics_reads_are_refused(field):
    task = TaskSpec(n_joints=3)
    other = dataclasses.replace(task, **{field: CHANGED[field]})
    with pytest.raises(ValueError, match=rf"tasks\[1\]\.{field} = .* differs from tasks\[0\]"):
        StackDynamics([task, other])


def test_held_joints_and_contact_model_are_refused():
    with pytest.raises(ValueError, match=r"tasks\[1\]\.held_joints = 'pd'"):
        StackDynamics([TaskSpec(), TaskSpec(held_joints="pd")])
    with pytest.raises(ValueError, match=r"tasks\[0\]\.contact_model = 'compliant'"):
        StackDynamics([TaskSpec(contact_model="compliant")])
    with pytest.raises(ValueError, match="at least one TaskSpec"):
        StackDynamics([])


def test_goal_side_fields_may_differ():
    specs = [TaskSpec(region="zheight", n_joints=3, success_radius=0.05),
             TaskSpec(region="closebox", n_joints=3, goal_sampler="cartesian",
                      max_episode_steps=50)]
    assert StackDynamics(specs).num_copies == 2


def test_bad_kernels_devices_and_inputs_are_refused():
    with pytest.raises(ValueError, match="kernel must be one of"):
        StackDynamics([TaskSpec()], kernel="torch")
    with pytest.raises(ValueError, match="kernel='numba' runs on the CPU"):
        StackDynamics([TaskSpec()], device="cuda", kernel="numba")
    stack = StackDynamics([TaskSpec(), TaskSpec()])
    with pytest.raises(ValueError, match=r"command must be \(2, 6\); got \(2, 3\)"):
        stack.step(torch.zeros(2, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"mask must be \(2,\); got \(3,\)"):
        stack.reset_where(torch.zeros(3, dtype=torch.bool))


@needs_triton
def test_triton_on_the_cpu_needs_the_interpreter():
    code = ("from envs.physics.stack import StackDynamics; from envs.spec import TaskSpec; "
            "StackDynamics([TaskSpec()], kernel='triton')")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "TRITON_INTERPRET": "0"}, timeout=300)
    assert run.returncode != 0
    assert "set TRITON_INTERPRET=1" in run.stderr, run.stderr[-2000:]


# ---------------------------------------------------------------------------- host reads
HOST_READS = ("item", "cpu", "numpy", "tolist", "__bool__", "__int__", "__float__",
              "__index__")


@pytest.fixture
def no_host_reads(monkeypatch):
    """Every way a tensor's value reaches Python raises (the CPU stand-in for CUDA's
    ``torch.cuda.set_sync_debug_mode("error")``)."""
    def forbid(name):
        def read(*args, **kwargs):
            raise AssertionError(f"Tensor.{name} read a value on the host")
        return read

    for name in HOST_READS:
        monkeypatch.setattr(torch.Tensor, name, forbid(name))


@pytest.mark.parametrize("kernel", ["numba", "triton"])
def test_step_and_reset_where_read_nothing_on_the_host(kernel, monkeypatch, request):
    if kernel == "triton":
        if not HAS_TRITON:
            pytest.skip("triton is not installed")
        from envs.physics import triton_kernel

        # the interpreter itself copies every tensor to numpy; on a GPU the launch reads
        # nothing: here the wrapper around the launch is what is checked
        calls = []
        monkeypatch.setattr(triton_kernel, "launch", lambda *args: calls.append(args))
    stack = StackDynamics(tasks()[:3], kernel=kernel)
    command = torch.zeros(3, 6, dtype=torch.float64)
    mask = torch.tensor([True, False, True])
    request.getfixturevalue("no_host_reads")
    stack.step(command)
    stack.reset_where(mask)
    with pytest.raises(AssertionError, match="read a value on the host"):
        bool(mask[0])  # the fixture is armed
    if kernel == "triton":
        assert len(calls) == 1


# ---------------------------------------------------------------------------- Triton
def hard_states(specs: list[TaskSpec], rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Start states ``q, w (B, 6)`` and their exact height bounds near the stops: every other
    copy's first joint 0.1 rad inside its limit, the others' moving joints random with every
    link 2-15 cm above the plane, moving fast (locked joints at their start, at rest)."""
    B = len(specs)
    q = np.array([task.start_q for task in specs])
    w = np.zeros((B, 6))
    for b, task in enumerate(specs):
        n = task.n_joints
        while True:
            trial = q[b].copy()
            trial[:n] = rng.uniform(-1.5, 1.5, n)
            if b % 2:
                trial[0] = 2 * np.pi - 0.1
            low = moving_link_heights(trial, task.base_height).min()
            if 0.02 < low < 0.15 or (b % 2 and low > 0.02):
                break
        q[b] = trial
        w[b, :n] = rng.uniform(-0.005, 0.005, n)  # rad per substep: up to 5 rad/s
    return q, w, moving_link_heights(q, specs[0].base_height)


def hard_case(specs: list[TaskSpec], steps: int, rng: np.random.Generator
              ) -> tuple[np.ndarray, ...]:
    """:func:`hard_states` and position targets ``(steps, B, 6)`` rad (past the limits:
    every other copy's first joint driven past its own) under which the numba stack stops
    copies both on the plane and at a limit (drawn again until it does)."""
    for _ in range(100):
        q, w, heights = hard_states(specs, rng)
        targets = rng.uniform(-8.0, 8.0, (steps, len(specs), 6))
        targets[:, 1::2, 0] = 8.0
        stack = StackDynamics(specs)
        stack.q[:], stack.w[:], stack.height_bound[:] = (torch.from_numpy(x) for x in
                                                        (q, w, heights))
        stops = np.zeros(2, int)
        for target in targets:
            stack.step(torch.from_numpy(target))
            stops += stack.contact.sum().item(), stack.limit_stop.sum().item()
        if stops.min() > 0:
            return q, w, heights, targets
    raise AssertionError("no draw stops a copy on the plane and one at a limit")


def test_the_height_bounds_never_change_the_answer():
    # the kernels take link k's exact height only where its Lipschitz bound fails (the others
    # keep the bound); against a stack whose bounds always fail (every substep, every link
    # exact), from states at the plane and commands past it: the same steps bit for bit
    specs = tasks()
    q, w, heights, targets = hard_case(specs, 20, np.random.default_rng(12))
    stacks = [StackDynamics(specs) for _ in range(2)]
    args = list(stacks[1]._args)
    [at] = [i for i, x in enumerate(args) if x is stacks[1]._plane.lipschitz]
    args[at] = np.full_like(args[at], 1e9)  # no bound proves a link clear
    stacks[1]._args = tuple(args)
    for stack in stacks:
        stack.q[:], stack.w[:], stack.height_bound[:] = (torch.from_numpy(x) for x in
                                                        (q, w, heights))
    contacts = 0
    for target in targets:
        for stack in stacks:
            stack.step(torch.from_numpy(target))
        skipping, exact = stacks
        for key in ("q", "w", "tool", "contact", "limit_stop"):
            assert torch.equal(skipping.__dict__[key], exact.__dict__[key]), key
        exact_links = moving_link_heights(skipping.q.numpy(), specs[0].base_height)
        assert (skipping.height_bound.numpy() <= exact_links + 1e-12).all()  # still bounds
        contacts += int(skipping.contact.sum())
    assert contacts > 0


def kernels_agree(dtype: str, steps: int, device: str = "cpu") -> None:
    """Assert that the Triton stack on ``device`` steps as the numba CPU kernel's stack does:
    the same stop flags, states within 1e-9 (float64) or `FLOAT32_TOLERANCE`, over ``steps``
    steps from states at the plane and the limits and commands past both (`hard_case`)."""
    specs = tasks()
    q, w, heights, targets = hard_case(specs, steps, np.random.default_rng(11))
    stacks = [StackDynamics(specs, dtype=dtype, kernel="numba"),
              StackDynamics(specs, dtype=dtype, kernel="triton", device=device)]
    for stack in stacks:
        stack.q[:], stack.w[:], stack.height_bound[:] = (torch.from_numpy(x).to(stack.q.device)
                                                        for x in (q, w, heights))
    tolerance = 1e-9 if dtype == "float64" else FLOAT32_TOLERANCE
    stops = np.zeros(2, int)
    for step, target in enumerate(targets):
        for stack in stacks:
            stack.step(torch.from_numpy(target).to(stack.q.device))
        numba = stacks[0].__dict__
        triton = {k: v.cpu() if isinstance(v, torch.Tensor) else v
                  for k, v in stacks[1].__dict__.items()}
        for key in ("contact", "limit_stop"):
            assert torch.equal(numba[key], triton[key]), (step, key)
        for key in ("q", "w", "v", "acceleration", "height_bound", "tool"):
            scale = 1.0 if key in ("q", "height_bound", "tool") else \
                float(numba[key].abs().max()) + 1.0
            err = float((numba[key] - triton[key]).abs().max()) / scale
            assert err <= tolerance, (step, key, err)
        stops += numba["contact"].sum().item(), numba["limit_stop"].sum().item()
    assert stops.min() > 0, f"the steps must hit the plane and the limits; got {stops}"


@needs_triton
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_the_triton_kernel_is_the_numba_kernel(dtype):
    # the interpreter is slow (a numpy call per operation): 8 copies, 3 steps
    kernels_agree(dtype, 3)


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (the GPU window's "
                    "stage 1 runs it: benchmarks/gpu_grid.sh)")
@needs_triton
@pytest.mark.parametrize(("dtype", "steps"), [("float64", 40), ("float32", 3)])
def test_the_compiled_triton_kernel_is_the_numba_kernel_on_cuda(dtype, steps):
    """The kernel compiled for the GPU (not the interpreter: a process without
    TRITON_INTERPRET) against the numba CPU kernel, as the interpreter is above."""
    here = os.path.dirname(os.path.abspath(__file__))
    run = subprocess.run([sys.executable, "-c", "import test_stack_dynamics as t; "
                          f"t.kernels_agree({dtype!r}, {steps}, device='cuda')"], cwd=here,
                         env={**os.environ, "TRITON_INTERPRET": "0",
                              "PYTHONPATH": os.pathsep.join([os.path.dirname(here), here])},
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]


@needs_triton
def test_the_benchmark_runs_in_its_dry_run():
    # benchmarks.stack_dynamics on the CPU: the stack on numba and on Triton's interpreter (4
    # copies, 1 step), the Triton-against-numba check
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {k: v for k, v in os.environ.items() if k not in ("TRITON_INTERPRET",
                                                            "NUMBA_ENABLE_CUDASIM")}
    run = subprocess.run([sys.executable, "-m", "benchmarks.stack_dynamics", "--dry-run",
                          "--json"], cwd=root, capture_output=True, text=True, env=env,
                         timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout)
    rows = result["rows"]
    assert [row["kernel"] for row in rows] == ["stack-triton", "stack-numba"]
    assert all("error" not in row and row["copy_steps_per_s"] > 0 and row["N"] == 4
               for row in rows), rows
    [check] = result["checks"]
    assert check["max_abs_q_rad"] <= 1e-9 and check["stop_flags_agree"], check
    usage = subprocess.run([sys.executable, "-m", "benchmarks.stack_dynamics", "--help"],
                           cwd=root, capture_output=True, text=True, env=env)
    for flag in ("--copies", "--steps", "--rounds", "--device", "--dtype", "--kernels",
                 "--modes", "--block", "--check-steps", "--dry-run", "--json"):
        assert flag in usage.stdout


MAX_LANE_MEMORY_OPS = 13
"""Lane-tensor loads and stores the kernel's TTIR may hold: one tile per state array (5 read,
``w`` twice, 5 written), ``free`` and the two stop flags. ``TritonGPUCoalesce`` walks the
whole kernel once per such access (its cost grows with their number times the kernel's size):
at one access per column (68) the sm_90 compile took 317 s of CPU, at 13 it takes 24 s."""

MAX_TTIR_OPERATIONS = 7_000
"""The kernel's TTIR operations (6,012 generated, the vertex table in the code; 6,818 before
with the tables as constants; 9,368 with their ~400 scalar loads, addresses and splats)."""

MAX_SPILL_BYTES = 16
"""ptxas's spill stores and loads (bytes) of the float64 kernel for sm_90: 1,588 and 2,012
before issue 42 (``results/grid_program/arm_kernel.md``)."""


@needs_triton
def test_the_kernel_keeps_the_compile_cheap_and_spills_nothing():
    # the sm_90 compile without a GPU, to the cubin (about 24 s of CPU): the counts that set
    # the compile's cost, and ptxas's spills
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    run = subprocess.run([sys.executable, "-m", "benchmarks.triton_compile"], cwd=root,
                         capture_output=True, text=True, env=env, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout)
    assert 0 < result["ttir_lane_memory_ops"] <= MAX_LANE_MEMORY_OPS, result
    assert result["ttir_operations"] <= MAX_TTIR_OPERATIONS, result
    assert result["registers"] > 0, result  # ptxas's log was read
    assert result["spill_store_bytes"] <= MAX_SPILL_BYTES, result
    assert result["spill_load_bytes"] <= MAX_SPILL_BYTES, result
    refused = subprocess.run([sys.executable, "-m", "benchmarks.triton_compile"], cwd=root,
                             capture_output=True, text=True,
                             env={**env, "TRITON_INTERPRET": "1"}, timeout=300)
    assert refused.returncode != 0 and "TRITON_INTERPRET is set" in refused.stderr
