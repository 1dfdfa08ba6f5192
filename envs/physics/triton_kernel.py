"""The Triton backend: a whole control step of B arm copies, each with its own locked joints,
as one Triton kernel launch on torch's current stream (so a CUDA graph can capture it).

The numba kernel's :func:`envs.physics.numba_kernel.step_copy` as lane-parallel Triton: a
program steps ``BLOCK`` copies, one lane each, a copy's state in registers, its early stop a
lane mask; link k's exact height is computed for a block only when one of its active lanes
needs it. The arithmetic is generated (:func:`generate`): the step's algebra traced once per
model and dtype over :class:`Value` objects, the tables as constants, and written out as
straight-line ``@triton.jit`` functions the kernel takes as ``tl.constexpr`` arguments. The
trace drops what the tables make exactly zero (most rotation, axis, offset and inertia entries,
54% of the vertex table, which is in the code: no loads) and keeps numba's order otherwise, so
the interpreter (``TRITON_INTERPRET=1``) agrees with the numba kernel bit for bit over the
tested steps in float64 (a dropped ``0 x`` differs only for x infinite or NaN, and in a zero's
sign), within 1e-5 in float32. Each (B, 6) array is read and written as one (BLOCK, 8) tile
(``TritonGPUCoalesce`` walks the kernel once per lane-tensor access). The sm_90 compile's
registers, spills and instructions: ``python -m benchmarks.triton_compile``, and
``results/grid_program/arm_kernel.md``. :mod:`envs.physics.stack` imports this module only
for ``kernel="triton"`` (``@triton.jit`` reads ``TRITON_INTERPRET`` at import).
"""

# ruff: noqa: RUF005 - tuples grow by concatenation, the form Triton 3.6's front end compiles here
from __future__ import annotations

import functools
import hashlib
import linecache
import operator
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


class Value:
    """A value of the generated code: a constant of the kernel's type (``const``, a numpy
    scalar) or a variable of the source (``name``). Arithmetic on Values writes the source
    (:class:`Source`), folding only what is exact: ``0 x = 0``, ``x + 0 = x``, ``1 x = x``,
    ``-1 x = -x``, ``0 - x = -x``, and constants with constants in the kernel's type."""

    __slots__ = ("const", "name", "src")

    def __init__(self, src: Source, name: str | None = None, const: Any = None) -> None:
        self.src, self.name, self.const = src, name, const

    def equals(self, c: float) -> bool:
        return self.name is None and self.const == c

    def _v(self, x: Any) -> Value:
        return x if isinstance(x, Value) else self.src.constant(x)

    def __neg__(self) -> Value:
        return self.src.neg(self)


def _binary(name: str, reflected: bool = False) -> Any:
    """``Value``'s operator ``__name__`` (:class:`Source`'s method of that name, constants
    folded here), its operands swapped when ``reflected`` (``2.0 * x``)."""
    def method(self: Value, other: Any) -> Value:
        a, b = (self._v(other), self) if reflected else (self, self._v(other))
        if a.name is None and b.name is None:
            return self.src.constant(getattr(operator, name)(a.const, b.const))
        return getattr(self.src, name)(a, b)
    return method


for _name in ("add", "sub", "mul", "truediv"):
    setattr(Value, f"__{_name}__", _binary(_name))
    setattr(Value, f"__r{_name}__", _binary(_name, reflected=True))


class Source:
    """The body of one generated ``@triton.jit`` function, a line per operation; ``cast`` is
    numpy's type of the kernel (float64 or float32): constants are rounded to it and folded
    in it."""

    def __init__(self, cast: Any) -> None:
        self.cast = cast
        self.dtype = {np.float64: "tl.float64", np.float32: "tl.float32"}[cast]
        self.lines: list[str] = []
        self.names: dict[float, str] = {}

    def constant(self, x: Any) -> Value:
        return Value(self, const=self.cast(x))

    def input(self, name: str) -> Value:
        return Value(self, name=name)

    def ref(self, v: Value) -> str:
        """``v`` in an expression: its name, or its constant's (declared once)."""
        if v.name is not None:
            return v.name
        if not np.isfinite(v.const):
            raise ValueError(f"the generated code cannot hold the constant {v.const}")
        return self.names.setdefault(float(v.const), f"k{len(self.names)}")

    def emit(self, expr: str) -> Value:
        name = f"v{len(self.lines)}"
        self.lines.append(f"{name} = {expr}")
        return Value(self, name=name)

    def add(self, a: Value, b: Value) -> Value:
        if a.equals(0):
            return b
        if b.equals(0):
            return a
        return self.emit(f"{self.ref(a)} + {self.ref(b)}")

    def sub(self, a: Value, b: Value) -> Value:
        if b.equals(0):
            return a
        if a.equals(0):
            return self.neg(b)
        return self.emit(f"{self.ref(a)} - {self.ref(b)}")

    def mul(self, a: Value, b: Value) -> Value:
        if a.equals(0) or b.equals(0):
            return self.constant(0)
        for x, y in ((a, b), (b, a)):
            if x.equals(1):
                return y
            if x.equals(-1):
                return self.neg(y)
        return self.emit(f"{self.ref(a)} * {self.ref(b)}")

    def truediv(self, a: Value, b: Value) -> Value:
        if b.equals(1):
            return a
        return self.emit(f"{self.ref(a)} / {self.ref(b)}")

    def neg(self, a: Value) -> Value:
        return self.constant(-a.const) if a.name is None else self.emit(f"-{a.name}")

    def call(self, fn: str, *args: Value) -> Value:
        return self.emit(f"{fn}({', '.join(self.ref(a) for a in args)})")

    def minimum(self, a: Value, b: Value) -> Value:
        return b if a.equals(np.inf) else self.call("tl.minimum", a, b)

    def where(self, mask: str | None, a: Value, b: Value) -> Value:
        """``a`` where ``mask`` (None: everywhere), ``b`` elsewhere."""
        if mask is None or a is b or (a.name is None and b.name is None and a.const == b.const):
            return a
        return self.emit(f"tl.where({mask}, {self.ref(a)}, {self.ref(b)})")

    def function(self, name: str, params: str, outputs: list[Value]) -> str:
        """The ``@triton.jit`` function's source: constants, body, ``return`` of
        ``outputs`` as lane vectors (a constant output is added to the lane vector
        ``zero``, which must be a parameter)."""
        out = [self.ref(v) if v.name is not None else f"zero + {self.ref(v)}" for v in outputs]
        head = [f"{k} = tl.full([], {v!r}, {self.dtype})" for v, k in self.names.items()]
        body = "\n".join("    " + line for line in head + self.lines)
        return (f"@triton.jit\ndef {name}({params}):\n{body}\n"
                f"    return ({', '.join(out)},)\n")


def _values(x: Any, cast: Any) -> Any:
    """``x`` rounded to ``cast`` (numpy's float64 or float32) as nested tuples of Python
    floats: each the exact value the numba kernel reads from its ``cast`` array."""
    return tuple(_values(v, cast) if np.ndim(v) else float(cast(v)) for v in np.asarray(x))


@dataclass(frozen=True)
class TritonModel:
    """The step kernel's model: the controller's limits as compile-time constants (tuples of
    Python floats holding the exact values of the kernel's type) and the generated functions
    (:func:`generate`) that hold every other table.

    Attributes
    ----------
    w_max, q_mid, q_half : (6,) tuples
        Velocity limits (rad per substep), centre and half-width of the joint limits (rad).
    margin : float
        The plane margin (m).
    substeps : int
        Substeps per control step.
    functions : tuple
        The generated ``@triton.jit`` functions, :data:`GENERATED`'s order.
    source : str
        Their source.
    """

    w_max: tuple[float, ...]
    q_mid: tuple[float, ...]
    q_half: tuple[float, ...]
    margin: float
    substeps: int
    functions: tuple[Any, ...]
    source: str

    @classmethod
    def build(cls, controller: dict[str, np.ndarray], chain: ChainModel, plane: PlaneModel,
              tool_pos: np.ndarray, base_height: float, margin: float, substeps: int,
              gravity_comp: bool, dtype: torch.dtype) -> TritonModel:
        """The model for ``dtype`` (its tables rounded to it): ``controller`` holds ``kp, kd,
        effort, w_max, q_mid, q_half`` (6,) arrays (time-scaled units)."""
        import torch

        name = {torch.float64: "float64", torch.float32: "float32"}[dtype]
        cast = np.dtype(name).type
        tables = (("kp", controller["kp"]), ("kd", controller["kd"]),
                  ("effort", controller["effort"]),
                  ("rot0", np.reshape(chain.rotation, (6, 9))), ("p", chain.translation),
                  ("axis", chain.axis), ("inertia", np.reshape(chain.inertia, (6, 36))),
                  ("armature", chain.armature), ("grav", chain.gravity),
                  ("tool_pos", tool_pos), ("vertex_heights", plane.vertex_heights),
                  ("lipschitz", plane.lipschitz), ("lift", plane.lift_offset),
                  ("wrist", plane.wrist_offset), ("base_height", base_height))
        frozen = tuple((k, _values(v, cast) if np.ndim(v) else float(cast(v)))
                       for k, v in tables)
        frozen += (("bounds", tuple(int(b) for b in plane.bounds)),
                   ("gravity_comp", bool(gravity_comp)))
        source, functions = generate(frozen, name)
        return cls(w_max=_values(controller["w_max"], cast),
                   q_mid=_values(controller["q_mid"], cast),
                   q_half=_values(controller["q_half"], cast), margin=float(cast(margin)),
                   substeps=int(substeps), functions=functions, source=source)


def launch(model: TritonModel, q: torch.Tensor, w: torch.Tensor, height_bound: torch.Tensor,
           bias: torch.Tensor, free: torch.Tensor, dw: torch.Tensor, contact: torch.Tensor,
           limit_stop: torch.Tensor, tool: torch.Tensor, block: int) -> None:
    """One control step of the B copies, one launch on torch's current stream; every tensor
    contiguous, on one device, nothing read on the host.

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
    accel, features, height, lower_bounds, tool_fn = m.functions
    args = (q, w, height_bound, bias, free, dw, contact, limit_stop, tool, q.shape[0])
    constexprs = dict(W_MAX=m.w_max, Q_MID=m.q_mid, Q_HALF=m.q_half, MARGIN=m.margin,
                      SUBSTEPS=m.substeps, BLOCK=block, ACCEL=accel, FEATURES=features,
                      HEIGHT=height, LOWER_BOUNDS=lower_bounds, TOOL=tool_fn)
    return args, constexprs


def kernel() -> Any:
    """The step kernel (:func:`step_kernel`)."""
    return step_kernel


# ------------------------------------------------------------------------------ the kernel
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
def load_lanes(ptr, offs, valid, N: tl.constexpr, VOLATILE: tl.constexpr = False):
    """Columns ``0..N-1`` of the rows ``offs`` of an (B, N) tensor, N <= 8: N lane vectors,
    read by one load of a (BLOCK, W) tile (W = 4 or 8, the columns past N masked).

    One memory access per array, not one per column: Triton's ``TritonGPUCoalesce`` pass
    walks the whole kernel once per access, so their number multiplies the compile time.
    ``VOLATILE``: read where the code says (not hoisted out of a loop nor merged)."""
    W: tl.constexpr = 4 if N <= 4 else 8
    cols = tl.arange(0, W)
    tile = tl.load(ptr + offs[:, None] * N + cols[None, :],
                   mask=valid[:, None] & (cols < N)[None, :], other=0, volatile=VOLATILE)
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


# ------------------------------------------------------------------------- the traced algebra
# Plain Python over Values, mirroring the numba functions named in each docstring operation by
# operation (their order of sums and products), so that the generated code rounds as they do.
# Tables are lists of constant Values; R[i] and the 6x6 matrices are row-major lists.


def _placements(q: list[Value], rot0: list[list[Value]], axis: list[list[Value]]
                ) -> list[list[Value]]:
    """``R[i] = rot0[i] Rot(axis[i], q[i])``: numba's ``placements``."""
    src = q[0].src
    R = []
    for i in range(6):
        s, c = src.call("tl.sin", q[i]), src.call("tl.cos", q[i])
        ax, ay, az = axis[i]
        t = 1.0 - c
        r = (c + t * ax * ax, t * ax * ay - s * az, t * ax * az + s * ay,
             t * ax * ay + s * az, c + t * ay * ay, t * ay * az - s * ax,
             t * ax * az - s * ay, t * ay * az + s * ax, c + t * az * az)
        R.append([rot0[i][3 * row] * r[k] + rot0[i][3 * row + 1] * r[3 + k]
                  + rot0[i][3 * row + 2] * r[6 + k] for row in range(3) for k in range(3)])
    return R


def _motion_inv(R: list[Value], p: list[Value], m: list[Value]) -> list[Value]:
    """``M^-1 m`` for a motion ``m = [v; w]`` in the parent frame: numba's ``_motion_inv``."""
    w0, w1, w2 = m[3], m[4], m[5]
    l0 = m[0] + w1 * p[2] - w2 * p[1]
    l1 = m[1] + w2 * p[0] - w0 * p[2]
    l2 = m[2] + w0 * p[1] - w1 * p[0]
    return ([R[r] * l0 + R[3 + r] * l1 + R[6 + r] * l2 for r in range(3)]
            + [R[r] * w0 + R[3 + r] * w1 + R[6 + r] * w2 for r in range(3)])


def _force_act(R: list[Value], p: list[Value], f: list[Value], out: list[Value]
               ) -> list[Value]:
    """``out + M f`` for a force ``f = [f; n]`` in the child frame: numba's ``_force_act``."""
    f0 = R[0] * f[0] + R[1] * f[1] + R[2] * f[2]
    f1 = R[3] * f[0] + R[4] * f[1] + R[5] * f[2]
    f2 = R[6] * f[0] + R[7] * f[1] + R[8] * f[2]
    return [out[0] + f0, out[1] + f1, out[2] + f2,
            out[3] + (R[0] * f[3] + R[1] * f[4] + R[2] * f[5] + p[1] * f2 - p[2] * f1),
            out[4] + (R[3] * f[3] + R[4] * f[4] + R[5] * f[5] + p[2] * f0 - p[0] * f2),
            out[5] + (R[6] * f[3] + R[7] * f[4] + R[8] * f[5] + p[0] * f1 - p[1] * f0)]


def _mat_vec(M: list[Value], v: list[Value]) -> list[Value]:
    """``M v`` for a row-major 6x6 M, each sum from 0 as numba's."""
    out = []
    for r in range(6):
        s = v[0].src.constant(0)
        for k in range(6):
            s = s + M[6 * r + k] * v[k]
        out.append(s)
    return out


def _gravity_torque(R: list[list[Value]], t: dict[str, Any]) -> list[Value]:
    """``g(q)``: RNEA at rest for the placements ``R``: numba's ``_gravity_torque``."""
    zero = R[0][0].src.constant(0)
    acc = [-t["grav"][0], -t["grav"][1], -t["grav"][2], zero, zero, zero]
    forces = []
    for i in range(6):
        acc = _motion_inv(R[i], t["p"][i], acc)
        forces.append(_mat_vec(t["inertia"][i], acc))
    g = [zero] * 6
    f = forces[5]
    for i in range(5, -1, -1):
        ax, ay, az = t["axis"][i]
        g[i] = ax * f[3] + ay * f[4] + az * f[5]
        if i > 0:
            f = _force_act(R[i], t["p"][i], f, forces[i - 1])
    return g


def _rotate_blocks(R: list[Value], ia: list[Value]) -> list[Value | None]:
    """``R A R^T, R B R^T, R C R^T`` of ``ia = [A, B; B^T, C]`` at their places in a 6x6
    (the lower left block None): numba's ``_rotate_blocks``."""
    out: list[Value | None] = [None] * 36
    for ro, co in ((0, 0), (0, 3), (3, 3)):
        M = [R[3 * r] * ia[6 * ro + co + k] + R[3 * r + 1] * ia[6 * ro + 6 + co + k]
             + R[3 * r + 2] * ia[6 * ro + 12 + co + k] for r in range(3) for k in range(3)]
        for r in range(3):
            for k in range(3):
                out[6 * (ro + r) + co + k] = (M[3 * r] * R[3 * k] + M[3 * r + 1] * R[3 * k + 1]
                                              + M[3 * r + 2] * R[3 * k + 2])
    return out


def _shift_into(p: list[Value], Y: list[Any], parent: list[Value]) -> list[Value]:
    """``parent + [A', B' - A'P; (B' - A'P)^T, C' + P B' + (P B')^T - P A' P]``, P = [p]x:
    numba's ``_shift_into`` (``Y`` from :func:`_rotate_blocks`)."""
    p0, p1, p2 = p
    S: list[Any] = [None] * 36
    for r in range(3):  # A'P
        S[6 * r + 3] = Y[6 * r + 1] * p2 - Y[6 * r + 2] * p1
        S[6 * r + 4] = Y[6 * r + 2] * p0 - Y[6 * r] * p2
        S[6 * r + 5] = Y[6 * r] * p1 - Y[6 * r + 1] * p0
    for k in range(3):  # P B' and P (A'P)
        S[18 + k] = p1 * Y[12 + 3 + k] - p2 * Y[6 + 3 + k]
        S[24 + k] = p2 * Y[3 + k] - p0 * Y[12 + 3 + k]
        S[30 + k] = p0 * Y[6 + 3 + k] - p1 * Y[3 + k]
        S[21 + k] = p1 * S[15 + k] - p2 * S[9 + k]
        S[27 + k] = p2 * S[3 + k] - p0 * S[15 + k]
        S[33 + k] = p0 * S[9 + k] - p1 * S[3 + k]
    out = list(parent)
    for r in range(3):
        for k in range(3):
            out[6 * r + k] = parent[6 * r + k] + Y[6 * r + k]
            top = Y[6 * r + 3 + k] - S[6 * r + 3 + k]
            out[6 * r + 3 + k] = parent[6 * r + 3 + k] + top
            out[6 * (3 + k) + r] = parent[6 * (3 + k) + r] + top
            out[6 * (3 + r) + 3 + k] = parent[6 * (3 + r) + 3 + k] + (
                Y[6 * (3 + r) + 3 + k] + S[6 * (3 + r) + k] + S[6 * (3 + k) + r]
                - S[6 * (3 + r) + 3 + k])
    return out


def _aba(R: list[list[Value]], t: dict[str, Any], qd: list[Value], tau: list[Value]
         ) -> list[Value]:
    """Featherstone's ABA, joints ``free ..`` locked per lane (``free``, an int32 lane vector
    of the generated function, >= 1): numba's ``_aba``, its per-copy branches as selects."""
    src = qd[0].src
    zero = src.constant(0)
    p, axis, inertia = t["p"], t["axis"], t["inertia"]
    moving = [None] + [src.emit(f"free > {i}").name for i in range(1, 6)]  # joint 0 moves
    # pass 1: velocities; the bias accelerations c and forces p = v x* (I v) that follow from
    # them are written where pass 2 first reads them (the same operations, fewer values live)
    vel = [zero] * 6
    vs, ss = [], []
    for i in range(6):
        vi = _motion_inv(R[i], p[i], vel)
        sx, sy, sz = (axis[i][k] * qd[i] for k in range(3))
        vi = vi[:3] + [vi[3] + sx, vi[4] + sy, vi[5] + sz]
        vs.append(vi)
        ss.append((sx, sy, sz))
        vel = vi

    @functools.cache
    def bias_acceleration(i: int) -> list[Value]:
        vi, (sx, sy, sz) = vs[i], ss[i]
        return [vi[1] * sz - vi[2] * sy, vi[2] * sx - vi[0] * sz, vi[0] * sy - vi[1] * sx,
                vi[4] * sz - vi[5] * sy, vi[5] * sx - vi[3] * sz, vi[3] * sy - vi[4] * sx]

    def bias_force(i: int) -> list[Value]:
        vi = vs[i]
        h = _mat_vec(inertia[i], vi)
        w0, w1, w2 = vi[3], vi[4], vi[5]
        return [w1 * h[2] - w2 * h[1], w2 * h[0] - w0 * h[2], w0 * h[1] - w1 * h[0],
                w1 * h[5] - w2 * h[4] + vi[1] * h[2] - vi[2] * h[1],
                w2 * h[3] - w0 * h[5] + vi[2] * h[0] - vi[0] * h[2],
                w0 * h[4] - w1 * h[3] + vi[0] * h[1] - vi[1] * h[0]]

    # pass 2: articulated inertias and bias forces, tip to base
    IA, pa = inertia[5], bias_force(5)
    Us, Ds, us = [None] * 6, [None] * 6, [None] * 6
    for i in range(5, -1, -1):
        ax, ay, az = axis[i]
        U = [IA[6 * r + 3] * ax + IA[6 * r + 4] * ay + IA[6 * r + 5] * az for r in range(6)]
        Us[i] = U
        Ds[i] = U[3] * ax + U[4] * ay + U[5] * az + t["armature"][i]
        us[i] = tau[i] - (pa[3] * ax + pa[4] * ay + pa[5] * az)
        if i == 0:
            break
        inv_d = 1.0 / Ds[i]
        Ia = [src.where(moving[i], IA[6 * r + k] - U[r] * U[k] * inv_d, IA[6 * r + k])
              for r in range(6) for k in range(6)]
        Yp = []
        for r in range(6):
            s = src.where(moving[i], pa[r] + U[r] * us[i] * inv_d, pa[r])
            for k in range(6):
                s = s + Ia[6 * r + k] * bias_acceleration(i)[k]
            Yp.append(s)
        pa = _force_act(R[i], p[i], Yp, bias_force(i - 1))
        IA = _shift_into(p[i], _rotate_blocks(R[i], Ia), inertia[i - 1])
    # pass 3: accelerations, base to tip (the base accelerates up: gravity)
    acc = [-t["grav"][0], -t["grav"][1], -t["grav"][2], zero, zero, zero]
    qdd = []
    for i in range(6):
        ai = _motion_inv(R[i], p[i], acc)
        ai = [ai[k] + bias_acceleration(i)[k] for k in range(6)]
        s = us[i]
        for k in range(6):
            s = s - Us[i][k] * ai[k]
        a = src.where(moving[i], s / Ds[i], zero)
        qdd.append(a)
        acc = ai[:3] + [src.where(moving[i], ai[3 + k] + axis[i][k] * a, ai[3 + k])
                        for k in range(3)]
    return qdd


def _accel(src: Source, t: dict[str, Any]) -> str:
    """``accel(q, w, bias, free, zero)``: the joint accelerations (rad per substep^2) of a
    substep, ``aba(q, w, clip(bias - kp q - kd w + g(q), +-effort))``: numba's
    ``step_copy`` up to the velocity update."""
    q, w, bias = ([src.input(f"{x}[{k}]") for k in range(6)] for x in ("q", "w", "bias"))
    R = _placements(q, t["rot0"], t["axis"])
    tau = [bias[k] - t["kp"][k] * q[k] - t["kd"][k] * w[k] for k in range(6)]
    if t["gravity_comp"]:
        g = _gravity_torque(R, t)
        tau = [tau[k] + g[k] for k in range(6)]
    effort = t["effort"]
    clipped = [src.call("tl.minimum", src.call("tl.maximum", tau[k], -effort[k]), effort[k])
               for k in range(6)]
    return src.function("accel", "q, w, bias, free, zero", _aba(R, t, w, clipped))


def _features(src: Source, t: dict[str, Any]) -> str:
    """``features(q, zero)``: the 13 features of numba's ``copy_link_heights`` (the first,
    1, is a constant of :func:`_link_height`'s and returned only as a placeholder)."""
    q = [src.input(f"q[{k}]") for k in range(6)]
    a = q[1] + t["lift"]
    b = a + q[2]
    c = b + q[3] + t["wrist"]
    sc, cc = src.call("tl.sin", c), src.call("tl.cos", c)
    s5, c5 = src.call("tl.sin", q[4]), src.call("tl.cos", q[4])
    s6, c6 = src.call("tl.sin", q[5]), src.call("tl.cos", q[5])
    f7 = sc * c5
    feat = [src.constant(1.0), src.call("tl.sin", a), src.call("tl.cos", a),
            src.call("tl.sin", b), src.call("tl.cos", b), sc, cc, f7, sc * s5, f7 * c6,
            cc * s6, cc * c6, f7 * s6]
    return src.function("features", "q, zero", feat)


def _link_height(src: Source, t: dict[str, Any], k: int) -> str:
    """``height_k(feat, zero)``: the exact lowest point (m, world z) of moving link k (1..6)
    from the features: numba's ``copy_link_heights``' rows of link k, the vertex table's zeros
    dropped."""
    feat = [src.constant(1.0)] + [src.input(f"feat[{f}]") for f in range(1, 13)]
    vh, bounds = t["vertex_heights"], t["bounds"]
    low = src.constant(np.inf)
    for row in range(bounds[k], bounds[k + 1]):
        s = src.constant(0)
        for f in range(13):
            s = s + vh[row][f] * feat[f]
        low = src.minimum(low, s)
    return src.function(f"height_{k}", "feat, zero", [low + t["base_height"]])


HEIGHT = ("@triton.jit\ndef height(feat, zero, K: tl.constexpr):\n"
          + "".join(f"    {'if' if k == 1 else 'elif'} K == {k - 1}:\n"
                    f"        out = height_{k}(feat, zero)\n" for k in range(1, 7))
          + "    return out[0]\n")
"""``height(feat, zero, K)``: moving link K + 1's exact height, K a compile-time index."""


def _lower_bounds(src: Source, t: dict[str, Any]) -> str:
    """``lower_bounds(known, q, q_ref, zero)``: ``known[k] - sum_i L[i, k] |q[i] -
    q_ref[i]|``, the Lipschitz bounds of the link heights at ``q`` from the exact ones at
    ``q_ref``, subtracted term by term (numba's ``step_copy``)."""
    known, q, q_ref = ([src.input(f"{x}[{k}]") for k in range(6)]
                       for x in ("known", "q", "q_ref"))
    L = t["lipschitz"]
    moved = [src.call("tl.abs", q[i] - q_ref[i]) if any(not L[i][k].equals(0)
                                                         for k in range(6)) else None
             for i in range(6)]
    out = []
    for k in range(6):
        bound = known[k]
        for i in range(6):
            if not L[i][k].equals(0):
                bound = bound - L[i][k] * moved[i]
        out.append(bound)
    return src.function("lower_bounds", "known, q, q_ref, zero", out)


def _tool(src: Source, t: dict[str, Any]) -> str:
    """``tool(q, zero)``: tool0's world position (m): numba's ``placements`` and
    ``tool_position``."""
    q = [src.input(f"q[{k}]") for k in range(6)]
    R = _placements(q, t["rot0"], t["axis"])
    one, zero = src.constant(1.0), src.constant(0)
    Ro = [one, zero, zero, zero, one, zero, zero, zero, one]
    x = [zero, zero, zero]
    for i in range(6):
        Ri, pi = R[i], t["p"][i]
        x = [x[r] + Ro[3 * r] * pi[0] + Ro[3 * r + 1] * pi[1] + Ro[3 * r + 2] * pi[2]
             for r in range(3)]
        Ro = [Ro[3 * r] * Ri[k] + Ro[3 * r + 1] * Ri[3 + k] + Ro[3 * r + 2] * Ri[6 + k]
              for r in range(3) for k in range(3)]
    tp = t["tool_pos"]
    out = [x[r] + Ro[3 * r] * tp[0] + Ro[3 * r + 1] * tp[1] + Ro[3 * r + 2] * tp[2]
           for r in range(3)]
    out[2] = out[2] + t["base_height"]
    return src.function("tool", "q, zero", out)


GENERATED = ("accel", "features", "height", "lower_bounds", "tool")
"""The generated functions, in :attr:`TritonModel.functions`' order."""


@functools.lru_cache(maxsize=8)
def generate(tables: tuple[tuple[str, Any], ...], cast_name: str) -> tuple[str, tuple[Any, ...]]:
    """The generated source for the model ``tables`` (name, nested tuples of floats) in
    ``cast_name``'s type, and its :data:`GENERATED` functions (compiled from it, the source
    registered in :mod:`linecache` so that Triton reads it like a file's)."""
    cast = {"float64": np.float64, "float32": np.float32}[cast_name]

    def values(src: Source, x: Any) -> Any:
        if isinstance(x, tuple):
            return [values(src, v) for v in x]
        return src.constant(x)

    def part(fn: Any, *args: Any) -> str:
        src = Source(cast)
        t = {k: v if k in ("bounds", "gravity_comp") else values(src, v) for k, v in tables}
        return fn(src, t, *args)

    parts = [part(_accel), part(_features), *(part(_link_height, k) for k in range(1, 7)),
             HEIGHT, part(_lower_bounds), part(_tool)]
    text = "import triton\nimport triton.language as tl\n\n\n" + "\n\n".join(parts)
    filename = f"<envs.physics.triton_kernel {hashlib.sha1(text.encode()).hexdigest()[:16]}>"
    linecache.cache[filename] = (len(text), None, text.splitlines(True), filename)
    namespace: dict[str, Any] = {"__name__": f"{__name__}.generated"}
    exec(compile(text, filename, "exec"), namespace)  # our own generated code
    return text, tuple(namespace[name] for name in GENERATED)


@triton.jit
def constants(values, dtype: tl.constexpr, N: tl.constexpr):
    """``values[0 .. N - 1]`` (a constexpr tuple of Python floats) as N scalars of ``dtype``,
    each exact (``tl.full``; a bare Python float in Triton arithmetic is a float32 constant)."""
    out = ()
    for k in tl.static_range(N):
        out = out + (tl.full([], values[k], dtype),)
    return out


@triton.jit
def step_kernel(q_ptr, w_ptr, hb_ptr, bias_ptr, free_ptr, dw_ptr, contact_ptr, limit_ptr,
                tool_ptr, B, W_MAX: tl.constexpr, Q_MID: tl.constexpr, Q_HALF: tl.constexpr,
                MARGIN: tl.constexpr, SUBSTEPS: tl.constexpr, BLOCK: tl.constexpr,
                ACCEL: tl.constexpr, FEATURES: tl.constexpr, HEIGHT: tl.constexpr,
                LOWER_BOUNDS: tl.constexpr, TOOL: tl.constexpr):
    """One control step of copies ``pid BLOCK ..``: :func:`launch`'s (the upper-case
    arguments are :class:`TritonModel`'s constants and generated functions)."""
    offs = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    valid = offs < B
    dt = q_ptr.dtype.element_ty
    w_max = constants(W_MAX, dt, 6)
    q_mid = constants(Q_MID, dt, 6)
    q_half = constants(Q_HALF, dt, 6)
    margin = tl.full([], MARGIN, dt)

    q = load_lanes(q_ptr, offs, valid, 6)
    w = load_lanes(w_ptr, offs, valid, 6)
    known = load_lanes(hb_ptr, offs, valid, 6)
    free = tl.load(free_ptr + offs, mask=valid, other=6)
    zero = tl.zeros_like(q[0])  # a lane vector of the kernel's type
    q_ref = q
    active = valid
    hit_plane = offs < 0
    hit_limit = offs < 0
    for _ in range(SUBSTEPS):
        # read each substep (volatile: not hoisted), not held in registers through the loop
        bias = load_lanes(bias_ptr, offs, valid, 6, True)
        a = ACCEL(q, w, bias, free, zero)
        w1 = ()
        q1 = ()
        limit = offs < 0
        for k in tl.static_range(6):
            wk = tl.minimum(tl.maximum(w[k] + a[k], -w_max[k]), w_max[k])
            qk = q[k] + wk
            limit = limit | (tl.abs(qk - q_mid[k]) > q_half[k])
            w1 = w1 + (wk,)
            q1 = q1 + (qk,)
        # the plane: link k's exact height only where its bound from the last exact ones
        # fails, computed for a block when one of its active lanes needs it
        bound = LOWER_BOUNDS(known, q1, q_ref, zero)
        fails = ()
        unsure = offs < 0
        for k in tl.static_range(6):
            fails = fails + ((bound[k] < margin) & active,)
            unsure = unsure | fails[k]
        plane = offs < 0
        if tl.max(unsure.to(tl.int32), 0) > 0:
            feat = FEATURES(q1, zero)
            known2 = ()
            for k in tl.static_range(6):
                # an unsure lane's bounds restart at q1: exact where they failed
                kk = tl.where(unsure, bound[k], known[k])
                if tl.max(fails[k].to(tl.int32), 0) > 0:
                    h = HEIGHT(feat, zero, k)
                    kk = tl.where(fails[k], h, kk)
                    plane = plane | (fails[k] & (h < margin))
                known2 = known2 + (kk,)
            ref2 = ()
            for k in tl.static_range(6):
                ref2 = ref2 + (tl.where(unsure, q1[k], q_ref[k]),)
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
    known = LOWER_BOUNDS(known, q, q_ref, zero)
    tool = TOOL(q, zero)
    store_lanes(q_ptr, offs, valid, q, 6)
    store_lanes(hb_ptr, offs, valid, known, 6)
    store_lanes(tool_ptr, offs, valid, tool, 3)
    # the old w read again after those stores (so that it is not merged with the first read
    # and held in registers through the loop)
    w0 = load_lanes(w_ptr, offs, valid, 6)
    dw = ()
    for k in tl.static_range(6):
        dw = dw + (w[k] - w0[k],)
    store_lanes(w_ptr, offs, valid, w, 6)
    store_lanes(dw_ptr, offs, valid, dw, 6)
    tl.store(contact_ptr + offs, hit_plane, mask=valid)
    tl.store(limit_ptr + offs, hit_limit, mask=valid)
