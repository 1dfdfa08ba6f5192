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

BACKENDS = ("auto", "pinocchio", "numba", "torch")
"""Dynamics backends, named for their tool (BatchedReach's ``dynamics`` option): ``pinocchio``
the reference, ``numba`` the compiled kernel (on the CPU, or one CUDA kernel launch a step on
``device="cuda"``), ``torch`` the vectorised path on ``device`` (its
state copied to the host every step; never chosen by ``auto``: on the CPU it is far slower than
``numba``), ``auto`` numba for B > 1 where it is installed and implements the task, else
pinocchio."""

RENAMED_BACKENDS = {"fast": "numba", "torch-cuda": "torch"}
"""Former backend names, for the message that gives the new spelling."""


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
