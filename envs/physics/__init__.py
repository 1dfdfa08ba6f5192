"""The arm's physics behind one seam: the :class:`Dynamics` protocol and :func:`make_dynamics`.

Every backend advances B copies of the UR5 under the task's joint PD controller, one control
step per call, with the same physics (docs/design.md, "Dynamics"; :mod:`envs.physics.
pinocchio_loop` has the equations) and reads the same :class:`envs.physics.model.ArmModel`:

- ``pinocchio`` (:class:`envs.physics.pinocchio_loop.PinocchioDynamics`, the reference):
  Pinocchio's ABA in a Python substep loop; the only backend of the compliant contact.
- ``numba`` (:class:`envs.physics.numba_kernel.NumbaDynamics`): one compiled call per step;
  on ``device="cuda"``, :class:`envs.physics.numba_cuda.NumbaCudaDynamics`: one GPU kernel
  launch per step, one thread per copy running the same step body.
- ``torch`` (:class:`envs.physics.torch_kernel.TorchDynamics` on any device, behind
  :class:`envs.physics.torch_kernel.HostMirror`'s numpy arrays for the numpy envs).

The backend is named for its tool; the device is its own argument.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

from envs.physics.model import supports_kernels

if TYPE_CHECKING:
    import numpy as np

    from envs.spec import TaskSpec

BACKENDS = ("auto", "pinocchio", "numba", "torch")
"""Dynamics backends, named for their tool (BatchedReach's ``dynamics`` option): ``pinocchio``
the reference, ``numba`` the compiled kernel (on the CPU, or one CUDA kernel launch a step on
``device="cuda"``), ``torch`` the vectorised path on ``device`` (its
state copied to the host every step; never chosen by ``auto``: on the CPU it is far slower than
``numba``), ``auto`` numba for B > 1 where it is installed and implements the task, else
pinocchio."""

RENAMED_BACKENDS = {"fast": "numba", "torch-cuda": "torch"}
"""Former backend names, for the message that gives the new spelling."""


class Dynamics(Protocol):
    """What every dynamics backend of B arm copies offers the env (:class:`envs.core.TaskCopies`).

    A backend is built as ``Backend(task, num_copies, ...)`` with the copies at rest at
    ``task.start_q``.

    Attributes
    ----------
    task : TaskSpec
        Start pose, controlled joints, control mode, gains, rates, base height, plane margin.
    num_copies : int
        B, the number of independent arms.
    q, v : (B, 6) float, rad and rad/s
        Joint angles and velocities now.
    acceleration : (B, 6) float, rad/s^2
        Mean realised acceleration over the last step, ``(v(t + dt) - v(t)) / dt`` (zero after
        a reset).
    contact : (B,) bool
        Whether the plane acted in the last step (stopped the arm; under the compliant contact
        also: pushed it).
    limit_stop : (B,) bool
        Whether the last step stopped at a URDF joint position limit.

    The arrays are owned by the backend and overwritten by every step; copy what you keep.
    """

    task: TaskSpec
    num_copies: int
    q: np.ndarray
    v: np.ndarray
    acceleration: np.ndarray
    contact: np.ndarray
    limit_stop: np.ndarray

    def reset(self, q: Any, index: Any = None) -> None:
        """Put copies ``index`` (None: all; an int, slice, ``(m,)`` int or ``(B,)`` bool) at
        rest at ``q (6,)`` or ``(m, 6)`` rad; ValueError for a configuration below the plane
        margin or with a locked joint off its start angle
        (:func:`envs.physics.model.rest_heights`)."""

    def step(self, command: np.ndarray) -> None:
        """One control step of ``task.substeps`` substeps; ``command (B, n)`` per copy, the
        command of joints 1..n in the control mode's unit (rad, rad/s or N m), within the
        action box (:func:`envs.task.action_bounds`)."""

    def tool_positions(self, out: np.ndarray) -> np.ndarray:
        """Write tool0's world position ``(B, 3)`` m into ``out`` and return it."""


def make_dynamics(task: TaskSpec, num_copies: int, backend: str = "auto", device: str = "cpu",
                  threads: int = 1) -> Dynamics:
    """The arm dynamics of ``num_copies`` copies of ``task``: the one place a backend is chosen.

    Every backend checks ``task`` against the robot (:func:`envs.validate`): the one check of
    an env. The backends are imported here, on first use: torch only for ``torch``, numba only
    for ``numba``.

    Parameters
    ----------
    backend : one of :data:`BACKENDS`
        The backend, named for its tool.
    device : str
        Where the ``torch`` backend runs (``"cpu"``, ``"cuda"``, ``"cuda:1"``); ``numba`` runs
        on ``"cpu"`` or a GPU (``"cuda"``, ``"cuda:N"``, numba's CUDA kernel); the others
        accept ``"cpu"`` only.
    threads : int
        CPU threads of the numba backend on the CPU (the Pinocchio loop uses one).

    Raises
    ------
    ValueError
        When ``backend`` is not one of :data:`BACKENDS` (a former name gets its new one), a
        CPU-only backend is given another device, or the backend cannot run the task here
        (numba missing, a contact model it does not implement, no GPU).
    """
    if backend in RENAMED_BACKENDS:
        raise ValueError(f"dynamics={backend!r} is now dynamics="
                         f"{RENAMED_BACKENDS[backend]!r}" + (", device='cuda'"
                                                            if backend == "torch-cuda" else ""))
    if backend not in BACKENDS:
        raise ValueError(f"dynamics must be one of {list(BACKENDS)}; got {backend!r}")
    if backend == "torch":
        from envs.physics.torch_kernel import HostMirror, TorchDynamics

        return HostMirror(TorchDynamics(task, num_copies, device=device))
    from envs.physics import numba_kernel

    fast_ok = numba_kernel.available() and supports_kernels(task)
    if backend == "numba" and str(device).startswith("cuda"):
        return _numba_cuda(task, num_copies, device, fast_ok)
    if str(device) != "cpu":
        raise ValueError(f"dynamics={backend!r} runs on the CPU only; got device={device!r} "
                         "(dynamics='torch' runs on any device, 'numba' on 'cuda' too)")
    if backend == "numba" and not fast_ok:
        raise ValueError("dynamics='numba' needs numba and the stop contact model; use "
                         "'pinocchio' (or 'auto')")
    if backend == "numba" or (backend == "auto" and fast_ok and num_copies > 1):
        return numba_kernel.NumbaDynamics(task, num_copies, threads=threads)
    from envs.physics.pinocchio_loop import PinocchioDynamics

    return PinocchioDynamics(task, num_copies)


def _numba_cuda(task: TaskSpec, num_copies: int, device: str, fast_ok: bool) -> Dynamics:
    """:class:`envs.physics.numba_cuda.NumbaCudaDynamics` on ``device``, or the ValueError
    that says why it cannot run here."""
    if not fast_ok:
        raise ValueError("dynamics='numba' needs numba and the stop contact model; use "
                         "'pinocchio' (or 'auto')")
    from envs.physics import numba_cuda

    numba_cuda.device_index(device)  # a ValueError for a malformed device
    if not numba_cuda.available():
        raise ValueError(f"dynamics='numba', device={device!r}: numba sees no CUDA GPU here "
                         "(numba.cuda.is_available() is False; NUMBA_ENABLE_CUDASIM=1 runs its "
                         "simulator); device='cpu' runs the numba kernel on the CPU")
    return numba_cuda.NumbaCudaDynamics(task, num_copies, device=device)
