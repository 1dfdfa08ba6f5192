"""Issue 23 on the env: ``reset(options=...)`` and ``compute_reward``'s arguments are checked
as ``step``'s action is: a ValueError naming the argument and what was expected, never another
exception type, numpy's bare message, or a string read as a sequence of keys."""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest

import envs


@pytest.fixture(scope="module")
def env():
    env = gymnasium.make("UR5Reach-v0", region="farbox", n_joints=3).unwrapped
    yield env
    env.close()


@pytest.mark.parametrize("options, message", [
    ({"goal": "abc"}, "options['goal'] must be 3 finite numbers"),
    ({"goal": [0.7 + 1j, 0.0, 0.1]}, "options['goal'] must be 3 finite numbers"),
    ({"goal": [0.7, None, 0.1]}, "options['goal'] must be 3 finite numbers"),
    ({"goal": [0.7, np.nan, 0.1]}, "options['goal'] must be 3 finite numbers"),
    ({"goal": [[0.7, 0.0, 0.1]]}, "options['goal'] must be 3 finite numbers"),
    (["goal"], "options must be a dict such as {'goal': (x, y, z)}; got ['goal']"),
    ("goal", "options must be a dict such as {'goal': (x, y, z)}; got 'goal'"),
    ({"gaol": [0.7, 0.0, 0.1]}, "unknown reset option(s) ['gaol']"),
])
def test_reset_options_are_checked_like_actions(env, options, message):
    with pytest.raises(ValueError) as err:
        env.reset(seed=0, options=options)
    assert message in str(err.value)


@pytest.mark.parametrize("options, message", [
    ("goal", "options must be a dict such as {'reset_mask'"),
    ([True, False], "options must be a dict such as {'reset_mask'"),
    ({"reset_mask": np.array([1, 0])}, "options['reset_mask'] must be a (2,) bool array; got int"),
    ({"reset_mask": "yes"}, "options['reset_mask'] must be a (2,) bool array"),
    ({"reset_mask": np.array([True])}, "options['reset_mask'] must be a (2,) bool array"),
    ({"goal": "abc"}, "options['goal'] must be (2, 3) finite goals"),
    ({"goal": [[1j, 0, 0], [0.7, 0, 0.1]]}, "options['goal'] must be (2, 3) finite goals"),
    ({"reset_mask": np.array([True, False]), "goal": [[0.7, 0, 0.1]] * 2},
     "options['goal'] must be (1, 3) finite goals"),
])
def test_vector_env_reset_options_are_checked_like_actions(options, message):
    vec = envs.BatchedReach(2, region="farbox", n_joints=3)
    with pytest.raises(ValueError) as err:
        vec.reset(seed=0, options=options)
    assert message in str(err.value)
    obs, _ = vec.reset(seed=0, options={"reset_mask": np.array([True, True]),
                                        "goal": [[0.7, 0.0, 0.1], [0.6, 0.1, 0.2]]})
    np.testing.assert_array_equal(obs["desired_goal"], [[0.7, 0.0, 0.1], [0.6, 0.1, 0.2]])


@pytest.mark.parametrize("info, message", [
    ({"action": "abc"}, "info['action'] must be real numbers"),
    ({"action": [0.0, np.inf, 0.0]}, "info['action'] must be finite"),
    ([{"action": [0.0, 0.0, 0.0]}, {"action": "x"}], "info['action'] must be real numbers"),
    ([{"action": [0.0, 0.0, 0.0]}, {"action": [0.0, 0.0]}], "must all have one shape"),
    ("action", "the dense reward needs the action"),
    ([{"act": [0.0, 0.0, 0.0]}], "the dense reward needs the action"),
])
def test_compute_reward_checks_the_actions_in_info(env, info, message):
    obs, _ = env.reset(seed=0)
    goals = np.stack([obs["achieved_goal"]] * 2), np.stack([obs["desired_goal"]] * 2)
    with pytest.raises(ValueError) as err:
        env.compute_reward(*goals, info)
    assert message in str(err.value)


def test_a_goal_given_to_reset_is_the_goal(env):
    obs, _ = env.reset(seed=0, options={"goal": (0.7, 0.1, 0.2)})
    np.testing.assert_array_equal(obs["desired_goal"], [0.7, 0.1, 0.2])


def test_task_copies_refuse_dynamics_of_another_size_or_task():
    from envs.core import TaskCopies
    from envs.physics import make_dynamics
    from envs.spec import TaskSpec

    task, other = TaskSpec(region="zheight", n_joints=3), TaskSpec(region="farbox", n_joints=3)
    TaskCopies(task, 2, make_dynamics(task, 2, "pinocchio"))  # the copies it was built for
    with pytest.raises(ValueError, match="of the 2 copies of this task; got 3 copies"):
        TaskCopies(task, 2, make_dynamics(task, 3, "pinocchio"))
    with pytest.raises(ValueError, match="got 2 copies of another task"):
        TaskCopies(task, 2, make_dynamics(other, 2, "pinocchio"))


@pytest.mark.parametrize("goal, message", [
    ((0.5, 0.1, -0.01), r"lies under the ground plane \(z < 0\)"),
    ((2.0, 0.0, 0.3), r"beyond the arm's reach of 0\.9\d\d m"),
])
def test_a_goal_no_episode_can_reach_is_refused_by_reset(goal, message):
    """Issue 37, kind 8: reset(options={'goal': ...}) took a goal under the plane or out of
    reach, and the episode's failure was the only sign."""
    import envs

    env = envs.UR5ReachEnv(region="farbox", n_joints=3)
    with pytest.raises(ValueError, match=message):
        env.reset(seed=0, options={"goal": goal})
    vec = envs.BatchedReach(2, region="farbox", n_joints=3)
    with pytest.raises(ValueError, match="goal 1 .*" + message):
        vec.reset(seed=0, options={"goal": [(0.5, 0.1, 0.2), goal]})
    env.reset(seed=0, options={"goal": (0.5, 0.1, 0.0)})  # on the plane, in reach: fine


@pytest.mark.parametrize("bad, named", [(np.nan, "got nan at [1, 2]"),
                                        (-np.inf, "got -inf at [1, 2]")])
def test_the_vector_env_names_a_non_finite_action_not_its_right_shape(bad, named):
    """Issue 37, kind 8 (found by benchmarks/reliability_probe.py): a NaN action of the right
    shape was refused with "got shape (2, 3)", the shape asked for, not the NaN."""
    vec = envs.BatchedReach(2, region="farbox", n_joints=3)
    vec.reset(seed=0)
    action = np.zeros((2, 3))
    action[1, 2] = bad
    with pytest.raises(ValueError, match=r"must be a finite \(2, 3\) array") as err:
        vec.step(action)
    assert named in str(err.value)
    with pytest.raises(ValueError, match=r"got shape \(3,\)"):
        vec.step(np.zeros(3))
