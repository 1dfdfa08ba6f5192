"""One DDPG agent written the way most code bases write it: ``nn.Linear`` layers, autograd, Adam.

Not installed with the packages (a test oracle and a benchmark's peer, not a user's agent).
It is the second code path for the stacked agent of `ddpg_her.agent`, which writes its gradients
by hand: ``tests/test_ddpg_agent.py`` checks K stacked agents against K of these to 1e-10 in
float64, and ``python -m benchmarks.agent_updates`` times it as the plain-PyTorch peer of our
update.
The update is the same algorithm: critic first, then the actor ascends the updated critic, then
the soft target update.
"""

from __future__ import annotations

import copy
import math

import torch
from torch import nn

from ddpg_her.config import AgentConfig
from ddpg_her.networks import BATCH_NORM_EPS


def _norm(dim: int, config: AgentConfig, shift: bool = True) -> nn.Module:
    """torch's own batch normalisation when the config asks for it, else the identity; without
    ``shift`` its shift is held at 0 (the input's: the next normalisation cancels it)."""
    if not config.batch_norm:
        return nn.Identity()
    bn = nn.BatchNorm1d(dim, eps=BATCH_NORM_EPS, momentum=config.batch_norm_momentum)
    if not shift:
        bn.bias.requires_grad_(False)
    return bn


class ReferenceCritic(nn.Module):
    """Lillicrap's critic: Q(x, u) = l3 relu(l2 [relu(bn1(l1 bn0(x))), u]), the action at
    layer 2; bn0, bn1 are ``nn.BatchNorm1d`` with ``config.batch_norm`` (l1 then without
    bias), else the identity.

    x : (B, in_dim) normalised input, u : (B, act_dim) in actor units -> (B, 1).
    """

    def __init__(self, in_dim: int, act_dim: int, config: AgentConfig):
        super().__init__()
        h1, h2 = config.hidden_sizes
        self.bn0, self.bn1 = _norm(in_dim, config, shift=False), _norm(h1, config)
        self.l1 = nn.Linear(in_dim, h1, bias=not config.batch_norm)
        self.l2 = nn.Linear(h1 + act_dim, h2)
        self.l3 = nn.Linear(h2, 1)

    def forward(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        h = torch.relu(self.bn1(self.l1(self.bn0(x))))
        return self.l3(torch.relu(self.l2(torch.cat([h, u], -1))))


def reference_actor(in_dim: int, act_dim: int, config: AgentConfig) -> nn.Sequential:
    """Lillicrap's actor: x (B, in_dim) -> tanh output (B, act_dim) in actor units [-1, 1];
    with ``config.batch_norm``, ``nn.BatchNorm1d`` on the input and before each ReLU, and no
    bias in the layers it follows."""
    h1, h2 = config.hidden_sizes
    bias = not config.batch_norm  # a layer that batch normalisation follows has none
    return nn.Sequential(_norm(in_dim, config, shift=False), nn.Linear(in_dim, h1, bias=bias),
                         _norm(h1, config), nn.ReLU(), nn.Linear(h1, h2, bias=bias),
                         _norm(h2, config), nn.ReLU(), nn.Linear(h2, act_dim), nn.Tanh())


def _float_buffers(net: nn.Module) -> list[torch.Tensor]:
    """Running means and variances (not BatchNorm1d's integer batch counter)."""
    return [b for b in net.buffers() if b.is_floating_point()]


@torch.no_grad()
def _soft_update(pairs: tuple[tuple[nn.Module, nn.Module], ...], tau: float) -> None:
    """target <- (1 - tau) target + tau online, for each (online, target) pair of networks:
    their parameters and running statistics."""
    for net, target in pairs:
        for p, pt in zip(list(net.parameters()) + _float_buffers(net),
                         list(target.parameters()) + _float_buffers(target), strict=True):
            pt.mul_(1 - tau).add_(tau * p)


class ReferenceDDPG:
    """One DDPG agent with fixed input statistics: ``norm(x) = clip((x - mean) / std, +-clip)``.

    mean, std : (in_dim,) tensors, default 0 and 1; ``fused`` picks torch's fused Adam kernel
    (what a tuned plain implementation uses) instead of its default per-tensor loop.
    Weights get torch's default ``nn.Linear`` initialisation (batch normalisation: scale 1,
    shift 0, running mean 0 and variance 1, as ours); a caller that copies other weights
    in calls `reset_targets` afterwards.
    """

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, *,
                 mean: torch.Tensor | None = None, std: torch.Tensor | None = None,
                 dtype: torch.dtype = torch.float32, device: str | torch.device = "cpu",
                 fused: bool = False):
        self.config = config
        net = {"dtype": dtype, "device": device}
        self.actor = reference_actor(in_dim, act_dim, config).to(**net)
        self.critic = ReferenceCritic(in_dim, act_dim, config).to(**net)
        self.reset_targets()
        adam = {"fused": True} if fused else {}
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr, **adam)
        self.critic_opt = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr,
                                           weight_decay=config.critic_l2, **adam)
        self.mean = torch.zeros(in_dim, **net) if mean is None else mean.to(**net)
        self.std = torch.ones(in_dim, **net) if std is None else std.to(**net)

    def reset_targets(self) -> None:
        """Targets := copies of the online networks, in eval mode (running statistics)."""
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False).eval()
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False).eval()

    @torch.no_grad()
    def act(self, x: torch.Tensor) -> torch.Tensor:
        """The deterministic action of raw inputs x (B, in_dim), the actor in eval mode."""
        self.actor.eval()
        try:
            return self.actor(self.norm(x))
        finally:
            self.actor.train()

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
        # the critic normalises this batch by its own statistics but, its step done, keeps
        # the running statistics it had (restored after the backward, which saves them)
        kept = [b.clone() for b in _float_buffers(self.critic)]
        actor_loss = -self.critic(x, self.actor(x)).mean()
        self.actor_opt.zero_grad()
        actor_loss.backward()
        self.actor_opt.step()
        with torch.no_grad():
            for b, old in zip(_float_buffers(self.critic), kept, strict=True):
                b.copy_(old)
        _soft_update(((self.actor, self.actor_target), (self.critic, self.critic_target)),
                     cfg.tau)
        return critic_loss.detach(), actor_loss.detach()


class ReferenceTD3(ReferenceDDPG):
    """One TD3 agent (Fujimoto et al. 2018) written plainly: twin ``ReferenceCritic``, a target
    per network, one Adam over both critics. Arguments as `ReferenceDDPG`'s."""

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, **kwargs):
        super().__init__(config, in_dim, act_dim, **kwargs)
        net = {"dtype": self.std.dtype, "device": self.std.device}
        self.critic2 = ReferenceCritic(in_dim, act_dim, config).to(**net)
        params = list(self.critic.parameters()) + list(self.critic2.parameters())
        self.critic_opt = torch.optim.Adam(params, lr=config.critic_lr,
                                           weight_decay=config.critic_l2)
        self.updates = 0
        self.reset_targets()

    def reset_targets(self) -> None:
        super().reset_targets()
        if hasattr(self, "critic2"):
            self.critic2_target = copy.deepcopy(self.critic2).requires_grad_(False).eval()

    def update(self, x, u, r, x2, terminated, noise):
        """One TD3 step; ``noise`` (B, act_dim) the clipped smoothing noise. Returns the critic
        loss (both critics' summed) and the actor loss (None on a step without the actor)."""
        cfg = self.config
        x, x2 = self.norm(x), self.norm(x2)
        with torch.no_grad():
            a2 = torch.clamp(self.actor_target(x2) + noise, -1.0, 1.0)
            q2 = torch.min(self.critic_target(x2, a2), self.critic2_target(x2, a2))
            y = r + cfg.gamma * (1 - terminated) * q2
        critic_loss = (nn.functional.mse_loss(self.critic(x, u), y)
                       + nn.functional.mse_loss(self.critic2(x, u), y))
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()
        self.updates += 1
        actor_loss = None
        if self.updates % cfg.td3_policy_delay == 0:
            actor_loss = -self.critic(x, self.actor(x)).mean()
            self.actor_opt.zero_grad()
            actor_loss.backward()
            self.actor_opt.step()
            actor_loss = actor_loss.detach()
            _soft_update(((self.actor, self.actor_target), (self.critic, self.critic_target),
                          (self.critic2, self.critic2_target)), cfg.tau)
        return critic_loss.detach(), actor_loss


class ReferenceSAC:
    """One SAC agent (Haarnoja et al. 2018, automatic entropy tuning) written plainly: an
    ``nn.Linear`` policy whose log-probabilities come from torch.distributions (a Normal through
    a ``TanhTransform``), twin ``ReferenceCritic`` with targets, a scalar log alpha. Fixed input
    statistics as `ReferenceDDPG`; weights are torch's defaults until a caller copies others in
    and calls `reset_targets`."""

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, *,
                 mean: torch.Tensor | None = None, std: torch.Tensor | None = None,
                 dtype: torch.dtype = torch.float64, device: str | torch.device = "cpu"):
        from ddpg_her.sac import LOG_STD_MAX, LOG_STD_MIN

        self.config, self.act_dim = config, act_dim
        self.log_std_range = (LOG_STD_MIN, LOG_STD_MAX)
        net = {"dtype": dtype, "device": device}
        h1, h2 = config.hidden_sizes
        self.actor = nn.Sequential(nn.Linear(in_dim, h1), nn.ReLU(), nn.Linear(h1, h2),
                                   nn.ReLU(), nn.Linear(h2, 2 * act_dim)).to(**net)
        self.critic = ReferenceCritic(in_dim, act_dim, config).to(**net)
        self.critic2 = ReferenceCritic(in_dim, act_dim, config).to(**net)
        self.log_alpha = torch.tensor(math.log(config.sac_init_alpha), **net,
                                      requires_grad=True)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr)
        self.critic_opt = torch.optim.Adam(
            list(self.critic.parameters()) + list(self.critic2.parameters()),
            lr=config.critic_lr, weight_decay=config.critic_l2)
        self.alpha_opt = torch.optim.Adam([self.log_alpha], lr=config.sac_alpha_lr)
        self.mean = torch.zeros(in_dim, **net) if mean is None else mean.to(**net)
        self.std = torch.ones(in_dim, **net) if std is None else std.to(**net)
        self.reset_targets()

    def reset_targets(self) -> None:
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.critic2_target = copy.deepcopy(self.critic2).requires_grad_(False)

    def norm(self, x: torch.Tensor) -> torch.Tensor:
        c = self.config.obs_clip
        return torch.clamp((x - self.mean) / self.std, -c, c)

    def policy(self, x: torch.Tensor, eps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A reparameterised draw a = tanh(m + s eps) and its log density (B, 1)."""
        from torch.distributions import Independent, Normal, TransformedDistribution
        from torch.distributions.transforms import TanhTransform

        m, log_std = self.actor(x).split(self.act_dim, dim=-1)
        log_std = log_std.clamp(*self.log_std_range)
        z = m + log_std.exp() * eps
        dist = TransformedDistribution(Independent(Normal(m, log_std.exp()), 1),
                                       [TanhTransform(cache_size=1)])
        a = dist.transforms[0](z)  # cached: log_prob inverts through z, not atanh(a)
        return a, dist.log_prob(a).unsqueeze(-1)

    def update(self, x, u, r, x2, terminated, eps2, eps1):
        """One SAC step; ``eps2``, ``eps1`` (B, act_dim) the policy's draws for s' and s.
        Returns the critic loss (both critics' summed) and the policy loss."""
        cfg = self.config
        x, x2 = self.norm(x), self.norm(x2)
        alpha = self.log_alpha.detach().exp()
        with torch.no_grad():
            a2, logp2 = self.policy(x2, eps2)
            q2 = torch.min(self.critic_target(x2, a2), self.critic2_target(x2, a2))
            y = r + cfg.gamma * (1 - terminated) * (q2 - alpha * logp2)
        critic_loss = (nn.functional.mse_loss(self.critic(x, u), y)
                       + nn.functional.mse_loss(self.critic2(x, u), y))
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()
        a, logp = self.policy(x, eps1)
        actor_loss = (alpha * logp - torch.min(self.critic(x, a), self.critic2(x, a))).mean()
        self.actor_opt.zero_grad()
        actor_loss.backward()
        self.actor_opt.step()
        alpha_loss = -(self.log_alpha * (logp.detach() - self.act_dim)).mean()
        self.alpha_opt.zero_grad()
        alpha_loss.backward()
        self.alpha_opt.step()
        _soft_update(((self.critic, self.critic_target), (self.critic2, self.critic2_target)),
                     cfg.tau)
        return critic_loss.detach(), actor_loss.detach()
