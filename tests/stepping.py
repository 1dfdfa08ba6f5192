"""Stepping helper shared by the dynamics tests (not a test module)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def record(dyn: Any, commands: np.ndarray, keys: Sequence[str]) -> dict[str, np.ndarray]:
    """Step ``dyn`` through ``commands (T, B, n)``; the attributes ``keys`` after each step,
    stacked ``(T, B, ...)``."""
    log: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    for command in commands:
        dyn.step(command)
        for k in keys:
            log[k].append(getattr(dyn, k).copy())
    return {k: np.array(v) for k, v in log.items()}


def step_without_cuda_sync(env: Any, actions: Any) -> None:
    """Step the vector env ``env`` with ``actions[0]`` (compilation and lazy CUDA set-up),
    then with each later row under torch's sync debug mode set to "error": any host
    synchronisation in those steps raises."""
    import torch

    env.step(actions[0])
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        for a in actions[1:]:
            env.step(a)
    finally:
        torch.cuda.set_sync_debug_mode("default")
