"""A heterogeneous stack: B arm copies where copy b runs its own task (its own n_joints and
start pose, every field the dynamics reads otherwise equal), stepped by one kernel call:
:class:`StackDynamics` (issue 35's one-program training; docs/design.md, "Dynamics").

The kernels: numba's CPU kernel (:func:`envs.physics.numba_kernel.control_step`, which reads
each copy's locked joints ``free[b]``) and the Triton kernel
(:mod:`envs.physics.triton_kernel`, on a GPU, or on the CPU under Triton's interpreter).
State and inputs are torch tensors on the device; :meth:`StackDynamics.step` and
:meth:`StackDynamics.reset_where` read nothing back to the host, so a CUDA graph can capture
them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from envs.checks import validate
from envs.physics.model import NJ, arm_model, rest_heights, tool_offset, ur5_plane
from envs.physics.numba_kernel import DTYPES, control_step, dtype_name, kernel_arguments, tool_batch
from envs.spec import TaskSpec

KERNELS = ("numba", "triton")
"""The stack's kernels: ``numba`` (the CPU kernel, on ``"cpu"``) and ``triton`` (on
``"cuda"``, or on ``"cpu"`` under ``TRITON_INTERPRET=1``)."""

PER_COPY_FIELDS = ("n_joints", "start_q")
"""TaskSpec fields that may differ between the copies of a stack."""

DYNAMICS_FIELDS = ("held_joints", "base_height", "control_mode", "control_hz", "sim_hz", "kp",
                   "kd", "gravity_compensation", "plane_margin", "contact_model")
"""TaskSpec fields the dynamics reads besides :data:`PER_COPY_FIELDS`: equal in every copy."""

UNREAD_FIELDS = ("region", "goal_sampler", "reward_type", "distance_weight", "action_weight",
                 "action_penalty_unit", "success_reward", "success_radius",
                 "terminate_on_success", "max_episode_steps", "contact_stiffness",
                 "contact_damping", "contact_friction", "contact_max_depth")
"""TaskSpec fields the stop-model dynamics never reads (the goal side, the reward, the
episode, the compliant contact model's constants): free to differ. The three tuples partition
TaskSpec's fields (tested), so a new field must be placed in one."""

BLOCK = 32
"""Copies per program of the Triton kernel by default (one warp's 32 lanes, one copy each);
untuned until a GPU measures it (``benchmarks.stack_dynamics --block``)."""

TORCH_DTYPES = {"float64": torch.float64, "float32": torch.float32}
"""The state's torch type per dtype name."""


def check_stack(tasks: Sequence[TaskSpec]) -> list[TaskSpec]:
    """``tasks`` as a list, each checked against the robot (:func:`envs.checks.validate`).

    Raises
    ------
    ValueError
        For an empty sequence, a task that is not ``held_joints="locked"`` and
        ``contact_model="stop"`` (the kernels' only cases), or tasks that differ in a field of
        :data:`DYNAMICS_FIELDS`; the message names the field, the copy and both values.
    """
    tasks = list(tasks)
    if not tasks:
        raise ValueError("tasks must hold at least one TaskSpec (one per copy); got none")
    for b, task in enumerate(tasks):
        if not isinstance(task, TaskSpec):
            raise ValueError(f"tasks[{b}] must be a TaskSpec; got {type(task).__name__}")
        if task.held_joints != "locked":
            raise ValueError(f"tasks[{b}].held_joints = {task.held_joints!r}; a stack steps "
                             "held_joints='locked' tasks only (joints n+1..6 out of the "
                             "dynamics)")
        if task.contact_model != "stop":
            raise ValueError(f"tasks[{b}].contact_model = {task.contact_model!r}; the stack's "
                             "kernels implement contact_model='stop' only")
        for field in DYNAMICS_FIELDS:
            if getattr(task, field) != getattr(tasks[0], field):
                raise ValueError(
                    f"tasks[{b}].{field} = {getattr(task, field)!r} differs from tasks[0]."
                    f"{field} = {getattr(tasks[0], field)!r}: a stack's copies may differ in "
                    f"{' and '.join(PER_COPY_FIELDS)} only (and in fields the dynamics does "
                    f"not read: {', '.join(UNREAD_FIELDS[:3])}, ...)")
    for task in dict.fromkeys(tasks):
        validate(task)
    return tasks


def _resolve_kernel(kernel: str | None, device: torch.device) -> str:
    """The kernel to run on ``device`` (None: numba on the CPU, triton on CUDA), or the
    ValueError that says why it cannot run there."""
    if kernel is None:
        kernel = "numba" if device.type == "cpu" else "triton"
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {list(KERNELS)} or None; got {kernel!r}")
    if device.type not in ("cpu", "cuda"):
        raise ValueError(f"device must be 'cpu' or 'cuda[:N]'; got {str(device)!r}")
    if kernel == "numba":
        if device.type != "cpu":
            raise ValueError(f"kernel='numba' runs on the CPU; got device {str(device)!r} "
                             "(kernel='triton' runs on CUDA)")
        return kernel
    try:
        import triton  # noqa: F401
    except ImportError:
        raise ValueError("kernel='triton' needs Triton (pip install triton)") from None
    import envs.physics.triton_kernel as triton_kernel

    if device.type == "cpu":
        from triton.runtime.interpreter import InterpretedFunction

        if not isinstance(triton_kernel.kernel(), InterpretedFunction):
            raise ValueError("kernel='triton' on device 'cpu' runs Triton's interpreter: set "
                             "TRITON_INTERPRET=1 before envs.physics.triton_kernel is first "
                             "imported (kernel='numba' is the CPU kernel)")
    elif not torch.cuda.is_available():
        raise ValueError(f"kernel='triton' on {str(device)!r}: torch sees no CUDA GPU here")
    return kernel


class StackDynamics:
    """B arm copies, copy b under ``tasks[b]``'s controller, one kernel call per control step.

    The physics of :class:`envs.physics.numba_kernel.NumbaDynamics` copy by copy (bitwise, in
    float64, for the numba kernel; the Triton kernel to rounding: both tested), with each
    copy's own locked joints (n_b + 1 .. 6, welded at its start angles) and start pose.

    Parameters
    ----------
    tasks : sequence of TaskSpec
        One per copy (:func:`check_stack`: equal in :data:`DYNAMICS_FIELDS`, locked held
        joints, the stop contact model).
    device : str or torch.device
        ``"cpu"`` or ``"cuda[:N]"``: where the state tensors live and the kernel runs.
    dtype : {"float64", "float32"}
        The kernel's arithmetic and the state's type.
    kernel : {"numba", "triton"} or None
        None: numba on the CPU, triton on CUDA. ``"triton"`` on the CPU runs Triton's
        interpreter (``TRITON_INTERPRET=1``; slow, for tests).
    block : int
        Copies per program of the Triton kernel, a power of two (:data:`BLOCK`).

    Attributes
    ----------
    q, v, acceleration : (B, 6) tensors
        rad, rad/s, rad/s^2 (the last step's mean); a locked joint's stay at its start
        angle, 0, 0.
    w, height_bound : (B, 6) tensors
        The integrator's velocity (rad per substep) and the plane check's lower bounds of
        each moving link's height (m, world z).
    tool : (B, 3) tensor, m, world frame
        tool0's position now.
    contact, limit_stop : (B,) bool tensors
        Whether the last step stopped on the plane, at a joint limit.
    n_joints : (B,) int32 tensor
        Each copy's controlled joints (its ``free``: the kernels' locked joints start there).

    Every state tensor is written in place by :meth:`step` and :meth:`reset_where` (clone what
    you keep). On the CPU with numba the tensors are views of the kernel's numpy arrays (zero
    copy, checked when built).

    Raises
    ------
    ValueError
        From :func:`check_stack`, for an unknown kernel or dtype, or a kernel that cannot run on
        ``device`` here (with why).
    """

    def __init__(self, tasks: Sequence[TaskSpec], device: Any = "cpu", dtype: str = "float64",
                 kernel: str | None = None, block: int = BLOCK) -> None:
        self.tasks = check_stack(tasks)
        if isinstance(block, bool) or not isinstance(block, int) or block < 1 \
                or block & (block - 1):
            raise ValueError(f"block must be a power of two >= 1 (copies per Triton program); "
                             f"got {block!r}")
        self.block = block
        self.device = torch.device(device)
        self.kernel = _resolve_kernel(kernel, self.device)
        name = self.dtype_name = dtype_name(str(dtype).removeprefix("torch."))
        cast, self.dtype = DTYPES[name], TORCH_DTYPES[name]
        B = self.num_copies = len(self.tasks)
        first = self.tasks[0]
        # the full arm's controller: a copy's controlled joints k < n_b get the same gains and
        # command gain under any n; the locked ones' torques never enter the dynamics
        arm = self.arm = arm_model(dataclasses.replace(first, n_joints=NJ))
        n = np.array([t.n_joints for t in self.tasks], dtype=np.int32)
        start_q = np.array([t.start_q for t in self.tasks], dtype=float)
        held = np.arange(NJ)[None, :] >= n[:, None]
        plane = self._plane = ur5_plane(name)
        chain = self._chain = arm.chain.astype(cast)
        tool_pos = tool_offset().astype(cast)
        heights = np.concatenate([rest_heights(t, t.start_q)[None] for t in self.tasks])
        start_tool = np.zeros((B, 3), cast)
        tool_batch(start_q.astype(cast), np.arange(B), chain.rotation, chain.translation,
                   chain.axis, tool_pos, float(first.base_height), start_tool)
        host = dict(q=start_q.astype(cast), w=np.zeros((B, NJ), cast),
                    v=np.zeros((B, NJ), cast), acceleration=np.zeros((B, NJ), cast),
                    height_bound=heights.astype(cast), tool=start_tool.copy(),
                    contact=np.zeros(B, bool), limit_stop=np.zeros(B, bool),
                    bias=np.zeros((B, NJ), cast), dw=np.zeros((B, NJ), cast), n_joints=n)
        tensors = {k: self._tensor(x) for k, x in host.items()}
        for key in ("q", "w", "v", "acceleration", "height_bound", "tool", "contact",
                    "limit_stop", "n_joints"):
            setattr(self, key, tensors[key])
        self._bias, self._dw = tensors["bias"], tensors["dw"]
        self._gain = self._tensor(np.where(held, 0.0, arm.command_gain).astype(cast))
        self._start_q = self._tensor(start_q.astype(cast))
        self._start_heights = self._tensor(heights.astype(cast))
        self._start_tool = self._tensor(start_tool)
        self._w_to_v, self._w_to_accel = float(arm.w_to_v), float(arm.w_to_accel)
        controller = dict(kp=arm.kp_eff, kd=arm.kd_eff, effort=arm.effort, w_max=arm.w_max,
                          q_mid=arm.q_mid, q_half=arm.q_half)
        if self.kernel == "numba":
            self._args = (*kernel_arguments(first, arm, chain, plane, tool_pos, cast, tuple(
                host[k] for k in ("q", "w", "bias", "height_bound", "dw", "contact",
                                  "limit_stop", "tool", "n_joints"))), 0, B)
        else:
            import envs.physics.triton_kernel as triton_kernel

            self._model = triton_kernel.TritonModel.build(
                controller, chain, plane, tool_pos, first.base_height, first.plane_margin,
                first.substeps, first.gravity_compensation, self.dtype)

    def _tensor(self, array: np.ndarray) -> torch.Tensor:
        """``array`` as a tensor on the device: on the CPU a view of it (zero copy; the numba
        kernel writes the arrays, the tensors see it), on CUDA a copy."""
        if self.device.type == "cpu":
            tensor = torch.from_numpy(array)
            if tensor.data_ptr() != array.ctypes.data:
                raise RuntimeError("torch copied the kernel's array instead of viewing it")
            return tensor
        return torch.as_tensor(array, device=self.device)

    def _input(self, x: Any, dtype: torch.dtype, what: str) -> torch.Tensor:
        """``x`` as a contiguous tensor of ``dtype`` on the device, shape-checked from its
        metadata alone (no host read of a device tensor)."""
        t = torch.as_tensor(x, device=self.device, dtype=dtype)
        shape = (self.num_copies, NJ) if what == "command" else (self.num_copies,)
        if tuple(t.shape) != shape:
            raise ValueError(f"{what} must be {shape}; got {tuple(t.shape)}")
        return t.contiguous()

    def step(self, command: Any) -> None:
        """One control step of every copy: one kernel call (plus the elementwise torque and
        rate updates), nothing read back.

        Parameters
        ----------
        command : (B, 6) tensor (or array)
            In the control mode's unit (position: rad); copy b reads its first n_b entries,
            the rest are ignored (any value, NaN included).
        """
        command = self._input(command, self.dtype, "command")
        # a locked joint's torque never enters the kernels' dynamics (its gain is 0 here,
        # and a NaN there is ignored: tested)
        torch.mul(self._gain, command, out=self._bias)
        self.kernel_step()
        torch.mul(self._dw, self._w_to_accel, out=self.acceleration)
        torch.mul(self.w, self._w_to_v, out=self.v)

    def kernel_step(self) -> None:
        """`step`'s kernel call alone, from the bias ``gain * command`` already in ``_bias``
        (B, 6); ``acceleration`` and ``v`` are left to the caller (``dw * w_to_accel``, ``w *
        w_to_v``: ``ddpg_her.program_kernels.settle`` fuses them)."""
        if self.kernel == "numba":
            control_step(*self._args)
        else:
            import envs.physics.triton_kernel as triton_kernel

            triton_kernel.launch(self._model, self.q, self.w, self.height_bound, self._bias,
                                 self.n_joints, self._dw, self.contact, self.limit_stop,
                                 self.tool, self.block)

    def reset_where(self, mask: Any) -> None:
        """Put the copies where ``mask (B,) bool`` is True at rest at their own start pose
        (state, height bounds, tool), elementwise on the device: the mask is never read on
        the host (the start poses were checked at construction)."""
        rows = self._input(mask, torch.bool, "mask")
        col = rows[:, None]
        for state, start in ((self.q, self._start_q), (self.height_bound, self._start_heights),
                             (self.tool, self._start_tool)):
            state.copy_(torch.where(col, start, state))
        for state in (self.w, self.v, self.acceleration):
            state.masked_fill_(col, 0.0)
        self.contact.masked_fill_(rows, False)
        self.limit_stop.masked_fill_(rows, False)
