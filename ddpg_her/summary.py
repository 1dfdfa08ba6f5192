"""``python -m ddpg_her.summary RUN_DIR ...``: a Markdown table of the runs' test sessions.

One column of successes per run (named by its folder; a folder of several seeds' run folders,
as ``--seeds`` writes them, stands for each of them), then each run's last session, its
wall-clock time and the time projected for a longer run from its steady pace (the last half of
its sessions, at least the last interval).
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from ddpg_her.config import Parser, usage_errors
from ddpg_her.runfolder import RunFolder, RunFolderError
from ur5kin.checks import COUNT


def summarize(run_dirs: Sequence[str], project_to: int) -> str:
    """The Markdown tables of the runs in ``run_dirs``, projecting to ``project_to`` episodes.

    Raises
    ------
    ddpg_her.runfolder.RunFolderError
        (a ValueError) When a folder has no ``spec.json``, or its ``spec.json`` or ``eval.csv``
        cannot be read; the message names the file.
    """
    runs = []
    for d in [str(s.parent) for g in map(Path, run_dirs) for s in (
            [g / "spec.json"] if (g / "spec.json").exists() or not g.is_dir()
            else sorted(g.glob("*/spec.json")) or [g / "spec.json"])]:
        folder = RunFolder(d)
        spec = folder.read_spec()
        if "seed" not in spec:
            raise RunFolderError(f"{folder.spec_path} has no 'seed': not a ddpg_her run")
        runs.append((d, spec, folder.read_eval()))
    lines = ["| episode | " + " | ".join(f"{d} (seed {spec['seed']})" for d, spec, _ in runs)
             + " |",
             "|---:|" + "---:|" * len(runs)]
    by_episode = [{int(r["episode"]): r for r in rows} for _, _, rows in runs]
    for e in sorted(set().union(*by_episode)):
        lines.append(f"| {e} | " + " | ".join(f"{r[e]['successes']}/{r[e]['tests']}" if e in r
                                               else "" for r in by_episode) + " |")
    lines += ["", "| run | last session | successes | mean final distance (m) | env steps "
              f"| wall (h) | projected wall for {project_to} episodes (h) |",
              "|---|---:|---:|---:|---:|---:|---:|"]
    for d, _, rows in runs:
        if not rows:
            lines.append(f"| {d} | - | - | - | - | - | - |")
            continue
        last = rows[-1]
        first = rows[min(len(rows) // 2, len(rows) - 2)] if len(rows) > 1 else \
            {"episode": 0, "wall_s": 0.0}  # one session: its pace from the start
        span = int(last["episode"]) - int(first["episode"])
        pace = (float(last["wall_s"]) - float(first["wall_s"])) / span
        projected = float(last["wall_s"]) + pace * (project_to - int(last["episode"]))
        lines.append(f"| {d} | {last['episode']} | {last['successes']}/{last['tests']} | "
                     f"{float(last['mean_final_distance_m']):.3f} | {last['env_steps']} | "
                     f"{float(last['wall_s']) / 3600:.2f} | {projected / 3600:.1f} |")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m ddpg_her.summary", description=__doc__)
    parser.add_argument("run_dirs", nargs="+", metavar="RUN_DIR", help="run folders")
    parser.add_argument("--project-to", type=COUNT.read, default=20_000, metavar="EPISODES",
                        help="episodes of the projected run (default: 20000, the paper's)")
    args = parser.parse_args(argv)
    with usage_errors(parser, OSError, ValueError):
        print(summarize(args.run_dirs, args.project_to))
    return 0


if __name__ == "__main__":
    sys.exit(main())
