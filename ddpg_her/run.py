"""A trained agent's policy from its run folder (`load`); the folder itself is `ddpg_her.runfolder`.

This module needs torch; reading a run folder's spec and evaluations does not (see
`ddpg_her.runfolder`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from ddpg_her.checkpoints import plain
from ddpg_her.config import AgentConfig
from ddpg_her.networks import Actor, load_agent_slices
from ddpg_her.normalizer import RunningNormalizer
from ddpg_her.runfolder import RunFolder, RunFolderError
from ddpg_her.spaces import ActionScale, goal_input


class TrainedPolicy:
    """A trained agent's deterministic policy, acting on the env's Dict observations.

    ``policy(obs)`` with obs arrays ``observation (obs_dim,)``, ``achieved_goal (goal_dim,)``,
    ``desired_goal (goal_dim,)`` returns the action ``(act_dim,)`` in env units (rad for the
    UR5's joint angles); with a leading batch axis B on every array it returns ``(B, act_dim)``.
    """

    def __init__(self, actor: torch.nn.Module, normalizer: RunningNormalizer, scale: ActionScale,
                 spec: dict[str, Any], episode: int, task: Any = None):
        self.actor, self.normalizer, self.scale = actor, normalizer, scale
        self.spec, self.episode, self._task = spec, episode, task
        self.device = actor.l1.weight.device

    def make_env(self, **kwargs: Any) -> Any:
        """A fresh copy of the env the policy was trained on: `make_run_env` of its spec
        (``kwargs`` go to ``gymnasium.make``, e.g. ``render_mode``)."""
        return make_run_env(self.spec, **kwargs)

    @property
    def task(self) -> Any:
        """The task of the run's env (an ``envs.TaskSpec`` for UR5Reach-v0), as `load` checked
        it: what `make_env`'s env has as ``env.unwrapped.task`` (None for an env without one)."""
        return self._task

    def _checked(self, obs: Any) -> list[np.ndarray]:
        """The three arrays of ``obs`` as float64, or ValueError naming what does not fit the
        layout the policy was trained on (its run's ``dims``)."""
        dims = self.spec["dims"]
        sizes = {"observation": dims["obs_dim"], "achieved_goal": dims["goal_dim"],
                 "desired_goal": dims["goal_dim"]}
        if not isinstance(obs, Mapping) or set(sizes) - set(obs):
            raise ValueError(f"obs must be the env's Dict observation with keys "
                             f"{sorted(sizes)}; got "
                             f"{sorted(obs) if isinstance(obs, Mapping) else type(obs).__name__}")
        arrays, batch = [], set()
        for key, n in sizes.items():
            arr = np.asarray(obs[key])
            if arr.dtype.kind not in "iuf" or arr.ndim not in (1, 2) or arr.shape[-1] != n:
                raise ValueError(f"obs[{key!r}] must be ({n},) or (B, {n}) real numbers (the "
                                 f"layout this policy was trained on); got "
                                 f"{arr.dtype} of shape {arr.shape}")
            if not np.isfinite(arr).all():
                raise ValueError(f"obs[{key!r}] must be finite; got {arr}")
            arrays.append(arr.astype(np.float64, copy=False))
            batch.add(arr.shape[:-1])
        if len(batch) > 1:
            raise ValueError(f"obs arrays must share their batch shape; got "
                             f"{[a.shape for a in arrays]}")
        return arrays

    @torch.no_grad()
    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The action for ``obs`` (see the class docstring).

        Raises
        ------
        ValueError
            When ``obs`` lacks a key, or an array is not real, finite and of the run's
            layout (``spec['dims']``), or the batch shapes differ.
        """
        x = goal_input(*self._checked(obs))
        single = x.ndim == 1
        xt = torch.as_tensor(x.reshape(1, -1, x.shape[-1]), device=self.device)
        u = self.actor(self.normalizer(xt.to(self.actor.l1.weight.dtype)))[0]
        a = self.scale.to_env(u.cpu().numpy())
        return a[0] if single else a


def make_run_env(spec: Mapping[str, Any], **kwargs: Any) -> Any:
    """A fresh copy of the env of the run whose ``spec.json`` is ``spec`` (``gymnasium.make``
    with the run's env id and arguments; ``kwargs`` go to ``gymnasium.make`` too).

    Where the run recorded its env's whole task (``spec.json``'s ``task``) and the env takes a
    task record (a ``task`` parameter, as UR5Reach-v0 does), the env gets that record as
    ``task=``: the arguments alone would take today's defaults for fields that a run of an
    older version did not name (the env reads a record as of its time)."""
    import inspect

    import gymnasium
    from gymnasium.envs.registration import load_env_creator

    from ddpg_her.vecenv import register_env

    env_id = register_env(spec["env_id"])
    env_kwargs = dict(spec["env_kwargs"])
    entry = gymnasium.spec(env_id).entry_point
    creator = load_env_creator(entry) if isinstance(entry, str) else entry
    if (spec.get("task") and "task" not in env_kwargs and "spec" not in env_kwargs
            and "task" in inspect.signature(creator).parameters):
        env_kwargs["task"] = spec["task"]
    return gymnasium.make(env_id, **env_kwargs, **kwargs)


def run_task(folder: RunFolder, spec: Mapping[str, Any]) -> Any:
    """The task of the run's env, after making the env once as `make_run_env` makes it: a
    spec whose env cannot be made (a region that does not parse, a field no task has, an env
    id that is not registered) is an error naming ``spec.json``, not a traceback of whichever
    reader makes the env first (issue 37, kind 7); a spec whose ``task`` record and
    ``env_kwargs`` make different tasks (an edited file) is refused too, naming the fields
    (kind 6). None for an env without a ``task``.

    Raises
    ------
    RunFolderError
        Naming ``spec.json`` and why its env cannot be made (the region and what it should be),
        or the fields on which its ``task`` and ``env_kwargs`` disagree.
    """
    import gymnasium

    if not spec.get("env_id"):
        raise RunFolderError(f"{folder.spec_path} names no env_id (the Gymnasium id of the "
                             "run's env), so the run's env cannot be made")
    try:
        env = make_run_env(spec)
    except (KeyError, TypeError, ValueError, ImportError, gymnasium.error.Error) as err:
        raise RunFolderError(f"{folder.spec_path}: the run's env cannot be made from it "
                             f"({type(err).__name__}: {err})") from err
    try:
        task = getattr(env.unwrapped, "task", None)
    finally:
        env.close()
    recorded = spec.get("task")
    if task is not None and recorded and hasattr(task, "to_dict"):
        made = task.to_dict()
        differ = [f"{key} (task: {recorded[key]!r}, env: {made[key]!r})" for key in recorded
                  if key in made and plain(made[key]) != plain(recorded[key])]
        if differ:
            raise RunFolderError(f"{folder.spec_path}: its task and its env_kwargs disagree on "
                                 f"{', '.join(differ)}; a run's spec records one task (issue 37, "
                                 "kind 6): was the file edited?")
    return task


def load(run_dir: str | os.PathLike, *, episode: int | None = None,
         device: str = "cpu") -> TrainedPolicy:
    """The policy of the run in ``run_dir`` at its latest checkpoint (or at ``episode``).

    Raises
    ------
    FileNotFoundError
        When ``run_dir`` has no ``spec.json`` or no checkpoint.
    ddpg_her.runfolder.RunFolderError
        (a ValueError) When there is no checkpoint at ``episode``, or ``spec.json`` or the
        checkpoint cannot be read, or the env of ``spec.json`` cannot be made (`run_task`); the
        message names the file.
    ValueError
        When ``device`` is not a torch device string.
    """
    try:  # torch's own message is a RuntimeError listing every device type it knows
        torch.device(device)
    except (RuntimeError, TypeError):
        raise ValueError(f"device must be a torch device string such as 'cpu' or 'cuda:0'; "
                         f"got {device!r}") from None
    folder = RunFolder(run_dir)
    if not folder.spec_path.exists():
        raise FileNotFoundError(f"{run_dir} is not a run folder (no spec.json)")
    spec = folder.read_spec()
    task = run_task(folder, spec)  # before any checkpoint is read
    ckpts = folder.checkpoints()
    if not ckpts:
        raise FileNotFoundError(f"{run_dir} has no checkpoint yet")
    if episode is not None and (not isinstance(episode, int) or isinstance(episode, bool)):
        raise ValueError(f"episode must be an integer (a checkpoint's episode, one of "
                         f"{sorted(ckpts)}) or None; got {episode!r}")
    episode = max(ckpts) if episode is None else episode
    state = folder.load_checkpoint(episode)["agent"]
    try:  # spec.json's values are checked as strictly as the command line's
        config = AgentConfig.from_dict(spec["agent"])
        dims = spec["dims"]
        in_dim = dims["obs_dim"] + 2 * dims["goal_dim"]
        if not all(isinstance(dims[k], int) and dims[k] >= 1
                   for k in ("obs_dim", "goal_dim", "act_dim")):
            raise ValueError(f"dims {dims} are not counts >= 1")
    except (KeyError, TypeError, ValueError) as err:
        raise RunFolderError(f"{folder.spec_path} does not hold a valid run specification "
                             f"({type(err).__name__}: {err})") from err
    net = {"dtype": torch.float32, "device": torch.device(device)}
    # an ensemble's state holds its M members and its partition (ddpg_her.ensemble)
    members = state.get("ensemble", [state])
    normalizer = RunningNormalizer(len(members), in_dim, eps=config.norm_eps,
                                   clip=config.obs_clip, enabled=config.normalize_obs, **net)
    try:
        actor = _actor(config, members, in_dim, dims["act_dim"], net)
        for k, member in enumerate(members):
            normalizer.load_state(k, member["normalizer"])
    except (KeyError, RuntimeError, ValueError) as err:
        raise RunFolderError(f"{ckpts[episode]} does not fit spec.json's networks (input "
                             f"{in_dim}, {dims['act_dim']} actions, hidden "
                             f"{list(config.hidden_sizes)}): a checkpoint of another run? "
                             f"({type(err).__name__}: {str(err).splitlines()[0]})") from None
    if "ensemble" in state:
        from ddpg_her.ensemble import RoutedPolicy

        actor = RoutedPolicy(actor, normalizer, torch.as_tensor(state["centres"]), in_dim)
        normalizer = RunningNormalizer(1, in_dim, eps=config.norm_eps, clip=config.obs_clip,
                                       enabled=False, **net)  # the members normalise
    scale = ActionScale(np.array(dims["action_low"]), np.array(dims["action_high"]))
    return TrainedPolicy(actor, normalizer, scale, spec, episode, task)


def _actor(config: AgentConfig, states: list[dict[str, Any]], in_dim: int, act_dim: int,
           net: dict[str, Any]) -> torch.nn.Module:
    """The deterministic test policy of ``len(states)`` stacked agents (their ``actor``)."""
    if config.algo.value == "sac":
        from ddpg_her.sac import GaussianActor, MeanPolicy

        gaussian = GaussianActor(len(states), in_dim, act_dim, config.hidden_sizes, **net)
        load_agent_slices(gaussian, [s["actor"] for s in states])
        return MeanPolicy(gaussian)
    actor = Actor(len(states), in_dim, act_dim, config.hidden_sizes, **net,
                  batch_norm=config.batch_norm_momentum if config.batch_norm else None)
    load_agent_slices(actor, [s["actor"] for s in states])
    return actor
