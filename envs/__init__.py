"""The UR5 Reacher as Gymnasium environments (see ../shared/DESIGN.md).

Importing the package registers :data:`ENV_IDS`:

>>> import gymnasium, envs
>>> env = gymnasium.make("UR5Reach-v0", region="zheight", n_joints=3)
>>> env.unwrapped.task.region, env.unwrapped.dt
('zheight', 0.02)
>>> obs, info = env.reset(seed=0)
>>> obs["observation"].shape, obs["desired_goal"].shape
((9,), (3,))
"""

import gymnasium

from envs.batched import DEFAULT_EPISODE_STEPS, BatchedReach
from envs.reach import UR5ReachEnv
from envs.reward import compute_reward
from envs.spec import TaskSpec
from envs.wrappers import FlatObservation

ENV_IDS: tuple[str, ...] = ("UR5Reach-v0",)
"""Ids registered on import: the tests and benchmarks run over this list."""

for _env_id in ENV_IDS:
    if _env_id not in gymnasium.registry:
        gymnasium.register(
            _env_id,
            entry_point="envs.reach:UR5ReachEnv",
            vector_entry_point="envs.batched:BatchedReach",
            max_episode_steps=DEFAULT_EPISODE_STEPS,
        )

__all__ = ["ENV_IDS", "BatchedReach", "FlatObservation", "TaskSpec", "UR5ReachEnv",
           "compute_reward"]
