"""Many copies of the Reacher stepped in one call: a Gymnasium ``VectorEnv`` for trainers."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from envs.core import TaskCopies
from envs.physics import make_dynamics
from envs.render import RENDER_MODES, check_render_mode
from envs.spec import TaskSpec, make_task
from envs.task import INFO_KEYS, as_autoreset_mode, real_actions
from envs.vector import copy_seeds, reset_options
from ur5kin.checks import COUNT


class BatchedReach(gymnasium.vector.VectorEnv):
    """N copies of ``UR5Reach-v0`` advanced together by one batched dynamics call.

    Copy i behaves exactly like ``gymnasium.make("UR5Reach-v0", ...)`` reset with seed
    ``seed + i`` (same goals; same trajectories up to floating-point rounding, since the batch
    goes through the compiled kernel of :mod:`envs.physics.numba_kernel` or Pinocchio's
    ``abaInParallel``). ``gymnasium.make_vec("UR5Reach-v0", num_envs=N)`` builds this class.

    Parameters
    ----------
    num_envs : int
        N, the number of copies.
    task : TaskSpec or its dict form, optional
        The task (defaults as :class:`TaskSpec`); ``**overrides`` change fields.
    autoreset_mode : gymnasium.vector.AutoresetMode or str
        What happens to a copy whose episode ended (terminated or truncated):

        - ``next_step`` (Gymnasium's default): the next ``step`` resets it instead of stepping
          it; its action is ignored, and it returns the first observation of the new episode
          with reward 0 and both flags False.
        - ``same_step``: it is reset within the same ``step``; the returned observation is the
          new episode's first, the episode's last observation and info are in
          ``info["final_obs"]`` / ``info["final_info"]`` (object arrays of one copy's dicts;
          masks ``info["_final_obs"]``, ``info["_final_info"]``).
        - ``disabled``: never reset automatically; ``reset(options={"reset_mask": done})``.
    render_mode : {"rgb_array", "human"}, optional
        ``render()`` draws every copy (one frame each).
    dynamics : {"auto", "pinocchio", "numba"}
        Which backend advances the arms (:data:`envs.physics.BACKENDS`); the same physics to
        floating-point rounding. ``auto`` (default) takes the compiled numba path for N > 1.
    device : str
        Where the arms are stepped: ``"cpu"``, the only one (a GPU's arm is the training
        program's, :class:`envs.stackreach.StackReach`; another device is refused).
    threads : int
        CPU threads of the fast path (default 1: the two-core machines this runs on share
        their cores with the learner; more pay on many-core hosts at large N).

    Observations are the single env's Dict with a leading (N,) axis; ``info`` holds
    :data:`envs.task.INFO_KEYS` as (N, ...) arrays, each with a ``_key`` mask.
    """

    def __init__(self, num_envs: int = 1, task: TaskSpec | Mapping[str, Any] | None = None, *,
                 autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 render_mode: str | None = None, dynamics: str = "auto", device: str = "cpu",
                 threads: int = 1, **overrides: Any) -> None:
        num_envs = COUNT("num_envs", num_envs)
        mode = as_autoreset_mode(autoreset_mode)
        self.task = make_task(task, overrides)
        self.num_envs = num_envs
        self.render_mode = check_render_mode(render_mode)
        self.metadata = {"autoreset_mode": mode, "render_modes": list(RENDER_MODES),
                         "render_fps": self.task.control_hz}
        self._core = TaskCopies(self.task, self.num_envs,
                               make_dynamics(self.task, self.num_envs, dynamics, device,
                                             threads))
        self.single_observation_space, self.single_action_space = self._core.single_spaces()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._ended = np.zeros(self.num_envs, dtype=bool)  # episodes awaiting a next-step reset
        self._true = np.ones(self.num_envs, dtype=bool)
        self._renderers: list[Any] = []

    @property
    def dt(self) -> float:
        """Duration of one step (s)."""
        return self.task.dt

    # ------------------------------------------------------------------ VectorEnv API
    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Reset copies (all of them, or ``options["reset_mask"]`` (N,) bool).

        ``seed``: an int seeds copy i with ``seed + i``; a sequence gives each copy its seed;
        None keeps each copy's generator (fresh entropy on the first reset).
        ``options["goal"]``: ``(m, 3)`` m goals for the m copies reset, instead of drawing them.
        """
        options = reset_options(options, ("reset_mask", "goal"),
                                "{'reset_mask': (N,) bool, 'goal': (m, 3) m}")
        mask = np.asarray(options.get("reset_mask", self._true))
        if mask.dtype != np.bool_ or mask.shape != (self.num_envs,):
            # 0/1 integers would pass a cast to bool while meaning indices to a numpy user
            raise ValueError(f"options['reset_mask'] must be a ({self.num_envs},) bool array; got "
                             f"{mask.dtype} of shape {mask.shape}")
        seeds = copy_seeds(seed, self.num_envs)
        index = np.flatnonzero(mask)
        for i in index:
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i] = seeding.np_random(seeds[i])[0]
        goals = None
        if "goal" in options:
            goals = real_actions(options["goal"])  # None for strings, complex, objects
            if goals is None or goals.shape != (len(index), 3) or not np.all(np.isfinite(goals)):
                raise ValueError(f"options['goal'] must be ({len(index)}, 3) finite goals (m, "
                                 f"world frame), one per copy reset; got "
                                 f"{options['goal']!r:.200}")
        self._core.reset(index, [self._rngs[i] for i in index], goals)
        self._ended[index] = False
        return self._observation(), self._info()

    def step(self, actions: Any
             ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Step every copy with ``actions (N, n)``; see ``autoreset_mode`` for episode ends.

        Returns observations (dict of (N, ...)), rewards (N,), terminations (N,), truncations
        (N,) and infos (dict of (N, ...) with ``_key`` masks). Raises ValueError when
        ``actions`` is not a finite real (N, n) array, gymnasium.error.ResetNeeded when a copy
        has never been reset.
        """
        reward, terminated, truncated = self._advance(self._checked_actions(actions))
        mode = self.metadata["autoreset_mode"]
        if mode == AutoresetMode.NEXT_STEP:
            ended = self._ended
            self._reset_where(ended)  # the copies that ended last step start anew instead
            keep = ~ended
            reward = np.where(keep, reward, 0.0)
            terminated, truncated = terminated & keep, truncated & keep
            self._ended = terminated | truncated
            return self._observation(), reward, terminated, truncated, self._info()
        info = self._info()
        if mode == AutoresetMode.SAME_STEP:
            done = terminated | truncated
            info.update(self._final(info, done))
            self._reset_where(done)
        return self._observation(), reward, terminated, truncated, info

    def _checked_actions(self, actions: Any) -> np.ndarray:
        a, n = real_actions(actions), self.task.n_joints
        if a is None or a.shape != (self.num_envs, n) or not np.isfinite(a).all():
            if a is None:
                got = repr(actions)
            elif a.shape != (self.num_envs, n):
                got = f"shape {a.shape}"
            else:  # the real cause: the shape is right
                at = np.argwhere(~np.isfinite(a))[0].tolist()
                got = f"{a[tuple(at)]} at {at}"
            raise ValueError(f"actions must be a finite ({self.num_envs}, {n}) array (the "
                             f"{self.task.control_mode} commands of joints 1..{n}); got {got}")
        return a

    def _advance(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        core = self._core
        core.step(actions)
        return core.reward.copy(), core.terminated.copy(), core.truncated.copy()

    def _reset_where(self, mask: np.ndarray) -> None:
        if mask.any():
            index = np.flatnonzero(mask)
            self._core.reset(index, [self._rngs[i] for i in index])

    def _final(self, info: dict[str, Any], done: np.ndarray) -> dict[str, Any]:
        if not done.any():
            return {}
        final_obs = np.empty(self.num_envs, dtype=object)
        final_info = np.empty(self.num_envs, dtype=object)
        last = self._observation()
        for i in np.flatnonzero(done):
            final_obs[i] = {key: value[i] for key, value in last.items()}
            final_info[i] = {key: info[key][i] for key in INFO_KEYS}
        return {"final_obs": final_obs, "_final_obs": done.copy(), "final_info": final_info,
                "_final_info": done.copy()}

    def _observation(self) -> dict[str, np.ndarray]:
        core = self._core
        return {"observation": core.observation.copy(), "achieved_goal": core.achieved.copy(),
                "desired_goal": core.goal.copy()}

    def _info(self) -> dict[str, Any]:
        info = self._core.info_arrays()
        info.update({f"_{key}": self._true.copy() for key in INFO_KEYS})
        return info

    # ------------------------------------------------------------------ GoalEnv functions
    def compute_reward(self, achieved_goal: Any, desired_goal: Any, info: Any) -> np.ndarray:
        """The task's reward, vectorised (see :meth:`envs.UR5ReachEnv.compute_reward`)."""
        return self._core.rules.compute_reward(achieved_goal, desired_goal, info)

    def compute_terminated(self, achieved_goal: Any, desired_goal: Any, info: Any
                           ) -> np.ndarray:
        """Success, if ``terminate_on_success`` (as :meth:`envs.UR5ReachEnv.compute_terminated`)."""
        return self._core.rules.compute_terminated(achieved_goal, desired_goal, info)

    # ------------------------------------------------------------------ rendering
    def render(self) -> tuple[np.ndarray, ...] | None:
        """One frame per copy in ``rgb_array`` mode (see :mod:`envs.render`); None otherwise."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode")
            return None
        from envs.render import ArmRenderer

        while len(self._renderers) < self.num_envs:
            self._renderers.append(ArmRenderer(self.task, human=self.render_mode == "human"))
        core = self._core
        frames = tuple(r.draw(core.dynamics.q[i], core.goal[i], success=bool(core.success[i]),
                              contact=bool(core.dynamics.contact[i]))
                       for i, r in enumerate(self._renderers))
        return None if self.render_mode == "human" else frames

    def close_extras(self, **kwargs: Any) -> None:
        for renderer in self._renderers:
            renderer.close()
        self._renderers = []
