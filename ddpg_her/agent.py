"""K independent DDPG agents (Lillicrap et al. 2016) updated together through stacked networks.

Agent k owns slice k of every parameter, optimiser moment and normaliser statistic; the losses of
the K agents are summed, so each agent's gradient is that of its own loss alone, and Adam, being
elementwise, steps every slice as K separate optimisers would.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import torch

from ddpg_her.config import AgentConfig
from ddpg_her.networks import Actor, Critic, agent_slice, load_agent_slices
from ddpg_her.normalizer import RunningNormalizer


def _adam(params, lr: float, weight_decay: float) -> torch.optim.Adam:
    """Adam with its fused kernel where torch has one for the device, else the foreach one."""
    params = list(params)
    try:
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, fused=True)
    except (RuntimeError, ValueError):
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, foreach=True)


class DDPG:
    """K DDPG agents with stacked actor, critic, their targets, Adam states and normalisers.

    in_dim : length of the network input x (see `ddpg_her.spaces.goal_input`);
    act_dim : action dimension; init_generators : K CPU generators, agent k's initial weights are
    drawn from generator k alone.
    """

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, *,
                 init_generators: Sequence[torch.Generator], dtype: torch.dtype = torch.float32,
                 device: str | torch.device = "cpu"):
        self.config = config
        self.k = k = len(init_generators)
        self.in_dim, self.act_dim = in_dim, act_dim
        self.device = torch.device(device)
        net = {"dtype": dtype, "device": self.device}
        self.actor = Actor(k, in_dim, act_dim, config.hidden_sizes, **net)
        self.critic = Critic(k, in_dim, act_dim, config.hidden_sizes, **net)
        self.actor.init_(config.final_init, init_generators)
        self.critic.init_(config.final_init, init_generators)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.normalizer = RunningNormalizer(
            k, in_dim, eps=config.norm_eps, clip=config.obs_clip, enabled=config.normalize_obs,
            **net)
        self.actor_opt = _adam(self.actor.parameters(), config.actor_lr, 0.0)
        self.critic_opt = _adam(self.critic.parameters(), config.critic_lr, config.critic_l2)
        self._actor_params = list(self.actor.parameters())
        self._online = self._actor_params + list(self.critic.parameters())
        self._target = list(self.actor_target.parameters()) + list(
            self.critic_target.parameters())

    @torch.no_grad()
    def act(self, x: torch.Tensor) -> torch.Tensor:
        """Deterministic actions mu(x): x : (K, M, in_dim) raw input -> (K, M, act_dim) in
        actor units [-1, 1]."""
        return self.actor(self.normalizer(x))

    def update(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
               terminated: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One DDPG step of every agent on its minibatch (K, N, ...) of transitions.

        x, x2 : raw inputs before and after the step, u : action in actor units, r : reward,
        terminated : 1 where the step ended the episode in success. Returns the critic and
        actor losses, (K,) each, before the step.
        """
        gamma, tau = self.config.gamma, self.config.tau
        x, x2 = self.normalizer(x), self.normalizer(x2)

        # Critic: minimise (Q(s, a) - y)^2 with y = r + gamma (1 - terminated) Q'(s', mu'(s')).
        with torch.no_grad():
            y = r + gamma * (1.0 - terminated) * self.critic_target(x2, self.actor_target(x2))
        critic_loss = (self.critic(x, u) - y).pow(2).mean(dim=(1, 2))
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.sum().backward()
        self.critic_opt.step()

        # Actor: ascend Q(s, mu(s)), the gradient reaching the actor's parameters only.
        actor_loss = -self.critic(x, self.actor(x)).mean(dim=(1, 2))
        self.actor_opt.zero_grad(set_to_none=True)
        actor_loss.sum().backward(inputs=self._actor_params)
        self.actor_opt.step()

        # Targets: theta' <- (1 - tau) theta' + tau theta.
        with torch.no_grad():
            torch._foreach_lerp_(self._target, self._online, tau)
        return critic_loss.detach(), actor_loss.detach()

    # --- per-agent state, for one checkpoint per agent ----------------------------------------
    def _modules(self) -> dict[str, torch.nn.Module]:
        return {"actor": self.actor, "critic": self.critic, "actor_target": self.actor_target,
                "critic_target": self.critic_target}

    def agent_state(self, k: int) -> dict[str, Any]:
        """Everything that defines agent k, without the agent axis, on the CPU."""
        state: dict[str, Any] = {n: agent_slice(m, k) for n, m in self._modules().items()}
        for name, opt in (("actor_opt", self.actor_opt), ("critic_opt", self.critic_opt)):
            sd = opt.state_dict()
            state[name] = {
                i: {key: (v[k] if v.ndim > 0 else v).detach().cpu().clone()
                    for key, v in s.items()}
                for i, s in sd["state"].items()
            }
        state["normalizer"] = self.normalizer.state(k)
        return state

    def load_agent_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Inverse of `agent_state` for all K agents at once."""
        if len(states) != self.k:
            raise ValueError(f"need {self.k} agent states, got {len(states)}")
        for name, module in self._modules().items():
            load_agent_slices(module, [s[name] for s in states])
        for name, opt in (("actor_opt", self.actor_opt), ("critic_opt", self.critic_opt)):
            sd = opt.state_dict()
            per_param = [s[name] for s in states]
            sd["state"] = {
                i: {key: (torch.stack([p[i][key] for p in per_param]) if v.ndim > 0 else v)
                    for key, v in per_param[0][i].items()}
                for i in per_param[0]
            }
            opt.load_state_dict(sd)
        for k, s in enumerate(states):
            self.normalizer.load_state(k, s["normalizer"])
