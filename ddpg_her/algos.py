"""The stacked agents by name (``AgentConfig.algo``) and what TD3 and SAC share: an autograd
update of K stacked agents, their per-agent state for checkpoints, their noise generators.

Every algorithm keeps the trainer's interface of `ddpg_her.agent.DDPG`: ``act(x, explore=)``,
``update(x, u, r, x2, terminated) -> (critic_loss, actor_loss)`` (K,) each, ``normalizer``,
``agent_state(k)`` and ``load_agent_states(states)``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from ddpg_her.config import AgentConfig
from ddpg_her.networks import agent_slice, load_agent_slices
from ddpg_her.normalizer import RunningNormalizer


def make_agent(config: AgentConfig, in_dim: int, act_dim: int, *,
               init_generators: Sequence[torch.Generator], dtype: torch.dtype = torch.float32,
               device: str | torch.device = "cpu") -> Any:
    """K stacked agents of ``config.algo`` (ddpg, td3, sac); arguments as `DDPG`'s."""
    from ddpg_her.agent import DDPG
    from ddpg_her.sac import SAC
    from ddpg_her.td3 import TD3

    cls = {"ddpg": DDPG, "td3": TD3, "sac": SAC}[config.algo.value]
    return cls(config, in_dim, act_dim, init_generators=init_generators, dtype=dtype,
               device=device)


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
            state[name] = {
                i: {key: (v[k] if v.ndim > 0 else v).detach().cpu().clone()
                    for key, v in s.items()}
                for i, s in opt.state_dict()["state"].items()
            }
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
            self.generators[k].set_state(s["noise_rng"])
        self.updates = int(states[0]["updates"])


def soft_update(targets: Sequence[torch.Tensor], online: Sequence[torch.Tensor],
                tau: float) -> None:
    """theta' <- (1 - tau) theta' + tau theta, tensor by tensor."""
    with torch.no_grad():
        for t, o in zip(targets, online, strict=True):
            t.lerp_(o, tau)
