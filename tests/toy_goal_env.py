"""A toy goal-reaching env with the UR5Reach-v0 API, for fast tests of ddpg_her.

A point in n dimensions (n = ``n_joints``) is commanded to absolute target positions and follows
them with a first-order lag, like the UR5's joint-position controller follows its commanded angles.
It learns in seconds, so the agent's tests need neither the robot nor its dynamics.

Observation Space (Dict)

| key           | shape  | content                                   | unit |
|---------------|--------|-------------------------------------------|------|
| observation   | (3n,)  | position p, velocity, acceleration        | m, m/step, m/step^2 |
| achieved_goal | (n,)   | p                                         | m    |
| desired_goal  | (n,)   | goal g                                    | m    |

Action Space: Box(-2, 2, (n,)), the absolute target position, m.
Rewards: ``-|p - g| - action_cost * |a|^2 + success_bonus * 1{|p - g| <= eps}`` (the action is read
from ``info["action"]``, as the UR5 env's dense reward does).
Starting State: p = 0, goal uniform in [-goal_range, goal_range]^n.
Episode End: terminated when |p - g| <= eps; truncated after ``max_episode_steps`` (20) steps.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

ENV_ID = "ToyReach-v0"


@dataclass(frozen=True)
class ToyTaskSpec:
    """Everything that defines the toy task; recorded in the run folder like the UR5 TaskSpec."""

    n_joints: int = 2
    """Dimension n of the point, 1..6."""
    region: str = "box"
    """Name of the goal region (only "box" exists here)."""
    goal_range: float = 1.0
    """Goals are uniform in [-goal_range, goal_range]^n, m."""
    lag: float = 0.5
    """Fraction of the distance to the commanded target covered per step."""
    eps: float = 0.1
    """Success radius, m."""
    action_cost: float = 0.05
    """Weight of |a|^2 in the reward, 1/m^2."""
    success_bonus: float = 10.0
    """Reward added on success."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


class ToyReach(gymnasium.Env):
    """Point-mass goal reaching with the GoalEnv API (see the module docstring)."""

    metadata = {"render_modes": []}  # noqa: RUF012

    def __init__(self, region: str = "box", n_joints: int = 2, **overrides: Any):
        if region != "box":
            raise ValueError(f"unknown region {region!r}; the toy env has only 'box'")
        if not 1 <= n_joints <= 6:
            raise ValueError(f"n_joints must be in 1..6, got {n_joints}")
        self.task = ToyTaskSpec(n_joints=n_joints, region=region, **overrides)
        n = n_joints
        box = gymnasium.spaces.Box
        self.observation_space = gymnasium.spaces.Dict(
            observation=box(-np.inf, np.inf, (3 * n,), np.float64),
            achieved_goal=box(-np.inf, np.inf, (n,), np.float64),
            desired_goal=box(-np.inf, np.inf, (n,), np.float64),
        )
        self.action_space = box(-2.0, 2.0, (n,), np.float64)
        self._p = np.zeros(n)
        self._v = np.zeros(n)
        self._acc = np.zeros(n)
        self._g = np.zeros(n)

    def _obs(self) -> dict[str, np.ndarray]:
        return {
            "observation": np.concatenate([self._p, self._v, self._acc]),
            "achieved_goal": self._p.copy(),
            "desired_goal": self._g.copy(),
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        n = self.task.n_joints
        self._p, self._v, self._acc = np.zeros(n), np.zeros(n), np.zeros(n)
        r = self.task.goal_range
        self._g = self.np_random.uniform(-r, r, n)
        return self._obs(), {"is_success": False}

    def step(self, action: np.ndarray):
        a = np.clip(np.asarray(action, dtype=np.float64), -2.0, 2.0)
        v = self.task.lag * (a - self._p)
        self._acc = v - self._v
        self._v = v
        self._p = self._p + v
        obs = self._obs()
        info = {"action": a}
        terminated = bool(self.compute_terminated(obs["achieved_goal"], self._g, info))
        info["is_success"] = terminated
        reward = float(self.compute_reward(obs["achieved_goal"], self._g, info))
        return obs, reward, terminated, False, info

    @staticmethod
    def _actions(info: Any) -> np.ndarray:
        """info["action"] from one info dict, or stacked from a sequence of them."""
        if isinstance(info, dict):
            return np.asarray(info["action"], dtype=np.float64)
        return np.stack([np.asarray(i["action"], dtype=np.float64) for i in info])

    def compute_reward(self, achieved_goal, desired_goal, info) -> np.ndarray:
        d = np.linalg.norm(np.asarray(achieved_goal) - desired_goal, axis=-1)
        a = self._actions(info)
        t = self.task
        return -d - t.action_cost * np.sum(a**2, axis=-1) + t.success_bonus * (d <= t.eps)

    def compute_terminated(self, achieved_goal, desired_goal, info) -> np.ndarray:
        return np.linalg.norm(np.asarray(achieved_goal) - desired_goal, axis=-1) <= self.task.eps

    def compute_truncated(self, achieved_goal, desired_goal, info) -> np.ndarray:
        return np.zeros(np.shape(achieved_goal)[:-1], dtype=bool)


if ENV_ID not in gymnasium.registry:
    gymnasium.register(ENV_ID, entry_point=ToyReach, max_episode_steps=20)
