"""The UR5's meshes as the URDF places them, for drawing: Pinocchio's visual and collision models.

Every part is one Pinocchio ``GeometryObject`` of example-robot-data's URDF, on the link its
parent joint moves; :func:`part_poses` places the parts for a batch of configurations through the
closed-form link poses (:func:`ur5kin.link_poses`), in the ``base_link`` frame. Nothing here
copies a number of the arm: the files, placements and scales are the URDF's.

Two kinds, as in the URDF: ``visual`` (example-robot-data's COLLADA meshes, 6.7 MB of text,
about 96,000 triangles, with their materials) and ``collision`` (binary STL meshes of 5,300
triangles in all, 270 kB, and the ``ee_link`` box), which :mod:`ur5kin.collision` reads too.
"""

from __future__ import annotations

import functools
import pathlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin

from ur5kin.kinematics import link_poses
from ur5kin.model import LINK_NAMES, load_model, resolve_package_uri, urdf_path

if TYPE_CHECKING:
    import trimesh

KINDS: dict[str, pin.GeometryType] = {
    "collision": pin.GeometryType.COLLISION,
    "visual": pin.GeometryType.VISUAL,
}
"""The URDF's two geometry kinds, by the names the command lines use."""


@functools.cache
def geometry_model(kind: str) -> pin.GeometryModel:
    """The URDF's ``visual`` or ``collision`` geometry as a Pinocchio ``GeometryModel`` (cached).

    Shared: treat it as read-only; make a ``GeometryData`` of your own
    (``pin.GeometryData(geometry_model(kind))``).
    """
    if kind not in KINDS:
        raise ValueError(f"mesh kind must be one of {sorted(KINDS)}; got {kind!r}")
    package_root = resolve_package_uri("package://example-robot-data/").parent
    return pin.buildGeomFromUrdf(load_model(), str(urdf_path()), KINDS[kind],
                                 package_dirs=[str(package_root)])


@dataclass(frozen=True)
class MeshPart:
    """One geometry object of the URDF: a mesh file or a box, on one link.

    Attributes
    ----------
    name : str
        Pinocchio's name of the object (``upper_arm_link_0``).
    link : str
        The link that carries it, one of :data:`ur5kin.LINK_NAMES` (a fixed child link's part,
        ``ee_link``'s box, joins its parent).
    joint : int
        Index of the joint that moves the link, 0 (the fixed base) to 6; also the link's index
        in :data:`ur5kin.LINK_NAMES` and in :func:`ur5kin.link_poses`.
    placement : (4, 4) float, m
        Pose of the part in the link's frame (Pinocchio's ``placement``).
    path : pathlib.Path or None
        The mesh file (``.dae`` or ``.stl``), None for a box.
    scale : (3,) float
        The URDF's mesh scale along the part's axes.
    half_extents : (3,) float, m, or None
        Half the edges of a box part; None for a mesh.
    """

    name: str
    link: str
    joint: int
    placement: np.ndarray
    path: pathlib.Path | None
    scale: tuple[float, float, float]
    half_extents: tuple[float, float, float] | None

    def local_mesh(self) -> trimesh.Trimesh:
        """The part as a triangle mesh in its own frame (m, scaled as the URDF says).

        Raises
        ------
        ValueError
            For a COLLADA file: trimesh reads those only with pycollada, which this project
            does not install; viewers take the file as it is (see :mod:`analysis.scene`).
        """
        import trimesh

        if self.half_extents is not None:
            return trimesh.creation.box(extents=2.0 * np.asarray(self.half_extents))
        assert self.path is not None
        if self.path.suffix.lower() == ".dae":
            raise ValueError(f"{self.path} is COLLADA; read it with a COLLADA loader")
        mesh = trimesh.load(str(self.path), force="mesh")
        mesh.apply_scale(np.asarray(self.scale, dtype=float))
        return mesh


def _part(obj: Any) -> MeshPart:
    kind = type(obj.geometry).__name__
    half = path = None
    if kind == "Box":
        half = tuple(float(h) for h in obj.geometry.halfSide)
    elif obj.meshPath:
        path = pathlib.Path(obj.meshPath)
    else:
        raise NotImplementedError(f"geometry {obj.name!r} is a {kind}; only meshes and boxes "
                                  "are supported")
    return MeshPart(name=obj.name, link=LINK_NAMES[obj.parentJoint], joint=int(obj.parentJoint),
                    placement=np.asarray(obj.placement.homogeneous, dtype=float),
                    path=path, scale=tuple(float(s) for s in obj.meshScale),
                    half_extents=half)


@functools.cache
def mesh_parts(kind: str = "collision") -> tuple[MeshPart, ...]:
    """Every part of the URDF's ``visual`` or ``collision`` geometry, in Pinocchio's order."""
    return tuple(_part(obj) for obj in geometry_model(kind).geometryObjects)


def part_poses(q: Any, kind: str = "collision") -> np.ndarray:
    """Poses of the parts of :func:`mesh_parts` for configurations ``q``.

    Parameters
    ----------
    q : (..., 6) float array_like, rad
    kind : ``collision`` or ``visual``

    Returns
    -------
    T : (..., P, 4, 4) float, m, ``base_link`` frame
        Pose of part p, ``link_poses(q)[..., joint_p] @ placement_p`` (Pinocchio's ``oMg``).
    """
    parts = mesh_parts(kind)
    q = np.asarray(q, dtype=float)
    links = link_poses(q[None] if q.ndim == 1 else q)
    joints = np.array([p.joint for p in parts])
    placements = np.stack([p.placement for p in parts])
    poses = links[..., joints, :, :] @ placements
    return poses[0] if q.ndim == 1 else poses
