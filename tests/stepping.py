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
