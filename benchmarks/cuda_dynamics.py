"""``python -m benchmarks.cuda_dynamics``: one control step of N arm copies on a GPU, the fused
numba-CUDA kernel against the torch backend on the same device (issue 24).

Rows, for each N of ``--sizes``: ``numba-cuda`` (:class:`envs.physics.numba_cuda.
NumbaCudaDynamics`, one kernel launch per control step, one thread per copy, for each
``--threads-per-block``) and ``torch`` (:class:`envs.physics.torch_kernel.TorchDynamics`,
eager and/or its control step replayed as one CUDA graph). Issue 24's goals: a control step of
55 copies (the paper's grid, one copy per run) in at most 50 us, and at least 5 M copy-steps/s
at N = 4,096.

Protocol: a round is one episode of every row, rows alternating: the copies put at the start
pose (off the clock), then ``--steps`` control steps of commands drawn uniform in the action
box before the clock, on the device (no host copy in a step: the numba kernel's host mirror is
off), the clock read after a device synchronisation. Reported per row: the median over rounds
of the time per control step (us), its min and max, copy-steps/s (N over the median step
time), and the first step's seconds (the numba kernel's compilation, the CUDA graph's capture).

    python -m benchmarks.cuda_dynamics                         # 55, 4096 and 65536 copies
    python -m benchmarks.cuda_dynamics --torch eager graph --threads-per-block 32 64 128 --json
    python -m benchmarks.cuda_dynamics --dry-run               # the CPU: a check of the script

``--dry-run`` runs every row on the CPU, tiny: torch on the CPU and the numba kernel under
numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, set before numba is imported); its times
mean nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

TORCH_MODES = ("eager", "graph")
"""How the torch row runs: eager, or its control step recorded once as a CUDA graph."""

DRY_RUN = {"sizes": (3,), "steps": 2, "rounds": 1, "device": "cpu", "torch": ("eager",),
           "threads_per_block": (2,)}
"""What ``--dry-run`` overrides: tiny, on the CPU (the numba kernel in numba's simulator)."""


@dataclass(frozen=True)
class BenchConfig:
    """What ``python -m benchmarks.cuda_dynamics`` measures (each field is a command-line flag)."""

    sizes: tuple[int, ...] = (55, 4096, 65536)
    """Copies N of each row."""
    steps: int = 100
    """Control steps per round (100: one episode of the paper's task)."""
    rounds: int = 5
    """Rounds; each row's median over them is reported."""
    device: str = "cuda"
    """The GPU of both backends: ``cuda`` or ``cuda:N``."""
    dtype: str = "float64"
    """Arithmetic of both backends: float64 (the env's) or float32."""
    torch: tuple[str, ...] = ("graph",)
    """Torch rows: ``eager`` and/or ``graph`` (the control step as one CUDA graph); none:
    the numba kernel alone."""
    threads_per_block: tuple[int, ...] = (64,)
    """Copies per block of the numba kernel's launch, one row each."""
    region: str = "unconstrained"
    """Goal region of the task (its start pose and base height)."""
    n_joints: int = 3
    """Controlled joints (2-6)."""
    control_mode: str = "position"
    """Control mode: position, velocity or torque."""
    held_joints: str = "locked"
    """How the other joints are held: locked (out of the dynamics) or pd."""
    seed: int = 0
    """Seed of the commands."""
    json: bool = False
    """Print JSON instead of the table."""
    dry_run: bool = False
    """Run on the CPU, tiny (:data:`DRY_RUN`): a check of the script, not a measurement."""


def make_task(config: BenchConfig) -> Any:
    """The task of the benchmark."""
    from envs.spec import TaskSpec

    return TaskSpec(region=config.region, n_joints=config.n_joints,
                    control_mode=config.control_mode, held_joints=config.held_joints)


def numba_row(task: Any, commands: np.ndarray, config: BenchConfig, block: int
              ) -> tuple[Callable[[], float], float]:
    """The numba-CUDA row: a function timing one round (seconds per control step), and the
    first step's seconds (compilation included)."""
    from numba import cuda

    from envs.physics.numba_cuda import NumbaCudaDynamics

    device = "cuda" if config.dry_run else config.device
    dyn = NumbaCudaDynamics(task, commands.shape[1], dtype=config.dtype, device=device,
                            mirror=False, threads_per_block=block)
    on_device = [cuda.to_device(np.ascontiguousarray(c, dtype=config.dtype)) for c in commands]
    start = time.perf_counter()
    dyn.step(on_device[0])
    dyn.synchronize()
    first = time.perf_counter() - start

    def round_() -> float:
        dyn.reset(task.start_q)
        dyn.synchronize()
        tic = time.perf_counter()
        for command in on_device:
            dyn.step(command)
        dyn.synchronize()
        return (time.perf_counter() - tic) / len(on_device)

    return round_, first


def torch_row(task: Any, commands: np.ndarray, config: BenchConfig, mode: str
              ) -> tuple[Callable[[], float], float]:
    """The torch row (``mode`` eager or graph): as :func:`numba_row`."""
    import torch

    from envs.physics.torch_kernel import TorchDynamics

    dyn = TorchDynamics(task, commands.shape[1], device=config.device, dtype=config.dtype,
                        cuda_graph=mode == "graph")
    on_device = torch.as_tensor(commands, device=config.device, dtype=dyn.dtype)

    def synchronize() -> None:
        if dyn.device.type == "cuda":
            torch.cuda.synchronize(dyn.device)

    start = time.perf_counter()
    dyn.step(on_device[0])
    synchronize()
    first = time.perf_counter() - start

    def round_() -> float:
        dyn.reset(task.start_q)
        synchronize()
        tic = time.perf_counter()
        for command in on_device:
            dyn.step(command)
        synchronize()
        return (time.perf_counter() - tic) / len(on_device)

    return round_, first


def device_name(device: str) -> str:
    """The GPU's name, or the CPU's for a dry run."""
    if device.startswith("cuda"):
        import torch

        return torch.cuda.get_device_name(torch.device(device))
    return platform.processor() or platform.machine()


def run(config: BenchConfig) -> dict[str, Any]:
    """Measure every row; returns the JSON-ready result."""
    from envs.task import action_bounds

    task = make_task(config)
    low, high = action_bounds(task)
    rng = np.random.default_rng(config.seed)
    rows: list[dict[str, Any]] = []
    timers: list[Callable[[], float]] = []
    for n in config.sizes:
        commands = rng.uniform(low, high, (config.steps, n, len(low)))
        for block in config.threads_per_block:
            timer, first = numba_row(task, commands, config, block)
            rows.append({"backend": "numba-cuda", "N": n, "threads_per_block": block,
                         "first_step_s": first})
            timers.append(timer)
        for mode in config.torch:
            timer, first = torch_row(task, commands, config, mode)
            rows.append({"backend": f"torch ({mode})", "N": n, "threads_per_block": None,
                         "first_step_s": first})
            timers.append(timer)
    samples: list[list[float]] = [[] for _ in rows]
    for _ in range(config.rounds):
        for timer, values in zip(timers, samples, strict=True):
            values.append(timer())
    for row, values in zip(rows, samples, strict=True):
        median = statistics.median(values)
        row.update(us_per_step=1e6 * median, min_us=1e6 * min(values), max_us=1e6 * max(values),
                   copy_steps_per_s=row["N"] / median)
    return {
        "config": dataclasses.asdict(config),
        "task": task.to_dict(),
        "substeps_per_step": task.substeps,
        "device": device_name(config.device),
        "machine": {"python": sys.version.split()[0], "platform": platform.platform()},
        "goals": {"us_per_step_at_55": 50.0, "copy_steps_per_s_at_4096": 5e6},
        "rows": rows,
    }


def format_table(result: dict[str, Any]) -> str:
    """The result as a text table."""
    cfg = result["config"]
    lines = [f"control steps on {result['device']} ({cfg['dtype']}): region {cfg['region']}, "
             f"{cfg['n_joints']} joints, {cfg['control_mode']} control, held "
             f"{cfg['held_joints']}, {result['substeps_per_step']} substeps/step; "
             f"{cfg['steps']} steps x {cfg['rounds']} rounds (median, min-max)"
             + ("; DRY RUN on the CPU: the times mean nothing" if cfg["dry_run"] else ""),
             "",
             f"{'backend':<24} {'N':>7} {'us/step':>10} {'min':>10} {'max':>10} "
             f"{'copy-steps/s':>13} {'first step s':>13}"]
    for row in result["rows"]:
        name = row["backend"] + (f", {row['threads_per_block']}/block"
                                 if row["threads_per_block"] else "")
        lines.append(f"{name:<24} {row['N']:>7} {row['us_per_step']:>10.1f} "
                     f"{row['min_us']:>10.1f} {row['max_us']:>10.1f} "
                     f"{row['copy_steps_per_s']:>13.3g} {row['first_step_s']:>13.2f}")
    lines.append("issue 24's goals: <= 50 us per step at N = 55, >= 5 M copy-steps/s at "
                 "N = 4096")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command line: one flag per :class:`BenchConfig` field."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.cuda_dynamics", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    d = BenchConfig()
    parser.add_argument("--sizes", type=int, nargs="+", default=list(d.sizes),
                        help="copies N of each row (>= 1)")
    parser.add_argument("--steps", type=int, default=d.steps,
                        help="control steps per round, from the start pose (>= 1)")
    parser.add_argument("--rounds", type=int, default=d.rounds,
                        help="rounds (>= 1); each row's median is reported")
    parser.add_argument("--device", default=d.device,
                        help="the GPU of both backends: cuda or cuda:N")
    parser.add_argument("--dtype", default=d.dtype, choices=("float64", "float32"),
                        help="arithmetic of both backends")
    parser.add_argument("--torch", nargs="*", default=list(d.torch), choices=TORCH_MODES,
                        help="torch rows: eager and/or graph (its control step as one CUDA "
                        "graph); none given: the numba kernel alone")
    parser.add_argument("--threads-per-block", type=int, nargs="+",
                        default=list(d.threads_per_block),
                        help="copies per block of the numba kernel (1-1024), a row each")
    parser.add_argument("--region", default=d.region,
                        help="goal region of the task (its start pose and base height)")
    parser.add_argument("--n-joints", type=int, default=d.n_joints,
                        help="controlled joints (2-6)")
    parser.add_argument("--control-mode", default=d.control_mode,
                        choices=("position", "velocity", "torque"),
                        help="command meaning: angles (rad), velocities (rad/s), torques (N m)")
    parser.add_argument("--held-joints", default=d.held_joints, choices=("locked", "pd"),
                        help="the joints beyond --n-joints: locked out of the dynamics, or held "
                        "by the PD")
    parser.add_argument("--seed", type=int, default=d.seed, help="seed of the commands")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")
    parser.add_argument("--dry-run", action="store_true",
                        help="check the script on the CPU: tiny sizes, torch eager on the CPU, "
                        "the numba kernel in numba's CUDA simulator (times mean nothing)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    fields = {f.name: getattr(args, f.name) for f in dataclasses.fields(BenchConfig)}
    fields.update({k: tuple(v) for k, v in fields.items() if isinstance(v, list)})
    if args.dry_run:
        fields.update(DRY_RUN)
        if "numba" in sys.modules:
            raise SystemExit("--dry-run must set NUMBA_ENABLE_CUDASIM before numba is imported")
        os.environ["NUMBA_ENABLE_CUDASIM"] = "1"
    config = BenchConfig(**fields)
    if min(config.sizes) < 1 or config.steps < 1 or config.rounds < 1:
        raise SystemExit(f"--sizes, --steps and --rounds must be >= 1; got {config.sizes}, "
                         f"{config.steps}, {config.rounds}")
    if not all(1 <= b <= 1024 for b in config.threads_per_block):
        raise SystemExit(f"--threads-per-block must be in 1..1024; got "
                         f"{config.threads_per_block}")
    if not config.dry_run:
        import torch
        from numba import cuda

        from envs.physics.numba_cuda import device_index

        try:
            device_index(config.device)
        except ValueError as err:
            raise SystemExit(f"--device: {err}") from None
        if not (torch.cuda.is_available() and cuda.is_available()):
            raise SystemExit(f"--device {config.device}: no CUDA device here (torch sees one: "
                             f"{torch.cuda.is_available()}, numba: {cuda.is_available()}); "
                             "--dry-run checks the script on the CPU")
    result = run(config)
    print(json.dumps(result, indent=2) if config.json else format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
