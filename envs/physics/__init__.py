"""The arm's physics behind one seam: the :class:`Dynamics` protocol and :func:`make_dynamics`.

Every backend (:data:`BACKENDS`) advances B copies of the UR5 under the task's joint PD
controller, one control step per call, with the same physics (docs/design.md, "Dynamics") read
from the same :class:`envs.physics.model.ArmModel`. The training program's env
(:class:`envs.stackreach.StackReach`) steps its own tensors on the device.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from envs.physics.model import supports_kernels
from envs.physics.protocol import Dynamics

if TYPE_CHECKING:
    from envs.spec import TaskSpec

__all__ = ["BACKENDS", "Dynamics", "make_dynamics"]

BACKENDS = ("auto", "pinocchio", "numba")
"""Dynamics backends, named for their tool (BatchedReach's ``dynamics`` option): ``pinocchio``
the reference, ``numba`` the compiled kernel on the CPU, ``auto`` numba for B > 1 where it is
installed and implements the task, else pinocchio."""

RENAMED_BACKENDS = {"fast": "numba"}
"""Former backend names, for the message that gives the new spelling."""

REMOVED_BACKENDS = ("torch", "torch-cuda")
"""Backends that were removed, for the message that says what replaced them: ``torch`` (the
vectorised torch dynamics behind the numpy env, its state copied to the host every step; last
at commit 401ca32) gave way to the training program's device env,
:class:`envs.stackreach.StackReach`."""


def make_dynamics(task: TaskSpec, num_copies: int, backend: str = "auto", device: str = "cpu",
                  threads: int = 1) -> Dynamics:
    """The arm dynamics of ``num_copies`` copies of ``task``: the one place a backend is chosen.

    Every backend checks ``task`` against the robot (:func:`envs.validate`): the one check of
    an env. The backends are imported here, on first use: numba only for ``numba`` and
    ``auto``.

    Parameters
    ----------
    backend : one of :data:`BACKENDS`
        The backend, named for its tool.
    device : str
        ``"cpu"``, the only one: the arm on a GPU is the training program's
        (:class:`envs.physics.stack.StackDynamics`, a Triton kernel).
    threads : int
        CPU threads of the numba backend on the CPU (the Pinocchio loop uses one).

    Raises
    ------
    ValueError
        When ``backend`` is not one of :data:`BACKENDS` (a former name gets its new one, a
        removed one what replaced it), another device than the CPU is given, or the backend
        cannot run the task here (numba missing, a contact model it does not implement).
    """
    if backend in RENAMED_BACKENDS:
        raise ValueError(f"dynamics={backend!r} is now dynamics={RENAMED_BACKENDS[backend]!r}")
    if backend in REMOVED_BACKENDS:
        raise ValueError(f"dynamics={backend!r} was removed (its device path is the training "
                         "program's env, envs.stackreach.StackReach); one of "
                         f"{list(BACKENDS)} steps BatchedReach")
    if backend not in BACKENDS:
        raise ValueError(f"dynamics must be one of {list(BACKENDS)}; got {backend!r}")
    if str(device) != "cpu":
        raise ValueError(f"dynamics={backend!r} runs on the CPU only; got device={device!r}"
                         + (" (numba's CUDA kernel, envs.physics.numba_cuda, was removed: the "
                            "training program, --env-backend program, steps the arm on the GPU)"
                            if str(device).startswith("cuda") else ""))
    from envs.physics import numba_kernel

    fast_ok = numba_kernel.available() and supports_kernels(task)
    if backend == "numba" and not fast_ok:
        raise ValueError("dynamics='numba' needs numba and the stop contact model; use "
                         "'pinocchio' (or 'auto')")
    if backend == "numba" or (backend == "auto" and fast_ok and num_copies > 1):
        return numba_kernel.NumbaDynamics(task, num_copies, threads=threads)
    from envs.physics.pinocchio_loop import PinocchioDynamics

    return PinocchioDynamics(task, num_copies)

