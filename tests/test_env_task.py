"""envs.task.TaskRules owns the task's rules: the single and the batched env give the same step
information key by key, and it agrees with the rules recomputed here from the task's numbers."""

from __future__ import annotations

import numpy as np
import pytest

from envs import BatchedReach, TaskSpec, UR5ReachEnv
from envs.task import INFO_KEYS, RESET_INFO_KEYS, TaskRules

SCALAR_TYPES = {"distance": float, "is_success": bool, "contact": bool, "joint_limit": bool,
                "clearance": float}
"""The single env's info values other than the action: Python scalars (not numpy ones)."""

COPIES = 3
STEPS = 30


def assert_same_info(single: dict, batched: dict, i: int, keys=INFO_KEYS) -> None:
    """Copy ``i`` of the batched env's info equals the single env's info, key by key."""
    assert list(single) == list(keys)
    assert set(keys) <= set(batched)
    for key in keys:
        if key == "action":
            assert isinstance(single[key], np.ndarray) and single[key].dtype == np.float64
            np.testing.assert_array_equal(batched[key][i], single[key])
        else:
            assert type(single[key]) is SCALAR_TYPES[key], (key, type(single[key]))
            if SCALAR_TYPES[key] is bool:
                assert bool(batched[key][i]) == single[key], key
            else:  # the batched arrays step through abaInParallel: rounding may differ
                assert batched[key][i] == pytest.approx(single[key], abs=1e-9), key


def assert_rules(task: TaskSpec, obs: dict, reward, terminated, info: dict) -> None:
    """The step's outcome recomputed from the task's numbers, without envs.task or envs.reward."""
    d = np.linalg.norm(np.asarray(obs["achieved_goal"]) - np.asarray(obs["desired_goal"]),
                       axis=-1)
    success = d <= task.success_radius
    a = np.asarray(info["action"])
    expected = (task.success_reward * success - task.distance_weight * d
                - task.action_weight * (a**2).sum(axis=-1))
    np.testing.assert_allclose(info["distance"], d, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(info["is_success"], success)
    np.testing.assert_array_equal(terminated, success & task.terminate_on_success)
    np.testing.assert_allclose(reward, expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("terminate_on_success", [True, False])
def test_single_and_batched_infos_match_key_by_key_and_follow_the_rules(terminate_on_success):
    task = TaskSpec(region="zheight", n_joints=3, max_episode_steps=STEPS,
                    terminate_on_success=terminate_on_success)
    singles = [UR5ReachEnv(task) for _ in range(COPIES)]
    vec = BatchedReach(COPIES, task, dynamics="pinocchio", autoreset_mode="disabled")
    # copy 0 aims at its own start (a success on the first step), the others at drawn goals
    start_tool = singles[0].reset(seed=0)[0]["achieved_goal"]
    vec_obs, vec_info = vec.reset(seed=10)
    goals = vec_obs["desired_goal"].copy()
    goals[0] = start_tool + 0.02
    vec_obs, vec_info = vec.reset(options={"goal": goals})
    for i, env in enumerate(singles):
        obs, info = env.reset(seed=10 + i, options={"goal": goals[i]})
        assert_same_info(info, vec_info, i, RESET_INFO_KEYS)
        np.testing.assert_array_equal(obs["desired_goal"], vec_obs["desired_goal"][i])
    rng = np.random.default_rng(1)
    hold = np.asarray(task.start_q[:3])
    successes, steps = 0, 0
    for _ in range(STEPS):
        steps += 1
        actions = rng.uniform(-4.0, 4.0, (COPIES, 3))  # beyond the box: clipping shows in info
        actions[0] = hold
        vec_obs, vec_reward, vec_term, _, vec_info = vec.step(actions)
        assert list(k for k in vec_info if not k.startswith("_")) == list(INFO_KEYS)
        assert_rules(task, vec_obs, vec_reward, vec_term, vec_info)
        for i, env in enumerate(singles):
            obs, reward, terminated, _, info = env.step(actions[i])
            assert_same_info(info, vec_info, i)
            assert_rules(task, obs, reward, terminated, info)
            assert terminated == vec_term[i]
            successes += info["is_success"]
        if vec_term.any():
            break
    assert successes >= 1  # the success branch was exercised
    assert (steps == 1) == terminate_on_success


def test_goal_env_functions_are_the_tasks():
    """compute_reward / compute_terminated of both envs equal TaskRules's on relabelled goals,
    and compute_terminated is success and terminate_on_success from the task's numbers."""
    for terminate_on_success in (True, False):
        task = TaskSpec(region="farbox", n_joints=3, terminate_on_success=terminate_on_success)
        rules = TaskRules(task)
        rng = np.random.default_rng(3)
        achieved = rng.normal(0.5, 0.1, (64, 3))
        desired = achieved + rng.normal(0.0, 0.08, (64, 3))
        info = {"action": rng.uniform(-1, 1, (64, 3))}
        success = np.linalg.norm(achieved - desired, axis=-1) <= task.success_radius
        assert 0 < success.sum() < 64
        for env in (UR5ReachEnv(task), BatchedReach(2, task, dynamics="pinocchio")):
            np.testing.assert_array_equal(env.compute_terminated(achieved, desired, info),
                                          success & terminate_on_success)
            np.testing.assert_array_equal(env.compute_reward(achieved, desired, info),
                                          rules.compute_reward(achieved, desired, info))


def test_sample_goals_draws_each_goal_from_its_own_generator():
    rules = TaskRules(TaskSpec(region="closebox", n_joints=3))
    together = rules.sample_goals([np.random.default_rng(s) for s in (4, 5, 6)])
    alone = np.concatenate([rules.sample_goals([np.random.default_rng(s)]) for s in (4, 5, 6)])
    assert together.shape == (3, 3)
    np.testing.assert_array_equal(together, alone)
    assert rules.spec.goal_region.contains(together).all()
    assert len({tuple(g) for g in together}) == 3


def test_info_puts_each_value_under_its_key_as_a_copy():
    """Distinct values per key (so a swapped key shows), copied (so the env's in-place arrays
    cannot change an info already returned), and one copy's row as Python scalars."""
    inputs = {"action": np.array([[0.5, -1.0, 2.0], [0.0, 0.1, 0.2]]),
              "distance": np.array([0.25, 0.05]), "success": np.array([False, True]),
              "contact": np.array([True, False]), "joint_limit": np.array([False, True]),
              "clearance": np.array([0.0, 0.3])}
    info = TaskRules.info(**inputs)
    assert list(info) == list(INFO_KEYS)
    renamed = {"is_success": "success"}
    for key in INFO_KEYS:
        np.testing.assert_array_equal(info[key], inputs[renamed.get(key, key)])
    for value in inputs.values():
        value[...] = 7  # the env overwrites its arrays on the next step
    assert info["distance"].tolist() == [0.25, 0.05] and info["contact"].tolist() == [True, False]
    row = TaskRules.copy_info(info, 1)
    assert row == {"action": row["action"], "distance": 0.05, "is_success": True,
                   "contact": False, "joint_limit": True, "clearance": 0.3}
    assert [type(row[k]) for k in SCALAR_TYPES] == list(SCALAR_TYPES.values())
    np.testing.assert_array_equal(row["action"], [0.0, 0.1, 0.2])
    row["action"][0] = 9.0
    assert info["action"][1, 0] == 0.0
