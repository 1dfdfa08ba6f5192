"""Merged batches (GoalVecEnv(merge=True), the trainer's ``batched`` env backend) against one
group per agent: the same goals exactly, the same steps to rounding, the same training."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import toy_goal_env  # noqa: F401  (registers ToyReach-v0)
from toy_goal_env import ENV_ID as TOY_ID

from ddpg_her.config import AgentConfig
from ddpg_her.trainer import Trainer
from ddpg_her.vecenv import GoalVecEnv

GROUPS = [{"region": r, "n_joints": 3} for r in ("unconstrained", "zheight", "farbox", "closebox")]
"""Four regions of one layout: unconstrained starts at the zero pose, the others at the
constrained start, so they merge into two batches."""
STEP_ATOL = 1e-9
"""Bound on a merged single copy (the compiled kernel) against the single env (Pinocchio's
loop): observations (m, rad, rad/s) and rewards over 40 steps with plane contacts; measured
6e-14."""


def _rollouts(copies: int, steps: int = 40):
    envs = [GoalVecEnv("UR5Reach-v0", GROUPS, copies, merge=m) for m in (False, True)]
    seeds = list(range(100, 100 + envs[0].num_envs))
    obs = [e.reset(seeds) for e in envs]
    first = [{k: v.copy() for k, v in o.items()} for o in obs]
    rng = np.random.default_rng(0)
    active = np.ones(envs[0].num_envs, dtype=bool)
    worst, flags = 0.0, []
    for _ in range(steps):
        action = rng.uniform(envs[0].scale.low, envs[0].scale.high,
                             (envs[0].num_envs, envs[0].scale.dim))
        out = [e.step(action, active, o) for e, o in zip(envs, obs, strict=True)]
        obs = [o[0] for o in out]
        worst = max(worst, *(np.abs(obs[0][k] - obs[1][k]).max() for k in obs[0]))
        worst = max(worst, np.abs(out[0][1] - out[1][1]).max())  # the rewards
        flags.append([np.array_equal(a, b) for a, b in zip(out[0][2:], out[1][2:], strict=True)])
        active &= ~(out[0][2] | out[0][3])
    return envs, first, worst, flags


@pytest.mark.parametrize("copies", [1, 4])
def test_merged_batches_keep_each_groups_goals_and_steps(copies):
    envs, first, worst, flags = _rollouts(copies)
    merged = envs[1]
    assert [len(b.index) for b in merged.batches] == [copies, 3 * copies]
    assert sorted(np.concatenate([b.index for b in merged.batches])) == \
        list(range(merged.num_envs))
    for key in first[0]:  # the goals are each group's own draws, the first observation too
        np.testing.assert_array_equal(first[1][key], first[0][key])
    # several copies per group are a compiled batch either way: bitwise; a single copy is
    # Pinocchio's loop unmerged: to rounding
    assert worst == 0.0 if copies > 1 else worst <= STEP_ATOL
    assert all(all(f) for f in flags)  # terminations, truncations, successes


def test_envs_without_a_vector_entry_point_or_task_are_not_merged():
    env = GoalVecEnv(TOY_ID, [{"region": "box", "n_joints": 2}] * 2, 3, merge=True)
    assert env.batches == []


QUIET = AgentConfig(episodes=2, eval_every=2, eval_episodes=2, hidden_sizes=(8, 8),
                    updates_per_episode=3, buffer_size=500, batch_size=8, exploration_rate=0.0,
                    warmup_episodes=1)
TASKS = [{"region": "zheight", "n_joints": 3, "max_episode_steps": 15},
         {"region": "farbox", "n_joints": 3, "max_episode_steps": 15}]


def _train(tmp_path, backend: str):
    trainer = Trainer("UR5Reach-v0", TASKS, QUIET, [3, 4],
                      [tmp_path / f"{backend}-a", tmp_path / f"{backend}-b"],
                      dtype=torch.float64, progress=False, tensorboard=False,
                      env_backend=backend)
    try:
        rows = trainer.run()
        total = trainer.buffer.total.copy()
        stored = trainer.buffer.rows[:, :int(total.max())].clone()
        for k, n in enumerate(total):  # rows past an agent's own count were never written
            stored[k, int(n):] = 0.0
        return trainer, rows, stored, total
    finally:
        trainer.close()


def test_batched_backend_trains_as_the_numpy_backend(tmp_path):
    """A warm-up episode and an exploring-free one, both agents in one merged batch: the same
    random actions, goals and HER relabels; the stored values equal to rounding."""
    numpy_run, rows, stored, total = _train(tmp_path, "numpy")
    batched, rows_b, stored_b, total_b = _train(tmp_path, "batched")
    assert len(batched.envs.batches) == 1 and len(batched.eval_envs.batches) == 1
    assert (total == total_b).all() and total[0] > QUIET.episodes * 15
    torch.testing.assert_close(stored_b, stored, rtol=0, atol=1e-6)
    assert [[r["successes"] for r in a] for a in rows_b] == \
        [[r["successes"] for r in a] for a in rows]
    assert batched.specs[0]["env_backend"] == "batched" and "env_backend" not in numpy_run.specs[0]


def test_a_run_resumes_only_under_its_own_backend(tmp_path):
    config = AgentConfig(**{**QUIET.to_dict(), "episodes": 1, "eval_every": 1})
    run = Trainer("UR5Reach-v0", TASKS[0], config, [0], [tmp_path / "run"], progress=False,
                  tensorboard=False)
    run.run()
    run.close()
    with pytest.raises(ValueError, match=r"differing: env_backend \(was 'numpy', now 'batched'\)"):
        Trainer("UR5Reach-v0", TASKS[0], config, [0], [tmp_path / "run"], resume=True,
                progress=False, tensorboard=False, env_backend="batched")
