"""Goal envs stepped in lockstep, one group of copies per agent, behind one tensor interface.

The agent sees the env only through the Gymnasium goal-env API: a Dict observation with
``observation``, ``achieved_goal`` and ``desired_goal``, a Box action, ``info["is_success"]``, and
the vectorised ``compute_reward`` / ``compute_terminated`` of the env. The trainer sees every env
backend through one interface of tensors: `HostEnvs` (a `GoalVecEnv`, its arrays entering torch
without a copy), which ``ddpg_her.collect`` rolls out; the training program on the device steps
its own env (``ddpg_her.program``). How groups merge into one batch, and why: docs/design.md,
"Dynamics".
"""

from __future__ import annotations

import dataclasses
import importlib
import json
from collections.abc import Sequence
from typing import Any

import gymnasium
import numpy as np
import torch
from gymnasium.vector import AutoresetMode

from ddpg_her.spaces import ActionScale

KEYS = ("observation", "achieved_goal", "desired_goal")

GOAL_FIELDS = ("region", "goal_sampler")
"""Task fields that only say where goals are drawn: groups whose tasks differ in these alone
(regions, samplers) step alike and may share a merged batch (``GoalVecEnv(merge=True)``)."""

Step = tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray, np.ndarray]

PROJECT_ENVS = "envs"
"""The package whose import registers this project's env ids (``UR5Reach-v0``): imported for an
id given without a module."""


def register_env(env_id: str) -> str:
    """Import the module that registers ``env_id``; return the id ``gymnasium.make`` takes.

    ``env_id`` is a registered id, one of this project's (``UR5Reach-v0``), or Gymnasium's
    ``module:EnvId``, whose module registers ``EnvId``.
    """
    module, _, name = env_id.rpartition(":")
    if module or name not in gymnasium.registry:
        importlib.import_module(module or PROJECT_ENVS)
    return name


def _make(env_id: str, kwargs: dict[str, Any]) -> gymnasium.Env:
    """``gymnasium.make(env_id, **kwargs)``, but a ``max_episode_steps`` in ``kwargs`` reaches
    the env as ``make_vec`` passes it: ``make`` would take it for its own time limit alone,
    and the task would keep (and record) its default episode length."""
    if "max_episode_steps" not in kwargs:
        return gymnasium.make(env_id, **kwargs)
    steps = kwargs["max_episode_steps"]
    spec = gymnasium.spec(env_id)
    spec = dataclasses.replace(spec, kwargs={**spec.kwargs, "max_episode_steps": steps})
    rest = {k: v for k, v in kwargs.items() if k != "max_episode_steps"}
    return gymnasium.make(spec, max_episode_steps=steps, **rest)


class _Singles:
    """M copies made one by one with ``gymnasium.make``, stepped in a loop."""

    def __init__(self, env_id: str, m: int, kwargs: dict[str, Any]):
        self.envs = [_make(env_id, kwargs) for _ in range(m)]
        env = self.envs[0]
        self.observation_space, self.action_space = env.observation_space, env.action_space
        self.goal_env = env.unwrapped
        limit = env.spec.max_episode_steps if env.spec is not None else None
        task_limit = _task_dict(self.goal_env).get("max_episode_steps")
        limits = [x for x in (limit, task_limit) if x is not None]
        self.max_steps = min(limits) if limits else None

    def reset(self, seeds: Sequence[int]) -> dict[str, np.ndarray]:
        obs = [env.reset(seed=int(s))[0] for env, s in zip(self.envs, seeds, strict=True)]
        return {key: np.stack([o[key] for o in obs]) for key in KEYS}

    def step(self, action: np.ndarray, active: np.ndarray) -> tuple:
        """`_Vector.step`'s arrays (M, ...); the copies not ``active`` are not stepped (their
        entries are zeros, ignored)."""
        m = len(self.envs)
        obs = {key: np.zeros((m, *self.observation_space[key].shape)) for key in KEYS}
        reward = np.zeros(m)
        flags = np.zeros((3, m), dtype=bool)
        for i in np.flatnonzero(active):
            o, r, term, trunc, info = self.envs[i].step(action[i])
            for key in KEYS:
                obs[key][i] = o[key]
            reward[i] = r
            flags[:, i] = term, trunc, bool(info.get("is_success", term))
        return obs, reward, flags[0], flags[1], flags[2]

    def close(self) -> None:
        for env in self.envs:
            env.close()


class _Vector:
    """M copies in the env's own vector implementation, never reset automatically."""

    def __init__(self, env_id: str, m: int, kwargs: dict[str, Any]):
        self.env = gymnasium.make_vec(env_id, num_envs=m, vectorization_mode="vector_entry_point",
                                      autoreset_mode=AutoresetMode.DISABLED, **kwargs)
        self.observation_space = self.env.single_observation_space
        self.action_space = self.env.single_action_space
        self.goal_env = self.env.unwrapped
        limit = _task_dict(self.goal_env).get("max_episode_steps")
        self.max_steps = limit if limit is not None else gymnasium.spec(env_id).max_episode_steps

    def reset(self, seeds: Sequence[int]) -> dict[str, np.ndarray]:
        return self.env.reset(seed=[int(s) for s in seeds])[0]

    def step(self, action: np.ndarray, active: np.ndarray) -> tuple:
        # Copies whose episode ended are stepped too (the batch moves as one) and ignored.
        o, r, term, trunc, info = self.env.step(action)
        return o, r, term, trunc, np.asarray(info.get("is_success", term), dtype=bool)

    def close(self) -> None:
        self.env.close()


def _dims(group: _Singles | _Vector) -> dict[str, Any]:
    low, high = group.action_space.low, group.action_space.high
    return {"obs_dim": int(group.observation_space["observation"].shape[0]),
            "goal_dim": int(group.observation_space["desired_goal"].shape[0]),
            "act_dim": int(low.shape[0]), "action_low": low.tolist(),
            "action_high": high.tolist(),
            "max_episode_steps": None if group.max_steps is None else int(group.max_steps)}


def _task_dict(goal_env: Any) -> dict[str, Any]:
    task = getattr(goal_env, "task", None)
    return task.to_dict() if task is not None and hasattr(task, "to_dict") else {}


class _Batch(_Vector):
    """One vector env stepping the copies ``index`` (flat indices) of several groups."""

    def __init__(self, env_id: str, n: int, kwargs: dict[str, Any], index: np.ndarray):
        super().__init__(env_id, n, kwargs)
        self.index = index


class GoalVecEnv:
    """``groups`` groups of ``copies`` copies of ``gymnasium.make(env_id, **kwargs)``.

    ``groups`` is a count (every group the same task) or one dict per group, whose keys
    override ``kwargs`` for that group (K agents of different tasks, e.g. regions or reward
    readings, in one lockstep batch). Every group must then have the same observation and
    action layout (`dims`). Copy m of group k sits at flat index ``k * copies + m``. Each copy
    is reseeded at every reset from the seed given for it, so an episode depends only on its
    own seed and its group's task: nothing about the env needs saving in a checkpoint.

    A group of several copies is the env's own vector implementation (its
    ``vector_entry_point``, e.g. ``envs.BatchedReach``) when it has one, a single copy
    ``gymnasium.make``. ``merge=True`` steps the copies of all groups whose tasks (``task_of``)
    are equal but for `GOAL_FIELDS` in one vector env, which must accept ``reset(seed=[...],
    options={"goal": (m, goal_dim)})``; each group still draws its copies' goals, so the goals
    are exactly those of ``merge=False`` and the trajectories equal to rounding. Envs without a
    vector entry point or a task specification are not merged.
    """

    def __init__(self, env_id: str, groups: int | Sequence[dict[str, Any]], copies: int = 1,
                 *, merge: bool = False, **kwargs: Any):
        per_group = [dict(kwargs)] * groups if isinstance(groups, int) else \
            [{**kwargs, **g} for g in groups]
        if not per_group or copies < 1:
            raise ValueError(f"need groups >= 1 and copies >= 1, got {groups}, {copies}")
        env_id = register_env(env_id)
        vector = copies > 1 and gymnasium.spec(env_id).vector_entry_point is not None
        make = _Vector if vector else _Singles
        self.kwargs = per_group
        self.groups = [make(env_id, copies, kw) for kw in per_group]
        g = self.groups[0]
        space = g.observation_space
        if not isinstance(space, gymnasium.spaces.Dict) or set(KEYS) - set(space.spaces):
            raise ValueError(f"{env_id} is not a goal env: its observations must be a Dict with "
                             f"keys {KEYS}, got {space}")
        if not isinstance(g.action_space, gymnasium.spaces.Box):
            raise ValueError(f"{env_id}: need a Box action space, got {g.action_space}")
        if g.max_steps is None:
            raise ValueError(f"{env_id} has no time limit (max_episode_steps)")
        # the layout is group 0's; every group must have the same
        self.copies, self.num_envs = copies, len(self.groups) * copies
        self.max_steps: int = int(g.max_steps)
        self.obs_dim = g.observation_space["observation"].shape[0]
        self.goal_dim = g.observation_space["desired_goal"].shape[0]
        self.scale = ActionScale(g.action_space.low, g.action_space.high)
        self.goal_env = g.goal_env
        for i, other in enumerate(self.groups[1:], start=1):
            if _dims(other) != _dims(g):
                raise ValueError(
                    f"{env_id}: group {i} ({self.kwargs[i]}) has the layout {_dims(other)}, "
                    f"group 0 ({self.kwargs[0]}) {_dims(g)}; one batch needs one layout")
        self.batches: list[_Batch] = self._merged(env_id) if merge else []

    @property
    def dims(self) -> dict[str, Any]:
        """The layout every group shares, as a run's ``spec.json`` records it: obs_dim,
        goal_dim, act_dim, action_low, action_high (env units), max_episode_steps."""
        return _dims(self.groups[0])

    def task_of(self, group: int) -> dict[str, Any]:
        """Group ``group``'s task specification (``task.to_dict()`` of its env), or {}."""
        return _task_dict(self.groups[group].goal_env)

    def _merged(self, env_id: str) -> list[_Batch]:
        """One `_Batch` per set of groups that may step in one batch, those whose tasks
        (`task_of`) are equal but for `GOAL_FIELDS` (sets in order of their first group), of
        their copies' flat indices group by group; none when the env has no vector entry point
        or a group's env no task specification."""
        if gymnasium.spec(env_id).vector_entry_point is None:
            return []
        members: dict[str, list[int]] = {}
        for k in range(len(self.groups)):
            task = self.task_of(k)
            if not task:
                return []
            key = json.dumps({f: v for f, v in task.items() if f not in GOAL_FIELDS},
                             sort_keys=True, default=str)
            members.setdefault(key, []).append(k)
        c = self.copies
        return [_Batch(env_id, len(ks) * c, self.kwargs[ks[0]],
                       np.concatenate([np.arange(k * c, (k + 1) * c) for k in ks]))
                for ks in members.values()]

    def reward_fn(self, achieved_goal: Any, desired_goal: Any, action: Any,
                  group: int = 0) -> Any:
        """Group ``group``'s ``compute_reward`` of transitions (..., goal_dim), (..., goal_dim),
        (..., act_dim) env units -> (...), arrays or tensors as the env takes them."""
        return self.groups[group].goal_env.compute_reward(achieved_goal, desired_goal,
                                                          {"action": action})

    def terminated_fn(self, achieved_goal: Any, desired_goal: Any, action: Any,
                      group: int = 0) -> Any:
        """Group ``group``'s ``compute_terminated`` of such transitions, (...) bool: whether each
        ends the episode (a success, when the task ends episodes at success)."""
        return self.groups[group].goal_env.compute_terminated(achieved_goal, desired_goal,
                                                              {"action": action})

    def reset(self, seeds: Sequence[int]) -> dict[str, np.ndarray]:
        """Reset every copy n with ``seeds[n]``; the observation arrays are (N, ...)."""
        if len(seeds) != self.num_envs:
            raise ValueError(f"need {self.num_envs} seeds, got {len(seeds)}")
        c = self.copies
        parts = [g.reset(seeds[i * c:(i + 1) * c]) for i, g in enumerate(self.groups)]
        obs = {key: np.concatenate([p[key] for p in parts]).astype(np.float64) for key in KEYS}
        for b in self.batches:  # the groups drew the goals; the batch starts the episodes
            o = b.env.reset(seed=[int(seeds[i]) for i in b.index],
                            options={"goal": obs["desired_goal"][b.index]})[0]
            for key in KEYS:
                obs[key][b.index] = o[key]
        return obs

    def step(self, action: np.ndarray, active: np.ndarray, obs: dict[str, np.ndarray]) -> Step:
        """Step the copies where ``active : (N,) bool``; the others keep their observation.

        action : (N, act_dim), env units. Returns obs (arrays (N, ...)), reward (N,),
        terminated (N,), truncated (N,), success (N,), the last three bool; entries of inactive
        copies are 0 / False.
        """
        obs = {key: v.copy() for key, v in obs.items()}
        reward = np.zeros(self.num_envs)
        flags = np.zeros((3, self.num_envs), dtype=bool)
        c = self.copies
        stepped = [(b, b.index) for b in self.batches] or \
            [(g, np.arange(i * c, (i + 1) * c)) for i, g in enumerate(self.groups)]
        for env, rows in stepped:  # each steps its copies ``rows`` (flat indices) together
            o, r, term, trunc, success = env.step(action[rows], active[rows])
            on = active[rows]
            rows = rows[on]
            for key in KEYS:
                obs[key][rows] = o[key][on]
            reward[rows] = np.asarray(r)[on]
            flags[0, rows], flags[1, rows], flags[2, rows] = term[on], trunc[on], success[on]
        return obs, reward, flags[0], flags[1], flags[2]

    def close(self) -> None:
        for g in self.groups:
            g.close()
        for b in self.batches:
            b.env.close()


# ------------------------------------------------------------------ tensors
class HostEnvs(GoalVecEnv):
    """A `GoalVecEnv` seen through tensors, for the trainer's host env backends (``numpy``,
    ``batched``): the one place where the host's arrays enter torch (zero-copy
    ``torch.from_numpy``, float64 on the CPU) and the actions leave it. The arguments are
    `GoalVecEnv`'s."""

    device = torch.device("cpu")

    def reset(self, seeds: Sequence[int]) -> dict[str, torch.Tensor]:
        """`GoalVecEnv.reset`, the observations (N, ...) as tensors."""
        return _tensors(super().reset(seeds))

    def step(self, action: torch.Tensor, active: torch.Tensor,
             obs: dict[str, torch.Tensor]) -> tuple[dict[str, torch.Tensor], torch.Tensor,
                                                    torch.Tensor, torch.Tensor, torch.Tensor]:
        """`GoalVecEnv.step` of tensors: action (N, act_dim) env units, active (N,) bool; the
        copies not active keep their observation and get 0 / False."""
        o, *rest = super().step(action.numpy(), active.numpy(),
                                {key: v.numpy() for key, v in obs.items()})
        reward, terminated, truncated, success = (torch.from_numpy(x) for x in rest)
        return _tensors(o), reward, terminated, truncated, success

    def reward_fn(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor,
                  action: torch.Tensor, group: int = 0) -> torch.Tensor:
        return torch.from_numpy(np.asarray(super().reward_fn(
            achieved_goal.numpy(), desired_goal.numpy(), action.numpy(), group),
            dtype=np.float64))

    def terminated_fn(self, achieved_goal: torch.Tensor, desired_goal: torch.Tensor,
                      action: torch.Tensor, group: int = 0) -> torch.Tensor:
        return torch.from_numpy(np.asarray(super().terminated_fn(
            achieved_goal.numpy(), desired_goal.numpy(), action.numpy(), group), dtype=bool))


def _tensors(obs: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {key: torch.from_numpy(obs[key]) for key in KEYS}
