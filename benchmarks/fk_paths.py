"""Forward-kinematics throughput: Pinocchio's Python loop against the batched closed form.

    python -m benchmarks.fk_paths [--n 1000000] [--rounds 3] [--json]

Every path computes the tool0 position of the same random configurations. Paths are measured in
interleaved rounds and the best round of each is kept, so the ratios compare paths that ran
under the same load on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
import pinocchio as pin
import torch
from tqdm import tqdm

import ur5kin
from ddpg_her.config import Parser


@dataclass(frozen=True)
class PathResult:
    """One measured path."""

    name: str
    configs_per_s: float
    """Configurations per second (best round)."""
    ratio_to_loop: float
    """Throughput relative to Pinocchio's Python loop measured in the same run."""
    max_error_m: float
    """Largest deviation from Pinocchio's positions over the batch (m)."""


def pinocchio_loop(q: np.ndarray) -> np.ndarray:
    """tool0 positions by calling Pinocchio once per configuration: what a user writes first."""
    model = ur5kin.load_model()
    data = model.createData()
    frame = model.getFrameId(ur5kin.TOOL_FRAME)
    out = np.empty((len(q), 3))
    for i, qi in enumerate(q):
        pin.forwardKinematics(model, data, qi)
        out[i] = pin.updateFramePlacement(model, data, frame).translation
    return out


def fk_synchronized(q: torch.Tensor) -> torch.Tensor:
    """``ur5kin.fk`` on a tensor already on its device, waiting for a GPU to finish."""
    out = ur5kin.fk(q)
    if out.is_cuda:
        torch.cuda.synchronize()
    return out


def measure(n: int, rounds: int, seed: int, show_progress: bool = True) -> list[PathResult]:
    """Time every path on ``n`` configurations; see the module docstring."""
    q = np.random.default_rng(seed).uniform(-np.pi, np.pi, (n, 6))
    reference = pinocchio_loop(q[: min(n, 20000)])
    paths: dict[str, tuple[Callable, object]] = {
        "pinocchio python loop": (pinocchio_loop, q),
        "numpy closed form (float64)": (ur5kin.fk, q),
    }
    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
    for device in devices:
        for dtype in (torch.float64, torch.float32):
            name = f"torch {device} {str(dtype).removeprefix('torch.')}"
            paths[name] = (fk_synchronized, torch.from_numpy(q).to(device, dtype))
    best = dict.fromkeys(paths, float("inf"))
    errors: dict[str, float] = {}
    steps = [(r, name) for r in range(rounds) for name in paths]
    for _, name in tqdm(steps, desc="benchmarks.fk_paths", disable=not show_progress,
                        file=sys.stderr):
        func, arg = paths[name]
        start = time.perf_counter()
        out = func(arg)
        best[name] = min(best[name], time.perf_counter() - start)
        if name not in errors:
            out_np = out.double().cpu().numpy() if isinstance(out, torch.Tensor) else out
            errors[name] = float(np.abs(out_np[: len(reference)] - reference).max())
    loop_rate = n / best["pinocchio python loop"]
    return [
        PathResult(name, n / best[name], n / best[name] / loop_rate, errors[name]) for name in paths
    ]


def main(argv: list[str] | None = None) -> None:
    parser = Parser(
        prog="python -m benchmarks.fk_paths",
        description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--n", type=int, default=1_000_000,
                        help="configurations per path and round (count)")
    parser.add_argument("--rounds", type=int, default=3,
                        help="interleaved timing rounds; the best round of each path counts")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random configurations")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch CPU threads (count); torch's own choice when omitted")
    parser.add_argument("--json", action="store_true", help="print one JSON object, no table")
    args = parser.parse_args(argv)
    if args.n < 1 or args.rounds < 1:
        parser.error(f"--n and --rounds must be positive; got {args.n} and {args.rounds}")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    results = measure(args.n, args.rounds, args.seed, show_progress=not args.json)
    meta = {
        "n": args.n, "rounds": args.rounds, "torch_threads": torch.get_num_threads(),
        "machine": platform.processor() or platform.machine(), "torch": torch.__version__,
        "pinocchio": pin.__version__, "numpy": np.__version__,
    }
    if args.json:
        print(json.dumps({**meta, "paths": [asdict(r) for r in results]}, indent=2))
        return
    print(f"tool0 FK on {args.n:,} configurations, best of {args.rounds} interleaved rounds, "
          f"{meta['torch_threads']} torch threads")
    print(f"{'path':<30} {'configs/s':>14} {'x loop':>8} {'max err (m)':>12}")
    for r in results:
        print(f"{r.name:<30} {r.configs_per_s:>14,.0f} {r.ratio_to_loop:>8.1f} "
              f"{r.max_error_m:>12.1e}")


if __name__ == "__main__":
    main()
