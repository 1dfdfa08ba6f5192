"""The stacked DDPG update's cost (issue 42): its kernel launches per update, counted at torch's
dispatch level (`benchmarks.launches`), and its flat-buffer Adam and soft target update against
torch.optim.Adam and a per-tensor lerp, the second path they replace."""

import pytest
import torch

from benchmarks.launches import LaunchCounter
from ddpg_her import agent as agent_module
from ddpg_her.agent import DDPG, FastPaths
from ddpg_her.config import AgentConfig
from ddpg_her.program import PADDED

PLAIN = FastPaths(fused_adam=False, threshold_backward=False, foreach_lerp=False)
"""Public torch only: the path a torch without the private functions takes."""

UPDATE_LAUNCH_BUDGET = 58
"""Launches of one `DDPG.update` of a stack as the training program calls it (after
``capturable()``), this branch's count; issue 42 asks for <= 40 (the rest needs fused kernels:
bias + ReLU epilogues, the TD error and the normalisation, see the issue's note)."""


def paper_stack(k: int = 5, hidden: tuple[int, int] = (40, 30), n: int = 64):
    """A capturable stack at the program's padded dims and a minibatch as the program's
    sampler gives it (views of one row tensor): the count depends on neither k nor sizes."""
    agent = DDPG(AgentConfig(hidden_sizes=hidden), PADDED.in_dim, PADDED.act_dim,
                 init_generators=[torch.Generator().manual_seed(i) for i in range(k)])
    agent.capturable()
    rows = torch.randn(k, n, PADDED.width, generator=torch.Generator().manual_seed(0))
    rows[..., -1] = (rows[..., -1] > 1.0).float()
    return agent, PADDED.split(rows)


def test_one_update_of_a_stack_stays_within_its_launch_budget():
    agent, batch = paper_stack()
    agent.update(*batch)
    with LaunchCounter() as count:
        agent.update(*batch)
    assert count.syncs == 0, "the update reads the device"
    assert count.total <= UPDATE_LAUNCH_BUDGET, count.by_op.most_common()
    # one fused Adam pass per network, one lerp for every target
    assert count.by_op["_fused_adam_"] == 2 and count.by_op["_foreach_lerp_"] == 1


@pytest.mark.parametrize("path", ["fast", "plain"])
@pytest.mark.parametrize("critic_l2", [0.0, 1e-2])
def test_flat_adam_and_lerp_equal_torch_adam_and_per_tensor_lerp(path, critic_l2,
                                                                  monkeypatch):
    """Five steps of random gradients: the flat layout's Adam steps and soft update against
    torch.optim.Adam (its default, per-tensor loop) over clones of the parameters and a
    lerp_ of each target tensor, in float64; and the checkpoint's optimiser entries are
    torch.optim.Adam's own state_dict entries, agent by agent."""
    monkeypatch.setattr(agent_module, "FAST", PLAIN if path == "plain" else FastPaths())
    config = AgentConfig(hidden_sizes=(12, 10), critic_l2=critic_l2, tau=0.05)
    k = 3
    agent = DDPG(config, 7, 2, dtype=torch.float64,
                 init_generators=[torch.Generator().manual_seed(i) for i in range(k)])
    nets = {name: getattr(agent, name) for name in ("actor", "critic")}
    online = {name: [p.detach().clone() for p in net.parameters()] for name, net in nets.items()}
    target = {name: [p.clone() + 0.1 for p in online[name]] for name in nets}
    for name in nets:
        for mine, theirs in zip(getattr(agent, f"{name}_target").parameters(), target[name],
                                strict=True):
            mine.data.copy_(theirs)
    opts = {name: torch.optim.Adam(online[name], lr=lr, weight_decay=wd, foreach=False)
            for name, lr, wd in (("actor", config.actor_lr, 0.0),
                                 ("critic", config.critic_lr, critic_l2))}
    gen = torch.Generator().manual_seed(1)
    for _ in range(5):
        agent._count_steps()
        for j, name in enumerate(("critic", "actor")):  # the update's order
            for mine, theirs in zip(nets[name].parameters(), online[name], strict=True):
                theirs.grad = torch.randn(theirs.shape, generator=gen, dtype=torch.float64)
                agent._grads[mine].copy_(theirs.grad)
            agent._adam(1 - j)
            opts[name].step()
        agent._soft_update()
        for name in nets:
            for t, o in zip(target[name], online[name], strict=True):
                t.lerp_(o, config.tau)
    for name, net in nets.items():
        for mine, theirs in zip(net.parameters(), online[name], strict=True):
            torch.testing.assert_close(mine, theirs, atol=1e-13, rtol=0)
        for mine, theirs in zip(getattr(agent, f"{name}_target").parameters(), target[name],
                                strict=True):
            torch.testing.assert_close(mine, theirs, atol=1e-13, rtol=0)
        for i in range(k):
            ours = agent.agent_state(i)[f"{name}_opt"]
            theirs = opts[name].state_dict()["state"]
            assert list(ours) == list(theirs)
            for p, entry in theirs.items():
                assert list(ours[p]) == list(entry) == ["step", "exp_avg", "exp_avg_sq"]
                assert torch.equal(ours[p]["step"], entry["step"])
                for key in ("exp_avg", "exp_avg_sq"):
                    torch.testing.assert_close(ours[p][key], entry[key][i], atol=1e-13, rtol=0)


def test_a_fresh_stack_checkpoints_no_optimiser_state_as_torch_adam_does():
    agent, _ = paper_stack(k=2)
    assert agent.agent_state(0)["actor_opt"] == {} == agent.agent_state(1)["critic_opt"]
