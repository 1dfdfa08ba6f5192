"""TorchReach on the numba kernels (``dynamics="numba"``) against the torch kernel and numpy.

Three paths step in lockstep from one seed: ``TorchReach(dynamics="numba")`` (a numba kernel
behind envs.physics.numba_torch's zero-copy tensors),
``TorchReach(dynamics="torch")`` and ``BatchedReach(dynamics="numba")`` on the CPU, through
contacts, successes and every autoreset mode (masked resets on the device), 2, 3 and 6 joints,
held joints locked and pd. Then the zero copy itself, the refusals, no read-back in ``step``,
and a short ``ddpg_her.train --env-backend torch --env-dynamics numba`` run against the torch
kernel's.

The checks (``check_*``) run three times: on the CPU kernel (envs.physics.numba_kernel,
``device="cpu"`` in this process, no simulator); for the CUDA kernel, as tests/test_numba_cuda.py's,
under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, one subprocess per check: the variable
must be set before numba.cuda is imported), where the kernel's device arrays are numpy arrays and
the env lives on ``device="cpu"``; and in this process on a real GPU (``device="cuda"``) where
numba and torch see one, with the GPU-only checks of streams and synchronisation. The simulator
runs the kernel as Python: 0.1 s per copy and step, so few copies and steps.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest

from envs.spec import TaskSpec
from envs.task import INFO_KEYS, action_bounds

torch = pytest.importorskip("torch")
pytest.importorskip("numba")  # the kernel is optional

ROOT = Path(__file__).resolve().parent.parent

ROLLOUT_ATOL = 1e-9
"""Bound on every float of a float64 rollout against the torch kernel's and BatchedReach's (m,
rad, rad/s, rad/s^2, reward; as tests/test_torchreach.py's). The simulator gives about 1e-13
against the torch kernel and 0 against BatchedReach's dynamics; a GPU may fuse multiply-adds."""

F32_ATOL = 1e-4
"""Bound of the float32 kernel's observations against the float32 torch kernel's over a few
contact-free steps (rad, rad/s; rad/s^2 scaled by 1e-3: float32 rounding over a step, divided
by dt)."""

CASES = {
    # held joints locked (joints 4..6 out of the dynamics), a wide success ball: terminations;
    # Gymnasium's default autoreset (a masked reset on the step after an episode ends)
    "j3-locked-next_step": (dict(n_joints=3, held_joints="locked", success_radius=0.6,
                                 max_episode_steps=4), "next_step", 5),
    # every joint controlled (nothing held), velocity control, final obs and info on the step
    "j6-velocity-same_step": (dict(n_joints=6, control_mode="velocity", region="zheight",
                                   success_radius=0.6, max_episode_steps=4), "same_step", 5),
    # joints 3..6 held by the PD (they give way), masked resets asked for by the caller
    "j2-pd-disabled": (dict(n_joints=2, held_joints="pd", success_radius=0.8,
                            max_episode_steps=3), "disabled", 7),
}
"""Task fields, autoreset mode and goal seed of each rollout check (short episodes:
autoresets happen; seeds picked so that contacts, successes and time limits all happen, which
each check asserts)."""

ROLLOUT_STEPS, ROLLOUT_COPIES = 9, 4


DEVICE = "cuda"
"""Where the checks put the env: set by each test ("cpu" for the CPU kernel and under the
simulator, "cuda" on a GPU)."""


def device() -> str:
    return DEVICE


def host_kernel() -> bool:
    """Whether the checks run on the CPU kernel (``device="cpu"`` without the simulator)."""
    from envs.physics import numba_cuda

    return DEVICE == "cpu" and not numba_cuda.simulated()


def kernel_array(dyn, key: str):
    """``(address, host copy)`` of the kernel's own state array ``key``."""
    from envs.physics import numba_cuda

    array = getattr(dyn.kernel.state, key)
    if host_kernel():
        return array.ctypes.data, np.array(array)
    return numba_cuda.device_pointer(array), array.copy_to_host()


def host(x) -> np.ndarray:
    return x.detach().cpu().numpy()


def commands(task: TaskSpec, steps: int, copies: int, seed: int) -> np.ndarray:
    """Actions ``(steps, copies, n)`` up to 1.3 times beyond the box (the env clips them), the
    shoulder of the first two copies driven down: into the plane."""
    low, high = action_bounds(task)
    out = np.random.default_rng(seed).uniform(1.3 * low, 1.3 * high, (steps, copies, len(low)))
    out[:, :2, 1] = high[1]
    return out


def assert_close(value, reference, what: str, atol: float = ROLLOUT_ATOL) -> None:
    ref = host(reference) if isinstance(reference, torch.Tensor) else np.asarray(reference)
    np.testing.assert_allclose(host(value).astype(np.float64), ref.astype(np.float64), rtol=0,
                               atol=atol, err_msg=what)


def compare_step(out, ref, mode: str) -> None:
    """Every output of one step (tensors, or BatchedReach's arrays) equal to rounding; the
    flags exactly."""
    (obs, reward, term, trunc, info), (r_obs, r_reward, r_term, r_trunc, r_info) = out, ref
    for key in r_obs:
        assert_close(obs[key], r_obs[key], key)
    assert_close(reward, r_reward, "reward")
    for flag, r_flag, what in ((term, r_term, "terminated"), (trunc, r_trunc, "truncated"),
                               (info["contact"], r_info["contact"], "contact"),
                               (info["joint_limit"], r_info["joint_limit"], "joint_limit")):
        np.testing.assert_array_equal(host(flag), np.asarray(host(r_flag) if isinstance(
            r_flag, torch.Tensor) else r_flag), err_msg=what)
    for key in INFO_KEYS:
        assert_close(info[key], r_info[key], f"info[{key!r}]")
    if mode == "same_step" and "_final_obs" in r_info:
        done = host(r_info["_final_obs"]) if isinstance(r_info["_final_obs"], torch.Tensor) \
            else r_info["_final_obs"]
        np.testing.assert_array_equal(host(info["_final_obs"]), done)
        for i in np.flatnonzero(done):
            for key in obs:
                final = r_info["final_obs"][key][i] if isinstance(r_info["final_obs"], dict) \
                    else r_info["final_obs"][i][key]
                assert_close(info["final_obs"][key][i], final, f"final_obs[{key!r}]")


# ------------------------------------------------------------------ the checks
def rollout_check(name: str) -> str:
    from envs.batched import BatchedReach
    from envs.torchreach import TorchReach

    fields, mode, seed = CASES[name]
    dev, num = device(), ROLLOUT_COPIES
    kwargs = dict(autoreset_mode=mode, **fields)
    fused = TorchReach(num, device=dev, dynamics="numba", goal_source="per_copy", goal_pool=2,
                       **kwargs)
    tensor = TorchReach(num, device=dev, goal_source="per_copy", goal_pool=2, **kwargs)
    batched = BatchedReach(num, dynamics="numba", **kwargs)
    assert type(fused.dynamics).__name__ == "NumbaTorchDynamics"
    obs = [env.reset(seed=seed)[0] for env in (fused, tensor, batched)]
    for key in obs[2]:
        assert_close(obs[0][key], obs[1][key], key)
        assert_close(obs[0][key], obs[2][key], key)
    seen = dict(contact=False, terminated=False, truncated=False)
    n = fused.task.n_joints
    for a in commands(fused.task, ROLLOUT_STEPS, num, seed=6):
        outs = [env.step(torch.as_tensor(a, device=dev)) for env in (fused, tensor)]
        ref = batched.step(a)
        compare_step(outs[0], outs[1], mode)
        compare_step(outs[0], ref, mode)
        seen["contact"] |= bool(ref[4]["contact"].any())
        seen["terminated"] |= bool(ref[2].any())
        seen["truncated"] |= bool(ref[3].any())
        done = ref[2] | ref[3]
        if mode == "disabled" and done.any():  # the caller's masked reset, on the device
            mask = torch.as_tensor(done, device=dev)
            got = [env.reset(options={"reset_mask": mask})[0] for env in (fused, tensor)]
            want = batched.reset(options={"reset_mask": done})[0]
            for key in want:
                assert_close(got[0][key], got[1][key], key)
                assert_close(got[0][key], want[key], key)
        q = host(fused.dynamics.q)
        if fused.task.held_joints == "locked" and n < 6:
            np.testing.assert_array_equal(q[:, n:], np.broadcast_to(fused.task.start_q[n:],
                                                                    q[:, n:].shape))
    assert seen["contact"] and seen["truncated"] and seen["terminated"], seen
    if fused.task.held_joints == "pd" and n < 6:
        held = host(fused.dynamics.q)[:, n:] - np.asarray(fused.task.start_q[n:])
        assert np.abs(held).max() > 1e-6, "the pd-held joints never moved: the check misses them"
    return "ok"


def check_rollout_j3_locked_next_step() -> str:
    return rollout_check("j3-locked-next_step")


def check_rollout_j6_velocity_same_step() -> str:
    return rollout_check("j6-velocity-same_step")


def check_rollout_j2_pd_disabled_masked_resets() -> str:
    return rollout_check("j2-pd-disabled")


def check_state_tensors_are_the_kernels_arrays() -> str:
    from envs.physics import numba_cuda
    from envs.physics.numba_torch import STATE, NumbaTorchDynamics

    task = TaskSpec(region="unconstrained", n_joints=3)
    dyn = NumbaTorchDynamics(task, 2, device=device(), threads_per_block=2)
    assert type(dyn.kernel).__name__ == ("HostKernel" if host_kernel() else "NumbaCudaDynamics")
    for key in STATE:
        assert getattr(dyn, key).data_ptr() == kernel_array(dyn, key)[0], key
    # a write through a tensor is in the kernel's array, and a launch shows in the tensor
    dyn.q[1, 0] = 0.25
    assert kernel_array(dyn, "q")[1][1, 0] == 0.25
    before, ptr = dyn.q.clone(), dyn.q.data_ptr()
    dyn.step(torch.full((2, 3), 0.3, dtype=torch.float64, device=dyn.device))
    dyn.synchronize()
    np.testing.assert_array_equal(host(dyn.q), kernel_array(dyn, "q")[1])
    assert dyn.q.data_ptr() == ptr and not torch.equal(dyn.q, before)
    # commands, masks and poses enter the kernels as views of the caller's tensors
    command = torch.zeros((2, 3), dtype=torch.float64, device=dyn.device)
    if host_kernel():
        assert command.numpy().ctypes.data == command.data_ptr()
    else:
        assert numba_cuda.device_pointer(numba_cuda.device_view(command)) == command.data_ptr()
    # the masked reset and the clearance, on the device
    mask = torch.tensor([False, True], device=dyn.device)
    dyn.reset_where(mask, torch.as_tensor(task.start_q, device=dyn.device))
    dyn.synchronize()
    np.testing.assert_array_equal(host(dyn.q[1]), task.start_q)
    assert not torch.equal(dyn.q[0], dyn.q[1])
    from envs.physics.numba_kernel import link_heights

    np.testing.assert_allclose(host(dyn.clearance()),
                               link_heights(host(dyn.q), task.base_height).min(-1),
                               rtol=0, atol=1e-12)
    return "ok"


def check_float32_follows_the_torch_kernel() -> str:
    from envs.torchreach import TorchReach

    dev = device()
    envs = [TorchReach(2, device=dev, dtype="float32", dynamics=d, goal_source="per_copy")
            for d in ("numba", "torch")]
    assert envs[0].dynamics.q.dtype == torch.float32
    outs = [env.reset(seed=1)[0] for env in envs]
    rng = np.random.default_rng(5)  # targets with the shoulder up: no contact
    for _ in range(3):
        a = torch.as_tensor(rng.uniform((-1.0, -1.2, -0.5), (1.0, -0.4, 0.5), (2, 3)),
                            dtype=torch.float32, device=dev)
        outs = [env.step(a)[0] for env in envs]
    n = envs[0].task.n_joints
    obs = [o["observation"].double() for o in outs]
    assert_close(obs[0][:, : 2 * n], obs[1][:, : 2 * n], "q, v", atol=F32_ATOL)
    assert_close(obs[0][:, 2 * n :] * 1e-3, obs[1][:, 2 * n :] * 1e-3, "acceleration",
                 atol=F32_ATOL)
    return "ok"


def check_bad_inputs_are_refused() -> str:
    from envs.physics.numba_torch import NumbaTorchDynamics
    from envs.torchreach import TorchReach

    dev = device()
    with pytest.raises(ValueError, match="'jax'"):
        TorchReach(2, device=dev, dynamics="jax")
    with pytest.raises(ValueError, match="cuda_graph"):
        TorchReach(2, device=dev, dynamics="numba", cuda_graph=True)
    with pytest.raises(ValueError, match="stop contact"):
        TorchReach(2, device=dev, dynamics="numba", contact_model="compliant")
    from envs.physics import numba_cuda

    if numba_cuda.simulated() or not gpu_available():  # the simulator is host memory
        with pytest.raises(ValueError, match="'cuda'"):
            NumbaTorchDynamics(TaskSpec(), 2, device="cuda")
    with pytest.raises(ValueError, match="'mps'"):
        NumbaTorchDynamics(TaskSpec(), 2, device="mps")
    dyn = NumbaTorchDynamics(TaskSpec(), 2, device=dev)
    with pytest.raises(ValueError, match=r"command must be \(2, 3\)"):
        dyn.step(torch.zeros((3, 3), dtype=torch.float64, device=dev))
    with pytest.raises(ValueError, match=r"mask must be \(2,\)"):
        dyn.reset_where(torch.ones(3, dtype=torch.bool, device=dev), dyn.q[0])
    with pytest.raises(ValueError, match="below the plane margin"):
        dyn.reset(np.array([0.0, 1.5, 0.0, 0.0, 0.0, 0.0]), [0])
    return "ok"


READS = ("__bool__", "item", "tolist", "cpu", "__int__", "__float__")
"""Tensor methods that bring a value to the host (a synchronisation on CUDA). Not ``numpy``:
under the simulator the kernel's views of CPU tensors are made by it, without a copy (on a GPU
a CUDA tensor has no ``numpy``, and the GPU check uses torch's sync debug mode)."""


def check_step_reads_nothing_back() -> str:
    from envs.torchreach import TorchReach

    if device() == "cuda":
        return check_step_does_not_synchronise_on_cuda()
    depth = 5
    env = TorchReach(3, device="cpu", dynamics="numba", goal_pool=depth, success_radius=0.6,
                     max_episode_steps=2)
    assert type(env.dynamics.kernel).__name__ == ("HostKernel" if host_kernel()
                                                  else "NumbaCudaDynamics")
    env.reset(seed=0)
    actions = torch.as_tensor(commands(env.task, depth - 1, 3, seed=1))

    def forbidden(*args, **kwargs):
        raise AssertionError("a device-to-host read inside step()")

    saved = {name: getattr(torch.Tensor, name) for name in READS}
    try:
        for name in READS:
            setattr(torch.Tensor, name, forbidden)
        for a in actions:  # autoresets included (episodes of 2 steps)
            env.step(a)
    finally:
        for name, method in saved.items():
            setattr(torch.Tensor, name, method)
    return "ok"


def check_train_run_equals_the_torch_kernels() -> str:
    """``python -m ddpg_her.train --env-backend torch --env-dynamics numba`` (its ``main``), 2
    episodes, tiny: eval.csv equal to the torch kernel's run to rounding, and spec.json
    records the dynamics."""
    from ddpg_her import train
    from envs.physics.numba_torch import NumbaTorchDynamics

    dev = device()
    rows, specs, launches = {}, {}, {}
    step = NumbaTorchDynamics.step
    calls = []

    def counted(self, command):  # the kernel steps the numba run's envs, and only its
        calls.append(1)
        step(self, command)

    # train.main sets torch's deterministic mode for the process: put it back (the GPU check
    # runs in pytest's process)
    deterministic = (torch.are_deterministic_algorithms_enabled(),
                     torch.is_deterministic_algorithms_warn_only_enabled())
    with tempfile.TemporaryDirectory() as tmp:
        for dynamics in ("numba", "torch"):
            out = Path(tmp) / dynamics
            argv = ["--region", "zheight", "--joints", "3", "--seeds", "3", "--episodes", "2",
                    "--eval-every", "2", "--eval-episodes", "2", "--hidden-sizes", "8", "8",
                    "--updates-per-episode", "2", "--warmup-episodes", "1", "--buffer-size",
                    "1000", "--batch-size", "8", "--task", "max_episode_steps=8", "--task",
                    "success_radius=0.6", "--no-progress", "--no-tensorboard", "--device", dev,
                    "--env-backend", "torch", "--env-dynamics", dynamics, "--out", str(out)]
            calls.clear()
            NumbaTorchDynamics.step = counted
            try:
                assert train.main(argv) == 0
            finally:
                NumbaTorchDynamics.step = step
                torch.use_deterministic_algorithms(deterministic[0],
                                                   warn_only=deterministic[1])
            launches[dynamics] = len(calls)
            with open(out / "eval.csv") as f:
                rows[dynamics] = list(csv.DictReader(f))
            specs[dynamics] = json.loads((out / "spec.json").read_text())
    assert specs["numba"]["env_dynamics"] == "numba" and "env_dynamics" not in specs["torch"]
    assert launches["numba"] > 0 and launches["torch"] == 0, launches
    assert len(rows["numba"]) == len(rows["torch"]) == 1
    for got, want in zip(rows["numba"], rows["torch"], strict=True):
        for key in want:
            if key != "wall_s":  # the printed values: 6 decimals
                np.testing.assert_allclose(float(got[key]), float(want[key]), rtol=0,
                                           atol=2e-6, err_msg=key)
    assert int(rows["numba"][0]["successes"]) > 0, "no success: the check is too easy"
    return f"eval {dict(rows['numba'][0])}"


# ------------------------------------------------------------------ GPU-only checks
def check_step_does_not_synchronise_on_cuda() -> str:
    from stepping import step_without_cuda_sync

    from envs.torchreach import TorchReach

    depth = 8
    env = TorchReach(8, device="cuda", dynamics="numba", goal_pool=depth, success_radius=0.6,
                     max_episode_steps=3)
    env.reset(seed=0)
    step_without_cuda_sync(env, torch.as_tensor(commands(env.task, depth - 1, 8, seed=1),
                                                device="cuda"))
    return "ok"


def check_launches_follow_torchs_current_stream() -> str:
    # the command is made on a side stream just before the step (after a long matmul on that
    # stream): a launch on numba's default stream could read it before it is written
    from envs.torchreach import TorchReach

    task = dict(n_joints=3, success_radius=0.6, max_episode_steps=5)
    envs = [TorchReach(64, device="cuda", dynamics=d, goal_source="per_copy", **task)
            for d in ("numba", "torch")]
    for env in envs:
        env.reset(seed=2)
    torch.cuda.synchronize()
    acts = torch.as_tensor(commands(envs[0].task, 6, 64, seed=3), device="cuda")
    side = torch.cuda.Stream()
    big = torch.randn(4096, 4096, device="cuda")
    logs: list[list[torch.Tensor]] = [[], []]
    for a in acts:
        for env, log in zip(envs, logs, strict=True):
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                delay = (big @ big).sum() * 0.0  # keeps the side stream busy
                command = a + delay.to(a.dtype)
                obs = env.step(command)[0]
                log.append(obs["observation"].clone())
            torch.cuda.current_stream().wait_stream(side)
    torch.cuda.synchronize()
    for got, want in zip(*logs, strict=True):
        assert_close(got, want, "observation")
    return "ok"


CHECKS = (check_rollout_j3_locked_next_step, check_rollout_j6_velocity_same_step,
          check_rollout_j2_pd_disabled_masked_resets, check_state_tensors_are_the_kernels_arrays,
          check_float32_follows_the_torch_kernel, check_bad_inputs_are_refused,
          check_step_reads_nothing_back, check_train_run_equals_the_torch_kernels)
"""Run on the CPU kernel, under the simulator (on the CPU) and on a GPU."""

GPU_CHECKS = (check_step_does_not_synchronise_on_cuda,
              check_launches_follow_torchs_current_stream)
"""Run on a GPU only (streams and synchronisation do not exist in the simulator)."""

SIMULATOR = """
import sys
sys.path.insert(0, "tests")
import test_torchreach_numba as t
t.DEVICE = "cpu"
check = getattr(t, sys.argv[1])
print(check.__name__, check(), flush=True)
"""


# ------------------------------------------------------------------ the tests
def run_python(code: str, *args: str, **env: str) -> subprocess.CompletedProcess:
    """``python -c code args`` from the repository root, with ``env`` added to the
    environment."""
    return subprocess.run([sys.executable, "-c", code, *args], env={**os.environ, **env},
                          cwd=ROOT, capture_output=True, text=True)


def gpu_available() -> bool:
    """Whether numba and torch both see a GPU (not the simulator) in this process."""
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1" or not torch.cuda.is_available():
        return False
    from envs.physics import numba_cuda

    return numba_cuda.available()


@pytest.fixture(scope="module")
def simulator() -> None:
    probe = run_python("from numba import cuda; assert cuda.is_available()",
                       NUMBA_ENABLE_CUDASIM="1")
    if probe.returncode:
        pytest.skip(f"numba's CUDA simulator does not start here: {probe.stderr[-300:]}")


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__.removeprefix("check_"))
def test_on_the_cpu_kernel(check, monkeypatch):
    from envs.physics import numba_cuda

    if numba_cuda.simulated():
        pytest.skip("this process runs numba's CUDA simulator: the CPU device is the CUDA path")
    monkeypatch.setattr(sys.modules[__name__], "DEVICE", "cpu")
    check()


@pytest.mark.parametrize("check", CHECKS, ids=lambda c: c.__name__.removeprefix("check_"))
def test_under_the_cuda_simulator(simulator, check):
    run = run_python(SIMULATOR, check.__name__, NUMBA_ENABLE_CUDASIM="1", OMP_NUM_THREADS="1")
    assert run.returncode == 0, run.stdout + run.stderr[-4000:]
    assert run.stdout.splitlines()[-1].startswith(f"{check.__name__} "), run.stdout


@pytest.mark.gpu
@pytest.mark.skipif(not gpu_available(), reason="numba and torch see no CUDA device")
@pytest.mark.parametrize("check", CHECKS + GPU_CHECKS,
                         ids=lambda c: c.__name__.removeprefix("check_"))
def test_on_the_gpu(check, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "DEVICE", "cuda")
    check()


def test_the_train_flag_is_refused_without_the_torch_backend():
    run = subprocess.run([sys.executable, "-m", "ddpg_her.train", "--region", "zheight",
                          "--env-dynamics", "numba", "--env-backend", "batched"], cwd=ROOT,
                         capture_output=True, text=True)
    assert run.returncode == 2
    assert "--env-dynamics numba is the dynamics of --env-backend torch" in run.stderr
    usage = subprocess.run([sys.executable, "-m", "ddpg_her.train", "--help"], cwd=ROOT,
                           capture_output=True, text=True).stdout
    assert "--env-dynamics {torch,numba}" in usage
