"""UR5Reach-v0 as a Gymnasium goal env: checker, GoalEnv invariant, seeding, episodes, vectors."""

from __future__ import annotations

import doctest
import warnings

import gymnasium
import numpy as np
import pytest
from arm_geometry import brute_force_heights
from gymnasium.utils.env_checker import check_env

import envs
import regions
import ur5kin
from envs import ENV_IDS, BatchedReach, FlatObservation, TaskSpec

PAPER_REGIONS = regions.names()


def make(env_id: str = "UR5Reach-v0", **kwargs):
    return gymnasium.make(env_id, **kwargs)


def rollout(env, steps: int, seed: int, action_seed: int = 0, angles: list | None = None,
            spread: float = 1.0):
    """Random actions from a seeded generator; every transition, restarting ended episodes.

    Actions are uniform in the action box scaled by ``spread`` about its centre (``spread`` > 1
    sends actions outside the box, which the env clips). ``angles`` collects all six joint
    angles after each step when given.
    """
    rng = np.random.default_rng(action_seed)
    space = env.action_space
    centre, half = (space.high + space.low) / 2, (space.high - space.low) / 2
    obs, _ = env.reset(seed=seed)
    out = []
    for _ in range(steps):
        action = rng.uniform(centre - spread * half, centre + spread * half)
        nxt, reward, terminated, truncated, info = env.step(action)
        out.append((obs, action, reward, terminated, truncated, info, nxt))
        if angles is not None:
            angles.append(env.unwrapped.joint_angles)
        obs = env.reset()[0] if terminated or truncated else nxt
    return out


@pytest.mark.parametrize("env_id", ENV_IDS)
@pytest.mark.parametrize("region", PAPER_REGIONS)
@pytest.mark.parametrize("n_joints", range(2, 7))
def test_gymnasium_env_checker_passes(env_id, region, n_joints):
    env = make(env_id, region=region, n_joints=n_joints)
    with warnings.catch_warnings():
        # the checker's advice about [-1, 1] action boxes and unbounded goal spaces: the paper's
        # action is an angle in rad and goals are positions in m, on purpose
        warnings.simplefilter("ignore", UserWarning)
        check_env(env.unwrapped, skip_render_check=True)


@pytest.mark.parametrize("mode", ["velocity", "torque"])
def test_env_checker_passes_in_the_other_control_modes_and_flat(mode):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        check_env(make(control_mode=mode, goal_sampler="cartesian").unwrapped)
        check_env(FlatObservation(make(region="farbox", control_mode=mode).unwrapped))


def test_render_rgb_array_draws_the_scene():
    env = make(region="farbox", render_mode="rgb_array")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        check_env(env.unwrapped)
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    assert len(np.unique(frame.reshape(-1, 3), axis=0)) > 4  # arm, goal, region, axes
    for _ in range(5):  # the arm swings towards a far pose: the drawing follows it
        env.step(np.array([1.5, -1.5, 0.5]))
    assert not np.array_equal(env.render(), frame)
    env.close()


@pytest.mark.parametrize("reward_type", ["dense", "sparse"])
def test_goal_env_reward_invariant(reward_type):
    """reward == compute_reward(achieved, desired, info), with half the actions sent outside the
    action box: the reward and info["action"] both use the action as applied (clipped)."""
    env = make(region="zheight", n_joints=3, reward_type=reward_type)
    transitions = rollout(env, 300, seed=1, spread=2.0)
    u = env.unwrapped
    space = u.action_space
    sent = np.stack([t[1] for t in transitions])
    outside = (sent < space.low) | (sent > space.high)
    assert 0.3 < outside.any(axis=1).mean() < 0.99  # clipping is exercised, and not always
    for (_, action, reward, _, _, info, nxt) in transitions:
        np.testing.assert_array_equal(info["action"], np.clip(action, space.low, space.high))
        assert reward == u.compute_reward(nxt["achieved_goal"], nxt["desired_goal"], info)
    rewards = np.array([t[2] for t in transitions])
    achieved = np.stack([t[6]["achieved_goal"] for t in transitions])
    desired = np.stack([t[6]["desired_goal"] for t in transitions])
    infos = [t[5] for t in transitions]
    # batched the ways HER libraries call it: a list of infos, an object array, a dict of arrays
    np.testing.assert_array_equal(u.compute_reward(achieved, desired, infos), rewards)
    np.testing.assert_array_equal(u.compute_reward(achieved, desired, np.array(infos)), rewards)
    actions = np.stack([i["action"] for i in infos])
    np.testing.assert_array_equal(u.compute_reward(achieved, desired, {"action": actions}),
                                  rewards)
    grid = u.compute_reward(achieved.reshape(30, 10, 3), desired.reshape(30, 10, 3),
                            np.array(infos).reshape(30, 10))
    np.testing.assert_array_equal(grid, rewards.reshape(30, 10))
    success = np.array([i["is_success"] for i in infos])
    np.testing.assert_array_equal(u.compute_terminated(achieved, desired, infos), success)
    if reward_type == "dense":  # eq. 2 written out, with the sent actions clipped here
        d = np.linalg.norm(achieved - desired, axis=-1)
        applied = np.clip(sent, -np.pi, np.pi)
        np.testing.assert_allclose(rewards, -d - (applied**2).sum(-1) + 100.0 * (d <= 0.1))
    else:
        np.testing.assert_array_equal(rewards, 100.0 * success)


@pytest.mark.parametrize("mode", ["position", "velocity", "torque"])
def test_action_penalty_in_actor_units_divides_by_the_command_bound(mode):
    """Eq. 2 in the actor's unit: |a / a_max|^2, a_max the mode's bound (pi rad in position
    mode, the URDF velocity or effort limits otherwise), against a second path: the command-unit
    reward with each joint's penalty weighted by 1 / a_max^2 by hand."""
    actor = make(region="zheight", n_joints=4, control_mode=mode,
                 action_penalty_unit="actor").unwrapped
    plain = make(region="zheight", n_joints=4, control_mode=mode).unwrapped
    bound = {"position": np.full(4, np.pi), "velocity": ur5kin.velocity_limits()[:4],
             "torque": ur5kin.effort_limits()[:4]}[mode]
    rng = np.random.default_rng(3)
    achieved, desired = rng.uniform(-1, 1, (50, 3)), rng.uniform(-1, 1, (50, 3))
    actions = rng.uniform(-1, 1, (50, 4)) * bound
    d = np.linalg.norm(achieved - desired, axis=-1)
    expected = -d - ((actions / bound) ** 2).sum(-1) + 100.0 * (d <= 0.1)
    got = actor.compute_reward(achieved, desired, {"action": actions})
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    literal = plain.compute_reward(achieved, desired, {"action": actions})
    assert np.all(got >= literal) and not np.allclose(got, literal)
    env = make(region="zheight", n_joints=3, action_penalty_unit="actor")
    for _, _, reward, _, _, info, nxt in rollout(env, 50, seed=2):  # the invariant holds too
        assert reward == env.unwrapped.compute_reward(nxt["achieved_goal"], nxt["desired_goal"],
                                                      info)


def test_dense_reward_needs_the_action_and_says_how_to_pass_it():
    u = make().unwrapped
    with pytest.raises(ValueError, match="copy_info_dict=True"):
        u.compute_reward(np.zeros((2, 3)), np.ones((2, 3)), [{}, {}])


def test_same_seed_same_goals_and_trajectories():
    a, b = make(region="closebox", n_joints=4), make(region="closebox", n_joints=4)
    ta, tb = rollout(a, 250, seed=11), rollout(b, 250, seed=11)
    for x, y in zip(ta, tb, strict=True):
        for key in ("observation", "achieved_goal", "desired_goal"):
            np.testing.assert_array_equal(x[6][key], y[6][key])
        assert x[2] == y[2] and x[3] == y[3] and x[4] == y[4]
    other = rollout(make(region="closebox", n_joints=4), 1, seed=12)
    assert not np.array_equal(other[0][0]["desired_goal"], ta[0][0]["desired_goal"])
    # reseeding the same env replays it
    again = rollout(a, 250, seed=11)
    np.testing.assert_array_equal(again[-1][6]["observation"], ta[-1][6]["observation"])


@pytest.mark.parametrize("region", PAPER_REGIONS)
def test_goals_lie_in_the_region_and_the_start_is_clear(region):
    env = make(region=region, n_joints=3)
    goals = np.array([env.reset(seed=s)[0]["desired_goal"] for s in range(30)])
    assert env.unwrapped.task.goal_region.contains(goals).all()
    task = env.unwrapped.task
    assert brute_force_heights(np.asarray(task.start_q), task.base_height)[0] >= 0.0


def test_observation_layout_and_frames():
    env = make(region="zheight", n_joints=3)
    obs, info = env.reset(seed=0)
    task = env.unwrapped.task
    np.testing.assert_array_equal(obs["observation"][:3], task.start_q[:3])
    np.testing.assert_array_equal(obs["observation"][3:], 0.0)
    # achieved goal = tool0 in the world frame: base_link + (0, 0, base_height)
    import ur5kin

    base = np.array([0.0, 0.0, task.base_height])
    np.testing.assert_allclose(obs["achieved_goal"], ur5kin.fk(task.start_q) + base, atol=1e-12)
    assert info["distance"] == pytest.approx(np.linalg.norm(obs["achieved_goal"]
                                                            - obs["desired_goal"]))
    nxt, _, _, _, step_info = env.step(np.array([0.3, -0.9, 1.4]))
    _, theta_dot, theta_ddot = np.split(nxt["observation"], 3)
    np.testing.assert_allclose(theta_ddot, theta_dot / env.unwrapped.dt)  # from rest
    assert env.unwrapped.dt == 0.02
    assert set(step_info) == {"action", "distance", "is_success", "contact", "joint_limit",
                              "clearance"}


def test_flat_observation_is_the_papers_state():
    env = FlatObservation(make(region="farbox", n_joints=3))
    flat, _ = env.reset(seed=3)
    inner = env.unwrapped
    goal, tool = inner._core.goal[0], inner._core.achieved[0]
    assert flat.shape == (3 * 3 + 6,) == env.observation_space.shape
    np.testing.assert_array_equal(flat[9:12], goal - tool)
    np.testing.assert_array_equal(flat[12:], goal)


def test_success_terminates_with_the_bonus_and_time_truncates():
    env = make(region="farbox", n_joints=3)
    task = env.unwrapped.task
    start_tool = env.reset(seed=0)[0]["achieved_goal"]
    env.reset(seed=0, options={"goal": start_tool + 0.02})
    hold = np.asarray(task.start_q[:3])
    _, reward, terminated, truncated, info = env.step(hold)
    assert terminated and not truncated and info["is_success"]
    assert reward == pytest.approx(100.0 - info["distance"] - float(hold @ hold))
    # a goal in reach but not where holding still goes: tool0 mirrored through the base axis
    # (a goal out of reach, as here before, is refused since issue 37)
    env.reset(seed=0, options={"goal": start_tool * np.array([-1.0, -1.0, 1.0])})
    for t in range(task.max_episode_steps):
        _, _, terminated, truncated, _ = env.step(hold)
        assert not terminated
        assert truncated == (t == task.max_episode_steps - 1)


@pytest.mark.parametrize("steps", [7, 130])
def test_the_tasks_episode_length_is_the_one_that_truncates(steps):
    """The reference is the task record: ``make`` and ``make_vec`` end episodes after the task's
    ``max_episode_steps``, longer or shorter than the default 100 (a registered outer limit of
    100 cut a 130-step task at 100 while its record said 130), and ``make_vec``'s
    ``max_episode_steps`` goes into the task it records."""
    def length(env):
        env.reset(seed=0)
        zero = np.zeros(env.action_space.shape)  # holds the start pose: never a success
        for t in range(1, 1000):
            _, _, terminated, truncated, _ = env.step(zero)
            if np.any(terminated) or np.any(truncated):
                return t
        return None

    task = TaskSpec(region="zheight", n_joints=2, max_episode_steps=steps)
    single = make(task=task)
    assert single.unwrapped.task.max_episode_steps == steps and length(single) == steps
    vec = gymnasium.make_vec("UR5Reach-v0", num_envs=2, vectorization_mode="vector_entry_point",
                             region="zheight", n_joints=2, max_episode_steps=steps)
    assert vec.unwrapped.task.max_episode_steps == steps and length(vec) == steps


@pytest.mark.parametrize("mode", ["make", "sync"])
def test_gymnasiums_max_episode_steps_is_the_length_the_task_records(mode):
    """The reference is Gymnasium's own TimeLimit: where ``make(..., max_episode_steps=7)``
    (and ``make_vec``'s sync copies, made by ``make``) cut the episode, the env underneath
    truncates too, and its record says 7 (it said 100: the env cannot see the outer limit; a
    Gymnasium that renames ``make``'s argument fails here)."""
    if mode == "make":
        env = gymnasium.make("UR5Reach-v0", region="zheight", n_joints=2, max_episode_steps=7)
    else:
        env = gymnasium.make_vec("UR5Reach-v0", num_envs=1, vectorization_mode="sync",
                                 region="zheight", n_joints=2, max_episode_steps=7).envs[0]
    inner = env.unwrapped
    assert inner.task.max_episode_steps == 7
    for wrapped in (env, inner):
        wrapped.reset(seed=0)
        ends = [wrapped.step(np.zeros(2))[3] for _ in range(7)]
        assert ends == [False] * 6 + [True]


def test_make_refuses_a_task_whose_length_gymnasiums_limit_contradicts():
    task = TaskSpec(region="zheight", n_joints=2, max_episode_steps=200)
    with pytest.raises(ValueError, match=r"max_episode_steps=50\) and the task's "
                                         r"max_episode_steps=200 disagree; give it once"):
        gymnasium.make("UR5Reach-v0", task=task, max_episode_steps=50)
    same = gymnasium.make("UR5Reach-v0", task=task.replace(max_episode_steps=50),
                          max_episode_steps=50)
    assert same.unwrapped.task.max_episode_steps == 50


def test_make_accepts_overrides_a_spec_and_region_objects():
    spec = TaskSpec(region="farbox", n_joints=4, reward_type="sparse")
    assert make(task=spec).unwrapped.task == spec
    assert make(task=spec, n_joints=2).unwrapped.task == spec.replace(n_joints=2)
    assert make(task=spec.to_dict()).unwrapped.task == spec
    box = regions.parse("box:0.3,0.7,-0.2,0.2,0,0.5")
    assert make(region=box).unwrapped.task.goal_region == box
    env = make(region="zheight", n_joints=3)
    assert env.unwrapped.task.region == "zheight"
    with pytest.raises(ValueError, match="n_joints"):
        make(n_joints=9)
    with pytest.raises(ValueError, match="unknown task field"):
        make(colour="red")
    with pytest.raises(ValueError, match=r"unreachable|no goals|almost no"):
        make(region="box:3,4,3,4,0,1")  # far outside the arm's reach
    with pytest.raises(ValueError, match="action must be 3 finite"):
        env.reset(seed=0)
        env.step(np.array([0.0, np.nan, 0.0]))


@pytest.mark.parametrize("make_env", [
    lambda **kw: gymnasium.make("UR5Reach-v0", **kw).unwrapped,
    lambda **kw: envs.BatchedReach(2, **kw)],
    ids=["UR5Reach-v0", "BatchedReach"])
def test_spec_is_the_deprecated_name_of_task_in_every_env(make_env):
    """``spec=`` (the keyword's old name, which clashed with Gymnasium's ``env.spec``) still
    gives the same task as ``task=``, with a DeprecationWarning; both at once is an error."""
    spec = TaskSpec(region="farbox", n_joints=4, max_episode_steps=50)
    with pytest.warns(DeprecationWarning, match="spec= is deprecated: it is task="):
        old = make_env(spec=spec, n_joints=3)
    assert old.task == make_env(task=spec, n_joints=3).task == spec.replace(n_joints=3)
    with pytest.raises(ValueError, match="give the task once"):
        make_env(task=spec, spec=spec)


@pytest.mark.parametrize("task", [TaskSpec(region="unconstrained", n_joints=6),
                                  TaskSpec(region="zheight", n_joints=3),
                                  TaskSpec(region="farbox", n_joints=2, control_mode="velocity"),
                                  TaskSpec(region="closebox", n_joints=5, control_mode="torque")])
def test_random_steps_keep_the_arm_above_the_plane(task):
    steps = 2500
    env = make(task=task)
    space = env.observation_space["observation"]
    angles: list[np.ndarray] = []
    transitions = rollout(env, steps, seed=5, angles=angles)
    q = np.array(angles)
    np.testing.assert_array_equal(q[:, : task.n_joints],
                                  [t[6]["observation"][: task.n_joints] for t in transitions])
    assert np.all(np.isfinite([t[6]["observation"] for t in transitions]))
    assert all(space.contains(t[6]["observation"]) for t in transitions)
    assert brute_force_heights(q, task.base_height).min() >= task.plane_margin - 1e-9
    assert any(t[5]["contact"] for t in transitions)  # the plane was actually tested


@pytest.mark.slow
def test_1e5_random_steps_keep_the_arm_above_the_plane():
    task = TaskSpec(region="unconstrained", n_joints=6)
    env = make(task=task)
    angles: list[np.ndarray] = []
    transitions = rollout(env, 100_000, seed=9, angles=angles)
    q = np.array(angles)
    assert np.all(np.isfinite([t[6]["observation"] for t in transitions]))
    assert brute_force_heights(q[::10], task.base_height).min() >= -1e-9
    assert ur5kin.link_heights(q, task.base_height)[:, 1:].min() >= -1e-12


def test_make_vec_builds_the_batched_env_and_copies_match_single_envs():
    vec = gymnasium.make_vec("UR5Reach-v0", num_envs=3, region="zheight", n_joints=3)
    assert isinstance(vec.unwrapped, BatchedReach)
    sync = gymnasium.make_vec("UR5Reach-v0", num_envs=2, vectorization_mode="sync")
    sync.reset(seed=0)
    sync.step(sync.action_space.sample())
    obs, _ = vec.reset(seed=20)
    singles = [make(region="zheight", n_joints=3) for _ in range(3)]
    single_obs = [env.reset(seed=20 + i)[0] for i, env in enumerate(singles)]
    for i in range(3):
        np.testing.assert_array_equal(obs["desired_goal"][i], single_obs[i]["desired_goal"])
    rng = np.random.default_rng(0)
    for _ in range(60):
        actions = rng.uniform(-np.pi, np.pi, (3, 3))
        obs, rewards, terminated, truncated, info = vec.step(actions)
        for i, env in enumerate(singles):
            o, r, te, tr, inf = env.step(actions[i])
            np.testing.assert_allclose(obs["observation"][i], o["observation"], atol=1e-7)
            assert rewards[i] == pytest.approx(r, abs=1e-6)
            assert (terminated[i], truncated[i], info["contact"][i]) == (te, tr, inf["contact"])
            if te or tr:
                break
        if terminated.any() or truncated.any():
            break
    u = vec.unwrapped
    np.testing.assert_array_equal(
        u.compute_reward(obs["achieved_goal"], obs["desired_goal"], info), rewards)


def test_batched_autoreset_modes():
    task = TaskSpec(region="farbox", n_joints=3, max_episode_steps=3)
    hold = np.tile(np.asarray(task.start_q[:3]), (2, 1))
    env = BatchedReach(2, task)  # next_step
    first, _ = env.reset(seed=0)
    for _ in range(3):
        _, _, _, truncated, _ = env.step(hold)
    assert truncated.all()
    obs, reward, terminated, truncated, _ = env.step(hold)  # resets instead of stepping
    assert not truncated.any() and not terminated.any() and np.all(reward == 0.0)
    assert not np.array_equal(obs["desired_goal"], first["desired_goal"])  # new episodes
    same = BatchedReach(2, task, autoreset_mode="same_step")
    same.reset(seed=0)
    for _ in range(3):
        obs, _, _, truncated, info = same.step(hold)
    assert truncated.all() and info["_final_obs"].all()
    assert not np.array_equal(obs["desired_goal"][0], info["final_obs"][0]["desired_goal"])
    off = BatchedReach(2, task, autoreset_mode="disabled")
    obs, _ = off.reset(seed=0)
    partial, _ = off.reset(options={"reset_mask": np.array([False, True])})
    np.testing.assert_array_equal(partial["desired_goal"][0], obs["desired_goal"][0])
    with pytest.raises(ValueError, match="autoreset_mode"):
        BatchedReach(2, task, autoreset_mode="sometimes")


def test_sb3_ddpg_with_her_runs_on_the_env_unmodified():
    """A smoke test: SB3's DDPG + HER trains on UR5Reach-v0 with both rewards (sparse, and dense
    with the infos copied for the action penalty). Too short to learn; see the next test."""
    from stable_baselines3 import DDPG, HerReplayBuffer

    for reward_type, buffer_kwargs in (("sparse", {}), ("dense", {"copy_info_dict": True})):
        env = make(region="farbox", n_joints=3, reward_type=reward_type, max_episode_steps=20)
        model = DDPG("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
                     replay_buffer_kwargs={"n_sampled_goal": 4, **buffer_kwargs},
                     learning_starts=50, batch_size=32, seed=0, device="cpu",
                     policy_kwargs={"net_arch": [32, 32]})
        model.learn(total_timesteps=150)
        action, _ = model.predict(env.reset(seed=0)[0], deterministic=True)
        assert env.action_space.contains(action.astype(np.float64))


def _toy_successes(model, goals: int = 50, seed: int = 1000) -> int:
    """Goals of the toy env hit by ``model``'s deterministic policy, all episodes side by side."""
    import toy_goal_env

    envs_ = [gymnasium.make(toy_goal_env.ENV_ID, n_joints=2) for _ in range(goals)]
    obs = [env.reset(seed=seed + i)[0] for i, env in enumerate(envs_)]
    done, success = np.zeros(goals, dtype=bool), np.zeros(goals, dtype=bool)
    while not done.all():
        actions, _ = model.predict({k: np.stack([o[k] for o in obs]) for k in obs[0]},
                                   deterministic=True)
        for i in np.flatnonzero(~done):
            obs[i], _, terminated, truncated, info = envs_[i].step(actions[i])
            success[i], done[i] = info["is_success"], terminated or truncated
    return int(success.sum())


def test_sb3_ddpg_with_her_learns_a_goal_env_with_the_same_reward_contract():
    """SB3's DDPG + HER, configured as for UR5Reach-v0's dense reward (the action read from the
    copied infos), learns the toy goal env of tests/toy_goal_env.py in 2,000 steps.

    Measured (seeds 0, 1, 2): 0, 0, 1 of 50 goals before training, 48, 50, 50 after. A learning
    check on UR5Reach-v0 itself does not fit in a minute: 2 joints, far box, sparse reward,
    2,000 steps scored 4 of 50 (7 before).
    """
    import toy_goal_env
    from stable_baselines3 import DDPG, HerReplayBuffer
    from stable_baselines3.common.noise import NormalActionNoise

    env = gymnasium.make(toy_goal_env.ENV_ID, n_joints=2)
    model = DDPG("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
                 replay_buffer_kwargs={"n_sampled_goal": 4, "goal_selection_strategy": "future",
                                       "copy_info_dict": True},
                 action_noise=NormalActionNoise(np.zeros(2), np.full(2, 0.3)),
                 learning_starts=200, batch_size=64, learning_rate=1e-3, gamma=0.95, tau=0.05,
                 policy_kwargs={"net_arch": [64, 64]}, seed=0, device="cpu")
    before = _toy_successes(model)
    model.learn(total_timesteps=2000)
    after = _toy_successes(model)
    assert before <= 5, before
    assert after >= 35, (before, after)


def test_package_doctests():
    from envs import spec

    for module in (envs, spec):
        result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
        assert result.failed == 0 and result.attempted > 0
