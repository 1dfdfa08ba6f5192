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
            if x.dtype.element_ty == tl.float32:
                y = tl.math.div_rn(y, s)
            else:
                y = y / s
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
