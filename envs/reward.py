"""The Reacher's reward and success test, vectorised over any batch (the GoalEnv functions).

``compute_reward(achieved_goal, desired_goal, info, task)`` is what
``env.unwrapped.compute_reward`` calls. HER libraries recompute rewards for relabelled goals
with it, passing ``info`` as one dict of batched arrays or as a list/array of per-transition
dicts (Stable-Baselines3); the dense reward reads the action from ``info["action"]``.

Bad input: :func:`compute_reward` and :func:`compute_success` raise ``ValueError`` for goals or
actions that are not real numbers, not finite, or whose shapes do not fit (goals ``(..., 3)``
broadcasting against each other, actions ``(..., n)`` against the goals' batch shape); they
never return NaN. :func:`goal_distance` and :func:`reach_reward` are the unchecked kernels the
env's step calls on values it made itself; NaN in gives NaN out there.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from envs.spec import TaskSpec

ACTION_KEY = "action"
"""The ``info`` key that carries the action (as applied, after clipping) to the dense reward."""


GOAL_DIM = 3
"""Length of a goal: tool0's x, y, z (m, world frame)."""


def _real(x: Any, name: str, what: str) -> np.ndarray:
    """``x`` as a finite float64 array, or ValueError naming ``name`` and what was expected."""
    arr = np.asarray(x)
    if arr.dtype.kind not in "biuf":
        try:
            if arr.dtype.kind == "c":
                raise TypeError("complex")
            arr = np.asarray(x, dtype=np.float64)
        except (TypeError, ValueError) as err:
            raise ValueError(f"{name} must be real numbers ({what}); got {x!r}") from err
    arr = arr.astype(np.float64, copy=False)
    if not np.isfinite(arr).all():
        where = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{name} must be finite ({what}); {name}{list(where)} = {arr[where]}")
    return arr


def checked_goals(achieved_goal: Any, desired_goal: Any) -> tuple[np.ndarray, np.ndarray]:
    """Both goals as finite float64 ``(..., 3)`` arrays whose batch shapes broadcast.

    Raises
    ------
    ValueError
        Naming the goal that is not real, not finite or not ``(..., 3)``, or both shapes when
        they do not broadcast.
    """
    what = "goal positions x, y, z in m, world frame, shape (..., 3)"
    a = _real(achieved_goal, "achieved_goal", what)
    d = _real(desired_goal, "desired_goal", what)
    for name, arr in (("achieved_goal", a), ("desired_goal", d)):
        if arr.ndim == 0 or arr.shape[-1] != GOAL_DIM:
            raise ValueError(f"{name} must have shape (..., {GOAL_DIM}) ({what}); got shape "
                             f"{arr.shape}")
    try:
        np.broadcast_shapes(a.shape, d.shape)
    except ValueError:
        raise ValueError(f"achieved_goal {a.shape} and desired_goal {d.shape} must have batch "
                         "shapes that broadcast") from None
    return a, d


def goal_distance(achieved_goal: Any, desired_goal: Any) -> np.ndarray:
    """Euclidean distance between goals (unchecked: see :func:`checked_goals`).

    Parameters
    ----------
    achieved_goal, desired_goal : (..., 3) float array_like, m, world frame
        Broadcast against each other.

    Returns
    -------
    d : (...) float, m
    """
    diff = np.subtract(achieved_goal, desired_goal, dtype=np.float64)
    return np.sqrt(np.square(diff).sum(axis=-1))


def info_actions(info: Any) -> np.ndarray:
    """The actions ``info`` carries: ``(..., n)`` float.

    Parameters
    ----------
    info : dict, or sequence / object ndarray of dicts
        A dict whose ``"action"`` is an ``(..., n)`` array, or per-transition dicts each with an
        ``(n,)`` action (their batch shape is kept).

    Raises
    ------
    ValueError
        When an action is missing, naming the fix for Stable-Baselines3's HER buffer.
    """
    if isinstance(info, Mapping):
        if ACTION_KEY not in info:
            raise _missing_action()
        return _real(info[ACTION_KEY], "info['action']", "the action as applied, (..., n)")
    if isinstance(info, str | bytes):
        raise _missing_action()
    infos = np.asarray(info, dtype=object)
    flat = infos.reshape(-1)
    try:
        actions = [i[ACTION_KEY] for i in flat]
    except (KeyError, TypeError, IndexError) as err:
        raise _missing_action() from err
    try:
        stacked = np.stack([_real(a, "info['action']", "the action as applied, (n,) per "
                                  "transition") for a in actions])
    except ValueError as err:
        if "info['action']" in str(err):
            raise
        raise ValueError(f"the infos' actions must all have one shape (n,); got shapes "
                         f"{sorted({np.shape(a) for a in actions})}") from err
    return stacked.reshape(*infos.shape, *stacked.shape[1:])


def _missing_action() -> ValueError:
    return ValueError(
        f"the dense reward needs the action: pass info with an {ACTION_KEY!r} entry (the env's "
        "step() info has one). Stable-Baselines3's HerReplayBuffer drops infos unless "
        "replay_buffer_kwargs=dict(copy_info_dict=True); or use reward_type='sparse'"
    )


@functools.cache
def action_penalty_scale(task: TaskSpec) -> np.ndarray:
    """Per-joint divisor ``(n,)`` applied to the action before eq. 2 squares it.

    Ones for ``action_penalty_unit="command"`` (the command's own unit); the command bound
    (:func:`envs.dynamics.command_bounds`: pi rad in position mode) for ``"actor"``.
    """
    if task.action_penalty_unit == "command":
        return np.ones(task.n_joints)
    from envs.dynamics import command_bounds  # Pinocchio only for this reading

    return command_bounds(task)[1]


def reach_reward(distance: Any, action: Any, task: TaskSpec, scale: Any = None) -> Any:
    """The task's reward (eq. 2), unchecked, for numpy arrays and torch tensors alike: the one
    definition the envs (:class:`envs.task.ReachTask`, :class:`envs.torchreach.TorchReach`),
    :func:`compute_reward` and the studies read.

    Parameters
    ----------
    distance : (...) float array or tensor, m
        tool0-goal distances after the step.
    action : (..., n) float array or tensor, or None
        The actions as applied, in the command's unit (ignored, may be None, if sparse).
    task : TaskSpec
    scale : (n,) array or tensor, optional
        :func:`action_penalty_scale` in ``action``'s own library (and device); built when None.

    Returns
    -------
    reward : (...) array or tensor of ``distance``'s dtype
        Dense: ``-distance_weight d - action_weight |a / s|^2 + success_reward
        1{d <= success_radius}``, with s from :func:`action_penalty_scale` (1 in the command's
        unit, the command bound in the actor's); sparse: the last term alone.
    """
    reached = distance <= task.success_radius
    # a tensor's bool -> float keeps the distance's dtype and device (torch's float * bool
    # would give the default float32); numpy's astype does the same for arrays
    bonus = task.success_reward * (reached.to(distance.dtype) if hasattr(reached, "to")
                                   else reached.astype(distance.dtype))
    if task.reward_type == "sparse":
        return bonus
    if task.action_penalty_unit != "command":
        if scale is None:
            scale = action_penalty_scale(task)
            if hasattr(action, "new_tensor"):  # a torch tensor: the scale on its device
                scale = action.new_tensor(scale)
        action = action / scale
    return bonus - task.distance_weight * distance - task.action_weight * (action * action).sum(
        -1)


def compute_reward(achieved_goal: Any, desired_goal: Any, info: Any, task: TaskSpec
                   ) -> np.ndarray:
    """Reward of transitions that reached ``achieved_goal`` while aiming at ``desired_goal``.

    Parameters
    ----------
    achieved_goal, desired_goal : (..., 3) float array_like, m, world frame
    info : dict or sequence of dicts
        See :func:`info_actions`; ignored by the sparse reward.
    task : TaskSpec

    Returns
    -------
    reward : (...) float
        Finite.

    Raises
    ------
    ValueError
        When a goal or action is not real, not finite, or of a shape that does not fit (see
        the module docstring), or the dense reward finds no action in ``info``.
    """
    distance = goal_distance(*checked_goals(achieved_goal, desired_goal))
    if task.reward_type == "sparse":
        return reach_reward(distance, None, task)
    action = _real(info_actions(info), "info['action']", "the action as applied, (..., n)")
    if action.ndim == 0 or action.shape[-1] != task.n_joints:
        raise ValueError(f"info['action'] must have shape (..., {task.n_joints}) (the action "
                         f"of joints 1..{task.n_joints}); got shape {action.shape}")
    try:
        np.broadcast_shapes(distance.shape, action.shape[:-1])
    except ValueError:
        raise ValueError(f"info['action'] {action.shape} does not fit the goals' batch shape "
                         f"{distance.shape}: one action per transition") from None
    return reach_reward(distance, action, task)


def compute_success(achieved_goal: Any, desired_goal: Any, task: TaskSpec) -> np.ndarray:
    """Whether tool0 is within ``success_radius`` of the goal, ``(...) bool``.

    Raises
    ------
    ValueError
        As :func:`compute_reward`, for goals.
    """
    return goal_distance(*checked_goals(achieved_goal, desired_goal)) <= task.success_radius
