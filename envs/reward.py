"""The Reacher's reward (eq. 2) and the checks of what a GoalEnv caller passes, vectorised.

:func:`goal_distance` and :func:`reach_reward` are the unchecked kernels the env's step calls
on values it made itself (NaN in gives NaN out), for numpy arrays and torch tensors alike.
:func:`checked_goals` and :func:`info_actions` check what a caller passes to the GoalEnv
functions (:func:`envs.task.compute_reward`): goals or actions that are not real numbers, not
finite, or whose shapes do not fit raise ``ValueError``, never a NaN reward. ``info`` is one
dict of batched arrays or a list/array of per-transition dicts (Stable-Baselines3); the dense
reward reads the action from ``info["action"]``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ur5kin import checks

if TYPE_CHECKING:
    from envs.spec import TaskSpec

ACTION_KEY = "action"
"""The ``info`` key that carries the action (as applied, after clipping) to the dense reward."""


GOAL_DIM = 3
"""Length of a goal: tool0's x, y, z (m, world frame)."""


def real_array(x: Any, name: str, what: str) -> np.ndarray:
    """``x`` as a finite float64 array, or ValueError naming ``name`` and what was expected."""
    arr = checks.real_array(x, name, what)
    checks.check_finite(arr, name)
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
    a = real_array(achieved_goal, "achieved_goal", what)
    d = real_array(desired_goal, "desired_goal", what)
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


def goal_distance(achieved_goal: Any, desired_goal: Any) -> Any:
    """Euclidean distance between goals (unchecked: see :func:`checked_goals`), for numpy
    arrays and torch tensors alike.

    Parameters
    ----------
    achieved_goal, desired_goal : (..., 3) float array_like or tensors, m, world frame
        Broadcast against each other.

    Returns
    -------
    d : (...) float64 array, or tensor of the goals' dtype and device, m
    """
    if hasattr(achieved_goal, "sqrt"):  # a torch tensor: its dtype and device
        diff = achieved_goal - desired_goal
        return (diff * diff).sum(-1).sqrt()
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
        return real_array(info[ACTION_KEY], "info['action']", "the action as applied, (..., n)")
    if isinstance(info, str | bytes):
        raise _missing_action()
    infos = np.asarray(info, dtype=object)
    flat = infos.reshape(-1)
    try:
        actions = [i[ACTION_KEY] for i in flat]
    except (KeyError, TypeError, IndexError) as err:
        raise _missing_action() from err
    try:
        stacked = np.stack([real_array(a, "info['action']", "the action as applied, (n,) per "
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


def reach_reward(distance: Any, action: Any, task: TaskSpec, scale: Any) -> Any:
    """The task's reward (eq. 2), unchecked, for numpy arrays and torch tensors alike: the one
    definition the envs (:class:`envs.task.TaskRules`, :class:`envs.stackreach.StackReach`),
    :func:`envs.task.compute_reward` and the studies read.

    Parameters
    ----------
    distance : (...) float array or tensor, m
        tool0-goal distances after the step.
    action : (..., n) float array or tensor, or None
        The actions as applied, in the command's unit (ignored, may be None, if sparse).
    task : TaskSpec
    scale : (n,) array or tensor, or None
        :func:`envs.task.action_penalty_scale` in ``action``'s own library (and device); read
        only under ``action_penalty_unit="actor"`` (None will do otherwise).

    Returns
    -------
    reward : (...) array or tensor of ``distance``'s dtype
        Dense: ``-distance_weight d - action_weight |a / s|^2 + success_reward
        1{d <= success_radius}``, with s the ``scale`` (1 in the command's
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
        action = action / scale
    return bonus - task.distance_weight * distance - task.action_weight * (action * action).sum(
        -1)
