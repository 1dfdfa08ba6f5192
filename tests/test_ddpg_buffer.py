"""ddpg_her's replay buffer and HER relabelling against hand-computed expectations."""

from dataclasses import dataclass

import numpy as np
import pytest
import torch
from toy_goal_env import ToyReach

from ddpg_her.buffer import (
    GoalFn,
    Layout,
    ReplayBuffer,
    TensorEpisodes,
    her_goal_steps,
    her_tensors,
    pack_tensors,
)
from ddpg_her.config import HERStrategy
from ddpg_her.spaces import ActionScale, goal_input

LAYOUT = Layout(in_dim=1, act_dim=1)  # rows of width 5


@dataclass
class Episode:
    """One agent's episode of L steps, everything in env units.

    observation : (L + 1, obs_dim), achieved_goal : (L + 1, goal_dim) (row t is the state before
    action t, row L the final state), desired_goal : (goal_dim,), action : (L, act_dim),
    reward : (L,), terminated : (L,) bool (True only on a last step that ended in success; a
    time-limit truncation is not termination, so it keeps bootstrapping).
    """

    observation: np.ndarray
    achieved_goal: np.ndarray
    desired_goal: np.ndarray
    action: np.ndarray
    reward: np.ndarray
    terminated: np.ndarray

    def __len__(self) -> int:
        return len(self.action)


def relabel(ep: Episode, goal_step: int, reward_fn: GoalFn, terminated_fn: GoalFn) -> Episode:
    """A copy of ``ep`` that pursues ``ep.achieved_goal[goal_step]``, cut where it terminates
    (`her_tensors` of the one episode; ``reward_fn`` and ``terminated_fn`` take arrays).

    The copy's transition t keeps (s_t, a_t, s_t+1) and gets the reward and the termination
    (``terminated_fn``, the env's ``compute_terminated``: a success, in the paper's task) of
    reaching s_t+1's achieved goal. The achieved goal at ``goal_step`` is hit exactly by
    transition ``goal_step - 1``, so with termination at success the copy ends there or
    earlier, terminated.
    """
    if not 1 <= goal_step <= len(ep):
        raise ValueError(f"goal_step must be in 1..{len(ep)}, got {goal_step}")
    one = TensorEpisodes(**{f: torch.as_tensor(np.asarray(getattr(ep, f)))[None] for f in (
        "observation", "achieved_goal", "desired_goal", "action", "reward", "terminated")},
        length=torch.tensor([len(ep)]), success=torch.zeros(1, dtype=torch.bool))

    def on_arrays(fn: GoalFn) -> GoalFn:
        return lambda *x: torch.as_tensor(np.asarray(fn(*(v.numpy() for v in x))))

    goal, reward, terminated, length = her_tensors(one, np.zeros(1, dtype=int),
                                                   np.array([goal_step]), on_arrays(reward_fn),
                                                   on_arrays(terminated_fn))
    n = int(length[0])
    return Episode(observation=ep.observation[:n + 1], achieved_goal=ep.achieved_goal[:n + 1],
                   desired_goal=goal[0].numpy(), action=ep.action[:n],
                   reward=reward[0, :n].numpy().astype(np.float64),
                   terminated=terminated[0, :n].numpy())


def pack(ep: Episode, scale: ActionScale) -> np.ndarray:
    """The episode's transitions as packed rows, ``(L, layout.width)`` float32 (`pack_tensors`
    of its arrays)."""
    arrays = (ep.observation, ep.achieved_goal, ep.desired_goal, ep.action, ep.reward,
              ep.terminated)
    return pack_tensors(*(torch.as_tensor(np.asarray(x)) for x in arrays), scale).numpy()


def numbered(first: int, n: int) -> np.ndarray:
    """Rows whose every column holds the row's transition number."""
    return np.repeat(np.arange(first, first + n, dtype=np.float32)[:, None], LAYOUT.width, 1)


def stored(buf: ReplayBuffer, k: int) -> list[int]:
    return buf.rows[k, : buf.size(k), 0].int().tolist()


def test_ring_buffer_wraps_around_oldest_first():
    buf = ReplayBuffer(2, 5, LAYOUT, dtype=torch.float32, device="cpu")
    buf.add(0, numbered(0, 3))
    assert stored(buf, 0) == [0, 1, 2] and buf.size(0) == 3
    buf.add(0, numbered(3, 5))  # transitions 5, 6, 7 overwrite 0, 1, 2
    assert stored(buf, 0) == [5, 6, 7, 3, 4]
    assert buf.total[0] == 8 and buf.size(0) == 5
    buf.add(0, numbered(8, 12))  # more than the capacity at once: the last 5 survive
    assert sorted(stored(buf, 0)) == [15, 16, 17, 18, 19]
    assert stored(buf, 0) == [15, 16, 17, 18, 19]  # 15 % 5 == 0
    assert buf.total[0] == 20
    assert buf.size(1) == 0 and buf.total[1] == 0  # agent 1 untouched


def test_since_returns_what_is_still_stored_in_order():
    buf = ReplayBuffer(1, 5, LAYOUT, dtype=torch.float32, device="cpu")
    buf.add(0, numbered(0, 8))
    first, rows = buf.since(0, 4)
    assert first == 4 and rows[:, 0].tolist() == [4, 5, 6, 7]
    first, rows = buf.since(0, 0)  # 0..2 are overwritten
    assert first == 3 and rows[:, 0].tolist() == [3, 4, 5, 6, 7]
    # put() restores a buffer from such chunks exactly
    other = ReplayBuffer(1, 5, LAYOUT, dtype=torch.float32, device="cpu")
    other.put(0, first, rows)
    assert torch.equal(other.rows, buf.rows) and other.total[0] == 8


def test_sampling_is_uniform_over_stored_rows_from_each_agents_generator():
    buf = ReplayBuffer(2, 5, LAYOUT, dtype=torch.float32, device="cpu")
    buf.add(0, numbered(0, 3))
    buf.add(1, numbered(100, 7))  # wrapped: holds 105, 106, 102, 103, 104
    gens = [torch.Generator().manual_seed(1), torch.Generator().manual_seed(2)]
    x, u, _, _, term = buf.sample(4, gens)
    assert x.shape == (2, 4, 1) and u.shape == (2, 4, 1) and term.shape == (2, 4, 1)
    # the indices are those of torch.randint over each agent's stored rows, agent by agent
    idx0 = torch.randint(3, (4,), generator=torch.Generator().manual_seed(1))
    idx1 = torch.randint(5, (4,), generator=torch.Generator().manual_seed(2))
    assert x[0, :, 0].tolist() == idx0.float().tolist()
    assert x[1, :, 0].tolist() == torch.tensor([105, 106, 102, 103, 104.0])[idx1].tolist()

    # uniform: 20,000 draws over 5 rows, each count within 5 sigma of 4,000
    x = buf.sample(20_000, gens)[0]
    counts = np.bincount(x[1, :, 0].int().numpy() - 100, minlength=7)
    assert counts[0] == counts[1] == 0
    sigma = np.sqrt(20_000 * 0.2 * 0.8)
    assert np.all(np.abs(counts[2:] - 4000) < 5 * sigma)


def test_layout_splits_packed_rows():
    layout = Layout(in_dim=3, act_dim=2)
    row = torch.arange(layout.width, dtype=torch.float32)
    x, u, r, x2, term = layout.split(row)
    assert x.tolist() == [0, 1, 2] and u.tolist() == [3, 4] and r.tolist() == [5]
    assert x2.tolist() == [6, 7, 8] and term.tolist() == [9]


# --- HER --------------------------------------------------------------------------------------
EPS = 0.1
COST = 0.5
BONUS = 100.0


def reward_fn(ag, g, a):
    """An independent copy of the UR5 env's dense reward: -d - cost |a|^2 + bonus 1{d <= eps}."""
    d = np.linalg.norm(ag - g, axis=-1)
    return -d - COST * np.sum(a**2, axis=-1) + BONUS * (d <= EPS)


def terminated_fn(ag, g, a):
    return np.linalg.norm(ag - g, axis=-1) <= EPS


def episode() -> Episode:
    """Four steps that end truncated: achieved goals on a line, the last two 0.05 apart."""
    return Episode(
        observation=np.arange(5.0)[:, None] * [1.0, 10.0],
        achieved_goal=np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.0], [1.45, 0.0], [1.5, 0.0]]),
        desired_goal=np.array([3.0, 3.0]),
        action=np.array([[1.0], [2.0], [0.0], [-1.0]]),
        reward=np.array([-1.0, -2.0, -3.0, -4.0]),
        terminated=np.zeros(4, dtype=bool),
    )


def test_final_relabelling_pursues_the_final_achieved_goal_and_stops_at_first_success():
    ep = episode()
    copy = relabel(ep, len(ep), reward_fn, terminated_fn)
    # goal (1.5, 0); transition 2 reaches (1.45, 0), 0.05 away: success, the copy ends there
    np.testing.assert_array_equal(copy.desired_goal, [1.5, 0.0])
    assert len(copy) == 3
    np.testing.assert_array_equal(copy.terminated, [False, False, True])
    np.testing.assert_allclose(copy.reward, [
        -1.0 - COST * 1.0,  # reaches (0.5, 0): 1.0 away, action 1
        -0.5 - COST * 4.0,  # reaches (1.0, 0): 0.5 away, action 2
        -0.05 - 0.0 + BONUS,  # reaches (1.45, 0): success, action 0
    ])
    np.testing.assert_array_equal(copy.observation, ep.observation[:4])
    np.testing.assert_array_equal(copy.achieved_goal, ep.achieved_goal[:4])
    np.testing.assert_array_equal(copy.action, ep.action[:3])
    # the original is left alone
    np.testing.assert_array_equal(ep.desired_goal, [3.0, 3.0])
    assert len(ep) == 4


def test_relabelling_towards_an_earlier_goal_cuts_there():
    ep = episode()
    copy = relabel(ep, 1, reward_fn, terminated_fn)  # goal (0.5, 0), reached by transition 0
    assert len(copy) == 1
    np.testing.assert_array_equal(copy.terminated, [True])
    np.testing.assert_allclose(copy.reward, [-0.0 - COST * 1.0 + BONUS])
    with pytest.raises(ValueError, match="goal_step"):
        relabel(ep, 0, reward_fn, terminated_fn)


def test_her_goal_steps():
    rng = np.random.default_rng(0)
    assert her_goal_steps(HERStrategy.FINAL, 7, 4, rng).tolist() == [7]
    assert her_goal_steps(HERStrategy.NONE, 7, 4, rng).size == 0
    future = her_goal_steps(HERStrategy.FUTURE, 7, 1000, rng)
    assert len(future) == 1000 and set(future.tolist()) == set(range(1, 8))


def test_pack_builds_inputs_actions_and_done_flags():
    ep = episode()
    ep.terminated[-1] = True
    scale = ActionScale(np.array([-2.0]), np.array([2.0]))
    rows = pack(ep, scale)
    layout = Layout(in_dim=2 + 2 * 2, act_dim=1)
    assert rows.shape == (4, layout.width) and rows.dtype == np.float32
    x, u, r, x2, term = (t.numpy() for t in layout.split(torch.from_numpy(rows)))
    # x = [observation, goal - achieved, goal]
    np.testing.assert_array_equal(x[1], [1.0, 10.0, 2.5, 3.0, 3.0, 3.0])
    np.testing.assert_array_equal(x2[1], x[2])
    np.testing.assert_array_equal(x2[3], [4.0, 40.0, 1.5, 3.0, 3.0, 3.0])
    np.testing.assert_array_equal(u[:, 0], [0.5, 1.0, 0.0, -0.5])  # action / 2
    np.testing.assert_array_equal(r[:, 0], ep.reward)
    np.testing.assert_array_equal(term[:, 0], [0, 0, 0, 1])


def test_goal_input_is_the_papers_state():
    x = goal_input(np.array([1.0, 2.0]), np.array([0.5, 0.5, 0.5]), np.array([1.0, 0.0, 2.0]))
    np.testing.assert_array_equal(x, [1.0, 2.0, 0.5, -0.5, 1.5, 1.0, 0.0, 2.0])


def test_action_scale_round_trip():
    scale = ActionScale(np.array([-np.pi, 0.0]), np.array([np.pi, 1.0]))
    np.testing.assert_allclose(scale.to_env(np.array([[-1, -1], [0, 0], [1, 1]])),
                               [[-np.pi, 0.0], [0.0, 0.5], [np.pi, 1.0]])
    a = np.array([0.3, 0.9])
    np.testing.assert_allclose(scale.to_env(scale.to_actor(a)), a)
    with pytest.raises(ValueError, match="action box"):
        ActionScale(np.array([0.0]), np.array([0.0]))


def test_toy_env_keeps_the_goal_env_invariant():
    """The test helper itself: reward == compute_reward(achieved, desired, info)."""
    env = ToyReach(n_joints=3)
    obs, _ = env.reset(seed=3)
    for a in np.random.default_rng(0).uniform(-2, 2, (10, 3)):
        obs, reward, terminated, _, info = env.step(a)
        assert reward == pytest.approx(
            env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info))
        assert terminated == env.compute_terminated(obs["achieved_goal"], obs["desired_goal"],
                                                    info)
