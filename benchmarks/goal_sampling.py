"""Timings and sampler comparison of the regions package: ``python -m benchmarks.goal_sampling``.

Prints the time to draw goals (the issue's figure: 10,000 farbox goals with 3 joints), the cost
of one plane-clearance call on the env's (20, 6) batch of sub-step configurations, how long a
sampler takes to refuse a region it cannot reach, and the joint-space and Cartesian samplers side
by side on the paper's regions.
"""

from __future__ import annotations

import argparse
import sys
import time
import timeit
from collections.abc import Sequence

import numpy as np
from tqdm import tqdm

import regions
import ur5kin
from ddpg_her.config import Parser
from regions.samplers import CartesianSampler, JointSpaceSampler

ENV_BATCH = 20
"""Configurations per clearance call in the env: 1 kHz sub-steps of one 50 Hz control step."""


def time_goals(region: str, n_joints: int, goals: int, repeats: int, seed: int) -> list[float]:
    """Seconds to draw ``goals`` goals (the sampler built and probed beforehand)."""
    start_q = regions.default_start(region)
    sampler = JointSpaceSampler(regions.get(region), n_joints, start_q)
    out = []
    for k in range(repeats):
        rng = np.random.default_rng(seed + k)
        t0 = time.perf_counter()
        sampler.sample(goals, rng)
        out.append(time.perf_counter() - t0)
    return out


def time_clearance(calls: int, seed: int) -> dict[str, float]:
    """Microseconds per call of the clearance functions on a (20, 6) batch (best of 7)."""
    rng = np.random.default_rng(seed)
    q = np.asarray(regions.CONSTRAINED_START) + rng.normal(0.0, 0.3, (ENV_BATCH, 6))
    h = regions.DEFAULT_BASE_HEIGHT
    out = {}
    for name, func in (("plane_clear", ur5kin.plane_clear),
                       ("link_heights", ur5kin.link_heights),
                       ("capsule_heights", ur5kin.capsule_heights)):
        func(q, h)
        best = min(timeit.repeat(lambda f=func: f(q, h), number=calls, repeat=7))
        out[name] = best / calls * 1e6
    return out


UNREACHABLE = (("box:-0.2,0.2,-0.2,0.2,5,6", 3, "joint"),
               ("box:-0.2,0.2,-0.2,0.2,5,6", 3, "cartesian"),
               ("box:-0.1,0.1,-0.1,0.1,0.9,1.0", 2, "joint"))
"""Regions the samplers cannot reach (region string, joints, sampler): far above the arm, and a
box off the surface that 2 joints sweep from the constrained start (the tests' cases)."""


def time_unreachable(repeats: int) -> list[tuple[str, int, str, float]]:
    """Seconds until each :data:`UNREACHABLE` sampler raises UnreachableRegionError (best of
    ``repeats``); rows ``(region, joints, sampler, s)``."""
    classes = {"joint": JointSpaceSampler, "cartesian": CartesianSampler}
    rows = []
    for spec, n, kind in UNREACHABLE:
        best = float("inf")
        for _ in range(repeats):
            t0 = time.perf_counter()
            try:
                classes[kind](regions.parse(spec), n, regions.CONSTRAINED_START)
            except regions.UnreachableRegionError:
                best = min(best, time.perf_counter() - t0)
            else:
                raise AssertionError(f"{spec} with {n} joints was reachable")
        rows.append((spec, n, kind, best))
    return rows


def compare_samplers(joints: Sequence[int], goals: int, seed: int, progress: bool
                     ) -> list[tuple[str, int, str, float, float, float]]:
    """Acceptance, reachable fraction of the region and mean goal distance of both samplers.

    Returns rows ``(region, joints, sampler, acceptance, reachable fraction, mean distance m)``.
    """
    rows = []
    jobs = [(r, n, cls) for r in regions.PAPER_REGIONS for n in joints
            for cls in (JointSpaceSampler, CartesianSampler)]
    for name, n, cls in tqdm(jobs, desc="samplers", disable=not progress, file=sys.stderr):
        start_q = regions.default_start(name)
        sampler = cls(regions.get(name), n, start_q)
        batch = sampler.sample(goals, np.random.default_rng(seed))
        origin = ur5kin.fk_world(start_q, regions.DEFAULT_BASE_HEIGHT)
        distance = float(np.linalg.norm(batch.goals - origin, axis=1).mean())
        rows.append((name, n, cls.kind, batch.acceptance, batch.reachable_fraction, distance))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m benchmarks.goal_sampling``."""
    parser = Parser(
        prog="python -m benchmarks.goal_sampling", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--goals", type=int, default=10_000,
                        help="goals per timed draw and per sampler comparison row")
    parser.add_argument("--repeats", type=int, default=5, help="timed draws (report min/median)")
    parser.add_argument("--calls", type=int, default=2000,
                        help="clearance calls per timing repeat")
    parser.add_argument("--joints", nargs="+", type=int, default=[3, 6],
                        help="joint counts of the sampler comparison (>= 3: the Cartesian "
                        "sampler needs a volume)")
    parser.add_argument("--seed", type=int, default=0, help="seed of every generator")
    parser.add_argument("--skip-comparison", action="store_true",
                        help="time only; skip the sampler comparison (about a minute)")
    args = parser.parse_args(argv)
    if any(n < CartesianSampler.MIN_JOINTS or n > 6 for n in args.joints):
        parser.error(f"--joints must lie in 3..6; got {args.joints}")

    times = time_goals("farbox", 3, args.goals, args.repeats, args.seed)
    print(f"{args.goals} farbox goals, 3 joints, joint-space sampler: min {min(times):.3f} s, "
          f"median {float(np.median(times)):.3f} s over {args.repeats} draws")
    costs = time_clearance(args.calls, args.seed)
    print(f"clearance on a ({ENV_BATCH}, 6) batch: " + ", ".join(
        f"{name} {us:.1f} us" for name, us in costs.items()))
    for spec, n, kind, seconds in time_unreachable(args.repeats):
        print(f"unreachable {spec}, {n} joints, {kind} sampler: refused in {seconds:.3f} s")
    if not args.skip_comparison:
        print("\nregion         n  sampler      acceptance  reachable  mean dist m")
        for name, n, kind, acc, reach, dist in compare_samplers(
                args.joints, args.goals, args.seed, sys.stderr.isatty()):
            print(f"{name:<14} {n}  {kind:<11}  {acc:>10.4f}  {reach:>9.4f}  {dist:>11.3f}")
        print("\nacceptance: goals per proposal (joint configurations, or points of the region's "
              "box); reachable: goals per proposal inside the region (Cartesian: the reachable "
              "fraction of the region's volume); mean dist: from the start's tool0")
    return 0


if __name__ == "__main__":
    sys.exit(main())
