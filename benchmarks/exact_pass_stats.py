"""``python -m benchmarks.exact_pass_stats``: how often the arm kernels need the exact plane
heights, with random actions, for the Triton kernel's cost model (issue 42).

The numba kernel's control step (:func:`envs.physics.numba_kernel.step_copy`) replayed in
Python around its own compiled helpers (placements, gravity torque, ABA, link heights), so that
every substep's Lipschitz test can be counted: per copy, per block of 1..32 copies (the Triton
kernel takes the exact pass for a block when one of its lanes needs it), and per link. The
copies cycle through eight tasks (2..6 joints, the unconstrained start pose and the
constrained regions'); each draws a uniform action in its task's box every step, and every 100
steps (an episode) goes back to its start pose. ``--rule all`` is the rule before issue 42
(all six exact heights when one link's bound fails), ``per-link`` today's (only the failing
links'; the others keep their bound). One JSON object on stdout:

    python -m benchmarks.exact_pass_stats --copies 55 --steps 100 --rule per-link
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from ddpg_her.config import Parser

GRID = [("unconstrained", 2), ("zheight", 3), ("closebox", 6), ("unconstrained", 5),
        ("farbox", 4), ("unconstrained", 6), ("zheight", 6), ("unconstrained", 3)]
"""(region, n_joints) of the copies, in turn (tests/test_stack_dynamics.py's grid)."""

BLOCKS = (1, 4, 8, 16, 32)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = Parser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--copies", type=int, default=55, help="copies, >= 1 (default 55)")
    parser.add_argument("--steps", type=int, default=100,
                        help="control steps, >= 1; an episode is 100 (default 100)")
    parser.add_argument("--rule", choices=("per-link", "all"), default="per-link",
                        help="which exact heights a failed bound takes (default per-link)")
    parser.add_argument("--seed", type=int, default=0, help="the actions' seed (default 0)")
    args = parser.parse_args(argv)
    if args.copies < 1 or args.steps < 1:
        parser.error(f"--copies and --steps must be >= 1; got {args.copies}, {args.steps}")
    return args


def measure(copies: int, steps: int, per_link: bool, seed: int) -> dict:
    from envs.physics import numba_kernel as nk
    from envs.physics.model import arm_model, rest_heights, ur5_plane
    from envs.spec import TaskSpec
    from envs.task import action_bounds

    tasks = [TaskSpec(region=r, n_joints=n) for r, n in GRID] * (copies // len(GRID) + 1)
    tasks = tasks[:copies]
    arm = arm_model(TaskSpec(n_joints=6))
    ch, pl, first = arm.chain, ur5_plane("float64"), tasks[0]
    free = np.array([t.n_joints for t in tasks])
    gain = np.where(np.arange(6)[None] >= free[:, None], 0.0, arm.command_gain)
    box = [action_bounds(t) for t in tasks]
    low = np.array([np.pad(np.asarray(lo, float), (0, 6 - len(lo))) for lo, _ in box])
    high = np.array([np.pad(np.asarray(hi, float), (0, 6 - len(hi))) for _, hi in box])
    R, vel, acc, cb, pA, U, IA, X, Y, D, u, force = nk._aba_scratch(np.float64)
    g, a, heights, feat = np.empty(6), np.empty(6), np.empty(6), np.empty(13)
    rng = np.random.default_rng(seed)
    fails = np.zeros((steps, first.substeps, copies, 6), bool)
    for step in range(steps):
        if step % 100 == 0:
            q = np.array([t.start_q for t in tasks], float)
            w = np.zeros((copies, 6))
            known = np.array([rest_heights(t, t.start_q) for t in tasks])
        bias = gain * rng.uniform(low, high)
        for b in range(copies):
            qb, wb, kb, q_ref = q[b], w[b], known[b], q[b].copy()
            for s in range(first.substeps):
                nk.placements(qb, ch.rotation, ch.axis, R)
                nk._gravity_torque(R, ch.translation, ch.axis, ch.inertia, ch.gravity, acc,
                                   force, g)
                tau = np.clip(bias[b] - arm.kp_eff * qb - arm.kd_eff * wb + g, -arm.effort,
                              arm.effort)
                nk._aba(R, ch.translation, ch.axis, ch.inertia, ch.armature, ch.gravity, wb,
                        tau, vel, cb, IA, pA, U, D, u, X, Y, acc, a, free[b])
                w1 = np.clip(wb + a, -arm.w_max, arm.w_max)
                q1 = qb + w1
                limit = (np.abs(q1 - arm.q_mid) > arm.q_half).any()
                bound = kb - np.abs(q1 - q_ref) @ pl.lipschitz
                fail = bound < first.plane_margin
                fails[step, s, b] = fail
                plane = False
                if fail.any():
                    nk.copy_link_heights(q1, pl.vertex_heights, pl.bounds, pl.lift_offset,
                                         pl.wrist_offset, first.base_height, feat, heights)
                    counted = fail if per_link else np.ones(6, bool)
                    kb[:] = np.where(counted, heights, bound)
                    plane = (counted & (heights < first.plane_margin)).any()
                    q_ref = q1.copy()
                if plane or limit:
                    wb[:] = 0
                    break
                qb[:], wb[:] = q1, w1
            kb -= np.abs(qb - q_ref) @ pl.lipschitz
    need = fails.any(-1)
    out = {"copies": copies, "steps": steps, "rule": "per-link" if per_link else "all",
           "seed": seed}
    for block in BLOCKS:
        nb = -(-copies // block)
        padded = np.zeros((steps, first.substeps, nb * block, 6), bool)
        padded[:, :, :copies] = fails
        blocks = padded.reshape(steps, first.substeps, nb, block, 6).any(3)
        out[f"block_{block}"] = {"exact_pass": round(float(blocks.any(-1).mean()), 3),
                                 "per_link": blocks.mean((0, 1, 2)).round(3).tolist()}
    out["per_copy"] = round(float(need.mean()), 3)
    return out


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    print(json.dumps(measure(args.copies, args.steps, args.rule == "per-link", args.seed)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
