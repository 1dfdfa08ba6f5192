"""The paper's sweep: every (region, joints) setting x seeds, on local processes or a Ray cluster.

    python -m analysis.sweep --grid paper [--episodes N] [--seeds K] [--out ROOT]
                             [--workers W | --ray-address ADDR] [--dry-run]

One training process per setting trains all its seeds at once (``ddpg_her.train --seeds``), into
``ROOT/<region>-j<joints>/s<seed>``. Finished runs are skipped and unfinished ones resumed from
their last checkpoint, so an interrupted sweep continues where it stopped when run again. Each
process's output goes to ``ROOT/logs/<region>-j<joints>.log``. Arguments after ``--`` pass to
``ddpg_her.train`` unchanged (e.g. ``-- --her-strategy future``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from analysis.paper import PAPER_EPISODES, PAPER_GRID, PAPER_SEEDS
from analysis.runs import read_run

GRIDS: dict[str, tuple[tuple[str, int], ...]] = {
    "paper": PAPER_GRID,
    "paper+tall": (*PAPER_GRID, ("farbox_tall", 3), ("farbox_tall", 6)),
}
"""Named grids of (region, joints) settings."""

RUN_DIR = "{region}-j{joints}/s{seed}"
"""Run folder of one seed below the sweep root."""


@dataclass(frozen=True)
class Unit:
    """One training process: a setting and the seeds it trains together."""

    region: str
    joints: int
    seeds: tuple[int, ...]
    root: Path
    episodes: int

    @property
    def name(self) -> str:
        return f"{self.region}-j{self.joints}"

    def run_dir(self, seed: int) -> Path:
        return self.root / RUN_DIR.format(region=self.region, joints=self.joints, seed=seed)

    def status(self, seed: int) -> str:
        """'done', 'resume' (a run folder exists, unfinished) or 'new'."""
        folder = self.run_dir(seed)
        if not (folder / "spec.json").exists():
            return "new"
        try:
            run = read_run(folder)
        except (ValueError, KeyError, OSError):
            return "resume"
        done = len(run.episode) and int(run.episode[-1]) >= self.episodes
        return "done" if done else "resume"

    def pending(self) -> bool:
        return any(self.status(s) != "done" for s in self.seeds)

    def command(self, threads: int, extra: Sequence[str]) -> list[str]:
        out = str(self.root / RUN_DIR).replace("{region}", self.region).replace(
            "{joints}", str(self.joints))
        return [sys.executable, "-m", "ddpg_her.train", "--region", self.region,
                "--joints", str(self.joints), "--seeds", *map(str, self.seeds),
                "--episodes", str(self.episodes), "--out", out, "--resume", "--no-progress",
                "--threads", str(threads), *extra]

    @property
    def log_path(self) -> Path:
        return self.root / "logs" / f"{self.name}.log"


def parse_setting(text: str) -> tuple[str, int]:
    """``REGION:JOINTS`` -> (region, joints)."""
    region, sep, joints = text.rpartition(":")
    if not sep or not region or not joints.isdigit() or not 2 <= int(joints) <= 6:
        raise argparse.ArgumentTypeError(
            f"expected REGION:JOINTS with joints in 2..6; got {text!r}")
    return region, int(joints)


def units_for(settings: Sequence[tuple[str, int]], seeds: int, root: Path,
              episodes: int) -> list[Unit]:
    return [Unit(region, joints, tuple(range(seeds)), root, episodes)
            for region, joints in settings]


def child_env(threads: int) -> dict[str, str]:
    """This process's environment with every BLAS and OpenMP pool of a child capped at
    ``threads``: concurrent trainers that each start one pool per core oversubscribe the
    machine (numpy's OpenBLAS in the env's clearance check ran 20x slower so on 2 cores)."""
    env = dict(os.environ)
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = str(threads)
    return env


def start_unit(command: Sequence[str], log_path: str | Path, threads: int,
               cwd: str | None = None) -> tuple[subprocess.Popen, IO[str]]:
    """Start one training process, its output appended to ``log_path`` after a line with the
    command; returns the process and the open log (the caller closes it when the process ends).
    """
    Path(log_path).parent.mkdir(parents=True, exist_ok=True)
    log = open(log_path, "a")  # noqa: SIM115 (outlives this function, with the process)
    log.write(f"\n$ {' '.join(command)}\n")
    log.flush()
    proc = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT, cwd=cwd,
                            env=child_env(threads))
    return proc, log


def run_unit(command: Sequence[str], log_path: str, cwd: str, threads: int = 1) -> int:
    """Run one training process with its output appended to ``log_path``; its exit code."""
    proc, log = start_unit(command, log_path, threads, cwd)
    with log:
        return proc.wait()


def run_local(units: Sequence[Unit], workers: int, threads: int, extra: Sequence[str]) -> int:
    """Run the units in at most ``workers`` concurrent processes; the number that failed."""
    from tqdm import tqdm

    queue = list(units)
    running: dict[subprocess.Popen, tuple[Unit, IO[str]]] = {}
    failed = 0
    bar = tqdm(total=len(units), desc="sweep", unit="setting", file=sys.stderr)
    try:
        while queue or running:
            while queue and len(running) < workers:
                unit = queue.pop(0)
                proc, log = start_unit(unit.command(threads, extra), unit.log_path, threads)
                running[proc] = (unit, log)
            for proc in [p for p in running if p.poll() is not None]:
                unit, log = running.pop(proc)
                log.close()
                if proc.returncode != 0:
                    failed += 1
                    tqdm.write(f"{unit.name} failed (exit {proc.returncode}); see "
                               f"{unit.log_path}", file=sys.stderr)
                bar.update(1)
            time.sleep(0.2)
    except KeyboardInterrupt:
        for proc in running:
            proc.terminate()
        for proc in running:
            proc.wait()
        tqdm.write("interrupted; run the same command again to resume", file=sys.stderr)
        raise
    finally:
        bar.close()
    return failed


def run_ray(units: Sequence[Unit], address: str, threads: int, extra: Sequence[str]) -> int:
    """Run the units as Ray tasks (``address``: a cluster, or 'local' to start one here)."""
    import ray
    from tqdm import tqdm

    ray.init(address=None if address == "local" else address, include_dashboard=False,
             log_to_driver=False, ignore_reinit_error=True)
    try:
        task = ray.remote(num_cpus=threads)(run_unit)
        cwd = os.getcwd()
        pending = {task.remote(u.command(threads, extra), str(u.log_path), cwd, threads): u
                   for u in units}
        failed = 0
        with tqdm(total=len(units), desc="sweep (ray)", unit="setting", file=sys.stderr) as bar:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                unit = pending.pop(done[0])
                code = ray.get(done[0])
                if code != 0:
                    failed += 1
                    tqdm.write(f"{unit.name} failed (exit {code}); see {unit.log_path}",
                               file=sys.stderr)
                bar.update(1)
        return failed
    finally:
        ray.shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra: list[str] = []
    if "--" in argv:
        cut = argv.index("--")
        argv, extra = argv[:cut], argv[cut + 1 :]
    parser = argparse.ArgumentParser(
        prog="python -m analysis.sweep", description=__doc__.split("\n\n")[0],
        epilog="Arguments after -- pass to python -m ddpg_her.train.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--grid", choices=sorted(GRIDS), default="paper",
                       help="named grid: 'paper' is unconstrained with 2-6 joints and zheight, "
                            "closebox, farbox with 3 and 6 joints (11 settings)")
    which.add_argument("--setting", type=parse_setting, action="append", metavar="REGION:JOINTS",
                       help="a setting instead of a named grid; repeatable")
    parser.add_argument("--episodes", type=int, default=PAPER_EPISODES,
                        help="training episodes per run (count)")
    parser.add_argument("--seeds", type=int, default=PAPER_SEEDS,
                        help="seeds per setting, 0..K-1 (count)")
    parser.add_argument("--out", type=Path, default=Path("runs/sweep"), help="sweep root folder")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=1,
                       help="concurrent local training processes (count)")
    where.add_argument("--ray-address", default=None,
                       help="run on this Ray cluster ('auto', 'ray://host:port', or 'local' "
                            "to start one on this machine)")
    parser.add_argument("--threads", type=int, default=None,
                        help="torch threads per training process (count; default: the "
                             "machine's cores divided by --workers)")
    parser.add_argument("--dry-run", action="store_true",
                        help="print one line per run (status, folder, command) and exit")
    args = parser.parse_args(argv)
    for flag in ("episodes", "seeds", "workers"):
        if getattr(args, flag) < 1:
            parser.error(f"--{flag} must be >= 1; got {getattr(args, flag)}")
    threads = args.threads or max(1, (os.cpu_count() or 1) // args.workers)
    settings = args.setting or GRIDS[args.grid]
    units = units_for(settings, args.seeds, args.out, args.episodes)

    if args.dry_run:
        for unit in units:
            cmd = " ".join(unit.command(threads, extra)[1:])
            for seed in unit.seeds:
                print(f"{unit.status(seed):<6} {unit.region:<14} joints={unit.joints} "
                      f"seed={seed} {unit.run_dir(seed)}  <- python {cmd}")
        print(f"{sum(len(u.seeds) for u in units)} runs in {len(units)} settings",
              file=sys.stderr)
        return 0

    todo = [u for u in units if u.pending()]
    print(f"{len(units) - len(todo)} of {len(units)} settings already finished; "
          f"{len(todo)} to run", file=sys.stderr)
    if args.ray_address:
        failed = run_ray(todo, args.ray_address, threads, extra)
    else:
        failed = run_local(todo, args.workers, threads, extra)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
