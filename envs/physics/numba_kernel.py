"""The numba backend: a whole control step of B arm copies in one compiled call.

The physics of :mod:`envs.physics.pinocchio_loop` (equations in ``results/dynamics/README.md``)
written as scalar loops: per copy, every substep (PD + gravity compensation, effort clip,
Featherstone's articulated-body algorithm, velocity clip, semi-implicit Euler) and the stop checks,
stopping a copy at its first invalid substep. :func:`step_copy` is one copy's step (no allocation,
no Python object); :func:`control_step` the CPU batch loop around it. The chain and plane tables are
:mod:`envs.physics.model`'s; the tests compare :func:`aba` with ``pin.aba`` and
:class:`NumbaDynamics` with the Pinocchio loop. The kernels are compiled on first use and cached on
disk (``cache=True``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

import ur5kin
from envs.checks import validate
from envs.physics.model import (
    NJ,
    arm_model,
    check_aba_batch,
    moving_link_heights,
    put_at_rest,
    require_kernels,
    tool_offset,
    ur5_chain,
    ur5_plane,
)
from ur5kin.checks import COUNT, integer, joint_count

if TYPE_CHECKING:
    from envs.spec import TaskSpec

try:
    import numba
except ImportError:  # the fast path is optional: envs.batched falls back to PinocchioDynamics
    numba = None

DTYPES = {"float64": np.float64, "float32": np.float32}
"""Floating-point types the kernels are compiled for."""

PARALLEL_CHUNKS_PER_THREAD = 4
"""Blocks of copies per thread when stepping on several threads: copies that stop early (on the
plane) finish sooner, and smaller blocks even the threads' loads out."""


def available() -> bool:
    """Whether the compiled path can run (numba is installed)."""
    return numba is not None


# ---------------------------------------------------------------------------- kernels
def _njit(func: Any) -> Any:
    """``numba.njit(cache=True)`` when numba is there; the plain function otherwise."""
    return numba.njit(cache=True, nogil=True)(func) if numba is not None else func


@_njit
def placements(q, rot0, axis, R):  # pragma: no cover - compiled
    """``R[i] = rot0[i] Rot(axis[i], q[i])``: each body's rotation in its parent's frame."""
    for i in range(6):
        s, c = np.sin(q[i]), np.cos(q[i])
        ax, ay, az = axis[i, 0], axis[i, 1], axis[i, 2]
        t = 1.0 - c
        # Rodrigues: c I + t a a^T + s [a]x
        r00, r01, r02 = c + t * ax * ax, t * ax * ay - s * az, t * ax * az + s * ay
        r10, r11, r12 = t * ax * ay + s * az, c + t * ay * ay, t * ay * az - s * ax
        r20, r21, r22 = t * ax * az - s * ay, t * ay * az + s * ax, c + t * az * az
        for r in range(3):
            a0, a1, a2 = rot0[i, r, 0], rot0[i, r, 1], rot0[i, r, 2]
            R[i, r, 0] = a0 * r00 + a1 * r10 + a2 * r20
            R[i, r, 1] = a0 * r01 + a1 * r11 + a2 * r21
            R[i, r, 2] = a0 * r02 + a1 * r12 + a2 * r22


@_njit
def _motion_inv(R, p, m, out):  # pragma: no cover - compiled
    """``out = M^-1 m`` for a motion ``m = [v; w]`` in the parent frame, ``M = (R, p)``."""
    w0, w1, w2 = m[3], m[4], m[5]
    # linear velocity at the child origin: v + w x p, then rotated into the child frame
    l0 = m[0] + w1 * p[2] - w2 * p[1]
    l1 = m[1] + w2 * p[0] - w0 * p[2]
    l2 = m[2] + w0 * p[1] - w1 * p[0]
    for r in range(3):
        out[r] = R[0, r] * l0 + R[1, r] * l1 + R[2, r] * l2
        out[3 + r] = R[0, r] * w0 + R[1, r] * w1 + R[2, r] * w2


@_njit
def _force_act(R, p, f, out):  # pragma: no cover - compiled
    """``out += M f`` for a force ``f = [f; n]`` in the child frame, ``M = (R, p)``."""
    f0 = R[0, 0] * f[0] + R[0, 1] * f[1] + R[0, 2] * f[2]
    f1 = R[1, 0] * f[0] + R[1, 1] * f[1] + R[1, 2] * f[2]
    f2 = R[2, 0] * f[0] + R[2, 1] * f[1] + R[2, 2] * f[2]
    out[0] += f0
    out[1] += f1
    out[2] += f2
    out[3] += R[0, 0] * f[3] + R[0, 1] * f[4] + R[0, 2] * f[5] + p[1] * f2 - p[2] * f1
    out[4] += R[1, 0] * f[3] + R[1, 1] * f[4] + R[1, 2] * f[5] + p[2] * f0 - p[0] * f2
    out[5] += R[2, 0] * f[3] + R[2, 1] * f[4] + R[2, 2] * f[5] + p[0] * f1 - p[1] * f0


@_njit
def _gravity_torque(R, p, axis, inertia, grav, acc, force, out):  # pragma: no cover
    """``out = g(q)``: RNEA at rest (v = 0, qdd = 0) for the placements ``R`` of ``q``."""
    for k in range(6):
        acc[0, k] = 0.0
    for k in range(3):
        acc[0, k] = -grav[k]  # the base accelerates up: gravity as a fictitious force
    for i in range(6):
        _motion_inv(R[i], p[i], acc[i], acc[i + 1])
        for r in range(6):
            s = 0.0
            for k in range(6):
                s += inertia[i, r, k] * acc[i + 1, k]
            force[i, r] = s
    for i in range(5, -1, -1):
        out[i] = axis[i, 0] * force[i, 3] + axis[i, 1] * force[i, 4] + axis[i, 2] * force[i, 5]
        if i > 0:
            _force_act(R[i], p[i], force[i], force[i - 1])


@_njit
def _rotate_blocks(R, ia, M, out):  # pragma: no cover - compiled
    """``out``'s blocks A', B', C' = R A R^T, R B R^T, R C R^T of ``ia = [A, B; B^T, C]``."""
    for ro, co in ((0, 0), (0, 3), (3, 3)):
        for r in range(3):
            for k in range(3):
                M[r, k] = R[r, 0] * ia[ro, co + k] + R[r, 1] * ia[ro + 1, co + k] + \
                    R[r, 2] * ia[ro + 2, co + k]
        for r in range(3):
            for k in range(3):
                out[ro + r, co + k] = M[r, 0] * R[k, 0] + M[r, 1] * R[k, 1] + M[r, 2] * R[k, 2]


@_njit
def _shift_into(p, Y, S, parent):  # pragma: no cover - compiled
    """``parent += [A', B' - A'P; (B' - A'P)^T, C' + P B' + (P B')^T - P A' P]``, P = [p]x,
    for the rotated blocks in ``Y`` (``S (6, 6)`` scratch)."""
    p0, p1, p2 = p[0], p[1], p[2]
    for r in range(3):  # A'P
        S[r, 3] = Y[r, 1] * p2 - Y[r, 2] * p1
        S[r, 4] = Y[r, 2] * p0 - Y[r, 0] * p2
        S[r, 5] = Y[r, 0] * p1 - Y[r, 1] * p0
    for k in range(3):  # P B' and P (A'P)
        S[3, k] = p1 * Y[2, 3 + k] - p2 * Y[1, 3 + k]
        S[4, k] = p2 * Y[0, 3 + k] - p0 * Y[2, 3 + k]
        S[5, k] = p0 * Y[1, 3 + k] - p1 * Y[0, 3 + k]
        S[3, 3 + k] = p1 * S[2, 3 + k] - p2 * S[1, 3 + k]
        S[4, 3 + k] = p2 * S[0, 3 + k] - p0 * S[2, 3 + k]
        S[5, 3 + k] = p0 * S[1, 3 + k] - p1 * S[0, 3 + k]
    for r in range(3):
        for k in range(3):
            parent[r, k] += Y[r, k]
            top = Y[r, 3 + k] - S[r, 3 + k]
            parent[r, 3 + k] += top
            parent[3 + k, r] += top
            parent[3 + r, 3 + k] += Y[3 + r, 3 + k] + S[3 + r, k] + S[3 + k, r] - S[3 + r, 3 + k]


@_njit
def _aba(R, p, axis, inertia, armature, grav, qd, tau, vel, cb, IA, pA, U, D, u, X, Y, acc,
         qdd, free):  # pragma: no cover - compiled
    """Featherstone's articulated-body algorithm (Pinocchio's ``aba``): ``qdd`` for the
    placements ``R`` (of ``q``), velocities ``qd`` and torques ``tau``.

    Joints ``free .. 5`` are locked (``free = 6``: none): welded at their angles in ``R``, with
    ``qd = 0`` there (the caller's invariant), they carry their child's articulated inertia and
    bias force to the parent whole, get ``qdd = 0`` and ignore ``tau``: the dynamics of the
    chain whose last body is the rigid composite of the locked joints' bodies (Pinocchio's
    ``buildReducedModel``; tested against it and against the full model's ``M`` and ``h``).

    Scratch: ``vel, acc (7, 6)`` (row i + 1 is body i, row 0 the fixed base), ``cb, pA, U (6,
    6)``, ``IA (6, 6, 6)``, ``X, Y (6, 6)``, ``D, u (6,)``.
    """
    for k in range(6):
        vel[0, k] = 0.0
    # pass 1: velocities, bias accelerations c = v x (S qd), bias forces p = v x* (I v)
    for i in range(6):
        vi = vel[i + 1]
        _motion_inv(R[i], p[i], vel[i], vi)
        sx, sy, sz = axis[i, 0] * qd[i], axis[i, 1] * qd[i], axis[i, 2] * qd[i]
        vi[3] += sx
        vi[4] += sy
        vi[5] += sz
        # c = v x_m [0; s] = [v_lin x s; w x s]
        cb[i, 0] = vi[1] * sz - vi[2] * sy
        cb[i, 1] = vi[2] * sx - vi[0] * sz
        cb[i, 2] = vi[0] * sy - vi[1] * sx
        cb[i, 3] = vi[4] * sz - vi[5] * sy
        cb[i, 4] = vi[5] * sx - vi[3] * sz
        cb[i, 5] = vi[3] * sy - vi[4] * sx
        for r in range(6):
            s = 0.0
            for k in range(6):
                s += inertia[i, r, k] * vi[k]
                IA[i, r, k] = inertia[i, r, k]
            Y[0, r] = s  # h = I v
        # p = v x_f h = [w x h_lin; w x h_ang + v_lin x h_lin]
        h0, h1, h2, h3, h4, h5 = Y[0, 0], Y[0, 1], Y[0, 2], Y[0, 3], Y[0, 4], Y[0, 5]
        w0, w1, w2 = vi[3], vi[4], vi[5]
        pA[i, 0] = w1 * h2 - w2 * h1
        pA[i, 1] = w2 * h0 - w0 * h2
        pA[i, 2] = w0 * h1 - w1 * h0
        pA[i, 3] = w1 * h5 - w2 * h4 + vi[1] * h2 - vi[2] * h1
        pA[i, 4] = w2 * h3 - w0 * h5 + vi[2] * h0 - vi[0] * h2
        pA[i, 5] = w0 * h4 - w1 * h3 + vi[0] * h1 - vi[1] * h0
    # pass 2: articulated inertias and bias forces, tip to base
    inv_d = 0.0
    for i in range(5, -1, -1):
        moving = i < free  # a locked body rides on its parent whole: Ia = IA, pa = pA + IA c
        if moving:
            ax, ay, az = axis[i, 0], axis[i, 1], axis[i, 2]
            for r in range(6):
                U[i, r] = IA[i, r, 3] * ax + IA[i, r, 4] * ay + IA[i, r, 5] * az
            D[i] = U[i, 3] * ax + U[i, 4] * ay + U[i, 5] * az + armature[i]
            u[i] = tau[i] - (pA[i, 3] * ax + pA[i, 4] * ay + pA[i, 5] * az)
            if i == 0:
                break
            inv_d = 1.0 / D[i]
            for r in range(6):
                for k in range(6):
                    IA[i, r, k] -= U[i, r] * U[i, k] * inv_d
        # Ia = IA - U U^T / D (above); pa = pA + Ia c + U u / D, carried to the parent
        for r in range(6):
            s = pA[i, r]
            if moving:
                s += U[i, r] * u[i] * inv_d
            for k in range(6):
                s += IA[i, r, k] * cb[i, k]
            Y[1, r] = s
        _force_act(R[i], p[i], Y[1], pA[i - 1])
        # IA[parent] += X^T Ia X, X = [R^T, -R^T [p]x; 0, R^T] the parent-to-child motion map,
        # by 3x3 blocks: Ia = [A, B; B^T, C] rotated, A' = R A R^T (and B', C'), then shifted
        # by P = [p]x: [A', B' - A'P; (.)^T, C' + P B' + (P B')^T - P A' P].
        _rotate_blocks(R[i], IA[i], X, Y)
        _shift_into(p[i], Y, X, IA[i - 1])
    # pass 3: accelerations, base to tip (the base accelerates up: gravity)
    for k in range(6):
        acc[0, k] = 0.0
    for k in range(3):
        acc[0, k] = -grav[k]
    for i in range(6):
        ai = acc[i + 1]
        _motion_inv(R[i], p[i], acc[i], ai)
        for k in range(6):
            ai[k] += cb[i, k]
        if i >= free:
            qdd[i] = 0.0
            continue
        s = u[i]
        for k in range(6):
            s -= U[i, k] * ai[k]
        qdd[i] = s / D[i]
        ai[3] += axis[i, 0] * qdd[i]
        ai[4] += axis[i, 1] * qdd[i]
        ai[5] += axis[i, 2] * qdd[i]


@_njit
def _aba_scratch(dt):  # pragma: no cover - compiled
    """The scratch of :func:`_aba` and :func:`_gravity_torque` in type ``dt``: ``R (6, 3, 3)``,
    ``vel, acc (7, 6)``, ``cb, pA, U (6, 6)``, ``IA (6, 6, 6)``, ``X, Y (6, 6)``, ``D, u (6,)``,
    ``force (6, 6)``."""
    return (np.empty((6, 3, 3), dt), np.empty((7, 6), dt), np.empty((7, 6), dt),
            np.empty((6, 6), dt), np.empty((6, 6), dt), np.empty((6, 6), dt),
            np.empty((6, 6, 6), dt), np.empty((6, 6), dt), np.empty((6, 6), dt), np.empty(6, dt),
            np.empty(6, dt), np.empty((6, 6), dt))


@_njit
def _aba_batch(q, qd, tau, rot0, p, axis, inertia, armature, grav, out, free
               ):  # pragma: no cover - compiled
    """``out[b] = aba(q[b], qd[b], tau[b])``, joints ``free ..`` locked (:func:`_aba`)."""
    R, vel, acc, cb, pA, U, IA, X, Y, D, u, _ = _aba_scratch(q.dtype)
    for b in range(q.shape[0]):
        placements(q[b], rot0, axis, R)
        _aba(R, p, axis, inertia, armature, grav, qd[b], tau[b], vel, cb, IA, pA, U, D, u, X, Y,
             acc, out[b], free)


def _batch(x: Any, name: str, dtype: Any) -> np.ndarray:
    """``x`` as a C-contiguous ``(B, 6)`` array of ``dtype``; ValueError otherwise."""
    arr = np.ascontiguousarray(x, dtype=dtype)
    if arr.ndim != 2 or arr.shape[1] != NJ or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a finite (B, 6) array; got shape {arr.shape}")
    return arr


def dtype_name(dtype: Any) -> str:
    name = np.dtype(dtype).name
    if name not in DTYPES:
        raise ValueError(f"dtype must be one of {sorted(DTYPES)}; got {name!r}")
    return name


def aba(q: Any, v: Any, tau: Any, dtype: Any = np.float64, free: int = NJ) -> np.ndarray:
    """Joint accelerations of B copies of the UR5 (Pinocchio's ``aba`` for each row), batched.

    Parameters
    ----------
    q : (B, 6) float, rad
    v : (B, 6) float, rad/s
        Zero in the locked joints' columns.
    tau : (B, 6) float, N m
    dtype : float64 or float32
        The arithmetic of the kernel (and of the result).
    free : int, 1..6
        Joints 1..free move; joints free+1..6 are locked at their angles in ``q``
        (``TaskSpec.held_joints == "locked"``; 6: none locked).

    Returns
    -------
    a : (B, 6) float, rad/s^2
        ``M(q)^-1 (tau - C(q, v) v - g(q))`` under the model's gravity; with locked joints,
        ``M_ff^-1 (tau_f - h_f(q, v))`` in the free columns (``M_ff`` the free joints' block)
        and 0 in the locked ones.

    Raises
    ------
    ValueError
        For arrays of another shape, non-finite values, a ``free`` outside 1..6, or a nonzero
        velocity of a locked joint.
    """
    free = joint_count(free, "free")
    cast = DTYPES[dtype_name(dtype)]
    chain = ur5_chain().astype(cast)
    q, v, tau = _batch(q, "q", cast), _batch(v, "v", cast), _batch(tau, "tau", cast)
    check_aba_batch(q, v, tau, free)
    out = np.empty_like(q)
    _aba_batch(q, v, tau, chain.rotation, chain.translation, chain.axis, chain.inertia,
               chain.armature, chain.gravity, out, free)
    return out


@_njit
def copy_link_heights(q, vh, bounds, lift, wrist, base_height, feat, out
                  ):  # pragma: no cover - compiled
    """``out[k - 1]``: exact lowest point (m, world z) of moving link k = 1..6 at ``q``.

    The features and the product of :func:`ur5kin.link_heights`, written out.
    """
    a = q[1] + lift
    b = a + q[2]
    c = b + q[3] + wrist
    sc, cc = np.sin(c), np.cos(c)
    s5, c5, s6, c6 = np.sin(q[4]), np.cos(q[4]), np.sin(q[5]), np.cos(q[5])
    feat[0] = 1.0
    feat[1], feat[2] = np.sin(a), np.cos(a)
    feat[3], feat[4] = np.sin(b), np.cos(b)
    feat[5], feat[6] = sc, cc
    feat[7] = sc * c5
    feat[8] = sc * s5
    feat[9] = feat[7] * c6
    feat[10] = cc * s6
    feat[11] = cc * c6
    feat[12] = feat[7] * s6
    for k in range(1, 7):
        low = np.inf
        for row in range(bounds[k], bounds[k + 1]):
            s = 0.0
            for f in range(13):
                s += vh[row, f] * feat[f]
            low = min(low, s)
        out[k - 1] = low + base_height


@_njit
def tool_position(R, p, tool_pos, base_height, out):  # pragma: no cover - compiled
    """``out``: tool0's world position (m) for the placements ``R``; base at base_height.

    ``tool_pos (3,)`` m: the tool frame's origin in joint 6's frame."""
    # oMi = oMi-1 liMi, accumulated as (Ro, po); the tool: po + Ro tool_pos
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0
    x, y, z = 0.0, 0.0, 0.0
    for i in range(6):
        Ri, pi = R[i], p[i]
        x, y, z = (x + r00 * pi[0] + r01 * pi[1] + r02 * pi[2],
                   y + r10 * pi[0] + r11 * pi[1] + r12 * pi[2],
                   z + r20 * pi[0] + r21 * pi[1] + r22 * pi[2])
        n00 = r00 * Ri[0, 0] + r01 * Ri[1, 0] + r02 * Ri[2, 0]
        n01 = r00 * Ri[0, 1] + r01 * Ri[1, 1] + r02 * Ri[2, 1]
        n02 = r00 * Ri[0, 2] + r01 * Ri[1, 2] + r02 * Ri[2, 2]
        n10 = r10 * Ri[0, 0] + r11 * Ri[1, 0] + r12 * Ri[2, 0]
        n11 = r10 * Ri[0, 1] + r11 * Ri[1, 1] + r12 * Ri[2, 1]
        n12 = r10 * Ri[0, 2] + r11 * Ri[1, 2] + r12 * Ri[2, 2]
        n20 = r20 * Ri[0, 0] + r21 * Ri[1, 0] + r22 * Ri[2, 0]
        n21 = r20 * Ri[0, 1] + r21 * Ri[1, 1] + r22 * Ri[2, 1]
        n22 = r20 * Ri[0, 2] + r21 * Ri[1, 2] + r22 * Ri[2, 2]
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = n00, n01, n02, n10, n11, n12, n20, n21, n22
    out[0] = x + r00 * tool_pos[0] + r01 * tool_pos[1] + r02 * tool_pos[2]
    out[1] = y + r10 * tool_pos[0] + r11 * tool_pos[1] + r12 * tool_pos[2]
    out[2] = z + r20 * tool_pos[0] + r21 * tool_pos[1] + r22 * tool_pos[2] + base_height


@_njit
def step_copy(q, w, known, bias, kp, kd, effort, w_max, gravity_comp, substeps, q_mid, q_half,
               vh, bounds, lift, wrist, lipschitz, base_height, margin, rot0, p, axis,
               inertia, armature, grav, tool_pos, free, R, vel, acc, cb, pA, U, IA, X, Y, D, u,
               tau, g, a, force, q1, w1, q_ref, heights, feat, tool
               ):  # pragma: no cover - compiled
    """One control step of one copy, in place, in the time-scaled units of
    :mod:`envs.physics.model`: the step body, pure scalar and array arithmetic on the arrays it
    is given (no allocation, no Python object), the body of the CPU loop :func:`control_step`
    (and the reference of the Triton kernel, :mod:`envs.physics.triton_kernel`).

    ``substeps`` times ``tau = clip(bias - kp q - kd w + g(q), +-effort)``,
    ``w' = clip(w + aba(q, w, tau), +-w_max)``, ``q' = q + w'`` (joints ``free ..`` locked:
    their ``aba`` is 0 and their ``w`` stays 0, so they never move); a substep that leaves the
    joint limits ``|q - q_mid| > q_half`` or brings a moving link below ``margin`` (m, world
    z) is not taken: the copy stays at the last valid substep with ``w = 0`` and the rest of
    the step is skipped (the Pinocchio loop computes and discards it: the same answer).

    Parameters
    ----------
    q, w : (6,) float
        The copy's state (rad, rad per substep), advanced in place.
    known : (6,) float, m
        A lower bound of each moving link's height at ``q``, kept valid in place: link k's
        exact height is taken only when the Lipschitz bound of a substep cannot prove link k
        clear (then the other links' bounds restart from the same substep), so a check that
        skips never changes whether the step stops.
    bias : (6,) float
        The constant part of the scaled PD torque (command and held joints).
    tool : (3,) float
        Written: tool0's world position (m) after the step.
    R .. feat
        Scratch of :func:`_aba`, :func:`_gravity_torque` and :func:`copy_link_heights`.

    Returns
    -------
    hit_plane, hit_limit : bool
        Whether the step stopped on the plane, at a joint limit.
    """
    for k in range(6):
        q_ref[k] = q[k]
    hit_plane = False
    hit_limit = False
    for _ in range(substeps):
        placements(q, rot0, axis, R)
        for k in range(6):
            tau[k] = bias[k] - kp[k] * q[k] - kd[k] * w[k]
        if gravity_comp:
            _gravity_torque(R, p, axis, inertia, grav, acc, force, g)
            for k in range(6):
                tau[k] += g[k]
        for k in range(6):
            tau[k] = min(max(tau[k], -effort[k]), effort[k])
        _aba(R, p, axis, inertia, armature, grav, w, tau, vel, cb, IA, pA, U, D, u, X, Y,
             acc, a, free)
        for k in range(6):
            w1[k] = min(max(w[k] + a[k], -w_max[k]), w_max[k])
            q1[k] = q[k] + w1[k]
            if abs(q1[k] - q_mid[k]) > q_half[k]:
                hit_limit = True
        # the plane: exact heights only where the bound from the last exact ones fails
        unsure = False
        for k in range(6):
            bound = known[k]
            for i in range(6):
                bound -= lipschitz[i, k] * abs(q1[i] - q_ref[i])
            if bound < margin:
                unsure = True
        if unsure:  # the bounds restart at q1: link k's exact height where its bound failed
            copy_link_heights(q1, vh, bounds, lift, wrist, base_height, feat, heights)
            for k in range(6):
                bound = known[k]
                for i in range(6):
                    bound -= lipschitz[i, k] * abs(q1[i] - q_ref[i])
                if bound < margin:
                    known[k] = heights[k]
                    if heights[k] < margin:
                        hit_plane = True
                else:
                    known[k] = bound
            for k in range(6):
                q_ref[k] = q1[k]
        if hit_plane or hit_limit:
            for k in range(6):
                w[k] = 0.0  # stopped dead at the last valid substep
            break
        for k in range(6):
            q[k] = q1[k]
            w[k] = w1[k]
    for k in range(6):
        bound = known[k]
        for i in range(6):
            bound -= lipschitz[i, k] * abs(q[i] - q_ref[i])
        known[k] = bound
    placements(q, rot0, axis, R)
    tool_position(R, p, tool_pos, base_height, tool)
    return hit_plane, hit_limit


@_njit
def control_step(Q, W, bias, kp, kd, effort, w_max, gravity_comp, substeps, q_mid, q_half,
                 vh, bounds, lift, wrist, lipschitz, base_height, margin, clearance,
                 rot0, p, axis, inertia, armature, grav, tool_pos, dW, contact, limit_stop,
                 tool, free, first, stop):  # pragma: no cover - compiled
    """One control step of copies ``first .. stop - 1`` (:func:`step_copy` each): the batch
    loop and the scratch it lends the body. Writes ``Q, W`` (the new state), ``dW = W_new -
    W_old``, ``clearance`` (the height bounds), the stop flags and the tool's world position.
    ``free (B,)`` int: copy b's joints ``free[b] ..`` are locked (its task's
    :attr:`envs.physics.model.ArmModel.free`), so one call steps copies of different n_joints.
    """
    dt = Q.dtype
    R, vel, acc, cb, pA, U, IA, X, Y, D, u, force = _aba_scratch(dt)
    tau, g, a = np.empty(6, dt), np.empty(6, dt), np.empty(6, dt)
    q, w, q1, w1, q_ref = (np.empty(6, dt), np.empty(6, dt), np.empty(6, dt), np.empty(6, dt),
                           np.empty(6, dt))
    known, heights, feat = np.empty(6, dt), np.empty(6, dt), np.empty(13, dt)
    for b in range(first, stop):
        for k in range(6):
            q[k] = Q[b, k]
            w[k] = W[b, k]
            known[k] = clearance[b, k]
        contact[b], limit_stop[b] = step_copy(
            q, w, known, bias[b], kp, kd, effort, w_max, gravity_comp, substeps, q_mid, q_half,
            vh, bounds, lift, wrist, lipschitz, base_height, margin, rot0, p, axis, inertia,
            armature, grav, tool_pos, free[b], R, vel, acc, cb, pA, U, IA, X, Y, D, u, tau, g, a,
            force, q1, w1, q_ref, heights, feat, tool[b])
        for k in range(6):
            dW[b, k] = w[k] - W[b, k]
            Q[b, k] = q[k]
            W[b, k] = w[k]
            clearance[b, k] = known[k]


def _parallel_step(chunks, *args):  # pragma: no cover - compiled
    """:func:`control_step` over ``chunks`` blocks of copies, on numba's thread pool;
    ``args`` are its arguments before ``first, stop``."""
    num_copies = args[0].shape[0]
    size = (num_copies + chunks - 1) // chunks
    for c in numba.prange(chunks):
        control_step(*args, c * size, min(num_copies, (c + 1) * size))


if numba is not None:
    _parallel_step = numba.njit(cache=True, parallel=True)(_parallel_step)


@_njit
def tool_batch(Q, rows, rot0, p, axis, tool_pos, base_height, tool):  # pragma: no cover
    """``tool[b]``: tool0's world position (m) for ``Q[b]``, for each b in ``rows``."""
    R = np.empty((6, 3, 3), Q.dtype)
    for b in rows:
        placements(Q[b], rot0, axis, R)
        tool_position(R, p, tool_pos, base_height, tool[b])


def kernel_arguments(task: TaskSpec, arm: Any, chain: Any, plane: Any, tool_pos: np.ndarray,
                     cast: Any, state: tuple[np.ndarray, ...]) -> tuple[Any, ...]:
    """The arguments of :func:`control_step` before ``first, stop``, in the order
    :func:`step_copy` reads them per copy: ``state``'s arrays ``q, w, bias, height_bound, dw,
    contact, limit_stop, tool, free`` (row b of each ``(B, ...)`` array, written in place), and
    ``task``'s, ``arm``'s (the controller, as ``cast``), the chain's, the plane's, the tool's."""
    q, w, bias, height_bound, *outputs = state
    return (q, w, bias, *(x.astype(cast) for x in (arm.kp_eff, arm.kd_eff, arm.effort,
                                                     arm.w_max)),
            bool(task.gravity_compensation), task.substeps, arm.q_mid.astype(cast),
            arm.q_half.astype(cast), plane.vertex_heights, plane.bounds, plane.lift_offset,
            plane.wrist_offset, plane.lipschitz, float(task.base_height),
            float(task.plane_margin), height_bound, chain.rotation, chain.translation,
            chain.axis, chain.inertia, chain.armature, chain.gravity, tool_pos, *outputs)


# ---------------------------------------------------------------------------- the class
class NumbaDynamics:
    """B copies of the UR5 under the task's controller, one compiled call per control step: an
    :class:`envs.physics.Dynamics` (its parameters and attributes, and
    :class:`envs.physics.pinocchio_loop.PinocchioDynamics`' ``w`` and ``height_bound``; the
    same physics to rounding, tested against it), built for B > 1.

    Parameters
    ----------
    dtype : {"float64", "float32"}
        The kernel's arithmetic and the state's type. float32 trajectories drift from float64
        ones (the bounds are in the tests); the env uses float64.
    threads : int
        Threads of numba's pool that step the copies (1: the calling thread alone, no pool).
        Each copy is computed the same way whatever the count: results do not depend on it.

    Attributes
    ----------
    tool : (B, 3) float, m, world frame
        tool0's position now.
    bias : (B, 6) float
        The constant part of each copy's scaled PD torque in this step (the command's and the
        held joints').
    """

    def __init__(self, task: TaskSpec, num_copies: int = 1, dtype: str = "float64",
                 threads: int = 1) -> None:
        if not available():
            raise RuntimeError("NumbaDynamics needs numba (pip install numba); "
                               "envs.physics.pinocchio_loop.PinocchioDynamics is the path "
                               "without it")
        B = self.num_copies = COUNT("num_copies", num_copies)
        require_kernels(task, "NumbaDynamics")
        pool = numba.config.NUMBA_NUM_THREADS
        threads = integer(1, pool, note="numba's pool on this machine")("threads", threads)
        name = dtype_name(dtype)
        cast = DTYPES[name]
        self.task, self.dtype, self.threads = validate(task), name, threads
        arm = self.arm = arm_model(task)
        self._chain = arm.chain.astype(cast)
        self._tool_pos = tool_offset().astype(cast)
        self.bias = arm.initial_bias(B, cast)

        self.q = np.tile(arm.start_q, (B, 1)).astype(cast)
        self.w = np.zeros((B, NJ), dtype=cast)
        self._dw = np.zeros((B, NJ), dtype=cast)
        self.v = np.zeros((B, NJ), dtype=cast)
        self.acceleration = np.zeros((B, NJ), dtype=cast)
        self.contact = np.zeros(B, dtype=bool)
        self.limit_stop = np.zeros(B, dtype=bool)
        self.height_bound = np.tile(moving_link_heights(arm.start_q, task.base_height),
                                    (B, 1)).astype(cast)
        self.tool = np.zeros((B, 3), dtype=cast)
        self._update_tools(np.arange(B))
        self._args = kernel_arguments(task, arm, self._chain, ur5_plane(name), self._tool_pos,
                                      cast, (self.q, self.w, self.bias, self.height_bound,
                                             self._dw, self.contact, self.limit_stop, self.tool,
                                             np.full(B, arm.free, dtype=np.int64)))

    def _update_tools(self, rows: np.ndarray) -> None:
        c = self._chain
        tool_batch(self.q, rows.astype(np.int64), c.rotation, c.translation, c.axis,
                   self._tool_pos, float(self.task.base_height), self.tool)

    def reset(self, q: Any, index: Any = None) -> None:
        """Put copies at rest at configurations ``q`` (``q (6,)`` or ``(m, 6)`` rad, ``index``
        the copies; ``ValueError`` below the plane: :func:`envs.physics.model.rest_heights`)."""
        sel = put_at_rest(self, q, index)
        self._update_tools(np.arange(self.num_copies)[sel].reshape(-1))

    def step(self, command: np.ndarray) -> None:
        """:meth:`envs.physics.Dynamics.step`."""
        arm = self.arm
        np.multiply(arm.command_gain, command, out=self.bias[:, : self.task.n_joints])
        args = self._args
        if self.threads == 1:
            control_step(*args, 0, self.num_copies)
        else:
            numba.set_num_threads(self.threads)
            _parallel_step(min(self.num_copies, PARALLEL_CHUNKS_PER_THREAD * self.threads),
                           *args)
        np.multiply(self._dw, arm.w_to_accel, out=self.acceleration)
        np.multiply(self.w, arm.w_to_v, out=self.v)

    def tool_positions(self, out: np.ndarray) -> np.ndarray:
        """Write tool0's world position ``(B, 3)`` m (base at (0, 0, base_height)) into ``out``."""
        out[:] = self.tool
        return out


@_njit
def _heights_batch(q, vh, bounds, lift, wrist, base_height, out):  # pragma: no cover
    feat = np.empty(13, q.dtype)
    for b in range(q.shape[0]):
        copy_link_heights(q[b], vh, bounds, lift, wrist, base_height, feat, out[b])


def link_heights(q: Any, base_height: float, dtype: Any = np.float64) -> np.ndarray:
    """The kernel's plane check: lowest point ``(B, 6)`` (m, world z) of shoulder_link ..
    wrist_3_link for ``q (B, 6)`` rad, base_link ``base_height`` m above the plane
    (:func:`ur5kin.link_heights` without the fixed base link)."""
    name = dtype_name(dtype)
    plane = ur5_plane(name)
    q = _batch(q, "q", DTYPES[name])
    out = np.empty_like(q)
    _heights_batch(q, plane.vertex_heights, plane.bounds, plane.lift_offset, plane.wrist_offset,
                   float(ur5kin.check_base_height(base_height)), out)
    return out
