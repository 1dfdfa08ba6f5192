"""How far the joints the agent does not control move: ``held_joints`` pd against locked.

    python examples/held_joints_swing.py [--episodes 20] [--joints 3] [--seed 0]

Random actions (uniform in the action box, the warm-up's) on ``UR5Reach-v0`` for each region
and hold; per episode, the largest deviation (rad) of joints n+1..6 from their start angles and
the largest displacement (m) of tool0 that this deviation causes (tool0 at the episode's angles
against tool0 with the held joints put back at the start). Prints the median and maximum over
episodes, and the share of episodes in which that displacement exceeds the 0.1 m success
radius. The recorded output is in results/held_joints/README.md.
"""

from __future__ import annotations

import argparse

import gymnasium
import numpy as np

import envs  # noqa: F401  (registers UR5Reach-v0)
import ur5kin


def swing(region: str, held: str, joints: int, episodes: int, seed: int
          ) -> tuple[np.ndarray, np.ndarray]:
    """Per episode: peak held-joint deviation (rad) and peak tool0 displacement it causes (m)."""
    env = gymnasium.make("UR5Reach-v0", region=region, n_joints=joints, held_joints=held)
    env.action_space.seed(seed)
    start = np.asarray(env.unwrapped.task.start_q)
    dev, shift = np.zeros(episodes), np.zeros(episodes)
    for e in range(episodes):
        env.reset(seed=seed + e)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            done = terminated or truncated
            q = env.unwrapped.joint_angles
            put_back = np.concatenate([q[:joints], start[joints:]])
            dev[e] = max(dev[e], np.abs(q[joints:] - start[joints:]).max())
            shift[e] = max(shift[e], float(np.linalg.norm(ur5kin.fk(q) - ur5kin.fk(put_back))))
    return dev, shift


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python examples/held_joints_swing.py",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=20,
                        help="episodes per region and hold, >= 1 (default: %(default)s)")
    parser.add_argument("--joints", type=int, default=3,
                        help="controlled joints n, 2..5 (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the first episode, >= 0 (default: %(default)s)")
    args = parser.parse_args(argv)
    if not 2 <= args.joints <= 5 or args.episodes < 1:
        parser.error("--joints must be 2..5 (6 holds no joint) and --episodes >= 1")
    print(f"{'region':14s} {'held':7s} {'median dev':>10s} {'max dev':>8s} "
          f"{'median shift':>12s} {'max shift':>9s} {'shift > 0.1 m':>13s}")
    for region in ("unconstrained", "zheight"):
        for held in ("pd", "locked"):
            dev, shift = swing(region, held, args.joints, args.episodes, args.seed)
            print(f"{region:14s} {held:7s} {np.median(dev):8.3f} rad {dev.max():4.2f} rad "
                  f"{np.median(shift):10.3f} m {shift.max():7.3f} m "
                  f"{np.mean(shift > 0.1):12.0%}")


if __name__ == "__main__":
    main()
