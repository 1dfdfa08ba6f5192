"""K independent SAC agents (Haarnoja et al. 2018, with automatic entropy tuning) updated together.

A squashed Gaussian policy a = tanh(m(s) + sigma(s) eps), twin critics with target copies, and a
temperature alpha per agent tuned towards the target entropy -dim(A) (Haarnoja et al. 2018,
"Soft Actor-Critic Algorithms and Applications"). The networks are Lillicrap's, as DDPG's here
(400-300 ReLU, the action at the critics' second layer, final layers in +-final_init; the
policy's last layer gives the mean and log std), and Table I's gamma, tau, rates, batch and
buffer apply. The update goes through autograd; ``tests/test_algos.py`` checks it against
`benchmarks.reference.ReferenceSAC` (torch.distributions' tanh-transformed Normal) to 1e-10.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from ddpg_her.agent import make_adam
from ddpg_her.algos import StackedAgent, set_grads, soft_update, stacked_normal
from ddpg_her.config import AgentConfig
from ddpg_her.networks import StackedLinear, ThreeLayers

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0
"""The policy's log standard deviation is clamped to this range (Haarnoja et al.'s code)."""


class GaussianActor(ThreeLayers):
    """m, log sigma = split(W3 relu(W2 relu(W1 x))), log sigma clamped to
    [LOG_STD_MIN, LOG_STD_MAX]: x (K, B, in_dim) -> two (K, B, act_dim), pre-tanh units."""

    def __init__(self, k, in_dim, act_dim, hidden: Sequence[int], *, dtype, device):
        super().__init__()
        h1, h2 = hidden
        self.l1 = StackedLinear(k, in_dim, h1, dtype=dtype, device=device)
        self.l2 = StackedLinear(k, h1, h2, dtype=dtype, device=device)
        self.l3 = StackedLinear(k, h2, 2 * act_dim, dtype=dtype, device=device)
        self.act_dim = act_dim

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = torch.relu(self.l2(torch.relu(self.l1(x))))
        mean, log_std = self.l3(h).split(self.act_dim, dim=-1)
        return mean, log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)


def squashed_sample(mean: torch.Tensor, log_std: torch.Tensor, eps: torch.Tensor
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """a = tanh(mean + exp(log_std) eps) and log pi(a | s) (..., 1): the Gaussian's log density
    minus sum log(1 - tanh(z)^2), the latter as 2 (log 2 - z - softplus(-2 z)) for stability."""
    z = mean + log_std.exp() * eps
    gauss = (-0.5 * eps.square() - log_std - 0.5 * math.log(2 * math.pi)).sum(-1, keepdim=True)
    squash = (2.0 * (math.log(2.0) - z - F.softplus(-2.0 * z))).sum(-1, keepdim=True)
    return torch.tanh(z), gauss - squash


class SAC(StackedAgent):
    """K SAC agents: stacked policy, two critics and their targets, log alpha, Adam states.

    Arguments as `ddpg_her.agent.DDPG`'s. The policy's noise comes from one generator per agent,
    seeded from its init generator, and is part of its checkpoint state.
    """

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, *,
                 init_generators: Sequence[torch.Generator], dtype: torch.dtype = torch.float32,
                 device: str | torch.device = "cpu"):
        self._set_up_twin_critics(config, in_dim, act_dim, GaussianActor, init_generators, dtype,
                                  device)
        self.log_alpha = torch.full((self.k, 1, 1), math.log(config.sac_init_alpha),
                                    dtype=dtype, device=self.device, requires_grad=True)
        self.target_entropy = -float(act_dim)
        self.alpha_opt = make_adam([self.log_alpha], config.sac_alpha_lr, 0.0)

    @torch.no_grad()
    def act(self, x: torch.Tensor, explore: bool = False) -> torch.Tensor:
        """x (K, M, in_dim) raw -> (K, M, act_dim) in actor units: tanh of the mean (test), or
        with ``explore`` a draw of the policy (training)."""
        mean, log_std = self.actor(self.normalizer(x))
        if not explore:
            return torch.tanh(mean)
        return squashed_sample(mean, log_std, self.normal(x.shape[1]))[0]

    def normal(self, n: int) -> torch.Tensor:
        """Standard normal draws (K, n, act_dim), agent k's from its own generator."""
        return stacked_normal(self.generators, (n, self.act_dim), dtype=self.dtype,
                              device=self.device)

    @torch.no_grad()
    def update(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
               terminated: torch.Tensor, eps: tuple[torch.Tensor, torch.Tensor] | None = None
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """One SAC step of every agent on its minibatch (K, N, ...); arguments as
        `DDPG.update`; ``eps`` the policy's standard normal draws (K, N, act_dim) for s' and s
        (default: drawn).

        Critics: y = r + gamma (1 - terminated) (min_i Q_i'(s', a') - alpha log pi(a' | s')),
        a' ~ pi(s'), both descend mean (Q_i(s, a) - y)^2. Then the policy descends
        mean(alpha log pi(a | s) - min_i Q_i(s, a)), a ~ pi(s) reparameterised, on the updated
        critics; then log alpha descends -mean(log alpha (log pi(a | s) + target entropy));
        then the critics' targets move by tau. Returns the critic loss (both critics' summed)
        and the policy loss, (K,) each.
        """
        c = self.config
        x, x2 = self.normalizer(x), self.normalizer(x2)
        n = x.shape[1]
        eps2, eps1 = (self.normal(n), self.normal(n)) if eps is None else eps
        alpha = self.log_alpha.exp()
        a2, logp2 = squashed_sample(*self.actor(x2), eps2)
        q2 = torch.minimum(self.critic1_target(x2, a2), self.critic2_target(x2, a2))
        y = r + c.gamma * (1.0 - terminated) * (q2 - alpha * logp2)
        with torch.enable_grad():
            critic_loss = ((self.critic1(x, u) - y).square().mean(dim=(1, 2))
                           + (self.critic2(x, u) - y).square().mean(dim=(1, 2)))
            set_grads(self.critic_params, critic_loss)
            self.critic_opt.step()
            a, logp = squashed_sample(*self.actor(x), eps1)
            q = torch.minimum(self.critic1(x, a), self.critic2(x, a))
            actor_loss = (alpha * logp - q).mean(dim=(1, 2))
            set_grads(list(self.actor.parameters()), actor_loss)
            self.actor_opt.step()
            alpha_loss = -(self.log_alpha * (logp.detach() + self.target_entropy)).mean(
                dim=(1, 2))
            set_grads([self.log_alpha], alpha_loss)
            self.alpha_opt.step()
        self.updates += 1
        soft_update([p for t in (self.critic1_target, self.critic2_target) for p in t.parameters()],
                    self.critic_params, c.tau)
        return critic_loss.detach(), actor_loss.detach()

    def _modules(self) -> dict[str, torch.nn.Module]:
        return {"actor": self.actor, "critic1": self.critic1, "critic2": self.critic2,
                "critic1_target": self.critic1_target, "critic2_target": self.critic2_target}

    def _optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"actor_opt": self.actor_opt, "critic_opt": self.critic_opt,
                "alpha_opt": self.alpha_opt}

    def _extra(self) -> dict[str, torch.Tensor]:
        return {"log_alpha": self.log_alpha}


class MeanPolicy(nn.Module):
    """The deterministic test policy of a `GaussianActor`: x -> tanh(m(x)), for
    `ddpg_her.run.load` (which reads ``l1.weight`` for its dtype and device)."""

    def __init__(self, actor: GaussianActor):
        super().__init__()
        self.actor = actor
        self.l1 = actor.l1

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self.actor(x)[0])
