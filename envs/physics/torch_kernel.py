"""The torch dynamics: one control step of B arm copies as vectorised tensor operations, any device.

The physics of :mod:`envs.physics.pinocchio_loop` (equations in ``results/dynamics/README.md``)
with a loop over the six joints in Python and over nothing else: every operation acts on
tensors of shape ``(B, ...)``, so the same code runs on the CPU and on CUDA. A copy that stops
keeps being integrated and its results are discarded by ``torch.where`` masks, and the plane is
checked exactly at every substep, so a step is a fixed graph of tensor operations with no
host-device synchronisation (ready for a CUDA graph or ``torch.compile``); :meth:`TorchDynamics.
reset` checks the configurations on the host. The chain and plane tables are
:mod:`envs.physics.model`'s, as tensors.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

import ur5kin
from envs.checks import validate
from envs.physics.model import (
    NJ,
    ChainModel,
    PlaneModel,
    arm_model,
    check_aba_batch,
    check_free,
    check_num_copies,
    require_kernels,
    rest_heights,
    tool_offset,
    ur5_chain,
    ur5_plane,
)

if TYPE_CHECKING:
    from envs.spec import TaskSpec

DTYPES = {"float64": torch.float64, "float32": torch.float32}
"""Floating-point types of the tensors."""


CUDA_GRAPH_WARMUP_STEPS = 3
"""Eager control steps run on a side stream before a CUDA graph is recorded (PyTorch's recipe:
lazy initialisations, cuBLAS workspaces, out of the recording)."""

COMPILE_MODES = ("default", "reduce-overhead", "max-autotune")
"""``torch.compile`` modes :class:`TorchDynamics` accepts for its ``compile`` option."""


def _dtype(dtype: Any) -> torch.dtype:
    """The torch dtype of ``dtype`` (a name, a numpy or a torch dtype); ValueError otherwise."""
    if isinstance(dtype, torch.dtype):
        name = str(dtype).removeprefix("torch.")
    else:
        try:
            name = np.dtype(dtype).name
        except TypeError:
            name = str(dtype)
    if name not in DTYPES:
        raise ValueError(f"dtype must be one of {sorted(DTYPES)}; got {dtype!r}")
    return DTYPES[name]


def _skew(x: torch.Tensor) -> torch.Tensor:
    """``[x]x (..., 3, 3)``, the cross-product matrix of ``x (..., 3)``."""
    zero = torch.zeros_like(x[..., 0])
    return torch.stack([torch.stack([zero, -x[..., 2], x[..., 1]], -1),
                        torch.stack([x[..., 2], zero, -x[..., 0]], -1),
                        torch.stack([-x[..., 1], x[..., 0], zero], -1)], -2)


def _mv(M: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``M x``: ``M (..., r, c)`` times ``x (..., c)``, batched."""
    return torch.matmul(M, x.unsqueeze(-1)).squeeze(-1)


# ---------------------------------------------------------------------------- the model
@dataclass(frozen=True)
class TorchChain:
    """:class:`envs.physics.model.ChainModel` as tensors on one device, with the constants the
    vectorised algorithms use. Spatial vectors are Pinocchio's: motions ``[v; w]``, forces
    ``[f; n]`` (linear part first).

    Attributes
    ----------
    rotation, translation, axis, inertia, armature
        :class:`envs.physics.model.ChainModel`'s, as tensors.
    skew_translation : (6, 3, 3) float, m
        ``[p]x`` of each translation.
    axis_outer : (6, 3, 3) float
        ``a a^T`` of each axis (Rodrigues' formula).
    skew_axis : (6, 3, 3) float
        ``[a]x`` of each axis.
    subspace : (6, 6) float
        Each joint's motion subspace ``S = [0; a]``.
    bias_map : (6, 6, 6) float
        ``diag([a]x, [a]x)^T``: ``v @ bias_map[i] = v x_m S_i`` (the bias acceleration per unit
        joint velocity).
    base_acceleration : (6,) float, m/s^2
        ``[-g; 0]``: the base accelerates up, gravity as a fictitious force (in the units of
        the chain's gravity, which the caller may have time-scaled).
    """

    rotation: torch.Tensor
    translation: torch.Tensor
    skew_translation: torch.Tensor
    axis: torch.Tensor
    axis_outer: torch.Tensor
    skew_axis: torch.Tensor
    subspace: torch.Tensor
    bias_map: torch.Tensor
    inertia: torch.Tensor
    armature: torch.Tensor
    base_acceleration: torch.Tensor

    @classmethod
    def from_chain(cls, chain: ChainModel, device: torch.device | str,
                   dtype: torch.dtype) -> TorchChain:
        """The tensors of ``chain`` on ``device`` as ``dtype`` (derived constants in float64
        first, then cast)."""
        def t(x: Any) -> torch.Tensor:
            return torch.as_tensor(np.asarray(x, dtype=np.float64))

        axis, p = t(chain.axis), t(chain.translation)
        skew_axis = _skew(axis)
        zeros = torch.zeros_like(skew_axis)
        block = torch.cat([torch.cat([skew_axis, zeros], -1), torch.cat([zeros, skew_axis], -1)],
                          -2)
        # v x_m [0; a] = [v_lin x a; w x a] = -diag([a]x, [a]x) v, as a row vector map: v @ M
        bias_map = -block.transpose(-1, -2)
        values = {
            "rotation": t(chain.rotation), "translation": p, "skew_translation": _skew(p),
            "axis": axis, "axis_outer": axis[:, :, None] * axis[:, None, :],
            "skew_axis": skew_axis,
            "subspace": torch.cat([torch.zeros_like(axis), axis], -1), "bias_map": bias_map,
            "inertia": t(chain.inertia), "armature": t(chain.armature),
            "base_acceleration": torch.cat([-t(chain.gravity), t(np.zeros(3))]),
        }
        return cls(**{k: v.to(device=device, dtype=dtype).contiguous() for k, v in values.items()})


@dataclass(frozen=True)
class TorchPlane:
    """:class:`envs.physics.model.PlaneModel` as tensors, laid out for one matrix product.

    Attributes
    ----------
    vertex_heights : (13, V) float, m
        Per feature, the height above base_link of the candidate lowest vertices of the moving
        links, link by link.
    bounds : tuple of 7 int
        Columns ``bounds[k]:bounds[k + 1]`` belong to moving link k = 0..5 (their sizes differ
        sixfold: one slice each, where padding to the longest tripled the product).
    lift_offset, wrist_offset : float, rad
        Offsets of the pitches the features use.
    """

    vertex_heights: torch.Tensor
    bounds: tuple[int, ...]
    lift_offset: float
    wrist_offset: float

    @classmethod
    def from_plane(cls, plane: PlaneModel, device: torch.device | str,
                   dtype: torch.dtype) -> TorchPlane:
        """The table of ``plane`` (float64 there) without base_link's rows, on ``device`` as
        ``dtype``."""
        bounds = [int(b) for b in plane.bounds]
        vh = np.asarray(plane.vertex_heights, dtype=np.float64)[bounds[1] :]
        table = torch.as_tensor(np.ascontiguousarray(vh.T))
        return cls(table.to(device=device, dtype=dtype), tuple(b - bounds[1] for b in bounds[1:]),
                   float(plane.lift_offset), float(plane.wrist_offset))


@functools.cache
def _ur5_models(device: str, dtype: torch.dtype) -> tuple[TorchChain, TorchPlane]:
    """The UR5's chain (real gravity) and plane tensors (cached per device and dtype)."""
    return (TorchChain.from_chain(ur5_chain(), device, dtype),
            TorchPlane.from_plane(ur5_plane(), device, dtype))


# ---------------------------------------------------------------------------- algorithms
def placements(q: torch.Tensor, chain: TorchChain) -> torch.Tensor:
    """Each body's rotation in its parent's frame, ``R (B, 6, 3, 3)`` for ``q (B, 6)`` rad:
    the placement's rotation times Rodrigues' ``c I + (1 - c) a a^T + s [a]x``."""
    s, c = torch.sin(q)[..., None, None], torch.cos(q)[..., None, None]
    eye = torch.eye(3, dtype=q.dtype, device=q.device)
    turn = c * eye + (1.0 - c) * chain.axis_outer + s * chain.skew_axis
    return torch.matmul(chain.rotation, turn)


def motion_transforms(R: torch.Tensor, chain: TorchChain) -> torch.Tensor:
    """Parent-to-child motion transforms ``X (B, 6, 6, 6)`` of the placements ``(R, p)``:
    ``X = [R^T, -R^T [p]x; 0, R^T]``. Forces go child-to-parent by ``X^T``."""
    Rt = R.transpose(-1, -2)
    top = torch.cat([Rt, -torch.matmul(Rt, chain.skew_translation)], -1)
    bottom = torch.cat([torch.zeros_like(Rt), Rt], -1)
    return torch.cat([top, bottom], -2)


def gravity_torque(X: torch.Tensor, chain: TorchChain) -> torch.Tensor:
    """``g(q) (B, 6)``: the recursive Newton-Euler algorithm at rest (v = 0, qdd = 0) for the
    motion transforms ``X`` of ``q``, in the chain's gravity units."""
    acc = chain.base_acceleration
    forces = []
    for i in range(NJ):
        acc = _mv(X[:, i], acc)
        forces.append(torch.matmul(acc, chain.inertia[i].T))
    torques = [torch.empty(0)] * NJ
    for i in range(NJ - 1, -1, -1):
        torques[i] = torch.matmul(forces[i], chain.subspace[i])
        if i > 0:
            forces[i - 1] = forces[i - 1] + _mv(X[:, i].transpose(-1, -2), forces[i])
    return torch.stack(torques, -1)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.linalg.cross(a, b, dim=-1)


def articulated_body(X: torch.Tensor, qd: torch.Tensor, tau: torch.Tensor, chain: TorchChain,
                     free: int = NJ) -> torch.Tensor:
    """Featherstone's articulated-body algorithm (Pinocchio's ``aba``), batched over copies.

    Parameters
    ----------
    X : (B, 6, 6, 6) float
        :func:`motion_transforms` of the configurations.
    qd : (B, 6) float
        Joint velocities (rad/s, or rad per substep in the time-scaled units).
    tau : (B, 6) float
        Joint torques, in the units of the chain's gravity times inertia.
    free : int, 1..6
        Joints 1..free move; free+1..6 are locked (welded at their angles, zero ``qd``), as in
        :func:`envs.physics.numba_kernel.aba`.

    Returns
    -------
    qdd : (B, 6) float
        ``M(q)^-1 (tau - C(q, qd) qd - g(q))`` (with locked joints, that of the free joints'
        block, and 0 for the locked).
    """
    S, inertia = chain.subspace, chain.inertia
    # pass 1, base to tip: velocities v, bias accelerations c = v x_m (S qd), bias forces
    # p = v x_f (I v)
    vel, bias_acc, IA, pA = [], [], [], []
    for i in range(NJ):
        joint = qd[:, i : i + 1] * S[i]
        v = joint if i == 0 else _mv(X[:, i], vel[-1]) + joint
        vel.append(v)
        bias_acc.append(qd[:, i : i + 1] * torch.matmul(v, chain.bias_map[i]))
        h = torch.matmul(v, inertia[i].T)
        lin, ang, h_lin = v[:, :3], v[:, 3:], h[:, :3]
        pA.append(torch.cat([_cross(ang, h_lin),
                             _cross(ang, h[:, 3:]) + _cross(lin, h_lin)], -1))
        IA.append(inertia[i])  # broadcast (6, 6) until a child adds to it
    # pass 2, tip to base: articulated inertias IA and bias forces pA
    U, D, u = [torch.empty(0)] * NJ, [torch.empty(0)] * NJ, [torch.empty(0)] * NJ
    for i in range(NJ - 1, -1, -1):
        if i >= free:  # locked: rides on its parent whole
            Xt = X[:, i].transpose(-1, -2)
            IA[i - 1] = IA[i - 1] + torch.matmul(torch.matmul(Xt, IA[i]), X[:, i])
            pA[i - 1] = pA[i - 1] + _mv(Xt, pA[i] + _mv(IA[i], bias_acc[i]))
            continue
        U[i] = torch.matmul(IA[i], S[i])  # (B, 6)
        D[i] = torch.matmul(U[i], S[i]) + chain.armature[i]  # (B,)
        u[i] = tau[:, i] - torch.matmul(pA[i], S[i])
        if i == 0:
            break
        scaled = U[i] / D[i].unsqueeze(-1)
        Ia = IA[i] - scaled.unsqueeze(-1) * U[i].unsqueeze(-2)
        pa = pA[i] + _mv(Ia, bias_acc[i]) + scaled * u[i].unsqueeze(-1)
        Xt = X[:, i].transpose(-1, -2)
        IA[i - 1] = IA[i - 1] + torch.matmul(torch.matmul(Xt, Ia), X[:, i])
        pA[i - 1] = pA[i - 1] + _mv(Xt, pa)
    # pass 3, base to tip: accelerations (the base accelerates up: gravity)
    acc = chain.base_acceleration
    qdd = []
    for i in range(NJ):
        acc = _mv(X[:, i], acc) + bias_acc[i]
        if i >= free:
            qdd.append(torch.zeros_like(qd[:, i]))
            continue
        a = (u[i] - (U[i] * acc).sum(-1)) / D[i]
        acc = acc + a.unsqueeze(-1) * S[i]
        qdd.append(a)
    return torch.stack(qdd, -1)


def plane_heights(q: torch.Tensor, plane: TorchPlane, base_height: float) -> torch.Tensor:
    """Lowest point ``(B, 6)`` (m, world z) of each moving link at ``q (B, 6)`` rad: the 13
    trigonometric features (:data:`ur5kin.collision.FEATURES`) times the vertex table, the
    minimum per link (the numba kernel's ``copy_link_heights``)."""
    a = q[:, 1] + plane.lift_offset
    b = a + q[:, 2]
    c = b + q[:, 3] + plane.wrist_offset
    sc, cc = torch.sin(c), torch.cos(c)
    s5, c5, s6, c6 = torch.sin(q[:, 4]), torch.cos(q[:, 4]), torch.sin(q[:, 5]), torch.cos(q[:, 5])
    sc5 = sc * c5
    feat = torch.stack([torch.ones_like(a), torch.sin(a), torch.cos(a), torch.sin(b),
                        torch.cos(b), sc, cc, sc5, sc * s5, sc5 * c6, cc * s6, cc * c6,
                        sc5 * s6], -1)
    heights = torch.matmul(feat, plane.vertex_heights)  # (B, V)
    b = plane.bounds
    return torch.stack([heights[:, b[k] : b[k + 1]].amin(-1) for k in range(NJ)], -1) + base_height


def tool_position(R: torch.Tensor, chain: TorchChain, tool: torch.Tensor, base_height: float
                  ) -> torch.Tensor:
    """tool0's world position ``(B, 3)`` m for the placements ``R (B, 6, 3, 3)``: the chain's
    placements composed base to tip, the base at ``(0, 0, base_height)``; ``tool (3,)`` m is the
    tool frame's origin in joint 6's frame."""
    rot = R[:, 0]
    pos = chain.translation[0].expand(R.shape[0], 3)
    for i in range(1, NJ):
        pos = pos + _mv(rot, chain.translation[i])
        rot = torch.matmul(rot, R[:, i])
    pos = pos + _mv(rot, tool)
    # the height as a kernel's scalar argument: assigning it into a device tensor would copy
    # a host scalar (a sync, and an error inside a CUDA graph's capture)
    return torch.cat([pos[:, :2], pos[:, 2:] + base_height], dim=-1)


def _batch(x: Any, name: str, device: Any, dtype: torch.dtype) -> torch.Tensor:
    """``x`` as a ``(B, 6)`` tensor on ``device``; ValueError naming ``name`` otherwise."""
    t = torch.as_tensor(x, device=device, dtype=dtype)
    if t.ndim != 2 or t.shape[1] != NJ:
        raise ValueError(f"{name} must be a (B, 6) array or tensor; got shape {tuple(t.shape)}")
    return t


def aba(q: Any, v: Any, tau: Any, device: Any = "cpu", dtype: Any = "float64",
        free: int = NJ) -> torch.Tensor:
    """Joint accelerations ``(B, 6)`` rad/s^2 of B copies of the UR5, as tensors on ``device``:
    :func:`envs.physics.numba_kernel.aba`'s parameters, result and errors (zero velocities in
    the locked joints' columns)."""
    free = check_free(free)
    cast = _dtype(dtype)
    chain, _ = _ur5_models(str(torch.device(device)), cast)
    q, v, tau = (_batch(x, n, device, cast) for x, n in ((q, "q"), (v, "v"), (tau, "tau")))
    check_aba_batch(q, v, tau, free)
    return articulated_body(motion_transforms(placements(q, chain), chain), v, tau, chain, free)


def generalized_gravity(q: Any, device: Any = "cpu", dtype: Any = "float64") -> torch.Tensor:
    """Gravity torques ``g(q) (B, 6)`` N m (Pinocchio's ``computeGeneralizedGravity`` for each
    row ``q (B, 6)`` rad), batched."""
    cast = _dtype(dtype)
    chain, _ = _ur5_models(str(torch.device(device)), cast)
    q = _batch(q, "q", device, cast)
    return gravity_torque(motion_transforms(placements(q, chain), chain), chain)


def link_heights(q: Any, base_height: float, device: Any = "cpu", dtype: Any = "float64"
                 ) -> torch.Tensor:
    """The plane check: lowest point ``(B, 6)`` (m, world z) of shoulder_link .. wrist_3_link
    for ``q (B, 6)`` rad, base_link ``base_height`` m above the plane
    (:func:`ur5kin.link_heights` without the fixed base link)."""
    cast = _dtype(dtype)
    _, plane = _ur5_models(str(torch.device(device)), cast)
    return plane_heights(_batch(q, "q", device, cast), plane,
                         float(ur5kin.check_base_height(base_height)))


# ---------------------------------------------------------------------------- the class
def copy_out(x: torch.Tensor, out: Any = None) -> Any:
    """``x`` as a new tensor, or written into ``out``: a tensor of its shape, or a numpy array
    (a device-to-host copy). Returns what it wrote."""
    if out is None:
        return x.clone()
    if isinstance(out, np.ndarray):
        out[:] = x.cpu().numpy()
    else:
        out.copy_(x)
    return out


class TorchDynamics:
    """B copies of the UR5 under the task's controller, one vectorised torch step per call: an
    :class:`envs.physics.Dynamics` with tensors for arrays (the same physics as the numba kernel
    to rounding; tested against it). The state lives on ``device``; a step is a fixed graph of
    tensor operations.

    Parameters
    ----------
    device : str or torch.device
        Where the tensors live and the step runs (``"cpu"``, ``"cuda"``, ``"cuda:1"``).
    dtype : {"float64", "float32"}
        The arithmetic and the state's type. float32 drifts from float64 like the numba path's
        (the bounds are in the tests). On CUDA, float32 assumes full-precision matrix products
        (torch's default): TF32 (``torch.set_float32_matmul_precision("high")``) would round
        them to 10-bit mantissas, beyond those bounds.
    compile : bool or str
        Run each substep through ``torch.compile`` (compiled on the first step): True for its
        default mode, or a mode name from :data:`COMPILE_MODES` (``"reduce-overhead"`` adds CUDA
        graphs on a GPU). On the CPU it needs a C++ compiler (timings:
        results/batched_env/README.md); a slow test checks it against the eager step.
    cuda_graph : bool
        Record the whole control step as one ``torch.cuda.CUDAGraph`` on the first step and
        replay it after (CUDA only, not with ``compile``): the ~6,000 kernels of a step are
        launched by one call. Written without a GPU at hand: the CUDA test checks it against
        the eager step where one is.

    Attributes
    ----------
    w : (B, 6) tensor, rad per substep
        The integrator's velocity ``h v``.
    tool : (B, 3) tensor, m, world frame
        tool0's position now.

    The tensors are owned by this object and overwritten in place by every step (their storage
    never changes, as a CUDA graph needs); clone what you keep.
    """

    def __init__(self, task: TaskSpec, num_copies: int = 1, device: Any = "cpu",
                 dtype: Any = "float64", compile: bool | str = False,
                 cuda_graph: bool = False) -> None:
        B = self.num_copies = check_num_copies(num_copies)
        require_kernels(task, "TorchDynamics")
        device = torch.device(device)
        if compile is not False and compile is not True and compile not in COMPILE_MODES:
            raise ValueError(f"compile must be a bool or one of {list(COMPILE_MODES)}; got "
                             f"{compile!r}")
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"device {str(device)!r}: torch sees no CUDA device here")
        if cuda_graph and (device.type != "cuda" or compile):
            raise ValueError(f"cuda_graph=True needs a CUDA device and compile=False; got "
                             f"device {str(device)!r}, compile={compile!r}")
        cast = _dtype(dtype)
        self.task, self.device, self.dtype = validate(task), device, cast
        arm = self.arm = arm_model(task)
        # time-scaled units (envs.physics.model): gravity and torques * h^2, velocities w = h v
        self._chain = TorchChain.from_chain(arm.chain, device, cast)
        self._plane = TorchPlane.from_plane(ur5_plane(), device, cast)

        def t(x: Any) -> torch.Tensor:
            return torch.as_tensor(np.array(x, dtype=np.float64)).to(device=device, dtype=cast)

        self._tool_pos = t(tool_offset())
        self._kp, self._kd = t(arm.kp_eff), t(arm.kd_eff)
        self._command_gain = t(arm.command_gain)
        self._effort, self._w_max = t(arm.effort), t(arm.w_max)
        self._q_mid, self._q_half = t(arm.q_mid), t(arm.q_half)
        self._bias = t(arm.initial_bias(B))
        self._gravity_comp = bool(task.gravity_compensation)
        self._base_height, self._margin = float(task.base_height), float(task.plane_margin)

        self.q = t(arm.start_q).repeat(B, 1)
        self.w = torch.zeros((B, NJ), device=device, dtype=cast)
        self.v = torch.zeros_like(self.w)
        self.acceleration = torch.zeros_like(self.w)
        self.contact = torch.zeros(B, dtype=torch.bool, device=device)
        self.limit_stop = torch.zeros_like(self.contact)
        self.tool = tool_position(placements(self.q, self._chain), self._chain, self._tool_pos,
                                   self._base_height)
        # the compiled unit is the substep: a graph of a few hundred operations (the whole
        # step unrolls to substeps times as many, and compiles for as much longer)
        self._substep_fn = self._masked_substep
        if compile:
            mode = None if compile is True else compile
            self._substep_fn = torch.compile(self._masked_substep, dynamic=False, mode=mode)
        self._use_graph, self._graph = bool(cuda_graph), None

    # ------------------------------------------------------------------ the step
    def _masked_substep(self, q: torch.Tensor, w: torch.Tensor, bias: torch.Tensor,
                        running: torch.Tensor, contact: torch.Tensor, limit: torch.Tensor
                        ) -> tuple[torch.Tensor, ...]:
        """One substep of every copy with the stop model, for copies still ``running`` ((B,)
        bool).

        A substep that leaves the joint limits or brings a link below the plane margin is not
        taken: the copy stays where it is with ``w = 0`` (stopped dead) and stops running; the
        substeps it has left are computed and discarded by the masks, as PinocchioDynamics computes
        and discards them. Returns the new ``q, w, running, contact, limit``.
        """
        chain = self._chain
        X = motion_transforms(placements(q, chain), chain)
        tau = bias - self._kp * q - self._kd * w
        if self._gravity_comp:
            tau = tau + gravity_torque(X, chain)
        tau = torch.minimum(torch.maximum(tau, -self._effort), self._effort)
        w1 = w + articulated_body(X, w, tau, chain, self.arm.free)
        w1 = torch.minimum(torch.maximum(w1, -self._w_max), self._w_max)
        q1 = q + w1
        beyond = ((q1 - self._q_mid).abs() > self._q_half).any(-1) & running
        below = (plane_heights(q1, self._plane, self._base_height) < self._margin).any(-1) \
            & running
        running = running & ~(beyond | below)
        keep = running.unsqueeze(-1)
        return (torch.where(keep, q1, q),
                torch.where(keep, w1, torch.zeros_like(w1)),  # a stopped copy's w is already 0
                running, contact | below, limit | beyond)

    def _control_step(self, q: torch.Tensor, w: torch.Tensor, bias: torch.Tensor
                      ) -> tuple[torch.Tensor, ...]:
        """``task.substeps`` masked substeps of every copy; pure (new tensors). Returns ``q,
        w, contact, limit_stop, tool``."""
        running = torch.ones(q.shape[0], dtype=torch.bool, device=q.device)
        contact, limit = torch.zeros_like(running), torch.zeros_like(running)
        for _ in range(self.task.substeps):
            q, w, running, contact, limit = self._substep_fn(q, w, bias, running, contact, limit)
        tool = tool_position(placements(q, self._chain), self._chain, self._tool_pos,
                             self._base_height)
        return q, w, contact, limit, tool

    def step(self, command: Any) -> None:
        """:meth:`envs.physics.Dynamics.step`; ``command`` a tensor or an array (a tensor on
        ``device`` avoids a host-to-device copy)."""
        n = self.task.n_joints
        command = torch.as_tensor(command, device=self.device, dtype=self.dtype)
        if command.shape != (self.num_copies, n):
            raise ValueError(f"command must be ({self.num_copies}, {n}); got "
                             f"{tuple(command.shape)}")
        torch.mul(self._command_gain, command, out=self._bias[:, :n])
        if not self._use_graph:
            self._advance()
            return
        if self._graph is None:
            self._graph = self._capture()
        self._graph.replay()

    def _state(self) -> tuple[torch.Tensor, ...]:
        """Every tensor a step writes."""
        return (self.q, self.w, self.v, self.acceleration, self.contact, self.limit_stop,
                self.tool)

    def _advance(self) -> None:
        """One control step from the state tensors into them, in place, with the command in
        ``_bias``: the work a CUDA graph captures (it reads and writes fixed storage only)."""
        q, w, contact, limit, tool = self._control_step(self.q, self.w, self._bias)
        torch.mul(w - self.w, self.arm.w_to_accel, out=self.acceleration)
        self.q.copy_(q)
        self.w.copy_(w)
        torch.mul(w, self.arm.w_to_v, out=self.v)
        self.contact.copy_(contact)
        self.limit_stop.copy_(limit)
        self.tool.copy_(tool)

    def _capture(self) -> Any:
        """A ``torch.cuda.CUDAGraph`` of :meth:`_advance`, recorded after warm-up steps on a
        side stream (PyTorch's recipe); the state the warm-up moves is put back."""
        saved = [t.clone() for t in self._state()]
        side = torch.cuda.Stream(self.device)
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            for _ in range(CUDA_GRAPH_WARMUP_STEPS):
                self._advance()
        torch.cuda.current_stream(self.device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self._advance()
        for t, before in zip(self._state(), saved, strict=True):
            t.copy_(before)
        return graph

    def tool_positions(self, out: Any = None) -> Any:
        """tool0's world position ``(B, 3)`` m (base at (0, 0, base_height)), written into
        ``out`` (a tensor, or a numpy array, which costs a device-to-host copy) when given."""
        return copy_out(self.tool, out)

    def reset(self, q: Any, index: Any = None) -> None:
        """:meth:`envs.physics.Dynamics.reset` (the configurations checked on the host: a reset
        synchronises)."""
        q = np.asarray(q.cpu() if isinstance(q, torch.Tensor) else q, dtype=float)
        rest_heights(self.task, q)  # on the host
        sel = slice(None) if index is None else index
        if isinstance(sel, np.ndarray):
            sel = torch.as_tensor(sel, device=self.device)
        self.q[sel] = torch.as_tensor(q, device=self.device, dtype=self.dtype)
        for state in (self.v, self.w, self.acceleration):
            state[sel] = 0.0
        self.contact[sel] = False
        self.limit_stop[sel] = False
        self.tool.copy_(tool_position(placements(self.q, self._chain), self._chain,
                                       self._tool_pos, self._base_height))
