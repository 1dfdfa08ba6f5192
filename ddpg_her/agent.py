"""K independent DDPG agents (Lillicrap et al. 2016) updated together through stacked networks.

Agent k owns slice k of every parameter, optimiser moment and normaliser statistic; the losses of
the K agents are summed, so each agent's gradient is that of its own loss alone, and Adam, being
elementwise, steps every slice as K separate optimisers would.

All parameters of a stack (actor, critic and their targets) are views into one flat buffer,
Adam's moments and the gradients likewise: an Adam step is one fused pass over a network's
parameters, the soft target update one pass over all, and an online network and its target,
each parameter's two stacks side by side, run as one stack of 2K agents.

The update is fast through three private torch functions (``torch._fused_adam_``,
``torch.ops.aten.threshold_backward``, ``torch._foreach_lerp_``). Each is checked once at import
against the public computation it replaces (:func:`probe_fast_paths`); one that is missing or
answers differently is replaced by that public computation, with a warning naming it: a torch
upgrade costs speed, never correctness.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import warnings
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch.optim.adam import adam as adam_loop

from ddpg_her.config import AgentConfig
from ddpg_her.networks import (
    Actor,
    Critic,
    agent_slice,
    bind_parameters,
    load_agent_slices,
    parameter_views,
)
from ddpg_her.normalizer import RunningNormalizer


@dataclasses.dataclass(frozen=True)
class FastPaths:
    """Which private torch functions `DDPG.update` may call; each False takes the plain path."""

    fused_adam: bool = True
    """``torch._fused_adam_`` called directly; else ``torch.optim.adam.adam``'s own loop."""
    threshold_backward: bool = True
    """``torch.ops.aten.threshold_backward`` for a ReLU's backward; else ``torch.where``."""
    foreach_lerp: bool = True
    """``torch._foreach_lerp_`` for the soft target update; else ``Tensor.lerp_`` per tensor."""


PROBE_TOL = 1e-12
"""Largest difference accepted between a private function and its public twin on the probe's
float64 values (the same arithmetic: they agree to rounding)."""


def _probe_fused_adam() -> None:
    p, g = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64), torch.tensor([0.3, -0.1, 0.0],
                                                                              dtype=torch.float64)
    m, v, step = torch.zeros_like(p), torch.zeros_like(p), torch.zeros((), dtype=torch.float64)
    lr, beta1, beta2, eps = 0.1, 0.9, 0.999, 1e-8
    expected = p - lr * g / (g.abs() + eps)  # Adam's first step: m_hat = g, v_hat = g^2
    step.add_(1)
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
    "fused_adam": ("torch._fused_adam_", _probe_fused_adam),
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


def _bmm(a: torch.Tensor, b: torch.Tensor, alpha: float) -> torch.Tensor:
    """alpha (a @ b) for (K, M, L) a and (K, L, P) b in one batched product (baddbmm ignores
    its input at beta = 0). A power of two alpha scales exactly, so the result is the bits of
    a @ b scaled after, or of a or b scaled before (but for subnormals)."""
    return torch.baddbmm(a[:, :1, :1], a, b, beta=0.0, alpha=alpha)


FAST = probe_fast_paths()
"""The private functions this torch offers and that pass their check; `DDPG` reads it when
built (a test sets it to all False to exercise the fallback)."""


def make_adam(params, lr: float, weight_decay: float) -> torch.optim.Adam:
    """Adam with its fused kernel where torch has one for the device, else the foreach one."""
    params = list(params)
    try:
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, fused=True)
    except (RuntimeError, ValueError):
        return torch.optim.Adam(params, lr=lr, weight_decay=weight_decay, foreach=True)


ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8
"""torch.optim.Adam's defaults, which Lillicrap et al.'s Adam (Kingma and Ba 2015) uses."""

NETWORKS = ("actor", "critic")
"""The networks in the order of the flat layout's first axis (their optimisers alike)."""


class DDPG:
    """K DDPG agents with stacked actor, critic, their targets, Adam states and normalisers.

    in_dim : length of the network input x (see `ddpg_her.spaces.goal_input`);
    act_dim : action dimension; init_generators : K CPU generators, agent k's initial weights are
    drawn from generator k alone.

    The flat layout: ``params`` (1-D) holds the actor's parameters, then the critic's, each
    parameter ``(K, ...)`` of the online network followed by the target's, one ``(2K, ...)``
    block (`ddpg_her.networks.parameter_views`); ``grads``, ``exp_avg`` and ``exp_avg_sq``
    (1-D) those of the online networks in the same order; ``steps (2,)`` the two Adam step
    counts. ``actor.l1.weight`` and every other parameter is a view into it, so checkpoints
    (`agent_state`) keep their per-parameter format.
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
        sizes = [sum(p.numel() for p in m.parameters()) for m in (self.actor, self.critic)]
        self.params = torch.zeros(2 * sum(sizes), **net)
        self.grads, self.exp_avg, self.exp_avg_sq = (torch.zeros(sum(sizes), **net)
                                                     for _ in "gmv")
        self.steps = torch.zeros(2, dtype=torch.float32, device=self.device)
        self._one = torch.ones((), **net)
        self.lr: list[float | torch.Tensor] = [config.actor_lr, config.critic_lr]
        self.weight_decay = (0.0, config.critic_l2)
        self._adam_tensors: list[tuple[list[torch.Tensor], ...]] = []
        self._grads: dict[torch.Tensor, torch.Tensor] = {}  # not .grad: compile cannot trace it
        pairs, start = {}, 0
        for j, name in enumerate(NETWORKS):
            online, target = getattr(self, name), getattr(self, f"{name}_target")
            flat = slice(start, start + sizes[j])
            views = parameter_views(online, self.params[2 * flat.start:2 * flat.stop], copies=2)
            bind_parameters(online, [v[:k] for v in views])
            bind_parameters(target, [v[k:] for v in views])
            grads = parameter_views(online, self.grads[flat])
            self._grads.update(zip(online.parameters(), grads, strict=True))
            self._adam_tensors.append((  # detached: the kernel is not autograd's business
                [p.detach() for p in online.parameters()], grads,
                parameter_views(online, self.exp_avg[flat]),
                parameter_views(online, self.exp_avg_sq[flat])))
            if not config.batch_norm:  # online beside target: one stack of 2K agents
                pairs[name] = copy.deepcopy(target)
                bind_parameters(pairs[name], views, copy=False)
            start = flat.stop
        self._actor_pair, self._critic_pair = pairs.get("actor"), pairs.get("critic")
        # the soft update moves batch normalisation's running statistics too
        nets = (self.actor, self.critic, self.actor_target, self.critic_target)
        self._lerp_online, self._lerp_target = (
            [t for m in modules for t in [*m.parameters(), *m.buffers()]]
            for modules in (nets[:2], nets[2:]))
        self.fast = FAST
        self._relu_backward = (_relu_backward if self.fast.threshold_backward
                               else _relu_backward_plain)
        self.fused = self.device.type == "cuda" and not config.batch_norm
        f64 = {"dtype": torch.float64, "device": self.device}  # `_update_fused`'s constants
        self._hyper = torch.tensor([[lr, wd, config.tau, *ADAM_BETAS, ADAM_EPS] for lr, wd in
                                    zip(self.lr, self.weight_decay, strict=True)], **f64)
        self._flats = [slice(0, sizes[0]), slice(sizes[0], sum(sizes))]
        self._starts = [torch.tensor([0, *itertools.accumulate(p.numel() for p in m.parameters())],
                                     device=self.device) for m in (self.actor, self.critic)]
        self._gamma_clip = torch.tensor([config.gamma, config.obs_clip], **f64)

    @torch.no_grad()
    def act(self, x: torch.Tensor, explore: bool = False) -> torch.Tensor:
        """Deterministic actions mu(x): x : (K, M, in_dim) raw input -> (K, M, act_dim) in
        actor units [-1, 1]. ``explore`` changes nothing: DDPG's exploration is the trainer's
        noise on top (a stochastic policy, SAC's, samples itself)."""
        return self.actor(self.normalizer(x))

    def capturable(self) -> None:
        """Make `update` safe to capture as a CUDA graph: the learning rates become device
        tensors, read at each replay (float64 on the CPU: the same bits; float32 on CUDA, its
        kernel's only dtype: Table I's rates move by <= 4.7e-8 relative). The rest reads only
        device tensors and config constants (``tests/test_counter_sampler.py`` compiles it
        with ``torch.compile(fullgraph=True)``). ValueError with ``batch_norm`` (autograd) or
        without torch's fused Adam kernel."""
        if self.config.batch_norm or not self.fast.fused_adam:
            raise ValueError("a capturable update needs the hand-written DDPG update (no "
                             "batch_norm, which trains through autograd) and torch's fused "
                             "Adam kernel (torch._fused_adam_)")
        dtype = torch.float64 if self.device.type == "cpu" else torch.float32
        self.lr = [torch.tensor(float(lr), dtype=dtype, device=self.device) for lr in self.lr]

    def _adam(self, j: int) -> None:
        """One Adam step of network j (`NETWORKS`): one fused kernel over its flat online
        parameters, else torch.optim.adam.adam's public loop."""
        params, grads, exp_avg, exp_avg_sq = self._adam_tensors[j]
        hyper = {"amsgrad": False, "beta1": ADAM_BETAS[0], "beta2": ADAM_BETAS[1],
                 "lr": self.lr[j], "weight_decay": self.weight_decay[j], "eps": ADAM_EPS,
                 "maximize": False}
        if self.fast.fused_adam:  # the kernel reads the count, one 0-dim view per parameter
            torch._fused_adam_(params, grads, exp_avg, exp_avg_sq, [], [self.steps[j]] * len(
                params), **hyper, grad_scale=None, found_inf=None)
        else:  # the loop advances a count per parameter: give it copies, the shared one after
            adam_loop(params, grads, exp_avg, exp_avg_sq, [],
                      [self.steps[j].clone() for _ in params], foreach=False, **hyper)
            self.steps[j] += 1

    def _count_steps(self) -> None:
        """Both Adam step counts + 1 in one pass (the plain path counts in `_adam`)."""
        if self.fast.fused_adam:
            self.steps.add_(1)

    def _soft_update(self) -> None:
        """Targets: theta' <- (1 - tau) theta' + tau theta (and running statistics alike)."""
        tau = self.config.tau
        if self.fast.foreach_lerp:
            torch._foreach_lerp_(self._lerp_target, self._lerp_online, tau)
        else:
            for target, online in zip(self._lerp_target, self._lerp_online, strict=True):
                target.lerp_(online, tau)

    @torch.no_grad()
    def update(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
               terminated: torch.Tensor, weight: torch.Tensor | None = None,
               loss_sum: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """One DDPG step of every agent on its minibatch (K, N, ...) of transitions.

        x, x2 : raw inputs before and after the step, u : action in actor units, r : reward,
        terminated : 1 where the step ended the episode in success. Returns the critic and
        actor losses, (K,) each, before the step. ``weight`` (K, N, 1), prioritised replay's
        importance weights: the critic minimises mean w (Q - y)^2 instead, and ``td_error``
        (K, N) keeps this minibatch's Q(s, a) - y. ``loss_sum`` (2, K) float64, if given,
        gains the two losses.

        Critic first: minimise mean (Q(s, a) - y)^2, y = r + gamma (1 - terminated)
        Q'(s', mu'(s')); then the actor ascends the updated critic's Q(s, mu(s)); then
        theta' <- (1 - tau) theta' + tau theta. Before the critic step, mu(s) beside mu'(s')
        and Q(s, a) beside Q'(s', mu'(s')) run as one stack of 2K agents each (an online
        network and its target lie side by side in the flat layout). The gradients are
        written out by hand (each layer a batched matrix product): that skips what autograd
        would compute and throw away (the critic's weight gradients in the actor step, the
        gradient of the state half of the critic's second-layer input), fuses each ReLU's
        backward into one pass and writes into the flat gradient buffer.
        `tests/test_ddpg_agent.py` checks it, on the fast, the plain and the fused path
        (`FastPaths`, ``fused``), against a plain autograd DDPG to 1e-10 in float64. With
        ``config.batch_norm`` the two steps go through autograd instead (`_update_autograd`).
        """
        if self.fused and weight is None:
            return self._update_fused(x, u, r, x2, terminated, loss_sum)
        self._count_steps()
        if self.config.batch_norm:
            critic_loss, actor_loss = self._update_autograd(x, u, r, x2, terminated)
        else:
            critic_loss, actor_loss = self._update_hand(x, u, r, x2, terminated, weight)
        self._soft_update()
        if loss_sum is not None:
            loss_sum[0] += critic_loss
            loss_sum[1] += actor_loss
        return critic_loss, actor_loss

    def _update_hand(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
                     terminated: torch.Tensor, weight: torch.Tensor | None
                     ) -> tuple[torch.Tensor, torch.Tensor]:
        """`update`'s critic and actor steps, the gradients written by hand."""
        k, n, h1 = self.k, x.shape[1], self.config.hidden_sizes[0]
        gamma = self.config.gamma
        actor, critic = self.actor, self.critic
        relu_backward, g = self._relu_backward, self._grads

        # [online; target] as 2K agents: mu(s) beside mu'(s'), Q(s, a) beside Q'(s', mu'(s'))
        xs = self.normalizer(torch.stack([x, x2])).view(2 * k, n, -1)
        a1s, a2s, mus = self._actor_pair.activations(xs)
        c1s, c1us, c2s, qs = self._critic_pair.activations(xs, torch.cat([u, mus[k:]]))
        x, a1, a2, mu, c1, c1u, c2, q = (t[:k] for t in (xs, a1s, a2s, mus, c1s, c1us, c2s, qs))
        y = torch.addcmul(r, 1.0 - terminated, qs[k:], value=gamma)

        # critic step
        err = q - y                                                   # (K, N, 1)
        if weight is not None:
            self.td_error = err[..., 0].clone()
            err_w = err * weight
            critic_loss, err = _bmm(err_w.mT, err, 1.0 / n).view(k), err_w
        else:
            critic_loss = _bmm(err.mT, err, 1.0 / n).view(k)
        dq = err.mul_(2.0 / n)                                        # d(loss)/dq
        torch.bmm(c2.mT, dq, out=g[critic.l3.weight])
        torch.sum(dq, dim=1, keepdim=True, out=g[critic.l3.bias])
        dc2 = relu_backward(dq * critic.l3.weight.mT, c2)          # (K, N, h2)
        torch.bmm(c1u.mT, dc2, out=g[critic.l2.weight])
        torch.sum(dc2, dim=1, keepdim=True, out=g[critic.l2.bias])
        dc1 = relu_backward(torch.bmm(dc2, critic.l2.weight[:, :h1].mT), c1)
        torch.bmm(x.mT, dc1, out=g[critic.l1.weight])
        torch.sum(dc1, dim=1, keepdim=True, out=g[critic.l1.bias])
        self._adam(1)

        # actor step: ascend Q(s, mu(s)) of the updated critic; only the actor moves
        _, _, c2, q = critic.activations(x, mu)
        actor_loss = _bmm(self._one.expand(k, 1, n), q, -1.0 / n).view(k)
        dc2 = relu_backward(critic.l3.weight.mT.expand_as(c2), c2)   # -n d(loss)/dc2
        dmu = _bmm(dc2, critic.l2.weight[:, h1:].mT, -1.0 / n)       # (K, N, act_dim)
        da3 = dmu.mul_(1.0 - mu * mu)
        torch.bmm(a2.mT, da3, out=g[actor.l3.weight])
        torch.sum(da3, dim=1, keepdim=True, out=g[actor.l3.bias])
        da2 = relu_backward(torch.bmm(da3, actor.l3.weight.mT), a2)
        torch.bmm(a1.mT, da2, out=g[actor.l2.weight])
        torch.sum(da2, dim=1, keepdim=True, out=g[actor.l2.bias])
        da1 = relu_backward(torch.bmm(da2, actor.l2.weight.mT), a1)
        torch.bmm(x.mT, da1, out=g[actor.l1.weight])
        torch.sum(da1, dim=1, keepdim=True, out=g[actor.l1.bias])
        self._adam(0)
        return critic_loss, actor_loss

    def _update_fused(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor,
                      x2: torch.Tensor, terminated: torch.Tensor, loss_sum: torch.Tensor | None
                      ) -> tuple[torch.Tensor, torch.Tensor]:
        """`update` with the steps between its matrix products in the Triton kernels of
        `ddpg_her.program_kernels` (37 launches where the hand-written path takes 58; on CUDA,
        or on the CPU under Triton's interpreter): the normalisation, each layer's activation
        backward with its bias gradient, the critic's head with its loss and target, each
        network's Adam step with its soft target update and the step counts. The same steps
        as `_update_hand`; the sums in another order (a few ulps)."""
        import ddpg_her.program_kernels as fuse

        k, n, h1 = self.k, x.shape[1], self.config.hidden_sizes[0]
        actor, critic, g = self.actor, self.critic, self._grads
        if self.normalizer.enabled:
            xs = x.new_empty(2 * k, n, x.shape[2])
            fuse.normalize(x, x2, self.normalizer, xs, self._gamma_clip[1:])
        else:
            xs = torch.cat([x, x2])
        a1s, a2s, mus = self._actor_pair.activations(xs)
        c1s, c1us, c2s, qs = self._critic_pair.activations(xs, torch.cat([u, mus[k:]]))
        x, a1, a2, mu, c1, c1u, c2 = (t[:k] for t in (xs, a1s, a2s, mus, c1s, c1us, c2s))
        losses = x.new_empty(2, k)
        acc = loss_sum if loss_sum is not None else losses.new_zeros(2, k, dtype=torch.float64)
        dc2 = torch.empty_like(c2)
        fuse.head(qs, c2, critic.l3.weight, dc2, losses[0], acc[0], (
            r, terminated, self._gamma_clip, g[critic.l3.weight], g[critic.l3.bias],
            g[critic.l2.bias]))
        torch.bmm(c1u.mT, dc2, out=g[critic.l2.weight])
        dc1 = torch.bmm(dc2, critic.l2.weight[:, :h1].mT)
        fuse.backward(dc1, c1, g[critic.l1.bias], tanh=False)
        torch.bmm(x.mT, dc1, out=g[critic.l1.weight])
        self._adam_fused(1, read=1, write=0, inc=1)   # t = critic's count + 1; actor's += 1

        _, _, c2, q = critic.activations(x, mu)
        dc2 = torch.empty_like(c2)
        fuse.head(q, c2, critic.l3.weight, dc2, losses[1], acc[1])
        da = _bmm(dc2, critic.l2.weight[:, h1:].mT, -1.0 / n)       # (K, N, act_dim)
        for layer, below, out in ((actor.l3, a2, mu), (actor.l2, a1, a2), (actor.l1, x, a1)):
            fuse.backward(da, out, g[layer.bias], tanh=layer is actor.l3)
            torch.bmm(below.mT, da, out=g[layer.weight])
            if layer is not actor.l1:
                da = torch.bmm(da, layer.weight.mT)
        self._adam_fused(0, read=0, write=1, inc=0)   # t = actor's count; critic's += 1
        return losses[0], losses[1]

    def _adam_fused(self, j: int, read: int, write: int, inc: int) -> None:
        """Network j's Adam step and soft target update, one launch (`program_kernels.adam`)."""
        import ddpg_her.program_kernels as fuse

        flat = self._flats[j]
        fuse.adam(self.params[2 * flat.start:2 * flat.stop], self.grads[flat],
                  self.exp_avg[flat], self.exp_avg_sq[flat], self._starts[j], self.steps,
                  self._hyper[j], read, write, inc)

    def _update_autograd(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor,
                         x2: torch.Tensor, terminated: torch.Tensor
                         ) -> tuple[torch.Tensor, torch.Tensor]:
        """The critic and actor steps of `update` through autograd, for batch normalisation.

        The same K stacked networks and Adam steps; the losses of the K agents are summed, so
        agent k's gradient is that of its own loss (batch statistics are per agent too). Targets
        and the target value use running statistics; the online networks the minibatch's. The
        critic's running statistics move in the critic step, the actor's in the actor step;
        the critic in the actor step normalises by the minibatch and leaves its statistics.
        `tests/test_ddpg_agent.py` checks it against `benchmarks.reference` with nn.BatchNorm1d.
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
            self._adam(1)
            mu = actor(x, batch_stats=True, update_stats=True)
            actor_loss = -critic(x, mu, batch_stats=True).mean(dim=(1, 2))
            self._set_grads(actor, actor_loss)
            self._adam(0)
        return critic_loss.detach(), actor_loss.detach()

    def _set_grads(self, net: torch.nn.Module, loss: torch.Tensor) -> None:
        """Write d(sum of the K losses)/d(parameter) into ``net``'s gradients, views into the
        flat gradient buffer that the Adam steps read."""
        params = list(net.parameters())
        for p, g in zip(params, torch.autograd.grad(loss.sum(), params), strict=True):
            self._grads[p].copy_(g)

    # --- per-agent state, for one checkpoint per agent ----------------------------------------
    def _modules(self) -> dict[str, torch.nn.Module]:
        return {"actor": self.actor, "critic": self.critic, "actor_target": self.actor_target,
                "critic_target": self.critic_target}

    def _moments(self, j: int) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Adam's two moments of each parameter of network j, views shaped as the parameter."""
        return list(zip(*self._adam_tensors[j][2:], strict=True))

    def agent_state(self, k: int) -> dict[str, Any]:
        """Everything that defines agent k, without the agent axis, on the CPU. The optimisers
        in torch.optim.Adam's ``state_dict()["state"]`` format (``{i: {"step", "exp_avg",
        "exp_avg_sq"}}`` by parameter; empty before the first step)."""
        state: dict[str, Any] = {n: agent_slice(m, k) for n, m in self._modules().items()}
        for j, name in enumerate(NETWORKS):
            step = self.steps[j].cpu()
            state[f"{name}_opt"] = {} if step == 0 else {
                i: {"step": step.clone(), "exp_avg": m[k].cpu().clone(),
                    "exp_avg_sq": v[k].cpu().clone()} for i, (m, v) in enumerate(self._moments(j))}
        state["normalizer"] = self.normalizer.state(k)
        return state

    @torch.no_grad()
    def load_agent_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Inverse of `agent_state` for all K agents at once (the step count from the first)."""
        if len(states) != self.k:
            raise ValueError(f"need {self.k} agent states, got {len(states)}")
        for name, module in self._modules().items():
            load_agent_slices(module, [s[name] for s in states])
        for j, name in enumerate(NETWORKS):
            opts = [s[f"{name}_opt"] for s in states]
            self.steps[j] = float(opts[0][0]["step"]) if opts[0] else 0.0
            for moment in (m for pair in self._moments(j) for m in pair):
                moment.zero_()
            for i, moments in enumerate(self._moments(j) if opts[0] else []):
                for moment, key in zip(moments, ("exp_avg", "exp_avg_sq"), strict=True):
                    moment.copy_(torch.stack([o[i][key] for o in opts]))
        for k, s in enumerate(states):
            self.normalizer.load_state(k, s["normalizer"])
