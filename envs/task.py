"""The Reacher's task rules in one place: goal sampling, the action box and the spaces, reward,
success and termination, step information, what an env does with an ended episode.

:class:`TaskRules` is the task half of the env in panda-gym's sense (its ``Task`` beside the
``Robot``): it knows the goal region, the reward and when an episode ends, and nothing of the
arm's motion. Every env, :class:`envs.core.TaskCopies` and the studies take their rules from
here, so they are written once.

The step kernels (:meth:`TaskRules.is_success`, :meth:`TaskRules.reward`,
:meth:`TaskRules.terminated`) take values the env made itself and do not check them; the GoalEnv
functions (:func:`compute_reward`, :func:`compute_success`) check what a caller passes with
:mod:`envs.reward`'s checks.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium.vector import AutoresetMode

import regions
import ur5kin
from envs.reward import (
    ACTION_KEY,
    checked_goals,
    goal_distance,
    info_actions,
    reach_reward,
    real_array,
)
from envs.spec import TaskSpec

INFO_KEYS = (ACTION_KEY, "distance", "is_success", "contact", "joint_limit", "clearance")
"""Keys of the step information, in order (see :meth:`TaskRules.info`)."""

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


def action_bounds(task: TaskSpec) -> tuple[np.ndarray, np.ndarray]:
    """The action box: the valid commands of the controlled joints in the task's control mode.

    Returns
    -------
    low, high : (n,) float
        Position: the joint-space goal range ``[-pi, pi]`` (rad, :data:`ur5kin.JOINT_LIMIT`);
        velocity: the URDF velocity limits (rad/s); torque: the URDF effort
        limits (N m).
    """
    n = task.n_joints
    if task.control_mode == "position":
        high = np.full(n, ur5kin.JOINT_LIMIT)
    elif task.control_mode == "velocity":
        high = ur5kin.velocity_limits()[:n]
    else:
        high = ur5kin.effort_limits()[:n]
    return -high, high.copy()


@functools.cache
def action_penalty_scale(task: TaskSpec) -> np.ndarray:
    """Per-joint divisor ``(n,)`` applied to the action before eq. 2 squares it
    (:func:`envs.reward.reach_reward`'s ``scale``).

    Ones for ``action_penalty_unit="command"`` (the command's own unit); the bound of the
    action box (:func:`action_bounds`: pi rad in position mode) for ``"actor"``.
    """
    if task.action_penalty_unit == "command":
        return np.ones(task.n_joints)
    return action_bounds(task)[1]


def single_spaces(task: TaskSpec) -> tuple[gymnasium.spaces.Dict, gymnasium.spaces.Box]:
    """Observation and action space of one copy of ``task``.

    The observation is a goal-env Dict: ``observation (3n,)`` bounded by the URDF joint
    position and velocity limits (the dynamics enforce both; the acceleration is
    unbounded), ``achieved_goal`` and ``desired_goal`` ``(3,)`` unbounded; the action box is
    :func:`action_bounds`. All float64.
    """
    model, n = ur5kin.load_model(), task.n_joints
    vel = ur5kin.velocity_limits()[:n]
    low = np.concatenate([model.lowerPositionLimit[:n], -vel, np.full(n, -np.inf)])
    high = np.concatenate([model.upperPositionLimit[:n], vel, np.full(n, np.inf)])
    box = gymnasium.spaces.Box
    observation = gymnasium.spaces.Dict({
        "observation": box(low, high, dtype=np.float64),
        "achieved_goal": box(-np.inf, np.inf, (3,), np.float64),
        "desired_goal": box(-np.inf, np.inf, (3,), np.float64),
    })
    action_low, action_high = action_bounds(task)
    return observation, box(np.asarray(action_low, dtype=np.float64),
                            np.asarray(action_high, dtype=np.float64), dtype=np.float64)


def real_actions(action: Any) -> np.ndarray | None:
    """``action`` as a float64 array, or None when it is not real numbers (strings, complex,
    None, objects): the step methods turn None into their ValueError."""
    arr = np.asarray(action)
    if arr.dtype.kind in "biuf":
        return arr.astype(np.float64, copy=False)
    if arr.dtype.kind == "O":
        try:
            return np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            return None
    return None


def as_autoreset_mode(mode: AutoresetMode | str) -> AutoresetMode:
    """An AutoresetMode from itself, its value (``"NextStep"``) or its name (``"next_step"``):
    what the vector envs do with a copy whose episode ended."""
    if isinstance(mode, AutoresetMode):
        return mode
    for member in AutoresetMode:
        if mode in (member.value, member.name.lower()):
            return member
    raise ValueError(f"autoreset_mode must be one of "
                     f"{[m.name.lower() for m in AutoresetMode]} (or a gymnasium.vector."
                     f"AutoresetMode); got {mode!r}")


def compute_reward(achieved_goal: Any, desired_goal: Any, info: Any, task: TaskSpec
                   ) -> np.ndarray:
    """Reward of transitions that reached ``achieved_goal`` while aiming at ``desired_goal``.

    Parameters
    ----------
    achieved_goal, desired_goal : (..., 3) float array_like, m, world frame
    info : dict or sequence of dicts
        See :func:`info_actions`; ignored by the sparse reward.
    task : TaskSpec

    Returns
    -------
    reward : (...) float
        Finite.

    Raises
    ------
    ValueError
        When a goal or action is not real, not finite, or of a shape that does not fit (see
        envs.reward), or the dense reward finds no action in ``info``.
    """
    distance = goal_distance(*checked_goals(achieved_goal, desired_goal))
    if task.reward_type == "sparse":
        return reach_reward(distance, None, task, None)
    action = real_array(info_actions(info), "info['action']", "the action as applied, (..., n)")
    if action.ndim == 0 or action.shape[-1] != task.n_joints:
        raise ValueError(f"info['action'] must have shape (..., {task.n_joints}) (the action "
                         f"of joints 1..{task.n_joints}); got shape {action.shape}")
    try:
        np.broadcast_shapes(distance.shape, action.shape[:-1])
    except ValueError:
        raise ValueError(f"info['action'] {action.shape} does not fit the goals' batch shape "
                         f"{distance.shape}: one action per transition") from None
    if not isinstance(info, Mapping) and action.shape[:-1] != distance.shape:
        # one info per transition: a shorter list would be broadcast over the batch silently
        raise ValueError(f"{action.shape[:-1]} infos for goals of batch shape {distance.shape}: "
                         "pass one info per transition")
    with np.errstate(over="ignore", invalid="ignore"):  # named below instead
        reward = reach_reward(distance, action, task, action_penalty_scale(task))
    if not np.all(np.isfinite(reward)):
        at = np.argwhere(~np.isfinite(np.asarray(reward)))[0].tolist()
        raise ValueError(f"the reward is not finite at {at} ({np.asarray(reward)[tuple(at)]}): "
                         "its action's penalty overflows (an action far outside the action "
                         "space?)")
    return reward


def compute_success(achieved_goal: Any, desired_goal: Any, task: TaskSpec) -> np.ndarray:
    """Whether tool0 is within ``success_radius`` of the goal, ``(...) bool``.

    Raises
    ------
    ValueError
        As :func:`compute_reward`, for goals.
    """
    return goal_distance(*checked_goals(achieved_goal, desired_goal)) <= task.success_radius


class TaskRules:
    """Goals, reward, episode end and step information of one :class:`TaskSpec`.

    Parameters
    ----------
    spec : TaskSpec
        The task (checked by the caller: :class:`envs.core.TaskCopies` runs
        :func:`envs.validate` before building this).

    Attributes
    ----------
    spec : TaskSpec
    sampler : regions.GoalSampler
        The task's goal sampler (:func:`task_sampler`).
    penalty_scale : (n,) float
        :func:`action_penalty_scale` of the task.
    """

    def __init__(self, spec: TaskSpec) -> None:
        self.spec = spec
        self.sampler = task_sampler(spec)
        self.penalty_scale = action_penalty_scale(spec)

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
        r = reach_reward(distance, action, self.spec, self.penalty_scale)
        if out is None:
            return r
        out[...] = r
        return out

    def terminated(self, success: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Whether episodes end on this step, ``(...) bool``: a success, when the task has
        ``terminate_on_success`` (truncation is the step count's, see :class:`TaskCopies`)."""
        return np.logical_and(success, self.spec.terminate_on_success, out=out)

    # ------------------------------------------------------------------ GoalEnv functions
    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
        """The reward of transitions, checked (:func:`compute_reward`)."""
        return compute_reward(achieved_goal, desired_goal, info, self.spec)

    def compute_terminated(self, achieved_goal: Any, desired_goal: Any, info: Any
                           ) -> np.ndarray:
        """:meth:`terminated` of transitions from their goals ``(..., 3)`` m, checked as
        :func:`compute_success` (``info`` is unused)."""
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
