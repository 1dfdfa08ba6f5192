"""UR5 kinematics on Pinocchio: forward kinematics, Jacobians and analytic inverse kinematics.

Every quantity is in the robot's ``base_link`` frame, SI units (m, rad); the end effector is the
URDF frame ``tool0``. ``q`` is ``(..., 6)``: shoulder_pan, shoulder_lift, elbow, wrist_1, wrist_2,
wrist_3. In this URDF all zeros stretches the arm along +x and a negative shoulder_lift raises it.

>>> import ur5kin
>>> ur5kin.fk([0, 0, 0, 0, 0, 0]).round(4)
array([ 0.8173,  0.1914, -0.0055])
"""

from ur5kin.ik import ik, ik_position, wrap
from ur5kin.kinematics import fk, fk_pose, fk_torch, jacobian, link_poses
from ur5kin.model import (
    BASE_FRAME,
    JOINT_NAMES,
    LINK_NAMES,
    TOOL_FRAME,
    UR5Geometry,
    effort_limits,
    geometry,
    load_model,
    resolve_package_uri,
    urdf_path,
    velocity_limits,
)
from ur5kin.subchain import SubChain

__all__ = [
    "BASE_FRAME",
    "JOINT_NAMES",
    "LINK_NAMES",
    "TOOL_FRAME",
    "SubChain",
    "UR5Geometry",
    "effort_limits",
    "fk",
    "fk_pose",
    "fk_torch",
    "geometry",
    "ik",
    "ik_position",
    "jacobian",
    "link_poses",
    "load_model",
    "resolve_package_uri",
    "urdf_path",
    "velocity_limits",
    "wrap",
]
