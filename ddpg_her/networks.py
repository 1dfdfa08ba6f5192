"""Actor and critic of Lillicrap et al. 2016 (low-dimensional), stacked for K independent agents.

Every weight carries a leading agent axis, ``(K, fan_in, fan_out)``, and a layer is one batched
matrix product, ``torch.baddbmm``: K agents cost one kernel launch per layer instead of K. Agent k
only ever touches slice k, so K stacked agents compute exactly what K separate ones would.

With ``batch_norm`` (AgentConfig.batch_norm) the networks carry Lillicrap's batch normalisation:
on the input, and before the ReLU of every actor hidden layer and of the critic's first layer.
``batch_stats=True`` normalises by the minibatch (the online networks in the update), else by
the running statistics (targets, and every action taken).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import nn


class StackedLinear(nn.Module):
    """K independent affine maps: ``y[k] = x[k] @ weight[k] + bias[k]``.

    Parameters: ``weight : (K, fan_in, fan_out)``, ``bias : (K, 1, fan_out)`` (None without
    ``bias``: a layer followed by batch normalisation, whose shift subsumes it).
    """

    def __init__(self, k: int, fan_in: int, fan_out: int, *, dtype: torch.dtype, device,
                 bias: bool = True):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(k, fan_in, fan_out, dtype=dtype, device=device))
        self.bias = (nn.Parameter(torch.empty(k, 1, fan_out, dtype=dtype, device=device))
                     if bias else None)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x : (K, B, fan_in) -> (K, B, fan_out)."""
        if self.bias is None:
            return torch.bmm(x, self.weight)
        return torch.baddbmm(self.bias, x, self.weight)

    @torch.no_grad()
    def init_uniform_(self, bound: float | None, generators: Sequence[torch.Generator]) -> None:
        """Uniform in +-bound (default 1/sqrt(fan_in)), agent k drawn from ``generators[k]``.

        The draws happen on the CPU in float64, so an agent's initial weights depend only on its
        own generator, not on K, the device or the dtype. A layer without bias draws (and
        drops) it too, so its weights are those it has with one.
        """
        k, fan_in, fan_out = self.weight.shape
        if len(generators) != k:
            raise ValueError(f"need one generator per agent ({k}), got {len(generators)}")
        b = 1.0 / math.sqrt(fan_in) if bound is None else bound
        for i, g in enumerate(generators):
            w = torch.rand(fan_in, fan_out, generator=g, dtype=torch.float64) * 2 * b - b
            c = torch.rand(1, fan_out, generator=g, dtype=torch.float64) * 2 * b - b
            self.weight[i].copy_(w)
            if self.bias is not None:
                self.bias[i].copy_(c)


BATCH_NORM_EPS = 1e-5
"""Added to the variance inside batch normalisation's square root (torch's default; Lillicrap
et al. do not say)."""


class StackedBatchNorm(nn.Module):
    """K independent batch normalisations over the batch axis of (K, B, dim) activations.

    y = (x - mean) / sqrt(var + BATCH_NORM_EPS) * weight + bias, weight and bias ``(K, 1, dim)``
    (initially 1 and 0; bias None without ``shift``); mean and var are the minibatch's (biased
    variance) with ``batch_stats``, else the buffers ``running_mean`` and ``running_var``
    ``(K, 1, dim)`` (initially 0 and 1), which ``update_stats`` moves by ``momentum`` towards
    the minibatch's mean and unbiased variance, as ``torch.nn.BatchNorm1d`` does.
    """

    def __init__(self, k: int, dim: int, momentum: float, *, dtype: torch.dtype, device,
                 shift: bool = True):
        super().__init__()
        net = {"dtype": dtype, "device": device}
        self.momentum = momentum
        self.weight = nn.Parameter(torch.ones(k, 1, dim, **net))
        self.bias = nn.Parameter(torch.zeros(k, 1, dim, **net)) if shift else None
        self.register_buffer("running_mean", torch.zeros(k, 1, dim, **net))
        self.register_buffer("running_var", torch.ones(k, 1, dim, **net))

    def forward(self, x: torch.Tensor, batch_stats: bool = False,
                update_stats: bool = False) -> torch.Tensor:
        """x : (K, B, dim) -> (K, B, dim); B >= 2 with ``batch_stats``."""
        if batch_stats:
            mean = x.mean(dim=1, keepdim=True)
            var = x.var(dim=1, keepdim=True, unbiased=False)
            if update_stats:
                n = x.shape[1]
                with torch.no_grad():
                    self.running_mean.lerp_(mean, self.momentum)
                    self.running_var.lerp_(var * (n / (n - 1)), self.momentum)
        else:
            mean, var = self.running_mean, self.running_var
        y = (x - mean) * torch.rsqrt(var + BATCH_NORM_EPS) * self.weight
        return y if self.bias is None else y + self.bias


def _norms(k: int, dims: Sequence[int], momentum: float | None, **net) -> nn.ModuleList | None:
    """One `StackedBatchNorm` per width in ``dims`` (input first), or None without batch
    normalisation.

    Every layer that batch normalisation follows loses its bias, and the input's normalisation
    its shift, as Ioffe and Szegedy 2015 drop them: the next normalisation subtracts any
    constant they add, so their gradient is zero but for rounding, which Adam's division by
    the gradient's own size would turn into steps of the learning rate that move the running
    statistics, and with them the targets, at random.
    """
    if momentum is None:
        return None
    return nn.ModuleList(StackedBatchNorm(k, d, momentum, shift=i > 0, **net)
                         for i, d in enumerate(dims))


class ThreeLayers(nn.Module):
    """A network of three `StackedLinear` layers ``l1``, ``l2``, ``l3`` (a subclass builds them)."""

    def init_(self, final_init: float, generators: Sequence[torch.Generator]) -> None:
        """Hidden layers uniform in +-1/sqrt(fan_in), the last in +-``final_init``."""
        self.l1.init_uniform_(None, generators)
        self.l2.init_uniform_(None, generators)
        self.l3.init_uniform_(final_init, generators)


class Actor(ThreeLayers):
    """mu(x) = tanh(W3 relu(W2 relu(W1 x))), in actor units: -1..1 spans the action box.

    x : (K, B, in_dim) normalised input -> (K, B, act_dim) in [-1, 1]. With ``batch_norm``
    (the running statistics' momentum; None: none), BN0 on x and BN1, BN2 before the ReLUs,
    and no bias in W1, W2 and no shift in BN0 (`_norms`): tanh(W3 relu(BN2(W2 relu(BN1(W1
    BN0(x))))) + b3).
    """

    def __init__(self, k, in_dim, act_dim, hidden: Sequence[int], *, dtype, device,
                 batch_norm: float | None = None):
        super().__init__()
        h1, h2 = hidden
        plain = batch_norm is None
        self.l1 = StackedLinear(k, in_dim, h1, dtype=dtype, device=device, bias=plain)
        self.l2 = StackedLinear(k, h1, h2, dtype=dtype, device=device, bias=plain)
        self.l3 = StackedLinear(k, h2, act_dim, dtype=dtype, device=device)
        self.norms = _norms(k, (in_dim, h1, h2), batch_norm, dtype=dtype, device=device)

    def activations(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Hidden activations and output: x (K, B, in) -> a1 (K, B, h1), a2 (K, B, h2), mu.

        The hand-written backward pass of `ddpg_her.agent` needs the hidden layers; the in-place
        ReLU and tanh are safe under autograd too (their backward reads the output). Without
        batch normalisation only.
        """
        assert self.norms is None, "the hand-written path has no batch normalisation"
        a1 = torch.relu_(torch.baddbmm(self.l1.bias, x, self.l1.weight))
        a2 = torch.relu_(torch.baddbmm(self.l2.bias, a1, self.l2.weight))
        return a1, a2, torch.tanh_(torch.baddbmm(self.l3.bias, a2, self.l3.weight))

    def forward(self, x: torch.Tensor, batch_stats: bool = False,
                update_stats: bool = False) -> torch.Tensor:
        """mu(x); the flags choose batch normalisation's statistics (`StackedBatchNorm`)."""
        if self.norms is None:
            return self.activations(x)[-1]
        bn0, bn1, bn2 = (lambda z, n=n: n(z, batch_stats, update_stats) for n in self.norms)
        a1 = torch.relu(bn1(self.l1(bn0(x))))
        a2 = torch.relu(bn2(self.l2(a1)))
        return torch.tanh(self.l3(a2))


class Critic(ThreeLayers):
    """Q(x, u) = W3 relu(W2 [relu(W1 x), u]); the action u enters at the second layer.

    x : (K, B, in_dim) normalised input, u : (K, B, act_dim) action in actor units
    -> (K, B, 1). With ``batch_norm`` (the running statistics' momentum; None: none), BN0 on x
    and BN1 before the first ReLU, the layers before the action input, and no bias in W1 and no
    shift in BN0 (`_norms`): W3 relu(W2 [relu(BN1(W1 BN0(x))), u] + b2) + b3.
    """

    def __init__(self, k, in_dim, act_dim, hidden: Sequence[int], *, dtype, device,
                 batch_norm: float | None = None):
        super().__init__()
        h1, h2 = hidden
        self.l1 = StackedLinear(k, in_dim, h1, dtype=dtype, device=device,
                                bias=batch_norm is None)
        self.l2 = StackedLinear(k, h1 + act_dim, h2, dtype=dtype, device=device)
        self.l3 = StackedLinear(k, h2, 1, dtype=dtype, device=device)
        self.norms = _norms(k, (in_dim, h1), batch_norm, dtype=dtype, device=device)

    def activations(self, x: torch.Tensor, u: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Hidden activations and output: x (K, B, in), u (K, B, act) -> c1 (K, B, h1), the
        second layer's input [c1, u] (K, B, h1 + act), c2 (K, B, h2), q (K, B, 1). Without
        batch normalisation only."""
        assert self.norms is None, "the hand-written path has no batch normalisation"
        c1 = torch.relu_(torch.baddbmm(self.l1.bias, x, self.l1.weight))
        c1u = torch.cat([c1, u], dim=-1)
        c2 = torch.relu_(torch.baddbmm(self.l2.bias, c1u, self.l2.weight))
        return c1, c1u, c2, torch.baddbmm(self.l3.bias, c2, self.l3.weight)

    def forward(self, x: torch.Tensor, u: torch.Tensor, batch_stats: bool = False,
                update_stats: bool = False) -> torch.Tensor:
        """Q(x, u); the flags choose batch normalisation's statistics (`StackedBatchNorm`)."""
        if self.norms is None:
            return self.activations(x, u)[-1]
        bn0, bn1 = (lambda z, n=n: n(z, batch_stats, update_stats) for n in self.norms)
        c1 = torch.relu(bn1(self.l1(bn0(x))))
        c2 = torch.relu(self.l2(torch.cat([c1, u], dim=-1)))
        return self.l3(c2)


def parameter_views(module: nn.Module, flat: torch.Tensor, copies: int = 1
                    ) -> list[torch.Tensor]:
    """Views into the 1-D ``flat`` shaped as ``module``'s parameters ``(K, ...)``, each as
    ``copies`` stacks of K in one ``(copies K, ...)`` view; parameter i's block follows i-1's
    (``copies`` times the parameters' numbers in all). ``copies=2`` lays an online network
    beside its target: ``view[:K]`` and ``view[K:]``, two stacks of K as one of 2K."""
    views, start = [], 0
    for p in module.parameters():
        size = copies * p.numel()
        views.append(flat[start:start + size].view(copies * p.shape[0], *p.shape[1:]))
        start += size
    return views


@torch.no_grad()
def bind_parameters(module: nn.Module, views: Sequence[torch.Tensor], copy: bool = True) -> None:
    """Make ``module``'s parameters ``views`` (in order), their values copied in (``copy``)."""
    for p, view in zip(list(module.parameters()), views, strict=True):
        if copy:
            view.copy_(p)
        p.data = view


def agent_slice(module: nn.Module, k: int) -> dict[str, torch.Tensor]:
    """The parameters of agent k alone, as a CPU state dict without the agent axis."""
    return {name: p[k].detach().cpu().clone() for name, p in module.state_dict().items()}


@torch.no_grad()
def load_agent_slices(module: nn.Module, slices: Sequence[dict[str, torch.Tensor]]) -> None:
    """Inverse of `agent_slice`: fill the K stacked parameters from K per-agent state dicts."""
    for name, p in module.state_dict().items():
        p.copy_(torch.stack([s[name] for s in slices]).to(p))


def optimizer_slice(opt: torch.optim.Optimizer, k: int) -> dict[int, dict[str, torch.Tensor]]:
    """Agent k's part of a stacked optimizer's state (Adam's moments of its slices; scalar
    entries such as the step count whole), on the CPU."""
    return {i: {key: (v[k] if v.ndim > 0 else v).detach().cpu().clone() for key, v in s.items()}
            for i, s in opt.state_dict()["state"].items()}


def load_optimizer_slices(opt: torch.optim.Optimizer,
                          slices: Sequence[dict[int, dict[str, torch.Tensor]]]) -> None:
    """Inverse of `optimizer_slice`: the stacked state from K agents' parts (the scalar entries
    from the first)."""
    sd = opt.state_dict()
    sd["state"] = {i: {key: (torch.stack([p[i][key] for p in slices]) if v.ndim > 0 else v)
                       for key, v in slices[0][i].items()}
                   for i in slices[0]}
    opt.load_state_dict(sd)
