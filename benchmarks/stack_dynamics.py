"""``python -m benchmarks.stack_dynamics``: one control step of a heterogeneous stack of arm
copies (issue 35: the paper's grid of agents as one program), per kernel, eager and replayed
from a CUDA graph.

Rows, for each N of ``--copies``:

- ``stack-triton``: :class:`envs.physics.stack.StackDynamics` with the Triton kernel, the N
  copies cycling through the grid's tasks (:data:`GRID`: unconstrained with 2..6 joints,
  z-height, close box and far box with 3 and 6: 11 tasks, so N = 55 is the paper's 55 runs);
- (the single-task numba-CUDA kernel went with ``envs.physics.numba_cuda`` after commit
  feb31e4, the torch row, ``envs.physics.torch_kernel.TorchDynamics``, after 401ca32)

Each row runs ``eager`` and ``graph`` (its control step captured once in a
``torch.cuda.CUDAGraph`` and replayed; the command copied into the graph's input first). The
first call (Triton's compilation) is timed apart, and so is
the capture. Protocol as :mod:`benchmarks.cuda_dynamics`: rounds of ``--steps`` steps from the
start pose, the clock read after a device synchronisation, the median over rounds reported.
A row that fails records its error in the JSON instead of ending the run. The Triton kernel's
first call compiles it: about 40 s of one CPU core per dtype and ``--block`` value (measured
offline for sm_90, 39-42 s float64 and 38-39 s float32: ``python -m benchmarks.triton_compile
--dtype float64``; it was 317 s before the tables became constants and the state tiles;
envs/physics/triton_kernel.py), then Triton caches it on disk.

Two checks ride along on a GPU: ``check``, the Triton stack on the device against the numba
CPU kernel's stack over ``--check-steps`` steps of the same commands (max |difference| of q,
rad, and whether the stop flags agree), and ``host_sync_free``, one eager step and masked reset
of the Triton stack under ``torch.cuda.set_sync_debug_mode("error")``.

    python -m benchmarks.stack_dynamics --device cuda --copies 55 5500 --json
    python -m benchmarks.stack_dynamics --dry-run      # the CPU: a check of the script

``--dry-run`` runs on the CPU, tiny: the numba kernel's stack in the Triton row's place, the
Triton kernel under its interpreter (``TRITON_INTERPRET=1``, set before Triton is imported)
with 4 copies and 1 step, no graphs; its times mean nothing.
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
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ddpg_her.config import Parser

GRID = (("unconstrained", 2), ("unconstrained", 3), ("unconstrained", 4), ("unconstrained", 5),
        ("unconstrained", 6), ("zheight", 3), ("zheight", 6), ("closebox", 3), ("closebox", 6),
        ("farbox", 3), ("farbox", 6))
"""(region, n_joints) of the paper's grid; copy i runs ``GRID[i % 11]``."""

MODES = ("eager", "graph")
"""How a row runs: eager, or its control step replayed from a CUDA graph."""

KERNELS = ("stack-triton", "stack-numba")
"""The rows' kernels (``stack-numba``: the stack on the CPU's numba kernel)."""

DRY_RUN = {"copies": (4,), "steps": 1, "rounds": 1, "device": "cpu", "modes": ("eager",),
           "check_steps": 1, "kernels": KERNELS}
"""What ``--dry-run`` overrides: tiny, on the CPU."""


@dataclass(frozen=True)
class BenchConfig:
    """What ``python -m benchmarks.stack_dynamics`` measures (each field is a flag)."""

    copies: tuple[int, ...] = (55, 5500)
    """Copies N of each row."""
    steps: int = 100
    """Control steps per round (one episode of the paper's task)."""
    rounds: int = 5
    """Rounds; each row's median is reported."""
    device: str = "cuda"
    """The GPU: ``cuda`` or ``cuda:N``."""
    dtype: str = "float64"
    """Arithmetic of every kernel."""
    kernels: tuple[str, ...] = ("stack-triton",)
    """Rows' kernels, of :data:`KERNELS`."""
    modes: tuple[str, ...] = MODES
    """Eager and/or graph rows."""
    block: tuple[int, ...] = (32,)
    """Copies per program of the Triton kernel (powers of two), a row each (32:
    :data:`envs.physics.stack.BLOCK`, the default)."""
    check_steps: int = 20
    """Steps of the Triton-against-numba check (0: none)."""
    seed: int = 0
    """Seed of the commands."""
    json: bool = False
    """Print JSON instead of the table."""
    dry_run: bool = False
    """Check the script on the CPU (times mean nothing)."""


def grid_tasks(n: int) -> list[Any]:
    """The tasks of n copies: :data:`GRID` cycled."""
    from envs.spec import TaskSpec

    return [TaskSpec(region=GRID[i % len(GRID)][0], n_joints=GRID[i % len(GRID)][1])
            for i in range(n)]


def make_commands(tasks: list[Any], steps: int, rng: np.random.Generator) -> np.ndarray:
    """Position targets ``(steps, N, 6)`` rad, uniform in each task's action box on its
    first n joints, 0 on the others (ignored by the stack)."""
    from envs.task import action_bounds

    out = np.zeros((steps, len(tasks), 6))
    for b, task in enumerate(tasks):
        low, high = action_bounds(task)
        out[:, b, : len(low)] = rng.uniform(low, high, (steps, len(low)))
    return out


class Row:
    """One stack kernel on the device: ``step(command)`` (a tensor), ``reset()`` (all copies
    at their start pose), ``sync()``."""

    def __init__(self, kernel: str, n: int, config: BenchConfig, block: int | None) -> None:
        import torch

        from envs.physics.stack import BLOCK, StackDynamics

        self.device = torch.device(config.device)
        self.dyn = StackDynamics(grid_tasks(n), device=config.device, dtype=config.dtype,
                                 kernel=kernel.removeprefix("stack-"), block=block or BLOCK)
        everyone = torch.ones(n, dtype=torch.bool, device=self.device)
        self.reset = lambda: self.dyn.reset_where(everyone)
        self.dtype = self.dyn.dtype

    def step(self, command: Any) -> None:
        self.dyn.step(command)

    def sync(self) -> None:
        import torch

        if self.device.type == "cuda":
            torch.cuda.synchronize(self.device)


def measure(kernel: str, mode: str, n: int, commands: np.ndarray, config: BenchConfig,
            block: int | None = None) -> tuple[dict[str, Any], Callable[[], float] | None]:
    """Build a row and time its first call (and its capture); returns the row's record and
    a function timing one round (seconds per step), or the record with the error."""
    import torch

    record: dict[str, Any] = {"kernel": kernel, "mode": mode, "N": n, "block": block}
    try:
        row = Row(kernel, n, config, block)
        on_device = torch.as_tensor(commands, device=config.device, dtype=row.dtype)
        tic = time.perf_counter()
        row.step(on_device[0])
        row.sync()
        record["first_call_s"] = time.perf_counter() - tic
        step: Callable[[Any], None] = row.step
        if mode == "graph":
            static = on_device[0].clone()
            side = torch.cuda.Stream(row.device)
            side.wait_stream(torch.cuda.current_stream(row.device))
            with torch.cuda.stream(side):
                for _ in range(3):  # warm-up off the default stream, as torch asks
                    row.step(static)
            torch.cuda.current_stream(row.device).wait_stream(side)
            graph = torch.cuda.CUDAGraph()
            tic = time.perf_counter()
            with torch.cuda.graph(graph):
                row.step(static)
            row.sync()
            record["capture_s"] = time.perf_counter() - tic

            def step(command: Any) -> None:
                static.copy_(command)
                graph.replay()

        def round_() -> float:
            row.reset()
            row.sync()
            tic = time.perf_counter()
            for command in on_device:
                step(command)
            row.sync()
            return (time.perf_counter() - tic) / len(on_device)

        return record, round_
    except Exception as err:  # a row's failure is a result: record it, go on
        record["error"] = f"{type(err).__name__}: {err}"
        record["traceback"] = traceback.format_exc(limit=6)
        return record, None


def check(config: BenchConfig, n: int, rng: np.random.Generator) -> dict[str, Any]:
    """The Triton stack on the device against the numba CPU kernel's stack (same commands)."""
    import torch

    from envs.physics.stack import StackDynamics

    try:
        tasks = grid_tasks(n)
        commands = make_commands(tasks, config.check_steps, rng)
        gpu = StackDynamics(tasks, device=config.device, dtype=config.dtype, kernel="triton")
        cpu = StackDynamics(tasks, dtype=config.dtype, kernel="numba")
        worst, flags_agree, stops = 0.0, True, 0
        for command in commands:
            gpu.step(torch.as_tensor(command, device=gpu.device, dtype=gpu.dtype))
            cpu.step(torch.as_tensor(command, dtype=cpu.dtype))
            worst = max(worst, float((gpu.q.cpu() - cpu.q).abs().max()))
            flags_agree &= bool(torch.equal(gpu.contact.cpu(), cpu.contact)
                                and torch.equal(gpu.limit_stop.cpu(), cpu.limit_stop))
            stops += int(cpu.contact.sum() + cpu.limit_stop.sum())
        result: dict[str, Any] = {"N": n, "steps": len(commands), "max_abs_q_rad": worst,
                                  "stop_flags_agree": flags_agree, "stops_seen": stops}
    except Exception as err:
        return {"N": n, "error": f"{type(err).__name__}: {err}",
                "traceback": traceback.format_exc(limit=6)}
    if gpu.device.type == "cuda":
        try:
            mask = torch.zeros(n, dtype=torch.bool, device=gpu.device)
            command = torch.zeros(n, 6, dtype=gpu.dtype, device=gpu.device)
            torch.cuda.synchronize()
            torch.cuda.set_sync_debug_mode("error")
            try:
                gpu.step(command)
                gpu.reset_where(mask)
            finally:
                torch.cuda.set_sync_debug_mode("default")
            result["host_sync_free"] = True
        except Exception as err:
            result["host_sync_free"] = f"{type(err).__name__}: {err}"
    return result


def device_name(device: str) -> str:
    """The GPU's name, or the CPU's for a dry run."""
    if device.startswith("cuda"):
        import torch

        return torch.cuda.get_device_name(torch.device(device))
    return platform.processor() or platform.machine()


def run(config: BenchConfig) -> dict[str, Any]:
    """Measure every row; returns the JSON-ready result."""
    rng = np.random.default_rng(config.seed)
    records: list[dict[str, Any]] = []
    timers: list[Callable[[], float] | None] = []
    for n in config.copies:
        commands = make_commands(grid_tasks(n), config.steps, rng)
        for kernel in config.kernels:
            for block in config.block if kernel == "stack-triton" else (None,):
                for mode in config.modes:
                    record, timer = measure(kernel, mode, n, commands, config, block)
                    records.append(record)
                    timers.append(timer)
    samples: list[list[float]] = [[] for _ in records]
    for _ in range(config.rounds):
        for record, timer, values in zip(records, timers, samples, strict=True):
            if timer is None or "error" in record:
                continue
            try:
                values.append(timer())
            except Exception as err:
                record["error"] = f"{type(err).__name__}: {err}"
    for record, values in zip(records, samples, strict=True):
        if values and "error" not in record:
            median = statistics.median(values)
            record.update(us_per_step=1e6 * median, min_us=1e6 * min(values),
                          max_us=1e6 * max(values), copy_steps_per_s=record["N"] / median)
    checks = ([check(config, min(config.copies), rng)]
              if config.check_steps and "stack-triton" in config.kernels else [])
    return {"config": dataclasses.asdict(config), "device": device_name(config.device),
            "machine": {"python": sys.version.split()[0], "platform": platform.platform()},
            "versions": versions(), "rows": records, "checks": checks}


def versions() -> dict[str, str]:
    """The versions of the stack's tools."""
    out = {}
    for name in ("torch", "triton", "numba", "numpy"):
        try:
            out[name] = __import__(name).__version__
        except Exception as err:  # a missing tool is part of the record
            out[name] = f"unavailable ({type(err).__name__})"
    return out


def format_table(result: dict[str, Any]) -> str:
    """The result as a text table."""
    cfg = result["config"]
    lines = [f"control steps on {result['device']} ({cfg['dtype']}), {cfg['steps']} steps x "
             f"{cfg['rounds']} rounds (median, min-max)"
             + ("; DRY RUN on the CPU: the times mean nothing" if cfg["dry_run"] else ""), "",
             f"{'kernel':<16} {'mode':<6} {'N':>6} {'us/step':>10} {'min':>10} {'max':>10} "
             f"{'copy-steps/s':>13} {'first call s':>13}"]
    for r in result["rows"]:
        if "error" in r:
            lines.append(f"{r['kernel']:<16} {r['mode']:<6} {r['N']:>6} ERROR {r['error']}")
            continue
        name = r["kernel"] + (f"/{r['block']}" if r.get("block") else "")
        lines.append(f"{name:<16} {r['mode']:<6} {r['N']:>6} {r['us_per_step']:>10.1f} "
                     f"{r['min_us']:>10.1f} {r['max_us']:>10.1f} "
                     f"{r['copy_steps_per_s']:>13.3g} {r['first_call_s']:>13.2f}")
    for c in result["checks"]:
        lines.append(f"check: {c}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command line: one flag per :class:`BenchConfig` field."""
    parser = Parser(
        prog="python -m benchmarks.stack_dynamics", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    d = BenchConfig()
    parser.add_argument("--copies", type=int, nargs="+", default=list(d.copies),
                        help="copies N of each row (>= 1; the stack cycles the 11 grid tasks)")
    parser.add_argument("--steps", type=int, default=d.steps,
                        help="control steps per round, from the start pose (>= 1)")
    parser.add_argument("--rounds", type=int, default=d.rounds,
                        help="rounds (>= 1); each row's median is reported")
    parser.add_argument("--device", default=d.device, help="the GPU: cuda or cuda:N")
    parser.add_argument("--dtype", default=d.dtype, choices=("float64", "float32"),
                        help="arithmetic of every kernel")
    parser.add_argument("--kernels", nargs="+", default=list(d.kernels), choices=KERNELS,
                        help="the rows' kernels")
    parser.add_argument("--modes", nargs="+", default=list(d.modes), choices=MODES,
                        help="eager and/or graph (the step replayed from a CUDA graph)")
    parser.add_argument("--block", type=int, nargs="+", default=list(d.block),
                        help="copies per program of the Triton kernel (powers of two), a row "
                        "each")
    parser.add_argument("--check-steps", type=int, default=d.check_steps,
                        help="control steps of the Triton-against-numba check (0: none)")
    parser.add_argument("--seed", type=int, default=d.seed, help="seed of the commands")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")
    parser.add_argument("--dry-run", action="store_true",
                        help="check the script on the CPU: 4 copies, 1 step, eager, the Triton "
                        "kernel under its interpreter (times mean nothing)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    fields = {f.name: getattr(args, f.name) for f in dataclasses.fields(BenchConfig)}
    fields.update({k: tuple(v) for k, v in fields.items() if isinstance(v, list)})
    if args.dry_run:
        fields.update(DRY_RUN)
        if "triton" in sys.modules:
            raise SystemExit("--dry-run must set TRITON_INTERPRET before triton is imported")
        os.environ["TRITON_INTERPRET"] = "1"
    config = BenchConfig(**fields)
    if min(config.copies) < 1 or config.steps < 1 or config.rounds < 1 \
            or config.check_steps < 0:
        raise SystemExit(f"--copies, --steps and --rounds must be >= 1, --check-steps >= 0; "
                         f"got {config.copies}, {config.steps}, {config.rounds}, "
                         f"{config.check_steps}")
    if not config.dry_run:
        import torch

        if not config.device.startswith("cuda") or not torch.cuda.is_available():
            raise SystemExit(f"--device {config.device}: needs a CUDA device torch sees "
                             f"(available: {torch.cuda.is_available()}); --dry-run checks the "
                             "script on the CPU")
    result = run(config)
    print(json.dumps(result, indent=2) if config.json else format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
