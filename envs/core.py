"""B copies of the Reacher task as arrays: goals, dynamics, observations, rewards, episode ends.

The single env (:class:`envs.reach.UR5ReachEnv`, B = 1) and the batched one
(:class:`envs.batched.BatchedReach`) are thin Gymnasium faces over this one class, so they
cannot drift apart. The task's rules (goals, reward, episode end, step information) are
:class:`envs.task.TaskRules`'s; this class holds the arrays and calls it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np

from envs.physics.model import clip, moving_link_heights
from envs.physics.protocol import Dynamics
from envs.spec import TaskSpec
from envs.task import TaskRules, action_bounds, single_spaces

GOAL_TOLERANCE = 1e-6
"""m: how far past the plane or the reach ball a given goal may lie and still be taken: goals
handed back from float32 observations (ddpg_her's envs) round by up to about 1e-7 m."""


def check_reachable_goals(goals: np.ndarray, base_height: float) -> None:
    """Raise ValueError naming the first of ``goals (m, 3) m, world frame`` that lies under the
    ground plane or outside the arm's reach ball (centre at the shoulder, radius
    `regions.reach.reach_radius`)."""
    from regions.reach import reach_ball

    ball = reach_ball(base_height)
    distance = np.linalg.norm(goals - np.asarray(ball.center), axis=-1)
    for i, (goal, d) in enumerate(zip(goals, distance, strict=True)):
        if goal[2] < -GOAL_TOLERANCE:
            raise ValueError(f"goal {i} {goal.tolist()} m lies under the ground plane (z < 0): "
                             "no episode can reach it")
        if d > ball.radius + GOAL_TOLERANCE:
            raise ValueError(f"goal {i} {goal.tolist()} m lies {d:.3f} m from the shoulder, "
                             f"beyond the arm's reach of {ball.radius:.3f} m: no episode can "
                             "reach it")


class TaskCopies:
    """B copies of the task, stepped together.

    Parameters
    ----------
    task : TaskSpec
    num_copies : int
        B.
    dynamics : Dynamics
        The arm's dynamics of the B copies of ``task``: any backend of the
        :class:`envs.physics.Dynamics` protocol, as :func:`envs.physics.make_dynamics` builds
        them (which checks the task against the robot: the one check of an env).

    Attributes
    ----------
    rules : TaskRules
        Goal sampling, reward, termination and the step information of ``task``.
    goal : (B, 3) float, m, world frame
        Desired goals.
    achieved : (B, 3) float, m, world frame
        tool0 positions (base at (0, 0, base_height)).
    observation : (B, 3n) float
        [theta (rad), theta_dot (rad/s), theta_ddot (rad/s^2)] of joints 1..n.
    action : (B, n) float
        The last actions as applied (clipped to :attr:`action_low`, :attr:`action_high`).
    distance, reward : (B,) float
        tool0-goal distance (m) and reward after the last step.
    success, terminated, truncated : (B,) bool
    elapsed : (B,) int
        Steps since each copy's reset.
    started : (B,) bool
        Whether each copy has been reset at least once (:meth:`step` refuses otherwise).

    Arrays are overwritten in place by every call; copy what you keep.
    """

    def __init__(self, task: TaskSpec, num_copies: int, dynamics: Dynamics) -> None:
        n, B = task.n_joints, num_copies
        if dynamics.num_copies != num_copies or dynamics.task != task:
            raise ValueError(f"dynamics must be of the {num_copies} copies of this task; got "
                             f"{dynamics.num_copies} copies of "
                             f"{'this' if dynamics.task == task else 'another'} task")
        self.dynamics = dynamics
        self.task = task
        self.rules = TaskRules(task)
        self.action_low, self.action_high = action_bounds(task)
        self.goal = np.zeros((B, 3))
        self.achieved = np.zeros((B, 3))
        self.observation = np.zeros((B, 3 * n))
        self.action = np.zeros((B, n))
        self.distance = np.zeros(B)
        self.reward = np.zeros(B)
        self.success = np.zeros(B, dtype=bool)
        self.terminated = np.zeros(B, dtype=bool)
        self.truncated = np.zeros(B, dtype=bool)
        self.elapsed = np.zeros(B, dtype=np.int64)
        self.started = np.zeros(B, dtype=bool)
        self._start_q = np.asarray(task.start_q)

    def reset(self, index: Sequence[int] | np.ndarray, rngs: Sequence[np.random.Generator],
              goals: np.ndarray | None = None) -> None:
        """Start new episodes in copies ``index``: arm at rest at the start pose, new goals.

        Parameters
        ----------
        index : (m,) int
            Copies to reset.
        rngs : sequence of m numpy.random.Generator
            Each copy's generator; copy ``index[j]``'s goal is drawn from ``rngs[j]`` alone.
        goals : (m, 3) float, m, world frame, optional
            Goals to use instead of drawing them.

        Raises
        ------
        ValueError
            When a given goal lies under the ground plane (z < 0) or outside the ball that
            holds every tool0 position of the arm (`regions.reach.reach_ball`): no episode
            could reach it, and its success rate would be 0 without a word.
        """
        index = np.asarray(index, dtype=np.intp)
        if goals is not None:
            check_reachable_goals(np.asarray(goals, dtype=float), self.task.base_height)
        if goals is None:
            goals = self.rules.sample_goals(rngs)
        self.goal[index] = goals
        self.dynamics.reset(self._start_q, index)
        self.elapsed[index] = 0
        self.started[index] = True
        self.action[index] = 0.0
        self.terminated[index] = False
        self.truncated[index] = False
        self.reward[index] = 0.0
        self._observe()

    def step(self, action: np.ndarray) -> None:
        """Apply ``action (B, n)`` (clipped to the action box) to every copy for one step.

        Raises
        ------
        gymnasium.error.ResetNeeded
            When a copy has never been reset: it has no goal yet, and stepping it would reward
            reaching (0, 0, 0).
        """
        if not self.started.all():
            never = np.flatnonzero(~self.started).tolist()
            raise gymnasium.error.ResetNeeded(
                f"step() before reset(): cop{'y' if len(never) == 1 else 'ies'} {never} of "
                f"{len(self.started)} {'has' if len(never) == 1 else 'have'} no episode (no goal) "
                "yet; call reset() first")
        clip(action, self.action_low, self.action_high, self.action)
        self.dynamics.step(self.action)
        self.elapsed += 1
        self._observe()
        self.rules.reward(self.distance, self.action, out=self.reward)
        self.rules.terminated(self.success, out=self.terminated)
        np.greater_equal(self.elapsed, self.task.max_episode_steps, out=self.truncated)

    def _observe(self) -> None:
        """Refresh observation, achieved goal, distance and success from the dynamics."""
        dyn, n = self.dynamics, self.task.n_joints
        # a view taken here, not kept: a deep copy or pickle of the env copies arrays, not views
        obs = self.observation.reshape(-1, 3, n)  # (B, theta/theta_dot/theta_ddot, n)
        obs[:, 0], obs[:, 1], obs[:, 2] = dyn.q[:, :n], dyn.v[:, :n], dyn.acceleration[:, :n]
        dyn.tool_positions(self.achieved)
        self.rules.distance(self.achieved, self.goal, out=self.distance)
        self.rules.is_success(self.distance, out=self.success)

    def single_spaces(self) -> tuple[gymnasium.spaces.Dict, gymnasium.spaces.Box]:
        """Observation and action space of one copy (:func:`single_spaces` of the task)."""
        return single_spaces(self.task)

    def clearance(self) -> np.ndarray:
        """Lowest point of the moving links (shoulder to wrist 3 with the tool flange) now,
        ``(B,) float``, m, world z (the ground plane is z = 0; negative would be below it).

        Exact (one link-height evaluation per copy), not the dynamics' conservative bound.
        """
        return moving_link_heights(self.dynamics.q, self.task.base_height).min(axis=-1)

    def info_arrays(self) -> dict[str, Any]:
        """Per-copy step information now, :meth:`envs.task.TaskRules.info` of the B copies."""
        dyn = self.dynamics
        return self.rules.info(action=self.action, distance=self.distance, success=self.success,
                               contact=dyn.contact, joint_limit=dyn.limit_stop,
                               clearance=self.clearance())
