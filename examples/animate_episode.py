"""Write an animation of one UR5Reach-v0 episode (side and top views) to a GIF or PNG frames.

The arm is driven by a scripted reacher: analytic position IK (``ur5kin.ik_position``) for joints
1-3 with the wrist at its start angles, taking the plane-clear solution nearest the current
angles; with 2 joints, where IK does not apply, by random actions.

    python examples/animate_episode.py --region farbox --joints 3 --out episode.gif
"""

from __future__ import annotations

import argparse
import importlib.util
import pathlib

import gymnasium
import numpy as np

import envs  # noqa: F401  (registers UR5Reach-v0)
import regions
import ur5kin


def ik_action(env: gymnasium.Env, goal: np.ndarray) -> np.ndarray | None:
    """Joint targets (n,) rad that put tool0 on ``goal`` (m, world), or None if none is clear."""
    task = env.unwrapped.task
    if task.n_joints < 3:
        return None
    q_now = env.unwrapped.joint_angles
    wrist = np.asarray(task.start_q[3:])
    target = ur5kin.to_base(goal, task.base_height)
    q, valid = ur5kin.ik_position(target, wrist)
    valid &= ur5kin.plane_clear(np.nan_to_num(q), task.base_height)
    if not valid.any():
        return None
    candidates = q[valid]
    best = candidates[np.argmin(np.abs(candidates - q_now).sum(axis=1))]
    return best[: task.n_joints]


def record(env: gymnasium.Env, steps: int, seed: int) -> tuple[list[np.ndarray], bool]:
    """Frames ``(H, W, 3) uint8`` of one episode (at most ``steps`` steps) and its success."""
    obs, _ = env.reset(seed=seed)
    frames = [env.render()]
    rng = np.random.default_rng(seed)
    action = ik_action(env, obs["desired_goal"])
    success = False
    for _ in range(steps):
        step = action if action is not None else rng.uniform(env.action_space.low,
                                                             env.action_space.high)
        obs, _, terminated, truncated, info = env.step(step)
        frames.append(env.render())
        success = bool(info["is_success"])
        if terminated or truncated:
            break
    return frames, success


def save(frames: list[np.ndarray], out: pathlib.Path, fps: float) -> pathlib.Path:
    """A GIF through matplotlib's PillowWriter when pillow is installed, else numbered PNGs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if importlib.util.find_spec("PIL") is not None and out.suffix.lower() == ".gif":
        from matplotlib.animation import FuncAnimation, PillowWriter

        height, width = frames[0].shape[:2]
        fig = plt.figure(figsize=(width / 100, height / 100), dpi=100)
        ax = fig.add_axes((0, 0, 1, 1))
        ax.axis("off")
        image = ax.imshow(frames[0])
        animation = FuncAnimation(fig, lambda i: [image.set_data(frames[i])],
                                  frames=len(frames))
        animation.save(str(out), writer=PillowWriter(fps=fps))
        plt.close(fig)
        return out
    folder = out.with_suffix("")
    folder.mkdir(parents=True, exist_ok=True)
    for i, frame in enumerate(frames):
        plt.imsave(folder / f"frame_{i:04d}.png", frame)
    return folder


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--region", default="farbox",
                        help=f"goal region: {regions.spec_help()}")
    parser.add_argument("--joints", dest="n_joints", type=int, default=3,
                        help="controlled joints 2-6 (the others are held at the start angles)")
    parser.add_argument("--steps", type=int, default=100,
                        help="most control steps to record (each 0.02 s of simulated time)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the episode's goal (reset(seed=...)) and random actions")
    parser.add_argument("--fps", type=float, default=25.0,
                        help="frames per second of the animation (50 is real time)")
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("episode.gif"),
                        help="output .gif (needs pillow); another suffix, or no pillow, writes "
                        "PNG frames into a folder of that name")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.steps < 1 or args.fps <= 0:
        raise SystemExit("--steps must be >= 1 and --fps > 0")
    env = gymnasium.make("UR5Reach-v0", region=args.region, n_joints=args.n_joints,
                         render_mode="rgb_array")
    frames, success = record(env, args.steps, args.seed)
    env.close()
    written = save(frames, args.out, args.fps)
    print(f"{len(frames)} frames, goal {'reached' if success else 'not reached'}: {written}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
