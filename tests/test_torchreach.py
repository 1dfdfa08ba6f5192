"""The torch env (envs.torchreach.TorchReach) against the numpy one (envs.batched.BatchedReach).

Two paths: the tensor reward against envs.task.compute_reward on random values, and whole
rollouts (autoresets, plane contacts, successes, goal-pool top-ups) step for step against
BatchedReach(dynamics="numba") with the same goals and actions. The goals are the task sampler's
own draws (same generator, same goals), a seed fixes everything, and ``step`` reads nothing back
from the device (checked on the CPU by forbidding the reads, and on CUDA by torch's sync debug
mode where a GPU is present).
"""

from __future__ import annotations

import gymnasium
import numpy as np
import pytest
from gymnasium.utils import seeding
from stepping import step_without_cuda_sync

from envs.batched import BatchedReach
from envs.spec import TaskSpec
from envs.task import INFO_KEYS, action_bounds, compute_reward, task_sampler

torch = pytest.importorskip("torch")
torchreach = pytest.importorskip("envs.torchreach")
TorchReach = torchreach.TorchReach

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="torch sees no CUDA device")

ROLLOUT_ATOL = 1e-9
"""Bound on every float of a float64 rollout against BatchedReach's (m, rad, rad/s, rad/s^2,
reward); measured 1e-13 (the accelerations, which divide a velocity difference by dt)."""

SPECS = {
    "paper": dict(max_episode_steps=7),
    # a wide success ball: terminations happen; the actor's penalty unit
    "wide": dict(max_episode_steps=9, success_radius=0.6, action_penalty_unit="actor"),
    # successes that do not end the episode
    "velocity-sparse": dict(max_episode_steps=6, control_mode="velocity", reward_type="sparse",
                            success_radius=0.6, terminate_on_success=False),
}
"""Tasks of the rollout test (short episodes, so that autoresets happen often)."""


def host(x) -> np.ndarray:
    return x.detach().cpu().numpy()


def random_actions(task: TaskSpec, steps: int, num: int, seed: int) -> np.ndarray:
    """Actions ``(steps, num, n)`` up to 1.3 times beyond the command box (the clip is tested)."""
    low, high = action_bounds(task)
    return np.random.default_rng(seed).uniform(1.3 * low, 1.3 * high, (steps, num, len(low)))


def assert_close(torch_value, numpy_value, what: str) -> None:
    np.testing.assert_allclose(host(torch_value).astype(np.float64),
                               np.asarray(numpy_value, dtype=np.float64), rtol=0,
                               atol=ROLLOUT_ATOL, err_msg=what)


# ---------------------------------------------------------------------------- the reward
@pytest.mark.parametrize("reward_type", ["dense", "sparse"])
@pytest.mark.parametrize("unit", ["command", "actor"])
@pytest.mark.parametrize("control_mode", ["position", "velocity"])
def test_compute_reward_is_the_numpy_one(reward_type, unit, control_mode):
    task = TaskSpec(reward_type=reward_type, action_penalty_unit=unit, control_mode=control_mode)
    env = TorchReach(1, task)
    rng = np.random.default_rng(0)
    achieved = rng.uniform(-1.0, 1.0, (5, 7, 3))
    # half the goals within the success radius, so that the bonus is tested
    desired = achieved + rng.normal(0.0, 0.1, (5, 7, 3))
    action = rng.uniform(-4.0, 4.0, (5, 7, task.n_joints))
    expected = compute_reward(achieved, desired, {"action": action}, task)
    got = env.compute_reward(torch.as_tensor(achieved), torch.as_tensor(desired),
                             {"action": torch.as_tensor(action)})
    assert got.shape == (5, 7) and got.dtype == torch.float64
    np.testing.assert_allclose(host(got), expected, rtol=1e-12, atol=1e-12)
    # a broadcast goal, as HER's "the episode's goal" relabelling passes it
    expected = compute_reward(achieved, desired[0, 0], {"action": action}, task)
    got = env.compute_reward(torch.as_tensor(achieved), torch.as_tensor(desired[0, 0]),
                             {"action": torch.as_tensor(action)})
    np.testing.assert_allclose(host(got), expected, rtol=1e-12, atol=1e-12)


def test_the_goal_env_invariant_holds_on_a_rollout():
    """reward == compute_reward(achieved, desired, info) for every step (no autoreset)."""
    env = TorchReach(4, SPECS["wide"], autoreset_mode="disabled")
    env.reset(seed=1)
    for a in random_actions(env.task, 8, 4, seed=2):
        obs, reward, *_, info = env.step(torch.as_tensor(a))
        recomputed = env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
        torch.testing.assert_close(reward, recomputed, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------- rollouts
def _compare_step(t_out, n_out, mode: str) -> None:
    (t_obs, t_rew, t_term, t_trunc, t_info), (n_obs, n_rew, n_term, n_trunc, n_info) = (t_out,
                                                                                      n_out)
    for key, value in n_obs.items():
        assert_close(t_obs[key], value, key)
    assert_close(t_rew, n_rew, "reward")
    np.testing.assert_array_equal(host(t_term), n_term)
    np.testing.assert_array_equal(host(t_trunc), n_trunc)
    for key in INFO_KEYS:
        assert_close(t_info[key], n_info[key], f"info[{key!r}]")
    if mode == "same_step" and "_final_obs" in n_info:
        done = n_info["_final_obs"]
        np.testing.assert_array_equal(host(t_info["_final_obs"]), done)
        for i in np.flatnonzero(done):
            for key, value in n_info["final_obs"][i].items():
                assert_close(t_info["final_obs"][key][i], value, f"final_obs[{key!r}]")
            for key, value in n_info["final_info"][i].items():
                assert_close(t_info["final_info"][key][i], value, f"final_info[{key!r}]")


@pytest.mark.parametrize("mode", ["next_step", "same_step", "disabled"])
@pytest.mark.parametrize("name", sorted(SPECS))
def test_a_rollout_equals_batched_reach_step_for_step(name, mode):
    """Same seed (per-copy goal generators, as BatchedReach's), same actions: same everything.
    A pool of 2 goals per copy makes the pool top up every other step."""
    num, steps = 4, 30
    kwargs = dict(autoreset_mode=mode, **SPECS[name])
    tenv = TorchReach(num, goal_source="per_copy", goal_pool=2, **kwargs)
    nenv = BatchedReach(num, dynamics="numba", **kwargs)
    t_obs, _ = tenv.reset(seed=5)
    n_obs, _ = nenv.reset(seed=5)
    for key, value in n_obs.items():
        assert_close(t_obs[key], value, key)
    seen = dict(contact=False, success=False, terminated=False, truncated=False)
    for a in random_actions(tenv.task, steps, num, seed=6):
        t_out, n_out = tenv.step(torch.as_tensor(a)), nenv.step(a)
        _compare_step(t_out, n_out, mode)
        seen["contact"] |= bool(n_out[4]["contact"].any())
        seen["success"] |= bool(n_out[4]["is_success"].any())
        seen["terminated"] |= bool(n_out[2].any())
        seen["truncated"] |= bool(n_out[3].any())
        if mode == "disabled":
            done = n_out[2] | n_out[3]
            t_obs, _ = tenv.reset(options={"reset_mask": torch.as_tensor(done)})
            n_obs, _ = nenv.reset(options={"reset_mask": done})
            for key, value in n_obs.items():
                assert_close(t_obs[key], value, key)
    assert seen["contact"] and seen["truncated"], seen  # what the rollout was meant to test
    if name != "paper":
        assert seen["success"], seen
        assert seen["terminated"] == TaskSpec(**SPECS[name]).terminate_on_success, seen


# ---------------------------------------------------------------------------- goals and seeds
def test_batched_goals_are_the_samplers_draws_from_the_seeded_generator():
    """The pool holds ``sampler.sample(m, rng)``'s goals in order, copy by copy, and a top-up
    continues the same generator: the goals are the numpy sampler's, not just alike."""
    num, depth, seed = 3, 2, 11
    env = TorchReach(num, autoreset_mode="disabled", goal_pool=depth)
    goals = [host(env.reset(seed=seed)[0]["desired_goal"])]
    for _ in range(2 * depth):
        goals.append(host(env.reset(options={"reset_mask": torch.ones(num, dtype=bool)})[0]
                          ["desired_goal"]))
    sampler, rng = task_sampler(env.task), seeding.np_random(seed)[0]
    fills = [sampler.sample(num * depth, rng).goals.reshape(num, depth, 3) for _ in range(3)]
    expected = np.concatenate(fills, axis=1)[:, : len(goals)].transpose(1, 0, 2)
    np.testing.assert_array_equal(np.array(goals), expected)


def test_same_seed_same_rollout_and_another_seed_other_goals():
    def rollout(seed: int) -> list[np.ndarray]:
        env = TorchReach(3, **SPECS["wide"])
        obs, _ = env.reset(seed=seed)
        out = [host(obs["desired_goal"])]
        for a in random_actions(env.task, 25, 3, seed=0):
            obs, reward, *_ = env.step(torch.as_tensor(a))
            out += [host(obs["observation"]), host(obs["desired_goal"]), host(reward)]
        return out

    first, again, other = rollout(7), rollout(7), rollout(8)
    for x, y in zip(first, again, strict=True):
        np.testing.assert_array_equal(x, y)
    assert not np.array_equal(first[0], other[0])


# ---------------------------------------------------------------------------- no sync in step
READS = ("__bool__", "item", "tolist", "numpy", "cpu", "__int__", "__float__")
"""Tensor methods that bring a value to the host (a synchronisation on CUDA)."""


def test_step_reads_nothing_back_from_the_device(monkeypatch):
    """On the CPU, with every value read from a tensor forbidden: steps (autoresets included)
    until the goal pool is due for its top-up, which is the one read allowed."""
    depth = 12
    env = TorchReach(4, SPECS["wide"], goal_pool=depth)
    env.reset(seed=0)
    actions = torch.as_tensor(random_actions(env.task, depth, 4, seed=1))

    def forbidden(*args, **kwargs):
        raise AssertionError("a device-to-host read inside step()")

    with monkeypatch.context() as patch:
        for name in READS:
            patch.setattr(torch.Tensor, name, forbidden)
        for a in actions[: depth - 1]:  # reset used one goal of each copy
            env.step(a)
    with pytest.raises(AssertionError, match="device-to-host"), monkeypatch.context() as patch:
        patch.setattr(torch.Tensor, "cpu", forbidden)
        env.step(actions[-1])  # the top-up reads the cursors: the guard above can see a read


def test_step_makes_no_tensor_from_host_data():
    """On the CPU, the other direction: inside ``step`` no tensor is made from host values
    (``aten.lift_fresh``: ``t[i] = 0.1``, ``torch.tensor(...)``). On a GPU each is a
    host-to-device copy, a sync, and an error inside a CUDA graph's capture (it was: the tool's
    base height, set into a device tensor, failed both CUDA tests on an H100)."""
    from torch.utils._python_dispatch import TorchDispatchMode

    class NoHostData(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if func is torch.ops.aten.lift_fresh.default:
                raise AssertionError("a tensor made from host data inside step()")
            return func(*args, **(kwargs or {}))

    depth = 8
    env = TorchReach(4, SPECS["wide"], goal_pool=depth)
    env.reset(seed=0)
    actions = torch.as_tensor(random_actions(env.task, depth - 1, 4, seed=1))
    with NoHostData():
        for a in actions:  # autoresets included (the wide ball ends episodes)
            env.step(a)
    with pytest.raises(AssertionError, match="host data"), NoHostData():
        torch.tensor([0.1])  # the guard sees what it forbids


@pytest.mark.gpu
@CUDA
def test_step_does_not_synchronise_on_cuda():
    depth = 16
    env = TorchReach(8, SPECS["wide"], device="cuda", goal_pool=depth)
    env.reset(seed=0)
    step_without_cuda_sync(env, torch.as_tensor(random_actions(env.task, depth - 1, 8, seed=1),
                                                device="cuda"))


@pytest.mark.gpu
@CUDA
def test_a_cuda_rollout_equals_the_cpu_one():
    envs = [TorchReach(4, SPECS["wide"], device=d, goal_pool=3) for d in ("cpu", "cuda")]
    outs = [env.reset(seed=2)[0] for env in envs]
    for key in outs[0]:
        assert_close(outs[1][key], host(outs[0][key]), key)
    for a in random_actions(envs[0].task, 20, 4, seed=3):
        cpu, cuda = (env.step(torch.as_tensor(a, device=env.device)) for env in envs)
        for key in cpu[0]:
            assert_close(cuda[0][key], host(cpu[0][key]), key)
        assert_close(cuda[1], host(cpu[1]), "reward")
        assert torch.equal(cuda[2].cpu(), cpu[2]) and torch.equal(cuda[3].cpu(), cpu[3])


# ---------------------------------------------------------------------------- bad inputs
def test_bad_inputs_get_clear_errors():
    with pytest.raises(ValueError, match="stop contact model"):
        TorchReach(2, contact_model="compliant")
    with pytest.raises(ValueError, match="goal_source"):
        TorchReach(2, goal_source="uniform")
    with pytest.raises(ValueError, match="goal_pool"):
        TorchReach(2, goal_pool=0)
    env = TorchReach(2)
    with pytest.raises(gymnasium.error.ResetNeeded):
        env.step(torch.zeros(2, 3))
    with pytest.raises(ValueError, match="first reset"):
        env.reset(options={"reset_mask": torch.ones(2, dtype=bool)})
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"\(2, 3\)"):
        env.step(torch.zeros(3, 3))
    with pytest.raises(ValueError, match="reset_mask"):
        env.reset(options={"reset_mask": torch.ones(3, dtype=bool)})
    with pytest.raises(ValueError, match="info\\['action'\\]"):
        env.compute_reward(torch.zeros(3), torch.zeros(3), {})
    with pytest.raises(ValueError, match="desired_goal"):
        env.compute_reward(torch.zeros(3), torch.zeros(2), {"action": torch.zeros(3)})
