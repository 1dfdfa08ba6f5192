"""Closed-form, batched UR5 kinematics for numpy arrays and torch tensors.

The formulas follow the chain in :class:`ur5kin.model.UR5Geometry`, with every length read off the
Pinocchio model; Pinocchio stays the reference they are tested against. Joints 2-4 share one
pitch axis, so in the frame turned by the shoulder pan (the "pan frame") the arm is planar:
``a = q2 + pi/2``, ``b = a + q3`` and ``c = b + q4 + pi/2`` are the absolute pitches of the upper
arm, the forearm and the wrist. One implementation serves numpy and torch: ``xp`` is the array
module of the input.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import numpy as np

from ur5kin.model import UR5Geometry, geometry

CHUNK = 16384
"""Rows per block in the numpy path: small enough that the temporaries stay in cache."""

TORCH_CPU_CHUNK = 65536
"""Rows per block for CPU tensors: cache-sized, yet large enough for torch's intra-op threads."""


def array_module(x: Any) -> ModuleType:
    """``numpy`` for numpy input, ``torch`` for a torch tensor (imported only then)."""
    if isinstance(x, np.ndarray):
        return np
    torch = torch_if_tensor(x)
    return torch if torch is not None else np


def torch_if_tensor(x: Any) -> ModuleType | None:
    mod = type(x).__module__
    if mod.startswith("torch"):
        import torch

        if isinstance(x, torch.Tensor):
            return torch
    return None


def _pitches(q: Any, g: UR5Geometry) -> tuple[Any, Any, Any]:
    a = q[..., 1] + g.lift_offset
    b = a + q[..., 2]
    c = b + q[..., 3] + g.wrist_offset
    return a, b, c


def position(q: Any, g: UR5Geometry | None = None) -> Any:
    """tool0 position for a batch of configurations, in closed form.

    Parameters
    ----------
    q : (..., 6) float ndarray or tensor, rad
    g : UR5Geometry, optional
        Link offsets; the URDF's by default.

    Returns
    -------
    p : (..., 3) float, m, ``base_link`` frame; same array type, dtype and device as ``q``.
    """
    g = geometry() if g is None else g
    xp = array_module(q)
    a, b, c = _pitches(q, g)
    s1, c1 = xp.sin(q[..., 0]), xp.cos(q[..., 0])
    sa, ca = xp.sin(a), xp.cos(a)
    sb, cb = xp.sin(b), xp.cos(b)
    sc, cc = xp.sin(c), xp.cos(c)
    s5, c5 = xp.sin(q[..., 4]), xp.cos(q[..., 4])
    d6s5 = g.wrist_3 * s5
    # Pan frame: planar arm in (x, z), constant lateral offset plus the tool's swing in y.
    x = g.upper_arm * sa + g.forearm * sb + g.wrist_2 * sc - d6s5 * cc
    y = g.lateral + g.wrist_3 * c5
    z = g.upper_arm * ca + g.forearm * cb + g.wrist_2 * cc + d6s5 * sc
    return xp.stack([c1 * x - s1 * y, s1 * x + c1 * y, z + g.d1], axis=-1)


def _rot_y(s: Any, c: Any, xp: ModuleType) -> Any:
    zero, one = xp.zeros_like(s), xp.ones_like(s)
    return xp.stack(
        [xp.stack([c, zero, s], axis=-1), xp.stack([zero, one, zero], axis=-1),
         xp.stack([-s, zero, c], axis=-1)], axis=-2)


def _rot_z(s: Any, c: Any, xp: ModuleType) -> Any:
    zero, one = xp.zeros_like(s), xp.ones_like(s)
    return xp.stack(
        [xp.stack([c, -s, zero], axis=-1), xp.stack([s, c, zero], axis=-1),
         xp.stack([zero, zero, one], axis=-1)], axis=-2)


def _as_const(values: Any, like: Any, xp: ModuleType) -> Any:
    if xp is np:
        return np.asarray(values, dtype=like.dtype)
    return xp.as_tensor(values, dtype=like.dtype, device=like.device)


def _homogeneous(rot: Any, pos: Any, xp: ModuleType) -> Any:
    top = xp.concatenate([rot, pos[..., :, None]], axis=-1)
    bottom = xp.zeros_like(top[..., :1, :])
    bottom[..., 0, 3] = 1.0
    return xp.concatenate([top, bottom], axis=-2)


def link_poses(q: Any, g: UR5Geometry | None = None) -> Any:
    """Poses of the 7 links and of tool0 for a batch of configurations, in closed form.

    Parameters
    ----------
    q : (..., 6) float ndarray or tensor, rad

    Returns
    -------
    T : (..., 8, 4, 4) float, m
        Homogeneous transforms in ``base_link`` of base_link, shoulder_link, upper_arm_link,
        forearm_link, wrist_1_link, wrist_2_link, wrist_3_link and tool0 (the first seven are
        Pinocchio's ``data.oMi``).
    """
    g = geometry() if g is None else g
    xp = array_module(q)
    a, b, c = _pitches(q, g)
    sin, cos = xp.sin, xp.cos
    sa, ca, sb, cb, sc, cc = sin(a), cos(a), sin(b), cos(b), sin(c), cos(c)
    s5, c5 = sin(q[..., 4]), cos(q[..., 4])
    ry_a, ry_b, ry_c = _rot_y(sa, ca, xp), _rot_y(sb, cb, xp), _rot_y(sc, cc, xp)
    r5 = ry_c @ _rot_z(s5, c5, xp)
    r6 = r5 @ _rot_y(sin(q[..., 5]), cos(q[..., 5]), xp)
    eye = xp.zeros_like(ry_a) + _as_const(np.eye(3), ry_a, xp)
    tool_rot = r6 @ _as_const(g.tool_rotation, ry_a, xp)
    # Pan-frame rotations of shoulder .. tool0; the base link does not turn with joint 1.
    rot_pan = xp.stack([eye, ry_a, ry_b, ry_c, r5, r6, tool_rot], axis=-3)

    zero = xp.zeros_like(sa)
    so, ye = zero + g.shoulder_offset, zero + g.shoulder_offset + g.elbow_offset
    x3, z3 = g.upper_arm * sa, g.upper_arm * ca
    x4, z4 = x3 + g.forearm * sb, z3 + g.forearm * cb
    yw = zero + g.lateral
    x6, z6 = x4 + g.wrist_2 * sc, z4 + g.wrist_2 * cc
    d6s5 = g.wrist_3 * s5
    pos_pan = xp.stack([
        xp.stack([zero, zero, zero], axis=-1),
        xp.stack([zero, so, zero], axis=-1),
        xp.stack([x3, ye, z3], axis=-1),
        xp.stack([x4, ye, z4], axis=-1),
        xp.stack([x4, yw, z4], axis=-1),
        xp.stack([x6, yw, z6], axis=-1),
        xp.stack([x6 - d6s5 * cc, yw + g.wrist_3 * c5, z6 + d6s5 * sc], axis=-1),
    ], axis=-2)

    rz = _rot_z(sin(q[..., 0]), cos(q[..., 0]), xp)[..., None, :, :]
    rot = rz @ rot_pan
    pos = (rz @ pos_pan[..., :, :, None])[..., 0]
    pos[..., 2] += g.d1
    links = _homogeneous(rot, pos, xp)
    base = xp.zeros_like(links[..., :1, :, :]) + _as_const(np.eye(4), links, xp)
    return xp.concatenate([base, links], axis=-3)


def tool_pose(q: Any, g: UR5Geometry | None = None) -> Any:
    """tool0 pose, ``(..., 4, 4)`` in ``base_link``; see :func:`link_poses`."""
    return link_poses(q, g)[..., -1, :, :]


JOINT_AXES = np.array([[0, 0, 1], [0, 1, 0], [0, 1, 0], [0, 1, 0], [0, 0, 1], [0, 1, 0]], float)
"""Axis of joint i in the frame of link i (z for shoulder_pan and wrist_2, y otherwise)."""


def jacobian_from_poses(poses: Any) -> Any:
    """Geometric Jacobian of tool0 from :func:`link_poses` output.

    Parameters
    ----------
    poses : (..., 8, 4, 4) float
        Output of :func:`link_poses`.

    Returns
    -------
    J : (..., 6, 6) float
        Rows 0-2 map joint rates (rad/s) to the linear velocity of the tool0 origin (m/s), rows
        3-5 to its angular velocity (rad/s); both in ``base_link`` axes (Pinocchio's
        ``LOCAL_WORLD_ALIGNED``).
    """
    xp = array_module(poses)
    rot = poses[..., 1:7, :3, :3]
    axes = (rot @ _as_const(JOINT_AXES, poses, xp)[..., None])[..., 0]
    origins = poses[..., 1:7, :3, 3]
    tool = poses[..., 7:8, :3, 3]
    linear = xp.linalg.cross(axes, tool - origins) if xp is not np else np.cross(
        axes, tool - origins)
    return xp.concatenate([xp.swapaxes(linear, -1, -2), xp.swapaxes(axes, -1, -2)], axis=-2)


def chunked(func: Any, q: Any, out_tail: tuple[int, ...], block: int | None = None,
            dtype: Any = None) -> Any:
    """Apply a batched ``func`` to ``q (..., 6)`` in cache-sized blocks of rows.

    numpy arrays go in blocks of ``block`` rows (:data:`CHUNK` by default), CPU tensors in
    blocks of :data:`TORCH_CPU_CHUNK`; GPU tensors in one piece. The output has ``q``'s dtype
    unless ``dtype`` is given (numpy only: a boolean answer, for instance).
    """
    xp = array_module(q)
    flat = q.reshape(-1, q.shape[-1])
    on_cpu = xp is np or flat.device.type == "cpu"
    if not on_cpu:
        block = len(flat)
    elif xp is not np:
        block = TORCH_CPU_CHUNK
    elif block is None:
        block = CHUNK
    if len(flat) <= block:
        return func(flat).reshape((*q.shape[:-1], *out_tail))
    if xp is np:
        out = np.empty((len(flat), *out_tail), dtype=q.dtype if dtype is None else dtype)
    else:
        out = xp.empty((len(flat), *out_tail), dtype=q.dtype, device=q.device)
    for start in range(0, len(flat), block):
        out[start : start + block] = func(flat[start : start + block])
    return out.reshape((*q.shape[:-1], *out_tail))
