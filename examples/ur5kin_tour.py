"""A short tour of ur5kin: where the paper's start poses put tool0, IK round trips, batched FK.

    python examples/ur5kin_tour.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import ur5kin

BASE_HEIGHT = 0.1
"""Height (m) of base_link above the ground plane in the task world (docs/design.md)."""

START_POSES = {
    "unconstrained start": np.zeros(6),
    "constrained start": np.array([0.0, -np.pi / 4, np.pi / 2, 0.0, 0.0, 0.0]),
}
"""The two start configurations of docs/design.md (rad)."""


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python examples/ur5kin_tour.py", description=__doc__)
    parser.add_argument("--batch", type=int, default=200_000,
                        help="configurations in the batched-FK timing (count)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random configurations")
    args = parser.parse_args(argv)
    if args.batch < 1:
        parser.error(f"--batch must be positive; got {args.batch}")

    print(f"UR5 model: {ur5kin.urdf_path()}")
    for name, q in START_POSES.items():
        p = ur5kin.fk(q) + np.array([0.0, 0.0, BASE_HEIGHT])
        print(f"{name:<20} q = {np.round(q, 4)} rad -> tool0 at {np.round(p, 4)} m (world)")

    rng = np.random.default_rng(args.seed)
    q = rng.uniform(-np.pi, np.pi, 6)
    pose = ur5kin.fk_pose(q)
    solutions = ur5kin.ik(pose)
    worst = max(np.abs(ur5kin.fk_pose(s) - pose).max() for s in solutions)
    print(f"IK of a random pose: {len(solutions)} solutions, worst pose error {worst:.1e}")

    batch = rng.uniform(-np.pi, np.pi, (args.batch, 6))
    start = time.perf_counter()
    ur5kin.fk(batch)
    elapsed = time.perf_counter() - start
    print(f"batched FK: {args.batch:,} configurations in {elapsed * 1e3:.1f} ms "
          f"({args.batch / elapsed / 1e6:.1f} M/s); python -m benchmarks.fk_paths compares all "
          "paths")


if __name__ == "__main__":
    main()
