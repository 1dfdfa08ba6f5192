"""The vector env's checks of its arguments and reset options, and Gymnasium's autoreset modes,
written for numpy arrays and torch tensors alike.

:class:`envs.batched.BatchedReach` derives from :class:`VectorReach` and supplies its few array
hooks (the torch twin that shared them, ``envs.torchreach``, gave way to the training program's
:class:`envs.stackreach.StackReach`); the single env (:class:`envs.reach.UR5ReachEnv`) checks its
options with :func:`reset_options` too.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode

from envs.spec import TaskSpec


def check_num_envs(num_envs: Any) -> int:
    """``num_envs`` as an int, or a ValueError when it is not an integer >= 1."""
    if not isinstance(num_envs, int | np.integer) or num_envs < 1:
        raise ValueError(f"num_envs must be an integer >= 1; got {num_envs!r}")
    return int(num_envs)


def reset_options(options: Any, known: Sequence[str], example: str) -> dict[str, Any]:
    """The reset ``options`` as a dict (empty for None), or a ValueError when they are not a
    mapping (``example`` shows one) or hold a key not in ``known``."""
    if options is not None and not isinstance(options, Mapping):
        raise ValueError(f"options must be a dict such as {example}; got {options!r:.200}")
    options = dict(options or {})
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ValueError(f"unknown reset option(s) {unknown}; known: "
                         + ", ".join(repr(k) for k in known))
    return options


def copy_seeds(seed: int | Sequence[int | None] | None, num_envs: int) -> list[int | None]:
    """Each copy's seed: copy i's ``seed + i`` for an int, ``seed[i]`` for one seed per copy,
    None (fresh entropy) for None; a ValueError for another number of seeds."""
    if seed is None:
        return [None] * num_envs
    if isinstance(seed, int | np.integer):
        return [int(seed) + i for i in range(num_envs)]
    seeds = list(seed)
    if len(seeds) != num_envs:
        raise ValueError(f"seed must be an int, None or {num_envs} seeds; got {len(seeds)} seeds")
    return seeds


class VectorReach:
    """N copies of the task with Gymnasium's autoreset modes, over arrays or tensors.

    A subclass sets ``task``, ``num_envs``, ``metadata["autoreset_mode"]`` and ``_ended``
    ((N,) bool, the episodes that ended on the last step), and supplies the hooks over its
    arrays: ``_checked_actions(actions)`` (N, n) or a ValueError; ``_advance(actions)`` steps
    every copy and returns its reward, terminated and truncated (N,); ``_reset_where(mask)``
    starts new episodes where ``mask``; ``_observation()`` and ``_info()`` (with the ``_key``
    masks) now; ``_final(info, done)``, ``same_step``'s ``final_obs``, ``final_info`` and
    their masks; ``_where``, its library's ``where(mask, x, y)``.

    Autoreset modes (``metadata["autoreset_mode"]``), for a copy whose episode ended:

    - ``next_step`` (Gymnasium's default): the next ``step`` resets it instead of stepping it;
      its action is ignored, and it returns the first observation of the new episode with
      reward 0 and both flags False.
    - ``same_step``: it is reset within the same ``step``; the returned observation is the new
      episode's first, the episode's last observation and info are in ``info["final_obs"]`` /
      ``info["final_info"]`` (masks ``info["_final_obs"]``, ``info["_final_info"]``).
    - ``disabled``: never reset automatically; ``reset(options={"reset_mask": done})``.
    """

    task: TaskSpec
    num_envs: int
    metadata: dict[str, Any]
    _ended: Any
    _where: Any
    _checked_actions: Any
    _advance: Any
    _reset_where: Any
    _observation: Any
    _info: Any
    _final: Any

    @property
    def dt(self) -> float:
        """Duration of one step (s)."""
        return self.task.dt

    def step(self, actions: Any) -> tuple[dict[str, Any], Any, Any, Any, dict[str, Any]]:
        """Step every copy with ``actions (N, n)``; see the class docstring for episode ends.

        Returns observations (dict of (N, ...)), rewards (N,), terminations (N,), truncations
        (N,) and infos (dict of (N, ...) with ``_key`` masks), arrays or tensors as the env's.
        """
        reward, terminated, truncated = self._advance(self._checked_actions(actions))
        mode = self.metadata["autoreset_mode"]
        if mode == AutoresetMode.NEXT_STEP:
            ended = self._ended
            self._reset_where(ended)  # the copies that ended last step start anew instead
            keep = ~ended
            reward = self._where(keep, reward, 0.0)
            terminated, truncated = terminated & keep, truncated & keep
            self._ended = terminated | truncated
            return self._observation(), reward, terminated, truncated, self._info()
        info = self._info()
        if mode == AutoresetMode.SAME_STEP:
            done = terminated | truncated
            info.update(self._final(info, done))
            self._reset_where(done)
        return self._observation(), reward, terminated, truncated, info
