"""An independent ground-plane check shared by the env tests (not a test module).

``brute_force_heights`` applies Pinocchio's geometry placements (oMg) to the convex hulls of the
URDF's collision meshes, with none of ur5kin.collision's closed forms, so the tests can check
the clearance code and the dynamics' plane against a second path.
"""

from __future__ import annotations

import functools

import numpy as np
import pinocchio as pin
import trimesh
from scipy.spatial import ConvexHull

import ur5kin


@functools.cache
def _collision_hulls() -> tuple[pin.GeometryModel, list[tuple[int, np.ndarray]]]:
    """The collision model and, for each moving link's geometry, the vertices of its hull (m,
    in the geometry's own frame)."""
    model = ur5kin.load_model()
    package_root = ur5kin.resolve_package_uri("package://example-robot-data/").parent
    geom = pin.buildGeomFromUrdf(model, str(ur5kin.urdf_path()), pin.GeometryType.COLLISION,
                                 package_dirs=[str(package_root)])
    hulls = []
    for i, obj in enumerate(geom.geometryObjects):
        if obj.parentJoint == 0:
            continue  # base_link is fixed to its mount
        if type(obj.geometry).__name__ == "Box":
            half = np.asarray(obj.geometry.halfSide)
            points = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1)
                               for sz in (-1, 1)]) * half
        else:
            mesh = trimesh.load(obj.meshPath, force="mesh")
            points = np.asarray(mesh.vertices) * np.asarray(obj.meshScale)
        hulls.append((i, points[ConvexHull(points).vertices]))
    return geom, hulls


def brute_force_heights(q: np.ndarray, base_height: float) -> np.ndarray:
    """Lowest world z of the moving links' collision geometry.

    Parameters
    ----------
    q : (m, 6) or (6,) float, rad
        Joint angles.
    base_height : float, m
        Height of base_link above the plane.

    Returns
    -------
    z : (m,) float, m, world frame
    """
    model = ur5kin.load_model()
    geom, hulls = _collision_hulls()
    data, gdata = model.createData(), geom.createData()
    out = []
    for qi in np.atleast_2d(q):
        pin.updateGeometryPlacements(model, data, geom, gdata, qi)
        lows = [(pts @ gdata.oMg[i].rotation.T + gdata.oMg[i].translation)[:, 2].min()
                for i, pts in hulls]
        out.append(min(lows) + base_height)
    return np.array(out)


def random_states(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n random (q rad, v rad/s, tau N m) rows of the 6 joints, for the dynamics tests."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (n, 6))
    v = rng.uniform(-3.0, 3.0, (n, 6))  # rad/s, the URDF's velocity limits
    tau = rng.uniform(-1.0, 1.0, (n, 6)) * ur5kin.effort_limits()
    return q, v, tau


def pinocchio_rows(func, *arrays: np.ndarray) -> np.ndarray:
    """``func(model, data, *row)`` of Pinocchio for each row of ``arrays``: the reference."""
    model = ur5kin.load_model()
    data = model.createData()
    return np.array([func(model, data, *row).copy() for row in zip(*arrays, strict=True)])
