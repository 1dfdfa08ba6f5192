"""``UR5Reach-v0``: the paper's UR5 Reacher as a Gymnasium goal env (see :class:`UR5ReachEnv`)."""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any

import gymnasium
import numpy as np

from envs.core import TaskCopies
from envs.physics import Dynamics, make_dynamics
from envs.render import RENDER_MODES, check_render_mode
from envs.spec import TaskSpec, make_task
from envs.task import RESET_INFO_KEYS, real_actions
from envs.vector import reset_options


def with_outer_limit(task: TaskSpec, given: bool) -> TaskSpec:
    """``task`` at the ``max_episode_steps`` of the ``gymnasium.make`` making this env (its
    ``TimeLimit`` wraps the env from outside, and ``make`` keeps the argument to itself: read
    from its frame, which ``tests/test_envs.py`` checks), or a one-line ``ValueError`` when a
    task record ``given`` has another length."""
    frame = inspect.currentframe()
    while frame is not None and frame.f_code is not gymnasium.make.__code__:
        frame = frame.f_back
    limit = None if frame is None else frame.f_locals.get("max_episode_steps")
    if limit in (None, -1, task.max_episode_steps):
        return task
    if given:
        raise ValueError(f"gymnasium.make(..., max_episode_steps={limit!r}) and the task's "
                         f"max_episode_steps={task.max_episode_steps} disagree; give it once")
    return task.replace(max_episode_steps=limit)


class UR5ReachEnv(gymnasium.Env):
    """Move the UR5's end effector (``tool0``) to a goal drawn from a goal constraint region.

    The paper's task (Lewis, Moll, Kavraki 2019; docs/design.md): a UR5 on an impermeable ground
    plane, joints 1..n under a 50 Hz controller, a new goal every episode. Every number below
    is a field of the task (:class:`envs.TaskSpec`, ``env.unwrapped.task``); the tables give
    the defaults. World frame: ground plane z = 0, robot base at (0, 0, ``base_height`` = 0.1 m),
    +x along the arm at all-zero joint angles.

    ## Action Space

    ``Box(low, high, (n,), float64)``, the command of joints 1..n (``n_joints`` = n, 2-6).
    Actions outside the box are clipped; an action that is not n finite real numbers raises
    ``ValueError``; ``step`` before the first ``reset`` raises
    ``gymnasium.error.ResetNeeded`` (there is no goal yet).

    | Num | Action, by ``control_mode``                 | Min                 | Max        | Unit  |
    |-----|---------------------------------------------|---------------------|------------|-------|
    | i   | ``position`` (default): joint i+1's target  | -pi                 | pi         | rad   |
    | i   | ``velocity``: joint i+1's target velocity   | -3.15 (wrists -3.2) | 3.15 (3.2) | rad/s |
    | i   | ``torque``: torque on joint i+1, plus g(q)  | -150 (wrists -28)   | 150 (28)   | N m   |

    A joint PD controller with gravity compensation turns the command into torques, saturated at
    the URDF effort limits, integrated at ``sim_hz`` = 1000 Hz; joints n+1..6 stay at their
    start angles (``held_joints``), and the URDF joint limits and the ground plane
    (``contact_model``) stop or push the arm: docs/design.md, "Dynamics".
    ``env.unwrapped.joint_angles`` gives all six angles.

    ## Observation Space

    A ``Dict`` of ``float64`` arrays. ``observation``, ``(3n,)``:

    | Num      | Observation                                | Min          | Max        | Unit    |
    |----------|--------------------------------------------|--------------|------------|---------|
    | 0..n-1   | theta, angles of joints 1..n               | -2 pi (elbow -pi) | 2 pi (pi) | rad |
    | n..2n-1  | theta_dot, velocities of joints 1..n       | -3.15 (-3.2) | 3.15 (3.2) | rad/s   |
    | 2n..3n-1 | theta_ddot, mean acceleration over the step | -Inf        | Inf        | rad/s^2 |

    | Key               | Observation                               | Min  | Max | Unit |
    |-------------------|-------------------------------------------|------|-----|------|
    | ``desired_goal``  | goal x, y, z, world frame, ``(3,)``       | -Inf | Inf | m    |
    | ``achieved_goal`` | tool0 x, y, z, world frame, ``(3,)``      | -Inf | Inf | m    |

    The paper's flat state ``[theta, theta_dot, theta_ddot, goal - fk(theta), goal]``
    (3n + 6 values) is :class:`envs.FlatObservation` of this env.

    ## Rewards

    With ``d`` the tool0-goal distance after the step and ``a`` the action as applied:

    | ``reward_type``        | Reward per step                             | Unit        |
    |------------------------|---------------------------------------------|-------------|
    | ``dense`` (paper eq. 2) | ``-1.0 d - 1.0 |a|^2 + 100 * 1{d <= 0.1}`` | d in m, a in rad |
    | ``sparse``             | ``100 * 1{d <= 0.1}``                       | d in m      |

    The numbers are ``distance_weight``, ``action_weight``, ``success_reward`` and
    ``success_radius``. ``compute_reward(achieved_goal, desired_goal, info)`` is vectorised
    over any batch; the dense reward reads the action from ``info["action"]`` (a dict of batched
    arrays, or a list/array of step infos as Stable-Baselines3's HER buffer passes them with
    ``copy_info_dict=True``). ``reward == env.compute_reward(obs["achieved_goal"],
    obs["desired_goal"], info)`` holds exactly.

    ## Starting State

    | Item             | Value                                                    | Unit    |
    |------------------|----------------------------------------------------------|---------|
    | joint angles     | region ``unconstrained``: (0, 0, 0, 0, 0, 0)             | rad     |
    | joint angles     | other regions: (0, -pi/4, pi/2, 0, 0, 0)                 | rad     |
    | joint velocities | 0                                                        | rad/s   |
    | theta_ddot       | 0                                                        | rad/s^2 |
    | goal             | tool0 at joints 1..n uniform in [-pi, pi] (the others at | m       |
    |                  | the start), kept when in the region with the arm clear   |         |
    |                  | of the plane (``goal_sampler="joint"``)                  |         |

    ``reset(seed=s)`` reproduces goals and trajectories exactly; ``reset(options={"goal":
    (x, y, z)})`` sets the goal (m, world frame) instead of drawing it.

    ## Episode End

    | End          | When                                                          | Unit  |
    |--------------|---------------------------------------------------------------|-------|
    | terminated   | d <= ``success_radius`` = 0.1 (if ``terminate_on_success``)   | m     |
    | truncated    | after ``max_episode_steps`` = 100 steps (2 s at 50 Hz)        | steps |

    The task's ``max_episode_steps`` truncates (``make(..., task=TaskSpec(max_episode_steps=
    200))``); the id is registered without an outer time limit. ``make(...,
    max_episode_steps=50)`` and ``make_vec(..., max_episode_steps=50)`` set the task's length
    to 50 (``make``'s own ``TimeLimit`` then ends the same step); ``make`` refuses a
    ``task=`` of another length beside it (`with_outer_limit`).

    ## Info

    | Key             | Content                                                 | Unit       |
    |-----------------|---------------------------------------------------------|------------|
    | ``action``      | the action as applied (clipped), ``(n,)``               | action's   |
    | ``distance``    | d, tool0 to goal                                        | m          |
    | ``is_success``  | d <= ``success_radius``                                 | -          |
    | ``contact``     | the ground plane acted during the step: it stopped the   | -          |
    |                 | arm (``stop``), or pushed it (``compliant``)             |            |
    | ``joint_limit`` | a joint hit its URDF limit during the step and stopped  | -          |
    | ``clearance``   | lowest point of the moving links at the end of the step | m, world z |

    ``reset`` returns ``distance``, ``is_success`` and ``clearance``.

    ## Arguments

    ``gymnasium.make("UR5Reach-v0", region="zheight", n_joints=3, **fields)`` takes any
    :class:`TaskSpec` field as a keyword, or ``task=TaskSpec(...)`` (and overrides; ``spec=``
    is its deprecated name), and
    ``render_mode`` (``"rgb_array"`` or ``"human"``). ``region``: a registered name
    (``unconstrained``, ``zheight``, ``closebox``, ``farbox``, ``farbox_tall``), a string of
    :func:`regions.parse`, or a :class:`regions.Region`.

    ## Version History

    - v0: first version.
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 50}  # noqa: RUF012

    def __init__(self, task: TaskSpec | Mapping[str, Any] | None = None,
                 render_mode: str | None = None, **overrides: Any) -> None:
        self.task = with_outer_limit(make_task(task, overrides), task is not None)
        task, n = self.task, self.task.n_joints
        self.render_mode = check_render_mode(render_mode)
        self.metadata = {**self.metadata, "render_fps": task.control_hz}
        # one copy: the reference backend
        self._core = TaskCopies(task, 1, make_dynamics(task, 1, "pinocchio"))
        self.observation_space, self.action_space = self._core.single_spaces()
        self._n = n
        self._renderer: Any = None

    @property
    def dt(self) -> float:
        """Duration of one step (s): 1 / control_hz = 0.02 by default."""
        return self.task.dt

    @property
    def dynamics(self) -> Dynamics:
        """The arm's dynamics (:class:`envs.physics.Dynamics`, one copy), for studies that read
        more of the arm than the observation (its ``depth_stop`` under the compliant contact);
        read it, never step it."""
        return self._core.dynamics

    @property
    def joint_angles(self) -> np.ndarray:
        """All six joint angles now, ``(6,) float, rad`` (a copy): the observation holds only
        joints 1..n (the held joints n+1..6 stay at their start angles under
        ``held_joints="locked"`` and give way under load under ``"pd"``; see Action Space)."""
        return self._core.dynamics.q[0].copy()

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        goals = None
        options = reset_options(options, ("goal",), "{'goal': (x, y, z)}")
        if options:
            goal = real_actions(options["goal"])  # None for strings, complex, objects
            if goal is None or goal.shape != (3,) or not np.all(np.isfinite(goal)):
                raise ValueError(f"options['goal'] must be 3 finite numbers (x, y, z in m, world "
                                 f"frame); got {options['goal']!r}")
            goals = goal[None]
        core = self._core
        core.reset([0], [self.np_random], goals)
        info = core.rules.copy_info(core.info_arrays(), 0, RESET_INFO_KEYS)
        if self.render_mode == "human":
            self.render()
        return self._observation(), info

    def step(self, action: Any) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        a = real_actions(action)
        if a is None or a.shape != (self._n,) or not np.isfinite(a).all():
            raise ValueError(f"action must be {self._n} finite numbers (the "
                             f"{self.task.control_mode} command of joints 1..{self._n}); got "
                             f"{action!r}")
        core = self._core
        core.step(a.reshape(1, self._n))
        info = core.rules.copy_info(core.info_arrays(), 0)
        if self.render_mode == "human":
            self.render()
        return (self._observation(), float(core.reward[0]), bool(core.terminated[0]),
                bool(core.truncated[0]), info)

    def _observation(self) -> dict[str, np.ndarray]:
        core = self._core
        return {"observation": core.observation[0].copy(),
                "achieved_goal": core.achieved[0].copy(),
                "desired_goal": core.goal[0].copy()}

    # ------------------------------------------------------------------ GoalEnv API
    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
        """Reward for reaching ``achieved_goal (..., 3)`` m when aiming at ``desired_goal
        (..., 3)`` m; ``info`` carries the action (see the Rewards section). Returns ``(...)``.

        Goals or actions that are not finite real numbers, or whose shapes do not fit, raise
        ``ValueError`` naming them (never a NaN reward); see :mod:`envs.reward`."""
        return self._core.rules.compute_reward(achieved_goal, desired_goal, info)

    def compute_terminated(self, achieved_goal: Any, desired_goal: Any, info: Any
                           ) -> np.ndarray:
        """Whether such transitions end the episode: success, if ``terminate_on_success``.
        Bad goals raise ``ValueError`` as in :meth:`compute_reward`."""
        return self._core.rules.compute_terminated(achieved_goal, desired_goal, info)

    def compute_truncated(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
        """Always False: truncation depends on the step count, not on the goals."""
        return np.zeros(np.shape(achieved_goal)[:-1], dtype=bool)

    # ------------------------------------------------------------------ rendering
    def render(self) -> np.ndarray | None:
        """Draw the arm, the goal and the region (see :mod:`envs.render`).

        Returns an ``(H, W, 3) uint8`` frame in ``rgb_array`` mode, None in ``human`` mode.
        """
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass "
                                  "render_mode='rgb_array' or 'human' to gymnasium.make")
            return None
        if self._renderer is None:
            from envs.render import ArmRenderer

            self._renderer = ArmRenderer(self.task, human=self.render_mode == "human")
        core, task = self._core, self.task
        title = (f"{self._renderer.region_name()}, {task.n_joints} joints: "
                 f"t = {core.elapsed[0] * task.dt:.2f} s, d = {core.distance[0]:.3f} m")
        return self._renderer.draw(core.dynamics.q[0], core.goal[0],
                                   success=bool(core.success[0]),
                                   contact=bool(core.dynamics.contact[0]), title=title)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
