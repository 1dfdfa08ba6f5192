"""The Triton backend: a whole control step of B arm copies, each with its own locked joints,
as one Triton kernel launch on torch's current stream (so a CUDA graph can capture it).

The same control step as the numba kernel's :func:`envs.physics.numba_kernel.step_copy`
(``substeps`` times PD + gravity compensation, effort clip, the articulated-body algorithm
with joints ``free[b] ..`` locked, velocity clip, semi-implicit Euler; the joint-limit and
plane stops with the Lipschitz skip of the exact heights; tool0's position), written as
lane-parallel Triton: a program steps ``BLOCK`` copies, one lane each; every 6-joint and 6x6
loop is unrolled at compile time (``tl.static_range``) over tuples of lane vectors, so the
whole state of a copy lives in registers. A copy's early stop (``break`` in ``step_copy``)
becomes a lane mask: a stopped lane keeps computing and discards it. The exact link heights
are computed for a block only when one of its active lanes needs them (the skip is per copy,
as in ``step_copy``; the block pays for the slowest lane). Same operations in the same order
as ``step_copy``, so the interpreter (``TRITON_INTERPRET=1``, numpy) agrees with the numba
kernel: bit for bit over the tested steps in float64 (the test's bound is 1e-9), within 1e-5
in float32. The interpreter takes about 9 s of CPU per control step of a block.

The model's tables are compile-time constants (:class:`TritonModel`), and each (B, 6) state
array is read and written as one (BLOCK, 8) tile: the compile for a GPU is then about 40 s of
CPU per dtype (sm_90 on the development machine, 39-42 s float64, 38-39 s float32:
``python -m benchmarks.triton_compile --dtype float64``), where one scalar load per table entry
and one access per column took 317 s. Most of it is Triton's ``TritonGPUCoalesce`` pass, which
walks the whole kernel once per lane-tensor memory access (68 then, 12 now), so its cost grows
with their number and with the kernel's size (9,368 TTIR operations then, 6,818 now);
``tests/test_stack_dynamics.py`` bounds both.
The first launch on a machine pays it (then Triton's disk cache).

This module imports Triton (``@triton.jit`` reads ``TRITON_INTERPRET`` when it is imported);
:mod:`envs.physics.stack` imports it only for ``kernel="triton"``.
"""

# ruff: noqa: RUF005 - tuples grow by concatenation, the form Triton 3.6's front end compiles here
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import triton
import triton.language as tl

from envs.physics.model import ChainModel, PlaneModel

if TYPE_CHECKING:
    import torch

NUM_WARPS = 1
"""Warps per program: 32 lanes (:data:`envs.physics.stack.BLOCK`) are one warp's threads, one
copy per thread."""

PLANE_SCALARS = ("lift", "wrist", "base_height", "margin")
"""The order of :attr:`TritonModel.plane`: the plane check's pitch offsets (rad), the base's
height (m) and the plane margin (m)."""


def _values(x: Any, cast: Any) -> tuple[float, ...]:
    """``x`` rounded to ``cast`` (numpy's float64 or float32), flattened in C order, as Python
    floats: each the exact value the numba kernel reads from its ``cast`` array."""
    return tuple(float(v) for v in np.asarray(x, dtype=float).astype(cast).ravel())


@dataclass(frozen=True)
class TritonModel:
    """The step kernel's model: the tables as compile-time constants (flat tuples of Python
    floats holding the exact values of the kernel's type, row-major), the plane's vertex table
    as a tensor on the device.

    The constants are ``tl.constexpr`` arguments of the kernel, each turned into a scalar of
    the kernel's type by ``tl.full([], value, dtype)`` (exact: a Python float used directly in
    Triton arithmetic would become a float32 constant). They replace the ~400 scalar loads of
    the tables the kernel had, which fed every substep's arithmetic through memory reads.

    Attributes
    ----------
    kp, kd, effort, w_max : (6,) tuples
        The scaled PD gains the torque uses, effort and velocity limits
        (:class:`envs.physics.model.ArmModel`'s ``kp_eff, kd_eff, effort, w_max``).
    q_mid, q_half : (6,) tuples, rad
        Centre and half-width of the joint limits.
    vertex_heights : (V, 13) tensor, m
        :class:`envs.physics.model.PlaneModel`'s, of the kernel's type, on its device.
    bounds : (8,) tuple of int
        Its row bounds: link k's rows are ``bounds[k] .. bounds[k + 1] - 1`` (k = 0 the base).
    lipschitz : (36,) tuple, m/rad
        The height bounds per joint, ``[i, k]`` at ``6 i + k``.
    plane : (4,) tuple
        :data:`PLANE_SCALARS`.
    rotation (54,), translation (18,), axis (18,), inertia (216,), armature (6,), gravity (3,)
        :class:`envs.physics.model.ChainModel`'s, flattened (gravity scaled by ``h^2``).
    tool_pos : (3,) tuple, m
        tool0's origin in joint 6's frame.
    substeps : int
        Substeps per control step.
    gravity_comp : bool
        Whether the PD adds the gravity torque.
    """

    kp: tuple[float, ...]
    kd: tuple[float, ...]
    effort: tuple[float, ...]
    w_max: tuple[float, ...]
    q_mid: tuple[float, ...]
    q_half: tuple[float, ...]
    vertex_heights: torch.Tensor
    bounds: tuple[int, ...]
    lipschitz: tuple[float, ...]
    plane: tuple[float, ...]
    rotation: tuple[float, ...]
    translation: tuple[float, ...]
    axis: tuple[float, ...]
    inertia: tuple[float, ...]
    armature: tuple[float, ...]
    gravity: tuple[float, ...]
    tool_pos: tuple[float, ...]
    substeps: int
    gravity_comp: bool

    @classmethod
    def build(cls, controller: dict[str, np.ndarray], chain: ChainModel, plane: PlaneModel,
              tool_pos: np.ndarray, base_height: float, margin: float, substeps: int,
              gravity_comp: bool, device: Any, dtype: torch.dtype) -> TritonModel:
        """The model for ``dtype`` (its tables rounded to it), the vertex table on ``device``:
        ``controller`` holds ``kp, kd, effort, w_max, q_mid, q_half`` (6,) arrays
        (time-scaled units)."""
        import torch

        cast = {torch.float64: np.float64, torch.float32: np.float32}[dtype]
        vertex_heights = torch.tensor(np.asarray(plane.vertex_heights, dtype=cast),
                                      device=device).contiguous()
        return cls(**{k: _values(controller[k], cast) for k in ("kp", "kd", "effort", "w_max",
                                                               "q_mid", "q_half")},
                   vertex_heights=vertex_heights,
                   bounds=tuple(int(b) for b in plane.bounds),
                   lipschitz=_values(plane.lipschitz, cast),
                   plane=_values([plane.lift_offset, plane.wrist_offset, base_height, margin],
                                 cast),
                   rotation=_values(chain.rotation, cast),
                   translation=_values(chain.translation, cast),
                   axis=_values(chain.axis, cast), inertia=_values(chain.inertia, cast),
                   armature=_values(chain.armature, cast), gravity=_values(chain.gravity, cast),
                   tool_pos=_values(tool_pos, cast), substeps=int(substeps),
                   gravity_comp=bool(gravity_comp))


def launch(model: TritonModel, q: torch.Tensor, w: torch.Tensor, height_bound: torch.Tensor,
           bias: torch.Tensor, free: torch.Tensor, dw: torch.Tensor, contact: torch.Tensor,
           limit_stop: torch.Tensor, tool: torch.Tensor, block: int) -> None:
    """One control step of the B copies, one launch on torch's current stream; every tensor
    contiguous, on the model's device, nothing read on the host.

    Parameters
    ----------
    q, w : (B, 6) tensors
        The state (rad, rad per substep), advanced in place.
    height_bound : (B, 6) tensor, m, world z
        Lower bounds of each moving link's height, kept valid in place.
    bias : (B, 6) tensor
        The constant part of each copy's scaled PD torque (the command's).
    free : (B,) int32 tensor
        Copy b's joints ``free[b] ..`` (0-based) are locked, 1 <= free[b] <= 6.
    dw, contact, limit_stop, tool : tensors
        Written: ``w_new - w_old (B, 6)``, the plane and joint-limit stops ``(B,)`` bool,
        tool0's world position ``(B, 3)`` m.
    block : int
        Copies per program (a power of two).
    """
    args, constexprs = launch_arguments(model, q, w, height_bound, bias, free, dw, contact,
                                        limit_stop, tool, block)
    kernel()[(triton.cdiv(q.shape[0], block),)](*args, **constexprs, num_warps=NUM_WARPS)


def launch_arguments(model: TritonModel, q: torch.Tensor, w: torch.Tensor,
                     height_bound: torch.Tensor, bias: torch.Tensor, free: torch.Tensor,
                     dw: torch.Tensor, contact: torch.Tensor, limit_stop: torch.Tensor,
                     tool: torch.Tensor, block: int) -> tuple[tuple[Any, ...], dict[str, Any]]:
    """The step kernel's arguments for :func:`launch`'s: the positional ones (tensors and the
    copy count B) and the compile-time constants by name (``benchmarks.triton_compile``
    compiles the kernel from them without a GPU)."""
    m = model
    args = (q, w, height_bound, bias, free, dw, contact, limit_stop, tool, m.vertex_heights,
            q.shape[0])
    constexprs = dict(KP=m.kp, KD=m.kd, EFFORT=m.effort, W_MAX=m.w_max, Q_MID=m.q_mid,
                      Q_HALF=m.q_half, LIPSCHITZ=m.lipschitz, PLANE=m.plane, ROT0=m.rotation,
                      P=m.translation, AXIS=m.axis, INERTIA=m.inertia, ARMATURE=m.armature,
                      GRAV=m.gravity, TOOL_POS=m.tool_pos, BOUNDS=m.bounds,
                      SUBSTEPS=m.substeps, GRAVITY_COMP=m.gravity_comp, BLOCK=block)
    return args, constexprs


def kernel() -> Any:
    """The step kernel (:func:`step_kernel`)."""
    return step_kernel


# ---------------------------------------------------------------------------- device functions
# Each takes and returns tuples of lane vectors (or of scalars: the model's tables), indexed at
# compile time; the comments name the numba function each one mirrors.


@triton.jit
def constants(values, dtype: tl.constexpr, N: tl.constexpr):
    """``values[0 .. N - 1]`` (a constexpr tuple of Python floats) as N scalars of ``dtype``,
    each exact (``tl.full``; a bare Python float in Triton arithmetic is a float32 constant)."""
    out = ()
    for k in tl.static_range(N):
        out = out + (tl.full([], values[k], dtype),)
    return out


@triton.jit
def constant_rows(values, dtype: tl.constexpr, ROWS: tl.constexpr, N: tl.constexpr):
    """Rows ``values[r N : (r + 1) N]`` as a tuple of ROWS tuples of N scalars of ``dtype``
    (the flat tuple is indexed here: a sub-tuple passed on to :func:`constants` would lose its
    constexpr type in Triton 3.6's front end)."""
    out = ()
    for r in tl.static_range(ROWS):
        row = ()
        for k in tl.static_range(N):
            row = row + (tl.full([], values[N * r + k], dtype),)
        out = out + (row,)
    return out


@triton.jit
def split_columns(tile, W: tl.constexpr):
    """The W columns of a (BLOCK, W) tile, W = 4 or 8, as W lane vectors (reshape and
    ``tl.split``: data movement only, every value exact)."""
    BLOCK: tl.constexpr = tile.shape[0]
    if W == 8:
        # t[b, i, j, l] = tile[b, 4 i + 2 j + l]; each split takes the last axis
        even, odd = tl.split(tl.reshape(tile, (BLOCK, 2, 2, 2)))
        e0, e1 = tl.split(even)
        o0, o1 = tl.split(odd)
        c0, c4 = tl.split(e0)
        c2, c6 = tl.split(e1)
        c1, c5 = tl.split(o0)
        c3, c7 = tl.split(o1)
        out = (c0, c1, c2, c3, c4, c5, c6, c7)
    else:
        # t[b, i, l] = tile[b, 2 i + l]
        even, odd = tl.split(tl.reshape(tile, (BLOCK, 2, 2)))
        c0, c2 = tl.split(even)
        c1, c3 = tl.split(odd)
        out = (c0, c1, c2, c3)
    return out


@triton.jit
def join_columns(x, W: tl.constexpr):
    """The (BLOCK, W) tile whose columns are the W lane vectors ``x``: :func:`split_columns`
    undone."""
    BLOCK: tl.constexpr = x[0].shape[0]
    if W == 8:
        even = tl.join(tl.join(x[0], x[4]), tl.join(x[2], x[6]))
        odd = tl.join(tl.join(x[1], x[5]), tl.join(x[3], x[7]))
    else:
        even = tl.join(x[0], x[2])
        odd = tl.join(x[1], x[3])
    return tl.reshape(tl.join(even, odd), (BLOCK, W))


@triton.jit
def load_lanes(ptr, offs, valid, N: tl.constexpr):
    """Columns ``0..N-1`` of the rows ``offs`` of an (B, N) tensor, N <= 8: N lane vectors,
    read by one load of a (BLOCK, W) tile (W = 4 or 8, the columns past N masked).

    One memory access per array, not one per column: Triton's ``TritonGPUCoalesce`` pass
    walks the whole kernel once per access, so their number multiplies the compile time."""
    W: tl.constexpr = 4 if N <= 4 else 8
    cols = tl.arange(0, W)
    tile = tl.load(ptr + offs[:, None] * N + cols[None, :],
                   mask=valid[:, None] & (cols < N)[None, :], other=0)
    columns = split_columns(tile, W)
    out = ()
    for k in tl.static_range(N):
        out = out + (columns[k],)
    return out


@triton.jit
def store_lanes(ptr, offs, valid, x, N: tl.constexpr):
    """Write the N lane vectors ``x`` as columns ``0..N-1`` of the rows ``offs`` of an (B, N)
    tensor, N <= 8: one store of a (BLOCK, W) tile (:func:`load_lanes`' layout)."""
    W: tl.constexpr = 4 if N <= 4 else 8
    padded = ()
    for k in tl.static_range(W):
        if k < N:  # noqa: SIM108 - a compile-time branch, as Triton's front end reads it
            padded = padded + (x[k],)
        else:
            padded = padded + (x[0],)  # masked out
    cols = tl.arange(0, W)
    tl.store(ptr + offs[:, None] * N + cols[None, :], join_columns(padded, W),
             mask=valid[:, None] & (cols < N)[None, :])


@triton.jit
def placements(q, rot0, axis):
    """``R[i] = rot0[i] Rot(axis[i], q[i])`` (row-major 9-tuples): numba's ``placements``."""
    R = ()
    for i in tl.static_range(6):
        s = tl.sin(q[i])
        c = tl.cos(q[i])
        ax = axis[i][0]
        ay = axis[i][1]
        az = axis[i][2]
        t = 1.0 - c
        r00 = c + t * ax * ax
        r01 = t * ax * ay - s * az
        r02 = t * ax * az + s * ay
        r10 = t * ax * ay + s * az
        r11 = c + t * ay * ay
        r12 = t * ay * az - s * ax
        r20 = t * ax * az - s * ay
        r21 = t * ay * az + s * ax
        r22 = c + t * az * az
        Ri = ()
        for r in tl.static_range(3):
            a0 = rot0[i][3 * r]
            a1 = rot0[i][3 * r + 1]
            a2 = rot0[i][3 * r + 2]
            Ri = Ri + (a0 * r00 + a1 * r10 + a2 * r20, a0 * r01 + a1 * r11 + a2 * r21,
                       a0 * r02 + a1 * r12 + a2 * r22)
        R = R + (Ri,)
    return R


@triton.jit
def motion_inv(R, p, m):
    """``M^-1 m`` for a motion ``m = [v; w]`` in the parent frame, ``M = (R, p)``."""
    w0 = m[3]
    w1 = m[4]
    w2 = m[5]
    l0 = m[0] + w1 * p[2] - w2 * p[1]
    l1 = m[1] + w2 * p[0] - w0 * p[2]
    l2 = m[2] + w0 * p[1] - w1 * p[0]
    lin = ()
    ang = ()
    for r in tl.static_range(3):
        lin = lin + (R[r] * l0 + R[3 + r] * l1 + R[6 + r] * l2,)
        ang = ang + (R[r] * w0 + R[3 + r] * w1 + R[6 + r] * w2,)
    return lin + ang


@triton.jit
def force_act(R, p, f, out):
    """``out + M f`` for a force ``f = [f; n]`` in the child frame, ``M = (R, p)``."""
    f0 = R[0] * f[0] + R[1] * f[1] + R[2] * f[2]
    f1 = R[3] * f[0] + R[4] * f[1] + R[5] * f[2]
    f2 = R[6] * f[0] + R[7] * f[1] + R[8] * f[2]
    return (out[0] + f0, out[1] + f1, out[2] + f2,
            out[3] + (R[0] * f[3] + R[1] * f[4] + R[2] * f[5] + p[1] * f2 - p[2] * f1),
            out[4] + (R[3] * f[3] + R[4] * f[4] + R[5] * f[5] + p[2] * f0 - p[0] * f2),
            out[5] + (R[6] * f[3] + R[7] * f[4] + R[8] * f[5] + p[0] * f1 - p[1] * f0))


@triton.jit
def mat_vec(M, v):
    """``M v`` for a row-major 36-tuple M, each sum from 0 as numba's."""
    out = ()
    for r in tl.static_range(6):
        s = 0.0
        for k in tl.static_range(6):
            s += M[6 * r + k] * v[k]
        out = out + (s,)
    return out


@triton.jit
def base_acceleration(grav, zero):
    """The base's spatial acceleration: up against gravity (a fictitious force)."""
    return (zero - grav[0], zero - grav[1], zero - grav[2], zero, zero, zero)


@triton.jit
def gravity_torque(R, p, axis, inertia, grav, zero):
    """``g(q)``: RNEA at rest for the placements ``R``: numba's ``_gravity_torque``."""
    acc = base_acceleration(grav, zero)
    forces = ()
    for i in tl.static_range(6):
        acc = motion_inv(R[i], p[i], acc)
        forces = forces + (mat_vec(inertia[i], acc),)
    f = forces[5]
    g = ()
    for i in tl.static_range(5, -1, -1):
        g = (axis[i][0] * f[3] + axis[i][1] * f[4] + axis[i][2] * f[5],) + g
        if i > 0:
            f = force_act(R[i], p[i], f, forces[i - 1])
    return g


@triton.jit
def rotate_block(R, ia, RO: tl.constexpr, CO: tl.constexpr):
    """``R X R^T`` (a row-major 9-tuple) of the 3x3 block X of ``ia`` at (RO, CO)."""
    M = ()
    for r in tl.static_range(3):
        for k in tl.static_range(3):
            M = M + (R[3 * r] * ia[6 * RO + CO + k] + R[3 * r + 1] * ia[6 * RO + 6 + CO + k]
                     + R[3 * r + 2] * ia[6 * RO + 12 + CO + k],)
    Y = ()
    for r in tl.static_range(3):
        for k in tl.static_range(3):
            Y = Y + (M[3 * r] * R[3 * k] + M[3 * r + 1] * R[3 * k + 1]
                     + M[3 * r + 2] * R[3 * k + 2],)
    return Y


@triton.jit
def rotate_blocks(R, ia):
    """``(R A R^T, R B R^T, R C R^T)`` of ``ia = [A, B; B^T, C]``: numba's
    ``_rotate_blocks``."""
    return (rotate_block(R, ia, 0, 0), rotate_block(R, ia, 0, 3), rotate_block(R, ia, 3, 3))


@triton.jit
def shift_into(p, Y, parent):
    """``parent + [A', B' - A'P; (B' - A'P)^T, C' + P B' + (P B')^T - P A' P]``, P =
    [p]x, for ``Y = (A', B', C')``: numba's ``_shift_into`` (parent a 36-tuple)."""
    A = Y[0]
    Bm = Y[1]
    C = Y[2]
    p0 = p[0]
    p1 = p[1]
    p2 = p[2]
    AP = ()  # A'P, row-major
    for r in tl.static_range(3):
        AP = AP + (A[3 * r + 1] * p2 - A[3 * r + 2] * p1,
                   A[3 * r + 2] * p0 - A[3 * r] * p2,
                   A[3 * r] * p1 - A[3 * r + 1] * p0)
    PB = ()  # P B'
    PAP = ()  # P (A'P)
    for j in tl.static_range(3):
        for k in tl.static_range(3):
            if j == 0:
                PB = PB + (p1 * Bm[6 + k] - p2 * Bm[3 + k],)
                PAP = PAP + (p1 * AP[6 + k] - p2 * AP[3 + k],)
            elif j == 1:
                PB = PB + (p2 * Bm[k] - p0 * Bm[6 + k],)
                PAP = PAP + (p2 * AP[k] - p0 * AP[6 + k],)
            else:
                PB = PB + (p0 * Bm[3 + k] - p1 * Bm[k],)
                PAP = PAP + (p0 * AP[3 + k] - p1 * AP[k],)
    out = ()
    for r in tl.static_range(6):
        for k in tl.static_range(6):
            if r < 3 and k < 3:
                out = out + (parent[6 * r + k] + A[3 * r + k],)
            elif r < 3:
                out = out + (parent[6 * r + k] + (Bm[3 * r + k - 3] - AP[3 * r + k - 3]),)
            elif k < 3:
                out = out + (parent[6 * r + k] + (Bm[3 * k + r - 3] - AP[3 * k + r - 3]),)
            else:
                out = out + (parent[6 * r + k]
                             + (C[3 * (r - 3) + k - 3] + PB[3 * (r - 3) + k - 3]
                                + PB[3 * (k - 3) + r - 3] - PAP[3 * (r - 3) + k - 3]),)
    return out


@triton.jit
def aba(R, p, axis, inertia, armature, grav, qd, tau, free, zero):
    """Featherstone's ABA, joints ``free ..`` locked per lane: numba's ``_aba``."""
    # pass 1: velocities, bias accelerations c, bias forces p = v x* (I v)
    vel = (zero, zero, zero, zero, zero, zero)
    cb = ()
    pA = ()
    for i in tl.static_range(6):
        vi = motion_inv(R[i], p[i], vel)
        sx = axis[i][0] * qd[i]
        sy = axis[i][1] * qd[i]
        sz = axis[i][2] * qd[i]
        vi = (vi[0], vi[1], vi[2], vi[3] + sx, vi[4] + sy, vi[5] + sz)
        cb = cb + ((vi[1] * sz - vi[2] * sy, vi[2] * sx - vi[0] * sz,
                    vi[0] * sy - vi[1] * sx, vi[4] * sz - vi[5] * sy,
                    vi[5] * sx - vi[3] * sz, vi[3] * sy - vi[4] * sx),)
        h = mat_vec(inertia[i], vi)
        w0 = vi[3]
        w1 = vi[4]
        w2 = vi[5]
        pA = pA + ((w1 * h[2] - w2 * h[1], w2 * h[0] - w0 * h[2], w0 * h[1] - w1 * h[0],
                    w1 * h[5] - w2 * h[4] + vi[1] * h[2] - vi[2] * h[1],
                    w2 * h[3] - w0 * h[5] + vi[2] * h[0] - vi[0] * h[2],
                    w0 * h[4] - w1 * h[3] + vi[0] * h[1] - vi[1] * h[0]),)
        vel = vi
    # pass 2: articulated inertias and bias forces, tip to base; body i's (IA, pa) arrive
    # as the carry from its child (its own inertia plus the child's contribution)
    IA = inertia[5]
    pa = pA[5]
    Us = ()
    Ds = ()
    us = ()
    for i in tl.static_range(5, -1, -1):
        moving = free > i
        ax = axis[i][0]
        ay = axis[i][1]
        az = axis[i][2]
        U = ()
        for r in tl.static_range(6):
            U = U + (IA[6 * r + 3] * ax + IA[6 * r + 4] * ay + IA[6 * r + 5] * az,)
        D = U[3] * ax + U[4] * ay + U[5] * az + armature[i]
        u = tau[i] - (pa[3] * ax + pa[4] * ay + pa[5] * az)
        Us = (U,) + Us
        Ds = (D,) + Ds
        us = (u,) + us
        if i > 0:
            inv_d = 1.0 / D
            Ia = ()
            for r in tl.static_range(6):
                for k in tl.static_range(6):
                    Ia = Ia + (tl.where(moving, IA[6 * r + k] - U[r] * U[k] * inv_d,
                                        IA[6 * r + k]),)
            Yp = ()
            for r in tl.static_range(6):
                s = tl.where(moving, pa[r] + U[r] * u * inv_d, pa[r])
                for k in tl.static_range(6):
                    s += Ia[6 * r + k] * cb[i][k]
                Yp = Yp + (s,)
            pa = force_act(R[i], p[i], Yp, pA[i - 1])
            IA = shift_into(p[i], rotate_blocks(R[i], Ia), inertia[i - 1])
    # pass 3: accelerations, base to tip
    acc = base_acceleration(grav, zero)
    qdd = ()
    for i in tl.static_range(6):
        ai = motion_inv(R[i], p[i], acc)
        ai = (ai[0] + cb[i][0], ai[1] + cb[i][1], ai[2] + cb[i][2], ai[3] + cb[i][3],
              ai[4] + cb[i][4], ai[5] + cb[i][5])
        moving = free > i
        s = us[i]
        for k in tl.static_range(6):
            s -= Us[i][k] * ai[k]
        a = tl.where(moving, s / Ds[i], zero)
        qdd = qdd + (a,)
        acc = (ai[0], ai[1], ai[2], tl.where(moving, ai[3] + axis[i][0] * a, ai[3]),
               tl.where(moving, ai[4] + axis[i][1] * a, ai[4]),
               tl.where(moving, ai[5] + axis[i][2] * a, ai[5]))
    return qdd


@triton.jit
def link_heights(q, vh_ptr, lift, wrist, base_height, zero, BOUNDS: tl.constexpr):
    """Exact lowest point (m, world z) of moving links 1..6: numba's
    ``copy_link_heights`` (link k's vertex rows ``BOUNDS[k] ..``, one row at a time, its 13
    products summed from 0 in numba's order; the rows are scalar loads, the same address in
    every lane)."""
    a = q[1] + lift
    b = a + q[2]
    c = b + q[3] + wrist
    sc = tl.sin(c)
    cc = tl.cos(c)
    s5 = tl.sin(q[4])
    c5 = tl.cos(q[4])
    s6 = tl.sin(q[5])
    c6 = tl.cos(q[5])
    f7 = sc * c5
    feat = (zero + 1.0, tl.sin(a), tl.cos(a), tl.sin(b), tl.cos(b), sc, cc, f7, sc * s5,
            f7 * c6, cc * s6, cc * c6, f7 * s6)
    out = ()
    for k in tl.static_range(1, 7):
        low = zero + float("inf")
        for row in range(BOUNDS[k], BOUNDS[k + 1]):
            s = zero
            for f in tl.static_range(13):
                s += tl.load(vh_ptr + row * 13 + f) * feat[f]
            low = tl.minimum(low, s)
        out = out + (low + base_height,)
    return out


@triton.jit
def tool_position(R, p, tool_pos, base_height, zero):
    """tool0's world position (m) for the placements ``R``: numba's ``tool_position``."""
    r00 = zero + 1.0
    r01 = zero
    r02 = zero
    r10 = zero
    r11 = zero + 1.0
    r12 = zero
    r20 = zero
    r21 = zero
    r22 = zero + 1.0
    x = zero
    y = zero
    z = zero
    for i in tl.static_range(6):
        Ri = R[i]
        pi = p[i]
        x, y, z = (x + r00 * pi[0] + r01 * pi[1] + r02 * pi[2],
                   y + r10 * pi[0] + r11 * pi[1] + r12 * pi[2],
                   z + r20 * pi[0] + r21 * pi[1] + r22 * pi[2])
        n00 = r00 * Ri[0] + r01 * Ri[3] + r02 * Ri[6]
        n01 = r00 * Ri[1] + r01 * Ri[4] + r02 * Ri[7]
        n02 = r00 * Ri[2] + r01 * Ri[5] + r02 * Ri[8]
        n10 = r10 * Ri[0] + r11 * Ri[3] + r12 * Ri[6]
        n11 = r10 * Ri[1] + r11 * Ri[4] + r12 * Ri[7]
        n12 = r10 * Ri[2] + r11 * Ri[5] + r12 * Ri[8]
        n20 = r20 * Ri[0] + r21 * Ri[3] + r22 * Ri[6]
        n21 = r20 * Ri[1] + r21 * Ri[4] + r22 * Ri[7]
        n22 = r20 * Ri[2] + r21 * Ri[5] + r22 * Ri[8]
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = (n00, n01, n02, n10, n11, n12, n20,
                                                       n21, n22)
    return (x + r00 * tool_pos[0] + r01 * tool_pos[1] + r02 * tool_pos[2],
            y + r10 * tool_pos[0] + r11 * tool_pos[1] + r12 * tool_pos[2],
            z + r20 * tool_pos[0] + r21 * tool_pos[1] + r22 * tool_pos[2] + base_height)


@triton.jit
def lower_bounds(known, q, q_ref, lipschitz):
    """``known[k] - sum_i L[i, k] |q[i] - q_ref[i]|``: the Lipschitz bounds of the link
    heights at ``q`` from the exact ones at ``q_ref``, subtracted term by term."""
    out = ()
    for k in tl.static_range(6):
        bound = known[k]
        for i in tl.static_range(6):
            bound -= lipschitz[i][k] * tl.abs(q[i] - q_ref[i])
        out = out + (bound,)
    return out


@triton.jit
def step_kernel(q_ptr, w_ptr, hb_ptr, bias_ptr, free_ptr, dw_ptr, contact_ptr, limit_ptr,
                tool_ptr, vh_ptr, B, KP: tl.constexpr, KD: tl.constexpr, EFFORT: tl.constexpr,
                W_MAX: tl.constexpr, Q_MID: tl.constexpr, Q_HALF: tl.constexpr,
                LIPSCHITZ: tl.constexpr, PLANE: tl.constexpr, ROT0: tl.constexpr,
                P: tl.constexpr, AXIS: tl.constexpr, INERTIA: tl.constexpr,
                ARMATURE: tl.constexpr, GRAV: tl.constexpr, TOOL_POS: tl.constexpr,
                BOUNDS: tl.constexpr, SUBSTEPS: tl.constexpr, GRAVITY_COMP: tl.constexpr,
                BLOCK: tl.constexpr):
    """One control step of copies ``pid BLOCK ..``: :func:`launch`'s (the upper-case
    arguments are :class:`TritonModel`'s constants)."""
    offs = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    valid = offs < B
    dt = q_ptr.dtype.element_ty
    kp = constants(KP, dt, 6)
    kd = constants(KD, dt, 6)
    effort = constants(EFFORT, dt, 6)
    w_max = constants(W_MAX, dt, 6)
    q_mid = constants(Q_MID, dt, 6)
    q_half = constants(Q_HALF, dt, 6)
    lipschitz = constant_rows(LIPSCHITZ, dt, 6, 6)
    lift, wrist, base_height, margin = constants(PLANE, dt, 4)
    rot0 = constant_rows(ROT0, dt, 6, 9)
    p = constant_rows(P, dt, 6, 3)
    axis = constant_rows(AXIS, dt, 6, 3)
    inertia = constant_rows(INERTIA, dt, 6, 36)
    armature = constants(ARMATURE, dt, 6)
    grav = constants(GRAV, dt, 3)
    tool_pos = constants(TOOL_POS, dt, 3)

    q = load_lanes(q_ptr, offs, valid, 6)
    w0 = load_lanes(w_ptr, offs, valid, 6)
    known = load_lanes(hb_ptr, offs, valid, 6)
    bias = load_lanes(bias_ptr, offs, valid, 6)
    free = tl.load(free_ptr + offs, mask=valid, other=6)
    zero = tl.zeros_like(q[0])  # a lane vector of the kernel's type
    w = w0
    q_ref = q
    active = valid
    hit_plane = offs < 0
    hit_limit = offs < 0
    for _ in range(SUBSTEPS):
        R = placements(q, rot0, axis)
        tau = ()
        for k in tl.static_range(6):
            tau = tau + (bias[k] - kp[k] * q[k] - kd[k] * w[k],)
        if GRAVITY_COMP:
            g = gravity_torque(R, p, axis, inertia, grav, zero)
            tau2 = ()
            for k in tl.static_range(6):
                tau2 = tau2 + (tau[k] + g[k],)
            tau = tau2
        clipped = ()
        for k in tl.static_range(6):
            clipped = clipped + (tl.minimum(tl.maximum(tau[k], -effort[k]), effort[k]),)
        a = aba(R, p, axis, inertia, armature, grav, w, clipped, free, zero)
        w1 = ()
        q1 = ()
        limit = offs < 0
        for k in tl.static_range(6):
            wk = tl.minimum(tl.maximum(w[k] + a[k], -w_max[k]), w_max[k])
            qk = q[k] + wk
            limit = limit | (tl.abs(qk - q_mid[k]) > q_half[k])
            w1 = w1 + (wk,)
            q1 = q1 + (qk,)
        # the plane: exact heights only where the bound from the last exact ones fails
        bound = lower_bounds(known, q1, q_ref, lipschitz)
        unsure = offs < 0
        for k in tl.static_range(6):
            unsure = unsure | (bound[k] < margin)
        need = unsure & active
        plane = offs < 0
        if tl.max(need.to(tl.int32), 0) > 0:
            heights = link_heights(q1, vh_ptr, lift, wrist, base_height, zero, BOUNDS)
            known2 = ()
            ref2 = ()
            for k in tl.static_range(6):
                known2 = known2 + (tl.where(need, heights[k], known[k]),)
                ref2 = ref2 + (tl.where(need, q1[k], q_ref[k]),)
                plane = plane | (need & (heights[k] < margin))
            known = known2
            q_ref = ref2
        stop = plane | limit
        hit_plane = hit_plane | (active & plane)
        hit_limit = hit_limit | (active & limit)
        moves = active & ~stop
        q_next = ()
        w_next = ()
        for k in tl.static_range(6):
            q_next = q_next + (tl.where(moves, q1[k], q[k]),)
            # stopped dead at the last valid substep
            w_next = w_next + (tl.where(moves, w1[k], tl.where(active, zero, w[k])),)
        q = q_next
        w = w_next
        active = moves
    known = lower_bounds(known, q, q_ref, lipschitz)
    R = placements(q, rot0, axis)
    tool = tool_position(R, p, tool_pos, base_height, zero)
    dw = ()
    for k in tl.static_range(6):
        dw = dw + (w[k] - w0[k],)
    store_lanes(q_ptr, offs, valid, q, 6)
    store_lanes(w_ptr, offs, valid, w, 6)
    store_lanes(hb_ptr, offs, valid, known, 6)
    store_lanes(dw_ptr, offs, valid, dw, 6)
    store_lanes(tool_ptr, offs, valid, tool, 3)
    tl.store(contact_ptr + offs, hit_plane, mask=valid)
    tl.store(limit_ptr + offs, hit_limit, mask=valid)
