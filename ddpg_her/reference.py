"""One DDPG agent written the way most code bases write it: ``nn.Linear`` layers, autograd, Adam.

It is the second code path for the stacked agent of `ddpg_her.agent`, which writes its gradients
by hand: ``tests/test_ddpg_agent.py`` checks K stacked agents against K of these to 1e-10 in
float64, and ``python -m benchmarks.agent_updates`` times it as the plain-PyTorch peer of our
update.
The update is the same algorithm: critic first, then the actor ascends the updated critic, then
the soft target update.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch
from torch import nn

from ddpg_her.config import AgentConfig


class ReferenceCritic(nn.Module):
    """Lillicrap's critic: Q(x, u) = l3 relu(l2 [relu(l1 x), u]), the action at layer 2.

    x : (B, in_dim) normalised input, u : (B, act_dim) in actor units -> (B, 1).
    """

    def __init__(self, in_dim: int, act_dim: int, hidden: Sequence[int]):
        super().__init__()
        h1, h2 = hidden
        self.l1 = nn.Linear(in_dim, h1)
        self.l2 = nn.Linear(h1 + act_dim, h2)
        self.l3 = nn.Linear(h2, 1)

    def forward(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        h = torch.relu(self.l1(x))
        return self.l3(torch.relu(self.l2(torch.cat([h, u], -1))))


def reference_actor(in_dim: int, act_dim: int, hidden: Sequence[int]) -> nn.Sequential:
    """Lillicrap's actor: x (B, in_dim) -> tanh output (B, act_dim) in actor units [-1, 1]."""
    h1, h2 = hidden
    return nn.Sequential(nn.Linear(in_dim, h1), nn.ReLU(), nn.Linear(h1, h2), nn.ReLU(),
                         nn.Linear(h2, act_dim), nn.Tanh())


class ReferenceDDPG:
    """One DDPG agent with fixed input statistics: ``norm(x) = clip((x - mean) / std, +-clip)``.

    mean, std : (in_dim,) tensors, default 0 and 1; ``fused`` picks torch's fused Adam kernel
    (what a tuned plain implementation uses) instead of its default per-tensor loop.
    Weights get torch's default ``nn.Linear`` initialisation; a caller that copies other weights
    in calls `reset_targets` afterwards.
    """

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, *,
                 mean: torch.Tensor | None = None, std: torch.Tensor | None = None,
                 dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu",
                 fused: bool = False):
        self.config = config
        net = {"dtype": dtype, "device": device}
        self.actor = reference_actor(in_dim, act_dim, config.hidden_sizes).to(**net)
        self.critic = ReferenceCritic(in_dim, act_dim, config.hidden_sizes).to(**net)
        self.reset_targets()
        adam = {"fused": True} if fused else {}
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr, **adam)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr,
                                           weight_decay=config.critic_l2, **adam)
        self.mean = torch.zeros(in_dim, **net) if mean is None else mean.to(**net)
        self.std = torch.ones(in_dim, **net) if std is None else std.to(**net)

    def reset_targets(self) -> None:
        """Targets := copies of the online networks."""
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)

    def norm(self, x: torch.Tensor) -> torch.Tensor:
        c = self.config.obs_clip
        return torch.clamp((x - self.mean) / self.std, -c, c)

    def update(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
               terminated: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One DDPG step on a minibatch x, x2 (B, in_dim) raw, u (B, act_dim), r and
        terminated (B, 1). Returns the critic and actor losses before the step (0-d tensors)."""
        cfg = self.config
        x, x2 = self.norm(x), self.norm(x2)
        with torch.no_grad():
            y = r + cfg.gamma * (1 - terminated) * self.critic_target(x2, self.actor_target(x2))
        critic_loss = ((self.critic(x, u) - y) ** 2).mean()
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()
        actor_loss = -self.critic(x, self.actor(x)).mean()
        self.actor_opt.zero_grad()
        actor_loss.backward()
        self.actor_opt.step()
        with torch.no_grad():
            for net, target in ((self.actor, self.actor_target),
                                (self.critic, self.critic_target)):
                for p, pt in zip(net.parameters(), target.parameters(), strict=True):
                    pt.mul_(1 - cfg.tau).add_(cfg.tau * p)
        return critic_loss.detach(), actor_loss.detach()
