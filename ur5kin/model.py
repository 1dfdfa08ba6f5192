"""The UR5 robot model: example-robot-data's URDF through Pinocchio, and the lengths read off it.

Everything numeric about the arm (link offsets, effort and velocity limits, inertias) comes from
the URDF via Pinocchio; this module only locates the file and checks that its kinematic structure
is the one the closed-form code in :mod:`ur5kin.closed_form` assumes.
"""

from __future__ import annotations

import functools
import importlib.metadata
import math
import pathlib
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

URDF_RELPATH = "robots/ur_description/urdf/ur5_robot.urdf"
"""The UR5 URDF inside example-robot-data's data folder (the ROS "kinetic" ur_description)."""

TOOL_FRAME = "tool0"
"""The end-effector frame."""

BASE_FRAME = "base_link"
"""The frame every ur5kin quantity is expressed in."""

JOINT_NAMES: tuple[str, ...] = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
"""Joints 1-6, in the order of every ``q`` in this project."""

JOINT_LIMIT = math.pi
"""Half-width (rad) of the range [-pi, pi] the task's joints live in (docs/design.md: the action
range): goals are drawn there and position commands are clipped to it. Every angle once; the
URDF itself allows [-2 pi, 2 pi]."""

LINK_NAMES: tuple[str, ...] = (
    "base_link",
    "shoulder_link",
    "upper_arm_link",
    "forearm_link",
    "wrist_1_link",
    "wrist_2_link",
    "wrist_3_link",
)
"""Links in chain order; link i (i >= 1) is moved by joint i."""


@functools.cache
def urdf_path() -> pathlib.Path:
    """Locate ``ur5_robot.urdf`` inside the installed example-robot-data distribution.

    Returns
    -------
    path : pathlib.Path
        Absolute path of the URDF file.

    Raises
    ------
    FileNotFoundError
        When example-robot-data is not installed or does not ship the UR5 description.
    """
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as err:
        raise FileNotFoundError(
            "example-robot-data is not installed; it provides the UR5 URDF "
            "(pip install example-robot-data)"
        ) from err
    for file in dist.files or ():
        if str(file).replace("\\", "/").endswith(URDF_RELPATH):
            path = pathlib.Path(str(dist.locate_file(file))).resolve()
            if path.is_file():
                return path
    raise FileNotFoundError(
        f"example-robot-data {dist.version} is installed but holds no {URDF_RELPATH}"
    )


def resolve_package_uri(uri: str) -> pathlib.Path:
    """Turn a URDF mesh URI such as ``package://example-robot-data/robots/...stl`` into a path."""
    prefix = "package://example-robot-data/"
    if not uri.startswith(prefix):
        raise ValueError(f"expected a URI starting with {prefix!r}; got {uri!r}")
    # the package folder: .../example-robot-data/robots/ur_description/urdf/ur5_robot.urdf
    return urdf_path().parents[3] / uri[len(prefix) :]


@functools.cache
def load_model() -> pin.Model:
    """The 6-joint UR5 as a Pinocchio ``Model`` (fixed base at ``base_link``, gravity -9.81 z).

    The model is built once and shared: treat it as read-only, and create a ``Data`` of your own
    with ``model.createData()``. Copy it (``pin.Model(model)``) before changing anything.
    """
    model = pin.buildModelFromUrdf(str(urdf_path()))
    names = tuple(model.names[1:])
    if names != JOINT_NAMES:
        raise RuntimeError(f"unexpected joints in {urdf_path()}: {names}; expected {JOINT_NAMES}")
    return model


def _rot_y(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


@dataclass(frozen=True)
class UR5Geometry:
    """Link offsets of the UR5 as the URDF gives them (m, rad).

    The chain, in the ``base_link`` frame (``Ry``/``Rz``: rotation about y/z)::

        Tz(d1) Rz(q1) . Ty(shoulder_offset) Ry(pi/2 + q2) . T(0, elbow_offset, upper_arm) Ry(q3)
        . Tz(forearm) Ry(pi/2 + q4) . Ty(wrist_1) Rz(q5) . Tz(wrist_2) Ry(q6) . Ty(wrist_3) R_tool

    So joints 2, 3 and 4 share one pitch axis and the arm's pitch angles add up.
    """

    d1: float
    """Height of the shoulder-pan axis above ``base_link`` (0.089159)."""
    shoulder_offset: float
    """Sideways (y) offset of the shoulder-lift joint (0.13585)."""
    elbow_offset: float
    """Sideways (y) offset of the elbow joint (-0.1197)."""
    upper_arm: float
    """Upper-arm length (0.425; UR's DH |a2|)."""
    forearm: float
    """Forearm length (0.39225; UR's DH |a3|)."""
    wrist_1: float
    """Sideways (y) offset of wrist 2 from wrist 1 (0.093)."""
    wrist_2: float
    """Length from wrist 2 to wrist 3 (0.09465; UR's DH d5)."""
    wrist_3: float
    """Length from wrist 3 to tool0 (0.0823; UR's DH d6)."""
    lift_offset: float
    """Pitch of the shoulder-lift joint placement (pi/2)."""
    wrist_offset: float
    """Pitch of the wrist-1 joint placement (pi/2)."""
    tool_rotation: tuple[tuple[float, float, float], ...]
    """Rotation of ``tool0`` in ``wrist_3_link`` (3 x 3), Rx(-pi/2) in this URDF."""

    @property
    def lateral(self) -> float:
        """Constant y offset of the wrist in the shoulder-pan frame (0.10915; UR's DH d4)."""
        return self.shoulder_offset + self.elbow_offset + self.wrist_1

    @classmethod
    def from_model(cls, model: pin.Model, tol: float = 1e-9) -> UR5Geometry:
        """Read the offsets off a Pinocchio model, checking it has the UR5's structure.

        Raises
        ------
        RuntimeError
            When an axis, a placement rotation or a zero offset differs from the UR layout, so
            that the closed form would silently disagree with the model.
        """
        axes = tuple(model.joints[i].shortname() for i in range(1, model.njoints))
        expected_axes = ("JointModelRZ", "JointModelRY", "JointModelRY", "JointModelRY",
                         "JointModelRZ", "JointModelRY")
        if axes != expected_axes:
            raise RuntimeError(f"joint axes {axes} are not the UR layout {expected_axes}")
        placements = [model.jointPlacements[i] for i in range(1, model.njoints)]
        t = [np.asarray(m.translation) for m in placements]
        pattern = [(0, 0, 1), (0, 1, 0), (0, 1, 1), (0, 0, 1), (0, 1, 0), (0, 0, 1)]
        for i, (ti, mask) in enumerate(zip(t, pattern, strict=True)):
            stray = np.abs(ti[np.logical_not(mask)])
            if np.any(stray > tol):
                raise RuntimeError(f"joint {i + 1} placement {ti} has offsets the UR layout lacks")
        lift = float(np.arctan2(placements[1].rotation[0, 2], placements[1].rotation[0, 0]))
        wrist = float(np.arctan2(placements[3].rotation[0, 2], placements[3].rotation[0, 0]))
        for i, pitch in ((1, lift), (3, wrist)):
            if not np.allclose(placements[i].rotation, _rot_y(pitch), atol=tol):
                raise RuntimeError(f"joint {i + 1} placement is not a pure pitch")
        for i in (0, 2, 4, 5):
            if not np.allclose(placements[i].rotation, np.eye(3), atol=tol):
                raise RuntimeError(f"joint {i + 1} placement has a rotation the UR layout lacks")
        tool = model.frames[model.getFrameId(TOOL_FRAME)]
        if tool.parentJoint != 6:
            raise RuntimeError(f"{TOOL_FRAME} is not attached to wrist_3_joint")
        tool_t = np.asarray(tool.placement.translation)
        if abs(tool_t[0]) > tol or abs(tool_t[2]) > tol:
            raise RuntimeError(f"{TOOL_FRAME} offset {tool_t} is not along wrist_3's y axis")
        return cls(d1=float(t[0][2]), shoulder_offset=float(t[1][1]), elbow_offset=float(t[2][1]),
                   upper_arm=float(t[2][2]), forearm=float(t[3][2]), wrist_1=float(t[4][1]),
                   wrist_2=float(t[5][2]), wrist_3=float(tool_t[1]), lift_offset=lift,
                   wrist_offset=wrist, tool_rotation=tuple(tuple(float(x) for x in row)
                                                           for row in tool.placement.rotation))


@functools.cache
def geometry() -> UR5Geometry:
    """The UR5's link offsets, read once from :func:`load_model`."""
    return UR5Geometry.from_model(load_model())


def effort_limits() -> np.ndarray:
    """URDF joint torque limits, ``(6,) float, N m`` (150, 150, 150, 28, 28, 28)."""
    return np.array(load_model().effortLimit, dtype=float)


def velocity_limits() -> np.ndarray:
    """URDF joint velocity limits, ``(6,) float, rad/s``."""
    return np.array(load_model().velocityLimit, dtype=float)
