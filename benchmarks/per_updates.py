"""``python -m benchmarks.per_updates``: the cost of prioritised replay's updates against uniform
replay's, both at the same stack, buffer fill and networks, in one process.

K agents' buffers hold ``--rows`` random transitions each (the far box 3 runs store about 18,000
per 100 training episodes: 180,000 by episode 1,000). Each round times ``--updates`` updates of
each path in turn: uniform (``ReplayBuffer.sample`` + ``DDPG.update``) and prioritised
(``PrioritizedBuffer.sample_prioritized`` + the weighted update + ``update_priorities``). Printed
as JSON: the median milliseconds per update of each and the median of the rounds' ratios
(prioritised over uniform, so drifts of a shared machine's load cancel).
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch

from ddpg_her.agent import DDPG
from ddpg_her.buffer import Layout, PrioritizedBuffer, ReplayBuffer
from ddpg_her.config import AgentConfig, Parser


def main(argv: list[str] | None = None) -> int:
    parser = Parser(prog="python -m benchmarks.per_updates",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--seeds", type=int, default=5, help="K agents of the stack, >= 1")
    parser.add_argument("--rows", type=int, default=180_000,
                        help="transitions stored per agent, >= batch size 64")
    parser.add_argument("--updates", type=int, default=50, help="updates per path and round, >= 1")
    parser.add_argument("--rounds", type=int, default=5, help="timed rounds, >= 1")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads, >= 1")
    args = parser.parse_args(argv)
    if min(args.seeds, args.updates, args.rounds, args.threads) < 1 or args.rows < 64:
        parser.error("--seeds, --updates, --rounds, --threads must be >= 1, --rows >= 64")
    torch.set_num_threads(args.threads)
    config = AgentConfig(prioritized_replay=True)
    layout = Layout(in_dim=15, act_dim=3)  # far box 3: 9 observations + 2 x 3 goal values
    gens = [torch.Generator().manual_seed(s) for s in range(args.seeds)]
    agent = DDPG(config, layout.in_dim, layout.act_dim, init_generators=gens)
    rows = torch.rand(args.rows, layout.width, generator=gens[0])
    uniform = ReplayBuffer(args.seeds, config.buffer_size, layout, dtype=torch.float32,
                           device="cpu")
    per = PrioritizedBuffer(args.seeds, config.buffer_size, layout, alpha=config.per_alpha,
                            eps=config.per_eps, dtype=torch.float32, device="cpu")
    for k in range(args.seeds):
        uniform.add(k, rows)
        per.add(k, rows)

    def uniform_update() -> None:
        agent.update(*uniform.sample(config.batch_size, gens))

    def per_update() -> None:
        *batch, idx, w = per.sample_prioritized(config.batch_size, gens, config.per_beta)
        agent.update(*batch, weight=w)
        per.update_priorities(idx, agent.td_error)

    ms: dict[str, list[float]] = {"uniform": [], "prioritized": []}
    per_update()  # the first Adam step builds its state
    for _ in range(args.rounds):
        for name, step in (("uniform", uniform_update), ("prioritized", per_update)):
            start = time.perf_counter()
            for _ in range(args.updates):
                step()
            ms[name].append(1e3 * (time.perf_counter() - start) / args.updates)
    ratios = [p / u for p, u in zip(ms["prioritized"], ms["uniform"], strict=True)]
    print(json.dumps({"seeds": args.seeds, "rows": args.rows, "threads": args.threads,
                      "uniform_ms_per_update": round(statistics.median(ms["uniform"]), 3),
                      "prioritized_ms_per_update": round(statistics.median(ms["prioritized"]), 3),
                      "prioritized_over_uniform": round(statistics.median(ratios), 3)}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
