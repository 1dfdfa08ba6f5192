"""The UR5 Reacher as Gymnasium environments (see ../shared/DESIGN.md).

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

import importlib
import importlib.util
from typing import Any

import gymnasium

from envs.checks import validate
from envs.spec import DEFAULT_EPISODE_STEPS, TaskSpec

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

_LAZY: dict[str, str] = {
    "BatchedReach": "envs.batched",
    "FlatObservation": "envs.wrappers",
    "UR5ReachEnv": "envs.reach",
    "compute_reward": "envs.reward",
}
"""Public names that load their module (and with it Pinocchio) on first use."""

__all__ = ["ENV_IDS", "BatchedReach", "FlatObservation", "TaskSpec", "UR5ReachEnv",
           "compute_reward", "validate"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif name.isidentifier() and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
