"""The arm model every dynamics backend reads, built once per task.

One job: turn a :class:`envs.spec.TaskSpec` into the numbers a control step needs, so that the
Pinocchio loop (:mod:`envs.physics.pinocchio_loop`), the numba kernels
(:mod:`envs.physics.numba_kernel`) and the stack's (:mod:`envs.physics.stack`) cannot drift
apart: the controller in time-scaled units (scaled PD gains per control mode, the command's gain,
effort and velocity limits, joint-limit box, held joints), the serial chain (:class:`ChainModel`,
read from Pinocchio) and the plane check's tables (:class:`PlaneModel`, read from
:mod:`ur5kin.collision`), and the checks of a reset configuration.

Time-scaled units: with ``h = 1 / sim_hz`` the integrator's velocity is ``w = h v`` (rad per
substep), torques and gravity are scaled by ``h^2``; the equations of motion are quadratic in
velocity and linear in torque and gravity, so ABA then returns ``h^2 a`` exactly and one Euler
substep is ``w' = w + aba(q, w, tau)``, ``q' = q + w'``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np

import ur5kin

if TYPE_CHECKING:
    from envs.spec import TaskSpec

NJ = 6
"""Joints of the chain (the UR5's six revolute joints)."""

AXES = {"JointModelRX": (1.0, 0.0, 0.0), "JointModelRY": (0.0, 1.0, 0.0),
        "JointModelRZ": (0.0, 0.0, 1.0)}
"""Joint axes (joint frame) of Pinocchio's axis-aligned revolute joints."""


def _clip_fallback(x: np.ndarray, lo: np.ndarray, hi: np.ndarray, out: np.ndarray) -> np.ndarray:
    return np.minimum(np.maximum(x, lo, out=out), hi, out=out)


clip = getattr(getattr(np, "_core", np).umath, "clip", _clip_fallback)
"""``clip(x, lo, hi, out=out)``: numpy's clip ufunc itself. ``np.clip`` wraps it in Python
argument handling that costs several times the ufunc call on 6-vectors, in the hot loop."""


def moving_link_heights(q: Any, base_height: float) -> np.ndarray:
    """Exact lowest point ``(..., 6)`` (m, world z) of each moving link (shoulder_link ..
    wrist_3_link) for configurations ``q (..., 6)`` rad: :func:`ur5kin.link_heights` without
    the fixed base link."""
    return ur5kin.link_heights(q, base_height)[..., 1:]


def moving_joints(task: TaskSpec) -> int:
    """Joints 1..m that are in the dynamics: n (the controlled ones) when the held joints are
    ``locked``, all 6 when the PD holds them (``task.held_joints``)."""
    return task.n_joints if task.held_joints == "locked" else 6


def supports_kernels(task: TaskSpec) -> bool:
    """Whether the compiled backends (the numba kernels) implement ``task``'s physics: the stop
    contact model (the compliant one runs on the Pinocchio loop only)."""
    return task.contact_model == "stop"


def require_kernels(task: TaskSpec, who: str) -> None:
    """The ValueError of ``who`` (a compiled backend or its env) for a task it cannot run."""
    if not supports_kernels(task):
        raise ValueError(f"{who} implements the stop contact model only; got "
                         f"contact_model={task.contact_model!r}")


def check_aba_batch(q: Any, v: Any, tau: Any, free: int) -> None:
    """The checks of the batched ``aba`` function (numba's) on ``(B, 6)`` arrays or
    tensors: one shape, and zero velocity in the locked joints' columns ``free ..``."""
    if not q.shape == v.shape == tau.shape:
        raise ValueError(f"q, v and tau must have one shape; got {tuple(q.shape)}, "
                         f"{tuple(v.shape)}, {tuple(tau.shape)}")
    if bool((v[:, free:] != 0).any()):
        raise ValueError(f"locked joints {free + 1}..{NJ} must have zero velocity; got "
                         f"{v[:, free:].tolist()}")


# ---------------------------------------------------------------------------- geometry
@functools.cache
def link_hulls() -> tuple[np.ndarray, ...]:
    """Convex-hull vertices ``(n_k, 3)`` (m, link frame) of the six moving links.

    shoulder_link .. wrist_3_link (``ee_link``'s box joins wrist_3_link): the URDF collision
    geometry of :func:`ur5kin.collision_geometry`, which the clearance check uses too.
    """
    return tuple(link.hull for link in ur5kin.collision_geometry()[1:])


@functools.cache
def height_lipschitz() -> np.ndarray:
    """Bounds ``R (6, 6)`` (m/rad): ``|dz/dq_i| <= R[i, k]`` for every collision point of link k.

    Rows are joints 1-6, columns the moving links shoulder_link .. wrist_3_link. A point of link
    k (moved by joints 1..k) lies at most ``sum_{j=i+1..k} |t_j| + max|p|`` from joint i's
    origin, ``t_j`` being joint j's placement offset and ``p`` the link's convex-hull vertices
    in its own frame; that bounds its distance from joint i's axis, hence its speed per rad of
    joint i. Joint 1 turns about the vertical axis and never changes a height (row 0 is zero),
    and joint i does not move links before it.
    """
    model = ur5kin.load_model()
    offsets = [float(np.linalg.norm(model.jointPlacements[j].translation)) for j in range(7)]
    reach = [0.0] + [float(np.linalg.norm(hull, axis=1).max()) for hull in link_hulls()]
    R = np.zeros((6, 6))
    for i in range(2, 7):  # joint i (1-based) moves links i..6; link k is the child of joint k
        for k in range(i, 7):
            R[i - 1, k - 1] = sum(offsets[i + 1 : k + 1]) + reach[k]
    return R


@dataclass(frozen=True)
class ChainModel:
    """The UR5's serial chain as flat arrays, read from a Pinocchio model.

    Attributes
    ----------
    rotation : (6, 3, 3) float
        Joint placement rotations ``R`` of ``jointPlacements[i]`` (joint frame in its parent's).
    translation : (6, 3) float, m, parent frame
        Joint placement translations.
    axis : (6, 3) float
        Unit rotation axis of each joint, in its joint frame.
    inertia : (6, 6, 6) float
        Spatial inertia of each body in its joint frame (Pinocchio's ``Inertia.matrix()``,
        ``[linear; angular]`` order), kg and kg m^2.
    armature : (6,) float, kg m^2
        Rotor inertia added to each joint's diagonal.
    gravity : (3,) float, m/s^2, world frame
        The model's gravity (linear part).
    """

    rotation: np.ndarray
    translation: np.ndarray
    axis: np.ndarray
    inertia: np.ndarray
    armature: np.ndarray
    gravity: np.ndarray

    @classmethod
    def from_pinocchio(cls, model: Any) -> ChainModel:
        """Read the chain from ``model`` (a ``pinocchio.Model``).

        Raises
        ------
        ValueError
            When the model is not a serial chain of 6 revolute joints (joint i the parent of
            joint i + 1), or has joint damping or friction (the kernels model neither).
        """
        if model.njoints != NJ + 1 or model.nq != NJ or model.nv != NJ:
            raise ValueError(f"the fast dynamics need a 6-joint chain (njoints = 7, nq = nv = "
                             f"6); got njoints = {model.njoints}, nq = {model.nq}, nv = "
                             f"{model.nv}")
        rotation, translation, axis, inertia = [], [], [], []
        for j in range(1, NJ + 1):
            joint = model.joints[j]
            if model.parents[j] != j - 1:
                raise ValueError(f"joint {j}'s parent is {model.parents[j]}, expected {j - 1}: "
                                 "the fast dynamics handle a serial chain only")
            kind = joint.shortname()
            if kind in AXES:
                axis.append(AXES[kind])
            elif kind == "JointModelRevoluteUnaligned":
                axis.append(np.asarray(joint.extract().axis, dtype=float))
            else:
                raise ValueError(f"joint {j} is a {kind}; the fast dynamics handle revolute "
                                 f"joints ({sorted(AXES)} or JointModelRevoluteUnaligned)")
            placement = model.jointPlacements[j]
            rotation.append(np.asarray(placement.rotation))
            translation.append(np.asarray(placement.translation))
            inertia.append(np.asarray(model.inertias[j].matrix()))
        for name in ("damping", "friction"):
            values = np.asarray(getattr(model, name), dtype=float)
            if np.any(values != 0.0):
                raise ValueError(f"the model's joint {name} is {values.tolist()}; the fast "
                                 "dynamics model neither damping nor friction (expected zeros)")
        return cls(np.array(rotation), np.array(translation), np.array(axis), np.array(inertia),
                   np.asarray(model.armature, dtype=float).copy(),
                   np.asarray(model.gravity.linear, dtype=float).copy())

    def astype(self, dtype: Any) -> ChainModel:
        """The same arrays as ``dtype`` (contiguous, for the kernels)."""
        return ChainModel(*(np.ascontiguousarray(getattr(self, f.name), dtype=dtype)
                            for f in fields(self)))


@functools.cache
def ur5_chain() -> ChainModel:
    """:class:`ChainModel` of :func:`ur5kin.load_model` (cached: never write its arrays)."""
    return ChainModel.from_pinocchio(ur5kin.load_model())


@dataclass(frozen=True)
class PlaneModel:
    """The plane check's constants, from :mod:`ur5kin.collision` (same math, same numbers).

    Attributes
    ----------
    vertex_heights : (V, 13) float, m
        Height above base_link of every vertex that can be a link's lowest, per feature.
    bounds : (8,) int
        Rows ``bounds[k]:bounds[k + 1]`` belong to link k (0 = base_link, never checked).
    lift_offset, wrist_offset : float, rad
        Offsets of the pitches the features use (:func:`ur5kin.collision.height_table`).
    lipschitz : (6, 6) float, m/rad
        :func:`height_lipschitz`: ``|dz_k| <= sum_i R[i, k] |dq_i|``.
    """

    vertex_heights: np.ndarray
    bounds: np.ndarray
    lift_offset: float
    wrist_offset: float
    lipschitz: np.ndarray


@functools.cache
def ur5_plane(dtype: str = "float64") -> PlaneModel:
    """:class:`PlaneModel` of the UR5 as ``dtype`` (cached)."""
    from ur5kin.collision import height_table

    vertex_heights, bounds, lift, wrist = height_table()
    return PlaneModel(np.ascontiguousarray(vertex_heights, dtype=dtype),
                      np.ascontiguousarray(bounds, dtype=np.int64), lift, wrist,
                      np.ascontiguousarray(height_lipschitz(), dtype=dtype))


@functools.cache
def tool_offset() -> np.ndarray:
    """tool0's origin ``(3,)`` m in joint 6's frame (the frame it hangs on; ValueError if not)."""
    model = ur5kin.load_model()
    tool = model.frames[model.getFrameId(ur5kin.TOOL_FRAME)]
    if tool.parentJoint != NJ:
        raise ValueError(f"{ur5kin.TOOL_FRAME} hangs on joint {tool.parentJoint}; the dynamics "
                         f"expect joint {NJ}")
    return np.array(tool.placement.translation, dtype=float)


# ---------------------------------------------------------------------------- the model
@dataclass(frozen=True, eq=False)
class ArmModel:
    """The controller and limits of one task, in time-scaled units (float64 arrays).

    Attributes
    ----------
    n : int
        Controlled joints (1..n follow the command).
    free : int
        Joints in the dynamics: n when the held joints are ``locked``, 6 under ``pd``.
    h : float, s
        Substep length ``1 / sim_hz``.
    kp, kd : (6,) float
        The task's PD gains scaled to the units: ``h^2 kp`` and ``h kd``.
    kp_eff, kd_eff : (6,) float
        The gains the PD torque ``b - kp_eff q - kd_eff w`` uses: the controlled joints' kp is 0
        outside position control and their kd is 0 under torque control.
    command_gain : (n,) float
        Command to the constant torque part b: ``kp q_cmd`` (position), ``kd (h v_cmd)``
        (velocity) or ``h^2 tau_cmd`` (torque).
    held_bias : (6 - n,) float
        b of the held joints: the PD to their start angles, ``kp q_start`` (used under ``pd``;
        under ``locked`` the held joints are out of the dynamics and it has no effect).
    effort, w_max : (6,) float
        URDF effort limits ``h^2 N m`` and velocity limits ``h rad/s``.
    q_mid, q_half : (6,) float, rad
        Centre and half-width of the URDF joint position limits.
    start_q : (6,) float, rad
        The task's start configuration.
    w_to_v, w_to_accel : float
        ``1 / h`` (w to rad/s) and ``1 / (h dt)`` (a step's change of w to its mean rad/s^2).
    chain : ChainModel
        The serial chain with its gravity scaled by ``h^2`` (float64).
    """

    n: int
    free: int
    h: float
    kp: np.ndarray
    kd: np.ndarray
    kp_eff: np.ndarray
    kd_eff: np.ndarray
    command_gain: np.ndarray
    held_bias: np.ndarray
    effort: np.ndarray
    w_max: np.ndarray
    q_mid: np.ndarray
    q_half: np.ndarray
    start_q: np.ndarray
    w_to_v: float
    w_to_accel: float
    chain: ChainModel

    def initial_bias(self, num_copies: int, dtype: Any = np.float64) -> np.ndarray:
        """The constant torque part b ``(B, 6)`` before any command: 0 for the controlled
        joints, :attr:`held_bias` for the held ones (their PD to the start, under ``pd``)."""
        bias = np.zeros((num_copies, NJ), dtype=dtype)
        bias[:, self.n :] = self.held_bias
        return bias


@functools.lru_cache(maxsize=64)
def arm_model(task: TaskSpec) -> ArmModel:
    """The :class:`ArmModel` of ``task`` (cached per task: arrays are shared, never write them)."""
    h, n = task.sim_dt, task.n_joints
    kp, kd = np.asarray(task.kp) * h * h, np.asarray(task.kd) * h
    kp_eff, kd_eff = kp.copy(), kd.copy()
    if task.control_mode != "position":
        kp_eff[:n] = 0.0
    if task.control_mode == "torque":
        kd_eff[:n] = 0.0
    command_gain = {"position": kp[:n], "velocity": kd[:n] * h,
                    "torque": np.full(n, h * h)}[task.control_mode]
    model = ur5kin.load_model()
    lo, hi = np.asarray(model.lowerPositionLimit), np.asarray(model.upperPositionLimit)
    start_q = np.asarray(task.start_q, dtype=float)
    chain = replace(ur5_chain(), gravity=ur5_chain().gravity * h * h)
    arrays = dict(kp=kp, kd=kd, kp_eff=kp_eff, kd_eff=kd_eff, command_gain=command_gain,
                  held_bias=kp[n:] * start_q[n:], effort=ur5kin.effort_limits() * h * h,
                  w_max=ur5kin.velocity_limits() * h, q_mid=0.5 * (lo + hi),
                  q_half=0.5 * (hi - lo), start_q=start_q)
    for value in arrays.values():
        value.flags.writeable = False
    return ArmModel(n=n, free=moving_joints(task), h=h, w_to_v=1.0 / h,
                    w_to_accel=1.0 / (h * task.dt), chain=chain, **arrays)


# ---------------------------------------------------------------------------- resets
def rest_heights(task: TaskSpec, q: Any) -> np.ndarray:
    """Check reset configurations ``q (6,)`` or ``(m, 6)`` rad and return their moving links'
    heights ``(..., 6)`` m (world z): every backend's reset calls this, on the host.

    Raises
    ------
    ValueError
        When a configuration is not clear of the plane by the task's margin, or moves a locked
        joint from its start angle (``held_joints="locked"`` welds them there; ``pd`` accepts
        any).
    """
    q = np.asarray(q, dtype=float)
    n = moving_joints(task)
    if n < 6 and np.any(q[..., n:] != np.asarray(task.start_q)[n:]):
        raise ValueError(f"joints {n + 1}..6 are locked at their start angles "
                         f"{list(task.start_q[n:])} rad (held_joints='locked'); got "
                         f"configuration(s) {q.tolist()} rad")
    heights = moving_link_heights(q, task.base_height)
    if np.any(heights < task.plane_margin):
        raise ValueError(f"reset configuration(s) {q.tolist()} rad reach z = "
                         f"{heights.min():.4f} m, below the plane margin "
                         f"{task.plane_margin} m")
    return heights


def put_at_rest(dyn: Any, q: Any, index: Any) -> Any:
    """The reset of the numpy backends: copies ``index`` (all when None) of ``dyn`` at rest at
    ``q (6,)`` or ``(m, 6)`` rad (checked by :func:`rest_heights`), their height bounds exact.

    ``dyn`` has the state arrays ``q, v, w, acceleration, contact, limit_stop, height_bound``.
    Returns the selection, so the caller can reset its own state too.
    """
    heights = rest_heights(dyn.task, q)
    sel = slice(None) if index is None else index
    dyn.q[sel] = q
    dyn.v[sel] = 0.0
    dyn.w[sel] = 0.0
    dyn.acceleration[sel] = 0.0
    dyn.contact[sel] = False
    dyn.limit_stop[sel] = False
    dyn.height_bound[sel] = heights
    return sel
