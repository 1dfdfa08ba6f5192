"""The fused step kernels (ddpg_her.program_kernels, Triton under its interpreter on the CPU)
against the eager rollout that defines them: a program run both ways on the real arm (the
numba kernel), every exploration kind, the stored rows, the buffer and the test session.

The fused reward sums its terms in its own order (one lane, left to right), so rewards agree
to a few ulps rather than bit for bit; everything else of the first episodes is equal."""

from __future__ import annotations

import importlib

import pytest
import torch

from ddpg_her.config import AgentConfig
from ddpg_her.program import Program

TASKS = [dict(region="farbox", n_joints=3, max_episode_steps=6),
         dict(region="unconstrained", n_joints=2, max_episode_steps=6),
         dict(region="zheight", n_joints=6, max_episode_steps=6)]

ULPS = 1e-13
"""Tolerance of the rewards and returns (their values are O(1-10); a few ulps)."""


@pytest.fixture
def interpreted(monkeypatch):
    """ddpg_her.program_kernels built under Triton's interpreter (its kernels are decorated
    when the module is imported)."""
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    import ddpg_her.program_kernels as kernels

    return importlib.reload(kernels)


def program(tmp_path, fused: bool, exploration: str) -> Program:
    cfg = AgentConfig(hidden_sizes=(16, 16), warmup_episodes=1, eval_every=3, eval_episodes=2,
                      updates_per_episode=2, batch_size=4, buffer_size=100, episodes=3,
                      exploration=exploration)
    return Program("UR5Reach-v0", TASKS, cfg, [0, 1, 2],
                   [tmp_path / f"{fused}{i}" for i in range(3)], progress=False, fused=fused)


@pytest.mark.parametrize("exploration", ["gaussian", "ou", "epsilon"])
def test_the_fused_rollout_is_the_eager_rollout(tmp_path, interpreted, exploration):
    eager, fused = program(tmp_path, False, exploration), program(tmp_path, True, exploration)
    for episode in range(3):                    # warm-up, acting, acting + the test session
        eager.step()
        fused.step()
        for name in ("obs", "achieved", "action", "terminated", "length", "success", "total",
                     "env_steps"):
            assert torch.equal(getattr(eager, name), getattr(fused, name)), (episode, name)
        torch.testing.assert_close(eager.reward, fused.reward, rtol=0, atol=ULPS)
        n = int(eager.buffer.filled.min())
        torch.testing.assert_close(eager.buffer.rows[:, :n], fused.buffer.rows[:, :n],
                                   rtol=0, atol=1e-6)    # float32 rows of the rewards above
    assert torch.equal(eager.logged[0], fused.logged[0])                    # successes
    torch.testing.assert_close(eager.logged[1:], fused.logged[1:], rtol=0, atol=1e-9)
    assert eager.rows[0][-1]["successes"] == fused.rows[0][-1]["successes"]


def test_the_switch_defaults_to_the_eager_path_on_the_cpu(tmp_path, interpreted):
    """The eager ops are the CPU's path (and the oracle); the kernels are CUDA's default."""
    assert not program(tmp_path, None, "gaussian").fused
