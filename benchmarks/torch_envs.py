"""``python -m benchmarks.torch_envs``: a training episode and a test session of a stack of
agents on the ``torch`` env backend, its tensor twins merged (one ``TorchReach`` per set of
tasks equal but for their goals, the trainer's way) against one twin per agent.

Two trainers of the same agents (``--settings`` x ``--seeds``, one stack as ``ddpg_her.
train_many`` builds it) step in alternating rounds: per round, one training episode of each
(rollout, exploration, HER storage; no updates: they do not depend on the envs) and one test
session of each (``--eval-episodes`` copies per agent). The unmerged peer is the trainer with
``TorchGoalVecEnv(merge=False)`` in place of the collector's default. Also counted, once: the
torch operations of one env step (top-level ``aten::`` ops in torch's profiler on the CPU;
on a GPU about as many kernel launches with ``--env-dynamics torch``). Printed as JSON: median
seconds of each and the median of each round's ratio (unmerged over merged, so that drifts of
a shared machine's load cancel).
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import json
import statistics
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

from ddpg_her import collect
from ddpg_her.config import AgentConfig
from ddpg_her.trainer import Trainer
from ddpg_her.vecenv import TorchGoalVecEnv

SETTINGS = ("unconstrained", "zheight", "closebox", "farbox")
"""The 3-joint settings of the paper's grid: unconstrained starts at the zero pose, the others
at the constrained start (two merged twins)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.torch_envs", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS),
                        help="goal regions, one setting each")
    parser.add_argument("--joints", type=int, default=3, help="joints every agent controls")
    parser.add_argument("--seeds", type=int, default=5, help="agents (seeds) per setting")
    parser.add_argument("--steps", type=int, default=10,
                        help="max_episode_steps of every episode (control steps)")
    parser.add_argument("--eval-episodes", type=int, default=10,
                        help="test copies per agent in a test session")
    parser.add_argument("--rounds", type=int, default=3,
                        help="timed rounds, each one training episode and one test session of "
                             "both trainers")
    parser.add_argument("--device", default="cpu", help="the trainers' and envs' device")
    parser.add_argument("--env-dynamics", default="torch", choices=collect.ENV_DYNAMICS,
                        help="the twins' arm (numba: the fused CUDA kernel)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    return parser


@contextlib.contextmanager
def _merging(merge: bool) -> Iterator[None]:
    """The collector's envs built with ``TorchGoalVecEnv(merge=merge)`` inside."""
    saved = collect.TorchGoalVecEnv
    collect.TorchGoalVecEnv = functools.partial(TorchGoalVecEnv, merge=merge)  # type: ignore
    try:
        yield
    finally:
        collect.TorchGoalVecEnv = saved  # type: ignore


def _ops_per_step(envs: TorchGoalVecEnv) -> int:
    """Top-level ``aten::`` operations of one ``envs.step`` of zero actions (after a reset)."""
    obs = envs.reset(list(range(envs.num_envs)))
    action = torch.zeros((envs.num_envs, envs.scale.dim), dtype=torch.float64,
                         device=envs.device)
    active = torch.ones(envs.num_envs, dtype=torch.bool, device=envs.device)
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        envs.step(action, active, obs)
    events = prof.events()
    return sum(1 for e in events if e.name.startswith("aten::")
               and (e.cpu_parent is None or not e.cpu_parent.name.startswith("aten::")))


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if min(args.seeds, args.steps, args.eval_episodes, args.rounds, args.joints) < 1:
        raise SystemExit("--seeds, --steps, --eval-episodes, --rounds and --joints must be >= 1")
    torch.set_num_threads(args.threads)
    tasks = [{"region": r, "n_joints": args.joints, "max_episode_steps": args.steps}
             for r in args.settings for _ in range(args.seeds)]
    seeds = [s for _ in args.settings for s in range(args.seeds)]
    config = AgentConfig(episodes=10 ** 6, eval_every=10 ** 6, warmup_episodes=0,
                         eval_episodes=args.eval_episodes)
    device = torch.device(args.device)
    names = ("merged", "unmerged")
    seconds: dict[str, list[float]] = {f"{n}_{what}": [] for n in names
                                       for what in ("train", "test")}
    ops: dict[str, int] = {}
    twins: dict[str, int] = {}
    with tempfile.TemporaryDirectory() as tmp:
        trainers: dict[str, Trainer] = {}
        for name in names:
            with _merging(name == "merged"):
                trainers[name] = Trainer(
                    "UR5Reach-v0", tasks, config, seeds,
                    [Path(tmp) / name / f"{i}" for i in range(len(seeds))], device=args.device,
                    progress=False, tensorboard=False, env_backend="torch",
                    env_dynamics=args.env_dynamics)
            envs = trainers[name].envs
            twins[name] = len(envs.batches) or len(envs.groups)
            ops[name] = _ops_per_step(envs)
        try:
            for t in trainers.values():  # lazy initialisations (and CUDA's) first
                t.train_episode()
            for _ in range(args.rounds):
                for name, t in trainers.items():
                    _sync(device)
                    start = time.perf_counter()
                    t.train_episode()
                    _sync(device)
                    middle = time.perf_counter()
                    t.evaluate()
                    _sync(device)
                    seconds[f"{name}_train"].append(middle - start)
                    seconds[f"{name}_test"].append(time.perf_counter() - middle)
        finally:
            for t in trainers.values():
                t.close()
    result: dict[str, Any] = {
        "settings": args.settings, "joints": args.joints, "seeds": args.seeds,
        "agents": len(seeds), "steps": args.steps, "eval_episodes": args.eval_episodes,
        "rounds": args.rounds, "device": str(device), "env_dynamics": args.env_dynamics,
        "threads": args.threads, "twins_stepped": twins, "aten_ops_per_step": ops}
    for what in ("train", "test"):
        for name in names:
            result[f"{name}_{what}_s"] = round(statistics.median(seconds[f"{name}_{what}"]), 4)
        ratios = [u / m for u, m in zip(seconds[f"unmerged_{what}"], seconds[f"merged_{what}"],
                                        strict=True)]
        result[f"{what}_unmerged_over_merged"] = round(statistics.median(ratios), 2)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
