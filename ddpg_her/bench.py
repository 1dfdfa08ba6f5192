"""``python -m ddpg_her.bench``: how fast the DDPG update runs, against SB3 and the machine's peak.

Measured in one process, one after the other, with the same torch thread count:

- ``agent_updates_per_s``: our update (minibatch sampling included) of K stacked agents, summed
  over the agents, on replay buffers filled with real env transitions (random-action episodes
  with their HER copies);
- ``sb3_updates_per_s``: Stable-Baselines3's DDPG + HerReplayBuffer ("final", the dense reward
  recomputed through ``copy_info_dict``) on the same env, networks 400-300, batch 64: its
  ``train()`` step, HER sampling included;
- ``update_gflops``: floating-point operations of our update (counted by
  ``torch.utils.flop_counter``, backward included) per second;
- ``matmul_peak_gflops``: the best float32 matrix-product rate of this machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import Any

from ddpg_her.config import AgentConfig


def matmul_peak_gflops(sizes: Sequence[int] = (512, 1024, 2048), repeats: int = 5) -> float:
    """The best float32 ``n x n`` matrix-product rate over ``sizes``, GFLOP/s."""
    import torch

    best = 0.0
    for n in sizes:
        a, b = torch.randn(n, n), torch.randn(n, n)
        a @ b
        for _ in range(repeats):
            t = time.perf_counter()
            a @ b
            best = max(best, 2 * n**3 / (time.perf_counter() - t) / 1e9)
    return best


def ours(k: int, env_id: str, env_kwargs: dict[str, Any], config: AgentConfig, updates: int,
         fill_episodes: int, device: str) -> dict[str, float]:
    """Agent-updates per second of K stacked agents, and the update's GFLOP/s."""
    import torch
    from torch.utils.flop_counter import FlopCounterMode

    from ddpg_her.trainer import Trainer

    config = AgentConfig(**{**config.to_dict(), "episodes": fill_episodes,
                            "warmup_episodes": fill_episodes, "eval_episodes": 1})
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(env_id, env_kwargs, config, list(range(k)),
                          [f"{tmp}/s{s}" for s in range(k)], device=device, progress=False,
                          tensorboard=False)
        try:
            for _ in range(fill_episodes):
                trainer.train_episode()
                trainer.episode += 1
            trainer.learn(10)
            with FlopCounterMode(display=False) as counter:
                trainer.learn(1)
            flops = counter.get_total_flops()
            if device == "cuda":
                torch.cuda.synchronize()
            t = time.perf_counter()
            trainer.learn(updates)
            if device == "cuda":
                torch.cuda.synchronize()
            seconds = time.perf_counter() - t
        finally:
            trainer.close()
    return {"agent_updates_per_s": k * updates / seconds,
            "update_gflops": flops * updates / seconds / 1e9,
            "update_mflop_per_agent": flops / k / 1e6}


def sb3(env_id: str, env_kwargs: dict[str, Any], config: AgentConfig, updates: int,
        fill_episodes: int, device: str) -> float:
    """Updates per second of Stable-Baselines3's DDPG + HER on the same env and networks."""
    import gymnasium
    from stable_baselines3 import DDPG, HerReplayBuffer

    env = gymnasium.make(env_id, **env_kwargs)
    steps = fill_episodes * env.spec.max_episode_steps
    model = DDPG(
        "MultiInputPolicy", env, buffer_size=config.buffer_size, batch_size=config.batch_size,
        learning_starts=steps, gamma=config.gamma, tau=config.tau, learning_rate=config.actor_lr,
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs={"n_sampled_goal": 1, "goal_selection_strategy": "final",
                              "copy_info_dict": True},
        policy_kwargs={"net_arch": list(config.hidden_sizes)}, device=device, seed=0, verbose=0)
    model.learn(total_timesteps=steps)
    model.train(gradient_steps=10, batch_size=config.batch_size)
    t = time.perf_counter()
    model.train(gradient_steps=updates, batch_size=config.batch_size)
    seconds = time.perf_counter() - t
    env.close()
    return updates / seconds


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m ddpg_her.bench",
        description="Agent-updates per second of our batched DDPG update next to Stable-"
                    "Baselines3's DDPG + HER on the same env, and the update's GFLOP/s against "
                    "the machine's float32 matrix-product peak, all measured in this run.")
    parser.add_argument("--seeds", type=int, default=5, metavar="K",
                        help="agents trained together (default: %(default)s)")
    parser.add_argument("--region", default="farbox", help="goal region (default: farbox)")
    parser.add_argument("--joints", type=int, default=3, help="controlled joints (default: 3)")
    parser.add_argument("--updates", type=int, default=300,
                        help="timed updates per measurement (default: %(default)s)")
    parser.add_argument("--fill-episodes", type=int, default=10,
                        help="random-action episodes that fill the buffers first (default: 10)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu",
                        help="device of our agents and of SB3's (default: cpu)")
    parser.add_argument("--no-sb3", action="store_true", help="skip the SB3 measurement")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.updates < 1 or args.fill_episodes < 1:
        parser.error("--seeds, --updates and --fill-episodes must be >= 1")
    if not 2 <= args.joints <= 6:
        parser.error(f"--joints must be in 2..6, got {args.joints}")

    import torch

    import envs  # noqa: F401  (registers UR5Reach-v0)

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    env_id, env_kwargs = "UR5Reach-v0", {"region": args.region, "n_joints": args.joints}
    config = AgentConfig()
    result: dict[str, Any] = {"seeds": args.seeds, "threads": torch.get_num_threads(),
                              "device": args.device, "env_id": env_id, **env_kwargs,
                              "batch_size": config.batch_size,
                              "hidden_sizes": list(config.hidden_sizes)}
    try:
        result.update(ours(args.seeds, env_id, env_kwargs, config, args.updates,
                           args.fill_episodes, args.device))
    except ValueError as e:
        parser.error(str(e))
    result["sb3_updates_per_s"] = None if args.no_sb3 else sb3(
        env_id, env_kwargs, config, args.updates, args.fill_episodes, args.device)
    result["matmul_peak_gflops"] = matmul_peak_gflops()
    if result["sb3_updates_per_s"]:
        result["speedup_vs_sb3"] = result["agent_updates_per_s"] / result["sb3_updates_per_s"]
    result["peak_fraction"] = result["update_gflops"] / result["matmul_peak_gflops"]
    if args.json:
        print(json.dumps(result))
        return 0
    for key, value in result.items():
        print(f"{key:>24}: {value:.4g}" if isinstance(value, float) else f"{key:>24}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
