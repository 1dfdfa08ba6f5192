"""The UR5's reach ball: the smallest ball about the shoulder that holds every tool0 position.

It bounds the reachable workspace of every joint count, so it turns z-limits into bounded regions
with an exact volume (``zheight``, ``unconstrained``) and gives the Cartesian sampler a box to
draw from.
"""

from __future__ import annotations

import functools

import numpy as np

import ur5kin
from regions.shapes import Ball

REACH_GRID = 20001
"""Points of the grid over q5 in [0, pi] on which the reach is first maximised (then refined)."""

REACH_MARGIN = 1e-9
"""Added to the maximised reach (m), so that the ball contains its own extreme points despite
rounding."""


def _reach_sq(q5: np.ndarray, g: ur5kin.UR5Geometry) -> np.ndarray:
    """Largest squared distance (m^2) of tool0 from the shoulder centre for a given q5 (rad).

    In the pan frame tool0 sits at ``y = lateral + wrist_3 cos q5`` and, in the arm's plane,
    at the end of the upper arm, the forearm and a last link of length
    ``hypot(wrist_2, wrist_3 sin q5)``; joints 2-4 can stretch those three in a line.
    """
    planar = g.upper_arm + g.forearm + np.hypot(g.wrist_2, g.wrist_3 * np.sin(q5))
    lateral = g.lateral + g.wrist_3 * np.cos(q5)
    return planar**2 + lateral**2


@functools.cache
def reach_radius() -> float:
    """The largest distance (m) of tool0 from the shoulder centre ``(0, 0, d1)`` of base_link.

    The distance does not depend on joints 1 and 6, and joints 2-4 stretch the arm straight, so
    it is a maximum over q5 alone: found on a grid of :data:`REACH_GRID` points, refined by
    Brent's method, plus :data:`REACH_MARGIN`.
    """
    from scipy.optimize import minimize_scalar  # loaded only when the reach is first needed

    g = ur5kin.geometry()
    grid = np.linspace(0.0, np.pi, REACH_GRID)
    i = int(np.argmax(_reach_sq(grid, g)))
    step = grid[1] - grid[0]
    lo, hi = max(0.0, grid[i] - step), min(np.pi, grid[i] + step)
    best = minimize_scalar(lambda x: -_reach_sq(np.asarray(x), g), bounds=(lo, hi),
                           method="bounded", options={"xatol": 1e-12})
    reach_sq = max(float(-best.fun), float(_reach_sq(grid[i], g)))
    return float(np.sqrt(reach_sq)) + REACH_MARGIN


def shoulder_centre(base_height: float) -> np.ndarray:
    """World position ``(3,) m`` of the shoulder centre: on the pan axis at the lift joint's
    height, ``(0, 0, base_height + d1)``."""
    return ur5kin.to_world([0.0, 0.0, ur5kin.geometry().d1], base_height)


def reach_ball(base_height: float) -> Ball:
    """The ball (world frame, m) holding every tool0 position of the arm at ``base_height``.

    Parameters
    ----------
    base_height : float, m
        Height of ``base_link``'s origin above the plane.
    """
    return Ball(tuple(shoulder_centre(base_height)), reach_radius(), name="reach")
