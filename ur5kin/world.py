"""The robot's place in the task world: its base at (0, 0, ``base_height``), axes unrotated.

Every quantity of :mod:`ur5kin` is in ``base_link``; the task world has the ground plane at
z = 0 and the base ``base_height`` above it, with the same axes. This module is that one
transform (a translation along z), so no caller adds the offset by hand. numpy only: importing
it loads neither Pinocchio nor torch.

>>> from ur5kin.world import to_world, to_base
>>> to_world([[0.5, 0.0, 0.2]], 0.1)
array([[0.5, 0. , 0.3]])
>>> to_base(to_world([0.5, 0.0, 0.2], 0.1), 0.1)
array([0.5, 0. , 0.2])
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ur5kin.checks import number

DEFAULT_BASE_HEIGHT = 0.1
"""Height (m) of the robot base above the plane: where ROS's ur_gazebo spawns the UR5."""


BASE_HEIGHT = number(0, note="m")
"""A height of the robot base above the ground plane: every task's and every region's."""


def check_base_height(base_height: Any) -> float:
    """Return ``base_height`` (m) as a float, or raise ``ValueError`` if not finite and >= 0."""
    return BASE_HEIGHT("base_height", base_height)


def height_to_world(z: Any, base_height: float) -> Any:
    """World heights (m) of heights ``z (...)`` (m) above ``base_link``'s origin."""
    return z + check_base_height(base_height)


def to_world(points: Any, base_height: float, out: np.ndarray | None = None) -> np.ndarray:
    """World positions ``(..., 3)`` (m) of ``points (..., 3)`` (m, ``base_link`` frame).

    ``out`` (same shape, float) receives the result when given (it may be ``points`` itself:
    the transform in place, for hot loops).
    """
    if out is None:
        out = np.array(points, dtype=float)
    elif out is not points:
        out[...] = points
    out[..., 2] += check_base_height(base_height)
    return out


def to_base(points: Any, base_height: float) -> np.ndarray:
    """``base_link`` positions ``(..., 3)`` (m) of world ``points (..., 3)`` (m); inverts
    :func:`to_world`. ValueError for points that are not ``(..., 3)`` finite numbers."""
    p = np.array(points, dtype=float)
    if p.shape[-1:] != (3,) or not np.isfinite(p).all():
        raise ValueError(f"points must be (..., 3) finite positions (m); got shape {p.shape}"
                         + ("" if p.shape[-1:] != (3,) else " with NaN or infinity"))
    p[..., 2] -= check_base_height(base_height)
    return p
