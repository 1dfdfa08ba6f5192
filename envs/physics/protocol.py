"""What every dynamics backend of B arm copies offers the env: the :class:`Dynamics` protocol.

Its own module so that the env's task copies (:mod:`envs.core`) stand on the protocol alone and
the backends, and :func:`envs.physics.make_dynamics` that picks one, stand above it; users
import it as ``envs.physics.Dynamics``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    import numpy as np

    from envs.spec import TaskSpec


class Dynamics(Protocol):
    """What every dynamics backend of B arm copies offers the env (:class:`envs.core.TaskCopies`).

    A backend is built as ``Backend(task, num_copies, ...)`` with the copies at rest at
    ``task.start_q``.

    Attributes
    ----------
    task : TaskSpec
        Start pose, controlled joints, control mode, gains, rates, base height, plane margin.
    num_copies : int
        B, the number of independent arms.
    q, v : (B, 6) float, rad and rad/s
        Joint angles and velocities now.
    acceleration : (B, 6) float, rad/s^2
        Mean realised acceleration over the last step, ``(v(t + dt) - v(t)) / dt`` (zero after
        a reset).
    contact : (B,) bool
        Whether the plane acted in the last step (stopped the arm; under the compliant contact
        also: pushed it).
    limit_stop : (B,) bool
        Whether the last step stopped at a URDF joint position limit.

    The arrays are owned by the backend and overwritten by every step; copy what you keep.
    """

    task: TaskSpec
    num_copies: int
    q: np.ndarray
    v: np.ndarray
    acceleration: np.ndarray
    contact: np.ndarray
    limit_stop: np.ndarray

    def reset(self, q: Any, index: Any = None) -> None:
        """Put copies ``index`` (None: all; an int, slice, ``(m,)`` int or ``(B,)`` bool) at
        rest at ``q (6,)`` or ``(m, 6)`` rad; ValueError for a configuration below the plane
        margin or with a locked joint off its start angle
        (:func:`envs.physics.model.rest_heights`)."""

    def step(self, command: np.ndarray) -> None:
        """One control step of ``task.substeps`` substeps; ``command (B, n)`` per copy, the
        command of joints 1..n in the control mode's unit (rad, rad/s or N m), within the
        action box (:func:`envs.task.action_bounds`)."""

    def tool_positions(self, out: np.ndarray) -> np.ndarray:
        """Write tool0's world position ``(B, 3)`` m into ``out`` and return it."""
