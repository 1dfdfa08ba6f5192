"""The capturable stacked update (``--update-graph``, issue 24) on the CPU: its minibatch stream
against a plain-Python reference of its formula and against uniformity, the update against
today's eager `DDPG.update` bit for bit, and ``torch.compile(fullgraph=True)`` as the proof that
the step holds no host synchronisation (a graph break is a failure)."""

import json

import numpy as np
import pytest
import torch
from toy_goal_env import ENV_ID

from ddpg_her.agent import DDPG
from ddpg_her.buffer import MASK32, CounterSampler, Layout, ReplayBuffer, counter_draws
from ddpg_her.config import AgentConfig
from ddpg_her.runfolder import RunFolder
from ddpg_her.trainer import Trainer
from ddpg_her.update_graph import UpdateStep, resolve

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


def test_the_capturable_step_is_todays_eager_update_bit_for_bit():
    """UpdateStep (tensor learning rates, device-drawn minibatches, in-place loss sums) against
    the default DDPG.update, fed the same minibatches, over 12 updates of 3 agents in float64;
    DDPG.update itself is checked against plain autograd in tests/test_ddpg_agent.py."""
    ours, buffer = stack()
    theirs, buffer2 = stack()
    step = UpdateStep(ours, buffer, [11, 12, 13], batch_size=16)
    assert step.graph is False and torch.is_tensor(ours._actor_step.lr)
    draws = CounterSampler([11, 12, 13], "cpu")
    agents = torch.arange(3)[:, None]
    for _ in range(4):
        losses = step.run(3)
        want = torch.zeros(2, 3, dtype=torch.float64)
        for _ in range(3):
            idx = draws.indices(buffer2.filled, 16)
            draws.counter.add_(1)
            critic_loss, actor_loss = theirs.update(*LAYOUT.split(buffer2.rows[agents, idx]))
            want += torch.stack([critic_loss, actor_loss])
        assert torch.equal(losses, want / 3)
        for a, b in zip(ours._lerp_online + ours._lerp_target,
                        theirs._lerp_online + theirs._lerp_target, strict=True):
            assert torch.equal(a, b)
    assert step.state() == 12 and int(step.sampler.counter) == 12
    for opt, other in ((ours.actor_opt, theirs.actor_opt), (ours.critic_opt, theirs.critic_opt)):
        for p, q in zip(opt.param_groups[0]["params"], other.param_groups[0]["params"],
                        strict=True):
            for key in ("exp_avg", "exp_avg_sq", "step"):
                assert torch.equal(opt.state[p][key], other.state[q][key])


def test_the_step_sees_new_rows_without_a_rebuild():
    """A graph bakes in addresses, not values: the stored-row counts are a device tensor that
    every put updates, so rows added between runs are drawn."""
    agent, buffer = stack(k=1)
    step = UpdateStep(agent, buffer, [5], batch_size=64)
    before = step.sampler.indices(buffer.filled, 64)
    assert int(before.max()) < 25
    buffer.add(0, np.full((10, LAYOUT.width), 0.5))
    after = step.sampler.indices(buffer.filled, 64)
    assert int(buffer.filled[0]) == 35 and int(after.max()) >= 25


def test_the_step_compiles_whole_so_it_holds_no_host_synchronisation():
    """torch.compile(fullgraph=True) raises at the first graph break: an .item(), a tensor in
    a Python branch, a generator argument, a tensor made from host data per step. Dynamo's
    tracing alone (backend "eager", about 5 s here) is what finds breaks; inductor cannot
    compile torch._fused_adam_ on the CPU (no fake kernel in this torch), and CUDA graphs
    capture it as it is."""
    agent, buffer = stack()
    step = UpdateStep(agent, buffer, [1, 2, 3], batch_size=16)
    step.run(1)  # Adam's state exists from the first update on, as in a capture's warm-up
    compiled = torch.compile(step.step, fullgraph=True, backend="eager")
    compiled()
    compiled()
    assert int(step.sampler.counter) == 3

    # the check itself: one host read in the same step is refused
    def with_sync():
        step.step()
        if step.loss_sum[0, 0] > 0:
            step.loss_sum.add_(0.0)
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


def test_modes_resolve_per_device_and_refuse_what_is_not_capturable():
    ddpg, td3 = AgentConfig(), AgentConfig(algo="td3")
    assert resolve("auto", "cuda", ddpg) and not resolve("auto", "cpu", ddpg)
    assert not resolve("auto", "cuda", td3) and not resolve("auto", "cuda",
                                                             AgentConfig(batch_norm=True))
    assert resolve("on", "cpu", ddpg) and not resolve("off", "cuda", ddpg)
    with pytest.raises(ValueError, match="--algo td3"):
        resolve("on", "cpu", td3)
    with pytest.raises(ValueError, match="--batch-norm"):
        resolve("on", "cpu", AgentConfig(batch_norm=True))
    ensemble = AgentConfig(ensemble=4)  # its members sample their own cells: not this step
    assert not resolve("auto", "cuda", ensemble)
    with pytest.raises(ValueError, match="--ensemble 4"):
        resolve("on", "cpu", ensemble)
    with pytest.raises(ValueError, match="must be one of"):
        resolve("yes", "cpu", ddpg)
    agent, buffer = stack(batch_norm=True)
    with pytest.raises(ValueError, match="autograd"):
        UpdateStep(agent, buffer, [1, 2, 3], 8)
    with pytest.raises(ValueError, match="CUDA device"):
        UpdateStep(*stack(), [1, 2, 3], 8, graph=True)


TASK = {"region": "box", "n_joints": 2}
TINY = AgentConfig(episodes=12, eval_every=3, eval_episodes=4, hidden_sizes=(16, 16),
                   updates_per_episode=4, buffer_size=70, batch_size=8, exploration_rate=0.3,
                   warmup_episodes=2)


def train(dirs, config=TINY, **kwargs):
    trainer = Trainer(ENV_ID, TASK, config, [0], [str(d) for d in dirs], progress=False,
                      tensorboard=False, **kwargs)
    try:
        return trainer.run()
    finally:
        trainer.close()


def test_a_trainer_with_the_graph_step_records_it_and_resumes_exactly(tmp_path):
    """spec.json says update_graph 'on'; 6 episodes then 6 more on resume end with the
    networks of 12 straight; the off path and another setting on resume are refused."""
    rows = train([tmp_path / "whole"], update_graph="on")
    assert len(rows[0]) == 4
    spec = json.loads((tmp_path / "whole" / "spec.json").read_text())
    assert spec["update_graph"] == "on"
    half = AgentConfig(**{**TINY.to_dict(), "episodes": 6})
    train([tmp_path / "cut"], config=half, update_graph="on")
    train([tmp_path / "cut"], resume=True, update_graph="on")
    a, b = (RunFolder(tmp_path / d).load_checkpoint(12) for d in ("whole", "cut"))
    assert a["rng"]["sample_counter"] == 4 * (12 - 2)
    for name in ("actor", "critic", "critic_target"):
        for key in a["agent"][name]:
            assert torch.equal(a["agent"][name][key], b["agent"][name][key])
    with pytest.raises(ValueError, match="update_graph"):
        train([tmp_path / "whole"], resume=True, update_graph="off")
    # the default trains another minibatch stream and records nothing
    train([tmp_path / "off"])
    assert "update_graph" not in json.loads((tmp_path / "off" / "spec.json").read_text())
    c = RunFolder(tmp_path / "off").load_checkpoint(12)
    assert "sample_counter" not in c["rng"]
    assert not torch.equal(a["agent"]["actor"]["l1.weight"], c["agent"]["actor"]["l1.weight"])


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_on_cuda_the_replayed_graph_equals_the_same_step_run_eagerly():
    """The graph (3 warm-up updates, a capture, replays) against UpdateStep's eager loop on
    the same device, float64, across new rows stored between runs (read through
    ReplayBuffer.filled by the captured kernels)."""
    def on_cuda():
        agent, buffer = stack()
        agent2 = DDPG(agent.config, IN, ACT, init_generators=[torch.Generator().manual_seed(i)
                                                              for i in range(3)],
                      dtype=torch.float64, device="cuda")
        buffer2 = ReplayBuffer(3, 40, LAYOUT, dtype=torch.float64, device="cuda")
        for k in range(3):
            first, rows = buffer.since(k, 0)
            buffer2.put(k, first, rows)
            agent2.normalizer.update(k, rows[:, :IN])
        return agent2, buffer2

    (a, abuf), (b, bbuf) = on_cuda(), on_cuda()
    graphed = UpdateStep(a, abuf, [1, 2, 3], 16, graph=True)
    eager = UpdateStep(b, bbuf, [1, 2, 3], 16, graph=False)
    new = np.random.default_rng(1).normal(size=(12, LAYOUT.width))
    for run in range(3):
        la, lb = graphed.run(10), eager.run(10)
        torch.testing.assert_close(la, lb, rtol=0, atol=1e-12)
        for p, q in zip(a._lerp_online + a._lerp_target, b._lerp_online + b._lerp_target,
                        strict=True):
            torch.testing.assert_close(p, q, rtol=0, atol=1e-12)
        for buf in (abuf, bbuf):
            buf.add(run % 3, new)
    assert graphed._cuda_graph is not None and int(graphed.sampler.counter) == 30
