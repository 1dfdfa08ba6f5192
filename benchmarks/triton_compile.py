"""``python -m benchmarks.triton_compile``: compile the Triton stack kernel
(:mod:`envs.physics.triton_kernel`) for a GPU on this machine, without one, and report what it
cost: CPU seconds per compiler stage and in all, the PTX's lines, the TTIR's operations and its
lane-tensor memory accesses (the count Triton's ``TritonGPUCoalesce`` pass walks the kernel
for, once each).

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
import json
import os
import platform
import re
import resource
import sys
import time
from typing import Any

import numpy as np

DTYPES = ("float64", "float32")

STAGES = ("ttir", "ttgir", "llir", "ptx", "cubin")
"""Triton's NVIDIA stages after the front end (``source``), in order."""

OPERATION = re.compile(r"^\s*(?:%[^=\n]+= )?\"?[a-z_]+\.[a-z_.]+", re.M)
"""A line of TTIR that is an operation (``%x = dialect.op ...`` or ``dialect.op ...``)."""

LANE_MEMORY_OP = re.compile(r"\btt\.(load|store)\b[^\n]*tensor<[^\n]*!tt\.ptr<")
"""A TTIR load or store through a tensor of pointers (one address per lane)."""


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dtype", choices=DTYPES, default="float64",
                        help="the kernel's arithmetic (default float64)")
    parser.add_argument("--arch", type=int, default=90,
                        help="CUDA compute capability as an integer 50..120 (major x 10 + "
                             "minor), e.g. 90 for sm_90 (default 90)")
    parser.add_argument("--block", type=int, default=None,
                        help="copies per program (default envs.physics.stack.BLOCK)")
    parser.add_argument("--stop-after", choices=STAGES, default="cubin",
                        help="the last stage to run (default cubin, what a launch needs)")
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


def cpu_seconds() -> float:
    """CPU seconds of this process and its finished children (ptxas runs as one)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def compile_kernel(dtype: str, arch: int, block: int | None, stop_after: str = "cubin"
                   ) -> dict[str, Any]:
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
        task.base_height, task.plane_margin, task.substeps, task.gravity_compensation, "cpu",
        tdtype)
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
    ptx = None
    for name in STAGES[: STAGES.index(stop_after) + 1]:
        t_cpu, t_wall = cpu_seconds(), time.perf_counter()
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
    return {"dtype": dtype, "arch": f"sm_{arch}", "block": block, "substeps": task.substeps,
            "stop_after": stop_after,
            "cpu_s": round(sum(cpu.values()), 2),
            "cpu_s_by_stage": {k: round(v, 2) for k, v in cpu.items()},
            "wall_s": round(sum(wall.values()), 2),
            "ptx_lines": None if ptx is None else len(ptx.splitlines()),
            "ptx_f64_lines": None if ptx is None else sum(".f64" in line
                                                          for line in ptx.splitlines()),
            **counts, "triton": triton.__version__, "torch": torch.__version__,
            "numpy": np.__version__, "python": platform.python_version(),
            "machine": platform.machine()}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if os.environ.get("TRITON_INTERPRET", "0") not in ("", "0"):
        raise SystemExit("TRITON_INTERPRET is set: the kernel would be the interpreter's "
                         "function, not compiled; unset it to run this benchmark")
    print(json.dumps(compile_kernel(args.dtype, args.arch, args.block,
                                                args.stop_after)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
