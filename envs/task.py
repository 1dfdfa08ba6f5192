"""The Reacher's task rules in one place: goal sampling, reward, termination, step information.

:class:`ReachTask` is the task half of the env in panda-gym's sense (its ``Task`` beside the
``Robot``): it knows the goal region, the reward and when an episode ends, and nothing of the
arm's motion. :class:`envs.core.ReachCore` calls it on every reset and step, and the single
env (:class:`envs.reach.UR5ReachEnv`) and the batched one (:class:`envs.batched.BatchedReach`)
take their GoalEnv functions (``compute_reward``, ``compute_terminated``) and their ``info``
from it, so the rules are written once.

The step kernels (:meth:`ReachTask.is_success`, :meth:`ReachTask.reward`,
:meth:`ReachTask.terminated`) take values the env made itself and do not check them; the GoalEnv
functions check what a caller passes (see :mod:`envs.reward`).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import numpy as np

import regions
from envs.reward import ACTION_KEY, compute_reward, compute_success, goal_distance, reach_reward
from envs.spec import TaskSpec

INFO_KEYS = (ACTION_KEY, "distance", "is_success", "contact", "joint_limit", "clearance")
"""Keys of the step information, in order (see :meth:`ReachTask.info`)."""

RESET_INFO_KEYS = ("distance", "is_success", "clearance")
"""Keys of the single env's reset information (a subset of :data:`INFO_KEYS`)."""


@functools.lru_cache(maxsize=64)
def goal_sampler(region: str, n_joints: int, start_q: tuple[float, ...], base_height: float,
                 kind: str) -> regions.GoalSampler:
    """The goal sampler of a task (shared between envs: it is immutable and takes the rng).

    ``kind`` is the task's ``goal_sampler`` field: ``"joint"`` (:class:`regions.
    JointSpaceSampler`) or ``"cartesian"`` (:class:`regions.CartesianSampler`). Built once per
    distinct task, because construction probes the region's acceptance (and raises
    :class:`regions.UnreachableRegionError` for a region the joints cannot reach).
    """
    cls = regions.JointSpaceSampler if kind == "joint" else regions.CartesianSampler
    return cls(regions.parse(region, base_height), n_joints, start_q, base_height)


def task_sampler(task: TaskSpec) -> regions.GoalSampler:
    """:func:`goal_sampler` for ``task``."""
    return goal_sampler(task.region, task.n_joints, task.start_q, task.base_height,
                        task.goal_sampler)


class ReachTask:
    """Goals, reward, episode end and step information of one :class:`TaskSpec`.

    Parameters
    ----------
    spec : TaskSpec
        The task (checked by the caller: :class:`envs.core.ReachCore` runs
        :func:`envs.validate` before building this).

    Attributes
    ----------
    spec : TaskSpec
    sampler : regions.GoalSampler
        The task's goal sampler (:func:`task_sampler`).
    """

    def __init__(self, spec: TaskSpec) -> None:
        self.spec = spec
        self.sampler = task_sampler(spec)

    # ------------------------------------------------------------------ goals
    def sample_goals(self, rngs: Sequence[np.random.Generator]) -> np.ndarray:
        """One goal per generator, ``(m, 3) float``, m, world frame.

        Goal j is drawn from ``rngs[j]`` alone, so a copy's goals depend on its own seed only.
        """
        goals = [self.sampler.sample(1, rng).goals[0] for rng in rngs]
        return np.array(goals).reshape(len(goals), 3)  # (0, 3) for no generator, not (0,)

    # ------------------------------------------------------------------ step kernels
    def distance(self, achieved: np.ndarray, desired: np.ndarray,
                 out: np.ndarray | None = None) -> np.ndarray:
        """tool0-goal distance ``(...)`` m of goals ``(..., 3)`` m (unchecked)."""
        d = goal_distance(achieved, desired)
        if out is None:
            return d
        out[...] = d
        return out

    def is_success(self, distance: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``distance <= success_radius``, ``(...) bool`` for distances ``(...)`` m."""
        return np.less_equal(distance, self.spec.success_radius, out=out)

    def reward(self, distance: np.ndarray, action: np.ndarray,
               out: np.ndarray | None = None) -> np.ndarray:
        """The reward ``(...)`` of distances ``(...)`` m and actions as applied ``(..., n)``
        (:func:`envs.reward.reach_reward`, unchecked)."""
        r = reach_reward(distance, action, self.spec)
        if out is None:
            return r
        out[...] = r
        return out

    def terminated(self, success: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Whether episodes end on this step, ``(...) bool``: a success, when the task has
        ``terminate_on_success`` (truncation is the step count's, see :class:`ReachCore`)."""
        return np.logical_and(success, self.spec.terminate_on_success, out=out)

    # ------------------------------------------------------------------ GoalEnv functions
    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
        """The reward of transitions, checked (:func:`envs.reward.compute_reward`)."""
        return compute_reward(achieved_goal, desired_goal, info, self.spec)

    def compute_terminated(self, achieved_goal: Any, desired_goal: Any, info: Any
                           ) -> np.ndarray:
        """:meth:`terminated` of transitions from their goals ``(..., 3)`` m, checked as
        :func:`envs.reward.compute_success` (``info`` is unused)."""
        return self.terminated(compute_success(achieved_goal, desired_goal, self.spec))

    # ------------------------------------------------------------------ step information
    @staticmethod
    def info(*, action: np.ndarray, distance: np.ndarray, success: np.ndarray,
             contact: np.ndarray, joint_limit: np.ndarray, clearance: np.ndarray
             ) -> dict[str, np.ndarray]:
        """The step information of B copies, keys :data:`INFO_KEYS` (copies of the inputs).

        Parameters
        ----------
        action : (B, n) float
            The actions as applied (clipped), in the command's unit.
        distance : (B,) float, m
            tool0 to goal.
        success : (B,) bool
            ``distance <= success_radius``.
        contact : (B,) bool
            The ground plane acted during the step.
        joint_limit : (B,) bool
            A joint hit its URDF limit during the step.
        clearance : (B,) float, m, world z
            Lowest point of the moving links at the end of the step.
        """
        values = (action, distance, success, contact, joint_limit, clearance)
        return {key: np.array(value) for key, value in zip(INFO_KEYS, values, strict=True)}

    @staticmethod
    def copy_info(info: dict[str, np.ndarray], index: int,
                  keys: Sequence[str] = INFO_KEYS) -> dict[str, Any]:
        """Copy ``index``'s entries of :meth:`info` as one env's info: Python ``float`` and
        ``bool`` scalars, the action an ``(n,)`` array."""
        row = {}
        for key in keys:
            value = info[key][index]
            row[key] = value.copy() if np.ndim(value) else value.item()
        return row
