"""``python -m benchmarks.ensemble_episode``: the time of one training episode of a regional
ensemble (``--ensemble M``) against one agent, both at the same budget, in one process.

Two trainers of K seeds on one task, one plain and one with ``--ensemble M`` (every other
agent field equal), step in alternating rounds: one training episode of each per round (the
rollout, storing it with its HER copies, the updates_per_episode updates; no test session).
Printed as JSON: the median seconds per episode of each, the median of each round's ratio
(ensemble over plain, so drifts of a shared machine's load cancel), and the seconds the
ensemble's partition takes to fit (once per task, when its trainer is built).
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import torch

from ddpg_her.config import AgentConfig, Parser
from ddpg_her.ensemble import task_partitions
from ddpg_her.trainer import Trainer


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m benchmarks.ensemble_episode", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--env-id", default="UR5Reach-v0", help="the env (module:id for a "
                        "test env)")
    parser.add_argument("--region", default="zheight", help="the task's goal region")
    parser.add_argument("--joints", type=int, default=3, help="joints the agent controls")
    parser.add_argument("--seeds", type=int, default=5, help="K seeds per trainer")
    parser.add_argument("--members", type=int, default=4,
                        help="M members of the ensemble (dividing --updates-per-episode)")
    parser.add_argument("--warmup", type=int, default=5,
                        help="random-action episodes first (fill the buffers; not timed)")
    parser.add_argument("--rounds", type=int, default=10,
                        help="timed rounds, one training episode of each trainer per round")
    parser.add_argument("--updates-per-episode", type=int, default=100,
                        help="updates per episode of one agent (the ensemble's in all)")
    parser.add_argument("--hidden-sizes", type=int, nargs=2, default=[400, 300], metavar="N",
                        help="hidden units of actor and critic")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.seeds < 1 or args.rounds < 1 or args.warmup < 0 or args.members < 2:
        raise SystemExit("--seeds and --rounds must be >= 1, --warmup >= 0, --members >= 2")
    torch.set_num_threads(args.threads)
    from ddpg_her.vecenv import register_env

    env_id = register_env(args.env_id)
    if env_id == "UR5Reach-v0":
        import envs  # noqa: F401  (registers UR5Reach-v0)
    task = {"region": args.region, "n_joints": args.joints}
    total = args.warmup + args.rounds + 1  # the last episode (its test session) is not run
    plain = AgentConfig(episodes=total, eval_every=total, warmup_episodes=args.warmup,
                        updates_per_episode=args.updates_per_episode,
                        hidden_sizes=tuple(args.hidden_sizes))
    ensemble = AgentConfig(**{**plain.to_dict(), "ensemble": args.members})
    seeds = list(range(args.seeds))
    with tempfile.TemporaryDirectory() as tmp:
        trainers = {}
        for name, config in (("plain", plain), ("ensemble", ensemble)):
            trainers[name] = Trainer(env_id, task, config, seeds,
                                     [Path(tmp) / name / f"s{s}" for s in seeds],
                                     progress=False, tensorboard=False)
            trainers[name].start()
        start = time.perf_counter()  # again, now that the env and its sampler are built
        task_partitions(env_id, [task], args.members)
        fit_s = time.perf_counter() - start
        try:
            for _ in range(args.warmup):
                for t in trainers.values():
                    t.step()
            seconds: dict[str, list[float]] = {name: [] for name in trainers}
            for _ in range(args.rounds):
                for name, t in trainers.items():
                    start = time.perf_counter()
                    t.step()
                    seconds[name].append(time.perf_counter() - start)
        finally:
            for t in trainers.values():
                t.close()
    ratios = [e / p for e, p in zip(seconds["ensemble"], seconds["plain"], strict=True)]
    print(json.dumps({
        "task": task, "seeds": args.seeds, "members": args.members,
        "updates_per_episode": args.updates_per_episode, "rounds": args.rounds,
        "threads": args.threads,
        "plain_s_per_episode": round(statistics.median(seconds["plain"]), 4),
        "ensemble_s_per_episode": round(statistics.median(seconds["ensemble"]), 4),
        "ensemble_over_plain": round(statistics.median(ratios), 3),
        "partition_fit_s": round(fit_s, 2),
    }, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
