"""Replay a trained policy in 3D: the UR5 reaching for N goals of its task, in the browser.

    python -m analysis.replay runs/demo --episodes 10 --out replay.html
    python -m analysis.replay runs/demo --episodes 5 --serve

The run's policy at its latest checkpoint (``ddpg_her.load``) acts deterministically, as in a
test session, on N goals of the run's own task (the env of its ``spec.json``, goals drawn by
its sampler from ``--seed``). The page shows the UR5's meshes, the ground plane, the goal region
as what it is (a box, a z-limit cut to the reach ball, a mesh), each goal's success ball
(radius: the task's success radius) green where reached and red where missed, the tool's path
of each episode, and the episodes one after another at the control rate (50 Hz: real time),
with the viewer's play, pause and time controls ("Open Controls", then Animations). The page is
one self-contained HTML file that opens offline; ``--serve`` shows the same scene live on a
local MeshCat server instead.
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from analysis.outputs import add_force, check_writable, usage_errors, write_errors
from ddpg_her.config import Parser
from ur5kin.checks import SEED, integer

SUPPORTED_ENV_IDS = ("UR5Reach-v0",)
"""Env ids whose runs can be replayed: the UR5 goal env, whose arm this module draws."""

HOLD_S = 0.5
"""Time (s) each episode's last pose stays on screen before the next episode starts."""

DEFAULT_EPISODES = 10
"""Episodes replayed by default."""

MAX_EPISODES = 200
"""Most episodes one page holds (the animation grows by about 60 kB per episode)."""


class ReplayError(ValueError):
    """A run folder that cannot be replayed; the message names the folder and why."""


@dataclass(frozen=True)
class Episode:
    """One replayed episode.

    Attributes
    ----------
    goal : (3,) float, m, world frame
    q : (T + 1, 6) float, rad
        All six joint angles after reset and after each of the T steps.
    tool : (T + 1, 3) float, m, world frame
        tool0's position (the achieved goal) at the same instants.
    reached : bool
        The episode ended in success (``info["is_success"]`` of its last step, as a test
        session counts it).
    """

    goal: np.ndarray
    q: np.ndarray
    tool: np.ndarray
    reached: bool

    @property
    def steps(self) -> int:
        """Control steps T of the episode."""
        return len(self.q) - 1


def check_run(run_dir: pathlib.Path) -> dict[str, Any]:
    """The run's ``spec.json``, after checking that the folder can be replayed (no torch).

    Raises
    ------
    ReplayError
        When the folder does not exist, is not a run folder, holds no checkpoint (no trained
        weights), or is a run of an env other than :data:`SUPPORTED_ENV_IDS`.
    """
    from ddpg_her.runfolder import RunFolder, RunFolderError

    if not run_dir.is_dir():
        raise ReplayError(f"{run_dir} is not a folder (expected a run folder of "
                          "python -m ddpg_her.train)")
    folder = RunFolder(run_dir)
    try:
        spec = folder.read_spec()
    except RunFolderError as err:
        raise ReplayError(str(err)) from err
    env_id = spec.get("env_id")
    if env_id not in SUPPORTED_ENV_IDS:
        raise ReplayError(f"{run_dir} is a run of env {env_id!r}; only runs of "
                          f"{', '.join(SUPPORTED_ENV_IDS)} can be replayed (the UR5 is drawn)")
    if not folder.checkpoints():
        raise ReplayError(f"{run_dir} has no checkpoint, so no trained weights to replay (it "
                          "holds only what a finished run keeps for its curves, or the run has "
                          "not reached its first test session)")
    return spec


def episode_seeds(seed: int, episodes: int) -> list[int]:
    """The env seeds of the replayed episodes: one per episode, from ``seed`` alone."""
    return [int(s) for s in np.random.SeedSequence(seed).generate_state(episodes)]


def rollout(policy: Any, seeds: Sequence[int], progress: bool = True
            ) -> tuple[Any, list[Episode]]:
    """Run the policy deterministically for one episode per seed in a fresh env of its run.

    Returns the task (``envs.TaskSpec``) and the episodes.
    """
    from tqdm import tqdm

    env = policy.make_env()
    base = env.unwrapped
    out = []
    try:
        for seed in tqdm(seeds, desc="episodes", unit="episode", disable=not progress,
                         file=sys.stderr):
            obs, info = env.reset(seed=seed)
            qs, tools = [base.joint_angles.copy()], [obs["achieved_goal"].copy()]
            done = False
            while not done:
                obs, _, terminated, truncated, info = env.step(policy(obs))
                qs.append(base.joint_angles.copy())
                tools.append(obs["achieved_goal"].copy())
                done = terminated or truncated
            out.append(Episode(obs["desired_goal"].copy(), np.array(qs), np.array(tools),
                               bool(info["is_success"])))  # of the last step
    finally:
        env.close()
    return base.task, out


def draw(scene: Any, task: Any, episodes: Sequence[Episode], meshes: str) -> Any:
    """Draw the task and the episodes into ``scene`` (an ``analysis.scene.Scene``) and animate
    them: episode i's goal appears as it starts, its path as it ends. Returns the timeline."""
    import regions
    from analysis.scene import MISSED_COLOUR, REACHED_COLOUR, REGION_COLOURS, Timeline

    region = regions.parse(task.region, task.base_height)
    scene.setup(target=_look_at(region, task.base_height))
    scene.ground()
    scene.region(region, "region", REGION_COLOURS[0][0])
    arm = scene.arm("arm", episodes[0].q[0] if episodes else task.start_q, meshes)
    timeline = Timeline(task.control_hz)
    hold = round(HOLD_S * task.control_hz)
    frame = 0
    for i, ep in enumerate(episodes):
        colour = REACHED_COLOUR if ep.reached else MISSED_COLOUR
        goal, path = f"goals/{i:03d}", f"paths/{i:03d}"
        scene.goal(goal, ep.goal, task.success_radius, ep.reached)
        scene.path(path, ep.tool, colour)
        timeline.poses(scene.vis, arm, frame, ep.q)
        end = frame + ep.steps
        timeline.poses(scene.vis, arm, end + hold, ep.q[-1:])  # hold the last pose
        for name, shown_from in ((goal, frame), (path, end)):
            if shown_from > 0:
                timeline.visible(scene.vis, name, 0, False)
            timeline.visible(scene.vis, name, shown_from, True)
        frame = end + hold + 1
    timeline.play(scene.vis)
    return timeline


def _look_at(region: Any, base_height: float) -> tuple[float, float, float]:
    """A point (m, world frame) between the robot base and the region's middle."""
    from analysis.scene import region_mesh

    centre = np.asarray(region_mesh(region, base_height).bounds).mean(axis=0)
    return tuple(float(x) for x in 0.5 * (centre + np.array([0.0, 0.0, base_height])))


def summary(run_dir: pathlib.Path, policy: Any, task: Any, episodes: Sequence[Episode],
            seed: int) -> str:
    """What the page shows, in two lines (its caption and the command's output)."""
    reached = sum(ep.reached for ep in episodes)
    return (f"{run_dir.name}: {task.region}, {task.n_joints} joints, episode {policy.episode}; "
            f"{reached} of {len(episodes)} goals reached (seed {seed})\n"
            f"green: reached within {task.success_radius} m; red: missed; lines: tool0 paths; "
            f"{task.control_hz} Hz, real time")


def serve_until_stopped(announce: str) -> None:
    """Print ``announce``, then wait until Ctrl-C or SIGTERM and return. MeshCat ends its server
    subprocess at a normal exit of this process only (an exit hook), so SIGTERM is turned into
    one: a terminated ``--serve`` would otherwise leave the server listening. The handler is in
    place before the address is printed: a SIGTERM sent as soon as it is read also ends cleanly."""
    import signal

    def stop(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        print(announce, flush=True)
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)


def build_parser() -> argparse.ArgumentParser:
    """The command line; every flag's help gives its unit or range."""
    parser = Parser(
        prog="python -m analysis.replay", description=__doc__.split("\n\n")[0],
        epilog="Pages hold the arm's collision meshes by default (about 1.3 MB for 10 "
        "episodes, most of it the viewer's script); --meshes visual embeds the COLLADA visual "
        "meshes (about 10 MB).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("run", type=pathlib.Path, metavar="RUN_DIR",
                        help="run folder of python -m ddpg_her.train (spec.json and a "
                        "checkpoint) of a UR5Reach-v0 task")
    parser.add_argument("--episodes", type=integer(1, MAX_EPISODES).read, default=DEFAULT_EPISODES,
                        help=f"episodes replayed, one goal each, 1..{MAX_EPISODES}")
    parser.add_argument("--seed", type=SEED.read, default=0,
                        help="seed of the goals, >= 0 (the episodes' env seeds derive from it)")
    parser.add_argument("--episode", type=int, default=None,
                        help="training episode of the checkpoint whose policy acts; None: the "
                        "latest")
    parser.add_argument("--out", type=pathlib.Path, default=pathlib.Path("replay.html"),
                        metavar="FILE.html", help="the page written (ignored with --serve)")
    parser.add_argument("--serve", action="store_true",
                        help="show the scene live on a local MeshCat server (a subprocess; "
                        "open the printed address, Ctrl-C ends it) instead of writing --out")
    parser.add_argument("--meshes", choices=("collision", "visual"), default="collision",
                        help="the arm's meshes: the URDF's collision meshes (5,300 triangles, "
                        "about 100 kB in the page) or its COLLADA visual meshes (96,000 "
                        "triangles, about 9 MB; MeshCat 0.3.2 leaves part of the shoulder out)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_force(parser, "replace an --out that holds something other than a viewer page (refused "
              "by default: nothing is written, the file is named)")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m analysis.replay``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    with usage_errors(parser, ReplayError):
        check_run(args.run)
    if not args.serve:
        with usage_errors(parser):  # before the rollout, which takes minutes
            check_writable(args.out, "--out")
    from analysis import scene as scenes

    with usage_errors(parser, ImportError):
        scenes.meshcat_module()
    import ddpg_her

    try:
        policy = ddpg_her.load(args.run, episode=args.episode)
    except (FileNotFoundError, ValueError) as err:
        parser.error(f"{args.run}: {err}")
    progress = not args.no_progress and sys.stderr.isatty()
    task, episodes = rollout(policy, episode_seeds(args.seed, args.episodes), progress)
    text = summary(args.run, policy, task, episodes, args.seed)
    vis = scenes.live_visualizer() if args.serve else scenes.offline_visualizer()
    scene = scenes.Scene(vis, task.base_height)
    draw(scene, task, episodes, args.meshes)
    print(text)
    if args.serve:
        serve_until_stopped(f"serving at {vis.url()} (Ctrl-C ends it)")
        return 0
    with write_errors(parser, args.force):  # a viewer page over a viewer page is no refusal
        size = scene.write_html(args.out, f"UR5 replay: {args.run.name}", text)
    print(f"-> {args.out} ({size / 1e6:.1f} MB)", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
