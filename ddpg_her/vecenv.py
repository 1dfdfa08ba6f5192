"""N goal envs stepped in lockstep, and the rollout of one episode in each.

The agent sees the env only through the Gymnasium goal-env API: a Dict observation with
``observation``, ``achieved_goal`` and ``desired_goal``, a Box action, ``info["is_success"]``, and
the vectorised ``compute_reward`` / ``compute_terminated`` of ``env.unwrapped``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import gymnasium
import numpy as np

from ddpg_her.buffer import Episode
from ddpg_her.spaces import ActionScale

KEYS = ("observation", "achieved_goal", "desired_goal")


class GoalVecEnv:
    """N copies of one Gymnasium goal env, made by ``gymnasium.make(env_id, **kwargs)``.

    Each copy is reseeded at every reset from the seed given for it, so an episode depends only
    on its own seed: nothing about the env needs saving in a checkpoint.
    """

    def __init__(self, env_id: str, num_envs: int, **kwargs: Any):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.envs = [gymnasium.make(env_id, **kwargs) for _ in range(num_envs)]
        env = self.envs[0]
        space = env.observation_space
        if not isinstance(space, gymnasium.spaces.Dict) or set(KEYS) - set(space.spaces):
            raise ValueError(f"{env_id} is not a goal env: its observations must be a Dict with "
                             f"keys {KEYS}, got {space}")
        if not isinstance(env.action_space, gymnasium.spaces.Box):
            raise ValueError(f"{env_id}: need a Box action space, got {env.action_space}")
        if env.spec is None or env.spec.max_episode_steps is None:
            raise ValueError(f"{env_id} has no time limit (max_episode_steps)")
        self.num_envs = num_envs
        self.max_steps: int = env.spec.max_episode_steps
        self.obs_dim = space["observation"].shape[0]
        self.goal_dim = space["desired_goal"].shape[0]
        self.scale = ActionScale(env.action_space.low, env.action_space.high)
        self.unwrapped = env.unwrapped

    @property
    def task(self) -> dict[str, Any]:
        """The env's task specification (``env.unwrapped.task.to_dict()``), or {}."""
        task = getattr(self.unwrapped, "task", None)
        return task.to_dict() if task is not None else {}

    def reset(self, seeds: Sequence[int]) -> dict[str, np.ndarray]:
        """Reset every copy n with ``seeds[n]``; the observation arrays are (N, ...)."""
        obs = [env.reset(seed=int(s))[0] for env, s in zip(self.envs, seeds, strict=True)]
        return {key: np.stack([o[key] for o in obs]) for key in KEYS}

    def step(self, action: np.ndarray, active: np.ndarray, obs: dict[str, np.ndarray]):
        """Step the copies where ``active : (N,) bool``; the others keep their observation.

        action : (N, act_dim), env units. Returns obs (arrays (N, ...)), reward (N,),
        terminated (N,), truncated (N,), success (N,), the last three bool.
        """
        obs = {key: v.copy() for key, v in obs.items()}
        reward = np.zeros(self.num_envs)
        flags = np.zeros((3, self.num_envs), dtype=bool)
        for n in np.flatnonzero(active):
            o, r, term, trunc, info = self.envs[n].step(action[n])
            for key in KEYS:
                obs[key][n] = o[key]
            reward[n] = r
            flags[:, n] = term, trunc, bool(info.get("is_success", term))
        return obs, reward, flags[0], flags[1], flags[2]

    def reward_fn(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                  action: np.ndarray) -> np.ndarray:
        """The env's reward for L transitions:
        (L, goal_dim), (L, goal_dim), (L, act_dim) -> (L,)."""
        return self.unwrapped.compute_reward(achieved_goal, desired_goal, {"action": action})

    def success_fn(self, achieved_goal: np.ndarray, desired_goal: np.ndarray,
                   action: np.ndarray) -> np.ndarray:
        """The env's success test for L transitions, (L,) bool."""
        return self.unwrapped.compute_terminated(achieved_goal, desired_goal, {"action": action})

    def close(self) -> None:
        for env in self.envs:
            env.close()


Policy = Callable[[dict[str, np.ndarray], np.ndarray], np.ndarray]
"""``policy(obs, active) -> action``: obs arrays (N, ...), active (N,) bool -> (N, act_dim)
action in env units (rows of inactive copies are ignored)."""


def rollout(envs: GoalVecEnv, policy: Policy,
            seeds: Sequence[int]) -> tuple[list[Episode], np.ndarray]:
    """One episode in each of the N copies, in lockstep until the last one ends.

    Returns the N episodes and their success flags (N,) bool.
    """
    n, t_max = envs.num_envs, envs.max_steps
    obs = envs.reset(seeds)
    o = np.zeros((n, t_max + 1, envs.obs_dim))
    ag = np.zeros((n, t_max + 1, envs.goal_dim))
    a = np.zeros((n, t_max, envs.scale.dim))
    r = np.zeros((n, t_max))
    term = np.zeros((n, t_max), dtype=bool)
    length = np.zeros(n, dtype=int)
    success = np.zeros(n, dtype=bool)
    o[:, 0], ag[:, 0] = obs["observation"], obs["achieved_goal"]
    goal = obs["desired_goal"].copy()
    active = np.ones(n, dtype=bool)
    for t in range(t_max):
        action = np.asarray(policy(obs, active), dtype=np.float64)
        obs, reward, terminated, truncated, succ = envs.step(action, active, obs)
        idx = np.flatnonzero(active)
        o[idx, t + 1], ag[idx, t + 1] = obs["observation"][idx], obs["achieved_goal"][idx]
        a[idx, t], r[idx, t], term[idx, t] = action[idx], reward[idx], terminated[idx]
        length[idx] += 1
        success[idx] = succ[idx]
        active &= ~(terminated | truncated)
        if not active.any():
            break
    if active.any():
        raise RuntimeError(f"episodes still running after the time limit of {t_max} steps")
    episodes = [
        Episode(observation=o[i, :length[i] + 1], achieved_goal=ag[i, :length[i] + 1],
                desired_goal=goal[i], action=a[i, :length[i]], reward=r[i, :length[i]],
                terminated=term[i, :length[i]])
        for i in range(n)
    ]
    return episodes, success
