"""``python -m benchmarks.agent_updates``: how fast the DDPG update runs, against SB3 and the
machine's peak.

Measured in one process with the same torch thread count, ours and SB3 in alternating rounds
(medians of the rounds; the speed-up is the median of each round's pair, so drifts of a shared
machine's load cancel):

- ``agent_updates_per_s``: our update (minibatch sampling included) of K stacked agents, summed
  over the agents, on replay buffers filled with real env transitions (random-action episodes
  with their HER copies);
- ``sb3_updates_per_s``: Stable-Baselines3's DDPG + HerReplayBuffer ("final", the dense reward
  recomputed through ``copy_info_dict``) on the same env, networks 400-300, batch 64: its
  ``train()`` step, HER sampling included;
- ``plain_updates_per_s``: one agent written the usual way (`benchmarks.reference`: ``nn.Linear``,
  autograd, torch's fused Adam), same networks and batch, on minibatches drawn from our buffers:
  what a plain PyTorch DDPG update costs here, without SB3's own overhead;
- ``update_gflops``: floating-point operations of our update (counted by
  ``torch.utils.flop_counter``, backward included) per second;
- ``speedup_vs_sb3``, ``speedup_vs_plain``: agent_updates_per_s over the peer's, round by
  round;
- ``matmul_peak_gflops``: the best rate of large float32 matrix products on the device the
  update ran on (the GPU with ``--device cuda``), and ``peak_fraction``, the update's
  ``update_gflops`` over it;
- ``stack_*`` (with ``--stack K``): the same update for one stack of K agents, e.g. the 55 of
  the paper's grid in one ``ddpg_her.train_many`` process (without peers, fewer rounds);
- ``rollout_*`` (with ``--rollout K``): one training episode (random actions) of K agents
  whose regions cycle through the paper's four, through the trainer's ``numpy`` env backend
  (one env per agent) and its ``batched`` one (the agents' copies merged into one vector env
  per start pose), in alternating rounds: seconds per episode of all K agents, and the
  speed-up, the median of each round's ratio;
- ``machine``: the CPU, its logical cores and the torch build, so a recorded result says where
  it was measured.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from typing import Any

from ddpg_her.config import AgentConfig, Parser

PEAK_SIZES = {"cpu": (1024, 2048), "cuda": (4096, 8192)}
"""Square matrix sizes n of the peak measurement per device: large enough that the product
runs at the library's full rate (a 512 x 512 product on a GPU mostly measures the launch)."""


def matmul_flops(n: int) -> int:
    """Floating-point operations of one ``n x n`` by ``n x n`` product: n^2 outputs, each n
    multiplications and n additions (``torch.utils.flop_counter``'s count, tested)."""
    return 2 * n**3


def matmul_peak_gflops(device: str = "cpu", sizes: Sequence[int] | None = None,
                       repeats: int = 5, dtype: Any = None) -> float:
    """The best rate of large square float32 matrix products on ``device``, GFLOP/s.

    For each n of ``sizes`` (default `PEAK_SIZES`): one warm-up product, then ``repeats``
    timed ones; on CUDA each timing waits for the GPU (``torch.cuda.synchronize``), so it counts
    the product and not its launch. Returns the best rate: the machine's attainable peak for
    the kind of work the update does (torch's float32 matrix products with this process's
    settings, e.g. TF32 off by default), which the update's own rate is a fraction of.
    """
    import torch

    dtype = torch.float32 if dtype is None else dtype
    dev = torch.device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    gen = torch.Generator(device=dev).manual_seed(0)
    best = 0.0
    for n in sizes or PEAK_SIZES[dev.type]:
        a = torch.randn(n, n, generator=gen, device=dev, dtype=dtype)
        b = torch.randn(n, n, generator=gen, device=dev, dtype=dtype)
        c = torch.empty(n, n, device=dev, dtype=dtype)
        torch.mm(a, b, out=c)
        sync()
        for _ in range(repeats):
            t = time.perf_counter()
            torch.mm(a, b, out=c)
            sync()
            best = max(best, matmul_flops(n) / (time.perf_counter() - t) / 1e9)
        del a, b, c
    return best


class _Ours:
    """K stacked agents on buffers filled with real transitions; ``run(n)`` times n updates."""

    def __init__(self, k: int, env_id: str, env_kwargs: dict[str, Any], config: AgentConfig,
                 fill_episodes: int, device: str):
        import torch
        from torch.utils.flop_counter import FlopCounterMode

        from ddpg_her.trainer import Trainer

        config = AgentConfig(**{**config.to_dict(), "episodes": fill_episodes,
                                "warmup_episodes": fill_episodes, "eval_episodes": 1})
        self.k, self.device, self._sync = k, device, torch.cuda.synchronize
        self._tmp = tempfile.TemporaryDirectory()
        self.trainer = Trainer(env_id, env_kwargs, config, list(range(k)),
                               [f"{self._tmp.name}/s{s}" for s in range(k)], device=device,
                               progress=False, tensorboard=False)
        for _ in range(fill_episodes):
            self.trainer.train_episode()
            self.trainer.episode += 1
        self.trainer.learn(10)  # warm-up: Adam's state, the first kernels' set-up
        with FlopCounterMode(display=False) as counter:
            self.trainer.learn(1)
        self.flops = counter.get_total_flops()

    def run(self, updates: int) -> float:
        if self.device == "cuda":
            self._sync()
        t = time.perf_counter()
        self.trainer.learn(updates)
        if self.device == "cuda":
            self._sync()
        return time.perf_counter() - t

    def close(self) -> None:
        self.trainer.close()
        self._tmp.cleanup()


class _SB3:
    """Stable-Baselines3's DDPG + HER on the same env and networks; ``run(n)`` times n updates."""

    def __init__(self, env_id: str, env_kwargs: dict[str, Any], config: AgentConfig,
                 fill_episodes: int, device: str):
        import gymnasium
        from stable_baselines3 import DDPG, HerReplayBuffer

        self.env = gymnasium.make(env_id, **env_kwargs)
        steps = fill_episodes * self.env.unwrapped.task.max_episode_steps
        self.batch_size = config.batch_size
        self.model = DDPG(
            "MultiInputPolicy", self.env, buffer_size=config.buffer_size,
            batch_size=config.batch_size, learning_starts=steps, gamma=config.gamma,
            tau=config.tau, learning_rate=config.actor_lr, replay_buffer_class=HerReplayBuffer,
            replay_buffer_kwargs={"n_sampled_goal": 1, "goal_selection_strategy": "final",
                                  "copy_info_dict": True},
            policy_kwargs={"net_arch": list(config.hidden_sizes)}, device=device, seed=0,
            verbose=0)
        self.model.learn(total_timesteps=steps)
        self.model.train(gradient_steps=10, batch_size=config.batch_size)

    def run(self, updates: int) -> float:
        t = time.perf_counter()
        self.model.train(gradient_steps=updates, batch_size=self.batch_size)
        return time.perf_counter() - t

    def close(self) -> None:
        self.env.close()


class _Plain:
    """One `ReferenceDDPG` agent on minibatches from our first agent's buffer; ``run(n)`` times
    n updates, each with its own uniform minibatch draw."""

    def __init__(self, ours: _Ours, config: AgentConfig):
        import torch

        from benchmarks.reference import ReferenceDDPG

        trainer = ours.trainer
        self.buffer, self.batch_size = trainer.buffer, config.batch_size
        norm = trainer.agent.normalizer
        self.agent = ReferenceDDPG(config, trainer.agent.in_dim, trainer.agent.act_dim,
                                   mean=norm.mean[0, 0], std=norm.std[0, 0],
                                   device=ours.device, fused=True)
        self.generator = torch.Generator(device=self.buffer.rows.device).manual_seed(0)
        self.run(10)

    def run(self, updates: int) -> float:
        import torch

        rows, size = self.buffer.rows[0], self.buffer.size(0)
        t = time.perf_counter()
        for _ in range(updates):
            idx = torch.randint(size, (self.batch_size,), generator=self.generator,
                                device=rows.device)
            self.agent.update(*self.buffer.layout.split(rows[idx]))
        if rows.device.type == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter() - t

    def close(self) -> None:
        """Nothing of its own to release: the buffer is ``_Ours``'s."""


def machine() -> dict[str, Any]:
    """The CPU model, its logical cores, and the torch build and threads."""
    import torch

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next(line.split(":", 1)[1].strip() for line in f
                       if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {"cpu": cpu, "logical_cpus": os.cpu_count(), "torch": torch.__version__,
            "torch_threads": torch.get_num_threads(),
            "cuda_device": torch.cuda.get_device_name() if torch.cuda.is_available() else None}


def measure(k: int, env_id: str, env_kwargs: dict[str, Any], config: AgentConfig, updates: int,
            rounds: int, fill_episodes: int, device: str, with_sb3: bool,
            with_plain: bool = True) -> dict[str, Any]:
    """Ours and each peer in alternating rounds of ``updates`` updates each; medians of the
    rounds.

    Alternating puts all under the same load from whatever else the machine runs, so their
    ratios hold even where the absolute rates drift.
    """
    ours = _Ours(k, env_id, env_kwargs, config, fill_episodes, device)
    peers: dict[str, Any] = {}
    try:
        if with_sb3:
            peers["sb3"] = _SB3(env_id, env_kwargs, config, fill_episodes, device)
        if with_plain:
            peers["plain"] = _Plain(ours, config)
        ours_s: list[float] = []
        peer_s: dict[str, list[float]] = {name: [] for name in peers}
        for _ in range(rounds):
            ours_s.append(ours.run(updates))
            for name, peer in peers.items():
                peer_s[name].append(peer.run(updates))
    finally:
        ours.close()
        for peer in peers.values():
            peer.close()
    seconds = statistics.median(ours_s)
    result = {"rounds": rounds, "updates_per_round": updates,
              "agent_updates_per_s": k * updates / seconds,
              "update_gflops": ours.flops * updates / seconds / 1e9,
              "update_mflop_per_agent": ours.flops / k / 1e6}
    for name in ("sb3", "plain"):
        times = peer_s.get(name)
        result[f"{name}_updates_per_s"] = updates / statistics.median(times) if times else None
        if times:  # the ratio of each round's pair, so slow phases of the machine cancel
            result[f"speedup_vs_{name}"] = statistics.median(
                k * p / o for o, p in zip(ours_s, times, strict=True))
    return result


ROLLOUT_REGIONS = ("unconstrained", "zheight", "closebox", "farbox")
"""The regions of the paper's grid, which agent k of ``--rollout`` cycles through."""


def measure_rollouts(k: int, joints: int, rounds: int) -> dict[str, float]:
    """Seconds per training episode of ``k`` agents (random actions, one copy each) under the
    ``numpy`` and ``batched`` env backends, alternating rounds; medians, and the median of the
    rounds' ratios as ``rollout_speedup``."""
    import torch

    from ddpg_her.collect import make_envs, rollout

    groups = [{"region": ROLLOUT_REGIONS[i % len(ROLLOUT_REGIONS)], "n_joints": joints}
              for i in range(k)]
    envs = {name: make_envs(name, "UR5Reach-v0", groups, 1)
            for name in ("numpy", "batched")}
    scale = envs["numpy"].scale
    generator = torch.Generator().manual_seed(0)

    def policy(obs: dict, active: torch.Tensor) -> torch.Tensor:
        u = torch.rand((k, scale.dim), generator=generator, dtype=torch.float64)
        return scale.to_env(2.0 * u - 1.0)

    times: dict[str, list[float]] = {name: [] for name in envs}
    for r in range(rounds + 1):  # round 0 warms up (the compiled kernel's first call)
        for name, env in envs.items():
            start = time.perf_counter()
            rollout(env, policy, list(range(r * k, (r + 1) * k)))
            if r:
                times[name].append(time.perf_counter() - start)
    for env in envs.values():
        env.close()
    return {"rollout_agents": k,
            "rollout_numpy_s": statistics.median(times["numpy"]),
            "rollout_batched_s": statistics.median(times["batched"]),
            "rollout_speedup": statistics.median(
                a / b for a, b in zip(times["numpy"], times["batched"], strict=True))}


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(
        prog="python -m benchmarks.agent_updates",
        description="Agent-updates per second of our batched DDPG update next to Stable-"
                    "Baselines3's DDPG + HER and a plain PyTorch DDPG on the same env, and the "
                    "update's GFLOP/s against the machine's float32 matrix-product peak, all "
                    "measured in this run.")
    parser.add_argument("--seeds", type=int, default=5, metavar="K",
                        help="agents trained together (default: %(default)s)")
    parser.add_argument("--region", default="farbox", help="goal region (default: farbox)")
    parser.add_argument("--joints", type=int, default=3, help="controlled joints (default: 3)")
    parser.add_argument("--updates", type=int, default=20,
                        help="timed updates per round, for ours and for SB3 "
                             "(default: %(default)s)")
    parser.add_argument("--rounds", type=int, default=30,
                        help="alternating rounds of ours and SB3; rates are the medians "
                             "(default: %(default)s)")
    parser.add_argument("--fill-episodes", type=int, default=10,
                        help="random-action episodes that fill the buffers first (default: 10)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu",
                        help="device of our agents and of SB3's (default: cpu)")
    parser.add_argument("--stack", type=int, default=0, metavar="K",
                        help="also time one stack of K agents (count, >= 0; 55 is "
                             "the paper's grid in one process; 0: skip)")
    parser.add_argument("--rollout", type=int, default=0, metavar="K",
                        help="also time one training episode of K agents under the numpy and "
                             "the batched env backends (count, >= 0; 20 is the paper grid's "
                             "3-joint agents; 0: skip)")
    parser.add_argument("--no-sb3", action="store_true", help="skip the SB3 measurement")
    parser.add_argument("--no-plain", action="store_true",
                        help="skip the plain-PyTorch (nn.Linear + autograd) measurement")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if min(args.seeds, args.updates, args.rounds, args.fill_episodes) < 1:
        parser.error("--seeds, --updates, --rounds and --fill-episodes must be >= 1, got "
                     f"{args.seeds}, {args.updates}, {args.rounds}, {args.fill_episodes}")
    if args.stack < 0 or args.rollout < 0:
        parser.error(f"--stack and --rollout must be >= 0, got {args.stack}, {args.rollout}")
    if not 2 <= args.joints <= 6:
        parser.error(f"--joints must be in 2..6, got {args.joints}")

    import torch

    from ddpg_her.vecenv import register_env

    if args.threads is not None:
        torch.set_num_threads(args.threads)
    env_id = register_env("UR5Reach-v0")  # SB3's gymnasium.make needs it registered too
    env_kwargs = {"region": args.region, "n_joints": args.joints}
    config = AgentConfig()
    result: dict[str, Any] = {"seeds": args.seeds, "threads": torch.get_num_threads(),
                              "device": args.device, "env_id": env_id, **env_kwargs,
                              "batch_size": config.batch_size,
                              "hidden_sizes": list(config.hidden_sizes)}
    try:
        result.update(measure(args.seeds, env_id, env_kwargs, config, args.updates,
                              args.rounds, args.fill_episodes, args.device, not args.no_sb3,
                              not args.no_plain))
    except ValueError as e:
        parser.error(str(e))
    if args.stack:
        stack = measure(args.stack, env_id, env_kwargs, config, args.updates,
                        max(1, args.rounds // 6), args.fill_episodes, args.device,
                        with_sb3=False, with_plain=False)
        result.update({"stack_agents": args.stack,
                       "stack_agent_updates_per_s": stack["agent_updates_per_s"],
                       "stack_update_gflops": stack["update_gflops"]})
    if args.rollout:
        result.update(measure_rollouts(args.rollout, args.joints, max(3, args.rounds // 6)))
    result["matmul_peak_gflops"] = matmul_peak_gflops(args.device)
    result["peak_fraction"] = result["update_gflops"] / result["matmul_peak_gflops"]
    if args.stack:
        result["stack_peak_fraction"] = (result["stack_update_gflops"]
                                         / result["matmul_peak_gflops"])
    result["machine"] = machine()
    return _report(result, args.json)


def _report(result: dict[str, Any], as_json: bool) -> int:
    """Print the figures: one JSON object, or one aligned line each."""
    if as_json:
        print(json.dumps(result))
        return 0
    for key, value in result.items():
        print(f"{key:>26}: {value:.4g}" if isinstance(value, float) else f"{key:>26}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
