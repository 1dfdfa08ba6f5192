"""Analytic inverse kinematics of the UR5: full poses (up to 8 solutions) and positions.

Both solvers work in the pan frame of :mod:`ur5kin.closed_form`, where the wrist-3 origin has a
constant lateral offset (which fixes the shoulder pan up to two choices) and joints 2-4 form a
planar chain (two elbow choices). For a full pose the wrist-2 angle has two signs, giving 8.
Every candidate is checked by forward kinematics before it is returned.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ur5kin.checks import joint_array, pose_array
from ur5kin.closed_form import jacobian_from_poses, link_poses, position, tool_pose
from ur5kin.model import UR5Geometry, geometry

REACH_TOL = 1e-9
"""Slack (dimensionless, on a cosine or a sine) admitted when a pose sits on a reach boundary."""

SINGULAR_TOL = 1e-6
"""``|sin q5|`` below which the wrist is treated as singular (joints 4 and 6 parallel)."""

VERIFY_TOL = 1e-9
"""A candidate whose forward kinematics misses the target by more (m, or in rotation) is dropped."""

DUPLICATE_TOL = 1e-6
"""Solutions closer than this (rad, every joint) are reported once: at a singularity the two
branches meet, and their angles are only determined to about sqrt(machine eps)."""


def wrap(angle: Any) -> Any:
    """Wrap angles (rad) into [-pi, pi]; ValueError for what is not a number."""
    angle = np.asarray(angle, dtype=float)
    return np.arctan2(np.sin(angle), np.cos(angle))


def _shoulder_pans(px: Any, py: Any, lateral: Any) -> tuple[Any, Any, Any]:
    """Both pan angles that give a point ``lateral`` m off the arm plane; and where they exist.

    In the pan frame the point's y is ``-sin(q1) px + cos(q1) py = r sin(phi - q1)``.
    """
    r = np.hypot(px, py)
    ratio = np.divide(lateral, r, out=np.full_like(r, np.inf), where=r > 0)
    ok = np.abs(ratio) <= 1.0 + REACH_TOL
    alpha = np.arcsin(np.clip(ratio, -1.0, 1.0))
    phi = np.arctan2(py, px)
    return phi - alpha, phi - np.pi + alpha, ok


def _planar_two_link(x: Any, z: Any, l1: float, l2: Any, sign: float) -> tuple[Any, Any, Any]:
    """Angles of a planar two-link arm reaching (x, z); angles measured from +z towards +x.

    Returns the first link's angle, the relative angle of the second, and where they exist.
    """
    cos_rel = (x * x + z * z - l1 * l1 - l2 * l2) / (2.0 * l1 * l2)
    ok = np.abs(cos_rel) <= 1.0 + REACH_TOL
    rel = sign * np.arccos(np.clip(cos_rel, -1.0, 1.0))
    first = np.arctan2(x, z) - np.arctan2(l2 * np.sin(rel), l1 + l2 * np.cos(rel))
    return first, rel, ok


def ik(pose: Any) -> np.ndarray:
    """Every joint configuration that puts tool0 at ``pose``.

    Parameters
    ----------
    pose : (4, 4) float array_like
        Homogeneous transform of tool0 in ``base_link`` (translation in m).

    Returns
    -------
    q : (k, 6) float, rad, in [-pi, pi]
        The distinct solutions, ``0 <= k <= 8``; ``(0, 6)`` when the pose is out of reach.
        Each reproduces ``pose`` to better than :data:`VERIFY_TOL`. At a wrist singularity
        (``sin q5 = 0``: joints 4 and 6 parallel) the solutions form one-parameter families;
        per pan and wrist branch the member whose elbow is nearest a right angle is returned (so
        never more than 8). At the
        shoulder or elbow singularities two solutions coincide and are returned once.

    Raises
    ------
    ValueError
        When ``pose`` is not a single rigid transform.
    """
    target = pose_array(pose)
    if target.shape != (4, 4):
        raise ValueError(f"ik takes one pose of shape (4, 4); got shape {target.shape}")
    g = geometry()
    rot, pos = target[:3, :3], target[:3, 3]
    r6 = rot @ np.asarray(g.tool_rotation).T  # wrist_3_link orientation
    wrist3 = pos - g.wrist_3 * r6[:, 1]  # tool0 sits d6 along wrist_3's y axis
    px, py, pz = wrist3[0], wrist3[1], wrist3[2] - g.d1
    pan_a, pan_b, pan_ok = _shoulder_pans(np.array(px), np.array(py), g.lateral)
    if not pan_ok:
        return np.zeros((0, 6))

    solutions = []
    for q1 in (float(pan_a), float(pan_b)):
        c1, s1 = np.cos(q1), np.sin(q1)
        rz_t = np.array([[c1, s1, 0.0], [-s1, c1, 0.0], [0.0, 0.0, 1.0]])
        m = rz_t @ r6  # = Ry(c) Rz(q5) Ry(q6); its y row is (s5 c6, c5, s5 s6)
        x_pan = c1 * px + s1 * py
        for sign5 in (1.0, -1.0):
            # atan2 keeps q5 accurate near 0 and pi, where arccos(c5) loses half the digits.
            q5 = sign5 * np.arctan2(np.hypot(m[1, 0], m[1, 2]), m[1, 1])
            # Try the rotation's own (c, q6) first; the singular family only where it fails.
            for c, q6 in _wrist_pitch_and_q6(m, q5, x_pan, pz, g):
                # Wrist-1 origin in the arm plane: step back along the wrist-2 link.
                wx = x_pan - g.wrist_2 * np.sin(c)
                wz = pz - g.wrist_2 * np.cos(c)
                branch = []
                for sign3 in (1.0, -1.0):
                    a, q3, ok = _planar_two_link(wx, wz, g.upper_arm, g.forearm, sign3)
                    if ok:
                        q4 = c - a - q3 - g.wrist_offset
                        branch.append([q1, a - g.lift_offset, q3, q4, q5, q6])
                found = _verified(_polish(np.array(branch).reshape(-1, 6), target), target)
                if len(found):
                    solutions.extend(found)
                    break
    return _unique(np.array(solutions).reshape(-1, 6))


def _wrist_pitch_and_q6(
    m: np.ndarray, q5: float, x_pan: float, z_pan: float, g: UR5Geometry
) -> list[tuple[float, float]]:
    """Wrist pitch ``c`` and q6 from ``m = Ry(c) Rz(q5) Ry(q6)`` (pan-frame wrist-3 rotation).

    Away from the wrist singularity the rotation fixes both. At ``sin q5 = 0`` the axes of
    joints 4 and 6 are parallel and the rotation fixes only ``c + cos(q5) q6``; the wrist-3
    position then admits a one-parameter family; its members whose elbow is at a right angle (the
    best-conditioned ones) follow, to be tried in turn.
    """
    s5, c5 = np.sin(q5), np.cos(q5)
    rz5_t = np.array([[c5, s5, 0.0], [-s5, c5, 0.0], [0.0, 0.0, 1.0]])
    out = []
    if s5 != 0.0:
        # Dividing by a small s5 costs digits (error ~ eps / s5), so near the singularity the
        # family members below are offered too; the polish and the check keep the accurate ones.
        q6 = np.arctan2(m[1, 2] * np.sign(s5), m[1, 0] * np.sign(s5))
        c6, s6 = np.cos(q6), np.sin(q6)
        ry6_t = np.array([[c6, 0.0, -s6], [0.0, 1.0, 0.0], [s6, 0.0, c6]])
        ry_c = m @ ry6_t @ rz5_t
        out.append((float(np.arctan2(ry_c[0, 2], ry_c[0, 0])), float(q6)))
    if abs(s5) >= SINGULAR_TOL:
        return out
    n = m @ rz5_t  # ~ Ry(c + sign(c5) q6)
    psi = np.arctan2(n[0, 2], n[0, 0])
    reach2 = g.upper_arm**2 + g.forearm**2  # |wrist-1 origin|^2 at a right-angled elbow
    dist = np.hypot(x_pan, z_pan)
    cos_off = (dist**2 + g.wrist_2**2 - reach2) / (2.0 * g.wrist_2 * max(dist, 1e-12))
    off = np.arccos(np.clip(cos_off, -1.0, 1.0))
    heading = np.arctan2(x_pan, z_pan)
    family = [(float(c), float(np.sign(c5) * (psi - c))) for c in (heading + off, heading - off)]
    return out + family


POLISH_STEPS = 3
"""Newton steps that refine each analytic candidate against the target pose (quadratic)."""

POLISH_RCOND = 1e-6
"""Relative singular-value cut of the Jacobian pseudo-inverse in the polish: directions the arm
can barely move in (at a singularity) are left alone instead of taking huge steps along them."""


def _polish(q: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Refine candidates with Gauss-Newton steps on the 6-D pose error.

    Near a singularity the analytic angles lose digits (they divide by a vanishing sine);
    a few steps with the pseudo-inverse Jacobian restore the pose to machine precision.
    """
    for _ in range(POLISH_STEPS):
        poses = link_poses(q)
        tool = poses[:, -1]
        err_pos = target[:3, 3] - tool[:, :3, 3]
        rel = target[:3, :3] @ np.swapaxes(tool[:, :3, :3], -1, -2)
        err_rot = 0.5 * np.stack(
            [rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]],
            axis=-1,
        )
        err = np.concatenate([err_pos, err_rot], axis=-1)
        jac = jacobian_from_poses(poses)
        q = q + (np.linalg.pinv(jac, rcond=POLISH_RCOND) @ err[..., None])[..., 0]
    return q


def _verified(q: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rows of ``q`` (wrapped to [-pi, pi]) whose tool0 pose is within VERIFY_TOL of target."""
    q = wrap(q)
    if len(q) == 0:
        return q
    err = tool_pose(q) - target
    return q[np.abs(err[:, :3, :]).max(axis=(-2, -1)) < VERIFY_TOL]


def _unique(q: np.ndarray) -> np.ndarray:
    unique: list[np.ndarray] = []
    for row in q:
        if not any(np.abs(wrap(row - other)).max() < DUPLICATE_TOL for other in unique):
            unique.append(row)
    return np.array(unique).reshape(-1, 6)


def ik_position(target: Any, wrist: Any) -> tuple[np.ndarray, np.ndarray]:
    """Joints 1-3 that bring tool0 to a position, with joints 4-6 held at given angles.

    With the wrist fixed, the forearm and wrist form one rigid link, so joints 2-3 are a planar
    two-link arm: up to 2 pan x 2 elbow = 4 solutions. Batched.

    Parameters
    ----------
    target : (..., 3) float array_like, m
        tool0 positions in ``base_link``.
    wrist : (..., 3) float array_like, rad
        Angles of joints 4-6 (broadcast against ``target``'s batch shape).

    Returns
    -------
    q : (..., 4, 6) float, rad, in [-pi, pi]
        Full configurations (joints 4-6 as given, wrapped); rows where ``valid`` is False hold
        NaN.
    valid : (..., 4) bool
        Which of the 4 candidates exist and reproduce ``target`` to :data:`VERIFY_TOL`.

    Raises
    ------
    ValueError
        When ``target`` or ``wrist`` is not ``(..., 3)``, not real, or not finite, or their
        batch shapes do not broadcast.
    """
    p = joint_array(target, "target", 3, "tool0 positions x, y, z in m, base_link frame")
    w = joint_array(wrist, "wrist", 3, "angles of joints 4-6 in rad")
    try:
        p, w = np.broadcast_arrays(p, w)
    except ValueError:
        raise ValueError(f"target {p.shape} and wrist {w.shape} must have batch shapes that "
                         "broadcast") from None
    g = geometry()
    phi4 = w[..., 0] + g.wrist_offset
    s5 = np.sin(w[..., 1])
    # The rigid forearm+wrist "link" seen from the elbow, in the forearm frame (x, z):
    # forearm along z, then wrist 2 at angle phi4, then tool0 swung by q5.
    lx = g.wrist_2 * np.sin(phi4) - g.wrist_3 * s5 * np.cos(phi4)
    lz = g.forearm + g.wrist_2 * np.cos(phi4) + g.wrist_3 * s5 * np.sin(phi4)
    length = np.hypot(lx, lz)
    delta = np.arctan2(lx, lz)
    lateral = g.lateral + g.wrist_3 * np.cos(w[..., 1])
    px, py, pz = p[..., 0], p[..., 1], p[..., 2] - g.d1
    pans = _shoulder_pans(px, py, lateral)

    out = np.full((*p.shape[:-1], 4, 6), np.nan)
    valid = np.zeros((*p.shape[:-1], 4), dtype=bool)
    k = 0
    for q1 in pans[:2]:
        x_pan = np.cos(q1) * px + np.sin(q1) * py
        for sign in (1.0, -1.0):
            a, rel, ok = _planar_two_link(x_pan, pz, g.upper_arm, length, sign)
            out[..., k, 0] = q1
            out[..., k, 1] = a - g.lift_offset
            out[..., k, 2] = rel - delta
            out[..., k, 3:] = w
            valid[..., k] = ok & pans[2]
            k += 1
    out = wrap(out)
    reached = np.abs(position(np.nan_to_num(out), g) - p[..., None, :]).max(axis=-1) < VERIFY_TOL
    valid &= reached
    out[~valid] = np.nan
    return out, valid

