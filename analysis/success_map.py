"""Success maps: where in a slice of the workspace a trained policy reaches its goals.

    python -m analysis.success_map RUN [RUN...] --goals 10000 --z 0.7 0.8 --out map.png

Goals are drawn as the run's task draws them (its region and goal sampler, joints 1..n uniform
for the paper's sampler), conditioned on the height slice ``z0 <= z <= z1``; the run's
deterministic policy then runs one episode per goal, many copies at once in the batched env.
Successes are binned on a square grid of the slice's (x, y), with one colour scale (0-100 %) for
every map so that maps of several runs compare directly. Every run sees the same goals. The
numbers of every cell go to a CSV beside the figure.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from analysis import outputs
from ddpg_her.config import Parser
from ur5kin.checks import COUNT, SEED, number

WORKSPACE_REACH_M = 1.1
"""A bound (m) on tool0's distance from the shoulder axis (the reach ball's radius is under it):
a slice of the workspace is at most twice this wide in x and y."""

GOAL_BYTES = 64
"""Memory per goal of a map (its position, configuration and outcome), a bound."""

CELL_BYTES = 48
"""Memory per grid cell of a map (two histograms, the rate, numpy's temporaries), a bound."""

CELL = 0.1
"""Default edge (m) of the grid cells: the paper's "coarse tiling"."""

BATCH = 1000
"""Episodes run at once in the batched env (copies)."""

MAPPED_ENV_IDS = ("UR5Reach-v0",)
"""Env ids whose runs can be mapped: the maps roll the policy out in the UR5 env of the run's
task record (a run of another env has another task, or none)."""

CSV_COLUMNS = ("run", "x_min_m", "x_max_m", "y_min_m", "y_max_m", "goals", "successes",
               "success_rate")


@dataclass(frozen=True)
class SuccessMap:
    """Success counts of one run on a grid of the slice."""

    run: str
    x_edges: np.ndarray
    """(nx + 1,) m, world frame."""
    y_edges: np.ndarray
    """(ny + 1,) m, world frame."""
    goals: np.ndarray
    """(nx, ny) int: goals per cell."""
    successes: np.ndarray
    """(nx, ny) int: goals reached per cell."""

    @property
    def rate(self) -> np.ndarray:
        """(nx, ny) float in [0, 1]; NaN where a cell has no goal."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.goals > 0, self.successes / self.goals, np.nan)


def slice_goals(task, count: int, z: tuple[float, float], seed: int) -> np.ndarray:
    """``count`` goals (m, world frame) of ``task``'s sampler, conditioned on the z slice."""
    import regions
    from envs.task import task_sampler

    base = task_sampler(task)
    sliced = regions.Intersection((base.region, regions.ZLimit(z[0], z[1], name="slice")),
                                  name=f"{base.region.name}&z[{z[0]},{z[1]}]")
    sampler = type(base)(sliced, base.n_joints, base.start_q, base.base_height, base.limits)
    return sampler.sample(count, np.random.default_rng(seed)).goals


def evaluate(policy, task, goals: np.ndarray, batch: int, label: str = "",
             progress: bool = True) -> np.ndarray:
    """Run one deterministic episode per goal; ``(len(goals),) bool``: the goal was reached."""
    from gymnasium.vector import AutoresetMode
    from tqdm import tqdm

    import envs

    env = envs.BatchedReach(min(batch, len(goals)), task=task,
                            autoreset_mode=AutoresetMode.DISABLED)
    reached = np.zeros(len(goals), dtype=bool)
    with tqdm(total=len(goals), desc=f"episodes {label}", disable=not progress, file=sys.stderr,
              unit="goal") as bar:
        for start in range(0, len(goals), env.num_envs):
            chunk = goals[start : start + env.num_envs]
            m = len(chunk)
            padded = np.concatenate([chunk, np.repeat(chunk[-1:], env.num_envs - m, axis=0)])
            obs, info = env.reset(seed=start, options={"goal": padded})
            hit = np.asarray(info["is_success"], dtype=bool).copy()
            for _ in range(task.max_episode_steps):
                if hit[:m].all():
                    break
                obs, _, _, _, info = env.step(policy(obs))
                hit |= np.asarray(info["is_success"], dtype=bool)
            reached[start : start + m] = hit[:m]
            bar.update(m)
    env.close()
    return reached


def bin_successes(run: str, goals: np.ndarray, reached: np.ndarray, cell: float) -> SuccessMap:
    """Histogram goals and successes on square cells of edge ``cell`` (m) aligned to 0."""
    lo = np.floor(goals[:, :2].min(axis=0) / cell) * cell
    hi = np.ceil(goals[:, :2].max(axis=0) / cell) * cell
    x_edges = np.arange(lo[0], hi[0] + cell / 2, cell)
    y_edges = np.arange(lo[1], hi[1] + cell / 2, cell)
    total, _, _ = np.histogram2d(goals[:, 0], goals[:, 1], bins=(x_edges, y_edges))
    hits, _, _ = np.histogram2d(goals[reached, 0], goals[reached, 1], bins=(x_edges, y_edges))
    return SuccessMap(run, x_edges, y_edges, total.astype(int), hits.astype(int))


def plot(maps: Sequence[SuccessMap], z: tuple[float, float], out: Path) -> None:
    fig, axes = outputs.pyplot().subplots(1, len(maps), squeeze=False, sharey=True,
                                          figsize=(4.6 * len(maps) + 0.8, 4.4))
    image = None
    for ax, m in zip(axes[0], maps, strict=True):
        image = ax.pcolormesh(m.x_edges, m.y_edges, 100.0 * m.rate.T, cmap="viridis", vmin=0.0,
                              vmax=100.0, shading="flat")
        overall = 100.0 * m.successes.sum() / max(m.goals.sum(), 1)
        ax.set_title(f"{m.run}\n{overall:.0f} % of {m.goals.sum():,} goals", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_aspect("equal")
        ax.plot(0.0, 0.0, "ks", ms=5)
    axes[0, 0].set_ylabel("y (m)")  # one label: the maps share their y axis
    fig.colorbar(image, ax=axes[0].tolist(), label="goals reached (%)", shrink=0.85)
    fig.suptitle(f"Success by goal position, {z[0]} <= z <= {z[1]} m (world frame)", fontsize=10)
    outputs.save_figure(fig, out, dpi=120, bbox_inches="tight")


def csv_rows(maps: Sequence[SuccessMap]) -> list[list[Any]]:
    """The rows of :data:`CSV_COLUMNS`: one per cell of every map."""
    rows = []
    for m in maps:
        rate = m.rate
        for i, j in np.ndindex(m.goals.shape):  # (nx, ny): x_edges and y_edges less one each
            rows.append([m.run, round(m.x_edges[i], 6), round(m.x_edges[i + 1], 6),
                         round(m.y_edges[j], 6), round(m.y_edges[j + 1], 6),
                         int(m.goals[i, j]), int(m.successes[i, j]),
                         "" if np.isnan(rate[i, j]) else round(float(rate[i, j]), 6)])
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(
        prog="python -m analysis.success_map", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("runs", nargs="+", metavar="RUN",
                        help="run folders (with spec.json and a checkpoint); several runs get "
                             "side-by-side maps on the same goals")
    parser.add_argument("--goals", type=COUNT.read, default=10_000, help="goals per run (count)")
    parser.add_argument("--z", type=number(note="m").read, nargs=2, default=(0.7, 0.8),
                        metavar=("Z0", "Z1"), help="height slice of the goals (m, world frame)")
    parser.add_argument("--cell", type=number(0, above=True, note="m").read, default=CELL,
                        help="grid cell edge (m)")
    parser.add_argument("--seed", type=SEED.read, default=0, help="seed of the goals")
    parser.add_argument("--episode", type=int, default=None,
                        help="checkpoint episode of the policy (default: the latest)")
    parser.add_argument("--batch", type=COUNT.read, default=BATCH,
                        help="episodes run at once in the batched env (copies)")
    parser.add_argument("--out", type=Path, default=Path("success_map.png"),
                        help="figure file; the CSV goes beside it")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    outputs.add_force(parser)
    args = parser.parse_args(argv)
    # what a map holds: its goals and outcomes per run, and its grid (two histograms and the
    # rate per cell over the slice, at most the reach ball's diameter wide)
    cells = math.ceil(2 * WORKSPACE_REACH_M / args.cell) ** 2
    need = len(args.runs) * args.goals * GOAL_BYTES + len(args.runs) * cells * CELL_BYTES
    have = outputs.available_bytes()
    if have is not None and need > have:
        parser.error(f"--goals {args.goals} and --cell {args.cell} m would need about "
                     f"{need / 2 ** 30:.3g} GiB ({args.goals} goals and {cells:.3g} grid cells "
                     f"per run), more than the {have / 2 ** 30:.3g} GiB of memory available")
    out, csv_path = outputs.figure_outputs(parser, args.out, "--out", ".csv")  # before any rollout
    z = (min(args.z), max(args.z))
    if z[0] == z[1]:
        parser.error(f"--z needs two different heights; got {args.z}")

    import ddpg_her
    from ddpg_her.runfolder import RunFolder

    for run in args.runs:  # before loading: load makes the run's env, which may not be ours
        with outputs.usage_errors(parser, ValueError):
            env_id = RunFolder(run).read_spec().get("env_id")
        if env_id not in MAPPED_ENV_IDS:
            parser.error(f"{run} is a run of env {env_id!r}; only runs of "
                         f"{', '.join(MAPPED_ENV_IDS)} can be mapped")
    with outputs.usage_errors(parser, FileNotFoundError, ValueError):  # load checks the run's env
        policies = [ddpg_her.load(run, episode=args.episode) for run in args.runs]
    tasks = [p.task for p in policies]  # the task of the env the policy was trained on
    if len({(t.region, t.n_joints, t.start_q, t.base_height, t.goal_sampler) for t in tasks}) > 1:
        parser.error("the runs have different tasks (region, joints, start, sampler); maps of "
                     "one figure must share their goals")
    try:
        goals = slice_goals(tasks[0], args.goals, z, args.seed)
    except ValueError as err:  # includes regions.UnreachableRegionError
        lo, hi = tasks[0].goal_region.bounds[:, 2]
        parser.error(f"no goals in the slice {z} m: {err}; the region spans z in [{lo:g}, "
                     f"{hi:g}] m: try --z {lo:g} {min(hi, lo + z[1] - z[0]):g}")
    maps = []
    for run, policy, task in zip(args.runs, policies, tasks, strict=True):
        label = f"{Path(run).as_posix()} (episode {policy.episode})"  # the run, not "s0"
        reached = evaluate(policy, task, goals, args.batch, label, not args.no_progress)
        maps.append(bin_successes(label, goals, reached, args.cell))
    with outputs.write_errors(parser, args.force):
        plot(maps, z, out)
        outputs.write_csv(csv_path, CSV_COLUMNS, csv_rows(maps))
    for m in maps:
        print(f"{m.run}: {m.successes.sum()} of {m.goals.sum()} goals reached "
              f"({100.0 * m.successes.sum() / m.goals.sum():.1f} %)")
    print(f"-> {out} and {csv_path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
