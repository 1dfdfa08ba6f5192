"""The numba-CUDA backend: a whole control step of B arm copies as one GPU kernel launch.

One thread per copy runs the numba kernel's step body, :func:`envs.physics.numba_kernel.
step_copy`, compiled for the device (:func:`envs.physics.numba_kernel.compile_step_functions`),
with its scratch in the thread's local memory: :class:`NumbaCudaDynamics`. Tested against the
CPU kernel under numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) and, where a GPU is there,
on it.
"""

from __future__ import annotations

import functools
import re
import types
from typing import TYPE_CHECKING, Any

import numpy as np

from envs.checks import validate
from envs.physics.model import (
    NJ,
    arm_model,
    check_num_copies,
    require_kernels,
    rest_heights,
    tool_offset,
    ur5_plane,
)
from envs.physics.numba_kernel import (
    DTYPES,
    compile_step_functions,
    copy_link_heights,
    dtype_name,
    placements,
    step_copy,
    tool_position,
)

if TYPE_CHECKING:
    from envs.spec import TaskSpec

try:
    from numba import cuda
except ImportError:  # numba missing: make_dynamics says so before this module is used
    cuda = None

THREADS_PER_BLOCK = 64
"""Threads (copies) per block of the step kernel. A copy is a long serial computation (20
substeps of ABA) with about 5 KB of float64 scratch, so small blocks spread few copies over
many multiprocessors; untuned until a GPU measures it (``threads_per_block``)."""

DT = np.float64
"""The kernels' float type; :func:`kernels` rebinds it (and the body's functions imported
above) per dtype when it compiles them for the device."""


def available() -> bool:
    """Whether numba sees a CUDA device (or runs under its simulator, ``NUMBA_ENABLE_CUDASIM``)."""
    return cuda is not None and cuda.is_available()


def simulated() -> bool:
    """Whether numba's CUDA is its simulator (``NUMBA_ENABLE_CUDASIM=1``): device arrays are
    numpy arrays on the host and every launch runs at once, as Python."""
    if cuda is None:
        return False
    from numba import config

    return bool(config.ENABLE_CUDASIM)


def device_index(device: Any) -> int:
    """The GPU number of ``device``: ``"cuda"`` (0) or ``"cuda:N"``; ValueError otherwise."""
    match = re.fullmatch(r"cuda(?::(\d+))?", str(device))
    if match is None:
        raise ValueError(f"device must be 'cuda' or 'cuda:N' for the numba-CUDA kernel; got "
                         f"{device!r}")
    return int(match.group(1) or 0)


def _device_array(x: Any) -> Any:
    """``x`` as a numba device array where it lives on a GPU (a numba device array, anything
    with ``__cuda_array_interface__`` such as a CUDA torch tensor, the simulator's arrays);
    None for a host array."""
    if hasattr(x, "__cuda_array_interface__"):
        return cuda.as_cuda_array(x)
    simulated = getattr(cuda, "devicearray", None)  # the simulator's arrays have no interface
    if simulated is not None and simulated.is_cuda_ndarray(x):
        return x
    return None


def device_view(x: Any) -> Any:
    """``x`` as a numba device array over the same memory: no copy, and no synchronisation on
    the stream that made it (the caller orders the launches, :meth:`NumbaCudaDynamics.
    external_stream`). ``x`` is a numba device array, anything with
    ``__cuda_array_interface__`` (a CUDA torch tensor), or under the simulator a host array
    (a numpy array, a CPU torch tensor), wrapped as the simulator's device array."""
    if cuda.devicearray.is_cuda_ndarray(x):
        return x
    if hasattr(x, "__cuda_array_interface__"):
        return cuda.as_cuda_array(x, sync=False)
    if simulated():
        return cuda.devicearray.FakeCUDAArray(np.asarray(x))
    raise ValueError(f"expected an array on the GPU (__cuda_array_interface__); got "
                     f"{type(x).__name__}")


def device_pointer(x: Any) -> int:
    """The address of the first element of the numba device array ``x`` (under the
    simulator: of the numpy array behind it), to check that another view shares it."""
    if hasattr(x, "__cuda_array_interface__"):
        return int(x.__cuda_array_interface__["data"][0])
    return int(np.asarray(x).ctypes.data)


# ---------------------------------------------------------------------------- kernels
# Plain Python, compiled by :func:`kernels` with ``DT`` and the step body bound to the device
# versions of one dtype.
def _fused_step(command, gain, base_bias, Q, W, V, A, clearance, contact, limit_stop, tool, kp,
                kd, effort, w_max, gravity_comp, substeps, q_mid, q_half, vh, bounds, lift,
                wrist, lipschitz, base_height, margin, rot0, p, axis, inertia, armature, grav,
                tool_pos, free, w_to_v, w_to_accel):  # pragma: no cover - compiled
    """One control step of copy ``b = cuda.grid(1)`` (a thread past B does nothing):
    :func:`envs.physics.numba_kernel.control_step`'s loop body for row b, plus the command's
    torque and the env's ``v`` and ``acceleration``, in place.

    ``command (B, n)`` in the control mode's unit (rad, rad/s or N m); the constant torque part
    is ``gain (n,) * command`` for joints 1..n and ``base_bias (6,)`` (the held joints' PD)
    for the others, in the time-scaled units of :mod:`envs.physics.model`. The state, read and
    written: ``Q (B, 6)`` rad, ``W (B, 6)`` rad per substep, ``V (B, 6)`` rad/s, ``A (B, 6)``
    rad/s^2 (the step's mean), ``clearance (B, 6)`` m (the plane check's height bounds, world
    z), ``contact, limit_stop (B,)`` bool, ``tool (B, 3)`` m (world frame). The rest is
    :func:`model_arguments`' (``free (B,)`` int: copy b's joints ``free[b] ..`` are locked;
    ``w_to_v``, ``w_to_accel``: w to rad/s, a step's change of w to rad/s^2)."""
    b = cuda.grid(1)
    if b >= Q.shape[0]:
        return
    R = cuda.local.array((6, 3, 3), DT)
    vel, acc = cuda.local.array((7, 6), DT), cuda.local.array((7, 6), DT)
    cb, pA, U = (cuda.local.array((6, 6), DT), cuda.local.array((6, 6), DT),
                 cuda.local.array((6, 6), DT))
    IA = cuda.local.array((6, 6, 6), DT)
    X, Y, force = (cuda.local.array((6, 6), DT), cuda.local.array((6, 6), DT),
                   cuda.local.array((6, 6), DT))
    D, u, tau, g, a = (cuda.local.array(6, DT), cuda.local.array(6, DT),
                       cuda.local.array(6, DT), cuda.local.array(6, DT),
                       cuda.local.array(6, DT))
    q, w, q1, w1, q_ref = (cuda.local.array(6, DT), cuda.local.array(6, DT),
                           cuda.local.array(6, DT), cuda.local.array(6, DT),
                           cuda.local.array(6, DT))
    known, heights, bias = (cuda.local.array(6, DT), cuda.local.array(6, DT),
                            cuda.local.array(6, DT))
    feat = cuda.local.array(13, DT)
    n = gain.shape[0]
    for k in range(6):
        q[k] = Q[b, k]
        w[k] = W[b, k]
        known[k] = clearance[b, k]
        if k < n:
            bias[k] = gain[k] * command[b, k]
        else:
            bias[k] = base_bias[k]
    hit_plane, hit_limit = step_copy(
        q, w, known, bias, kp, kd, effort, w_max, gravity_comp, substeps, q_mid, q_half, vh,
        bounds, lift, wrist, lipschitz, base_height, margin, rot0, p, axis, inertia, armature,
        grav, tool_pos, free[b], R, vel, acc, cb, pA, U, IA, X, Y, D, u, tau, g, a, force, q1,
        w1, q_ref, heights, feat, tool[b])
    contact[b] = hit_plane
    limit_stop[b] = hit_limit
    for k in range(6):
        A[b, k] = (w[k] - W[b, k]) * w_to_accel
        V[b, k] = w[k] * w_to_v
        Q[b, k] = q[k]
        W[b, k] = w[k]
        clearance[b, k] = known[k]


def _at_rest(b, q_new, heights, Q, W, V, A, clearance, contact, limit_stop, tool, rot0, p,
             axis, tool_pos, base_height):  # pragma: no cover - compiled
    """Copy ``b`` at rest at ``q_new (6,)`` rad with the exact link heights ``heights (6,)`` m
    (world z), and its tool position: the device function of both resets."""
    R = cuda.local.array((6, 3, 3), DT)
    for k in range(6):
        Q[b, k] = q_new[k]
        W[b, k] = 0
        V[b, k] = 0
        A[b, k] = 0
        clearance[b, k] = heights[k]
    contact[b] = False
    limit_stop[b] = False
    placements(Q[b], rot0, axis, R)
    tool_position(R, p, tool_pos, base_height, tool[b])


def _rest(mask, q_new, heights, Q, W, V, A, clearance, contact, limit_stop, tool, rot0, p, axis,
          tool_pos, base_height):  # pragma: no cover - compiled
    """Copy ``b`` at rest at ``q_new[b]`` (its exact link heights ``heights[b]``) where
    ``mask[b]``, with its tool position; the other copies untouched."""
    b = cuda.grid(1)
    if b < Q.shape[0] and mask[b]:
        _at_rest(b, q_new[b], heights[b], Q, W, V, A, clearance, contact, limit_stop, tool,
                 rot0, p, axis, tool_pos, base_height)


def _rest_where(mask, q_new, Q, W, V, A, clearance, contact, limit_stop, tool, rot0, p, axis,
                tool_pos, base_height, vh, bounds, lift, wrist):  # pragma: no cover - compiled
    """Copy ``b`` at rest at the one configuration ``q_new (6,)`` rad where ``mask[b]``, with
    its exact link heights (m, world z) and tool position computed here; the other copies
    untouched. The mask is read on the device only (the env's masked autoreset)."""
    b = cuda.grid(1)
    if b >= Q.shape[0] or not mask[b]:
        return
    feat, heights = cuda.local.array(13, DT), cuda.local.array(6, DT)
    copy_link_heights(q_new, vh, bounds, lift, wrist, base_height, feat, heights)
    _at_rest(b, q_new, heights, Q, W, V, A, clearance, contact, limit_stop, tool, rot0, p, axis,
             tool_pos, base_height)


def _lowest_point(Q, vh, bounds, lift, wrist, base_height, out):  # pragma: no cover - compiled
    """``out[b]``: the lowest point (m, world z) of copy b's moving links at ``Q[b]`` rad, from
    their exact heights (the plane check's, :func:`envs.physics.numba_kernel.copy_link_heights`)."""
    b = cuda.grid(1)
    if b >= Q.shape[0]:
        return
    feat, heights = cuda.local.array(13, DT), cuda.local.array(6, DT)
    copy_link_heights(Q[b], vh, bounds, lift, wrist, base_height, feat, heights)
    low = heights[0]
    for k in range(1, 6):
        if heights[k] < low:  # not min(): numba's CUDA target fails on it (issue 10753)
            low = heights[k]
    out[b] = low


@functools.cache
def kernels(dtype: str = "float64") -> types.SimpleNamespace:
    """The compiled kernels of ``dtype`` (float64 or float32), cached: ``step``
    (:func:`_fused_step`), ``rest`` (:func:`_rest`), ``rest_where`` (:func:`_rest_where`) and
    ``lowest_point`` (:func:`_lowest_point`), each a ``numba.cuda`` kernel whose ``py_func``
    is the Python function it compiles (for ``numba.cuda.compile_ptx``). Compilation for the
    device happens at the first launch."""
    if cuda is None:
        raise RuntimeError("the numba-CUDA kernels need numba (pip install numba)")
    name = dtype_name(dtype)
    space = {**globals(), **compile_step_functions(cuda.jit(device=True), name),
             "DT": DTYPES[name]}

    def rebound(func: Any) -> Any:  # ``func`` reading its globals from ``space``
        return types.FunctionType(func.__code__, space, func.__name__)

    space["_at_rest"] = cuda.jit(device=True)(rebound(_at_rest))
    return types.SimpleNamespace(step=cuda.jit(rebound(_fused_step)),
                                 rest=cuda.jit(rebound(_rest)),
                                 rest_where=cuda.jit(rebound(_rest_where)),
                                 lowest_point=cuda.jit(rebound(_lowest_point)))


def model_arguments(task: TaskSpec, dtype: str = "float64", num_copies: int = 1
                    ) -> dict[str, Any]:
    """The arguments of :func:`_fused_step` after ``tool``, by its parameter names, in its
    order (the controller, limits, plane tables, chain, ``free``, ``w_to_v``, ``w_to_accel``):
    host arrays and scalars of ``dtype``, what :class:`NumbaCudaDynamics` copies to the GPU
    once. ``free`` is ``(num_copies,)`` int32, the task's moving joints for every copy."""
    name = dtype_name(dtype)
    cast = DTYPES[name]
    arm, plane = arm_model(task), ur5_plane(name)
    c = arm.chain.astype(cast)
    return dict(kp=arm.kp_eff.astype(cast), kd=arm.kd_eff.astype(cast),
                effort=arm.effort.astype(cast), w_max=arm.w_max.astype(cast),
                gravity_comp=bool(task.gravity_compensation), substeps=int(task.substeps),
                q_mid=arm.q_mid.astype(cast), q_half=arm.q_half.astype(cast),
                vh=plane.vertex_heights, bounds=plane.bounds, lift=cast(plane.lift_offset),
                wrist=cast(plane.wrist_offset), lipschitz=plane.lipschitz,
                base_height=cast(task.base_height), margin=cast(task.plane_margin),
                rot0=c.rotation, p=c.translation, axis=c.axis, inertia=c.inertia,
                armature=c.armature, grav=c.gravity, tool_pos=tool_offset().astype(cast),
                free=np.full(num_copies, arm.free, np.int32), w_to_v=cast(arm.w_to_v),
                w_to_accel=cast(arm.w_to_accel))


def step_signature(task: TaskSpec, dtype: str = "float64") -> tuple[Any, ...]:
    """The numba types of :func:`_fused_step`'s arguments for ``task`` (for
    ``numba.cuda.compile_ptx``, which needs no GPU)."""
    import numba

    name = dtype_name(dtype)
    cast = DTYPES[name]
    n = task.n_joints
    state = (np.zeros((1, n), cast), np.zeros(n, cast), np.zeros(NJ, cast),
             *(np.zeros((1, NJ), cast) for _ in range(5)), np.zeros(1, bool), np.zeros(1, bool),
             np.zeros((1, 3), cast))
    return tuple(numba.typeof(x) for x in (*state, *model_arguments(task, name).values()))


# ---------------------------------------------------------------------------- the class
class NumbaCudaDynamics:
    """B copies of the UR5 under the task's controller on a GPU, one kernel launch per control
    step (:func:`_fused_step`, one thread per copy): an :class:`envs.physics.Dynamics`, the
    same physics as :class:`envs.physics.numba_kernel.NumbaDynamics` (to 1e-9 in float64,
    tested).

    Parameters
    ----------
    task : TaskSpec
        The task (stop contact model only).
    num_copies : int
        B.
    dtype : {"float64", "float32"}
        The kernel's arithmetic and the state's type; float32 computes in float32 throughout
        (no float64 instruction of its own, tested on the PTX: only libdevice's ``sinf``
        reduction of angles beyond 1e5 rad has some).
    device : str
        ``"cuda"`` or ``"cuda:N"``.
    mirror : bool
        Copy the state the env reads to the host after every step and reset (one
        synchronisation each). False: the host arrays are refreshed only by :meth:`pull`, and a
        step is a launch (plus the command's upload when it is a numpy array).
    threads_per_block : int
        Copies per block of the launch, 1..1024.

    Attributes
    ----------
    q, v, acceleration, contact, limit_stop, tool : numpy arrays
        The host mirrors of the Dynamics protocol's state (``tool (B, 3)`` m, world frame).
    state : types.SimpleNamespace of numba device arrays
        ``q, w, v, acceleration, height_bound (B, 6)``, ``contact, limit_stop (B,)``, ``tool
        (B, 3)``, on the GPU: the state itself (``w`` rad per substep, ``height_bound`` m).
    lowest : (B,) numba device array, m, world z
        :meth:`lowest_points`' output.
    """

    def __init__(self, task: TaskSpec, num_copies: int = 1, dtype: str = "float64",
                 device: str = "cuda", mirror: bool = True,
                 threads_per_block: int = THREADS_PER_BLOCK) -> None:
        if not available():
            raise RuntimeError("NumbaCudaDynamics needs a CUDA GPU that numba sees "
                               "(numba.cuda.is_available() is False here), or numba's simulator "
                               "(NUMBA_ENABLE_CUDASIM=1)")
        B = self.num_copies = check_num_copies(num_copies)
        if isinstance(threads_per_block, bool) \
                or not isinstance(threads_per_block, int | np.integer) \
                or not 1 <= threads_per_block <= 1024:
            raise ValueError(f"threads_per_block must be an integer in [1, 1024]; got "
                             f"{threads_per_block!r}")
        require_kernels(task, "NumbaCudaDynamics")
        name = dtype_name(dtype)
        cast = self._cast = DTYPES[name]
        self.task, self.dtype, self.mirror = validate(task), name, bool(mirror)
        self._gpu = cuda.gpus[device_index(device)]
        self._kernels = kernels(name)
        self.arm = arm = arm_model(task)
        self._block = int(threads_per_block)
        self._grid = (B + self._block - 1) // self._block
        self.q, self.v, self.acceleration = (np.zeros((B, NJ), cast) for _ in range(3))
        self.contact, self.limit_stop = np.zeros(B, bool), np.zeros(B, bool)
        self.tool = np.zeros((B, 3), cast)
        with self._gpu:
            self._model = {k: cuda.to_device(x) if isinstance(x, np.ndarray) else x
                           for k, x in model_arguments(task, name, B).items()}
            self._gain = cuda.to_device(arm.command_gain.astype(cast))
            self._base_bias = cuda.to_device(arm.initial_bias(1, cast)[0])
            self._command = cuda.device_array((B, task.n_joints), cast)
            self.state = types.SimpleNamespace(
                **{k: cuda.to_device(np.zeros((B, NJ), cast))
                   for k in ("q", "w", "v", "acceleration", "height_bound")},
                contact=cuda.to_device(np.zeros(B, bool)),
                limit_stop=cuda.to_device(np.zeros(B, bool)),
                tool=cuda.to_device(np.zeros((B, 3), cast)))
            self.lowest = cuda.to_device(np.zeros(B, cast))
        self.reset(arm.start_q)
        if not self.mirror:
            self.pull()

    def _launch(self, kernel: Any, stream: Any = None) -> Any:
        """``kernel`` configured for one thread per copy, on ``stream`` (None: numba's
        default)."""
        return kernel[self._grid, self._block, 0 if stream is None else stream]

    def _device_command(self, command: Any, stream: Any) -> Any:
        """``command`` as a ``(B, n)`` device array of the kernel's type: a CUDA array (a
        numba device array, a torch tensor on the GPU) as is, a host array copied up (on
        ``stream``, None: numba's default)."""
        shape = (self.num_copies, self.task.n_joints)
        if stream is None:
            arr = _device_array(command)  # a foreign array synchronises on its stream
        elif cuda.devicearray.is_cuda_ndarray(command) \
                or hasattr(command, "__cuda_array_interface__"):
            arr = device_view(command)  # the caller ordered its producer on ``stream``
        else:
            arr = None
        if arr is not None:
            if arr.shape != shape or arr.dtype != self._cast:
                raise ValueError(f"command must be a ({shape[0]}, {shape[1]}) {self.dtype} "
                                 f"array; got a device array {arr.shape} {arr.dtype}")
            return arr
        arr = np.ascontiguousarray(command, dtype=self._cast)
        if arr.shape != shape:
            raise ValueError(f"command must be ({shape[0]}, {shape[1]}); got {arr.shape}")
        self._command.copy_to_device(arr, stream=0 if stream is None else stream)
        return self._command

    def step(self, command: Any, stream: Any = None) -> None:
        """:meth:`envs.physics.Dynamics.step`: ``command (B, n)``, a numpy array or a device
        array of the kernel's type on this GPU (no upload).

        ``stream``: None launches on numba's default stream, after synchronising on the
        stream a foreign device array names (numba's ``CUDA_ARRAY_INTERFACE_SYNC``, a host
        wait); a numba stream (:meth:`external_stream`) launches there without any wait: the
        caller has queued the command's producer on that stream."""
        with self._gpu:
            arr = self._device_command(command, stream)
            s = self.state
            self._launch(self._kernels.step, stream)(
                arr, self._gain, self._base_bias, s.q, s.w, s.v, s.acceleration,
                s.height_bound, s.contact, s.limit_stop, s.tool, *self._model.values())
        if self.mirror:
            self.pull()

    def reset_where(self, mask: Any, q: Any, stream: Any = None) -> None:
        """Put the copies where ``mask`` is True at rest at ``q``, on the GPU: one launch
        (:func:`_rest_where`), nothing read back (the env's masked autoreset).

        Parameters
        ----------
        mask : (B,) bool device array
            Which copies (:func:`device_view` of a CUDA tensor, say).
        q : (6,) device array of the kernel's type, rad
            One configuration for all of them, unchecked: the caller has checked it clear of
            the plane and within the limits once (:meth:`reset` does on the host).
        stream : numba stream or None
            Where to launch (:meth:`step`'s meaning).
        """
        B = self.num_copies
        if mask.shape != (B,) or mask.dtype != np.bool_:
            raise ValueError(f"mask must be a ({B},) bool device array; got {mask.shape} "
                             f"{mask.dtype}")
        if q.shape != (NJ,) or q.dtype != self._cast:
            raise ValueError(f"q must be a ({NJ},) {self.dtype} device array (rad); got "
                             f"{q.shape} {q.dtype}")
        m, s = self._model, self.state
        with self._gpu:
            self._launch(self._kernels.rest_where, stream)(
                mask, q, s.q, s.w, s.v, s.acceleration, s.height_bound, s.contact,
                s.limit_stop, s.tool, m["rot0"], m["p"], m["axis"], m["tool_pos"],
                m["base_height"], m["vh"], m["bounds"], m["lift"], m["wrist"])
        if self.mirror:
            self.pull()

    def lowest_points(self, stream: Any = None) -> Any:
        """Each copy's lowest moving-link point now, ``(B,)`` m (world z, the plane check's
        exact heights), computed on the GPU (one launch on ``stream``, :meth:`step`'s meaning)
        into :attr:`lowest`, which is returned (overwritten by the next call)."""
        m, out = self._model, self.lowest
        with self._gpu:
            self._launch(self._kernels.lowest_point, stream)(
                self.state.q, m["vh"], m["bounds"], m["lift"], m["wrist"], m["base_height"],
                out)
        return out

    def external_stream(self, handle: int) -> Any:
        """The numba stream of the raw CUDA stream ``handle`` on this GPU (torch's
        ``torch.cuda.current_stream().cuda_stream``), for :meth:`step`'s ``stream``: 0 is the
        legacy default stream (torch's default stream), anything else wraps the handle
        (``numba.cuda.external_stream``). The simulator has no streams: 0 there."""
        if simulated():
            return 0
        with self._gpu:
            return cuda.legacy_default_stream() if handle == 0 else \
                cuda.external_stream(handle)

    def reset(self, q: Any, index: Any = None) -> None:
        """:meth:`envs.physics.Dynamics.reset`: copies ``index`` (None: all) at rest at ``q
        (6,)`` or ``(m, 6)`` rad, checked on the host (:func:`envs.physics.model.
        rest_heights`), then set on the GPU (one launch)."""
        B = self.num_copies
        heights = rest_heights(self.task, q)
        sel = slice(None) if index is None else index
        mask = np.zeros(B, bool)
        mask[sel] = True
        rows, height_rows = np.zeros((B, NJ), self._cast), np.zeros((B, NJ), self._cast)
        rows[sel] = np.asarray(q, dtype=float)
        height_rows[sel] = heights
        m = self._model
        with self._gpu:
            s = self.state
            self._launch(self._kernels.rest)(
                cuda.to_device(mask), cuda.to_device(rows), cuda.to_device(height_rows), s.q,
                s.w, s.v, s.acceleration, s.height_bound, s.contact, s.limit_stop, s.tool,
                m["rot0"], m["p"], m["axis"], m["tool_pos"], m["base_height"])
        if self.mirror:
            self.pull()

    def pull(self) -> None:
        """Copy the protocol's state (``q, v, acceleration, contact, limit_stop, tool``) from
        the GPU into the host arrays (a synchronisation)."""
        s = self.state
        with self._gpu:
            for host, dev in ((self.q, s.q), (self.v, s.v), (self.acceleration, s.acceleration),
                              (self.contact, s.contact), (self.limit_stop, s.limit_stop),
                              (self.tool, s.tool)):
                dev.copy_to_host(host)

    def synchronize(self) -> None:
        """Wait until the GPU has run every launch and copy queued so far (for a clock)."""
        with self._gpu:
            cuda.synchronize()

    @property
    def w(self) -> np.ndarray:
        """The integrator's velocities ``(B, 6)`` rad per substep, copied from the GPU."""
        with self._gpu:
            return self.state.w.copy_to_host()

    @property
    def height_bound(self) -> np.ndarray:
        """The plane check's lower bounds ``(B, 6)`` m (world z) of each moving link's
        height, copied from the GPU."""
        with self._gpu:
            return self.state.height_bound.copy_to_host()

    def tool_positions(self, out: np.ndarray) -> np.ndarray:
        """Write tool0's world position ``(B, 3)`` m (base at (0, 0, base_height)) into ``out``
        (the host mirror's)."""
        out[:] = self.tool
        return out
