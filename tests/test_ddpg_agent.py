"""ddpg_her's stacked K-agent DDPG against K separate, plainly written DDPG agents."""

import importlib
import warnings

import numpy as np
import pytest
import torch
from torch import nn

from benchmarks.reference import ReferenceDDPG
from ddpg_her import agent as agent_module
from ddpg_her.agent import DDPG, FastPaths, probe_fast_paths
from ddpg_her.config import AgentConfig

PLAIN = FastPaths(fused_adam=False, threshold_backward=False, foreach_lerp=False)
"""Public torch only: the path a torch without the private functions takes."""

IN, ACT, HIDDEN = 7, 2, (32, 24)


def batch_norms(stacked: nn.Module, ref: nn.Module) -> list[tuple[nn.Module, nn.Module]]:
    """Our stacked batch normalisations beside nn.BatchNorm1d's, input first (none: [])."""
    theirs = [m for m in ref.modules() if isinstance(m, nn.BatchNorm1d)]
    norms = getattr(stacked, "norms", None)
    mine = [] if norms is None else list(norms)
    assert len(mine) == len(theirs)
    return list(zip(mine, theirs, strict=True))


def copy_slice(stacked: nn.Module, ref: nn.Module, k: int) -> None:
    """Our layer stores W as (K, in, out); nn.Linear as (out, in)."""
    ref_linears = [m for m in ref.modules() if isinstance(m, nn.Linear)]
    ours = [stacked.l1, stacked.l2, stacked.l3]
    with torch.no_grad():
        for mine, theirs in zip(ours, ref_linears, strict=True):
            theirs.weight.copy_(mine.weight[k].T)
            assert (mine.bias is None) == (theirs.bias is None)
            if mine.bias is not None:
                theirs.bias.copy_(mine.bias[k, 0])
        for mine, theirs in batch_norms(stacked, ref):
            for name in ("weight", "bias", "running_mean", "running_var"):
                if getattr(mine, name) is not None:
                    getattr(theirs, name).copy_(getattr(mine, name)[k, 0])


def assert_slice_equal(stacked: nn.Module, ref: nn.Module, k: int, tol: float) -> None:
    ref_linears = [m for m in ref.modules() if isinstance(m, nn.Linear)]
    for mine, theirs in zip([stacked.l1, stacked.l2, stacked.l3], ref_linears, strict=True):
        torch.testing.assert_close(mine.weight[k].T, theirs.weight, atol=tol, rtol=0)
        if mine.bias is not None:
            torch.testing.assert_close(mine.bias[k, 0], theirs.bias, atol=tol, rtol=0)
    for mine, theirs in batch_norms(stacked, ref):
        if mine.bias is None:  # the input's normalisation has no shift: nn's stays at 0
            assert not theirs.bias.any()
        for name in ("weight", "bias", "running_mean", "running_var"):
            if getattr(mine, name) is not None:
                torch.testing.assert_close(getattr(mine, name)[k, 0], getattr(theirs, name),
                                           atol=tol, rtol=0)


def reference_agent(config: AgentConfig, stacked: DDPG, k: int, data: np.ndarray):
    """Agent k of ``stacked`` as one plain autograd DDPG agent, with its normaliser's stats."""
    ref = ReferenceDDPG(config, IN, ACT, mean=torch.from_numpy(data.mean(0)),
                        std=torch.from_numpy(np.maximum(data.std(0), config.norm_eps)),
                        dtype=torch.float64)
    copy_slice(stacked.actor, ref.actor, k)
    copy_slice(stacked.critic, ref.critic, k)
    ref.reset_targets()
    return ref


def onlines(agent: DDPG) -> list[torch.Tensor]:
    return list(agent.actor.parameters()) + list(agent.critic.parameters())


def targets(agent: DDPG) -> list[torch.Tensor]:
    return list(agent.actor_target.parameters()) + list(agent.critic_target.parameters())


def make_agent(k: int, config: AgentConfig, seed0: int = 0) -> DDPG:
    gens = [torch.Generator().manual_seed(seed0 + i) for i in range(k)]
    return DDPG(config, IN, ACT, init_generators=gens, dtype=torch.float64)


@pytest.fixture
def interpreted(monkeypatch):
    """ddpg_her.program_kernels built under Triton's interpreter (the fused update's kernels
    are decorated when the module is imported)."""
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    import ddpg_her.program_kernels as kernels

    return importlib.reload(kernels)


@pytest.mark.parametrize(("critic_l2", "path", "batch_norm"), [
    (0.0, "fast", False), (1e-2, "fast", False), (1e-2, "plain", False),
    (0.0, "fast", True), (1e-2, "plain", True), (1e-2, "fused", False)])
def test_k_stacked_agents_equal_k_separate_agents_after_200_updates(critic_l2, path,
                                                                    batch_norm, request,
                                                                    monkeypatch):
    """Our hand-written gradients against autograd through nn.Linear, agent by agent, on the
    private-torch fast path, on the public-torch path a torch without it takes and on the
    fused path (Triton kernels, `DDPG._update_fused`, under the interpreter); with batch
    normalisation, our stacked autograd path against nn.BatchNorm1d (train mode online, eval
    mode for the targets and the actions taken), running statistics included."""
    config = AgentConfig(hidden_sizes=HIDDEN, tau=0.01, critic_l2=critic_l2,
                         batch_norm=batch_norm, batch_norm_momentum=0.1)
    k, n = 3, 64
    monkeypatch.setattr(agent_module, "FAST", PLAIN if path == "plain" else FastPaths())
    agent = make_agent(k, config)
    if path == "fused":
        request.getfixturevalue("interpreted")
        agent.fused = True
    assert agent.fast == (PLAIN if path == "plain" else FastPaths())
    rng = np.random.default_rng(0)
    # each agent's normaliser sees its own data, with a different scale per agent
    data = [rng.normal(size=(500, IN)) * (1 + i) + i for i in range(k)]
    for i in range(k):
        agent.normalizer.update(i, data[i][:200])
        agent.normalizer.update(i, data[i][200:])
    refs = [reference_agent(config, agent, i, data[i]) for i in range(k)]

    for _ in range(40 if path == "fused" else 200):   # the interpreter is slow
        batch = [torch.from_numpy(rng.normal(size=(k, n, d)) * 3) for d in (IN, ACT, 1, IN)]
        batch[1] = torch.tanh(batch[1])
        term = torch.from_numpy((rng.random((k, n, 1)) < 0.2).astype(float))
        critic_loss, actor_loss = agent.update(*batch, term)
        for i, ref in enumerate(refs):
            c, a = (v.item() for v in ref.update(*(b[i] for b in batch), term[i]))
            assert critic_loss[i].item() == pytest.approx(c, rel=1e-10, abs=1e-10)
            assert actor_loss[i].item() == pytest.approx(a, rel=1e-10, abs=1e-10)
    probe = torch.from_numpy(rng.normal(size=(k, 5, IN)) * 3)
    actions = agent.act(probe)
    for i, ref in enumerate(refs):
        assert_slice_equal(agent.actor, ref.actor, i, 1e-10)
        assert_slice_equal(agent.critic, ref.critic, i, 1e-10)
        assert_slice_equal(agent.actor_target, ref.actor_target, i, 1e-10)
        assert_slice_equal(agent.critic_target, ref.critic_target, i, 1e-10)
        torch.testing.assert_close(actions[i], ref.act(probe[i]), atol=1e-10, rtol=0)
    # and they did move: the agents are not trivially equal to their initial weights
    assert not torch.allclose(agent.actor.l1.weight, make_agent(k, config).actor.l1.weight)


@pytest.mark.parametrize(("dtype", "tol"), [(torch.float64, 1e-12), (torch.float32, 2e-5)])
def test_the_fused_update_is_the_hand_written_update(interpreted, dtype, tol):
    """`DDPG._update_fused` (the Triton kernels under the interpreter) against the torch path
    it replaces on CUDA, 20 updates of 3 agents with weight decay and a normaliser: weights,
    targets, Adam's moments and counts, the returned losses and their running sums."""
    config = AgentConfig(hidden_sizes=HIDDEN, tau=0.05, critic_l2=1e-2)
    agents = [DDPG(config, IN, ACT, dtype=dtype, init_generators=[
        torch.Generator().manual_seed(i) for i in range(3)]) for _ in range(2)]
    agents[1].fused = True
    rng = np.random.default_rng(1)
    data = rng.normal(size=(100, IN)) * 3 + 1
    sums = [torch.zeros(2, 3, dtype=torch.float64) for _ in agents]
    for agent in agents:
        agent.normalizer.update(0, data)
    for _ in range(20):
        rows = torch.from_numpy(rng.normal(size=(3, 32, 2 * IN + ACT + 2)) * 3).to(dtype)
        rows[..., -1] = rows[..., -1] > 1.0              # terminated: 1 in about 1 row in 6
        batch = (rows[..., :IN], torch.tanh(rows[..., IN:IN + ACT]),
                 rows[..., IN + ACT:IN + ACT + 1], rows[..., IN + ACT + 1:-1], rows[..., -1:])
        losses = [agent.update(*batch, loss_sum=s) for agent, s in zip(agents, sums, strict=True)]
        for mine, theirs in zip(*losses, strict=True):
            torch.testing.assert_close(theirs, mine, atol=tol, rtol=tol)
    torch.testing.assert_close(sums[1], sums[0], atol=tol * 20, rtol=tol)
    for name in ("params", "exp_avg", "exp_avg_sq", "steps"):
        torch.testing.assert_close(getattr(agents[1], name), getattr(agents[0], name),
                                   atol=tol, rtol=tol)
    assert agents[1].steps.tolist() == [20.0, 20.0]


def test_without_batch_norm_the_networks_and_update_are_the_hand_written_ones(monkeypatch):
    """batch_norm off (the default) changes nothing: the parameters of before and the
    hand-written update, never the autograd path (checked once bit for bit, weights, targets
    and Adam moments after 50 updates in float32 and float64, against the commit before
    batch normalisation existed)."""
    def autograd_path(*args):
        raise AssertionError("the autograd path ran without batch normalisation")

    monkeypatch.setattr(DDPG, "_update_autograd", autograd_path)
    agent = make_agent(2, AgentConfig(hidden_sizes=HIDDEN))
    layers = [f"l{i}.{p}" for i in (1, 2, 3) for p in ("weight", "bias")]
    for net in (agent.actor, agent.critic, agent.actor_target, agent.critic_target):
        assert net.norms is None and list(net.state_dict()) == layers
    batch = [torch.randn(2, 8, d, dtype=torch.float64) for d in (IN, ACT, 1, IN)]
    agent.update(*batch, torch.zeros(2, 8, 1, dtype=torch.float64))
    with_bn = make_agent(2, AgentConfig(hidden_sizes=HIDDEN, batch_norm=True))
    with pytest.raises(AssertionError, match="autograd path ran"):
        with_bn.update(*batch, torch.zeros(2, 8, 1, dtype=torch.float64))


def test_batch_norm_layers_where_lillicrap_had_them():
    """Input and every actor hidden layer; the critic's input and first layer (before the
    action); no bias where a normalisation follows; scale 1, shift 0, statistics 0 and 1."""
    agent = make_agent(1, AgentConfig(hidden_sizes=HIDDEN, batch_norm=True))
    widths = {"actor": [IN, *HIDDEN], "critic": [IN, HIDDEN[0]]}
    for name, net in (("actor", agent.actor), ("critic", agent.critic)):
        assert [n.weight.shape[-1] for n in net.norms] == widths[name]
        assert net.norms[0].bias is None and all(n.bias is not None for n in net.norms[1:])
        for n in net.norms:
            assert torch.equal(n.weight, torch.ones_like(n.weight))
            assert torch.equal(n.running_mean, torch.zeros_like(n.running_mean))
            assert torch.equal(n.running_var, torch.ones_like(n.running_var))
    assert agent.actor.l1.bias is None and agent.actor.l2.bias is None
    assert agent.critic.l1.bias is None and agent.critic.l2.bias is not None
    plain = make_agent(1, AgentConfig(hidden_sizes=HIDDEN))
    assert torch.equal(agent.actor.l1.weight, plain.actor.l1.weight)  # same draws


def test_update_does_only_the_matrix_products_ddpg_needs():
    """FLOPs of one update, counted by torch, against the count written out layer by layer.

    Autograd would also form the critic's weight gradients in the actor step and the gradient
    of the state half of the critic's second-layer input; the hand-written update skips both.
    """
    from torch.utils.flop_counter import FlopCounterMode

    i, a, (h1, h2), n, k = 13, 3, (400, 300), 64, 2
    agent = DDPG(AgentConfig(), i, a, init_generators=[torch.Generator() for _ in range(k)])
    batch = [torch.randn(k, n, d) for d in (i, a, 1, i)]
    with FlopCounterMode(display=False) as counter:
        agent.update(*batch, torch.zeros(k, n, 1))
    actor = i * h1 + h1 * h2 + h2 * a  # multiply-adds per row (+ 1: a loss, a (1, n) product)
    critic = i * h1 + (h1 + a) * h2 + h2
    target = actor + critic
    critic_step = critic + 1 + h2 + (h1 + a) * h2 + h2 * h1 + i * h1  # 1: the loss
    actor_step = (actor + critic + 1 + h2 * a + h2 * a + a * h2 + h1 * h2 + h2 * h1
                  + i * h1)
    assert counter.get_total_flops() == 2 * n * k * (target + critic_step + actor_step)


def test_soft_target_update_is_the_formula():
    config = AgentConfig(hidden_sizes=HIDDEN, tau=0.25)
    agent = make_agent(2, config)
    with torch.no_grad():  # targets apart from the online nets, so the lerp shows
        for p in list(agent.actor_target.parameters()) + list(agent.critic_target.parameters()):
            p.add_(1.0)
    before = [p.clone() for p in targets(agent)]
    batch = [torch.randn(2, 8, d, dtype=torch.float64) for d in (IN, ACT, 1, IN)]
    agent.update(*batch, torch.zeros(2, 8, 1, dtype=torch.float64))
    for old, online, new in zip(before, onlines(agent), targets(agent), strict=True):
        torch.testing.assert_close(new, 0.75 * old + 0.25 * online, atol=1e-12, rtol=0)


def test_lillicrap_initialisation():
    config = AgentConfig(hidden_sizes=(400, 300))
    agent = DDPG(config, 15, 3, init_generators=[torch.Generator().manual_seed(0)])
    for net in (agent.actor, agent.critic):
        for layer, fan_in in ((net.l1, 15), (net.l2, net.l2.weight.shape[1])):
            bound = 1 / np.sqrt(fan_in)
            assert layer.weight.abs().max() <= bound and layer.bias.abs().max() <= bound
            assert layer.weight.abs().max() > 0.9 * bound  # uniform over the whole range
        assert net.l3.weight.abs().max() <= 3e-3 and net.l3.bias.abs().max() <= 3e-3
    assert agent.critic.l2.weight.shape[1] == 400 + 3  # the action enters at layer 2
    # targets start equal to the online networks
    for p, pt in zip(onlines(agent), targets(agent), strict=True):
        assert torch.equal(p, pt)


def test_an_agents_initial_weights_depend_on_its_generator_alone():
    config = AgentConfig(hidden_sizes=HIDDEN)
    alone = make_agent(1, config, seed0=5)
    batch = make_agent(3, config, seed0=3)  # generators seeded 3, 4, 5
    for p_alone, p_batch in zip(onlines(alone), onlines(batch), strict=True):
        assert torch.equal(p_alone[0], p_batch[2])


@pytest.mark.parametrize("batch_norm", [False, True])
def test_agent_state_round_trip_continues_identically(batch_norm):
    config = AgentConfig(hidden_sizes=HIDDEN, batch_norm=batch_norm)
    a, b = make_agent(2, config), make_agent(2, config, seed0=9)
    batches = [[torch.randn(2, 8, d, dtype=torch.float64) for d in (IN, ACT, 1, IN)]
               for _ in range(6)]
    term = torch.zeros(2, 8, 1, dtype=torch.float64)
    a.normalizer.update(1, np.random.default_rng(0).normal(size=(10, IN)))
    for batch in batches[:3]:
        a.update(*batch, term)
    b.load_agent_states([a.agent_state(0), a.agent_state(1)])
    for batch in batches[3:]:
        a.update(*batch, term)
        b.update(*batch, term)
    for p, q in zip(onlines(a) + targets(a), onlines(b) + targets(b), strict=True):
        assert torch.equal(p, q)


def test_this_torch_passes_every_fast_path_probe():
    # the fast path is what we time; a torch that fails a probe runs, but slower
    assert FastPaths() == agent_module.FAST


def test_fallback_equals_fast_path_to_1e_10(monkeypatch):
    config = AgentConfig(hidden_sizes=HIDDEN, tau=0.05)
    monkeypatch.setattr(agent_module, "FAST", FastPaths())  # every private function
    fast = make_agent(2, config)
    monkeypatch.setattr(agent_module, "FAST", PLAIN)
    plain = make_agent(2, config)
    assert plain.fast == PLAIN
    gen = torch.Generator().manual_seed(3)
    for _ in range(50):
        batch = [torch.randn(2, 16, d, generator=gen, dtype=torch.float64) * 2
                 for d in (IN, ACT, 1, IN)]
        term = (torch.rand(2, 16, 1, generator=gen) < 0.3).double()
        for a, b in zip(fast.update(*batch, term), plain.update(*batch, term), strict=True):
            torch.testing.assert_close(a, b, atol=1e-10, rtol=0)
    for name in ("actor", "critic", "actor_target", "critic_target"):
        for p, q in zip(getattr(fast, name).parameters(), getattr(plain, name).parameters(),
                        strict=True):
            torch.testing.assert_close(p, q, atol=1e-10, rtol=0)


@pytest.mark.parametrize(("missing", "field"), [
    ("_fused_adam_", "fused_adam"), ("_foreach_lerp_", "foreach_lerp")])
def test_a_missing_private_function_warns_and_turns_its_fast_path_off(monkeypatch, missing,
                                                                      field):
    monkeypatch.delattr(torch, missing)
    with pytest.warns(RuntimeWarning, match=f"torch.{missing}"):
        paths = probe_fast_paths()
    assert paths == FastPaths(**{field: False})


def test_a_private_function_that_changed_meaning_is_not_used(monkeypatch):
    class Ops:  # threshold_backward that no longer zeroes the gradient
        class aten:
            @staticmethod
            def threshold_backward(grad, out, threshold):
                return grad.clone()

    monkeypatch.setattr(torch, "ops", Ops)
    with pytest.warns(RuntimeWarning, match="threshold_backward"):
        assert probe_fast_paths() == FastPaths(threshold_backward=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        monkeypatch.undo()
        assert probe_fast_paths() == FastPaths()
