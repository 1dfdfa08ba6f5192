"""Is seed 0's run the same trained alone and beside seed 1 (`--seeds 0 1`)? Issue 36.

    python results/seed_alone_group/check.py eval toy    # eval.csv, toy env, batch 8 and 64
    python results/seed_alone_group/check.py eval ur5    # eval.csv, UR5Reach-v0 far box 3, batch 64
    python results/seed_alone_group/check.py weights 64  # max |weight difference|, toy, batch 64
    python results/seed_alone_group/check.py weights 8   # the same at the tests' batch of 8

16-16 networks, 40 training episodes, a test session of 4 episodes after every episode, 2
warm-up episodes, the CPU with one torch thread; the rest `AgentConfig`'s defaults. Run from
the repository root (the toy env lives in tests/). Output recorded in README.md.
"""

from __future__ import annotations

import csv
import itertools
import sys
import tempfile
from pathlib import Path

import torch

sys.path.insert(0, "tests")

ENVS = {"toy": ("ToyReach-v0", {"region": "box", "n_joints": 2}),
        "ur5": ("UR5Reach-v0", {"region": "farbox", "n_joints": 3})}
"""Env id and task of each case."""

DTYPES = (torch.float32, torch.float64)
UPDATES = (4, 8)
"""Updates per episode tried."""


def _train(env: str, config, seeds: list[int], root: str, dtype: torch.dtype) -> Path:
    """Train ``seeds`` together in one process; the run folder of the first seed."""
    from ddpg_her.trainer import Trainer

    env_id, task = ENVS[env]
    dirs = [str(Path(root) / f"s{s}") for s in seeds]
    trainer = Trainer(env_id, task, config, seeds, dirs, progress=False, tensorboard=False,
                      dtype=dtype)
    try:
        trainer.run()
    finally:
        trainer.close()
    return Path(dirs[0])


def _config(episodes: int, updates: int, batch: int, eval_every: int):
    from ddpg_her.config import AgentConfig

    return AgentConfig(episodes=episodes, eval_every=eval_every, eval_episodes=4,
                       hidden_sizes=(16, 16), updates_per_episode=updates, batch_size=batch,
                       warmup_episodes=2)


def _eval(run: Path) -> list[list[str]]:
    """eval.csv's rows without the header and the wall-clock column."""
    with open(run / "eval.csv", newline="") as f:
        return [row[:-1] for row in csv.reader(f)][1:]


def eval_rows(env: str) -> None:
    """Print the first test session where seed 0 alone and in the pair differ."""
    batches = (8, 64) if env == "toy" else (64,)
    for updates, batch, dtype in itertools.product(UPDATES, batches, DTYPES):
        config = _config(40, updates, batch, eval_every=1)
        with tempfile.TemporaryDirectory() as tmp:
            alone = _eval(_train(env, config, [0], tmp + "/alone", dtype))
            pair = _eval(_train(env, config, [0, 1], tmp + "/pair", dtype))
        differ = [int(a[0]) for a, b in zip(alone, pair, strict=True) if a != b]
        print(f"{ENVS[env][0]} updates/episode={updates} batch={batch} {str(dtype)[6:]}: "
              + (f"first differing session at episode {differ[0]} ({len(differ)} of "
                 f"{len(alone)} differ)" if differ else f"all {len(alone)} sessions equal"),
              flush=True)


def weights(batch: int) -> None:
    """Print the largest difference of seed 0's weights alone and in the pair (toy env)."""
    from ddpg_her.runfolder import RunFolder

    lengths = (3, 12, 40) if batch != 8 else (40,)
    for updates, episodes, dtype in itertools.product(UPDATES, lengths, DTYPES):
        config = _config(episodes, updates, batch, eval_every=episodes)
        with tempfile.TemporaryDirectory() as tmp:
            a, b = (RunFolder(_train("toy", config, seeds, tmp + name, dtype))
                    .load_checkpoint(episodes)["agent"]
                    for seeds, name in (([0], "/alone"), ([0, 1], "/pair")))
        diff = max((a[n][k].double() - b[n][k].double()).abs().max().item()
                   for n in ("actor", "critic", "actor_target", "critic_target") for k in a[n])
        print(f"toy updates/episode={updates} batch={batch} episodes={episodes} "
              f"{str(dtype)[6:]}: max |weight difference| {diff:.3g}", flush=True)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    torch.set_num_threads(1)
    import toy_goal_env  # noqa: F401  (registers ToyReach-v0)

    if len(args) == 2 and args[0] == "eval" and args[1] in ENVS:
        eval_rows(args[1])
    elif len(args) == 2 and args[0] == "weights" and args[1].isdigit() and int(args[1]) >= 1:
        weights(int(args[1]))
    else:
        print(f"usage: check.py eval {{{','.join(ENVS)}}} | check.py weights BATCH (a count "
              f">= 1); got {args}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
