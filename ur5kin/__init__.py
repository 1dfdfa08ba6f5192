"""UR5 kinematics on Pinocchio: forward kinematics, Jacobians, analytic inverse kinematics, and
the arm's collision geometry with its clearance above the ground plane, and its meshes placed for
drawing (:func:`mesh_parts`, :func:`part_poses`).

Frame ``base_link``, SI units, end effector ``tool0``, ``q`` ``(..., 6)`` in joint order 1-6:
docs/design.md, "Frames and units"; the task world is :mod:`ur5kin.world`'s.

Names load on first use (PEP 562), so that ``import ur5kin.world`` or ``ur5kin.checks`` does not
load Pinocchio.

>>> import ur5kin
>>> ur5kin.fk([0, 0, 0, 0, 0, 0]).round(4)
array([ 0.8173,  0.1914, -0.0055])
"""

from __future__ import annotations

from ur5kin.lazy import lazy_attributes

_EXPORTS: dict[str, str] = {
    **dict.fromkeys(("ik", "ik_position", "wrap"), "ur5kin.analytic_ik"),
    **dict.fromkeys(("fk", "fk_pose", "fk_world", "jacobian", "link_poses"), "ur5kin.kinematics"),
    **dict.fromkeys(("BASE_FRAME", "JOINT_LIMIT", "JOINT_NAMES", "LINK_NAMES", "TOOL_FRAME",
                     "UR5Geometry", "effort_limits", "geometry", "load_model",
                     "resolve_package_uri", "urdf_path", "velocity_limits"), "ur5kin.model"),
    **dict.fromkeys(("MeshPart", "mesh_parts", "part_poses"), "ur5kin.meshes"),
    "SubChain": "ur5kin.subchain",
    **dict.fromkeys(("capsule_heights", "collision_geometry", "link_heights", "plane_clear"),
                    "ur5kin.collision"),
    **dict.fromkeys(("DEFAULT_BASE_HEIGHT", "check_base_height", "height_to_world", "to_base",
                     "to_world"), "ur5kin.world"),
}
"""Public name -> the module that defines it."""

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
