"""Actor and critic of Lillicrap et al. 2016 (low-dimensional), stacked for K independent agents.

Every weight carries a leading agent axis, ``(K, fan_in, fan_out)``, and a layer is one batched
matrix product, ``torch.baddbmm``: K agents cost one kernel launch per layer instead of K. Agent k
only ever touches slice k, so K stacked agents compute exactly what K separate ones would.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn


class StackedLinear(nn.Module):
    """K independent affine maps: ``y[k] = x[k] @ weight[k] + bias[k]``.

    Parameters: ``weight : (K, fan_in, fan_out)``, ``bias : (K, 1, fan_out)``.
    """

    def __init__(self, k: int, fan_in: int, fan_out: int, *, dtype: torch.dtype, device):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(k, fan_in, fan_out, dtype=dtype, device=device))
        self.bias = nn.Parameter(torch.empty(k, 1, fan_out, dtype=dtype, device=device))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x : (K, B, fan_in) -> (K, B, fan_out)."""
        return torch.baddbmm(self.bias, x, self.weight)

    @torch.no_grad()
    def init_uniform_(self, bound: float | None, generators: Sequence[torch.Generator]) -> None:
        """Uniform in +-bound (default 1/sqrt(fan_in)), agent k drawn from ``generators[k]``.

        The draws happen on the CPU in float64, so an agent's initial weights depend only on its
        own generator, not on K, the device or the dtype.
        """
        k, fan_in, fan_out = self.weight.shape
        if len(generators) != k:
            raise ValueError(f"need one generator per agent ({k}), got {len(generators)}")
        b = 1.0 / math.sqrt(fan_in) if bound is None else bound
        for i, g in enumerate(generators):
            w = torch.rand(fan_in, fan_out, generator=g, dtype=torch.float64) * 2 * b - b
            c = torch.rand(1, fan_out, generator=g, dtype=torch.float64) * 2 * b - b
            self.weight[i].copy_(w)
            self.bias[i].copy_(c)


class Actor(nn.Module):
    """mu(x) = tanh(W3 relu(W2 relu(W1 x))), in actor units: -1..1 spans the action box.

    x : (K, B, in_dim) normalised input -> (K, B, act_dim) in [-1, 1].
    """

    def __init__(self, k, in_dim, act_dim, hidden: Sequence[int], *, dtype, device):
        super().__init__()
        h1, h2 = hidden
        self.l1 = StackedLinear(k, in_dim, h1, dtype=dtype, device=device)
        self.l2 = StackedLinear(k, h1, h2, dtype=dtype, device=device)
        self.l3 = StackedLinear(k, h2, act_dim, dtype=dtype, device=device)

    def init_(self, final_init: float, generators: Sequence[torch.Generator]) -> None:
        self.l1.init_uniform_(None, generators)
        self.l2.init_uniform_(None, generators)
        self.l3.init_uniform_(final_init, generators)

    def activations(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Hidden activations and output: x (K, B, in) -> a1 (K, B, h1), a2 (K, B, h2), mu.

        The hand-written backward pass of `ddpg_her.agent` needs the hidden layers; the in-place
        ReLU and tanh are safe under autograd too (their backward reads the output).
        """
        a1 = torch.relu_(torch.baddbmm(self.l1.bias, x, self.l1.weight))
        a2 = torch.relu_(torch.baddbmm(self.l2.bias, a1, self.l2.weight))
        return a1, a2, torch.tanh_(torch.baddbmm(self.l3.bias, a2, self.l3.weight))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.activations(x)[-1]


class Critic(nn.Module):
    """Q(x, u) = W3 relu(W2 [relu(W1 x), u]); the action u enters at the second layer.

    x : (K, B, in_dim) normalised input, u : (K, B, act_dim) action in actor units
    -> (K, B, 1).
    """

    def __init__(self, k, in_dim, act_dim, hidden: Sequence[int], *, dtype, device):
        super().__init__()
        h1, h2 = hidden
        self.l1 = StackedLinear(k, in_dim, h1, dtype=dtype, device=device)
        self.l2 = StackedLinear(k, h1 + act_dim, h2, dtype=dtype, device=device)
        self.l3 = StackedLinear(k, h2, 1, dtype=dtype, device=device)

    def init_(self, final_init: float, generators: Sequence[torch.Generator]) -> None:
        self.l1.init_uniform_(None, generators)
        self.l2.init_uniform_(None, generators)
        self.l3.init_uniform_(final_init, generators)

    def activations(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Hidden activations and output: x (K, B, in), u (K, B, act) -> c1 (K, B, h1), the
        second layer's input [c1, u] (K, B, h1 + act), c2 (K, B, h2), q (K, B, 1)."""
        c1 = torch.relu_(torch.baddbmm(self.l1.bias, x, self.l1.weight))
        c1u = torch.cat([c1, u], dim=-1)
        c2 = torch.relu_(torch.baddbmm(self.l2.bias, c1u, self.l2.weight))
        return c1, c1u, c2, torch.baddbmm(self.l3.bias, c2, self.l3.weight)

    def forward(self, x: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        return self.activations(x, u)[-1]


def agent_slice(module: nn.Module, k: int) -> dict[str, torch.Tensor]:
    """The parameters of agent k alone, as a CPU state dict without the agent axis."""
    return {name: p[k].detach().cpu().clone() for name, p in module.state_dict().items()}


@torch.no_grad()
def load_agent_slices(module: nn.Module, slices: Sequence[dict[str, torch.Tensor]]) -> None:
    """Inverse of `agent_slice`: fill the K stacked parameters from K per-agent state dicts."""
    for name, p in module.state_dict().items():
        p.copy_(torch.stack([s[name] for s in slices]).to(p))
