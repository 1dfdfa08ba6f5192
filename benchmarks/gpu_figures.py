"""``python -m benchmarks.gpu_figures``: the figures of a GPU window's stage 2, in one JSON file
(issues 35, 42): the training program's grid episode, and the kernel, update and bandwidth
figures that explain it.

Figures (each under ``figures`` in the JSON, with its ``seconds`` and its ``window_s``, the
seconds since the start at which it began and ended; a figure that fails records its
``error`` and the stage goes on):

- ``bandwidth``: the achieved memory bandwidth of a large device-to-device copy (read and
  write counted, GB/s), the roof of the memory-bound parts of an update;
- ``kernel_in_graph``: the grid's stack (`envs.physics.stack.StackDynamics`: copies of the
  grid's 11 settings in turn, the Triton kernel on CUDA) stepped ``steps`` control steps
  eagerly and as one replayed CUDA graph: microseconds per step of each, the first call
  (compilation) apart, and whether the replay's final state equals the eager one's bit for
  bit (a replay that launched nothing would be fast and wrong);
- ``updates``: the stacked update of K = 55 agents (400-300 networks, batch 64, float32,
  minibatches drawn on the device by ``buffer.CounterSampler``, the body captured as the
  training program captures it, ``ddpg_her.program.Graphed``): the 3-joint layout (inputs
  9 + 3 + 3, actions 3), and the padded stack (inputs padded to 6 joints: 18 + 3 + 3,
  actions 6) in float32 and in TF32
  (``torch.backends.cuda.matmul.allow_tf32``), each eager and captured: milliseconds per
  update of all K and agent-updates/s (buffers of random rows: the cost does not depend on
  their values);
- ``grid_episode``, first: ``python -m benchmarks.grid_episode --device cuda --path program
  --window --json`` in its own process, alone (the other figures wait for it), killed at
  ``GRID_SHARE`` of the budget with its log: the training program's grid episode timed on
  replays (after its warm-up and capture), its amortised test session and save apart, its
  start-up (the stage's start-up figure), host syncs and graph replays per episode.

``--dry-run`` runs every figure on the CPU, tiny (the CUDA graphs skipped): a check of the
script, whose times mean nothing. ``--note`` records how they were measured (e.g. beside a
training on the same GPU, ``benchmarks/gpu_grid.sh``: then every time is an upper bound).

    python -m benchmarks.gpu_figures --out figures.json
    python -m benchmarks.gpu_figures --out /tmp/figures.json --dry-run
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from ddpg_her.config import Parser

GRID_SHARE = 0.7
"""The share of ``--budget-s`` the grid episode's process may take before it is killed."""

OBS_PER_JOINT = 3
"""Observation entries per controlled joint (angle, velocity and one more: 9 for 3 joints, 18
for 6; ``GoalVecEnv.dims``)."""

GOAL_DIM = 3
"""Entries of the achieved and of the desired goal (m, world frame)."""

PADDED_JOINTS = 6
"""The padded stack's joint count: the largest of the grid."""

TODAY_JOINTS = 3
"""The joint count of today's captured update figure (the grid's largest stacks are 3 and 6)."""


@dataclass(frozen=True)
class Sizes:
    """How much each figure measures; :data:`FULL` on a GPU, :data:`DRY` for ``--dry-run``."""

    copy_mib: int = 2048
    """Bytes of the bandwidth figure's source tensor, MiB."""
    copies: tuple[int, ...] = (55, 5500)
    """Arm copies of the kernel figure: one per agent of the grid, and a test session's
    (100 per agent)."""
    steps: int = 100
    """Control steps per round of the kernel figures (one episode)."""
    rounds: int = 5
    """Rounds of every timed figure; medians are reported."""
    agents: int = 55
    """K of the stacked update (the grid's agents)."""
    hidden: tuple[int, int] = (400, 300)
    """Hidden layer widths of actor and critic (Table I)."""
    batch: int = 64
    """Minibatch per agent and update (Table I)."""
    buffer_rows: int = 100_000
    """Rows of each agent's replay buffer (the paper's 1e6 would take 12 GiB for 55 padded
    agents; a minibatch's gather costs about the same from 1e5)."""
    updates: int = 100
    """Updates per timed round (one training episode's)."""
    grid_args: tuple[str, ...] = ("--device", "cuda", "--path", "program", "--window",
                                  "--episodes", "5")
    """``benchmarks.grid_episode``'s arguments."""


FULL = Sizes()
DRY = Sizes(copy_mib=16, copies=(3,), steps=2, rounds=1, agents=3,
            hidden=(16, 16), buffer_rows=256, updates=4,
            grid_args=("--device", "cpu", "--path", "program", "--window", "--part", "2",
                       "--seeds", "1", "--episodes", "1", "--sessions", "1", "--unit-args",
                       "--hidden-sizes 8 8 --buffer-size 1000 --batch-size 8 "
                       "--updates-per-episode 2 --task max_episode_steps=5"))
"""Tiny, on the CPU: a check of the script."""

GOALS = {"ms_per_grid_episode_h200": 30.0, "ms_per_grid_episode_h100": 40.0,
         "startup_s": 60.0, "host_syncs_per_episode": 0}
"""Issues 35 and 42's goals for the training program."""


@dataclass
class Context:
    """What the figures share: the device, the sizes, whether this is a dry run, the clock."""

    device: str
    sizes: Sizes
    dry_run: bool
    t0: float

    def sync(self) -> None:
        if self.device == "cuda":
            import torch

            torch.cuda.synchronize()

    def median_seconds(self, run: Callable[[], None], before: Callable[[], None] | None = None
                       ) -> tuple[float, list[float]]:
        """The median over ``rounds`` of ``run()``'s seconds (``before()`` first, off the
        clock, each synchronised), and every round's."""
        times = []
        for _ in range(self.sizes.rounds):
            if before is not None:
                before()
            self.sync()
            tic = time.perf_counter()
            run()
            self.sync()
            times.append(time.perf_counter() - tic)
        return statistics.median(times), times


# ---------------------------------------------------------------------------- figures
def bandwidth(ctx: Context) -> dict[str, Any]:
    """GB/s of ``dst.copy_(src)`` on the device, bytes read plus bytes written."""
    import torch

    n = ctx.sizes.copy_mib * 2**20 // 4
    src = torch.ones(n, dtype=torch.float32, device=ctx.device)
    dst = torch.empty_like(src)
    dst.copy_(src)
    seconds, times = ctx.median_seconds(lambda: dst.copy_(src))
    moved = 2 * src.numel() * src.element_size()
    return {"bytes_copied": src.numel() * src.element_size(), "gb_per_s": moved / seconds / 1e9,
            "best_gb_per_s": moved / min(times) / 1e9}


def kernel_in_graph(ctx: Context) -> dict[str, Any]:
    """``steps`` control steps of the grid's stack (`envs.physics.stack.StackDynamics`: the
    Triton kernel on CUDA, numba on the CPU), eager and as one replayed CUDA graph (CUDA only;
    a dry run times the eager calls)."""
    import torch

    from envs.physics.stack import StackDynamics
    from envs.spec import TaskSpec

    s = ctx.sizes
    out: dict[str, Any] = {"rows": []}
    grid = [TaskSpec(region=r, n_joints=j) for r, j in
            (("unconstrained", 2), ("unconstrained", 3), ("unconstrained", 4),
             ("unconstrained", 5), ("unconstrained", 6), ("zheight", 3), ("zheight", 6),
             ("closebox", 3), ("closebox", 6), ("farbox", 3), ("farbox", 6))]
    for n in s.copies:
        tasks = [grid[b % len(grid)] for b in range(n)]
        dyn = StackDynamics(tasks, device=ctx.device, dtype="float64")
        gen = torch.Generator().manual_seed(1)
        commands = ((torch.rand(s.steps, n, 6, generator=gen, dtype=torch.float64) * 2 - 1)
                    * 3.14159).to(ctx.device)
        command = commands[0].clone()
        everyone = torch.ones(n, dtype=torch.bool, device=ctx.device)

        def eager(dyn: Any = dyn, command: Any = command, commands: Any = commands) -> None:
            for c in commands:
                command.copy_(c)
                dyn.step(command)

        def restart(dyn: Any = dyn, everyone: Any = everyone) -> None:
            dyn.reset_where(everyone)

        tic = time.perf_counter()
        eager()  # compiles on a first call
        ctx.sync()
        row: dict[str, Any] = {"copies": n, "first_call_s": time.perf_counter() - tic}
        median, _ = ctx.median_seconds(eager, restart)
        row["eager_us_per_step"] = 1e6 * median / s.steps
        if ctx.device != "cuda":
            row["graph"] = "skipped: a CUDA graph needs a GPU (dry run)"
            out["rows"].append(row)
            continue
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            eager()  # the capture's warm-up on a side stream (torch.cuda.graph's rule)
        torch.cuda.current_stream().wait_stream(side)
        restart()
        eager()
        ctx.sync()
        expected = dyn.q.clone()
        graph = torch.cuda.CUDAGraph()
        tic = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with torch.cuda.graph(graph):
                eager()
        row["capture_s"] = time.perf_counter() - tic
        row["capture_warnings"] = sorted({str(w.message)[:200] for w in caught})
        restart()
        graph.replay()
        ctx.sync()
        row["replay_equals_eager"] = bool(torch.equal(dyn.q, expected))
        median, _ = ctx.median_seconds(graph.replay, restart)
        row["graph_us_per_step"] = 1e6 * median / s.steps
        row["eager_over_graph"] = row["eager_us_per_step"] / row["graph_us_per_step"]
        out["rows"].append(row)
    return out


def _update_row(ctx: Context, joints: int, graph: bool, tf32: bool) -> dict[str, Any]:
    """One variant of the stacked update: ms per update of all K, agent-updates/s."""
    import torch

    from ddpg_her.agents import make_agent
    from ddpg_her.buffer import CounterSampler, Layout, ReplayBuffer
    from ddpg_her.config import AgentConfig
    from ddpg_her.program import WARMUP_REPLAYS, Graphed

    s = ctx.sizes
    layout = Layout(OBS_PER_JOINT * joints + 2 * GOAL_DIM, joints)
    config = AgentConfig(hidden_sizes=s.hidden, batch_size=s.batch, buffer_size=s.buffer_rows)
    previous = torch.backends.cuda.matmul.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = tf32
    try:
        agent = make_agent(config, layout.in_dim, layout.act_dim, device=ctx.device,
                           init_generators=[torch.Generator().manual_seed(k)
                                            for k in range(s.agents)])
        buffer = ReplayBuffer(s.agents, s.buffer_rows, layout, dtype=torch.float32,
                              device=ctx.device)
        gen = torch.Generator(ctx.device).manual_seed(0)
        rows = torch.randn(s.buffer_rows, layout.width, generator=gen, device=ctx.device)
        rows[:, layout.in_dim + layout.act_dim] = -rows[:, layout.in_dim + layout.act_dim].abs()
        rows[:, -1] = 0.0  # terminated: none, every target bootstraps
        for k in range(s.agents):
            buffer.put(k, 0, rows)
        # the program's update body: minibatches from the counter stream, captured as one
        # graph of s.updates updates after its eager warm-up runs (ddpg_her.program.Graphed)
        agent.capturable()
        sampler = CounterSampler(list(range(s.agents)), ctx.device)

        def body() -> None:
            for _ in range(s.updates):
                agent.update(*sampler.sample(buffer, s.batch))

        step = Graphed(body, capture=graph)
        in_effect = torch.backends.cuda.matmul.allow_tf32  # as torch reads it back
        tic = time.perf_counter()
        for _ in range(WARMUP_REPLAYS + 1):  # the capture, where graph
            step()
        ctx.sync()
        first = time.perf_counter() - tic
        median, _ = ctx.median_seconds(step)
    finally:
        torch.backends.cuda.matmul.allow_tf32 = previous
    ms = 1e3 * median / s.updates
    return {"joints": joints, "in_dim": layout.in_dim, "act_dim": layout.act_dim,
            "graph": graph, "tf32": tf32, "allow_tf32_read_back": in_effect,
            "ms_per_update": ms,
            "agent_updates_per_s": s.agents / ms * 1e3, "first_run_s": first}


def updates(ctx: Context) -> dict[str, Any]:
    """Today's captured update (3-joint layout) and the padded stack's four variants; a
    failing variant records its error beside the others."""
    import torch

    s = ctx.sizes
    graphs = (False, True) if ctx.device == "cuda" else (False,)
    variants = [("today 3-joint", TODAY_JOINTS, g, False) for g in graphs[::-1]]
    variants += [(f"padded {PADDED_JOINTS}-joint {'tf32' if tf32 else 'float32'}",
                  PADDED_JOINTS, g, tf32) for tf32 in (False, True) for g in graphs]
    rows = []
    for name, joints, graph, tf32 in variants:
        name = f"{name} {'graph' if graph else 'eager'}"
        try:
            rows.append({"name": name, **_update_row(ctx, joints, graph, tf32)})
        except Exception as err:  # one variant's failure is a figure, not the stage's end
            rows.append({"name": name, "error": f"{type(err).__name__}: {err}"})
        if ctx.device == "cuda":
            torch.cuda.empty_cache()
    return {"agents": s.agents, "hidden_sizes": list(s.hidden), "batch": s.batch,
            "buffer_rows": s.buffer_rows, "updates_per_round": s.updates,
            "graph": "skipped on the CPU (dry run)" if ctx.device != "cuda" else "on and off",
            "rows": rows}


FIGURES: dict[str, Callable[[Context], dict[str, Any]]] = {
    "bandwidth": bandwidth, "updates": updates, "kernel_in_graph": kernel_in_graph}
"""The figures measured in this process, in their order (the capture last: a capture that
fails may leave the CUDA context unusable), after ``grid_episode`` in its own process."""


# ---------------------------------------------------------------------------- the grid episode
class GridEpisode:
    """``python -m benchmarks.grid_episode`` in its own process (its CUDA context and
    compiled kernels apart from this one's), started at once; :meth:`result` waits for it."""

    def __init__(self, args: Sequence[str], env: dict[str, str]):
        self._folder = tempfile.TemporaryDirectory(prefix="gpu_figures-")
        folder = Path(self._folder.name)  # not beside --out: that folder's files come back
        self.log_path = folder / "grid_episode.log"
        self.command = [sys.executable, "-m", "benchmarks.grid_episode", "--json", *args]
        self._log = open(self.log_path, "w")  # noqa: SIM115 - open as long as the process runs
        self.proc = subprocess.Popen(self.command, stdout=subprocess.PIPE, stderr=self._log,
                                     text=True, env=env)
        self.started = time.perf_counter()

    def kill(self) -> None:
        """End the process if it still runs (this one failed before asking for its result)."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()

    def result(self, deadline: float) -> dict[str, Any]:
        """Its JSON, or its error, killed at ``deadline`` (a ``time.perf_counter`` reading)."""
        out: dict[str, Any] = {"command": shlex.join(self.command[1:])}
        try:
            stdout, _ = self.proc.communicate(timeout=max(deadline - time.perf_counter(), 1))
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.communicate()
            out["error"] = (f"timed out: killed {time.perf_counter() - self.started:.0f} s "
                            "after its start (the budget's end)")
        else:
            if self.proc.returncode == 0:
                out.update(json.loads(stdout))
            else:
                out["error"] = f"exit status {self.proc.returncode}"
        self._log.close()
        out["log"] = self.log_path.read_text().splitlines()[-30:]
        self._folder.cleanup()
        return out


# ---------------------------------------------------------------------------- main
def versions() -> dict[str, Any]:
    """The software and the device these figures were measured with."""
    import numpy as np
    import torch

    found: dict[str, Any] = {"python": sys.version.split()[0], "numpy": np.__version__,
                             "torch": torch.__version__, "cuda": torch.version.cuda,
                             "platform": platform.platform(),
                             "device": torch.cuda.get_device_name()
                             if torch.cuda.is_available() else platform.processor()}
    for name in ("numba", "triton"):
        try:
            module = __import__(name)
            found[name] = getattr(module, "__version__", "?")
        except Exception as err:  # an import that fails is a finding, not a crash
            found[name] = f"not importable: {type(err).__name__}: {err}"
    return found


def run_figure(name: str, ctx: Context) -> dict[str, Any]:
    """One figure, with its seconds and window; its error instead where it fails."""
    start = time.perf_counter()
    try:
        result = FIGURES[name](ctx)
    except Exception as err:
        result = {"error": f"{type(err).__name__}: {err}",
                  "traceback": traceback.format_exc().splitlines()[-8:]}
    end = time.perf_counter()
    return {**result, "seconds": end - start, "window_s": [start - ctx.t0, end - ctx.t0]}


def summary(figures: dict[str, Any]) -> dict[str, Any]:
    """The headline numbers of ``figures`` in one flat dict (None where a figure failed or was
    not measured): what a reader compares with issue 35's goals first."""

    def get(*keys: Any) -> Any:
        value: Any = figures
        for key in keys:
            try:
                value = value[key]
            except (KeyError, IndexError, TypeError):
                return None
        return value

    out: dict[str, Any] = {
        "ms_per_grid_episode": get("grid_episode", "ms_per_grid_episode"),
        "startup_s": get("grid_episode", "startup_s"),
        "host_syncs_per_episode": get("grid_episode", "host_syncs_per_episode"),
        "graph_replays_per_episode": get("grid_episode", "graph_replays_per_episode"),
        "copy_gb_per_s": get("bandwidth", "gb_per_s"),
        "test_session_ms": get("grid_episode", "test_session_ms"),
        "save_ms": get("grid_episode", "save_ms"),
        "ms_per_grid_episode_with_session_and_save":
            get("grid_episode", "ms_per_grid_episode_with_session_and_save")}
    for row in get("kernel_in_graph", "rows") or []:
        for key in ("eager_us_per_step", "graph_us_per_step", "replay_equals_eager"):
            if key in row:
                out[f"kernel_in_graph_{key}_at_{row['copies']}"] = row[key]
    for row in get("updates", "rows") or []:
        out[f"update_ms {row['name']}"] = row.get("ms_per_update")
    return out


def write(path: Path, result: dict[str, Any]) -> None:
    """Write the JSON now (again after every figure: a stage killed midway keeps what is done)."""
    path.write_text(json.dumps(result, indent=1) + "\n")


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m benchmarks.gpu_figures", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--out", type=Path, required=True, help="the JSON file to write")
    parser.add_argument("--budget-s", type=float, default=170.0,
                        help="seconds for the whole stage (> 0): the grid episode's process is "
                        "killed at its end")
    parser.add_argument("--only", nargs="+", choices=[*FIGURES, "grid_episode"], default=None,
                        help="measure only these figures (default: all)")
    parser.add_argument("--dry-run", action="store_true",
                        help="check the script on the CPU: tiny sizes, no CUDA graphs (times "
                        "mean nothing)")
    parser.add_argument("--note", default=None,
                        help="how the figures were measured, recorded in the JSON (e.g. "
                        "'beside the grid's training on the same GPU')")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    t0 = time.perf_counter()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.budget_s <= 0:
        parser.error(f"--budget-s must be > 0 seconds; got {args.budget_s}")
    sizes = DRY if args.dry_run else FULL
    wanted = args.only or ["grid_episode", *FIGURES]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    grid = GridEpisode(sizes.grid_args, dict(os.environ)) \
        if "grid_episode" in wanted else None
    try:
        return measure_all(args, sizes, wanted, grid, t0, argv, parser)
    finally:
        if grid is not None:
            grid.kill()


def measure_all(args: argparse.Namespace, sizes: Sizes, wanted: Sequence[str],
                grid: GridEpisode | None, t0: float, argv: Sequence[str] | None,
                parser: argparse.ArgumentParser) -> int:
    """Every wanted figure into ``args.out``; the grid episode's first."""
    import torch

    device = "cpu" if args.dry_run else "cuda"
    if device == "cuda" and not torch.cuda.is_available():
        parser.error("no CUDA device is available to torch; --dry-run checks the script on "
                     "the CPU")
    ctx = Context(device, sizes, args.dry_run, t0)
    result: dict[str, Any] = {"stage": "figures", "dry_run": args.dry_run,
                              "date": time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime()),
                              "command": shlex.join(["python", "-m", "benchmarks.gpu_figures",
                                                     *(argv if argv is not None
                                                       else sys.argv[1:])]),
                              "versions": versions(), "sizes": asdict(sizes),
                              "note": args.note, "goals": GOALS, "figures": {}}
    write(args.out, result)
    if grid is not None:  # first and alone: the figure the window is for
        print(f"[{time.perf_counter() - t0:6.1f} s] grid_episode", file=sys.stderr, flush=True)
        figure = grid.result(t0 + GRID_SHARE * args.budget_s)
        end = time.perf_counter()
        result["figures"]["grid_episode"] = {**figure, "seconds": end - grid.started,
                                             "window_s": [grid.started - t0, end - t0]}
        write(args.out, result)
    for name in FIGURES:
        if name in wanted:
            print(f"[{time.perf_counter() - t0:6.1f} s] {name}", file=sys.stderr, flush=True)
            result["figures"][name] = run_figure(name, ctx)
            write(args.out, result)
    result["summary"] = summary(result["figures"])
    result["seconds"] = time.perf_counter() - t0
    write(args.out, result)
    failed = [k for k, v in result["figures"].items() if "error" in v]
    print(f"[{result['seconds']:6.1f} s] wrote {args.out}"
          + (f"; failed: {', '.join(failed)}" if failed else ""), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
