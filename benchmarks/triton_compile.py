"""``python -m benchmarks.triton_compile``: compile the Triton stack kernel
(:mod:`envs.physics.triton_kernel`) for a GPU on this machine, without one, and report what it
cost: CPU seconds per compiler stage and in all, the PTX's lines, the TTIR's operations and its
lane-tensor memory accesses (the count Triton's ``TritonGPUCoalesce`` pass walks the kernel
for, once each); and, from the cubin, what the GPU would run: ptxas's registers, stack frame and
spill bytes (its ``-v`` log, the one a launch's compile writes), and the SASS's instructions
(``cuobjdump -sass``): all, FP64, and those inside the substep loop (the outermost backward
branch's range) with the loop's inner loops (the exact plane heights' rows) apart.

The kernel is compiled as its first launch on that GPU would compile it (``triton.compile`` of
the same arguments to a ``GPUTarget``, the same options), here for sm_90 (H100) by default:

    python -m benchmarks.triton_compile --dtype float64
    python -m benchmarks.triton_compile --dtype float32 --arch 90 --block 32

The arguments are :func:`envs.physics.triton_kernel.launch_arguments`' for a stack of the
default task (:class:`envs.spec.TaskSpec`: its substeps, gravity compensation, plane); the
kernel's code does not depend on the number of copies. Triton's disk cache is bypassed
(``TRITON_ALWAYS_COMPILE=1``), so every run compiles. One JSON object on stdout.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import json
import os
import platform
import re
import resource
import sys
import time
from typing import Any

import numpy as np

from ddpg_her.config import Parser

DTYPES = ("float64", "float32")

STAGES = ("ttir", "ttgir", "llir", "ptx", "cubin")
"""Triton's NVIDIA stages after the front end (``source``), in order."""

OPERATION = re.compile(r"^\s*(?:%[^=\n]+= )?\"?[a-z_]+\.[a-z_.]+", re.M)
"""A line of TTIR that is an operation (``%x = dialect.op ...`` or ``dialect.op ...``)."""

PTXAS_USAGE = {
    "registers": re.compile(r"Used (\d+) registers"),
    "stack_bytes": re.compile(r"(\d+) bytes stack frame"),
    "spill_store_bytes": re.compile(r"(\d+) bytes spill stores"),
    "spill_load_bytes": re.compile(r"(\d+) bytes spill loads"),
}
"""ptxas ``-v``'s figures for the kernel, by name."""

SASS_LINE = re.compile(r"/\*([0-9a-f]{4,})\*/\s+(@!?U?P\w+\s+)?([A-Z][A-Z0-9_.]*)([^;]*);")
"""One SASS instruction of ``cuobjdump -sass``: its address, predicate, opcode, operands."""

LANE_MEMORY_OP = re.compile(r"\btt\.(load|store)\b[^\n]*tensor<[^\n]*!tt\.ptr<")
"""A TTIR load or store through a tensor of pointers (one address per lane)."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = Parser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dtype", choices=DTYPES, default="float64",
                        help="the kernel's arithmetic (default float64)")
    parser.add_argument("--arch", type=int, default=90,
                        help="CUDA compute capability as an integer 50..120 (major x 10 + "
                             "minor), e.g. 90 for sm_90 (default 90)")
    parser.add_argument("--block", type=int, default=None,
                        help="copies per program (default envs.physics.stack.BLOCK)")
    parser.add_argument("--stop-after", choices=STAGES, default="cubin",
                        help="the last stage to run (default cubin, what a launch needs)")
    parser.add_argument("--cubin", default=None, metavar="PATH",
                        help="also write the compiled cubin to PATH (for cuobjdump/nvdisasm)")
    args = parser.parse_args(argv)
    if not 50 <= args.arch <= 120:
        parser.error(f"--arch must be a compute capability 50..120 (e.g. 90); got {args.arch}")
    if args.arch < 70:
        parser.error(f"--arch must be a compute capability >= 70 (Triton's CUDA targets); "
                     f"got {args.arch}")
    if args.block is not None and (args.block < 1 or args.block & (args.block - 1)):
        parser.error(f"--block must be a power of two >= 1; got {args.block}")
    return args


def launch_source(fn: Any, backend: Any, args: tuple[Any, ...], constexprs: dict[str, Any],
                  num_warps: int) -> Any:
    """The ``ASTSource`` Triton's JIT builds for ``fn[grid](*args, **constexprs,
    num_warps=...)``: its own binder and packing (Triton 3.6's ``JITFunction`` internals), so
    the signature, constants and specialisations (pointer and int alignment) are a launch's."""
    from triton.compiler.compiler import ASTSource
    from triton.runtime.jit import create_function_from_signature

    binder = create_function_from_signature(fn.signature, fn.params, backend)
    bound_args, specialization, options = binder(*args, **constexprs, num_warps=num_warps)
    _, signature, constants, attrs = fn._pack_args(backend, {"num_warps": num_warps},
                                                   bound_args, specialization, options)
    return ASTSource(fn, signature, constants, attrs)


def ptxas_figures(log: str) -> dict[str, int | None]:
    """Registers, stack frame and spill bytes from ptxas's ``-v`` log (None where absent)."""
    out: dict[str, int | None] = {}
    for key, pattern in PTXAS_USAGE.items():
        found = pattern.search(log)
        out[key] = int(found.group(1)) if found else None
    return out


def sass_figures(cubin: bytes, rows: list[int]) -> dict[str, Any]:
    """Instruction counts of the cubin's SASS (``cuobjdump -sass``, shipped with Triton).

    ``substep_loop`` is the outermost loop (the largest backward branch's range: the substep
    loop). Inside it ``exact_pass`` is the largest region a forward branch skips (the exact
    plane heights, taken when a lane of the block needs them); the loops inside it (one per
    link with more than one vertex row, in order) run ``rows`` times each when their number
    matches, which gives the exact pass's dynamic count. ``per_substep`` counts the loop body
    without the exact pass, and with it (static instructions, each counted once per run; FP64
    ones apart): the estimate of what one lane issues per substep.
    """
    import subprocess
    import tempfile

    from triton.backends.nvidia.compiler import get_ptxas

    tool = os.path.join(os.path.dirname(get_ptxas(90).path), "cuobjdump")
    with tempfile.NamedTemporaryFile(suffix=".cubin") as f:
        f.write(cubin)
        f.flush()
        text = subprocess.run([tool, "-sass", f.name], capture_output=True, text=True,
                              check=True).stdout
    code = []  # (address, opcode, operands)
    for m in SASS_LINE.finditer(text):
        code.append((int(m.group(1), 16), m.group(3), m.group(4)))
    addr = [a for a, _, _ in code]
    fp64 = [op.startswith(("DADD", "DMUL", "DFMA", "DSETP", "DMNMX", "DSET", "F2F.F64", "DMMA"))
            or (op.startswith("MUFU") and ".64" in op) for _, op, _ in code]
    branches = []  # (from index, to index)
    for i, (_, op, args) in enumerate(code):
        target = re.search(r"0x([0-9a-f]+)", args) if op.startswith("BRA") else None
        if target and int(target.group(1), 16) in addr:
            branches.append((i, addr.index(int(target.group(1), 16))))

    def count(lo: int, hi: int) -> tuple[int, int]:
        return hi - lo, sum(fp64[lo:hi])

    out: dict[str, Any] = {"instructions": len(code), "fp64_instructions": sum(fp64),
                           "spill_instructions": sum(op.startswith(("STL", "LDL"))
                                                     for _, op, _ in code)}
    loops = sorted(((j, i + 1) for i, j in branches if j <= i), key=lambda r: r[0] - r[1])
    if not loops:
        return out
    lo, hi = loops[0]
    body, body_fp64 = count(lo, hi)
    skips = sorted(((i, j) for i, j in branches if lo <= i < j <= hi),
                   key=lambda r: r[0] - r[1])
    ops = collections.Counter(op.split(".")[0] for _, op, _ in code[lo:hi])
    out["substep_loop"] = {"instructions": body, "fp64": body_fp64,
                           "opcodes": dict(ops.most_common(12))}
    if skips:
        s_lo, s_hi = skips[0]
        inner = sorted((a, b) for a, b in loops[1:] if s_lo <= a and b <= s_hi and b - a > 50)
        # keep the outermost inner loops only
        outer_inner = [r for r in inner if not any(o != r and o[0] <= r[0] and r[1] <= o[1]
                                                     for o in inner)]
        static, static_fp64 = count(s_lo, s_hi)
        dynamic, dynamic_fp64 = static, static_fp64
        looped = [n for n in rows if n > 1]
        if outer_inner and len(outer_inner) != len(looped):
            dynamic = dynamic_fp64 = None
        for (a, b), n in zip(outer_inner, looped if dynamic is not None else [], strict=False):
            # a loop over n rows, unrolled by ptxas: one minimum (a DSETP) per row
            extra, extra_fp64 = count(a, b)
            per_row = max(1, sum(op.startswith("DSETP") for _, op, _ in code[a:b]))
            dynamic += round((n / per_row - 1) * extra)
            dynamic_fp64 += round((n / per_row - 1) * extra_fp64)
        # the branches inside it (one per link when the links are taken apart): the maximal
        # regions a forward branch skips, in order
        inside = [(i, j) for i, j in branches if s_lo < i < j <= s_hi and j - i > 50]
        parts = sorted(r for r in inside if not any(o != r and o[0] <= r[0] and r[1] <= o[1]
                                                     for o in inside))
        ops = collections.Counter(op.split(".")[0] for _, op, _ in code[s_lo:s_hi])
        out["exact_pass"] = {"static": static, "static_fp64": static_fp64,
                             "opcodes": dict(ops.most_common(8)),
                             "branches": [count(a, b)[0] for a, b in parts],
                             "inner_loops": [count(a, b)[0] for a, b in outer_inner],
                             "dynamic": dynamic, "dynamic_fp64": dynamic_fp64}
        out["per_substep"] = {
            "without_exact": body - static, "without_exact_fp64": body_fp64 - static_fp64,
            "with_exact": None if dynamic is None else body - static + dynamic,
            "with_exact_fp64": None if dynamic is None else body_fp64 - static_fp64
            + dynamic_fp64}
    return out


def cpu_seconds() -> float:
    """CPU seconds of this process and its finished children (ptxas runs as one)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def compile_kernel(dtype: str, arch: int, block: int | None, stop_after: str = "cubin",
                   cubin_path: str | None = None) -> dict[str, Any]:
    """Compile the stack kernel stage by stage, timed; the figures as a dict."""
    os.environ["TRITON_ALWAYS_COMPILE"] = "1"
    import torch
    import triton
    from triton._C.libtriton import ir
    from triton.backends.compiler import GPUTarget
    from triton.compiler.compiler import make_backend

    import envs.physics.triton_kernel as triton_kernel
    from envs.physics.model import arm_model, tool_offset, ur5_plane
    from envs.physics.numba_kernel import DTYPES as CASTS
    from envs.physics.stack import BLOCK, TORCH_DTYPES
    from envs.spec import TaskSpec

    block = BLOCK if block is None else block
    task = TaskSpec(n_joints=6)
    arm = arm_model(task)
    cast, tdtype = CASTS[dtype], TORCH_DTYPES[dtype]
    controller = dict(kp=arm.kp_eff, kd=arm.kd_eff, effort=arm.effort, w_max=arm.w_max,
                      q_mid=arm.q_mid, q_half=arm.q_half)
    model = triton_kernel.TritonModel.build(
        controller, arm.chain.astype(cast), ur5_plane(dtype), tool_offset().astype(cast),
        task.base_height, task.plane_margin, task.substeps, task.gravity_compensation, tdtype)
    B = 2 * block

    def lanes(width: int, dt: torch.dtype = tdtype) -> torch.Tensor:
        return torch.zeros((B, width) if width else (B,), dtype=dt)

    args, constexprs = triton_kernel.launch_arguments(
        model, lanes(6), lanes(6), lanes(6), lanes(6), lanes(0, torch.int32), lanes(6),
        lanes(0, torch.bool), lanes(0, torch.bool), lanes(3), block)
    target = GPUTarget("cuda", arch, 32)
    backend = make_backend(target)
    src = launch_source(triton_kernel.kernel(), backend, args, constexprs,
                        triton_kernel.NUM_WARPS)

    # triton.compile's steps, each stage timed apart (compiler.compile runs the same ones)
    options = backend.parse_options({"num_warps": triton_kernel.NUM_WARPS})
    metadata: dict[str, Any] = {"hash": "benchmark", "target": target, **options.__dict__}
    stages: dict[str, Any] = {}
    backend.add_stages(stages, options, src.language)
    context = ir.context()
    ir.load_dialects(context)
    backend.load_dialects(context)
    cpu, wall = {}, {}
    start_cpu, start_wall = cpu_seconds(), time.perf_counter()
    module = src.make_ir(target, options, backend.get_codegen_implementation(options),
                         backend.get_module_map(), context)
    cpu["source"] = cpu_seconds() - start_cpu
    wall["source"] = time.perf_counter() - start_wall
    counts: dict[str, int] = {}
    ptx = cubin = None
    ptxas_log = io.StringIO()
    triton.knobs.nvidia.dump_ptxas_log = True  # printed by the cubin stage: captured
    for name in STAGES[: STAGES.index(stop_after) + 1]:
        t_cpu, t_wall = cpu_seconds(), time.perf_counter()
        with contextlib.redirect_stdout(ptxas_log):
            module = stages[name](module, metadata)
        cpu[name] = cpu_seconds() - t_cpu
        wall[name] = time.perf_counter() - t_wall
        if name == "ttir":
            text = str(module)
            counts = {"ttir_operations": len(OPERATION.findall(text)),
                      "ttir_lane_memory_ops": len(LANE_MEMORY_OP.findall(text)),
                      "ttir_scalar_loads": len(re.findall(r"\btt\.load\b[^\n]*: !tt\.ptr<",
                                                          text))}
        if name == "ptx":
            ptx = module
        if name == "cubin":
            cubin = module
    machine_code: dict[str, Any] = {}
    if cubin is not None:
        if cubin_path is not None:
            with open(cubin_path, "wb") as f:
                f.write(cubin)
        bounds = ur5_plane(dtype).bounds
        machine_code = {**ptxas_figures(ptxas_log.getvalue()),
                        "sass": sass_figures(cubin, [bounds[k + 1] - bounds[k]
                                                     for k in range(1, len(bounds) - 1)])}
    return {"dtype": dtype, "arch": f"sm_{arch}", "block": block, "substeps": task.substeps,
            "stop_after": stop_after,
            "cpu_s": round(sum(cpu.values()), 2),
            "cpu_s_by_stage": {k: round(v, 2) for k, v in cpu.items()},
            "wall_s": round(sum(wall.values()), 2),
            "ptx_lines": None if ptx is None else len(ptx.splitlines()),
            "ptx_f64_lines": None if ptx is None else sum(".f64" in line
                                                          for line in ptx.splitlines()),
            **counts, **machine_code, "triton": triton.__version__, "torch": torch.__version__,
            "numpy": np.__version__, "python": platform.python_version(),
            "machine": platform.machine()}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if os.environ.get("TRITON_INTERPRET", "0") not in ("", "0"):
        raise SystemExit("TRITON_INTERPRET is set: the kernel would be the interpreter's "
                         "function, not compiled; unset it to run this benchmark")
    print(json.dumps(compile_kernel(args.dtype, args.arch, args.block,
                                                args.stop_after, args.cubin)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
