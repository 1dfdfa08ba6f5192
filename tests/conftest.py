"""Fixtures shared by the test modules (helpers shared as functions live in non-test modules:
``arm_geometry``, ``cli_tools``, ``toy_goal_env``)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Torch on one CPU thread for the test: small networks gain nothing from more, and on a
    loaded machine extra threads only wait for cores."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
