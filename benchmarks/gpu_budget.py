"""``python -m benchmarks.gpu_budget``: the training program's GPU budget counted on the CPU
(issue 42): kernel launches, bytes moved and FLOPs of each body of one grid episode, the arm
kernel's figures from Triton's compiler for sm_90, and a projection of milliseconds per grid
episode on a GPU from stated parameters.

The grid is the paper's (`benchmarks.grid_episode`: 55 agents, or ``--part J`` the settings with
J joints, 400-300 networks, T = 100 steps, 100 updates per episode), built as the program
(``ddpg_her.program``) trains it, run eagerly on the CPU. Each body is run once under a
dispatch-level counter (`benchmarks.launches.LaunchCounter`; the arm kernel, called directly,
counts one launch per call, as its Triton launch does on CUDA):

- ``warm``: a random-action training episode (rollout + store);
- ``act``: a training episode of the actors (rollout + store), the paper's episodes 101 on;
- ``learn``: the ``updates_per_episode`` updates (and ``per_update``, that over the updates);
- ``test``: a test session, amortised over ``eval_every`` episodes;
- ``between``: the eager ops of `Program.step` outside the bodies (the finite-loss check).

A grid episode is ``act + learn + between + test / eval_every``.

Bytes and FLOPs are estimated per counted op from its tensors: bytes as the sum over its
tensor inputs and outputs of elements x element size (each read and written once, as one
kernel does; broadcast inputs counted at their stored size); FLOPs as ``2 M N K`` for a matrix
product and one per output element for any other op. The arm kernel's bytes are its state
tensors read and written once per call; its arithmetic is the compiled figures' (``arm``).

The projection (``--node-us`` and the others: every parameter a flag) is

    ms = sum over bodies of (launches x node_us + bytes / bandwidth + flops / tflops
                             + arm launches x arm_us_per_step)

with the update's body taken from its measurement instead: ``--update-ms`` measured with
``--update-launches`` launches, less ``node_us`` for each launch removed since, never below
its bytes / bandwidth. ``arm_us_per_step`` is ``--arm-us-per-step`` (one lane's latency), or
the FP64 instructions of all copies at ``--fp64-tflops`` if more; the static SASS count at
``--cycles-per-instruction`` and ``--clock-ghz`` is reported beside it (a lower bound: loops
inside a substep, such as the exact-height pass, run more than once). One JSON object
on stdout (``--out`` writes it too, the counts first).

    python -m benchmarks.gpu_budget --out results/grid_program/gpu_budget.json
    python -m benchmarks.gpu_budget --part 3 --no-arm
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

from benchmarks.launches import LaunchCounter
from ddpg_her.config import Parser

MATMULS = frozenset({"mm", "addmm", "bmm", "baddbmm", "matmul"})
"""Ops whose FLOPs are ``2 M N K`` (the rest: one per output element)."""

GUARD = {"part": 2, "seeds": 1,
         "unit_args": "--buffer-size 2000 --hidden-sizes 16 16 --eval-episodes 1"}
"""The small stack whose counts the suite compares (tests/test_gpu_budget.py): one agent, the
same bodies' code."""

UNIT_ARGS = ("--buffer-size", "20000")
"""The units' extra ``ddpg_her.train`` arguments of the count: a small ring buffer (the count
and the bytes of the store and the update do not depend on its capacity)."""


class TrafficCounter(LaunchCounter):
    """`LaunchCounter` that also sums each counted op's bytes and FLOPs (see the module's
    docstring), and the arm kernel's state bytes per call (``arm_bytes``, set by the caller)."""

    def __init__(self, arm_bytes: int = 0) -> None:
        super().__init__()
        self.bytes = 0
        self.flops = 0
        self.arm_bytes = arm_bytes

    def __torch_dispatch__(self, func: Any, types: Any, args: tuple = (),
                           kwargs: dict | None = None) -> Any:
        before = self.total
        out = super().__torch_dispatch__(func, types, args, kwargs)
        if self.total == before:  # a view, an allocation or a host read: no kernel
            return out
        tensors = [t for t in _leaves((args, kwargs or {}, out)) if isinstance(t, torch.Tensor)]
        self.bytes += sum(_stored_bytes(t) for t in tensors)
        name = func.overloadpacket.__name__
        if name in MATMULS:
            a, b = _matmul_operands(name, args)
            self.flops += 2 * a.numel() * b.shape[-1]
        else:
            outs = [t for t in _leaves(out) if isinstance(t, torch.Tensor)]
            self.flops += sum(t.numel() for t in outs)
        return out


def _matmul_operands(name: str, args: tuple) -> tuple[torch.Tensor, torch.Tensor]:
    """The two factors of a matrix product op (addmm / baddbmm take the sum first)."""
    return (args[1], args[2]) if name in ("addmm", "baddbmm") else (args[0], args[1])


def _leaves(x: Any) -> list[Any]:
    if isinstance(x, (list, tuple)):
        return [y for item in x for y in _leaves(item)]
    if isinstance(x, dict):
        return [y for item in x.values() for y in _leaves(item)]
    return [x]


def _stored_bytes(t: torch.Tensor) -> int:
    """Bytes a kernel reads or writes of ``t``: its elements, a broadcast (stride-0) axis
    counted once."""
    n = 1
    for size, stride in zip(t.shape, t.stride(), strict=True):
        if stride != 0:
            n *= size
    return n * t.element_size()


def build(part: int | None, seeds: int, unit_args: Sequence[str], folder: Path, fused: bool
          ) -> Any:
    """The grid (or its ``part``) as one `ddpg_her.program.Program` on the CPU, eager, its
    rollouts through `ddpg_her.program_kernels` (Triton's interpreter) where ``fused``."""
    from benchmarks.grid_episode import GridSpec, grid_settings, grid_units
    from ddpg_her.config import AgentConfig
    from ddpg_her.program import Program

    budget = AgentConfig().eval_every
    spec = GridSpec(grid_settings(part), seeds, "cpu", folder, tuple(unit_args), budget)
    program = Program.of_settings(grid_units(spec), device="cpu", progress=False, fused=fused)
    program.agent.fused = fused  # the update's kernels too, as on CUDA
    return program


def arm_state_bytes(env: Any) -> int:
    """Bytes the arm kernel reads and writes per call: its state and inputs once each."""
    d = env.dynamics
    read = [d.q, d.w, d.height_bound, d._bias, d.n_joints]
    written = [d.q, d.w, d.height_bound, d._dw, d.contact, d.limit_stop, d.tool]
    return sum(t.numel() * t.element_size() for t in read + written)


def counted(body: Callable[[], None], arm_bytes: int) -> dict[str, Any]:
    """``body()`` once under a `TrafficCounter`: launches (in all, the arm's, the top ops),
    bytes, FLOPs."""
    with TrafficCounter(arm_bytes) as c:
        body()
    arm = c.by_op.get("arm", 0)
    return {"launches": c.total, "arm_launches": arm, "bytes": c.bytes + arm * arm_bytes,
            "flops": c.flops, "syncs": c.syncs, "top_ops": dict(c.by_op.most_common(12))}


UPDATE_KERNELS = ("normalize", "head", "backward", "adam")
"""`ddpg_her.program_kernels`' kernels of the update, whose bytes `moving` counts."""


def moving(name: str, launch: Callable[..., Any]) -> Callable[..., Any]:
    """`LaunchCounter.wrap` that also adds to a `TrafficCounter` each tensor argument's bytes
    twice (read and written once: an upper bound, the update's kernels write some of them)."""
    counted = LaunchCounter.wrap(name, launch)

    def run(*args: Any, **kwargs: Any) -> Any:
        if isinstance(LaunchCounter.active, TrafficCounter):
            LaunchCounter.active.bytes += 2 * sum(
                _stored_bytes(t) for t in _leaves((args, kwargs)) if isinstance(t, torch.Tensor))
        return counted(*args, **kwargs)

    return run


def count_bodies(program: Any) -> dict[str, Any]:
    """Each body of ``program`` (freshly built, at episode 0) run once, counted, in the order
    a run meets them: warm, act, learn, the finite check, test."""
    import envs.physics.stack as stack
    from ddpg_her import program_kernels

    kernel = stack.control_step
    stack.control_step = LaunchCounter.wrap("arm", kernel)
    fused = {name: getattr(program_kernels, name)
             for name in ("explore", "settle", *UPDATE_KERNELS)}
    for name, launch in fused.items():
        setattr(program_kernels, name, (moving if name in UPDATE_KERNELS else LaunchCounter.wrap)(
            name, launch))
    try:
        train_bytes = arm_state_bytes(program.env)
        bodies = {"warm": counted(lambda: program._train_episode(warm=True), train_bytes),
                  "act": counted(lambda: program._train_episode(warm=False), train_bytes)}
        bodies["learn"] = counted(program._learn, 0)

        def between() -> None:
            program._finite &= torch.isfinite(program.loss_sum).all()

        bodies["between"] = counted(between, 0)
        bodies["test"] = counted(program._test_session, arm_state_bytes(program.eval_env))
    finally:
        stack.control_step = kernel
        for name, launch in fused.items():
            setattr(program_kernels, name, launch)
    return bodies


def grid_episode(bodies: dict[str, Any], config: Any) -> dict[str, Any]:
    """The figures of one grid episode from the bodies': act + learn + between + test /
    eval_every; ``per_update`` the learn body over its updates."""
    every, updates = config.eval_every, config.updates_per_episode
    keys = ("launches", "bytes", "flops", "arm_launches")
    total = {k: bodies["act"][k] + bodies["learn"][k] + bodies["between"][k]
             + bodies["test"][k] / every for k in keys}
    return {"per_grid_episode": {k: round(v, 1) for k, v in total.items()},
            "rollout_store": bodies["act"]["launches"],
            "per_update": bodies["learn"]["launches"] / max(updates, 1),
            "test_amortised": bodies["test"]["launches"] / every}


# ---------------------------------------------------------------------------- the arm kernel
PTXAS_REGISTERS = re.compile(r"Used (\d+) registers")
PTXAS_FRAME = re.compile(r"(\d+) bytes stack frame, (\d+) bytes spill stores, (\d+) bytes spill "
                         r"loads")
"""ptxas ``-v``'s resource lines (the frame line precedes the registers' line)."""


def ptxas_usage(log: str) -> dict[str, int]:
    """Registers, stack frame and spills (bytes) from a ptxas ``-v`` log of one kernel."""
    regs, frame = PTXAS_REGISTERS.search(log), PTXAS_FRAME.search(log)
    if regs is None or frame is None:
        raise RuntimeError(f"ptxas printed no resource line: {log[-500:]!r}")
    stack, stores, loads = map(int, frame.groups())
    return {"registers": int(regs.group(1)), "stack_bytes": stack,
            "spill_store_bytes": stores, "spill_load_bytes": loads}


SASS_LINE = re.compile(r"/\*[0-9a-f]{4,}\*/\s+(?:@!?U?P\w+\s+)?([A-Z][A-Z0-9_.]*)")
"""An instruction of ``cuobjdump -sass``: its opcode (after any predicate)."""


def arm_figures(dtype: str, arch: int, block: int | None) -> dict[str, Any]:
    """`benchmarks.triton_compile.compile_kernel`'s figures of the arm kernel for sm_``arch``:
    ptxas's registers, stack and spills, and the SASS's instruction counts (whole kernel and
    per substep), as that module reads them from the cubin it compiles."""
    from benchmarks import triton_compile

    figures = triton_compile.compile_kernel(dtype, arch, block)
    sass = figures["sass"]
    return {**{k: figures[k] for k in ("dtype", "arch", "block", "substeps", "cpu_s",
                                       "ptx_lines", "ptx_f64_lines", "triton", "registers",
                                       "stack_bytes", "spill_store_bytes", "spill_load_bytes")
               if k in figures},
            "sass_instructions": sass["instructions"],
            "sass_fp64_instructions": sass["fp64_instructions"],
            "sass_substep_loop": sass.get("substep_loop")}


FP64_OPS = frozenset({"DADD", "DMUL", "DFMA", "DSETP", "DMNMX", "DSET", "F2F", "I2F", "F2I",
                      "MUFU"})
"""SASS opcodes counted as FP64 work (the double-precision pipe's, and its conversions and
special-function steps: on sm_90 the FP64 unit runs these)."""


def fused_figures(arch: int) -> dict[str, Any]:
    """ptxas's resources of `ddpg_her.program_kernels`' kernels compiled for sm_``arch``
    (every noise kind of ``_explore``; ``_settle`` with float32 inputs, the program's)."""
    import contextlib
    import io

    import triton
    from triton import knobs
    from triton.backends.compiler import GPUTarget
    from triton.compiler.compiler import ASTSource

    from ddpg_her import program_kernels as pk

    f64, target, out = "*fp64", GPUTarget("cuda", arch, 32), {}
    explore = dict.fromkeys(("mu",), "*fp32") | dict.fromkeys(
        ("table", "ou", "mask", "low", "high", "env_low", "env_high", "gain", "stored",
         "env_action", "bias", "params"), f64) | {"active": "*i8"}
    settle = dict.fromkeys(("q", "w", "dw", "acceleration", "v", "tool", "goal", "action",
                            "scale", "mask", "ret", "final", "reward", "params", "obs",
                            "achieved"), f64) \
        | dict.fromkeys(("elapsed", "length"), "*i64") \
        | dict.fromkeys(("active", "success", "term"), "*i8") \
        | dict.fromkeys(("x", "mean", "std"), "*fp32")
    cases = [(f"explore_{kind}", pk._explore, explore,
              dict(KIND=value, STORE=True, BLOCK=pk.BLOCK)) for kind, value in pk.KINDS.items()]
    cases.append(("settle", pk._settle, settle,
                  dict(STORE=True, NORM=True, DENSE=True, BLOCK=pk.BLOCK)))
    f32 = dict.fromkeys(("x", "x2", "mean", "std", "out", "q", "r", "term", "c2", "w3", "dc2",
                         "gw3", "gb3", "gb2", "loss", "grad", "gb", "params", "grads",
                         "exp_avg", "exp_avg_sq", "steps"), "*fp32") \
        | dict.fromkeys(("clip", "acc", "gamma", "hyper"), f64) | {"starts": "*i64"}
    tiles = dict(BLOCK_N=256, BLOCK_H=16)     # the paper's minibatch of 256
    cases += [("update_normalize", pk._normalize, f32, dict(BLOCK_R=32, BLOCK_D=32)),
              ("update_head_critic", pk._head, f32, dict(CRITIC=True, **tiles)),
              ("update_head_actor", pk._head, f32, dict(CRITIC=False, **tiles)),
              ("update_backward_relu", pk._backward, f32, dict(TANH=False, **tiles)),
              ("update_backward_tanh", pk._backward, f32, dict(TANH=True, **tiles)),
              ("update_adam", pk._adam, f32, dict(READ=1, WRITE=0, INC=1, SEGMENTS=6,
                                                  BLOCK=1024))]
    knobs.nvidia.dump_ptxas_log = True
    try:
        for name, fn, pointers, constants in cases:
            signature = {a: pointers.get(a, "i32") for a in fn.arg_names if a not in constants}
            log = io.StringIO()
            with contextlib.redirect_stdout(log):
                triton.compile(ASTSource(fn, {**signature, **dict.fromkeys(constants,
                                                                           "constexpr")},
                                         constants), target=target)
            out[name] = ptxas_usage(log.getvalue())
    finally:
        knobs.nvidia.dump_ptxas_log = False
    return out


def compiled_arm(arch: int) -> dict[str, Any]:
    """`arm_figures` in a child process without ``TRITON_INTERPRET`` (this process counts
    under Triton's interpreter, which compiles nothing)."""
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    out = subprocess.run([sys.executable, "-m", "benchmarks.gpu_budget", "--arm-only",
                          "--arch", str(arch)], env=env, check=True, capture_output=True,
                         text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


# ---------------------------------------------------------------------------- projection
def project(counts: dict[str, Any], arm: dict[str, Any] | None, p: argparse.Namespace
            ) -> dict[str, Any]:
    """Milliseconds per grid episode on a GPU from ``counts`` (`count`'s), the arm's compiled
    figures and the parameters ``p`` (the module's docstring gives the formula)."""
    bodies, every, updates = counts["bodies"], counts["eval_every"], counts["updates_per_episode"]
    copies, eval_copies = counts["train_copies"], counts["eval_copies"]
    fp64 = 0 if arm is None else arm["sass_fp64_instructions"] * arm["substeps"]
    throughput = {"train": fp64 * copies / (p.fp64_tflops * 1e6),
                  "test": fp64 * eval_copies / (p.fp64_tflops * 1e6)}
    arm_us = {k: max(p.arm_us_per_step, v) for k, v in throughput.items()}
    static = None if arm is None else (arm["sass_instructions"] * arm["substeps"]
                                       * p.cycles_per_instruction / (p.clock_ghz * 1e3))

    def body_ms(b: dict[str, Any], arm_step_us: float) -> float:
        return (b["launches"] * p.node_us * 1e-3 + b["bytes"] / (p.bandwidth_gbs * 1e6)
                + b["flops"] / (p.tflops * 1e9) + b["arm_launches"] * arm_step_us * 1e-3)

    per_update = bodies["learn"]["launches"] / updates
    floor = bodies["learn"]["bytes"] / updates / (p.bandwidth_gbs * 1e6)
    update_ms = max(p.update_ms - (p.update_launches - per_update) * p.node_us * 1e-3, floor)
    ms = {"rollout_store": body_ms(bodies["act"], arm_us["train"]),
          "updates": updates * update_ms,
          "between": body_ms(bodies["between"], 0.0),
          "test_amortised": body_ms(bodies["test"], arm_us["test"]) / every}
    return {"ms_per_grid_episode": round(sum(ms.values()), 2),
            "ms_by_part": {k: round(v, 2) for k, v in ms.items()},
            "update_ms": round(update_ms, 4), "update_traffic_floor_ms": round(floor, 4),
            "arm_us_per_step": {k: round(v, 1) for k, v in arm_us.items()},
            "arm_static_sass_us_per_step": None if static is None else round(static, 1),
            "parameters": {k: getattr(p, k) for k in PROJECTION_FLAGS}}


PROJECTION_FLAGS = ("node_us", "bandwidth_gbs", "tflops", "fp64_tflops", "clock_ghz",
                    "cycles_per_instruction", "arm_us_per_step", "update_ms", "update_launches")


def count(args: argparse.Namespace) -> dict[str, Any]:
    """The counts of the grid (``args.part``, ``args.seeds``) and of the suite's `GUARD`."""
    import shlex

    os.environ["TRITON_INTERPRET"] = "1"      # before ddpg_her.program_kernels is imported
    torch.set_num_threads(1)
    tic = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="gpu_budget-") as tmp:
        program = build(args.part, args.seeds, shlex.split(args.unit_args), Path(tmp),
                        not args.eager)
        try:
            bodies = count_bodies(program)
        finally:
            program.close()
        guard = {**GUARD, "launches": {}}
        if not args.no_guard:
            small = build(GUARD["part"], GUARD["seeds"], shlex.split(GUARD["unit_args"]),
                          Path(tmp) / "guard", not args.eager)
            try:
                guard["launches"] = {k: v["launches"] for k, v in count_bodies(small).items()}
            finally:
                small.close()
    cfg = program.config
    return {"path": "eager" if args.eager else "fused", "agents": program.k,
            "part": args.part, "seeds": args.seeds, "unit_args": args.unit_args, "T": program.T,
            "updates_per_episode": cfg.updates_per_episode, "eval_every": cfg.eval_every,
            "train_copies": program.env.num_envs, "eval_copies": program.eval_env.num_envs,
            **grid_episode(bodies, cfg), "bodies": bodies, "guard": guard,
            "count_s": round(time.perf_counter() - tic, 1), "torch": torch.__version__,
            "method": {"launches": "non-view ATen ops at dispatch level "
                       "(benchmarks.launches.LaunchCounter), the arm kernel and each fused "
                       "kernel one per call",
                       "bytes": "per op: its tensor inputs and outputs, elements x size, "
                       "stride-0 axes once; the arm: its state read and written once; the "
                       "update's kernels: each tensor argument twice; the rollout's fused "
                       "kernels: not counted (their rows: about 0.5 kB per copy)",
                       "flops": "2 M N K per matrix product, one per output element "
                       "otherwise; the arm's and the fused kernels' not included"}}


def positive(text: str) -> float:
    """A rate or clock flag's value: a finite number > 0."""
    value = float(text)
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m benchmarks.gpu_budget", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--part", type=int, default=None, metavar="J",
                        help="only the grid's settings with J joints (default: the whole "
                        "grid, 55 agents)")
    parser.add_argument("--seeds", type=int, default=5, help="seeds per setting (>= 1)")
    parser.add_argument("--unit-args", default=" ".join(UNIT_ARGS),
                        help="extra ddpg_her.train arguments of every unit, one shell-quoted "
                        "string (the count does not depend on --buffer-size)")
    parser.add_argument("--eager", action="store_true",
                        help="count the eager rollouts (the CPU path) instead of the fused "
                        "Triton kernels of ddpg_her.program_kernels (the GPU path; counted "
                        "here under Triton's interpreter)")
    parser.add_argument("--arm-only", action="store_true",
                        help="print the arm kernel's compiled figures alone (JSON) and exit")
    parser.add_argument("--no-guard", action="store_true",
                        help="skip counting the suite's small stack (GUARD)")
    parser.add_argument("--no-arm", action="store_true",
                        help="skip the arm kernel's compile for sm_90 (about 40 s of CPU)")
    parser.add_argument("--arch", type=int, default=90,
                        help="compute capability of the arm kernel's compile (70..120)")
    parser.add_argument("--node-us", type=float, default=2.0,
                        help="microseconds per launch, a CUDA graph node's latency (H100/H200: "
                        "about 1.5-3)")
    parser.add_argument("--bandwidth-gbs", type=positive, default=4800.0,
                        help="memory bandwidth, GB/s, > 0 (H200 HBM3e 4,800; H100 SXM 3,350)")
    parser.add_argument("--tflops", type=positive, default=60.0,
                        help="arithmetic rate of the bodies' ops, TFLOP/s, > 0 (H200 float32 "
                        "without tensor cores: about 60)")
    parser.add_argument("--fp64-tflops", type=positive, default=34.0,
                        help="FP64 issue rate of the arm kernel when many lanes run, "
                        "TFLOP/s, > 0 (H100/H200 vector FP64: 34)")
    parser.add_argument("--clock-ghz", type=positive, default=1.98,
                        help="SM clock, GHz, > 0 (H200 boost 1.98)")
    parser.add_argument("--cycles-per-instruction", type=float, default=1.0,
                        help="one lane's SASS issue interval, cycles, for the static count's "
                        "figure (arm_static_sass_us_per_step: every instruction once per "
                        "substep; a lower bound, loops inside a substep run more)")
    parser.add_argument("--arm-us-per-step", type=float, default=300.0,
                        help="the arm kernel's microseconds per control step at a few copies "
                        "(latency-bound; issue 42 projected 150-450 from its SASS), or the "
                        "FP64 work of all copies at --fp64-tflops if more")
    parser.add_argument("--update-ms", type=float, default=0.87,
                        help="one update of the 55 agents, ms, measured on an H200 "
                        "(the calibration)")
    parser.add_argument("--update-launches", type=int, default=124,
                        help="the launches per update when --update-ms was measured (count, >= 1)")
    parser.add_argument("--out", type=Path, default=None, help="also write the JSON here")
    parser.add_argument("--counts-from", type=Path, default=None, metavar="JSON",
                        help="take the counts from this earlier output instead of counting "
                        "(recompute the arm's figures and the projection)")
    parser.add_argument("--arm-from", type=Path, default=None, metavar="JSON",
                        help="take the arm's compiled figures from this --arm-only output")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error(f"--seeds must be >= 1; got {args.seeds}")
    bad = [f"--{k.replace('_', '-')} {getattr(args, k)}" for k in PROJECTION_FLAGS
           if getattr(args, k) is not None and getattr(args, k) <= 0]
    if bad:
        parser.error(f"the projection's parameters must be > 0; got {', '.join(bad)}")
    from benchmarks.grid_episode import grid_settings

    try:
        grid_settings(args.part)
    except ValueError as err:
        parser.error(str(err))
    if args.arm_only:
        os.environ["TRITON_ALWAYS_COMPILE"] = "1"
        print(json.dumps({**arm_figures("float64", args.arch, None),
                          "fused_kernels": fused_figures(args.arch)}))
        return 0
    if args.counts_from is not None:
        result = json.loads(args.counts_from.read_text())
    else:
        result = count(args)
        if args.out is not None:                # the counts first: the compile may fail
            args.out.write_text(json.dumps(result, indent=1) + "\n")
    result["arm"] = None if args.no_arm else json.loads(args.arm_from.read_text()) \
        if args.arm_from is not None else compiled_arm(args.arch)
    result["projection"] = project(result, result["arm"], args)
    text = json.dumps(result, indent=1)
    if args.out is not None:
        args.out.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
