"""The arm model every dynamics backend reads: the task's controller in time-scaled units.

One job: turn a :class:`envs.spec.TaskSpec` into the numbers a control step needs (scaled PD
gains per control mode, the command's gain, effort and velocity limits, joint-limit box, held
joints), once, so that the Pinocchio loop (:mod:`envs.dynamics`), the numba kernel
(:mod:`envs.fastdyn`) and the torch path (:mod:`envs.torchdyn`) cannot drift apart.

Time-scaled units (:mod:`envs.dynamics`' docstring): with ``h = 1 / sim_hz`` the integrator's
velocity is ``w = h v`` (rad per substep), torques and gravity are scaled by ``h^2``, so one
Euler substep is ``w' = w + aba(q, w, tau)``, ``q' = q + w'``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

import ur5kin

if TYPE_CHECKING:
    from envs.spec import TaskSpec


class Dynamics(Protocol):
    """What every dynamics backend of B arm copies offers the env (:class:`envs.core.ReachCore`):
    :class:`envs.dynamics.ArmDynamics` (Pinocchio, the reference), :class:`envs.fastdyn.
    FastArmDynamics` (numba) and :class:`envs.torchdyn.HostArrays` (torch behind numpy arrays).

    ``q, v, acceleration : (B, 6) float`` (rad, rad/s, rad/s^2; the mean realised acceleration
    of the last step), ``contact, limit_stop : (B,) bool`` (the last step stopped on the plane,
    at a joint limit); owned by the backend and overwritten by every step.
    """

    task: TaskSpec
    num_copies: int
    q: Any
    v: Any
    acceleration: Any
    contact: Any
    limit_stop: Any

    def reset(self, q: Any, index: Any = None) -> None:
        """Put copies ``index`` (all when None) at rest at ``q (6,)`` or ``(m, 6)`` rad."""

    def step(self, command: np.ndarray) -> None:
        """One control step; ``command (B, n)`` in the control mode's unit, within its box."""

    def tool_positions(self, out: np.ndarray) -> np.ndarray:
        """Write tool0's world position ``(B, 3)`` m into ``out`` and return it."""


def moving_link_heights(q: Any, base_height: float) -> np.ndarray:
    """Exact lowest point ``(..., 6)`` (m, world z) of each moving link (shoulder_link ..
    wrist_3_link) for configurations ``q (..., 6)`` rad: :func:`ur5kin.link_heights` without
    the fixed base link."""
    return ur5kin.link_heights(q, base_height)[..., 1:]


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


def moving_joints(task: TaskSpec) -> int:
    """Joints 1..m that are in the dynamics: n (the controlled ones) when the held joints are
    ``locked``, all 6 when the PD holds them (``task.held_joints``)."""
    return task.n_joints if task.held_joints == "locked" else 6


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
    arrays = dict(kp=kp, kd=kd, kp_eff=kp_eff, kd_eff=kd_eff, command_gain=command_gain,
                  held_bias=kp[n:] * start_q[n:], effort=ur5kin.effort_limits() * h * h,
                  w_max=ur5kin.velocity_limits() * h, q_mid=0.5 * (lo + hi),
                  q_half=0.5 * (hi - lo), start_q=start_q)
    for value in arrays.values():
        value.flags.writeable = False
    return ArmModel(n=n, free=moving_joints(task), h=h, w_to_v=1.0 / h,
                    w_to_accel=1.0 / (h * task.dt), **arrays)
