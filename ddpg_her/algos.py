"""What TD3 and SAC share (`ddpg_her.agents.make_agent` picks an algorithm by name): an autograd
update of K stacked agents, their per-agent state for checkpoints, their noise generators.

Every algorithm keeps the trainer's interface of `ddpg_her.agent.DDPG`: ``act(x, explore=)``,
``update(x, u, r, x2, terminated) -> (critic_loss, actor_loss)`` (K,) each, ``normalizer``,
``agent_state(k)`` and ``load_agent_states(states)``.
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import torch

from ddpg_her.agent import make_adam
from ddpg_her.config import AgentConfig
from ddpg_her.networks import (
    Critic,
    agent_slice,
    load_agent_slices,
    load_optimizer_slices,
    optimizer_slice,
)
from ddpg_her.normalizer import RunningNormalizer


def noise_generators(init_generators: Sequence[torch.Generator],
                     device: torch.device) -> list[torch.Generator]:
    """One generator per agent for the update's noise, seeded from agent k's init generator
    (after its weights are drawn), so it depends on that agent's seed alone."""
    gens = []
    for g in init_generators:
        seed = int(torch.randint(0, 2**62, (1,), generator=g).item())
        gens.append(torch.Generator(device).manual_seed(seed))
    return gens


def stacked_normal(generators: Sequence[torch.Generator], shape: tuple[int, ...], *,
                   dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """Standard normal draws (K, *shape), agent k's slice from ``generators[k]`` alone."""
    return torch.stack([torch.randn(shape, generator=g, dtype=dtype, device=device)
                        for g in generators])


def set_grads(params: Sequence[torch.Tensor], loss: torch.Tensor) -> None:
    """p.grad := d(loss.sum())/dp for each p; the K losses are summed, so agent k's slice of
    each gradient is that of its own loss alone."""
    for p, g in zip(params, torch.autograd.grad(loss.sum(), list(params)), strict=True):
        p.grad = g


class StackedAgent:
    """Checkpoint state of K stacked agents: ``_modules()``, ``_optimizers()``, the normaliser,
    the noise generators and ``extra_state`` tensors with a leading agent axis."""

    k: int
    normalizer: RunningNormalizer
    generators: list[torch.Generator]
    updates: int

    def _set_up_twin_critics(self, config: AgentConfig, in_dim: int, act_dim: int,
                             actor: type[torch.nn.Module],
                             init_generators: Sequence[torch.Generator], dtype: torch.dtype,
                             device: str | torch.device) -> None:
        """What TD3 and SAC build alike: the actor (class ``actor``) and two critics, drawn
        from the init generators in that order, the noise generators seeded after them, the
        critics' targets, the normaliser, and Adam for the actor and for both critics."""
        self.config = config
        self.k = k = len(init_generators)
        self.in_dim, self.act_dim = in_dim, act_dim
        self.device = torch.device(device)
        self.dtype = dtype
        net = {"dtype": dtype, "device": self.device}
        self.actor = actor(k, in_dim, act_dim, config.hidden_sizes, **net)
        self.critic1 = Critic(k, in_dim, act_dim, config.hidden_sizes, **net)
        self.critic2 = Critic(k, in_dim, act_dim, config.hidden_sizes, **net)
        for m in (self.actor, self.critic1, self.critic2):
            m.init_(config.final_init, init_generators)
        self.generators = noise_generators(init_generators, self.device)
        self.critic1_target = copy.deepcopy(self.critic1).requires_grad_(False)
        self.critic2_target = copy.deepcopy(self.critic2).requires_grad_(False)
        self.normalizer = RunningNormalizer(
            k, in_dim, eps=config.norm_eps, clip=config.obs_clip, enabled=config.normalize_obs,
            **net)
        self.actor_opt = make_adam(self.actor.parameters(), config.actor_lr, 0.0)
        self.critic_params = list(self.critic1.parameters()) + list(self.critic2.parameters())
        self.critic_opt = make_adam(self.critic_params, config.critic_lr, config.critic_l2)
        self.updates = 0

    def _modules(self) -> dict[str, torch.nn.Module]:
        raise NotImplementedError

    def _optimizers(self) -> dict[str, torch.optim.Optimizer]:
        raise NotImplementedError

    def _extra(self) -> dict[str, torch.Tensor]:
        """Per-agent tensors (K, ...) outside the modules (SAC's log alpha)."""
        return {}

    def agent_state(self, k: int) -> dict[str, Any]:
        """Everything that defines agent k, without the agent axis, on the CPU."""
        state: dict[str, Any] = {n: agent_slice(m, k) for n, m in self._modules().items()}
        for name, opt in self._optimizers().items():
            state[name] = optimizer_slice(opt, k)
        for name, t in self._extra().items():
            state[name] = t[k].detach().cpu().clone()
        state["normalizer"] = self.normalizer.state(k)
        state["noise_rng"] = self.generators[k].get_state()
        state["updates"] = self.updates
        return state

    def load_agent_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Inverse of `agent_state` for all K agents at once."""
        if len(states) != self.k:
            raise ValueError(f"need {self.k} agent states, got {len(states)}")
        with torch.no_grad():
            for name, module in self._modules().items():
                load_agent_slices(module, [s[name] for s in states])
            for name, t in self._extra().items():
                t.copy_(torch.stack([s[name] for s in states]).to(t))
        for name, opt in self._optimizers().items():
            load_optimizer_slices(opt, [s[name] for s in states])
        for k, s in enumerate(states):
            self.normalizer.load_state(k, s["normalizer"])
            self.generators[k].set_state(s["noise_rng"])
        self.updates = int(states[0]["updates"])


def soft_update(targets: Sequence[torch.Tensor], online: Sequence[torch.Tensor],
                tau: float) -> None:
    """theta' <- (1 - tau) theta' + tau theta, tensor by tensor."""
    with torch.no_grad():
        for t, o in zip(targets, online, strict=True):
            t.lerp_(o, tau)
