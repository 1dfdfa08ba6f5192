"""Publish a trained policy: a run folder's spec.json, eval.csv and a checkpoint of its actor
and observation normaliser alone, the part `ddpg_her.load` (and so ``analysis.replay`` and
``analysis.success_map``) reads.

    python examples/publish_policy.py runs/demo runs/published/demo

``out`` may also be the committed copy of the same run (its spec.json identical but for the
``created`` time of the process that wrote it, as when a lost stage is retrained on the same
kind of CPU, and its eval.csv the run's up to a test session but for the ``wall_s`` column):
then the checkpoint alone is added beside them, so that a reported run's folder under
``results/`` replays as it stands.

The checkpoint keeps, per agent (an ensemble's members each), the actor's weights and the
normaliser's count, sums and sums of squares (float32, unchanged); the critics, target
networks, optimisers, random streams and the replay buffer stay behind. A policy of 400-300
networks for 3 joints is about 0.5 MB. The published folder replays and maps; it does not
resume training (no critic, optimiser or buffer).
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

import torch

from ddpg_her.runfolder import RunFolder

KEPT = ("actor", "normalizer")
"""What `ddpg_her.load` reads of each agent's state in a checkpoint."""


def policy_state(state: dict) -> dict:
    """The part of a checkpoint ``state`` (``{"episode", "agent", ...}``) that `ddpg_her.load`
    reads: the episode, and per agent its actor and normaliser (an ensemble: its members' and
    the cells' centres)."""
    agent = state["agent"]
    if "ensemble" in agent:
        kept = {"ensemble": [{k: m[k] for k in KEPT} for m in agent["ensemble"]],
                "centres": agent["centres"]}
    else:
        kept = {k: agent[k] for k in KEPT}
    return {"episode": state["episode"], "agent": kept}


def same_spec(a: Path, b: Path) -> bool:
    """Whether the spec.json files ``a`` and ``b`` record the same run: equal in every field
    but ``created`` (when the process that wrote it started)."""
    def record(path: Path) -> dict:
        return {k: v for k, v in json.loads(path.read_text()).items() if k != "created"}
    return record(a) == record(b)


def without_wall(csv_text: str) -> list[list[str]]:
    """The rows of an eval.csv's text without its ``wall_s`` column (seconds of the machine's
    clock: a retrained run's differ, its test sessions do not)."""
    rows = [line.split(",") for line in csv_text.splitlines()]
    keep = [i for i, name in enumerate(rows[0]) if name != "wall_s"] if rows else []
    return [[row[i] for i in keep] for row in rows]


def publish(run: Path, out: Path) -> Path:
    """Write ``out``/spec.json, eval.csv and checkpoints/episode-N.pt (the latest checkpoint of
    ``run``, `policy_state` only); returns the checkpoint's path."""
    source = RunFolder(run)
    episodes = source.checkpoints()
    if not episodes:
        raise FileNotFoundError(f"{run} has no checkpoint")
    episode = max(episodes)
    rows = (run / "eval.csv").read_text().splitlines(keepends=True)  # up to the checkpoint's
    rows = "".join(rows[:1] + [r for r in rows[1:] if int(r.split(",")[0]) <= episode])
    if RunFolder(out).exists():
        same = (same_spec(out / "spec.json", run / "spec.json")
                and without_wall((out / "eval.csv").read_text()) == without_wall(rows))
        if not same or (out / "checkpoints").exists():
            raise FileExistsError(f"{out} holds another run, or a published checkpoint already "
                                  "(expected a new folder, or the committed copy of this run "
                                  f"up to episode {episode} without checkpoints)")
    state = policy_state(source.load_checkpoint(episode))
    (out / "checkpoints").mkdir(parents=True)
    if not (out / "spec.json").exists():  # a committed copy keeps its own
        shutil.copyfile(run / "spec.json", out / "spec.json")
        (out / "eval.csv").write_text(rows)
    path = out / "checkpoints" / f"episode-{episode:06d}.pt"
    torch.save(state, path)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="the trained run folder (spec.json, eval.csv, "
                                                "checkpoints)")
    parser.add_argument("out", type=Path, help="the folder to publish into: a new one, or the "
                        "committed copy of this same run (spec.json equal but for created, "
                        "eval.csv but for wall_s)")
    args = parser.parse_args(argv)
    try:
        path = publish(args.run, args.out)
    except (OSError, ValueError) as err:
        parser.error(str(err))
    print(f"{path}: {path.stat().st_size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
