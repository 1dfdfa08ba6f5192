"""How goal-env observations and actions map to the networks' inputs and outputs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch


def goal_input(observation: Any, achieved_goal: Any, desired_goal: Any) -> Any:
    """The network input ``x = [observation, desired_goal - achieved_goal, desired_goal]``.

    For the UR5 env this is the paper's ``s = [theta, theta_dot, theta_ddot, goal - fk, goal]``.

    observation : (..., obs_dim), achieved_goal, desired_goal : (..., goal_dim)
    -> (..., obs_dim + 2 goal_dim), float32, arrays or (given tensors) tensors on their device.
    The goal may broadcast against the leading axes.
    """
    if isinstance(achieved_goal, torch.Tensor):
        dg = torch.broadcast_to(desired_goal, achieved_goal.shape)
        return torch.cat([observation, dg - achieved_goal, dg], -1).to(torch.float32)
    achieved_goal = np.asarray(achieved_goal)
    dg = np.broadcast_to(desired_goal, achieved_goal.shape)
    return np.concatenate([np.asarray(observation), dg - achieved_goal, dg],
                          axis=-1).astype(np.float32)


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

    def _like(self, x: Any) -> tuple[Any, Any, Any]:
        """``x``, low and high as float64 arrays, or as tensors on ``x``'s device."""
        if isinstance(x, torch.Tensor):
            return (x.to(torch.float64), *(torch.as_tensor(v, device=x.device)
                                           for v in (self.low, self.high)))
        return np.asarray(x, dtype=np.float64), self.low, self.high

    def to_env(self, u: Any) -> Any:
        """u : (..., act_dim) in [-1, 1] -> (..., act_dim) in [low, high], float64 (an array,
        or a tensor on ``u``'s device)."""
        u, low, high = self._like(u)
        return low + (u + 1.0) * 0.5 * (high - low)

    def to_actor(self, a: Any) -> Any:
        """Inverse of `to_env`: a : (..., act_dim) in [low, high] -> (..., act_dim) in [-1, 1]."""
        a, low, high = self._like(a)
        return (a - low) / (0.5 * (high - low)) - 1.0
