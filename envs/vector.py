"""The envs' checks of their arguments and reset options: the vector env's
(:class:`envs.batched.BatchedReach`) and the single env's (:class:`envs.reach.UR5ReachEnv`,
which checks its options with :func:`reset_options` too).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np


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
