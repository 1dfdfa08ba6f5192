"""K independent DDPG agents (Lillicrap et al. 2016) updated together through stacked networks.

Agent k owns slice k of every parameter, optimiser moment and normaliser statistic; the losses of
the K agents are summed, so each agent's gradient is that of its own loss alone, and Adam, being
elementwise, steps every slice as K separate optimisers would.

The update is fast through three private torch functions (``torch._fused_adam_`` with
``torch._foreach_add_``, ``torch.ops.aten.threshold_backward``, ``torch._foreach_lerp_``). Each
is checked once at import against the public computation it replaces (:func:`probe_fast_paths`);
one that is missing or answers differently is replaced by that public computation, with a
warning naming it: a torch upgrade costs speed, never correctness.
"""

from __future__ import annotations

import copy
import dataclasses
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import torch

from ddpg_her.config import AgentConfig
from ddpg_her.networks import (
    Actor,
    Critic,
    agent_slice,
    load_agent_slices,
    load_optimizer_slices,
    optimizer_slice,
)
from ddpg_her.normalizer import RunningNormalizer


@dataclasses.dataclass(frozen=True)
class FastPaths:
    """Which private torch functions `DDPG.update` may call; each False takes the plain path."""

    fused_adam: bool = True
    """``torch._fused_adam_`` and ``torch._foreach_add_`` called directly; else ``opt.step()``."""
    threshold_backward: bool = True
    """``torch.ops.aten.threshold_backward`` for a ReLU's backward; else ``torch.where``."""
    foreach_lerp: bool = True
    """``torch._foreach_lerp_`` for the soft target update; else ``Tensor.lerp_`` per tensor."""


PLAIN = FastPaths(fused_adam=False, threshold_backward=False, foreach_lerp=False)
"""Public torch only: the path a torch without the private functions takes."""

PROBE_TOL = 1e-12
"""Largest difference accepted between a private function and its public twin on the probe's
float64 values (the same arithmetic: they agree to rounding)."""


def _probe_fused_adam() -> None:
    p, g = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64), torch.tensor([0.3, -0.1, 0.0],
                                                                              dtype=torch.float64)
    m, v, step = torch.zeros_like(p), torch.zeros_like(p), torch.zeros((), dtype=torch.float64)
    lr, beta1, beta2, eps = 0.1, 0.9, 0.999, 1e-8
    expected = p - lr * g / (g.abs() + eps)  # Adam's first step: m_hat = g, v_hat = g^2
    torch._foreach_add_([step], 1)
    torch._fused_adam_([p], [g], [m], [v], [], [step], amsgrad=False, lr=lr, beta1=beta1,
                       beta2=beta2, weight_decay=0.0, eps=eps, maximize=False, grad_scale=None,
                       found_inf=None)
    if not torch.allclose(p, expected, rtol=0.0, atol=PROBE_TOL):
        raise ValueError(f"first Adam step gave {p.tolist()}, expected {expected.tolist()}")


def _probe_threshold_backward() -> None:
    grad = torch.tensor([1.0, 2.0, 3.0, 4.0], dtype=torch.float64)
    out = torch.tensor([0.5, 0.0, -1.0, 2.0], dtype=torch.float64)
    got = torch.ops.aten.threshold_backward(grad, out, 0.0)
    if not torch.equal(got, _relu_backward_plain(grad, out)):
        raise ValueError(f"gave {got.tolist()} for the ReLU backward [1, 0, 0, 4]")


def _probe_foreach_lerp() -> None:
    a, b = torch.tensor([1.0, 2.0], dtype=torch.float64), torch.tensor([3.0, -2.0],
                                                                        dtype=torch.float64)
    expected = a.lerp(b, 0.25)
    torch._foreach_lerp_([a], [b], 0.25)
    if not torch.allclose(a, expected, rtol=0.0, atol=PROBE_TOL):
        raise ValueError(f"gave {a.tolist()}, expected {expected.tolist()}")


_PROBES: dict[str, tuple[str, Callable[[], None]]] = {
    "fused_adam": ("torch._fused_adam_ / torch._foreach_add_", _probe_fused_adam),
    "threshold_backward": ("torch.ops.aten.threshold_backward", _probe_threshold_backward),
    "foreach_lerp": ("torch._foreach_lerp_", _probe_foreach_lerp),
}
"""Field of `FastPaths` -> (the private functions it calls, a check against the public twin)."""


def probe_fast_paths() -> FastPaths:
    """Try each private function on a small float64 example against its public twin.

    Returns the `FastPaths` that passed; warns (``RuntimeWarning``) naming each one that is
    missing or answers differently, and the plain path that replaces it.
    """
    ok, failed = {}, []
    for field, (names, probe) in _PROBES.items():
        try:
            with torch.no_grad():
                probe()
            ok[field] = True
        except Exception as err:  # any failure of a private API means: do not use it
            ok[field] = False
            failed.append(f"{names} ({type(err).__name__}: {err})")
    if failed:
        warnings.warn(
            f"torch {torch.__version__}: {'; '.join(failed)}. ddpg_her.agent uses the plain "
            "public-torch path for these instead: the same update, slower",
            RuntimeWarning, stacklevel=2)
    return FastPaths(**ok)


def _relu_backward_plain(grad: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """grad where the ReLU's output is positive, else 0 (public ops)."""
    return torch.where(out > 0.0, grad, 0.0)


def _relu_backward(grad: torch.Tensor, out: torch.Tensor) -> torch.Tensor:
    """grad where the ReLU's output is positive, else 0: one fused pass, no mask tensor."""
    return torch.ops.aten.threshold_backward(grad, out, 0.0)


FAST = probe_fast_paths()
"""The private functions this torch offers and that pass their check; `DDPG` reads it when
built (a test sets it to `PLAIN` to exercise the fallback)."""


def make_adam(params, lr: float, weight_decay: float) -> torch.optim.Adam:
    """Adam with its fused kernel where torch has one for the device, else the foreach one."""
    params = list(params)
    try:
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, fused=True)
    except (RuntimeError, ValueError):
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, foreach=True)


class _AdamStep:
    """``opt.step()`` of a fused torch Adam, without its per-call Python bookkeeping.

    The optimiser keeps its state (so ``state_dict`` and checkpoints are torch's own); this calls
    the kernel ``opt.step()`` would, ``torch._fused_adam_``, on the tensors gathered once
    (results/throughput/README.md has the saving). Any optimiser that is not a single-group
    fused Adam, and the first step (which creates the state), go through ``opt.step()``. Call
    `reset` after ``opt.load_state_dict``.
    """

    def __init__(self, opt: torch.optim.Adam, allowed: bool = True):
        self.opt = opt
        group = opt.param_groups[0]
        self.direct = (allowed and len(opt.param_groups) == 1 and bool(group.get("fused"))
                       and not group["amsgrad"] and not group["maximize"]
                       and not group.get("decoupled_weight_decay", False)
                       and not torch.is_tensor(group["lr"]) and hasattr(torch, "_fused_adam_"))
        self._state: tuple[list[torch.Tensor], ...] | None = None
        self.lr: float | torch.Tensor = group["lr"]
        """The learning rate the kernel gets: the group's float, or after `capturable` a
        0-dim tensor on the parameters' device that a captured graph reads at each replay."""

    def capturable(self) -> None:
        """Pass the learning rate as a device tensor from now on, so that a CUDA graph of the
        step reads it rather than baking a Python float in (Adam's step counts already are
        device tensors of the fused kernel). float64 on the CPU, where the kernel reads it
        as the double it gets today (the same bits); float32 on CUDA, the only dtype of the
        CUDA kernel's tensor learning rate (Table I's 1e-4 and 1e-3 move by 2.5e-8 and 4.7e-8
        relative, below float32 parameters' own rounding of 6e-8)."""
        if not self.direct:
            raise ValueError(
                "a capturable Adam step needs torch's fused Adam kernel (torch._fused_adam_, "
                "one parameter group); this torch or optimiser takes opt.step() instead")
        device = self.opt.param_groups[0]["params"][0].device
        dtype = torch.float64 if device.type == "cpu" else torch.float32
        self.lr = torch.tensor(float(self.opt.param_groups[0]["lr"]), dtype=dtype,
                               device=device)

    def reset(self) -> None:
        self._state = None

    def __call__(self) -> None:
        if not self.direct or self._state is None:
            self.opt.step()
            if self.direct:
                params = self.opt.param_groups[0]["params"]
                st = [self.opt.state[p] for p in params]
                self._state = ([p.detach() for p in params], [p.grad for p in params],
                               [s["exp_avg"] for s in st], [s["exp_avg_sq"] for s in st],
                               [s["step"] for s in st])
            return
        params, grads, exp_avg, exp_avg_sq, steps = self._state
        g = self.opt.param_groups[0]
        beta1, beta2 = g["betas"]
        torch._foreach_add_(steps, 1)
        torch._fused_adam_(params, grads, exp_avg, exp_avg_sq, [], steps, amsgrad=False,
                           lr=self.lr, beta1=beta1, beta2=beta2, weight_decay=g["weight_decay"],
                           eps=g["eps"], maximize=False, grad_scale=None, found_inf=None)


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
        bn = config.batch_norm_momentum if config.batch_norm else None
        self.actor = Actor(k, in_dim, act_dim, config.hidden_sizes, batch_norm=bn, **net)
        self.critic = Critic(k, in_dim, act_dim, config.hidden_sizes, batch_norm=bn, **net)
        self.actor.init_(config.final_init, init_generators)
        self.critic.init_(config.final_init, init_generators)
        self.actor_target = copy.deepcopy(self.actor).requires_grad_(False)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.normalizer = RunningNormalizer(
            k, in_dim, eps=config.norm_eps, clip=config.obs_clip, enabled=config.normalize_obs,
            **net)
        self.actor_opt = make_adam(self.actor.parameters(), config.actor_lr, 0.0)
        self.critic_opt = make_adam(self.critic.parameters(), config.critic_lr, config.critic_l2)
        self.fast = FAST
        self._actor_step = _AdamStep(self.actor_opt, self.fast.fused_adam)
        self._critic_step = _AdamStep(self.critic_opt, self.fast.fused_adam)
        self._relu_backward = (_relu_backward if self.fast.threshold_backward
                               else _relu_backward_plain)
        self._online = list(self.actor.parameters()) + list(self.critic.parameters())
        self._target = list(self.actor_target.parameters()) + list(
            self.critic_target.parameters())
        # the soft target update moves batch normalisation's running statistics too (none
        # without it, so these are the parameter lists)
        self._lerp_online = self._online + [
            b for m in (self.actor, self.critic) for b in m.buffers()]
        self._lerp_target = self._target + [
            b for m in (self.actor_target, self.critic_target) for b in m.buffers()]
        # `update` writes every gradient into these buffers, which the optimisers read
        for p in self._online:
            p.grad = torch.zeros_like(p)
        self._grads = {p: p.grad for p in self._online}

    @torch.no_grad()
    def act(self, x: torch.Tensor, explore: bool = False) -> torch.Tensor:
        """Deterministic actions mu(x): x : (K, M, in_dim) raw input -> (K, M, act_dim) in
        actor units [-1, 1]. ``explore`` changes nothing: DDPG's exploration is the trainer's
        noise on top (a stochastic policy, SAC's, samples itself)."""
        return self.actor(self.normalizer(x))

    def capturable(self) -> None:
        """Make `update` safe to capture as a CUDA graph: the Adam steps take their learning
        rates as device tensors (`_AdamStep.capturable`). The rest of the hand-written update
        already reads only device tensors (parameters, gradients, Adam's moments and step
        counts, the normaliser's mean and std, all updated in place) and Python constants of
        the config; ``tests/test_counter_sampler.py`` proves it by compiling the update with
        ``torch.compile(fullgraph=True)``. On the CPU the update stays bit for bit the same.

        Raises ValueError with ``batch_norm`` (its update goes through autograd) or without
        torch's fused Adam kernel.
        """
        if self.config.batch_norm:
            raise ValueError("a capturable update needs the hand-written DDPG update; "
                             "batch_norm trains through autograd")
        self._actor_step.capturable()
        self._critic_step.capturable()

    @torch.no_grad()
    def update(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
               terminated: torch.Tensor, weight: torch.Tensor | None = None
               ) -> tuple[torch.Tensor, torch.Tensor]:
        """One DDPG step of every agent on its minibatch (K, N, ...) of transitions.

        x, x2 : raw inputs before and after the step, u : action in actor units, r : reward,
        terminated : 1 where the step ended the episode in success. Returns the critic and
        actor losses, (K,) each, before the step. ``weight`` (K, N, 1), prioritised replay's
        importance weights: the critic minimises mean w (Q - y)^2 instead, and ``td_error``
        (K, N) keeps this minibatch's Q(s, a) - y.

        Critic first: minimise mean (Q(s, a) - y)^2, y = r + gamma (1 - terminated)
        Q'(s', mu'(s')); then the actor ascends the updated critic's Q(s, mu(s)); then
        theta' <- (1 - tau) theta' + tau theta. The gradients are written out by hand (each
        layer a batched matrix product): that skips what autograd would compute and throw
        away (the critic's weight gradients in the actor step, the gradient of the state half
        of the critic's second-layer input), fuses each ReLU's backward into one pass and
        reuses preallocated gradient buffers. `tests/test_ddpg_agent.py` checks it, on the
        fast and on the plain path (`FastPaths`), against a plain autograd DDPG to 1e-10 in
        float64. With ``config.batch_norm`` the two steps go through autograd instead
        (`_update_autograd`).
        """
        if self.config.batch_norm:
            critic_loss, actor_loss = self._update_autograd(x, u, r, x2, terminated)
            self._soft_update()
            return critic_loss, actor_loss
        gamma = self.config.gamma
        n = x.shape[1]
        h1 = self.config.hidden_sizes[0]
        x, x2 = self.normalizer(x), self.normalizer(x2)
        actor, critic = self.actor, self.critic
        at, ct = self.actor_target, self.critic_target
        relu_backward = self._relu_backward

        # target y = r + gamma (1 - terminated) Q'(s', mu'(s'))
        q2 = ct(x2, at(x2))
        y = torch.addcmul(r, (1.0 - terminated) * gamma, q2)

        # critic step
        c1, c1u, c2, q = critic.activations(x, u)
        err = q - y                                                   # (K, N, 1)
        if weight is not None:
            self.td_error = err[..., 0].clone()
            err_w = err * weight
            critic_loss, err = (err_w * err).mean(dim=(1, 2)), err_w
        else:
            critic_loss = err.square().mean(dim=(1, 2))
        dq = err.mul_(2.0 / n)                                        # d(loss)/dq
        g = self._grads
        torch.bmm(c2.mT, dq, out=g[critic.l3.weight])
        torch.sum(dq, dim=1, keepdim=True, out=g[critic.l3.bias])
        dc2 = relu_backward(dq * critic.l3.weight.mT, c2)          # (K, N, h2)
        torch.bmm(c1u.mT, dc2, out=g[critic.l2.weight])
        torch.sum(dc2, dim=1, keepdim=True, out=g[critic.l2.bias])
        dc1 = relu_backward(torch.bmm(dc2, critic.l2.weight[:, :h1].mT), c1)
        torch.bmm(x.mT, dc1, out=g[critic.l1.weight])
        torch.sum(dc1, dim=1, keepdim=True, out=g[critic.l1.bias])
        self._critic_step()

        # actor step: ascend Q(s, mu(s)) of the updated critic; only the actor moves
        a1, a2, mu = actor.activations(x)
        _, _, c2, q = critic.activations(x, mu)
        actor_loss = -q.mean(dim=(1, 2))
        dc2 = relu_backward((critic.l3.weight.mT * (-1.0 / n)).expand_as(c2), c2)
        dmu = torch.bmm(dc2, critic.l2.weight[:, h1:].mT)            # (K, N, act_dim)
        da3 = dmu.mul_(1.0 - mu * mu)
        torch.bmm(a2.mT, da3, out=g[actor.l3.weight])
        torch.sum(da3, dim=1, keepdim=True, out=g[actor.l3.bias])
        da2 = relu_backward(torch.bmm(da3, actor.l3.weight.mT), a2)
        torch.bmm(a1.mT, da2, out=g[actor.l2.weight])
        torch.sum(da2, dim=1, keepdim=True, out=g[actor.l2.bias])
        da1 = relu_backward(torch.bmm(da2, actor.l2.weight.mT), a1)
        torch.bmm(x.mT, da1, out=g[actor.l1.weight])
        torch.sum(da1, dim=1, keepdim=True, out=g[actor.l1.bias])
        self._actor_step()
        self._soft_update()
        return critic_loss, actor_loss

    def _soft_update(self) -> None:
        """Targets: theta' <- (1 - tau) theta' + tau theta (and running statistics alike)."""
        tau = self.config.tau
        if self.fast.foreach_lerp:
            torch._foreach_lerp_(self._lerp_target, self._lerp_online, tau)
        else:
            for target, online in zip(self._lerp_target, self._lerp_online, strict=True):
                target.lerp_(online, tau)

    def _update_autograd(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor,
                         x2: torch.Tensor, terminated: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
        """The critic and actor steps of `update` through autograd, for batch normalisation.

        The same K stacked networks and Adam steps; the losses of the K agents are summed, so
        agent k's gradient is that of its own loss (batch statistics are per agent too). Targets
        and the target value use running statistics; the online networks the minibatch's. The
        critic's running statistics move in the critic step, the actor's in the actor step;
        the critic in the actor step normalises by the minibatch and leaves its statistics.
        `tests/test_ddpg_agent.py` checks it against `ddpg_her.reference` with nn.BatchNorm1d.
        """
        gamma = self.config.gamma
        x, x2 = self.normalizer(x), self.normalizer(x2)
        actor, critic = self.actor, self.critic
        q2 = self.critic_target(x2, self.actor_target(x2))
        y = torch.addcmul(r, (1.0 - terminated) * gamma, q2)
        with torch.enable_grad():
            q = critic(x, u, batch_stats=True, update_stats=True)
            critic_loss = (q - y).square().mean(dim=(1, 2))
            self._set_grads(critic, critic_loss)
            self._critic_step()
            mu = actor(x, batch_stats=True, update_stats=True)
            actor_loss = -critic(x, mu, batch_stats=True).mean(dim=(1, 2))
            self._set_grads(actor, actor_loss)
            self._actor_step()
        return critic_loss.detach(), actor_loss.detach()

    def _set_grads(self, net: torch.nn.Module, loss: torch.Tensor) -> None:
        """Write d(sum of the K losses)/d(parameter) into the preallocated gradient buffers
        of ``net``'s parameters (which the optimiser steps read)."""
        params = list(net.parameters())
        for p, g in zip(params, torch.autograd.grad(loss.sum(), params), strict=True):
            self._grads[p].copy_(g)

    # --- per-agent state, for one checkpoint per agent ----------------------------------------
    def _modules(self) -> dict[str, torch.nn.Module]:
        return {"actor": self.actor, "critic": self.critic, "actor_target": self.actor_target,
                "critic_target": self.critic_target}

    def agent_state(self, k: int) -> dict[str, Any]:
        """Everything that defines agent k, without the agent axis, on the CPU."""
        state: dict[str, Any] = {n: agent_slice(m, k) for n, m in self._modules().items()}
        for name, opt in (("actor_opt", self.actor_opt), ("critic_opt", self.critic_opt)):
            state[name] = optimizer_slice(opt, k)
        state["normalizer"] = self.normalizer.state(k)
        return state

    def load_agent_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Inverse of `agent_state` for all K agents at once."""
        if len(states) != self.k:
            raise ValueError(f"need {self.k} agent states, got {len(states)}")
        for name, module in self._modules().items():
            load_agent_slices(module, [s[name] for s in states])
        for name, opt in (("actor_opt", self.actor_opt), ("critic_opt", self.critic_opt)):
            load_optimizer_slices(opt, [s[name] for s in states])
        self._actor_step.reset()
        self._critic_step.reset()
        for k, s in enumerate(states):
            self.normalizer.load_state(k, s["normalizer"])
