"""Kernel launches counted on any device, the CPU included: every ATen op that would launch a
device kernel, seen at torch's dispatch level (issue 42).

An op counts one launch unless it only makes a view or allocates (``is_view`` ops, ``empty*``,
``detach``, ``alias``, ``lift_fresh``), which on CUDA launch nothing. Work done outside torch's
dispatcher (a Triton or numba kernel called directly) is not seen here: wrap its launcher with
:meth:`LaunchCounter.wrap` so each call counts one launch under its own name.

    with LaunchCounter() as n:
        body()
    n.total, n.by_op.most_common(10)
"""

from __future__ import annotations

import collections
import functools
from collections.abc import Callable
from typing import Any

import torch
from torch.utils._python_dispatch import TorchDispatchMode

NO_KERNEL = frozenset({"empty", "empty_strided", "empty_like", "new_empty", "detach", "alias",
                       "lift_fresh", "lift_fresh_copy", "_local_scalar_dense"})
"""ATen ops (overload packet names) that launch no device kernel: allocation, aliasing. The
host read ``_local_scalar_dense`` is not a launch but a sync; it is counted in ``syncs``."""


class LaunchCounter(TorchDispatchMode):
    """Counts launches inside a ``with`` block: ``total``, ``by_op`` (a Counter by op name)
    and ``syncs`` (host reads of a device value, ``_local_scalar_dense``)."""

    active: LaunchCounter | None = None

    def __init__(self) -> None:
        super().__init__()
        self.by_op: collections.Counter[str] = collections.Counter()
        self.syncs = 0

    @property
    def total(self) -> int:
        return sum(self.by_op.values())

    def __enter__(self) -> LaunchCounter:
        LaunchCounter.active = self
        return super().__enter__()

    def __exit__(self, *exc: Any) -> None:
        LaunchCounter.active = None
        return super().__exit__(*exc)

    def __torch_dispatch__(self, func: Any, types: Any, args: tuple = (),
                           kwargs: dict | None = None) -> Any:
        out = func(*args, **(kwargs or {}))
        name = func.overloadpacket.__name__
        if name == "_local_scalar_dense":
            self.syncs += 1
        elif not (func.is_view or name in NO_KERNEL):
            self.by_op[name] += 1
        return out

    @staticmethod
    def wrap(name: str, launch: Callable[..., Any]) -> Callable[..., Any]:
        """``launch`` counting one launch named ``name`` per call while a counter is active
        (its own torch ops, if any, are not counted: a kernel launch is one launch)."""

        @functools.wraps(launch)
        def counted(*args: Any, **kwargs: Any) -> Any:
            counter = LaunchCounter.active
            if counter is None:
                return launch(*args, **kwargs)
            counter.by_op[name] += 1
            with torch.utils._python_dispatch._disable_current_modes():
                return launch(*args, **kwargs)

        return counted
