"""Wall time of a short far-box training run alone and with a twin beside it, per torch thread
setting: ``python -m benchmarks.thread_share``.

Two trainers whose torch (OpenMP) pools each take every core fight over them: on a 2-core
machine two 200-episode far-box runs took 303 s each together against 41 s alone (issue 37,
kind 9). This script times, for each ``--threads`` setting (``default``: the flag left out, so
the training program's own default), ``--repeats`` rounds of one run alone and of two identical
runs started together, and prints one JSON line per run and a summary (median wall seconds per
setting and case). It also says whether the runs' ``eval.csv`` agree with the first setting's
(all columns but ``wall_s``): the thread count must not change what is computed. Each line
records the machine's 1-minute load average before the case: other work shares the cores.

Examples::

    python -m benchmarks.thread_share --episodes 50 --repeats 2 --settings default 1
"""

from __future__ import annotations

import csv
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

from ddpg_her.config import Parser

RUN = ["--region", "farbox", "--joints", "3", "--seed", "0", "--no-progress",
       "--no-tensorboard", "--device", "cpu", "--warmup-episodes", "10"]
"""Flags of every timed run: far box, 3 joints, seed 0, the default agent but for 10 warm-up
episodes instead of 100, so that a short run spends most of its time in the network updates,
where the torch threads work."""


def command(out: Path, episodes: int, threads: str) -> list[str]:
    """The ``ddpg_her.train`` command of one timed run in ``out``."""
    extra = [] if threads == "default" else ["--threads", threads]
    return [sys.executable, "-m", "ddpg_her.train", *RUN, "--episodes", str(episodes),
            "--eval-every", str(episodes), "--out", str(out), *extra]


def timed(commands: Sequence[Sequence[str]], limit_s: float) -> list[float | None]:
    """Start ``commands`` together; each one's wall seconds, None for one still running after
    ``limit_s`` (then ended); a failed one stops the script."""
    start = time.perf_counter()
    procs = [subprocess.Popen(c, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for c in commands]
    walls: list[float | None] = []
    for c, p in zip(commands, procs, strict=True):
        try:
            _, err = p.communicate(timeout=max(1.0, limit_s - (time.perf_counter() - start)))
        except subprocess.TimeoutExpired:
            p.kill()
            p.communicate()
            walls.append(None)
            continue
        walls.append(time.perf_counter() - start)
        if p.returncode:
            sys.exit(f"thread_share: {' '.join(c)} failed ({p.returncode}): {err[-2000:]}")
    return walls


def eval_rows(run: Path) -> list[dict[str, str]]:
    """A run's eval.csv rows without the clock column."""
    with open(run / "eval.csv", newline="") as f:
        return [{k: v for k, v in row.items() if k != "wall_s"} for row in csv.DictReader(f)]


def _round(seconds: float) -> float | None:
    """Seconds to 0.1 s for JSON; None for a run ended at the limit (inf)."""
    return None if math.isinf(seconds) else round(seconds, 1)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m benchmarks.thread_share",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=50, help="episodes per run (count)")
    parser.add_argument("--repeats", type=int, default=2, help="rounds per setting (count)")
    parser.add_argument("--limit-s", type=float, default=900.0,
                        help="a run still going after this many seconds is ended and recorded "
                             "as null (s)")
    parser.add_argument("--settings", nargs="+", default=["default", "1"],
                        help="--threads values to time; 'default' leaves the flag out")
    args = parser.parse_args(argv)
    summary: dict[str, dict[str, list[float]]] = {}
    reference = None
    with tempfile.TemporaryDirectory(prefix="thread_share-") as tmp:
        for r in range(args.repeats):
            for threads in args.settings:
                for case, n in (("alone", 1), ("two_together", 2)):
                    outs = [Path(tmp, f"{threads}-{case}-{r}-{i}") for i in range(n)]
                    load = os.getloadavg()[0]
                    walls = timed([command(o, args.episodes, threads) for o in outs],
                                  args.limit_s)
                    rows = [eval_rows(o) for o, w in zip(outs, walls, strict=True)
                            if w is not None]
                    reference = reference if reference is not None or not rows else rows[0]
                    same = all(x == reference for x in rows)
                    summary.setdefault(threads, {}).setdefault(case, []).extend(
                        w if w is not None else math.inf for w in walls)
                    print(json.dumps({"threads": threads, "case": case, "round": r,
                                      "wall_s": [None if w is None else round(w, 1)
                                                 for w in walls],
                                      "eval_same_as_first": same,
                                      "load_1min_before": round(load, 2)}), flush=True)
    print(json.dumps({"episodes": args.episodes, "repeats": args.repeats,
                      "median_wall_s": {t: {c: _round(statistics.median(w))
                                            for c, w in cases.items()}
                                        for t, cases in summary.items()},
                      "all_wall_s": {t: {c: [_round(x) for x in w] for c, w in cases.items()}
                                     for t, cases in summary.items()}}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
