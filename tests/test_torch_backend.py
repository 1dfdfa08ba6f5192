"""The trainer's torch env backend (issue 14): rollout, HER and buffer on the device.

Two paths: with no exploration draws (no warm-up, rate 0) the torch backend gives the numpy
backend's eval.csv and replay buffer (after HER relabelling) for the same seeds; with
exploration, its own stream makes a run deterministic per seed.
"""

from __future__ import annotations

import pytest
import torch

from ddpg_her.config import AgentConfig
from ddpg_her.trainer import Trainer

QUIET = AgentConfig(episodes=2, eval_every=2, eval_episodes=2, hidden_sizes=(8, 8),
                    updates_per_episode=3, buffer_size=500, batch_size=8, exploration_rate=0.0,
                    warmup_episodes=0)
"""No exploration draws: the two backends' streams cannot differ."""
TASK = {"region": "zheight", "n_joints": 3, "max_episode_steps": 15}
DEVICES = ["cpu", pytest.param("cuda", marks=[pytest.mark.gpu, pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA device")])]


def _train(tmp_path, backend: str, config: AgentConfig = QUIET, device: str = "cpu",
           name: str = "run"):
    trainer = Trainer("UR5Reach-v0", TASK, config, [3, 4],
                      [tmp_path / f"{name}-{backend}-a", tmp_path / f"{name}-{backend}-b"],
                      dtype=torch.float64, device=device, progress=False, tensorboard=False,
                      env_backend=backend)
    rows = [[{k: v for k, v in r.items() if k != "wall_s"} for r in agent]
            for agent in trainer.run()]
    total = trainer.buffer.total.copy()
    stored = trainer.buffer.rows[:, :int(total.max())].cpu().clone()
    for k, n in enumerate(total):  # rows past an agent's own count were never written
        stored[k, int(n):] = 0.0
    return rows, stored, total


@pytest.mark.parametrize("device", DEVICES)
def test_torch_backend_trains_as_the_numpy_backend(tmp_path, device):
    # both backends' networks and buffers on ``device``, so that only where the envs step
    # differs (on an H100, CUDA networks for the torch backend against CPU ones for the numpy
    # backend stored values up to 0.62 apart after 2 episodes)
    rows, stored, total = _train(tmp_path, "numpy", device=device)
    rows_t, stored_t, total_t = _train(tmp_path, "torch", device=device)
    assert (total == total_t).all()
    assert total[0] > QUIET.episodes * TASK["max_episode_steps"]  # HER copies are stored too
    # obs, goals, actions, rewards (HER-relabelled too) and terminations, in float64 on the CPU
    torch.testing.assert_close(stored_t, stored, rtol=1e-6 if device == "cuda" else 0,
                               atol=1e-6 if device == "cuda" else 0)
    assert rows_t == rows if device == "cpu" else \
        [[r["successes"] for r in a] for a in rows_t] == [[r["successes"] for r in a]
                                                          for a in rows]


def test_torch_backend_is_deterministic_per_seed(tmp_path):
    explore = AgentConfig(**{**QUIET.to_dict(), "exploration_rate": 0.3, "warmup_episodes": 1})
    a = _train(tmp_path, "torch", explore, name="first")
    b = _train(tmp_path, "torch", explore, name="second")
    assert a[0] == b[0]
    assert torch.equal(a[1], b[1])
    # ... and it explores: the quiet run's actions differ
    quiet = _train(tmp_path, "torch", name="quiet")
    assert not torch.equal(quiet[1], a[1])


def test_torch_backend_refuses_an_env_without_a_tensor_twin(tmp_path):
    with pytest.raises(ValueError, match="tensor twin"):
        Trainer("toy_goal_env:ToyReach-v0", {}, QUIET, [0], [tmp_path / "x"],
                progress=False, tensorboard=False, env_backend="torch")
