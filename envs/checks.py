"""The physics checks of a task: what :class:`envs.spec.TaskSpec` leaves out to stay a record.

:func:`validate` asks the robot model whether a task can run: its start pose within the URDF
joint limits and clear of the plane, its PD gains and its compliant contact (if any) stable
under its integrator. Every dynamics backend (:mod:`envs.physics`) calls it when built, once
per env; reading a task from JSON does not.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

import ur5kin
from envs.gains import contact_stability_violations, pd_stability_violations

if TYPE_CHECKING:
    from envs.spec import TaskSpec

VALIDATED_TASKS = 256
"""Tasks whose check is remembered (a task is immutable, so its answer never changes)."""


def validate(task: TaskSpec) -> TaskSpec:
    """Check that ``task`` is physically runnable; return it unchanged.

    Raises
    ------
    ValueError
        When ``start_q`` lies outside the URDF joint limits or puts a moving link below
        ``plane_margin``, or when the PD gains are unstable under semi-implicit Euler at
        ``sim_hz``; the message names the value and what was expected.
    """
    _checked(task)
    return task


@functools.lru_cache(maxsize=VALIDATED_TASKS)
def _checked(task: TaskSpec) -> None:
    """Both checks, remembered per task (an equal task gets the same answer)."""
    _check_start(task)
    _check_gains(task)
    _check_contact(task)


def _check_start(task: TaskSpec) -> None:
    """Raise ``ValueError`` if ``start_q`` is outside the URDF limits or not clear of the plane."""
    model = ur5kin.load_model()
    q = np.asarray(task.start_q)
    lo, hi = np.asarray(model.lowerPositionLimit), np.asarray(model.upperPositionLimit)
    outside = np.flatnonzero((q < lo) | (q > hi))
    if outside.size:
        j = int(outside[0])
        raise ValueError(f"start_q[{j}] = {q[j]} rad is outside joint {j + 1}'s URDF limits "
                         f"[{lo[j]}, {hi[j]}] rad; start_q = {list(task.start_q)}")
    heights = ur5kin.link_heights(q, task.base_height)[1:]
    if heights.min() < task.plane_margin:
        link = ur5kin.LINK_NAMES[1 + int(np.argmin(heights))]
        raise ValueError(
            f"start_q = {list(task.start_q)} rad puts {link} at z = {heights.min():.4f} m, below "
            f"the plane margin {task.plane_margin} m (base at {task.base_height} m): the start "
            "pose must be clear of the ground plane"
        )


def _check_gains(task: TaskSpec) -> None:
    """Raise ``ValueError`` when the PD gains cannot be stable under the task's integrator."""
    problems = pd_stability_violations(task.kp, task.kd, task.sim_dt)
    if problems:
        raise ValueError(
            f"the PD gains kp={list(task.kp)} N m/rad, kd={list(task.kd)} N m s/rad are unstable "
            f"under semi-implicit Euler at sim_hz={task.sim_hz} Hz: " + "; ".join(problems)
            + ". Lower the gains or raise sim_hz"
        )


def _check_contact(task: TaskSpec) -> None:
    """Raise ``ValueError`` when the compliant contact cannot be stable under the integrator."""
    if task.contact_model != "compliant":
        return
    problems = contact_stability_violations(task.contact_stiffness, task.contact_damping,
                                            task.sim_dt)
    if problems:
        raise ValueError("the compliant contact is unstable under semi-implicit Euler at "
                         f"sim_hz={task.sim_hz} Hz: " + "; ".join(problems)
                         + ". Lower contact_stiffness / contact_damping or raise sim_hz")
