"""The paper's flat observation of the goal env."""

from __future__ import annotations

import gymnasium
import numpy as np

GOAL_KEYS = ("observation", "achieved_goal", "desired_goal")
"""The keys of a goal env's Dict observation."""


class FlatObservation(gymnasium.ObservationWrapper, gymnasium.utils.RecordConstructorArgs):
    """The paper's state ``s = [theta, theta_dot, theta_ddot, goal - fk(theta), goal]``.

    ``(3n + 6,) float64``, from a goal env's Dict observation:

    | Num          | Observation                                  | Unit    |
    |--------------|----------------------------------------------|---------|
    | 0..3n-1      | ``observation``: theta, theta_dot, theta_ddot | rad, rad/s, rad/s^2 |
    | 3n..3n+2     | goal - tool0 position (world frame)          | m       |
    | 3n+3..3n+5   | goal (world frame)                           | m       |

    Rewards, ``info`` and ``compute_reward`` are the wrapped env's.

    Parameters
    ----------
    env : gymnasium.Env
        With a Dict observation space holding ``observation``, ``achieved_goal`` and
        ``desired_goal``.

    Raises
    ------
    ValueError
        When the observation space is not such a Dict.
    """

    def __init__(self, env: gymnasium.Env) -> None:
        gymnasium.utils.RecordConstructorArgs.__init__(self)
        gymnasium.ObservationWrapper.__init__(self, env)
        space = env.observation_space
        if not isinstance(space, gymnasium.spaces.Dict) or set(GOAL_KEYS) - set(space.spaces):
            raise ValueError(f"FlatObservation needs a goal env whose observation space is a Dict "
                             f"with keys {list(GOAL_KEYS)}; got {space}")
        state = space["observation"]
        goal_dim = space["desired_goal"].shape[0]
        unbounded = np.full(2 * goal_dim, np.inf)
        self.observation_space = gymnasium.spaces.Box(
            np.concatenate([state.low, -unbounded]), np.concatenate([state.high, unbounded]),
            dtype=np.float64,
        )

    def observation(self, observation: dict[str, np.ndarray]) -> np.ndarray:
        """``[observation, desired_goal - achieved_goal, desired_goal]``."""
        goal = observation["desired_goal"]
        return np.concatenate([observation["observation"], goal - observation["achieved_goal"],
                               goal])
