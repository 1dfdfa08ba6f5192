"""The training program's random numbers drawn once per episode (issue 42: a batched call each
instead of one per step, chunk or update) are the numbers it drew one at a time, bit for bit:
each against `counter_draws` evaluated on Python ints, the stream's definition."""

from __future__ import annotations

import numpy as np
import torch

import envs.stackreach as stackreach
from ddpg_her.buffer import MASK32, CounterSampler, Layout, ReplayBuffer, counter_draws
from ddpg_her.program import CounterDraws
from tests.test_program import FirstOrderArm, make_program

KEYS = (7, 2**32 - 1, 123456789)


def uniform(key: int, counter: int, slot: int) -> float:
    """The stream's number at (key, counter, slot), on Python ints (53 bits in [0, 1))."""
    return (counter_draws(key, counter & MASK32, slot) >> 9) * 2.0**-53


def test_an_episodes_exploration_table_holds_each_steps_numbers():
    """Row t of the table drawn for counters c_t is what step t drew by itself before:
    slots 0 .. 11 of counter c_t (the counters span a wrap past 2**32)."""
    draws = CounterDraws(KEYS, torch.device("cpu"), steps=5)
    counters = torch.tensor([0, 1, 99, 2**32 - 1, 2**32 + 3])
    draws.episode(counters)
    want = [[[uniform(k, int(c), j) for j in range(CounterDraws.SLOTS)] for c in counters]
            for k in KEYS]
    assert torch.equal(draws.table, torch.tensor(want, dtype=torch.float64))
    draws.step = 3
    want = torch.tensor(want, dtype=torch.float64)
    assert torch.equal(draws.uniform(None, 6), 2.0 * want[:, 3, :6] - 1.0)


def test_the_episodes_minibatches_are_the_updates_one_by_one():
    """`CounterSampler.samples` (every update's indices and rows at once) against `sample`
    called once per update, and the indices against the stream on Python ints."""
    layout = Layout(3, 2)
    buffer = ReplayBuffer(3, 50, layout, dtype=torch.float32, device="cpu")
    rng = np.random.default_rng(0)
    for k, n in enumerate((50, 7, 31)):
        buffer.add(k, rng.normal(size=(n, layout.width)))
    batched, single = CounterSampler(KEYS, "cpu"), CounterSampler(KEYS, "cpu")
    batched.counter.fill_(2**32 - 2)
    single.counter.fill_(2**32 - 2)
    idx = batched.indices(buffer.filled, 4, 5)
    for u in range(5):
        want = [[counter_draws(k, (2**32 - 2 + u) & MASK32, j) % f for j in range(4)]
                for k, f in zip(KEYS, (50, 7, 31), strict=True)]
        assert idx[u].tolist() == want
    together = batched.samples(buffer, 4, 5)
    for u in range(5):
        for a, b in zip(together[u], single.sample(buffer, 4), strict=True):
            assert torch.equal(a, b)
    assert int(batched.counter) == int(single.counter) == 2**32 + 3


def test_the_goal_draw_in_one_pass_is_the_chunked_draw(tmp_path, monkeypatch):
    """Goals of all proposals tested at once equal goals tested 64 proposals at a time (the
    first accepted proposal wins either way), from the program's hoisted goal numbers, which
    equal the stream's on Python ints."""
    program = make_program(tmp_path, tasks=[dict(region="farbox", n_joints=3)], seeds=(0,))
    env = stackreach.StackReach(6, [dict(region="farbox", n_joints=3)],
                                dynamics=FirstOrderArm)
    keys, counter = torch.tensor([3, 4, 5, 6, 7, 8]), torch.tensor([0, 1, 2, 3, 2**32, 5])
    uniforms = program._goal_uniforms(keys, counter)
    assert uniforms(0, 3).shape == (6, 3, 6)
    assert uniforms(70, 1)[4, 0].tolist() == [uniform(7, 2**32, 6 * 70 + j) for j in range(6)]
    one_pass = env.draw_goals(uniforms)
    monkeypatch.setattr(stackreach, "PROPOSAL_BUDGET", 1)
    assert torch.equal(env.draw_goals(uniforms), one_pass)
    assert int(env.goal_misses) == 0


def test_an_acting_episode_draws_its_steps_numbers(tmp_path):
    """The program's third episode (its first acting one) holds, at step t, the numbers of
    counter 2 T + t: the per-step stream's."""
    program = make_program(tmp_path, seeds=(0, 1, 2))
    program.step()
    program.step()
    program.step()                              # an acting episode: the actors and the noise
    t = 7
    draws = program.draws
    keys = draws.keys[:, 0, 0].tolist()
    want = [[uniform(k, 2 * program.T + t, j) for j in range(CounterDraws.SLOTS)] for k in keys]
    assert torch.equal(draws.table[:, t], torch.tensor(want, dtype=torch.float64))
