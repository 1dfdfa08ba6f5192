"""The counter-based minibatch stream and the capturable DDPG update that the training program
(``ddpg_her.program``) builds its captured update body from, on the CPU: the stream against a
plain-Python reference of its formula and against uniformity, the capturable update against
the default eager `DDPG.update` bit for bit, and ``torch.compile(fullgraph=True)`` as the proof
that a draw and an update hold no host synchronisation (a graph break is a failure)."""

import numpy as np
import pytest
import torch

from ddpg_her.agent import DDPG
from ddpg_her.buffer import MASK32, CounterSampler, Layout, ReplayBuffer, counter_draws
from ddpg_her.config import AgentConfig

IN, ACT, HIDDEN = 7, 2, (32, 24)
LAYOUT = Layout(IN, ACT)


def py_mix32(x: int) -> int:
    """lowbias32 written from its published definition with Python's unbounded ints, an
    independent second path to the int64 tensor version (which must avoid overflow)."""
    x ^= x >> 16
    x = (x * 0x21F0AAAD) % 2**32
    x ^= x >> 15
    x = (x * 0x735A2D97) % 2**32
    return x ^ (x >> 15)


def py_index(key: int, counter: int, slot: int, filled: int) -> int:
    base = py_mix32(py_mix32(key) ^ counter)
    hi, lo = py_mix32(base ^ (2 * slot)), py_mix32(base ^ (2 * slot + 1))
    return ((hi >> 2) * 2**32 + lo) % filled


def test_counter_draws_equal_the_formula_in_python_integers():
    keys = [0, 1, 12345, MASK32, 2**31 + 7]
    filled = [1, 2, 1000, 999_983, 1_000_000]
    sampler = CounterSampler(keys, "cpu")
    for counter in (0, 1, 2_000_000):
        sampler.load_state(counter)
        got = sampler.indices(torch.tensor(filled), 16)
        want = [[py_index(k, counter, j, f) for j in range(16)] for k, f in zip(keys, filled,
                                                                                  strict=True)]
        assert got.tolist() == want
    # and the raw 62 bits at the largest key, counter and slot of their ranges
    top, slot = MASK32, 2**31 - 1
    base = py_mix32(py_mix32(top) ^ top)
    want = (py_mix32(base ^ (2 * slot)) >> 2) * 2**32 + py_mix32(base ^ (2 * slot + 1))
    assert int(counter_draws(torch.tensor(top), torch.tensor(top), torch.tensor(slot))) == want
    assert want < 2**62


def test_counter_draws_are_uniform_and_fresh_per_update_and_agent_alone():
    """5 sigma bounds: counts over 7 rows, and over pairs of consecutive updates (a draw must
    not predict the next update's); agent k draws the same in a stack of 3 as alone."""
    sampler = CounterSampler([7, 8, 9], "cpu")
    filled = torch.tensor([7, 7, 1000])
    draws = []
    for _ in range(400):
        draws.append(sampler.indices(filled, 50))
        sampler.counter.add_(1)
    draws = torch.stack(draws)                                   # (updates, K, batch)
    n = draws[:, 0].numel()
    counts = np.bincount(draws[:, 0].flatten().numpy(), minlength=7)
    sigma = np.sqrt(n / 7 * (1 - 1 / 7))
    assert np.all(np.abs(counts - n / 7) < 5 * sigma), counts
    pairs = (draws[:-1, 1] * 7 + draws[1:, 1]).flatten().numpy()  # slot j at updates c, c+1
    m = len(pairs)
    counts = np.bincount(pairs, minlength=49)
    sigma = np.sqrt(m / 49 * (1 - 1 / 49))
    assert np.all(np.abs(counts - m / 49) < 5 * sigma), counts
    assert not torch.equal(draws[0, 0], draws[1, 0])             # the counter moves the draw
    assert not torch.equal(draws[:, 0], draws[:, 1])             # so does the key
    alone = CounterSampler([9], "cpu")
    alone.load_state(0)
    for c in range(3):
        assert torch.equal(alone.indices(filled[2:], 50)[0], draws[c, 2])
        alone.counter.add_(1)


def test_sampler_keys_are_checked():
    with pytest.raises(ValueError, match="one key in"):
        CounterSampler([2**32], "cpu")
    with pytest.raises(ValueError, match="one key in"):
        CounterSampler([], "cpu")


def stack(k: int = 3, batch_norm: bool = False) -> tuple[DDPG, ReplayBuffer]:
    """K float64 agents and buffers of different fill (one wrapped around)."""
    config = AgentConfig(hidden_sizes=HIDDEN, batch_norm=batch_norm, critic_l2=1e-2)
    agent = DDPG(config, IN, ACT, init_generators=[torch.Generator().manual_seed(i)
                                                   for i in range(k)], dtype=torch.float64)
    buffer = ReplayBuffer(k, 40, LAYOUT, dtype=torch.float64, device="cpu")
    rng = np.random.default_rng(0)
    for i in range(k):
        rows = rng.normal(size=(25 + 10 * i, LAYOUT.width))
        rows[:, IN:IN + ACT] = np.tanh(rows[:, IN:IN + ACT])
        rows[:, -1] = rows[:, -1] > 1.0
        buffer.add(i, rows)
        agent.normalizer.update(i, rows[:, :IN])
    return agent, buffer


def step(agent: DDPG, buffer: ReplayBuffer, sampler: CounterSampler, loss_sum: torch.Tensor,
         batch_size: int = 16) -> None:
    """One update of every agent on a minibatch of the counter stream, its losses added to
    ``loss_sum`` (2, K) in place: the body the program captures, without a host value."""
    critic_loss, actor_loss = agent.update(*sampler.sample(buffer, batch_size))
    loss_sum[0] += critic_loss
    loss_sum[1] += actor_loss


def test_the_capturable_update_is_the_default_eager_update_bit_for_bit():
    """A capturable DDPG (tensor learning rates) fed the counter stream's minibatches against
    the default DDPG.update fed the same minibatches, over 12 updates of 3 agents in float64;
    DDPG.update itself is checked against plain autograd in tests/test_ddpg_agent.py."""
    ours, buffer = stack()
    theirs, buffer2 = stack()
    ours.capturable()
    assert all(torch.is_tensor(lr) for lr in ours.lr)
    assert not any(torch.is_tensor(lr) for lr in theirs.lr)
    sampler, draws = CounterSampler([11, 12, 13], "cpu"), CounterSampler([11, 12, 13], "cpu")
    agents = torch.arange(3)[:, None]
    for _ in range(4):
        losses = torch.zeros(2, 3, dtype=torch.float64)
        want = torch.zeros(2, 3, dtype=torch.float64)
        for _ in range(3):
            step(ours, buffer, sampler, losses)
            idx = draws.indices(buffer2.filled, 16)
            draws.counter.add_(1)
            critic_loss, actor_loss = theirs.update(*LAYOUT.split(buffer2.rows[agents, idx]))
            want += torch.stack([critic_loss, actor_loss])
        assert torch.equal(losses, want)
        assert torch.equal(ours.params, theirs.params)  # online and target networks
    assert int(sampler.counter) == 12
    for key in ("exp_avg", "exp_avg_sq", "steps"):
        assert torch.equal(getattr(ours, key), getattr(theirs, key))


def test_the_stream_sees_new_rows_without_a_rebuild():
    """A graph bakes in addresses, not values: the stored-row counts are a device tensor that
    every put updates, so rows added between replays are drawn."""
    _, buffer = stack(k=1)
    sampler = CounterSampler([5], "cpu")
    before = sampler.indices(buffer.filled, 64)
    assert int(before.max()) < 25
    buffer.add(0, np.full((10, LAYOUT.width), 0.5))
    after = sampler.indices(buffer.filled, 64)
    assert int(buffer.filled[0]) == 35 and int(after.max()) >= 25


def test_the_update_compiles_whole_so_it_holds_no_host_synchronisation():
    """torch.compile(fullgraph=True) raises at the first graph break: an .item(), a tensor in
    a Python branch, a generator argument, a tensor made from host data per step. Dynamo's
    tracing alone (backend "eager", about 5 s here) is what finds breaks; inductor cannot
    compile torch._fused_adam_ on the CPU (no fake kernel in this torch), and CUDA graphs
    capture it as it is."""
    agent, buffer = stack()
    agent.capturable()
    sampler, loss_sum = CounterSampler([1, 2, 3], "cpu"), torch.zeros(2, 3, dtype=torch.float64)
    step(agent, buffer, sampler, loss_sum)  # Adam's state exists from the first update on
    compiled = torch.compile(lambda: step(agent, buffer, sampler, loss_sum), fullgraph=True,
                             backend="eager")
    compiled()
    compiled()
    assert int(sampler.counter) == 3

    # the check itself: one host read in the same step is refused
    def with_sync():
        step(agent, buffer, sampler, loss_sum)
        if loss_sum[0, 0] > 0:
            loss_sum.add_(0.0)
    torch._dynamo.reset()
    with pytest.raises(torch._dynamo.exc.Unsupported):
        torch.compile(with_sync, fullgraph=True, backend="eager")()


def test_today_s_sampling_would_break_the_graph():
    """Why the counter stream: the default sampling (a host count and one torch generator per
    agent) cannot be traced whole."""
    _, buffer = stack()
    gens = [torch.Generator().manual_seed(i) for i in range(3)]
    torch._dynamo.reset()
    with pytest.raises(torch._dynamo.exc.Unsupported):
        torch.compile(lambda: buffer.sample(16, gens), fullgraph=True, backend="eager")()


def test_an_update_through_autograd_is_not_capturable():
    """Batch normalisation trains through autograd (Python branches): no tensor learning rate
    can make it a captured body, and `capturable` says so rather than capture a broken one."""
    agent, _ = stack(batch_norm=True)
    with pytest.raises(ValueError, match="autograd"):
        agent.capturable()
