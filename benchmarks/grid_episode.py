"""``python -m benchmarks.grid_episode``: milliseconds per episode of the paper's whole grid in one
process, its start-up, and the host synchronisations and graph replays inside an episode
(issue 35).

A *grid episode* is one training episode of every agent of the grid (55 agents: unconstrained
with 2-6 joints, z-height, close box and far box with 3 and 6, 5 seeds each; ``--part J`` the
settings with J joints) with its updates (``updates_per_episode``, 100), without test sessions
and checkpoints. Printed with ``--json`` as one object::

    {"device", "ms_per_grid_episode", "startup_s", "host_syncs_per_episode",
     "graph_replays_per_episode", ...}

- ``ms_per_grid_episode``: the median over the ``--episodes`` timed episodes (each ends with a
  device synchronisation), after ``--warmup`` untimed ones: by default `DEFAULT_WARMUP`, so
  that on CUDA every timed episode of the program replays its captured bodies (the eager and
  capturing episodes are the warm-up's), ``replayed_timed_episodes`` counting those that did;
- ``test_session_ms`` and ``save_ms`` (``--path program``): a test session (the captured
  body, replayed, after its own warm-up and capture) and what follows it on the host (the
  one read of the interval, the eval rows and the save: eval.csv with ``--window``, else
  buffer chunks and checkpoints of buffers holding only the benchmark's few episodes), medians
  over ``--sessions``; ``ms_per_grid_episode_with_session_and_save`` adds both amortised over
  the paper's 100 episodes per session (`SESSION_EVERY`);
- ``startup_s``: from the start of ``main`` (imports included, the interpreter's own start not)
  to the end of the warm-up episodes: building the stacks, compiling kernels, capturing graphs;
- ``host_syncs_per_episode``: on CUDA, the synchronising CUDA operations that torch reports
  under ``torch.cuda.set_sync_debug_mode("warn")``; on the CPU, where nothing synchronises,
  the calls that would read a device value on the host: ``Tensor.item``, ``.cpu``,
  ``.numpy``, ``.tolist`` and ``.__bool__``, counted by patching them;
- ``graph_replays_per_episode``: calls of ``torch.cuda.CUDAGraph.replay`` (through which
  ``torch.compile``'s CUDA graphs replay too);

both counts are means over ``--count-episodes`` further episodes run with the counters in
place (the timed episodes run without them, so the counting costs them nothing).

Paths (``--path``, :data:`PATHS`): ``today``, ``ddpg_her.multi.MultiTrainer`` as
``ddpg_her.train_many`` builds it for ``analysis.sweep --grid paper --one-process``: one stack
per joint count, stepped in turn, ``--env-backend batched``, run folders in a temporary folder;
``program`` (the default), the training program (``ddpg_her.program``): the whole grid as
one stack, ``--window`` its window mode. A new
path is one more entry of :data:`PATHS`: a function from a :class:`GridSpec` to a
:class:`GridRunner`.

    python -m benchmarks.grid_episode --device cuda --window --json
    python -m benchmarks.grid_episode --device cuda --part 3 --episodes 5 --json
    python -m benchmarks.grid_episode --device cpu --path today --part 2 \
        --unit-args="--hidden-sizes 8 8"
"""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from analysis.paper import PAPER_GRID, PAPER_SEEDS
from ddpg_her.config import Parser
from ddpg_her.train_many import unit_arguments

CPU_READS = ("item", "cpu", "numpy", "tolist", "__bool__")
"""The ``torch.Tensor`` methods counted as host reads on the CPU (each a synchronisation, or a
copy to the host, where the tensor lives on a GPU)."""

SYNC_WARNING = "synchroniz"
"""A fragment of the warning torch's sync debug mode gives for each synchronising call
("called a synchronizing CUDA operation")."""

START_AFTER_TIMEOUT_S = 600.0
"""The longest ``--start-after`` waits for its file (a GPU window's call lasts at most 600 s):
a caller that died does not leave this process holding the GPU."""

RL_WARMUP_EPISODES = 1
"""The agents' random-action episodes (``--warmup-episodes`` of every unit) before the actor
acts and the updates start: one, so the second warm-up episode already captures the update
graph and every timed episode acts and updates as the paper's episodes 101-20,000 do."""


DEFAULT_WARMUP = RL_WARMUP_EPISODES + 2 + 1
"""Untimed grid episodes by default: the random-action episode(s), then the
``ddpg_her.program.WARMUP_REPLAYS`` (2) eager runs of the acting and update bodies, then the
episode that captures them; from the next on, the program's episodes replay."""

SESSION_EVERY = 100
"""Training episodes per test session in the paper's protocol (``--eval-every``'s default):
what a test session and its save are amortised over."""


@dataclass(frozen=True)
class GridSpec:
    """What to build: the settings, seeds, device and the units' extra ``ddpg_her.train``
    arguments, in ``folder`` (run folders there are throwaway)."""

    settings: tuple[tuple[str, int], ...]
    """(region, joints) of each setting."""
    seeds: int
    """Seeds per setting (0 .. seeds-1)."""
    device: str
    """``cpu`` or ``cuda``."""
    folder: Path
    """Where the run folders go (a temporary folder)."""
    unit_args: tuple[str, ...] = ()
    """Extra ``ddpg_her.train`` arguments of every unit (e.g. tiny networks for a test)."""
    budget: int = 1
    """Training episodes of each run's budget (``--episodes`` and ``--eval-every``: the timed
    episodes stay below it, so no test session or checkpoint falls among them)."""
    window: bool = False
    """The program's window mode (``ddpg_her.train --window``): its saves write eval.csv."""

    @property
    def agents(self) -> int:
        return len(self.settings) * self.seeds


class GridRunner(Protocol):
    """A built grid: ``episode()`` trains one grid episode (every agent one episode and its
    updates), ``synchronize()`` waits for the device, ``close()`` releases it."""

    def episode(self) -> None: ...

    def synchronize(self) -> None: ...

    def close(self) -> None: ...


@dataclass
class TodayRunner:
    """Today's path: a ``ddpg_her.multi.MultiTrainer`` whose stacks step in turn."""

    trainer: Any
    device: str
    started: bool = field(default=False)

    def episode(self) -> None:
        if not self.started:
            for t in self.trainer.trainers:
                t.start()
            self.started = True
        for t in self.trainer.trainers:
            t.step()

    def synchronize(self) -> None:
        if self.device == "cuda":
            import torch

            torch.cuda.synchronize()

    def close(self) -> None:
        self.trainer.close()


def grid_units(spec: GridSpec) -> list[Any]:
    """The `ddpg_her.units.Setting` of each setting of ``spec``, as ``ddpg_her.train_many``
    parses its units (both paths train these)."""
    from ddpg_her.train_many import settings_of

    return settings_of([
        ["--region", region, "--joints", str(joints), "--seeds", *map(str, range(spec.seeds)),
         "--episodes", str(spec.budget), "--eval-every", str(spec.budget),
         "--warmup-episodes", str(RL_WARMUP_EPISODES),
         "--out", str(spec.folder / f"{region}-j{joints}" / "s{seed}")]
        for region, joints in spec.settings], common=spec.unit_args)


def today_path(spec: GridSpec) -> TodayRunner:
    """Today's grid in one process (``analysis.sweep --grid paper --one-process``'s
    ``ddpg_her.train_many``) with ``--env-backend batched``: the host envs, one compiled call
    per control step for each stack's copies (the torch env backend it measured before, 0.55 s
    per grid episode on an H200, gave way to the program)."""
    from ddpg_her.multi import MultiTrainer
    from ddpg_her.vecenv import register_env

    register_env("UR5Reach-v0")
    settings = grid_units(spec)
    trainer = MultiTrainer(settings, device=spec.device, env_backend="batched",
                           progress=False, tensorboard=False)
    return TodayRunner(trainer, spec.device)


@dataclass
class ProgramRunner:
    """The training program (``ddpg_her.program.Program``): the whole grid as one stack."""

    program: Any
    device: str

    def episode(self) -> None:
        self.program.step()

    def synchronize(self) -> None:
        if self.device == "cuda":
            import torch

            torch.cuda.synchronize()

    def replays(self) -> int:
        """Graph replays of the acting and update bodies so far."""
        return sum(self.program._bodies[b].replays for b in ("act", "learn"))

    def session(self, repeats: int) -> dict[str, Any]:
        """The test session's body, warmed up and captured, then timed ``repeats`` times, and
        what follows it on the host (`Program._read` and `_session`: the read, the rows, the
        save)."""
        from ddpg_her.program import WARMUP_REPLAYS

        test = self.program._bodies["test"]
        for _ in range(WARMUP_REPLAYS + 1):
            test()
        self.synchronize()
        body, save = [], []
        for _ in range(repeats):
            tic = time.perf_counter()
            test()
            self.synchronize()
            body.append(time.perf_counter() - tic)
            tic = time.perf_counter()
            self.program._session(self.program._read())
            save.append(time.perf_counter() - tic)
        return {"test_session_ms": 1e3 * statistics.median(body),
                "save_ms": 1e3 * statistics.median(save),
                "session_replays": test.replays,
                "buffer_rows_per_agent_at_save": int(self.program.total.max())}

    def close(self) -> None:
        self.program.close()


def program_path(spec: GridSpec) -> ProgramRunner:
    """The grid as ``analysis.sweep --grid paper --program`` trains it: every agent in one
    `ddpg_her.program.Program` on ``spec.device`` (captured on CUDA, eager on the CPU)."""
    from ddpg_her.program import Program

    settings = grid_units(spec)
    program = Program.of_settings(settings, device=spec.device, progress=False,
                                  window=spec.window)
    return ProgramRunner(program, spec.device)


PATHS: dict[str, Callable[[GridSpec], GridRunner]] = {"today": today_path,
                                                      "program": program_path}
"""``--path``: how the grid is built, a function of a `GridSpec` returning a `GridRunner`:
``today`` (the stacks of ``ddpg_her.multi``) or ``program`` (``ddpg_her.program``, issue 35's
training program)."""


# ---------------------------------------------------------------------------- counters
@dataclass
class Counts:
    """What the counters saw: host syncs (torch's, or the CPU's reads), graph replays."""

    host_syncs: int = 0
    replays: int = 0


def _counting(owner: Any, name: str, counts: Counts, key: str, stack: ExitStack) -> None:
    """Replace ``owner.name`` by a wrapper that adds one to ``counts.key`` per call; undone
    when ``stack`` closes."""
    original = getattr(owner, name)

    def counted(*args: Any, **kwargs: Any) -> Any:
        setattr(counts, key, getattr(counts, key) + 1)
        return original(*args, **kwargs)

    setattr(owner, name, counted)
    stack.callback(setattr, owner, name, original)


@contextmanager
def counters(device: str) -> Iterator[Counts]:
    """Count host synchronisations and graph replays inside the block (see the module's
    docstring for what counts on each device)."""
    import torch

    counts = Counts()
    with ExitStack() as stack:
        _counting(torch.cuda.CUDAGraph, "replay", counts, "replays", stack)
        if device == "cuda":
            caught = stack.enter_context(warnings.catch_warnings(record=True))
            warnings.simplefilter("always")
            previous = torch.cuda.get_sync_debug_mode()
            torch.cuda.set_sync_debug_mode("warn")
            stack.callback(torch.cuda.set_sync_debug_mode, previous)
            yield counts
            torch.cuda.set_sync_debug_mode(previous)
            counts.host_syncs = sum(SYNC_WARNING in str(w.message) for w in caught)
        else:
            for name in CPU_READS:
                _counting(torch.Tensor, name, counts, "host_syncs", stack)
            yield counts


# ---------------------------------------------------------------------------- measurement
def grid_settings(part: int | None) -> tuple[tuple[str, int], ...]:
    """The paper grid's settings, or those with ``part`` joints; ValueError for a joint count
    the grid does not have."""
    if part is None:
        return PAPER_GRID
    chosen = tuple(s for s in PAPER_GRID if s[1] == part)
    if not chosen:
        raise ValueError(f"--part must be a joint count of the paper grid, one of "
                         f"{sorted({j for _, j in PAPER_GRID})}; got {part}")
    return chosen


def log(t0: float, text: str) -> None:
    """A progress line on stderr, seconds since ``t0`` first (read when a caller times out)."""
    print(f"[{time.perf_counter() - t0:7.1f} s] {text}", file=sys.stderr, flush=True)


def measure(runner: GridRunner, device: str, episodes: int, warmup: int, count_episodes: int,
            t0: float, start_after: Path | None = None, sessions: int = 0) -> dict[str, Any]:
    """Warm up, then time ``episodes`` grid episodes and count over ``count_episodes`` more,
    then (a runner with ``session``) time ``sessions`` test sessions and saves; the
    JSON-ready figures (``startup_s`` from ``t0``, a ``time.perf_counter`` reading)."""
    for i in range(warmup):
        runner.episode()
        runner.synchronize()
        log(t0, f"warm-up episode {i + 1}/{warmup} done")
    startup = time.perf_counter() - t0
    waited = 0.0
    if start_after is not None:
        tic = time.perf_counter()
        while not start_after.exists():
            if time.perf_counter() - tic > START_AFTER_TIMEOUT_S:
                raise TimeoutError(f"--start-after: {start_after} did not appear within "
                                   f"{START_AFTER_TIMEOUT_S:.0f} s")
            time.sleep(0.2)
        waited = time.perf_counter() - tic
        log(t0, f"{start_after} exists after {waited:.1f} s of waiting: timing")
    seconds, replayed = [], 0
    replays = getattr(runner, "replays", lambda: 0)
    for i in range(episodes):
        before = replays()
        tic = time.perf_counter()
        runner.episode()
        runner.synchronize()
        seconds.append(time.perf_counter() - tic)
        replayed += replays() > before
        log(t0, f"timed episode {i + 1}/{episodes}: {1e3 * seconds[-1]:.1f} ms")
    totals = Counts()
    for _ in range(count_episodes):
        with counters(device) as c:
            runner.episode()
            runner.synchronize()
        totals.host_syncs += c.host_syncs
        totals.replays += c.replays
    n = max(count_episodes, 1)
    ms = 1e3 * statistics.median(seconds) if seconds else None
    session: dict[str, Any] = {}
    if sessions and hasattr(runner, "session"):
        session = runner.session(sessions)
        log(t0, f"test session {session['test_session_ms']:.1f} ms, its read and save "
                f"{session['save_ms']:.1f} ms")
        if ms is not None:
            session["ms_per_grid_episode_with_session_and_save"] = ms + (
                session["test_session_ms"] + session["save_ms"]) / SESSION_EVERY
    return {"ms_per_grid_episode": ms, **session, "replayed_timed_episodes": replayed,
            "startup_s": startup,
            "host_syncs_per_episode": round(totals.host_syncs / n),
            "graph_replays_per_episode": round(totals.replays / n),
            "episode_ms": [1e3 * s for s in seconds],
            "waited_s": waited}


def device_name(device: str) -> str:
    import platform

    import torch

    if device == "cuda":
        return torch.cuda.get_device_name()
    return platform.processor() or platform.machine()


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m benchmarks.grid_episode", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cuda",
                        help="torch device of the agents and the envs")
    parser.add_argument("--episodes", type=int, default=3,
                        help="timed grid episodes after the warm-up (>= 1); the median is "
                        "reported")
    parser.add_argument("--warmup", type=int, default=DEFAULT_WARMUP,
                        help="untimed grid episodes first (>= 0): the agents' random-action "
                        "episode, the bodies' eager runs and their capture, so that the "
                        "timed episodes replay")
    parser.add_argument("--sessions", type=int, default=3,
                        help="test sessions and saves timed after the episodes (--path "
                        "program; >= 0, 0: none), after the session's own warm-up and "
                        "capture; medians reported")
    parser.add_argument("--window", action="store_true",
                        help="the program in window mode (ddpg_her.train --window): a save "
                        "writes eval.csv only")
    parser.add_argument("--count-episodes", type=int, default=1,
                        help="further grid episodes run with the sync and replay counters "
                        "(>= 1); the counts are their means")
    parser.add_argument("--part", type=int, default=None, metavar="J",
                        help="only the grid's settings with J joints (default: the whole "
                        "grid, 55 agents)")
    parser.add_argument("--seeds", type=int, default=PAPER_SEEDS,
                        help="seeds per setting (>= 1)")
    parser.add_argument("--path", choices=sorted(PATHS), default="program",
                        help="which training path builds the grid")
    parser.add_argument("--unit-args", type=unit_arguments, default=[],
                        help="extra ddpg_her.train arguments of every unit, one shell-quoted "
                        "string (e.g. \"--hidden-sizes 8 8 --buffer-size 1000\"); not the "
                        "grid's own --region, --joints, --seeds, --episodes, --eval-every, "
                        "--warmup-episodes or --out (refused: the figures measure the grid)")
    parser.add_argument("--start-after", type=Path, default=None, metavar="FILE",
                        help="after the warm-up, wait until FILE exists before timing (so a "
                        "caller can run the start-up beside other work and time alone); "
                        f"an error after {START_AFTER_TIMEOUT_S:.0f} s without it")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    t0 = time.perf_counter()
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.warmup < 0 or args.count_episodes < 1 or args.seeds < 1 \
            or args.sessions < 0:
        parser.error(f"--episodes, --count-episodes and --seeds must be >= 1, --warmup and "
                     f"--sessions >= 0; got {args.episodes}, {args.count_episodes}, "
                     f"{args.seeds}, {args.warmup}, {args.sessions}")
    if args.window and args.path != "program":
        parser.error("--window is the program's (--path program)")
    if args.start_after is not None and not args.start_after.parent.is_dir():
        parser.error(f"--start-after {args.start_after}: its folder does not exist (the file "
                     "could never appear there)")
    try:
        settings = grid_settings(args.part)
    except ValueError as err:
        parser.error(str(err))
    import torch

    from ddpg_her import train

    args.threads = None
    train.start_process(parser, args)
    budget = args.warmup + args.episodes + args.count_episodes + 1
    with tempfile.TemporaryDirectory(prefix="grid_episode-") as tmp:
        spec = GridSpec(settings, args.seeds, args.device, Path(tmp),
                        tuple(args.unit_args), budget, args.window)
        try:
            runner = PATHS[args.path](spec)
        except ValueError as err:
            parser.error(str(err))
        log(t0, f"built {spec.agents} agents ({args.path}) on {args.device}")
        try:
            figures = measure(runner, args.device, args.episodes, args.warmup,
                              args.count_episodes, t0, args.start_after, args.sessions)
        finally:
            runner.close()
    result = {"device": device_name(args.device), **figures, "path": args.path,
              "agents": spec.agents, "part": args.part, "episodes": args.episodes,
              "warmup": args.warmup, "count_episodes": args.count_episodes,
              "window": args.window, "sessions": args.sessions,
              "session_every": SESSION_EVERY,
              "unit_args": shlex.join(args.unit_args), "torch": torch.__version__,
              "host_syncs_counted": "torch.cuda.set_sync_debug_mode('warn') warnings"
              if args.device == "cuda" else "calls of Tensor." + "/.".join(CPU_READS)}
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:>26}: {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
