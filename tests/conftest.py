"""Fixtures shared by the test modules (helpers shared as functions live in non-test modules:
``arm_geometry``, ``cli_tools``, ``toy_goal_env``)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def one_torch_thread() -> Iterator[None]:
    """Torch on one CPU thread in every test. The tests' networks are small and gain nothing
    from more threads; on a loaded machine extra threads only wait for cores. Measured on the
    2-core machine under load: the stacked-vs-separate DDPG test took 176 s with torch's default
    threads and 6 s with one, SB3's smoke run 152 s and 26 s."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
    # A Trainer sets the CPU's subnormal flush process-wide (AgentConfig.flush_denormals) and
    # torch cannot read it back: turn it off after every test, or a later test in the process
    # computes with subnormals flushed (hypothesis then refuses to draw floats at all).
    torch.set_flush_denormal(False)


@pytest.fixture(scope="session")
def tiny_ur5_run(tmp_path_factory) -> Path:
    """A UR5 far-box run of 2 episodes with a checkpoint (an untrained policy: it still moves
    the arm away from its start), trained once per session; tests that change it copy it.

    Under pytest-xdist the workers share one: the first to ask trains it in the session's
    base folder (the parent of the workers' own) under a lock, the others wait for it."""
    import fcntl
    import os
    import shutil

    from cli_tools import run_module

    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        folder = tmp_path_factory.mktemp("tiny-ur5")
    else:
        folder = tmp_path_factory.getbasetemp().parent / "tiny-ur5"
        folder.mkdir(exist_ok=True)
    run, done = folder / "run", folder / "trained"
    with open(folder / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            shutil.rmtree(run, ignore_errors=True)  # a worker's attempt that failed
            run_module("ddpg_her.train", "--region", "farbox", "--joints", "3", "--episodes",
                       "2", "--eval-every", "2", "--eval-episodes", "2", "--hidden-sizes", "16",
                       "16", "--warmup-episodes", "1", "--out", str(run), "--no-progress",
                       "--threads", "1", "--no-tensorboard")
            done.touch()
    return run
