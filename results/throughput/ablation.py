"""What each part of the K = 5 update costs: the full update against the same update without
its two Adam steps, without its target update, and without both, in alternating rounds.

Diagnostic only (the parts left out are replaced by no-ops through the agent's internals); the
networks are 400-300, batch 64, in_dim 15 (3 joints), random minibatches. Prints one JSON
object: median milliseconds per update of all 5 agents at the torch threads given.

    python results/throughput/ablation.py [--threads T]
"""

import argparse
import json
import statistics
import time

import torch

from ddpg_her.agent import DDPG
from ddpg_her.config import AgentConfig

K, IN, ACT, N = 5, 15, 3, 64


def agent() -> DDPG:
    return DDPG(AgentConfig(), IN, ACT,
                init_generators=[torch.Generator().manual_seed(i) for i in range(K)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--rounds", type=int, default=20, help="alternating rounds")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)
    g = torch.Generator().manual_seed(0)
    batches = [(torch.randn(K, N, IN, generator=g), torch.rand(K, N, ACT, generator=g) * 2 - 1,
                -torch.rand(K, N, 1, generator=g), torch.randn(K, N, IN, generator=g),
                (torch.rand(K, N, 1, generator=g) < 0.1).float()) for _ in range(20)]
    variants = {name: agent() for name in ("full", "no_adam", "no_target_update", "neither")}
    for a in variants.values():
        for b in batches[:3]:
            a.update(*b)  # the first step creates Adam's state
    for name in ("no_adam", "neither"):
        variants[name]._critic_step = variants[name]._actor_step = lambda: None
    for name in ("no_target_update", "neither"):
        variants[name]._target, variants[name]._online = [torch.zeros(1)], [torch.zeros(1)]
    times: dict[str, list[float]] = {name: [] for name in variants}
    for _ in range(args.rounds):
        for name, a in variants.items():
            t = time.perf_counter()
            for b in batches:
                a.update(*b)
            times[name].append((time.perf_counter() - t) / len(batches) * 1e3)
    full = times["full"]
    print(json.dumps({
        "threads": torch.get_num_threads(),
        "ms_per_update": {n: round(statistics.median(v), 3) for n, v in times.items()},
        "full_over_variant": {
            n: round(statistics.median(f / x for f, x in zip(full, v, strict=True)), 3)
            for n, v in times.items()},
    }))


if __name__ == "__main__":
    main()
