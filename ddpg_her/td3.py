"""K independent TD3 agents (Fujimoto, van Hoof, Meger 2018) updated together, stacked like DDPG.

TD3 is DDPG with three changes, each an `AgentConfig` field: twin critics whose smaller value
forms the target, target policy smoothing (clipped Gaussian noise on the target action), and a
delayed actor (and target) update. The networks are Lillicrap's, as DDPG's here (the action enters
the critics at their second layer; Fujimoto's enter at the first), and Table I's gamma, tau, rates,
batch and buffer apply. The update goes through autograd; ``tests/test_algos.py`` checks it
against `benchmarks.reference.ReferenceTD3` to 1e-10 in float64.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence

import torch

from ddpg_her.algos import StackedAgent, set_grads, soft_update, stacked_normal
from ddpg_her.config import AgentConfig
from ddpg_her.networks import Actor


class TD3(StackedAgent):
    """K TD3 agents: stacked actor, two critics, their targets, Adam states and normalisers.

    Arguments as `ddpg_her.agent.DDPG`'s. The smoothing noise comes from one generator per
    agent, seeded from its init generator, and is part of its checkpoint state.
    """

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, *,
                 init_generators: Sequence[torch.Generator], dtype: torch.dtype = torch.float32,
                 device: str | torch.device = "cpu"):
        self._set_up_twin_critics(config, in_dim, act_dim, Actor, init_generators, dtype, device)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self._actor_loss = torch.zeros(self.k, dtype=dtype, device=self.device)

    @torch.no_grad()
    def act(self, x: torch.Tensor, explore: bool = False) -> torch.Tensor:
        """Deterministic actions mu(x): x (K, M, in_dim) raw -> (K, M, act_dim) in actor units;
        exploration is the trainer's noise on top (``explore`` changes nothing here)."""
        return self.actor(self.normalizer(x))

    def smoothing_noise(self, n: int) -> torch.Tensor:
        """Target policy smoothing noise (K, n, act_dim): N(0, td3_target_noise^2) clipped to
        +-td3_target_noise_clip, in actor units."""
        c = self.config
        eps = stacked_normal(self.generators, (n, self.act_dim), dtype=self.dtype,
                             device=self.device)
        return (eps * c.td3_target_noise).clamp_(-c.td3_target_noise_clip,
                                                 c.td3_target_noise_clip)

    @torch.no_grad()
    def update(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
               terminated: torch.Tensor, noise: torch.Tensor | None = None
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """One TD3 step of every agent on its minibatch (K, N, ...); arguments as
        `DDPG.update`, ``noise`` (K, N, act_dim) the clipped smoothing noise (default: drawn).

        y = r + gamma (1 - terminated) min_i Q_i'(s', clip(mu'(s') + noise, -1, 1)); both
        critics descend mean (Q_i(s, a) - y)^2; every ``td3_policy_delay``-th update the actor
        ascends Q_1(s, mu(s)) and all targets move by tau. Returns the critic loss (the sum of
        both critics') and the actor loss of the latest actor step, (K,) each.
        """
        c = self.config
        x, x2 = self.normalizer(x), self.normalizer(x2)
        if noise is None:
            noise = self.smoothing_noise(x.shape[1])
        a2 = (self.actor_target(x2) + noise).clamp_(-1.0, 1.0)
        q2 = torch.minimum(self.critic1_target(x2, a2), self.critic2_target(x2, a2))
        y = r + c.gamma * (1.0 - terminated) * q2
        with torch.enable_grad():
            critic_loss = ((self.critic1(x, u) - y).square().mean(dim=(1, 2))
                           + (self.critic2(x, u) - y).square().mean(dim=(1, 2)))
            set_grads(self.critic_params, critic_loss)
            self.critic_opt.step()
            self.updates += 1
            if self.updates % c.td3_policy_delay == 0:
                actor_loss = -self.critic1(x, self.actor(x)).mean(dim=(1, 2))
                set_grads(list(self.actor.parameters()), actor_loss)
                self.actor_opt.step()
                self._actor_loss = actor_loss.detach()
                pairs = ((self.actor, self.actor_target), (self.critic1, self.critic1_target),
                         (self.critic2, self.critic2_target))
                soft_update([p for _, t in pairs for p in t.parameters()],
                            [p for m, _ in pairs for p in m.parameters()], c.tau)
        return critic_loss.detach(), self._actor_loss

    def _modules(self) -> dict[str, torch.nn.Module]:
        return {"actor": self.actor, "critic1": self.critic1, "critic2": self.critic2,
                "actor_target": self.actor_target, "critic1_target": self.critic1_target,
                "critic2_target": self.critic2_target}

    def _optimizers(self) -> dict[str, torch.optim.Optimizer]:
        return {"actor_opt": self.actor_opt, "critic_opt": self.critic_opt}
