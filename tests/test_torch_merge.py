"""Merged tensor twins (TorchGoalVecEnv(merge=True), the trainer's ``torch`` env backend) against
one twin per group: the same goals, the same steps bit for bit on the CPU, the same rewards for
HER, the same training.

Two paths, as tests/test_merged_envs.py holds the host's merge: the groups of one layout stepped
each by its own ``envs.TorchReach`` (``merge=False``) and those whose tasks differ only in
``GOAL_FIELDS`` stepped by one (``merge=True``). The groups interleave regions whose start poses
differ (unconstrained at the zero pose, the others at the constrained start) and a reward
reading (sparse) that must not merge with the dense one, so that the merged batches' copies are
not in flat order. The fused kernel's twin (``dynamics="numba"``) runs under numba's CUDA
simulator in a subprocess (as tests/test_torchreach_numba.py's checks).
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from ddpg_her import collect
from ddpg_her.config import AgentConfig
from ddpg_her.trainer import Trainer
from ddpg_her.vecenv import TorchGoalVecEnv
from envs.torchreach import TorchReach

ROOT = Path(__file__).resolve().parent.parent

COMMON = {"n_joints": 3, "success_radius": 0.3, "max_episode_steps": 12}
"""Every group's fields: a wide success ball (terminations happen) and short episodes."""
GROUPS = [{"region": "zheight"}, {"region": "farbox"}, {"region": "unconstrained"},
          {"region": "closebox"}, {"region": "zheight", "reward_type": "sparse"},
          {"region": "farbox"}]
"""Groups 0, 1, 3, 5 differ only in their regions: one batch; 2 starts at another pose and 4
reads the reward otherwise: one batch each."""
BATCHES = [[0, 1, 3, 5], [2], [4]]


def _pair(copies: int, **kwargs) -> list[TorchGoalVecEnv]:
    return [TorchGoalVecEnv("UR5Reach-v0", GROUPS, copies, merge=m, **COMMON, **kwargs)
            for m in (False, True)]


def _stepped(monkeypatch) -> list[int]:
    """The ids of the TorchReach instances stepped from now on, one entry per step call."""
    ids: list[int] = []
    step = TorchReach.step

    def counted(self, actions):
        ids.append(id(self))
        return step(self, actions)

    monkeypatch.setattr(TorchReach, "step", counted)
    return ids


def rollouts(copies: int, steps: int, dynamics: str | None = None,
             stepped: list[int] | None = None) -> dict[str, object]:
    """Two episodes (two resets, other seeds) of random actions in both pairs; every output
    compared. Returns the worst difference of floats, whether flags and goals were equal, the
    TorchReach step calls per env step (unmerged, merged) and whether the check saw
    terminations and contacts' effects (rewards of both signs)."""
    envs = _pair(copies, dynamics=dynamics)
    n, scale = envs[0].num_envs, envs[0].scale
    rng = np.random.default_rng(7)
    worst, flags_equal, goals_equal, calls, ended = 0.0, True, True, [0, 0], False
    for episode in range(2):
        seeds = list(range(100 * episode, 100 * episode + n))
        obs = [e.reset(seeds) for e in envs]
        goals_equal &= torch.equal(obs[0]["desired_goal"], obs[1]["desired_goal"])
        worst = max(worst, *(float((obs[0][k] - obs[1][k]).abs().max()) for k in obs[0]))
        active = torch.ones(n, dtype=torch.bool)
        for _ in range(steps):
            action = torch.as_tensor(rng.uniform(scale.low, scale.high, (n, scale.dim)))
            out = []
            for i, (e, o) in enumerate(zip(envs, obs, strict=True)):
                before = len(stepped) if stepped is not None else 0
                out.append(e.step(action, active, o))
                calls[i] = len(stepped) - before if stepped is not None else 0
            obs = [x[0] for x in out]
            worst = max(worst, *(float((obs[0][k] - obs[1][k]).abs().max()) for k in obs[0]),
                        float((out[0][1] - out[1][1]).abs().max()))
            flags_equal &= all(torch.equal(a, b) for a, b in zip(out[0][2:], out[1][2:],
                                                                  strict=True))
            ended |= bool(out[0][2].any())
            active &= ~(out[0][2] | out[0][3])
    return {"worst": worst, "flags": flags_equal, "goals": goals_equal, "calls": calls,
            "terminated": ended, "batches": [[int(i) // copies for i in b.index[::copies]]
                                             for b in envs[1].batches]}


def her_rules(dynamics: str | None = None) -> None:
    """Every group's reward_fn and terminated_fn, merged and unmerged, on the same transitions
    (..., goal_dim) with actions: equal; and the sparse group's differ from the dense ones'."""
    envs = _pair(1, dynamics=dynamics)
    rng = np.random.default_rng(3)
    ag, dg = (torch.as_tensor(rng.uniform(-0.8, 0.8, (4, 5, 3))) for _ in range(2))
    dg[0, 0] = ag[0, 0]  # one success
    action = torch.as_tensor(rng.uniform(-2.0, 2.0, (4, 5, 3)))
    for k in range(len(GROUPS)):
        for fn in ("reward_fn", "terminated_fn"):
            want, got = (getattr(e, fn)(ag, dg, action, group=k) for e in envs)
            assert torch.equal(got, want), (fn, k)
    sparse, dense = (envs[1].reward_fn(ag, dg, action, group=k) for k in (4, 0))
    assert not torch.equal(sparse, dense)


# ------------------------------------------------------------------ the CPU, torch's kernel
@pytest.mark.parametrize("copies", [1, 3])
def test_merged_twins_step_as_one_twin_per_group(monkeypatch, copies):
    stepped = _stepped(monkeypatch)
    got = rollouts(copies, steps=12, stepped=stepped)
    assert got["batches"] == BATCHES
    assert got["calls"] == [len(GROUPS), len(BATCHES)]  # one TorchReach per batch is stepped
    assert got["goals"] and got["flags"] and got["terminated"]
    assert got["worst"] == 0.0  # bit for bit: the copies do not interact


def test_merged_twins_reward_and_terminate_as_each_group():
    her_rules()


def test_merged_goals_are_the_groups_own_draws():
    # the merged batches' twins draw from their own (batched) source; the goals they start with
    # are each group's twin's draw for the copy's seed, TorchReach.reset's own goals
    envs = _pair(2)
    seeds = list(range(40, 40 + envs[0].num_envs))
    merged = envs[1].reset(seeds)["desired_goal"]
    for k, kw in enumerate(GROUPS):
        own = TorchReach(2, goal_source="per_copy", goal_pool=1, **{**COMMON, **kw})
        want = own.reset(seed=seeds[2 * k:2 * k + 2])[0]["desired_goal"]
        assert torch.equal(merged[2 * k:2 * k + 2], want), k


# ------------------------------------------------------------------ the fused kernel, simulated
def check_numba_merged_twins() -> str:
    """Under numba's simulator: the fused kernel's twins merged against one per group, every
    output to 1e-12 (bitwise in practice), one kernel launch per batch and step."""
    from envs.physics import numba_cuda
    from envs.physics.numba_torch import NumbaTorchDynamics

    assert numba_cuda.simulated()
    launches: list[int] = []
    step = NumbaTorchDynamics.step

    def counted(self, command):
        launches.append(id(self))
        step(self, command)

    NumbaTorchDynamics.step = counted
    try:
        got = rollouts(1, steps=5, dynamics="numba", stepped=launches)
    finally:
        NumbaTorchDynamics.step = step
    assert got["batches"] == BATCHES, got
    assert got["calls"] == [len(GROUPS), len(BATCHES)], got
    assert got["goals"] and got["flags"], got
    assert got["worst"] <= 1e-12, got
    her_rules("numba")
    return f"worst {got['worst']}"


SIMULATOR = """
import sys
sys.path.insert(0, "tests")
import test_torch_merge as t
print(getattr(t, sys.argv[1])(), flush=True)
"""


def test_numba_merged_twins_under_the_cuda_simulator():
    pytest.importorskip("numba")
    env = {**os.environ, "NUMBA_ENABLE_CUDASIM": "1", "OMP_NUM_THREADS": "1"}
    run = subprocess.run([sys.executable, "-c", SIMULATOR, "check_numba_merged_twins"], env=env,
                         cwd=ROOT, capture_output=True, text=True)
    if run.returncode and "CUDA" in run.stderr and "simulat" not in run.stderr:
        pytest.skip(f"numba's CUDA simulator does not start here: {run.stderr[-300:]}")
    assert run.returncode == 0, run.stdout + run.stderr[-4000:]
    assert run.stdout.splitlines()[-1].startswith("worst "), run.stdout


# ------------------------------------------------------------------ training
CONFIG = AgentConfig(episodes=2, eval_every=2, eval_episodes=2, hidden_sizes=(8, 8),
                     updates_per_episode=3, buffer_size=500, batch_size=8, exploration_rate=0.3,
                     warmup_episodes=1)
"""A warm-up episode, then an exploring one: the noise is drawn on the device."""
TASKS = [{"region": "zheight", "n_joints": 3, "max_episode_steps": 15},
         {"region": "farbox", "n_joints": 3, "max_episode_steps": 15}]


def _train(tmp_path, merge: bool, monkeypatch):
    monkeypatch.setattr(collect, "TorchGoalVecEnv",
                        functools.partial(TorchGoalVecEnv, merge=merge))
    name = "merged" if merge else "apart"
    trainer = Trainer("UR5Reach-v0", TASKS, CONFIG, [3, 4],
                      [tmp_path / f"{name}-a", tmp_path / f"{name}-b"], dtype=torch.float64,
                      progress=False, tensorboard=False, env_backend="torch")
    try:
        rows = [[{k: v for k, v in r.items() if k != "wall_s"} for r in agent]
                for agent in trainer.run()]
        total = trainer.buffer.total.copy()
        stored = trainer.buffer.rows[:, :int(total.max())].clone()
        for k, n in enumerate(total):  # rows past an agent's own count were never written
            stored[k, int(n):] = 0.0
        batches = (len(trainer.envs.batches), len(trainer.eval_envs.batches))
        return rows, stored, total, batches
    finally:
        trainer.close()


def test_merged_torch_backend_trains_as_one_twin_per_agent(tmp_path, monkeypatch):
    rows, stored, total, batches = _train(tmp_path, False, monkeypatch)
    rows_m, stored_m, total_m, batches_m = _train(tmp_path, True, monkeypatch)
    assert batches == (0, 0) and batches_m == (1, 1)  # both regions in one twin
    assert (total == total_m).all() and total[0] > CONFIG.episodes * 15
    assert torch.equal(stored_m, stored)  # obs, goals, actions, HER rewards, terminations
    assert rows_m == rows
