"""The UR5 Reacher as Gymnasium environments (see docs/design.md).

Importing the package registers :data:`ENV_IDS`; the env classes load on first use (PEP 562),
so that ``import envs.spec`` (reading a task) loads neither Pinocchio nor torch.

>>> import gymnasium, envs
>>> env = gymnasium.make("UR5Reach-v0", region="zheight", n_joints=3)
>>> env.unwrapped.task.region, env.unwrapped.dt
('zheight', 0.02)
>>> obs, info = env.reset(seed=0)
>>> obs["observation"].shape, obs["desired_goal"].shape
((9,), (3,))
"""

from __future__ import annotations

from typing import NoReturn

import gymnasium

from envs.checks import validate
from envs.spec import TaskSpec
from ur5kin.lazy import lazy_attributes

ENV_IDS: tuple[str, ...] = ("UR5Reach-v0",)
"""Ids registered on import: the tests and benchmarks run over this list."""

for _env_id in ENV_IDS:
    if _env_id not in gymnasium.registry:
        gymnasium.register(
            _env_id,
            entry_point="envs.reach:UR5ReachEnv",
            vector_entry_point="envs.batched:BatchedReach",
            # no outer TimeLimit: the task's own max_episode_steps truncates (a registered
            # limit of 100 cut a task of 200 steps at 100 without a word)
        )


def _no_single_stack_env(**_: object) -> NoReturn:
    raise ValueError("UR5StackReach-v0 is a stack of copies with no single env (no reset()): "
                     "build envs.stackreach.StackReach directly, or gymnasium.make_vec("
                     "'UR5StackReach-v0', num_envs=B, vectorization_mode='vector_entry_point', "
                     "tasks=[...])")


if "UR5StackReach-v0" not in gymnasium.registry:
    gymnasium.register("UR5StackReach-v0", entry_point=_no_single_stack_env,
                       vector_entry_point="envs.stackreach:StackReach")

STACK_TWINS: dict[str, str] = {"UR5Reach-v0": "UR5StackReach-v0"}
"""Each env id that has a stack twin, and the twin's id: ``gymnasium.make_vec(twin,
num_envs=B, vectorization_mode="vector_entry_point", tasks=[...])`` makes an
`envs.stackreach.StackReach` (copies of several tasks, tensors on one device), the env of
``ddpg_her.program``."""

_LAZY: dict[str, str] = {
    "BatchedReach": "envs.batched",
    "FlatObservation": "envs.wrappers",
    "UR5ReachEnv": "envs.reach",
    "compute_reward": "envs.task",
}
"""Public names that load their module (and with it Pinocchio) on first use."""

__all__ = ["ENV_IDS", "BatchedReach", "FlatObservation", "TaskSpec",
           "UR5ReachEnv", "compute_reward", "validate"]


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)
