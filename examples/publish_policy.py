"""Publish a trained policy: a run folder's spec.json, eval.csv and a checkpoint of its actor
and observation normaliser alone, the part `ddpg_her.load` (and so ``analysis.replay`` and
``analysis.success_map``) reads.

    python examples/publish_policy.py runs/demo runs/published/demo

The checkpoint keeps, per agent (an ensemble's members each), the actor's weights and the
normaliser's count, sums and sums of squares (float32, unchanged); the critics, target
networks, optimisers, random streams and the replay buffer stay behind. A policy of 400-300
networks for 3 joints is about 0.5 MB. The published folder replays and maps; it does not
resume training (no critic, optimiser or buffer).
"""

from __future__ import annotations

import argparse
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


def publish(run: Path, out: Path) -> Path:
    """Write ``out``/spec.json, eval.csv and checkpoints/episode-N.pt (the latest checkpoint of
    ``run``, `policy_state` only); returns the checkpoint's path."""
    source = RunFolder(run)
    episodes = source.checkpoints()
    if not episodes:
        raise FileNotFoundError(f"{run} has no checkpoint")
    if RunFolder(out).exists():
        raise FileExistsError(f"{out} holds a run already; choose another folder")
    episode = max(episodes)
    state = policy_state(source.load_checkpoint(episode))
    (out / "checkpoints").mkdir(parents=True)
    shutil.copyfile(run / "spec.json", out / "spec.json")
    rows = (run / "eval.csv").read_text().splitlines(keepends=True)  # up to the checkpoint's
    (out / "eval.csv").write_text("".join(rows[:1] + [r for r in rows[1:]
                                                      if int(r.split(",")[0]) <= episode]))
    path = out / "checkpoints" / f"episode-{episode:06d}.pt"
    torch.save(state, path)
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="the trained run folder (spec.json, eval.csv, "
                                                "checkpoints)")
    parser.add_argument("out", type=Path, help="the folder to publish into (must not hold a "
                                                "run)")
    args = parser.parse_args(argv)
    try:
        path = publish(args.run, args.out)
    except (OSError, ValueError) as err:
        parser.error(str(err))
    print(f"{path}: {path.stat().st_size / 1e6:.2f} MB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
