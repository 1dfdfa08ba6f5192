"""How goal-env observations and actions map to the networks' inputs and outputs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def goal_input(observation: np.ndarray, achieved_goal: np.ndarray,
               desired_goal: np.ndarray) -> np.ndarray:
    """The network input ``x = [observation, desired_goal - achieved_goal, desired_goal]``.

    For the UR5 env this is the paper's ``s = [theta, theta_dot, theta_ddot, goal - fk, goal]``.

    observation : (..., obs_dim), achieved_goal, desired_goal : (..., goal_dim)
    -> (..., obs_dim + 2 goal_dim), float32. The goal may broadcast against the leading axes.
    """
    observation = np.asarray(observation)
    achieved_goal = np.asarray(achieved_goal)
    desired_goal = np.broadcast_to(desired_goal, achieved_goal.shape)
    return np.concatenate(
        [observation, desired_goal - achieved_goal, desired_goal], axis=-1
    ).astype(np.float32)


@dataclass(frozen=True)
class ActionScale:
    """The affine map between actor units u in [-1, 1] and the env's action box [low, high].

    low, high : (act_dim,) float, in the env's action unit (rad for joint angles).
    """

    low: np.ndarray
    high: np.ndarray

    def __post_init__(self) -> None:
        low = np.asarray(self.low, dtype=np.float64)
        high = np.asarray(self.high, dtype=np.float64)
        if low.shape != high.shape or low.ndim != 1 or not np.all(np.isfinite(low)) \
                or not np.all(np.isfinite(high)) or not np.all(high > low):
            raise ValueError(f"need a finite action box with low < high, got {low} .. {high}")
        object.__setattr__(self, "low", low)
        object.__setattr__(self, "high", high)

    @property
    def dim(self) -> int:
        return len(self.low)

    def to_env(self, u: np.ndarray) -> np.ndarray:
        """u : (..., act_dim) in [-1, 1] -> (..., act_dim) in [low, high], float64."""
        return self.low + (np.asarray(u, dtype=np.float64) + 1.0) * 0.5 * (self.high - self.low)

    def to_actor(self, a: np.ndarray) -> np.ndarray:
        """Inverse of `to_env`: a : (..., act_dim) in [low, high] -> (..., act_dim) in [-1, 1]."""
        return (np.asarray(a, dtype=np.float64) - self.low) / (0.5 * (self.high - self.low)) - 1.0
