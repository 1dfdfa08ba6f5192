"""The numba kernels behind the tensor face of the torch backend, zero copy, on either device:
:class:`NumbaTorchDynamics` (on CUDA the fused kernel, on the CPU the CPU kernel or, under
numba's CUDA simulator, the CUDA kernel run as Python, which is how it is tested without a
GPU; docs/design.md, "Dynamics").
"""

from __future__ import annotations

from collections import OrderedDict
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

import envs.physics.numba_cuda as numba_cuda
from envs.physics.model import NJ
from envs.physics.numba_kernel import NumbaDynamics, dtype_name, link_heights
from envs.physics.torch_kernel import DTYPES, copy_out

if TYPE_CHECKING:
    from envs.spec import TaskSpec

STATE = ("q", "w", "v", "acceleration", "height_bound", "contact", "limit_stop", "tool")
"""The kernel's state arrays (:attr:`envs.physics.numba_cuda.NumbaCudaDynamics.state`), each
a tensor attribute of :class:`NumbaTorchDynamics` of the same name."""


class HostKernel:
    """:class:`envs.physics.numba_kernel.NumbaDynamics` behind the face of
    :class:`envs.physics.numba_cuda.NumbaCudaDynamics` that :class:`NumbaTorchDynamics` reads
    (``state``, ``lowest``, ``step``, ``reset_where``, ``lowest_points``, ``reset``), on the CPU:
    the arrays are host memory, a call runs at once, and streams do not exist (``stream`` is
    accepted and ignored).

    Attributes
    ----------
    dynamics : NumbaDynamics
        The CPU kernel's object (one thread).
    state : types.SimpleNamespace of numpy arrays
        :data:`STATE`, the CPU kernel's own arrays (written in place by every call).
    lowest : (B,) numpy array, m, world z
        :meth:`lowest_points`' output.
    """

    def __init__(self, task: TaskSpec, num_copies: int, dtype: str) -> None:
        self.dynamics = NumbaDynamics(task, num_copies, dtype=dtype)
        dyn = self.dynamics
        self.task, self.num_copies, self.arm = dyn.task, dyn.num_copies, dyn.arm
        self.state = SimpleNamespace(**{key: getattr(self.dynamics, key) for key in STATE})
        self.lowest = np.zeros(num_copies, self.dynamics.q.dtype)

    def step(self, command: np.ndarray, stream: Any = None) -> None:
        self.dynamics.step(command)

    def reset_where(self, mask: np.ndarray, q: np.ndarray, stream: Any = None) -> None:
        """The copies where ``mask (B,) bool`` is True at rest at ``q (6,)`` rad (the CPU
        kernel's reset, which checks ``q`` on the host; the copies are read on the host too,
        which costs nothing on the CPU)."""
        rows = np.flatnonzero(mask)
        if rows.size:
            self.dynamics.reset(q, rows)

    def lowest_points(self, stream: Any = None) -> np.ndarray:
        self.lowest[:] = link_heights(self.dynamics.q, self.task.base_height,
                                      self.dynamics.dtype).min(-1)
        return self.lowest

    def reset(self, q: Any, index: Any = None) -> None:
        self.dynamics.reset(q, index)

    def external_stream(self, handle: int) -> int:
        return 0

    def synchronize(self) -> None:
        pass


VIEW_CACHE = 4
"""Numba views of input tensors kept for reuse (the env steps with one action tensor, and
resets at one start pose): making a view costs some tens of microseconds of Python."""


class NumbaTorchDynamics:
    """B copies of the UR5 stepped by a numba kernel (the fused CUDA kernel on a GPU, the CPU
    kernel on the CPU), state as tensors on the device.

    The tensor interface :class:`envs.torchreach.TorchReach` reads from
    :class:`envs.physics.torch_kernel.TorchDynamics` (``q``, ``v``, ``acceleration``, ``tool``,
    ``contact``, ``limit_stop``, ``step``, ``reset``, ``reset_where``, ``tool_positions``,
    ``clearance``, ``device``, ``dtype``), the same physics as the numba kernel on the CPU
    (equal to 1e-9 in float64, tested).

    Zero copy: each state tensor is a view of the kernel's array (its ``data_ptr`` is the
    array's address; checked when built), commands, masks and configurations enter the
    kernels as views of the tensors given. On the CPU the kernel is :class:`HostKernel`'s (no
    simulator): the same results as :class:`envs.batched.BatchedReach`'s dynamics, bit for
    bit, since it is the same kernel.

    Streams: numba launches on its own default stream unless told otherwise, torch works on
    its *current* stream. Every launch here goes to torch's current stream of ``device``
    (``torch.cuda.current_stream(device).cuda_stream``, wrapped by ``numba.cuda.
    external_stream``; 0, torch's default, is the legacy default stream), so a launch follows
    the torch operations that made its inputs, and the torch operations that read the state
    after it follow the launch, with no wait on the host. :meth:`reset` (the host path) waits
    for both sides instead.

    Parameters
    ----------
    task : TaskSpec
        The task (stop contact model only).
    num_copies : int
        B.
    device : str or torch.device
        ``"cuda"`` or ``"cuda:N"`` (the CUDA kernel); ``"cpu"`` (the CPU kernel, or the CUDA
        kernel under numba's CUDA simulator).
    dtype : {"float64", "float32"} or the torch dtype
        The kernel's arithmetic and the state's type.
    threads_per_block : int
        Copies per block of a launch (:class:`envs.physics.numba_cuda.NumbaCudaDynamics`;
        unused by the CPU kernel).

    Attributes
    ----------
    q, w, v, acceleration, height_bound : (B, 6) tensors
        rad, rad per substep, rad/s, rad/s^2 (the last step's mean), m (world z: lower bounds
        of each moving link's height).
    contact, limit_stop : (B,) bool tensors
    tool : (B, 3) tensor, m, world frame
        tool0's position now.
    kernel : NumbaCudaDynamics or HostKernel
        The kernel's own object (CUDA: ``mirror=False``, its host arrays wait for ``pull()``).

    The tensors are overwritten in place by every launch; clone what you keep.

    Raises
    ------
    ValueError
        For a device the kernel cannot run on here: ``"cuda"`` under the simulator or where
        numba or torch sees no GPU, any other device.
    """

    def __init__(self, task: TaskSpec, num_copies: int = 1, device: Any = "cuda",
                 dtype: Any = "float64",
                 threads_per_block: int = numba_cuda.THREADS_PER_BLOCK) -> None:
        self.device = torch.device(device)
        gpu = self._numba_device()
        name = dtype_name(str(dtype).removeprefix("torch.") if isinstance(dtype, torch.dtype)
                          else dtype)
        self._host = gpu is None
        self.kernel: numba_cuda.NumbaCudaDynamics | HostKernel = (
            HostKernel(task, num_copies, name) if self._host else
            numba_cuda.NumbaCudaDynamics(task, num_copies, dtype=name, device=gpu,
                                         mirror=False, threads_per_block=threads_per_block))
        self.task, self.num_copies, self.arm = self.kernel.task, self.kernel.num_copies, \
            self.kernel.arm
        self.dtype = DTYPES[name]
        self._stream_handle: int | None = None
        self._stream: Any = None
        self._views: OrderedDict[tuple, Any] = OrderedDict()
        for key in STATE:
            setattr(self, key, self._tensor(getattr(self.kernel.state, key)))
        self._lowest = self._tensor(self.kernel.lowest)
        self.kernel.synchronize()  # the construction's reset ran on numba's default stream

    def _numba_device(self) -> str | None:
        """The numba-CUDA device of ``self.device`` (normalised to its index; ``"cuda"`` for
        the CPU under the simulator), None for the CPU kernel, or the ValueError that says why
        no kernel runs there."""
        dev = self.device
        if dev.type == "cpu":
            return "cuda" if numba_cuda.simulated() else None
        if dev.type != "cuda":
            raise ValueError(f"dynamics='numba' runs on 'cuda' (or 'cpu' under numba's CUDA "
                             f"simulator); got device {str(dev)!r}")
        if numba_cuda.simulated():
            raise ValueError(f"device {str(dev)!r}: under numba's CUDA simulator "
                             "(NUMBA_ENABLE_CUDASIM=1) the kernel's arrays are host memory; "
                             "use device 'cpu'")
        if not torch.cuda.is_available() or not numba_cuda.available():
            raise ValueError(f"dynamics='numba', device {str(dev)!r}: no CUDA GPU here "
                             f"(torch sees one: {torch.cuda.is_available()}, numba: "
                             f"{numba_cuda.available()})")
        index = dev.index if dev.index is not None else torch.cuda.current_device()
        self.device = torch.device("cuda", index)
        return f"cuda:{index}"

    # ------------------------------------------------------------------ views and streams
    def _tensor(self, array: Any) -> torch.Tensor:
        """The torch tensor over the kernel's array ``array`` (CUDA: its
        ``__cuda_array_interface__``; the simulator and the CPU kernel: the numpy array), never
        a copy (RuntimeError if torch made one)."""
        tensor = torch.as_tensor(array, device=self.device)
        if tensor.data_ptr() != numba_cuda.device_pointer(array):
            raise RuntimeError("torch copied the kernel's state instead of viewing it")
        return tensor

    def _view(self, tensor: torch.Tensor) -> Any:
        """A numba device array over ``tensor`` (contiguous, on ``device``), reused while the
        same memory comes back: a cached view keeps its tensor alive, so an address seen again
        with the same layout is that tensor's memory."""
        if self._host:
            return tensor.numpy()  # a view of a CPU tensor, made in microseconds
        key = (tensor.data_ptr(), tuple(tensor.shape), tuple(tensor.stride()), tensor.dtype)
        view = self._views.get(key)
        if view is None:
            view = self._views[key] = numba_cuda.device_view(tensor)
            if len(self._views) > VIEW_CACHE:
                self._views.popitem(last=False)
        else:
            self._views.move_to_end(key)
        return view

    def _launch_stream(self) -> Any:
        """The numba stream of torch's current stream on ``device`` (cached per handle); 0
        under the simulator, where a launch runs at once."""
        if self.device.type != "cuda":
            return 0
        handle = torch.cuda.current_stream(self.device).cuda_stream
        if handle != self._stream_handle:
            self._stream, self._stream_handle = self.kernel.external_stream(handle), handle
        return self._stream

    def _input(self, x: Any, dtype: torch.dtype, shape: tuple[int, ...], what: str
               ) -> torch.Tensor:
        """``x`` as a contiguous tensor of ``dtype`` on ``device`` (no copy when it is one
        already); ValueError naming ``what`` for another shape (host metadata only)."""
        t = torch.as_tensor(x, device=self.device, dtype=dtype)
        if tuple(t.shape) != shape:
            raise ValueError(f"{what} must be {shape}; got {tuple(t.shape)}")
        return t.contiguous()

    # ------------------------------------------------------------------ the Dynamics face
    def step(self, command: Any) -> None:
        """One control step of every copy, one launch on torch's current stream (CUDA; the
        CPU kernel's call on the CPU), nothing read back: ``command (B, n)`` in the control
        mode's unit (a tensor on ``device`` of ``dtype`` enters as it is; anything else is
        converted by torch first)."""
        command = self._input(command, self.dtype, (self.num_copies, self.task.n_joints),
                              "command")
        self.kernel.step(self._view(command), stream=self._launch_stream())

    def reset(self, q: Any, index: Any = None) -> None:
        """:meth:`envs.physics.Dynamics.reset`: copies ``index`` (None: all) at rest at ``q
        (6,)`` or ``(m, 6)`` rad, checked on the host; waits for torch's queued work first
        and for the launch after (a synchronisation)."""
        if isinstance(q, torch.Tensor):
            q = q.cpu().numpy()
        if isinstance(index, torch.Tensor):
            index = index.cpu().numpy()
        if self.device.type == "cuda":
            torch.cuda.current_stream(self.device).synchronize()
        self.kernel.reset(np.asarray(q, dtype=float), index)
        self.kernel.synchronize()

    def reset_where(self, mask: torch.Tensor, q: torch.Tensor) -> None:
        """Put the copies where ``mask (B,) bool`` is True at rest at ``q (6,)`` rad, on the
        device: one launch, the mask never read on the host (``q`` unchecked: the caller has
        checked it once, as :meth:`TorchDynamics.reset_where`'s). On the CPU,
        :meth:`HostKernel.reset_where`."""
        mask = self._input(mask, torch.bool, (self.num_copies,), "mask")
        q = self._input(q, self.dtype, (NJ,), "q")
        self.kernel.reset_where(self._view(mask), self._view(q), stream=self._launch_stream())

    def tool_positions(self, out: Any = None) -> Any:
        """tool0's world position ``(B, 3)`` m (base at (0, 0, base_height)), a new tensor,
        or written into ``out`` (a tensor, or a numpy array: a device-to-host copy)."""
        return copy_out(self.tool, out)

    def clearance(self) -> torch.Tensor:
        """Lowest point ``(B,)`` (m, world z) of the moving links now, a new tensor on the
        device (the plane check's exact heights; one launch and a clone)."""
        self.kernel.lowest_points(stream=self._launch_stream())
        return self._lowest.clone()

    def synchronize(self) -> None:
        """Wait until the GPU has run everything queued on torch's current stream (launches
        included)."""
        if self.device.type == "cuda":
            torch.cuda.current_stream(self.device).synchronize()
