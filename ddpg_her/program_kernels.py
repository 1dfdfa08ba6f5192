"""The training program's per-step chain fused into two Triton kernels (issue 42), one lane per
copy: `explore` (the actor's action to the arm's command: exploration noise, clip, joint mask,
the action box, the env's clip, the PD bias) and `settle` (after the arm kernel: rates,
observation, reward, success, the episode's bookkeeping and stored rows, and the next
normalised input). ``ddpg_her.program``'s eager code is their definition and oracle (the CPU
path); these run where ``Program(fused=True)``, on CUDA, or on the CPU under Triton's
interpreter (``TRITON_INTERPRET=1`` before this module is imported), as the tests run them.

Float constants travel in a float64 tensor (a Python float argument would be float32); float64
``tl.sqrt`` and division are IEEE (correctly rounded), float32 division is ``div_rn``.
"""

from __future__ import annotations

import os
from typing import Any

import torch
import triton
import triton.language as tl

BLOCK = 64
"""Copies per program."""

KINDS = {"uniform": 0, "gaussian": 1, "ou": 2, "epsilon": 3, "none": 4}
"""`explore`'s noise: warm-up's uniform action, `ddpg_her.config.Exploration`'s three, none
(the test session's deterministic policy)."""


@triton.jit
def _explore(mu, mu_m, table, table_b, ou, mask, low, high, env_low, env_high, gain, active,
             stored, stored_b, env_action, bias, params, B, KIND: tl.constexpr,
             STORE: tl.constexpr, BLOCK: tl.constexpr):
    b = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    ok = b < B
    nu, theta, two_pi = tl.load(params), tl.load(params + 1), tl.load(params + 2)
    run = tl.load(active + b, mask=ok, other=0) != 0
    a = b // mu_m                                              # the copy's agent
    for j in tl.static_range(6):
        r = b * 6 + j
        m = tl.load(mu + b * 6 + j, mask=ok, other=0.0).to(tl.float64)
        if KIND == 0:
            u = tl.load(table + a * table_b + j, mask=ok, other=0.0)
            noisy = 2.0 * u - 1.0
        elif KIND == 1 or KIND == 2:
            u1 = tl.load(table + a * table_b + j, mask=ok, other=0.0)
            u2 = tl.load(table + a * table_b + 6 + j, mask=ok, other=0.0)
            n = tl.sqrt(-2.0 * tl.log(1.0 - u1)) * tl.cos(two_pi * u2)   # 1 - u1: exact
            if KIND == 1:
                noisy = m + nu * n
            else:
                o = tl.load(ou + r, mask=ok, other=0.0)
                o = o + (-theta * o + nu * n)
                tl.store(ou + r, o, mask=ok)
                noisy = m + o
        elif KIND == 3:
            hit = tl.load(table + a * table_b, mask=ok, other=1.0) < nu
            value = 2.0 * tl.load(table + a * table_b + 1 + j, mask=ok, other=0.0) - 1.0
            noisy = tl.where(hit, value, m)
        else:
            noisy = m
        if KIND != 4:
            noisy = tl.minimum(tl.maximum(noisy, -1.0), 1.0)
        u = noisy * tl.load(mask + r, mask=ok, other=0.0)
        lo, hi = tl.load(low + r, mask=ok, other=0.0), tl.load(high + r, mask=ok, other=0.0)
        action = lo + (u + 1.0) * 0.5 * (hi - lo)
        if STORE:
            tl.store(stored + b * stored_b + j, tl.where(run, action, 0.0), mask=ok)
        action = tl.minimum(tl.maximum(action, tl.load(env_low + r, mask=ok, other=0.0)),
                            tl.load(env_high + r, mask=ok, other=0.0))
        tl.store(env_action + r, action, mask=ok)
        tl.store(bias + r, tl.load(gain + r, mask=ok, other=0.0) * action, mask=ok)


@triton.jit
def _settle(q, w, dw, acceleration, v, tool, goal, elapsed, action, scale, mask, active, ret,
            final, length, success, obs, obs_b, achieved, achieved_b, reward, reward_b, term,
            term_b, x, mean, std, norm_m, params, B, T, STORE: tl.constexpr,
            NORM: tl.constexpr, DENSE: tl.constexpr, BLOCK: tl.constexpr):
    b = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
    ok = b < B
    w_to_v, w_to_accel, radius, bonus = (tl.load(params), tl.load(params + 1),
                                         tl.load(params + 2), tl.load(params + 3))
    d_weight, a_weight, stop, clip = (tl.load(params + 4), tl.load(params + 5),
                                      tl.load(params + 6), tl.load(params + 7))
    run = tl.load(active + b, mask=ok, other=0) != 0
    a = b // norm_m                                            # the copy's agent (normaliser)
    qs, vs, accs = (), (), ()
    for j in tl.static_range(6):
        r = b * 6 + j
        m = tl.load(mask + r, mask=ok, other=0.0)
        acc = tl.load(dw + r, mask=ok, other=0.0) * w_to_accel
        vel = tl.load(w + r, mask=ok, other=0.0) * w_to_v
        tl.store(acceleration + r, acc, mask=ok)
        tl.store(v + r, vel, mask=ok)
        qs, vs, accs = qs + (tl.load(q + r, mask=ok, other=0.0) * m,), vs + (vel * m,), \
            accs + (acc * m,)
    xs = qs + vs + accs
    t = tl.load(elapsed + b, mask=ok, other=0) + 1
    tl.store(elapsed + b, t, mask=ok)
    ag, g = (), ()
    for i in tl.static_range(3):
        ag = ag + (tl.load(tool + b * 3 + i, mask=ok, other=0.0),)
        g = g + (tl.load(goal + b * 3 + i, mask=ok, other=0.0),)
    diff = (ag[0] - g[0], ag[1] - g[1], ag[2] - g[2])
    distance = tl.sqrt(diff[0] * diff[0] + diff[1] * diff[1] + diff[2] * diff[2])
    reached = distance <= radius
    rew = bonus * reached.to(tl.float64)
    if DENSE:
        penalty = tl.zeros([BLOCK], tl.float64)
        for j in tl.static_range(6):
            u = tl.load(action + b * 6 + j, mask=ok, other=0.0) / tl.load(
                scale + b * 6 + j, mask=ok, other=1.0)
            penalty = penalty + u * u
        rew = rew - d_weight * distance - a_weight * penalty
    ended = reached.to(tl.float64) * stop != 0.0            # stop: 1.0 or 0.0
    if STORE:
        for j in tl.static_range(18):
            tl.store(obs + b * obs_b + j, xs[j], mask=ok)
        for i in tl.static_range(3):
            tl.store(achieved + b * achieved_b + i, ag[i], mask=ok)
        tl.store(reward + b * reward_b, rew, mask=ok)
        tl.store(term + b * term_b, ended.to(tl.int8), mask=ok)
    tl.store(ret + b, tl.load(ret + b, mask=ok, other=0.0) + tl.where(run, rew, 0.0), mask=ok)
    for i in tl.static_range(3):
        old = tl.load(final + b * 3 + i, mask=ok, other=0.0)
        tl.store(final + b * 3 + i, tl.where(run, ag[i], old), mask=ok)
    tl.store(length + b, tl.load(length + b, mask=ok, other=0) + run.to(tl.int64), mask=ok)
    was = tl.load(success + b, mask=ok, other=0) != 0
    tl.store(success + b, tl.where(run, reached, was).to(tl.int8), mask=ok)
    tl.store(active + b, (run & ~(ended | (t >= T))).to(tl.int8), mask=ok)
    xs = xs + (g[0] - ag[0], g[1] - ag[1], g[2] - ag[2], g[0], g[1], g[2])
    for j in tl.static_range(24):
        y = xs[j].to(tl.float32)
        if NORM:
            y = y.to(x.dtype.element_ty) - tl.load(mean + a * 24 + j, mask=ok, other=0.0)
            s = tl.load(std + a * 24 + j, mask=ok, other=1.0)
            y = tl.math.div_rn(y, s) if x.dtype.element_ty == tl.float32 else y / s
            y = tl.minimum(tl.maximum(y, -clip.to(y.dtype)), clip.to(y.dtype))
        tl.store(x + b * 24 + j, y, mask=ok)


def _grid(b: int) -> tuple[int]:
    return (triton.cdiv(b, BLOCK),)


def _bytes(t: torch.Tensor) -> torch.Tensor:
    """A bool tensor seen as int8 (Triton stores bytes; torch's bool is one)."""
    return t.view(torch.int8) if t.dtype == torch.bool else t


def explore(kind: str, mu: torch.Tensor, table: torch.Tensor, ou: torch.Tensor,
            params: torch.Tensor, mask: torch.Tensor, scale: Any, env: Any,
            active: torch.Tensor, stored: torch.Tensor | None) -> None:
    """`ddpg_her.program`'s policy and ``env.step``'s first half in one launch: the actor's
    ``mu (K, M, 6)`` float32 (copy b of the B = K M: agent b // M), perturbed by ``kind``
    (`KINDS`) from ``table (K, 12)`` (a row of `CounterDraws.table`) and the OU state ``ou
    (K, 6)`` float64 (written), masked (``mask (B, 6)`` float64), mapped to the box
    ``scale`` (`StackScale`), stored where ``active (B,)`` into ``stored (B, 6)`` (a strided
    row view; None: not stored), clipped into ``env.action`` and multiplied by the arm's gain
    into its bias. params : (3,) float64 [nu, theta, 2 pi]."""
    d, B = env.dynamics, env.num_envs
    row = stored if stored is not None else env.action
    _explore[_grid(B)](mu, mu.shape[1], table, table.stride(0), ou, mask,
                       scale.low, scale.high, env.action_low, env.action_high, d._gain,
                       _bytes(active), row, row.stride(0), env.action, d._bias, params, B,
                       KIND=KINDS[kind], STORE=stored is not None, BLOCK=BLOCK)


def settle(env: Any, mask: torch.Tensor, active: torch.Tensor, ret: torch.Tensor,
           final: torch.Tensor, length: torch.Tensor, success: torch.Tensor,
           rows: tuple[torch.Tensor, ...] | None, x: torch.Tensor, normalizer: Any, norm_m: int,
           params: torch.Tensor, T: int) -> None:
    """After the arm kernel, one launch: its rates, the step's observation, reward and
    success (``mask (B, 6)`` float64: the env's joints); ``ret``, ``final``, ``length``,
    ``success``, ``active`` (B,) updated as the eager rollout does; ``rows`` (obs (B, 18),
    achieved (B, 3), reward (B,), terminated (B,):
    strided views of step t + 1's and t's rows; None: not stored); and ``x (B, 24)`` float32
    the next normalised input (agent b // ``norm_m``'s normaliser). params : (8,) float64
    [w_to_v, w_to_accel, success radius, success reward, distance weight, action weight,
    terminate on success, clip]."""
    d, B = env.dynamics, env.num_envs
    obs, ach, rew, term = rows if rows is not None else (x, x, x, x)
    _settle[_grid(B)](d.q, d.w, d._dw, d.acceleration, d.v, d.tool, env.goal, env.elapsed,
                      env.action, env.penalty_scale, mask, _bytes(active), ret,
                      final, length, _bytes(success), obs, obs.stride(0), ach, ach.stride(0),
                      rew, rew.stride(0), _bytes(term), term.stride(0), x,
                      normalizer.mean, normalizer.std, norm_m, params, B, T,
                      STORE=rows is not None, NORM=bool(normalizer.enabled),
                      DENSE=env.task.reward_type != "sparse", BLOCK=BLOCK)


# ---------------------------------------------------------------------------- the update
# `ddpg_her.agent.DDPG.update`'s elementwise and reduction steps between its matrix products,
# fused where the agent's ``fused`` is set (`DDPG._update_fused`; its torch path is their
# definition and oracle). One program per (agent, tile of the hidden axis), the whole
# minibatch in it: every reduction over the minibatch is a fixed tree, deterministic. Indices
# are int64 (the interpreter checks int32 arithmetic for overflow, op by op: slow).
@triton.jit
def _normalize(x, x2, sk, sn, mean, std, out, clip, K, N, D, BLOCK_R: tl.constexpr,
               BLOCK_D: tl.constexpr):
    row = tl.program_id(0).to(tl.int64) * BLOCK_R + tl.arange(0, BLOCK_R)[:, None]  # 2K N rows
    d = tl.arange(0, BLOCK_D).to(tl.int64)[None, :]
    ok = (row < 2 * K * N) & (d < D)
    c, n = row // N, row % N
    a = c % K
    src = a * sk + n * sn + d
    y = tl.where(c < K, tl.load(x + src, mask=ok & (c < K), other=0.0),
                 tl.load(x2 + src, mask=ok & (c >= K), other=0.0))
    y = y - tl.load(mean + a * D + d, mask=ok, other=0.0)
    s = tl.load(std + a * D + d, mask=ok, other=1.0)
    y = tl.math.div_rn(y, s) if y.dtype == tl.float32 else y / s
    c_ = tl.load(clip).to(y.dtype)
    tl.store(out + row * D + d, tl.minimum(tl.maximum(y, -c_), c_), mask=ok)


@triton.jit
def _head(q, r, term, sk, sn, c2, w3, dc2, gw3, gb3, gb2, loss, acc, gamma, K, N, H,
          CRITIC: tl.constexpr, BLOCK_N: tl.constexpr, BLOCK_H: tl.constexpr):
    k, tile = tl.program_id(0).to(tl.int64), tl.program_id(1)
    n = tl.arange(0, BLOCK_N).to(tl.int64)
    h = tile * BLOCK_H + tl.arange(0, BLOCK_H)
    okn, okh = n < N, h < H
    qk = tl.load(q + k * N + n, mask=okn, other=0.0)
    inv_n = (1.0 / N.to(tl.float64)).to(qk.dtype)
    if CRITIC:      # y = r + gamma (1 - terminated) Q'(s', mu'(s')); d loss / dq = 2 (q - y) / N
        done = tl.load(term + k * sk + n * sn, mask=okn, other=0.0)
        q2 = tl.load(q + (K + k) * N + n, mask=okn, other=0.0)
        y = tl.load(r + k * sk + n * sn, mask=okn, other=0.0) + tl.load(gamma).to(
            qk.dtype) * (1.0 - done) * q2
        err = tl.where(okn, qk - y, 0.0)
        value = tl.sum(err * err, 0) * inv_n
        dq = err * (2.0 * inv_n)
    else:           # the actor's loss -mean Q(s, mu(s)); the head's gradient is W3 itself
        value = -tl.sum(qk, 0) * inv_n
        dq = tl.where(okn, 1.0, 0.0).to(qk.dtype)
    ok = okn[:, None] & okh[None, :]
    c = tl.load(c2 + (k * N + n[:, None]) * H + h[None, :], mask=ok, other=0.0)
    d = tl.where(c > 0.0, dq[:, None] * tl.load(w3 + k * H + h, mask=okh, other=0.0)[None, :],
                 0.0)
    tl.store(dc2 + (k * N + n[:, None]) * H + h[None, :], d, mask=ok)
    if CRITIC:
        tl.store(gb2 + k * H + h, tl.sum(d, 0), mask=okh)
        tl.store(gw3 + k * H + h, tl.sum(c * dq[:, None], 0), mask=okh)
        tl.store(gb3 + k, tl.sum(dq, 0), mask=tile == 0)
    tl.store(loss + k, value, mask=tile == 0)
    tl.store(acc + k, tl.load(acc + k) + value.to(tl.float64), mask=tile == 0)


@triton.jit
def _backward(grad, out, gb, N, H, TANH: tl.constexpr, BLOCK_N: tl.constexpr,
              BLOCK_H: tl.constexpr):
    k, n = tl.program_id(0).to(tl.int64), tl.arange(0, BLOCK_N).to(tl.int64)[:, None]
    h = tl.program_id(1) * BLOCK_H + tl.arange(0, BLOCK_H)
    ok = (n < N) & (h < H)[None, :]
    at = (k * N + n) * H + h[None, :]
    g, o = tl.load(grad + at, mask=ok, other=0.0), tl.load(out + at, mask=ok, other=0.0)
    d = g * (1.0 - o * o) if TANH else tl.where(o > 0.0, g, 0.0)
    tl.store(grad + at, d, mask=ok)
    tl.store(gb + k * H + h, tl.sum(d, 0), mask=h < H)


@triton.jit
def _adam(params, grads, exp_avg, exp_avg_sq, starts, steps, hyper, n, READ: tl.constexpr,
          WRITE: tl.constexpr, INC: tl.constexpr, SEGMENTS: tl.constexpr,
          BLOCK: tl.constexpr):
    i = tl.program_id(0).to(tl.int64) * BLOCK + tl.arange(0, BLOCK)
    ok = i < n
    start, size = tl.zeros([BLOCK], tl.int64), tl.zeros([BLOCK], tl.int64)
    for s in tl.static_range(SEGMENTS):      # i's parameter: its block's start and size
        lo, hi = tl.load(starts + s), tl.load(starts + s + 1)
        start, size = tl.where(i >= lo, lo, start), tl.where(i >= lo, hi - lo, size)
    online = i + start                       # each parameter's (K) online beside (K) target
    lr, wd, tau = tl.load(hyper), tl.load(hyper + 1), tl.load(hyper + 2)
    beta1, beta2, eps = tl.load(hyper + 3), tl.load(hyper + 4), tl.load(hyper + 5)
    t = tl.load(steps + READ).to(tl.float64) + INC
    p = tl.load(params + online, mask=ok, other=0.0)
    g = tl.load(grads + i, mask=ok, other=0.0) + (wd * p.to(tl.float64)).to(p.dtype)
    m = beta1.to(p.dtype) * tl.load(exp_avg + i, mask=ok, other=0.0) + (1.0 - beta1).to(
        p.dtype) * g
    v = beta2.to(p.dtype) * tl.load(exp_avg_sq + i, mask=ok, other=0.0) + (1.0 - beta2).to(
        p.dtype) * g * g
    step = (lr / (1.0 - tl.exp(t * tl.log(beta1)))).to(p.dtype)
    root = tl.sqrt(1.0 - tl.exp(t * tl.log(beta2))).to(p.dtype)
    p = p - step * m / (tl.sqrt(v) / root + eps.to(p.dtype))
    tl.store(exp_avg + i, m, mask=ok)
    tl.store(exp_avg_sq + i, v, mask=ok)
    tl.store(params + online, p, mask=ok)
    target = tl.load(params + online + size, mask=ok, other=0.0)
    tl.store(params + online + size, target + tau.to(p.dtype) * (p - target), mask=ok)
    tl.store(steps + WRITE, tl.load(steps + WRITE) + 1.0, mask=tl.program_id(0) == 0)


def _pow2(n: int) -> int:
    return triton.next_power_of_2(max(int(n), 1))


TILE = 1 << 20 if os.environ.get("TRITON_INTERPRET") == "1" else 4096
"""Elements per program of the update's kernels on a GPU: 4,096 (the normalisation's and
Adam's a quarter: no spills for sm_90, `benchmarks.gpu_budget`'s figures); under the
interpreter, which runs programs one after another at a fixed cost each, as many as memory
allows (the tiling changes no result: each sum is over the minibatch, which a program holds
whole)."""


def normalize(x: torch.Tensor, x2: torch.Tensor, normalizer: Any, out: torch.Tensor,
              clip: torch.Tensor) -> None:
    """``out (2K, N, D)`` = [normalizer(x); normalizer(x2)] for the strided minibatch views
    ``x``, ``x2 (K, N, D)`` (the same strides), in one launch. clip : (1,) float64."""
    k, n, d = x.shape
    block = min(max(1, TILE // 4 // _pow2(d)), _pow2(2 * k * n))
    _normalize[(triton.cdiv(2 * k * n, block),)](
        x, x2, x.stride(0), x.stride(1), normalizer.mean, normalizer.std, out, clip, k, n, d,
        BLOCK_R=block, BLOCK_D=_pow2(d))


def head(q: torch.Tensor, c2: torch.Tensor, w3: torch.Tensor, dc2: torch.Tensor,
         loss: torch.Tensor, acc: torch.Tensor, critic: tuple | None = None) -> None:
    """The critic's output layer backward in one launch. ``c2 (K, N, H)`` its last hidden
    layer, ``w3 (K, H, 1)``; writes ``dc2 (K, N, H)`` the loss's gradient at its input
    (before the ReLU, masked by it), ``loss (K,)`` and adds it to ``acc (K,)`` float64.
    ``critic`` None: the actor step's, q (K, N, 1) = Q(s, mu(s)), loss -mean q, dc2 = W3
    masked (unscaled, as `DDPG.update`'s); else (r, terminated, gamma (1,) float64, gw3,
    gb3, gb2): the critic step's, q (2K, N, 1) = [Q(s, a); Q'(s', mu'(s'))], loss mean
    (Q - y)^2, and the gradients of W3, b3 and b2 written."""
    k, n, h = c2.shape
    r, term, gamma, gw3, gb3, gb2 = critic if critic is not None else (q,) * 6
    if r.stride() != term.stride():
        raise ValueError(f"the reward and terminated views need the same strides (one row "
                         f"layout), got {r.stride()} and {term.stride()}")
    block_n = _pow2(n)
    block_h = max(1, min(_pow2(h), TILE // block_n))
    _head[(k, triton.cdiv(h, block_h))](
        q, r, term, r.stride(0), r.stride(1), c2, w3, dc2, gw3, gb3, gb2, loss, acc,
        gamma if critic is not None else acc, k, n, h, CRITIC=critic is not None,
        BLOCK_N=block_n, BLOCK_H=block_h)


def backward(grad: torch.Tensor, out: torch.Tensor, gb: torch.Tensor, tanh: bool) -> None:
    """An activation's backward in place and its bias's gradient, one launch: ``grad (K, N,
    H)`` becomes grad (1 - out^2) (``tanh``) or grad where out > 0 (a ReLU), ``gb (K, 1, H)``
    its sum over N. ``out`` the activation's output (K, N, H), contiguous as grad."""
    k, n, h = grad.shape
    block_n = _pow2(n)
    block_h = max(1, min(_pow2(h), TILE // block_n))
    _backward[(k, triton.cdiv(h, block_h))](grad, out, gb, n, h, TANH=tanh, BLOCK_N=block_n,
                                            BLOCK_H=block_h)


def adam(params: torch.Tensor, grads: torch.Tensor, exp_avg: torch.Tensor,
         exp_avg_sq: torch.Tensor, starts: torch.Tensor, steps: torch.Tensor,
         hyper: torch.Tensor, read: int, write: int, inc: int) -> None:
    """One network's Adam step (torch's fused kernel's arithmetic, L2 weight decay) and its
    soft target update in one launch over its flat buffers: ``grads``, ``exp_avg``,
    ``exp_avg_sq (n,)`` the online parameters', ``params (2n,)`` each parameter's online
    block beside its target's, ``starts (S + 1,)`` int64 the parameters' starts in ``grads``
    and n. hyper : (6,) float64 [lr, weight decay, tau, beta1, beta2, eps]. The step count t
    is ``steps[read] + inc``; ``steps[write]`` gains 1 (read and write differ: no program
    reads what another writes)."""
    n = grads.numel()
    block = min(TILE // 4, _pow2(n))
    _adam[(triton.cdiv(n, block),)](params, grads, exp_avg, exp_avg_sq, starts, steps, hyper,
                                    n, READ=read, WRITE=write, INC=inc,
                                    SEGMENTS=len(starts) - 1, BLOCK=block)
