"""The paper's sweep: every (region, joints) setting x seeds, on local processes or a Ray cluster.

    python -m analysis.sweep --grid paper [--episodes N] [--seeds K] [--out ROOT]
                             [--workers W | --ray-address ADDR] [--device cpu|cuda]
                             [--one-process | --no-one-process] [--dry-run]
    python -m analysis.sweep --grid paper --device cuda --one-process --dry-run  # 1 process

One training process per setting trains all its seeds at once (``ddpg_her.train --seeds``), into
``ROOT/<region>-j<joints>/s<seed>``; with ``--one-process`` one ``ddpg_her.train_many`` process
trains every unfinished setting, the settings of one joint count stacked into one agent batch.
Finished runs are skipped and unfinished ones resumed from their last checkpoint, so an interrupted
sweep continues where it stopped when run again; a setting another ``ddpg_her.train`` or
``ddpg_her.train_many`` process is training (it holds a run folder's lock) is left to it.
Each process's output goes to ``ROOT/logs/<region>-j<joints>.log`` (one process:
``ROOT/logs/one-process.log``). Arguments after ``--`` pass to ``ddpg_her.train`` unchanged
(e.g. ``-- --her-strategy future``) but for those the study or a unit's reading sets
(`owned_flag_problems`); a unit that could not start (`unit_problems`) is refused before any
starts, in a dry run too.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import itertools
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO, Any

from analysis.outputs import check_folder, usage_errors
from analysis.paper import PAPER_EPISODES, PAPER_GRID, PAPER_SEEDS
from analysis.runs import read_run
from ddpg_her.config import Parser
from ddpg_her.runfolder import RunFolder, run_status
from ddpg_her.train import add_window_flags, check_window_flags
from ddpg_her.units import DEFAULT_THREADS, option_dests, overrides, split_passthrough
from ur5kin.checks import COUNT

GRIDS: dict[str, tuple[tuple[str, int], ...]] = {
    "paper": PAPER_GRID, "paper+tall": (*PAPER_GRID, ("farbox_tall", 3), ("farbox_tall", 6))}
"""Named grids of (region, joints) settings."""


@dataclasses.dataclass(frozen=True)
class Unit:
    """One training process: a setting and the seeds it trains together.

    ``train_args`` are extra ``ddpg_her.train`` arguments of this unit (e.g. a reading of the
    sensitivity study, ``("--task", "action_penalty_unit=actor")``) and ``tag`` names them in
    messages; ``root`` is the folder its runs go to (``root/<region>-j<joints>/s<seed>``).
    """

    region: str
    joints: int
    seeds: tuple[int, ...]
    root: Path
    episodes: int
    train_args: tuple[str, ...] = ()
    tag: str = ""

    @property
    def setting(self) -> str:
        """``<region>-j<joints>``: the setting's folder below the root."""
        return f"{self.region}-j{self.joints}"

    @property
    def name(self) -> str:
        """The setting, prefixed by the tag when there is one (``tag/<region>-j<joints>``)."""
        return f"{self.tag}/{self.setting}" if self.tag else self.setting

    def run_dir(self, seed: int) -> Path:
        return self.root / self.setting / f"s{seed}"

    def status(self, seed: int) -> str:
        """'done', 'resume' or 'new' (`ddpg_her.runfolder.run_status`) of seed's run."""
        return run_status(self.run_dir(seed), self.episodes)

    def pending(self) -> bool:
        return any(self.status(s) != "done" for s in self.seeds)

    def episodes_done(self) -> int:
        """Training episodes evaluated so far, summed over the seeds and capped at the budget
        (an eval.csv that can't be read yet counts 0)."""
        total = 0
        for seed in self.seeds:
            try:
                run = read_run(self.run_dir(seed))
            except (ValueError, KeyError, OSError):
                continue
            if len(run.episode):
                total += min(int(run.episode[-1]), self.episodes)
        return total

    @property
    def episodes_total(self) -> int:
        """Training episodes of the whole unit: the budget times the seeds."""
        return self.episodes * len(self.seeds)

    @property
    def out(self) -> str:
        """The ``--out`` template of the unit's process (``{seed}`` left in)."""
        return str(self.root / self.setting / "s{seed}")

    def run_args(self, extra: Sequence[str] = ()) -> list[str]:
        """The unit's ``ddpg_her.train`` arguments without the process flags: its setting,
        seeds, budget, own ``train_args`` and folder, then ``extra``."""
        return ["--region", self.region, "--joints", str(self.joints),
                "--seeds", *map(str, self.seeds), "--episodes", str(self.episodes),
                *self.train_args, "--out", self.out, *extra]

    def command(self, threads: int, extra: Sequence[str], device: str = "cpu") -> list[str]:
        """The ``ddpg_her.train`` command line: the unit's own ``train_args``, then ``extra``."""
        return [sys.executable, "-m", "ddpg_her.train", *self.run_args(), "--resume",
                "--no-progress", "--threads", str(threads), "--device", device, *extra]

    @property
    def log_path(self) -> Path:
        return self.root / "logs" / f"{self.setting}.log"


def parse_setting(text: str) -> tuple[str, int]:
    """``REGION:JOINTS`` -> (region, joints)."""
    region, sep, joints = text.rpartition(":")
    if not sep or not region or not joints.isdigit() or not 2 <= int(joints) <= 6:
        raise argparse.ArgumentTypeError(
            f"expected REGION:JOINTS with joints in 2..6; got {text!r}")
    return region, int(joints)


def child_env(threads: int) -> dict[str, str]:
    """This process's environment with every BLAS and OpenMP pool of a child capped at
    ``threads``: concurrent trainers that each start one pool per core oversubscribe the
    machine (numpy's OpenBLAS in the env's clearance check ran 20x slower so on 2 cores)."""
    return {**os.environ, **dict.fromkeys(
        ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"), str(threads))}


PR_SET_PDEATHSIG = 1
"""prctl(2)'s option (Linux, <sys/prctl.h>): the signal a process gets when the thread that
started it ends."""


def die_with_parent() -> Callable[[], None] | None:
    """A ``preexec_fn`` after which the started process gets SIGKILL when the thread that
    started it ends, however it ends (SIGKILL included), so a killed study leaves no orphan
    training on: it would hold its run folder's lock, so the study run again would leave that
    unit to it, and its log would fill with both (issue 37, kind 1). None where prctl cannot be
    called (not Linux): there a killed study's processes train on until they end.

    Each caller of `start_unit` waits for its process in the thread that started it (the main
    thread, or a Ray task's), so the signal comes only when that wait can no longer end.
    """
    if not sys.platform.startswith("linux"):
        return None
    import ctypes

    try:
        prctl = ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None
    parent = os.getpid()

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
        if os.getppid() != parent:  # the parent died before prctl took effect
            os.kill(os.getpid(), signal.SIGKILL)

    return preexec


def start_unit(command: Sequence[str], log_path: str | Path, threads: int,
               cwd: str | None = None) -> tuple[subprocess.Popen, IO[str]]:
    """Start one training process, its output appended to ``log_path`` after a line with the
    command; returns the process and the open log (the caller closes it when the process ends).
    The process dies with this one (`die_with_parent`).
    """
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    log = open(log_path, "a")  # noqa: SIM115 (outlives this function, with the process)
    log.write(f"\n$ {' '.join(command)}\n")
    log.flush()
    proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, cwd=cwd,
                            env=child_env(threads), preexec_fn=die_with_parent())
    return proc, log


def run_unit(command: Sequence[str], log_path: str, cwd: str, threads: int = 1) -> int:
    """Run one training process with its output appended to ``log_path``; its exit code."""
    proc, log = start_unit(command, log_path, threads, cwd)
    with log:
        return proc.wait()


PROGRESS_POLL_S = 5.0
"""Seconds between two reads of the running units' eval.csv files for the progress bar."""


class EpisodeBar:
    """A tqdm bar over the training episodes of a set of units, read from their eval.csv files.

    Evaluations come every ``--eval-every`` episodes, so the bar moves in those steps; a unit
    whose process has ended well counts in full, a failed one only with the episodes it
    finished, so the bar never reaches 100 % over a failure, and its postfix counts them.
    """

    def __init__(self, units: Sequence[Unit], desc: str):
        from tqdm import tqdm

        self.units = list(units)
        self.ended: set[int] = set()
        self.failed: set[int] = set()
        self._last_poll = 0.0
        # episodes of a resumed sweep count as done from the start, not as progress of this
        # process (tqdm's rate and time left count from ``initial``)
        self.bar = tqdm(total=sum(u.episodes_total for u in self.units), desc=desc,
                        unit="episode", file=sys.stderr, smoothing=0.05,
                        initial=sum(u.episodes_done() for u in self.units))

    def end(self, unit: Unit, failed: bool = False) -> None:
        """Mark ``unit``'s process as ended (``failed``: with a non-zero status)."""
        (self.failed if failed else self.ended).add(self.units.index(unit))
        self.refresh(force=True)

    def refresh(self, force: bool = False) -> None:
        now = time.monotonic()
        if not force and now - self._last_poll < PROGRESS_POLL_S:
            return
        self._last_poll = now
        done = sum(u.episodes_total if i in self.ended else u.episodes_done()
                   for i, u in enumerate(self.units))
        if done > self.bar.n:
            self.bar.update(done - self.bar.n)
        self.bar.set_postfix_str(f"{len(self.ended) + len(self.failed)}/{len(self.units)} units"
                                 + (f", {len(self.failed)} FAILED" if self.failed else ""),
                                 refresh=False)

    def finish(self, unit: Unit, code: int) -> int:
        """Mark ``unit``'s process as ended with exit status ``code``, saying what it said last
        when it failed (`failure`); 1 when it failed, else 0."""
        if code != 0:
            self.write(f"{unit.name} failed (exit {code}): {failure(unit.log_path)}")
        self.end(unit, failed=code != 0)
        return int(code != 0)

    def write(self, text: str) -> None:
        self.bar.write(text, file=sys.stderr)

    def close(self) -> None:
        self.bar.close()


def run_local(units: Sequence[Unit], workers: int, threads: int, extra: Sequence[str],
              device: str = "cpu") -> int:
    """Run the units in at most ``workers`` concurrent processes; the number that failed."""
    queue = list(units)
    running: dict[subprocess.Popen, tuple[Unit, IO[str]]] = {}
    failed = 0
    bar = EpisodeBar(units, "training")
    try:
        while queue or running:
            while queue and len(running) < workers:
                unit = queue.pop(0)
                proc, log = start_unit(unit.command(threads, extra, device), unit.log_path, threads)
                running[proc] = (unit, log)
            for proc in [p for p in running if p.poll() is not None]:
                unit, log = running.pop(proc)
                log.close()
                failed += bar.finish(unit, proc.returncode)
            bar.refresh()
            time.sleep(0.2)
    except KeyboardInterrupt:
        for proc in running:
            proc.terminate()
        for proc in running:
            proc.wait()
        bar.write("interrupted; run the same command again to resume")
        raise
    finally:
        bar.close()
    return failed


def run_ray(units: Sequence[Unit], address: str, threads: int, extra: Sequence[str],
            device: str = "cpu") -> int:
    """Run the units as Ray tasks (``address``: a cluster, or 'local' to start one here).

    With ``device='cuda'`` each task asks Ray for a fraction of a GPU (the units share the
    cluster's GPUs evenly, at most one each). The bar reads eval.csv files, so on a cluster
    without a shared file system it moves only as units end.
    """
    import ray

    ray.init(address=None if address == "local" else address, include_dashboard=False,
             log_to_driver=False, ignore_reinit_error=True)
    try:
        gpus = 0.0
        if device == "cuda":
            total = float(ray.cluster_resources().get("GPU", 0.0))
            if total <= 0:
                raise RuntimeError("--device cuda: the Ray cluster has no GPU")
            gpus = min(1.0, total / max(1, len(units)))
        task = ray.remote(num_cpus=threads, num_gpus=gpus)(run_unit)
        cwd = os.getcwd()
        pending = {task.remote(u.command(threads, extra, device), str(u.log_path), cwd,
                               threads): u for u in units}
        failed = 0
        bar = EpisodeBar(units, "training (ray)")
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1, timeout=PROGRESS_POLL_S)
                bar.refresh()
                if done:
                    failed += bar.finish(pending.pop(done[0]), ray.get(done[0]))
        finally:
            bar.close()
        return failed
    finally:
        ray.shutdown()


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """``--help`` with each flag's default, except where there is none to show (None, False,
    an empty list: the help text says what happens then)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        if action.default is None or action.default is False or action.default == []:
            return action.help
        return super()._get_help_string(action)


def add_execution_arguments(parser: argparse.ArgumentParser, default_out: Path,
                            unit_word: str = "setting") -> None:
    """The flags of every study that trains units: budget, root, where and how they run."""
    parser.add_argument("--episodes", type=COUNT.read, default=PAPER_EPISODES,
                        help="training episodes per run (count, >= 1); a run with fewer is "
                             "resumed up to it")
    parser.add_argument("--seeds", type=COUNT.read, default=PAPER_SEEDS,
                        help=f"seeds per {unit_word}, 0..K-1, trained together in one process "
                             "(count, >= 1)")
    parser.add_argument("--out", type=Path, default=default_out, help="root folder of the runs")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=COUNT.read, default=1,
                       help="concurrent local training processes (count, >= 1)")
    where.add_argument("--ray-address", default=None,
                       help="run on this Ray cluster ('auto', 'ray://host:port', or 'local' "
                            "to start one on this machine)")
    parser.add_argument("--threads", type=COUNT.read, default=None,
                        help="torch threads per training process (count, >= 1; default: "
                             f"{DEFAULT_THREADS}, ddpg_her.train's, which keeps a fair share "
                             "of the cores when other work runs)")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="torch device of each training process (cuda: networks and replay "
                             "buffers on the GPU; runs are bitwise repeatable only on the cpu)")
    parser.add_argument("--env-backend", choices=("numpy", "batched", "program"), default="numpy",
                        help="the training processes' env backend (ddpg_her.train --env-backend): "
                             "'batched' steps the envs of all agents of a process whose tasks "
                             "differ only in their goals in one compiled call, the same goals, "
                             "trajectories equal to rounding; 'program', the training program "
                             "(ddpg_her.program: all agents of a process as one stack on --device; "
                             "see --program) (default: numpy, one env per agent)")
    parser.add_argument("--program", action="store_true",
                        help="the training program for every unfinished unit in one process: "
                             "--one-process --env-backend program (the whole grid, or --part, "
                             "as one stack of agents on --device)")
    add_window_flags(parser, "the training program (--program)",
                     "--episodes, its half, quarter and eighth")
    parser.add_argument("--one-process", action=argparse.BooleanOptionalAction, default=False,
                        help="train every unfinished unit in one process (python -m "
                             "ddpg_her.train_many: units of one joint count and agent "
                             "configuration share one stacked agent), its output in "
                             "ROOT/logs/one-process.log (default: one process per unit: on an "
                             "H100 the paper's grid in one process ran 2.1 s per episode of "
                             "its 55 agents with --env-backend numpy, no faster than one "
                             "process per unit; pair it with --env-backend batched)")
    parser.add_argument("--dry-run", action="store_true",
                        help="print one line per run (status, folder, command) and exit")
    parser.add_argument("--project", nargs="?", const="quick", choices=("quick", "full"),
                        default=None,
                        help="with --dry-run: print the projected wall time (s and h) of the run. "
                             "'quick' (the flag alone): each distinct process layout (joint count, "
                             "seeds, own arguments), one at a time, trains 2 episodes (a warm-up "
                             "and a learning episode of 25 updates, each with a test session of 1 "
                             "episode per agent) as the real command would run it, in a temporary "
                             "folder deleted afterwards, scaled by a stated model, its processes "
                             "run --workers at a time without slowing each other (seconds to a "
                             "minute); 'full': then also train the first two test intervals (2 x "
                             "--eval-every episodes) of every unfinished unit, its cost by the "
                             "quick model printed before it starts (about 1 %% of the paper's run)")


RAY_CONNECT_S = 5.0
"""s: how long a Ray address's host may take to accept a connection before the study says no
cluster answers there (ray.init itself kept trying for over 120 s)."""


def ray_address_problem(address: str) -> str | None:
    """Why ``address`` cannot be a Ray cluster to run on, in our words, or None: the ``ray``
    package missing, an address that is not 'local', 'auto', ``HOST:PORT`` or
    ``ray://HOST:PORT``, or nothing accepting a connection at HOST:PORT within
    `RAY_CONNECT_S`. 'auto' is left to Ray, which finds the cluster of this machine."""
    import importlib.util
    import socket

    if importlib.util.find_spec("ray") is None:
        return "the ray package is not installed (pip install 'ray[default]')"
    if address in ("local", "auto"):
        return None
    hostport = address.removeprefix("ray://")
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        return "expected 'local', 'auto', HOST:PORT or ray://HOST:PORT (a port in 1..65535)"
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=RAY_CONNECT_S):
            return None
    except OSError as err:
        return (f"no Ray cluster answers at {host}:{port} ({err.strerror or err}); start one "
                "(ray start --head) or use 'local'")


def check_execution_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """Exit through ``parser.error`` on a count below 1; the threads per process to use.
    ``--program`` becomes ``--one-process --env-backend program``."""
    if args.program:
        if args.env_backend not in ("numpy", "program"):
            parser.error(f"--program trains with --env-backend program; got --env-backend "
                         f"{args.env_backend}")
        args.one_process, args.env_backend = True, "program"
    check_window_flags(parser, args, "the training program (--program)")
    if args.one_process and args.ray_address:
        parser.error("--one-process runs here, not on Ray; drop --ray-address or add "
                     "--no-one-process")
    if args.one_process and args.workers > 1:
        parser.error(f"--one-process runs one process; --workers {args.workers} contradicts it")
    if args.project and not args.dry_run:
        parser.error("--project is part of a dry run: add --dry-run")
    if args.project and args.ray_address:
        parser.error("--project times the units on this machine, not on a Ray cluster; drop "
                     "--ray-address")
    if not args.dry_run and getattr(args, "collect", None) is None:  # before any unit starts
        problem = args.ray_address and ray_address_problem(args.ray_address)
        if problem:
            parser.error(f"--ray-address {args.ray_address}: {problem}")
        with usage_errors(parser):  # the root of the runs (and its logs)
            check_folder(args.out / "logs", "--out")
    return args.threads or DEFAULT_THREADS


GPU_COMMAND_S = 600
"""The longest command a lent GPU machine runs (s): a part of the grid trained by the program
must end within it, since replay buffers cannot leave the machine."""

ONE_PROCESS_LOG = "logs/one-process.log"
"""Below the root: the output of the one-process trainings, appended run after run."""


def failure(log: Path) -> str:
    """What a failed training process said last (the last line of its ``log``: its error, or
    a traceback's last line), and where the whole log is."""
    try:
        lines = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        lines = []
    return f"{lines[-1].strip() if lines else 'it wrote nothing'} (whole log: {log})"


def one_process_command(plan: Path | str, threads: int, args: argparse.Namespace) -> list[str]:
    """The ``ddpg_her.train_many`` command line that trains a plan's units in one process."""
    return [sys.executable, "-m", "ddpg_her.train_many", "--plan", str(plan), "--resume",
            "--no-progress", "--threads", str(threads), "--device", args.device,
            *backend_args(args)]


def backend_args(args: argparse.Namespace) -> list[str]:
    """The training command's arguments for ``--env-backend``, ``--tf32``, ``--window`` and
    ``--budget-seconds`` (none for the defaults)."""
    budget = getattr(args, "budget_seconds", None)
    return ((["--env-backend", args.env_backend] if args.env_backend != "numpy" else [])
            + (["--tf32"] if args.tf32 else [])
            + (["--window"] if getattr(args, "window", False) else [])
            + (["--budget-seconds", str(budget)] if budget is not None else []))


def run_one_process(units: Sequence[Unit], args: argparse.Namespace, threads: int,
                    extra: Sequence[str]) -> int:
    """Train the units in one ``ddpg_her.train_many`` process, whose plan (every unit's
    ``ddpg_her.train`` arguments) goes to ``ROOT/logs/one-process-<time>.json``; 1 when the
    process failed, else 0."""
    from ddpg_her.units import write_plan

    root = args.out
    plan = root / "logs" / f"one-process-{time.strftime('%Y%m%d-%H%M%S')}.json"
    write_plan(plan, [u.run_args(extra) for u in units])
    proc, log = start_unit(one_process_command(plan, threads, args), root / ONE_PROCESS_LOG,
                           threads)
    bar = EpisodeBar(units, "training (one process)")
    try:
        while proc.poll() is None:
            bar.refresh()
            time.sleep(0.2)
    except KeyboardInterrupt:
        proc.terminate()
        proc.wait()
        bar.write("interrupted; run the same command again to resume")
        raise
    finally:
        log.close()
        if proc.returncode is not None:
            for unit in units:
                bar.end(unit, failed=proc.returncode != 0)
        bar.close()
    if proc.returncode != 0:
        print(f"the training process failed (exit {proc.returncode}): "
              f"{failure(root / ONE_PROCESS_LOG)}", file=sys.stderr)
        return 1
    return 0


def busy(unit: Unit) -> bool:
    """Whether another live process trains one of ``unit``'s run folders: it holds the
    folder's lock (`ddpg_her.runfolder.RunFolder.lock`), whatever its command line or cwd."""
    return any(RunFolder(unit.run_dir(seed)).holder() is not None for seed in unit.seeds)


STUDY_FLAGS = ("region", "joints", "seeds", "seed", "episodes", "out", "resume", "no_progress",
               "threads", "device", "env_backend", "tf32")
"""The ``ddpg_her.train`` options (by dest) that a study sets itself for every unit: its setting,
seeds, budget and folder, and the process flags it has options of its own for. Arguments after
``--`` and a reading's arguments may not set them: the last flag would win, and a unit would
train something else than the study counts (issue 37: ``-- --region zheight`` trained z-height
into ``farbox-j3``, ``-- --out X`` trained into X while the study counted the unit done)."""


def task_keys(args: Sequence[str]) -> list[str]:
    """The TaskSpec fields that the ``--task KEY=VALUE`` options of ``args`` set (a malformed
    one is left to ``ddpg_her.train`` to name)."""
    values = [v for f, v in itertools.pairwise(args) if f == "--task"]
    values += [a.partition("=")[2] for a in args if a.startswith("--task=")]
    return [v.partition("=")[0] for v in values if "=" in v]


def owned_flag_problems(parser: argparse.ArgumentParser, unit: Unit,
                        extra: Sequence[str]) -> list[str]:
    """Where ``unit``'s own arguments or ``extra`` (the arguments after ``--``) set what the
    study sets (`STUDY_FLAGS`), or ``extra`` sets an option or ``--task`` field that the unit's
    reading sets: one line each, naming the flag."""
    problems = []
    for where, args in (("its reading's arguments", unit.train_args),
                        ("the arguments after --", extra)):
        problems += [f"{unit.name}: {flag} in {where}: the study sets it for every unit (use "
                     "the study's own option, or drop it)"
                     for flag, dest in option_dests(parser, args) if dest in STUDY_FLAGS]
        problems += [f"{unit.name}: --task {key}=... in {where}: the study sets it for every "
                     "unit (its setting)" for key in task_keys(args)
                     if key in ("region", "n_joints")]
    own_task = task_keys(unit.train_args)
    return problems + [
        f"{unit.name}: {flag} after --: the unit's reading sets it ({' '.join(unit.train_args)})"
        for flag in [*overrides(parser, unit.train_args, extra),
                     *(f"--task {key}=..." for key in task_keys(extra) if key in own_task)]]


def unit_problems(units: Sequence[Unit], extra: Sequence[str],
                  process: Sequence[str] = (), one_process: bool = False,
                  device: str = "cpu", dry: bool = False) -> list[str]:
    """Why units could not start, one line each: an option the study sets itself given again
    after ``--`` or by a reading (`owned_flag_problems`), a command line ``ddpg_her.train``
    refuses (an unknown flag, a bad value, a task its record refuses: `ddpg_her.units.Setting`),
    or two units (or two seeds) with one run folder. Checks
    what needs neither the robot nor torch. ``process``: the study's own process arguments
    (`backend_args`), checked with ``extra`` by ``ddpg_her.train`` but not as passed-through.
    With ``one_process``, a flag of the training process (`ddpg_her.train.PROCESS_FLAGS`) after
    ``--`` is refused too: ``ddpg_her.train_many`` takes those once, and the study sets them.
    ``device``: the study's --device, which must exist (a ``dry`` run notes its absence, to
    plan a GPU run on another machine); with ``--env-backend program`` in
    ``process``, what the program refuses (`ddpg_her.train.check_stack`), unit by unit, then
    the stack of them all (its memory), so a dry run refuses what the real run would."""
    import io

    from ddpg_her import train

    tf32 = "--tf32" in process
    try:
        train.check_device(device)
    except ValueError as error:
        if not dry:
            return [str(error)]
        print(f"note: {error}: the real run here would refuse; listed as a machine with one "
              "would run it", file=sys.stderr)
        device, tf32 = "cpu", False
    problems: list[str] = []
    reqs = []
    program = "program" in process
    parser = train.make_parser()
    if one_process:
        problems += [f"{flag} after --: a flag of the training process, which the study's one "
                     "ddpg_her.train_many process takes once (its own options set it, or "
                     "drop --one-process)"
                     for flag, dest in option_dests(parser, extra) if dest in train.PROCESS_FLAGS]
        if problems:
            return problems
    for unit in units:
        owned = owned_flag_problems(parser, unit, extra)
        if owned:
            problems += owned
            continue
        args = unit.run_args([*extra, *process])
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err):
                req = train.request(train.parse_args(parser, args), resume=True)
            if program:
                train.check_stack([req], device, tf32)
        except SystemExit:
            message = err.getvalue().strip().splitlines()[-1:] or ["a usage error"]
            problems.append(f"{unit.name}: ddpg_her.train refuses its command line: "
                            f"{message[0]}")
            continue
        except ValueError as error:
            problems.append(f"{unit.name}: {error}")
            continue
        reqs.append(req)
    from ddpg_her.units import shared_folders

    problems += shared_folders((u.run_dir(s), f"{u.name} s{s}") for u in units for s in u.seeds)
    if program and one_process and reqs and not problems:
        try:
            train.check_stack(reqs, device, tf32)
        except ValueError as error:
            problems.append(f"the units as one program stack: {error}")
    return problems


def refuse_problems(units: Sequence[Unit], extra: Sequence[str], args: argparse.Namespace
                    ) -> None:
    """Exit with status 2 and every line of `unit_problems` when a unit could not start (the
    study's --env-backend, --tf32, --one-process and --device from ``args``)."""
    problems = unit_problems(units, extra, backend_args(args), args.one_process, args.device,
                             args.dry_run)
    if problems:
        for line in problems:
            print(f"error: {line}", file=sys.stderr)
        print(f"error: {len(problems)} problem(s); nothing was started", file=sys.stderr)
        raise SystemExit(2)


def dry_run(units: Sequence[Unit], args: argparse.Namespace, threads: int,
            extra: Sequence[str]) -> None:
    """One line per run: status ('done', 'resume', 'new', or 'busy' while another process trains its
    unit), tag, setting, seed, folder and the unit's command (with ``--one-process``: its arguments
    in the one ``ddpg_her.train_many`` process); then, with ``--project``, `print_projection`. Units
    that could not start are refused first (`refuse_problems`), as a real run would."""
    refuse_problems(units, extra, args)
    for unit in units:
        cmd = "one process, unit " + " ".join(unit.run_args(extra)) if args.one_process else \
            "python " + " ".join(unit.command(threads, [*extra, *backend_args(args)],
                                              args.device)[1:])
        tag = f"{unit.tag:<18} " if unit.tag else ""
        for seed in unit.seeds:
            status = "busy" if busy(unit) and unit.status(seed) != "done" else unit.status(seed)
            print(f"{status:<6} {tag}{unit.region:<14} joints={unit.joints} "
                  f"seed={seed} {unit.run_dir(seed)}  <- {cmd}")
    command = one_process_command("ROOT/logs/one-process-TIME.json", threads, args)
    print(f"{sum(len(u.seeds) for u in units)} runs in {len(units)} units"
          + (f", the unfinished ones in one process: python {' '.join(command[1:])}"
             if args.one_process else " (one process each)"), file=sys.stderr)
    if args.project:
        print_projection(units, args, threads, extra)


def projected_seconds(walls: Sequence[tuple[int, float]], every: int, episodes: int) -> float:
    """Projected wall time (s) of a run of ``episodes`` training episodes from the eval rows of
    its first two test intervals, ``walls`` = [(every, wall_s), (2 * every, wall_s)]
    (eval.csv's ``episode`` and ``wall_s``): the first interval as measured (start-up, warm-up
    episodes, the first test session), then every further ``every`` episodes (training and
    updates, a test session, a checkpoint) as long as the second, the last part pro rata.

    Raises ValueError unless ``walls`` are those two rows with wall times increasing.
    """
    if len(walls) != 2 or [e for e, _ in walls] != [every, 2 * every] \
            or not 0 <= walls[0][1] <= walls[1][1]:
        raise ValueError(f"need the eval rows at episodes {every} and {2 * every} with wall_s "
                         f"increasing; got {list(walls)}")
    (_, first), (_, second) = walls
    return first + max(episodes - every, 0) / every * (second - first)


def makespan(seconds: Sequence[float], workers: int) -> float:
    """Wall time (s) of jobs of these durations run in this order by ``workers`` concurrent
    processes, each next job taking the first free process (as `run_local` does)."""
    free = [0.0] * max(1, min(workers, len(seconds)))
    for s in seconds:
        free[free.index(min(free))] += s
    return max(free, default=0.0)


QUICK_UPDATES = 25
"""Updates per agent in the quick projection's one timed learning episode; the projection
scales the time of one update to each unit's ``--updates-per-episode``."""

QUICK_ARGS = ("--warmup-episodes", "1", "--eval-every", "1", "--eval-episodes", "1",
              "--updates-per-episode", str(QUICK_UPDATES))
"""Appended (last, so they win) to the quick projection's timed processes of 2 episodes: a warm-up
episode and its test session of one episode per agent, then a learning episode and its session."""


@dataclasses.dataclass(frozen=True)
class EpisodeCosts:
    """The stated model of a training process's wall time (s): ``start`` (imports, envs,
    networks) + every episode one ``rollout`` (one episode of each agent of the process) +
    every learning episode ``--updates-per-episode`` x ``update`` (one update of each agent) +
    every test session ``--eval-episodes`` rollouts. A session's episodes are counted one by
    one: as they cost under --env-backend numpy (an env each), an upper bound where they step
    together (batched, program). Episodes that end early as agents learn make it lean long."""

    start: float
    rollout: float
    update: float

    @classmethod
    def of_rows(cls, walls: Sequence[float], start: float) -> EpisodeCosts:
        """From the ``wall_s`` of a timed process's two eval rows (`QUICK_ARGS`): the first is
        2 rollouts (the warm-up episode, a session of one); the second adds a learning episode
        with `QUICK_UPDATES` updates and a session."""
        first, second = walls
        return cls(start, first / 2, max(second - 2 * first, 0.0) / QUICK_UPDATES)

    def seconds(self, config: Any, done: int = 0) -> float:
        """Training of ``config`` (an AgentConfig) from episode ``done`` to its budget, s."""
        left = max(config.episodes - done, 0)
        warm = min(max(config.warmup_episodes - done, 0), left)
        sessions = config.episodes // config.eval_every - done // config.eval_every
        return (left * self.rollout + (left - warm) * config.updates_per_episode * self.update
                + sessions * config.eval_episodes * self.rollout)


PROJECTION_PREFIX = "sweep-projection-"
"""Temporary folders of projections: ``<prefix><pid>-<random>``."""


def projection_folder() -> Path:
    """A new temporary folder for a projection's timed processes, named with this process's
    id; the folders of projections whose process has ended (killed before it could delete
    its own) are deleted first."""
    for old in Path(tempfile.gettempdir()).glob(f"{PROJECTION_PREFIX}*-*"):
        pid = old.name[len(PROJECTION_PREFIX):].partition("-")[0]
        try:
            alive = pid.isdigit() and (os.kill(int(pid), 0) or True)
        except ProcessLookupError:
            alive = False
        except OSError:  # another user's: alive
            alive = True
        if not alive:
            shutil.rmtree(old, ignore_errors=True)
    return Path(tempfile.mkdtemp(prefix=f"{PROJECTION_PREFIX}{os.getpid()}-"))


def timed_run(units: Sequence[Unit], args: argparse.Namespace, threads: int,
              extra: Sequence[str], what: str, workers: int | None = None
              ) -> tuple[float, list[list[float]]]:
    """Train ``units`` (their roots in a `projection_folder`) as `execute` would, ``extra``
    after every unit's own arguments, in ``workers`` processes at a time (default --workers);
    (wall seconds spent, each unit's first seed's eval ``wall_s``). The folder is deleted
    afterwards, also on SIGTERM or Ctrl-C; a process that failed is named with its log's last
    line before (not a path to a deleted log)."""
    tmp = projection_folder()
    timed = [dataclasses.replace(u, root=tmp / f"unit{i}") for i, u in enumerate(units)]
    previous = signal.signal(signal.SIGTERM, lambda *_: (_ for _ in ()).throw(KeyboardInterrupt))
    try:
        start = time.perf_counter()
        with contextlib.redirect_stdout(sys.stderr):
            if args.one_process:
                status = run_one_process(timed, argparse.Namespace(**{**vars(args), "out": tmp}),
                                         threads, extra)
            else:
                status = run_local(timed, workers or args.workers, threads,
                                   [*extra, *backend_args(args)], args.device) and 1
        spent = time.perf_counter() - start
        if status != 0:
            for log in sorted(tmp.rglob("*.log")):
                lines = [x for x in log.read_text(errors="replace").splitlines() if x.strip()]
                print(f"projection: {log.stem}: {lines[-1] if lines else 'no output'}",
                      file=sys.stderr)
            raise SystemExit(f"projection: {what} failed (each process's last line above); "
                             "nothing of it is kept")
        walls = [[float(r["wall_s"]) for r in RunFolder(t.run_dir(t.seeds[0])).read_eval()]
                 for t in timed]
    except KeyboardInterrupt:
        raise SystemExit(f"projection: interrupted; {what} deleted") from None
    finally:
        signal.signal(signal.SIGTERM, previous)
        shutil.rmtree(tmp, ignore_errors=True)
    return spent, walls


def print_projection(units: Sequence[Unit], args: argparse.Namespace, threads: int,
                     extra: Sequence[str]) -> float:
    """Print the projected wall time (s) of the real run of the unfinished units, and return
    it: by default ("quick") by `EpisodeCosts`, timed on 2 episodes of one process per
    distinct layout (with ``--one-process``, of the one process), run one at a time as the
    real command would run them, then scheduled on --workers (`makespan`); with ``--project
    full``, then by training the first two test intervals of every unit
    (`projected_seconds`), its cost by the quick model printed first."""
    from ddpg_her import train

    todo = [u for u in units if u.pending()]
    if not todo:
        print("projection: every unit has finished; nothing to run", file=sys.stderr)
        return 0.0
    # each unit's AgentConfig as ddpg_her.train reads its command line
    configs = [train.request(train.parse_args(train.make_parser(), u.run_args(extra)),
                             resume=True).config for u in todo]
    done = [u.episodes_done() // len(u.seeds) for u in todo]
    # a layout: what makes two units' processes cost alike, the agents they stack (joints,
    # seeds) and their own arguments; not the region (goals cost alike to draw)
    keys = [("all",) if args.one_process else (u.joints, len(u.seeds), u.train_args) for u in todo]
    reps = list(dict.fromkeys(keys))
    timed = [dataclasses.replace(u, episodes=2) for u in
             (todo if args.one_process else [todo[keys.index(k)] for k in reps])]
    # one at a time: 2 episodes run beside another layout's start-up (or alone, the last of
    # --workers) would time that start-up (or none) as every episode's
    spent, walls = timed_run(timed, args, threads, [*extra, *QUICK_ARGS],
                             f"the timed run of {len(reps)} process layout(s)", workers=1)
    def span(times: Sequence[float]) -> float:  # the processes' wall time, run as planned
        # one process is one stack: each episode steps every unit at once
        return max(times) if args.one_process else makespan(times, args.workers)

    ends = [w[-1] for w in walls]
    start = max(0.0, spent - max(ends)) if args.one_process else \
        max(0.0, spent - sum(ends)) / len(timed)
    costs = {k: EpisodeCosts.of_rows(w, start) for k, w in zip(reps, walls, strict=True)}
    seconds = [costs[k].seconds(c, d) for k, c, d in zip(keys, configs, done, strict=True)]
    for unit, n, sec in zip(todo, done, seconds, strict=True):
        print(f"projection: {unit.name:<24} {unit.episodes - n:>6} episodes left -> "
              f"{sec:10.0f} s of training", file=sys.stderr)
    total = span([start + s for s in seconds])
    where = "one process" if args.one_process else f"{args.workers} process(es) at a time"
    print(f"projected wall time: {total:.0f} s ({total / 3600:.2f} h) for {len(todo)} "
          f"unfinished unit(s) to {max(u.episodes for u in todo):,} episodes, {where}, "
          f"--device {args.device}; model: per process {start:.0f} s of start-up + episodes x "
          "(a rollout of its agents + its updates) + test episodes x a rollout (sessions "
          "counted episode by episode), each term timed on 2 episodes of each of "
          f"{len(reps)} process layout(s) in {spent:.0f} s, one at a time, at a load average "
          f"of {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
    if args.project == "full":
        first = [dataclasses.replace(c, episodes=min(2 * c.eval_every, c.episodes))
                 for c in configs]
        cost = span([start + costs[k].seconds(c) for k, c in zip(keys, first, strict=True)])
        print(f"projection (full): training the first 2 test intervals of each of {len(todo)} "
              f"unit(s) costs about {cost:.0f} s by the model above; starting (Ctrl-C stops "
              "it and deletes what it trained)", file=sys.stderr, flush=True)
        spent, rows = timed_run([dataclasses.replace(u, episodes=c.episodes)
                                 for u, c in zip(todo, first, strict=True)], args, threads,
                                extra, "the full projection's timed run")
        timed_s = [w[-1] if c.episodes < 2 * c.eval_every else projected_seconds(
            [(c.eval_every, w[0]), (2 * c.eval_every, w[1])], c.eval_every, u.episodes - d)
            for u, c, w, d in zip(todo, first, rows, done, strict=True)]
        start = max(0.0, spent - span([w[-1] for w in rows]))
        total = span(timed_s) + start
        print(f"projected wall time (full): {total:.0f} s ({total / 3600:.2f} h), with "
              f"{start:.0f} s of process start-up; measured by training the first "
              f"{2 * max(c.eval_every for c in configs)} episodes of each in {spent:.0f} s",
              flush=True)
    if args.env_backend == "program":
        verdict = "fits" if total <= GPU_COMMAND_S else "does not fit"
        print(f"the training program: {verdict} one command of a GPU window ({GPU_COMMAND_S} "
              f"s; --part J runs the grid by joint count)", flush=True)
    return total


def execute(units: Sequence[Unit], args: argparse.Namespace, threads: int,
            extra: Sequence[str], unit_word: str = "settings") -> int:
    """Run the unfinished units locally or on Ray; 1 when one failed, else 0."""
    refuse_problems(units, extra, args)
    todo = [u for u in units if u.pending()]
    print(f"{len(units) - len(todo)} of {len(units)} {unit_word} already finished; "
          f"{len(todo)} to run", file=sys.stderr)
    for unit in [u for u in todo if busy(u)]:
        print(f"{unit.name}: another process is training it ({unit.out}); skipped, run again "
              "when it has ended", file=sys.stderr)
        todo.remove(unit)
    if not todo:
        return 0
    try:  # Ctrl-C: the runners said so in one line and stopped their processes
        if args.one_process:
            return run_one_process(todo, args, threads, extra)
        extra = [*extra, *backend_args(args)]
        if args.ray_address:
            failed = run_ray(todo, args.ray_address, threads, extra, args.device)
        else:
            failed = run_local(todo, args.workers, threads, extra, args.device)
    except KeyboardInterrupt:
        return 130
    except OSError as err:  # a full disk, a folder made read-only: what finished stays whole
        print(f"error: {err}; free space or make {args.out} writable, then run the same "
              "command again to resume", file=sys.stderr)
        return 1
    return 1 if failed else 0


def main(argv: Sequence[str] | None = None) -> int:
    argv, extra = split_passthrough(sys.argv[1:] if argv is None else argv)
    parser = Parser(
        prog="python -m analysis.sweep", description=__doc__.split("\n\n")[0],
        epilog="Arguments after -- pass to python -m ddpg_her.train.",
        formatter_class=HelpFormatter)
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--grid", choices=sorted(GRIDS), default="paper",
                       help="named grid: 'paper' is unconstrained with 2-6 joints and zheight, "
                            "closebox, farbox with 3 and 6 joints (11 settings)")
    which.add_argument("--setting", type=parse_setting, action="append", metavar="REGION:JOINTS",
                       help="a setting instead of a named grid; repeatable")
    parser.add_argument("--part", type=COUNT.read, default=None, metavar="JOINTS",
                        help="only the settings with this many controlled joints (2-6): a "
                             "part of the grid that fits one GPU window with --program")
    add_execution_arguments(parser, Path("runs/sweep"))
    from ddpg_her import train

    train.refuse_removed(parser, argv)
    args = parser.parse_args(argv)
    threads = check_execution_arguments(parser, args)
    settings = args.setting or GRIDS[args.grid]
    if args.part is not None:
        settings = [s for s in settings if s[1] == args.part]
        if not settings:
            parser.error(f"--part {args.part}: no setting of the grid has {args.part} joints")
    units = [Unit(r, j, tuple(range(args.seeds)), args.out, args.episodes) for r, j in settings]
    if args.dry_run:
        dry_run(units, args, threads, extra)
        return 0
    status = execute(units, args, threads, extra)
    runs = [unit.run_dir(seed) for unit in units for seed in unit.seeds]
    done = sum(unit.status(seed) == "done" for unit in units for seed in unit.seeds)
    print(f"sweep: {done} of {len(runs)} runs finished in {args.out}"
          + (f", {len(runs) - done} not (their logs: {args.out / 'logs'}; the same command "
             "resumes)" if done < len(runs) else "")
          + f"; look at them: python -m analysis.curves {args.out} --out "
          f"{args.out / 'curves.png'} && python -m analysis.report {args.out}", file=sys.stderr)
    return status


if __name__ == "__main__":
    sys.exit(main())
