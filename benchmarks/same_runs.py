"""Short training runs of every env backend and algorithm, recorded and compared bit for bit:
``python -m benchmarks.same_runs``.

A refactoring of the trainer must not change what it computes. ``record OUT`` trains a fixed
matrix of short runs (each ``--env-backend`` x ``--algo``, the exploration kinds, HER
strategies, a resumed run and a ``ddpg_her.train_many`` stack) with the code of ``--tree`` (a
checkout: the one to compare against, e.g. ``git worktree add /tmp/old REV``), one run folder
each under OUT. ``compare A B`` then says, for every run folder, whether its ``eval.csv`` is
the same in every column but ``wall_s`` (as text, so to the last printed digit) and whether
its last checkpoint holds the same values: every tensor ``torch.equal``, every array
``numpy.array_equal``, everything else ``==`` (but the clock, ``wall_s``, and the ``config``
and ``rows`` that record it), and whether its replay-buffer chunks are equal arrays.

Examples::

    python -m benchmarks.same_runs record /tmp/before --tree /tmp/old
    python -m benchmarks.same_runs record /tmp/after
    python -m benchmarks.same_runs compare /tmp/before /tmp/after
"""

from __future__ import annotations

import csv
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ddpg_her.config import Parser

BASE = ["--region", "zheight", "--joints", "3", "--seeds", "0", "1", "--eval-every", "3",
        "--no-progress", "--threads", "1", "--device", "cpu", "--no-tensorboard"]
"""Flags of every run: two seeds stacked, a test session every 3 episodes, on one CPU thread."""

LEARN = ["--warmup-episodes", "2", "--updates-per-episode", "8", "--hidden-sizes", "16", "16",
         "--batch-size", "16", "--eval-episodes", "10", "--exploration-rate", "0.3"]
"""Small networks that learn from episode 3 on, so that updates and exploration noise count
(the defaults' 100 warm-up episodes would leave both out of 6 episodes)."""

BACKENDS = ("numpy", "batched")
ALGOS = ("ddpg", "td3", "sac")


def runs() -> dict[str, list[list[str]]]:
    """{name: the ``ddpg_her.train`` command lines that make run folder ``name``, in order}."""
    out: dict[str, list[list[str]]] = {}
    for b in BACKENDS:
        for a in ALGOS:
            flags = ["--env-backend", b, "--algo", a]
            out[f"{b}-{a}"] = [["--episodes", "6", *flags]]
            out[f"{b}-{a}-learn"] = [["--episodes", "6", *flags, *LEARN]]
        flags = ["--env-backend", b, *LEARN]
        out[f"{b}-ou-future"] = [["--episodes", "6", *flags, "--exploration", "ou",
                                  "--her-strategy", "future"]]
        out[f"{b}-epsilon-none"] = [["--episodes", "6", *flags, "--exploration", "epsilon",
                                     "--her-strategy", "none"]]
        out[f"{b}-resume"] = [["--episodes", "3", *flags],
                              ["--episodes", "6", *flags, "--resume"]]
    return out


def record(out: Path, tree: Path, python: str, only: Sequence[str] = ()) -> None:
    """Train every run of `runs` (those whose name starts with one of ``only``, if given; the
    ``train_many`` stack is named so) with the code in ``tree`` into ``out/NAME``."""
    out.mkdir(parents=True, exist_ok=False)
    for name, commands in runs().items():
        if only and not name.startswith(tuple(only)):
            continue
        start = time.perf_counter()
        for argv in commands:
            cmd = [python, "-m", "ddpg_her.train", *BASE, *argv, "--out",
                   str(out.resolve() / name / "s{seed}")]
            subprocess.run(cmd, cwd=tree, check=True, stdout=subprocess.DEVNULL)
        print(f"{name}: {time.perf_counter() - start:.1f} s", flush=True)
    if only and not "train_many".startswith(tuple(only)):
        return
    many = out.resolve() / "train_many"
    units = [f"--region {r} --joints 3 --seeds 0 1 --out {many}/{r}/s{{seed}}"
             for r in ("zheight", "farbox")]
    subprocess.run([python, "-m", "ddpg_her.train_many", *(f"--unit={u}" for u in units),
                    "--threads", "1", "--no-progress", "--no-tensorboard", "--",
                    "--episodes", "6", "--eval-every", "3", *LEARN],
                   cwd=tree, check=True, stdout=subprocess.DEVNULL)
    print("train_many: done", flush=True)


def _eval_rows(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k != "wall_s"} for row in csv.DictReader(f)]


CLOCK = ("wall_s", "rows", "created")
"""Checkpoint keys that hold the clock (``rows`` are the eval rows, compared in eval.csv)."""


def _differences(a: Any, b: Any, where: str) -> list[str]:
    """Where two loaded checkpoint values differ (tensors bitwise, arrays exactly)."""
    import numpy as np
    import torch

    if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
        same = isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor) \
            and a.dtype == b.dtype and a.shape == b.shape and torch.equal(a, b)
        return [] if same else [where]
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return [] if np.array_equal(a, b) and np.asarray(a).dtype == np.asarray(b).dtype \
            else [where]
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{where} keys {sorted(set(a) ^ set(b))}"]
        return [d for k in a if k not in CLOCK
                for d in _differences(a[k], b[k], f"{where}.{k}")]
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return [f"{where} length {len(a)} != {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b, strict=True))
                for d in _differences(x, y, f"{where}[{i}]")]
    return [] if a == b else [where]


def compare_run(a: Path, b: Path) -> list[str]:
    """The differences between run folders ``a`` and ``b`` (empty when bitwise the same)."""
    import numpy as np
    import torch

    diffs = []
    if _eval_rows(a / "eval.csv") != _eval_rows(b / "eval.csv"):
        diffs.append("eval.csv")
    ckpts = [sorted((x / "checkpoints").glob("episode-*.pt")) for x in (a, b)]
    if [p.name for p in ckpts[0]] != [p.name for p in ckpts[1]] or not ckpts[0]:
        return [*diffs, f"checkpoints {[p.name for p in ckpts[0]]} / "
                        f"{[p.name for p in ckpts[1]]}"]
    states = [torch.load(c[-1], weights_only=False) for c in ckpts]
    diffs += [f"{ckpts[0][-1].name}: {d}" for d in _differences(*states, "checkpoint")]
    chunks = [sorted((x / "buffer").glob("episode-*.npz")) for x in (a, b)]
    # by episode: a chunk's name holds its span since issue 42 (episode-NNNNNN.FIRST-END.npz)
    if [p.name.split(".")[0] for p in chunks[0]] != [p.name.split(".")[0] for p in chunks[1]]:
        diffs.append("buffer chunk names")
    for pa, pb in zip(*chunks, strict=False):
        with np.load(pa) as za, np.load(pb) as zb:
            if set(za) != set(zb) or any(not np.array_equal(za[k], zb[k]) for k in za):
                diffs.append(f"buffer/{pa.name}")
    return diffs


def compare(a: Path, b: Path) -> int:
    """Print one line per run folder of ``b`` (all of which ``a`` must have: ``b`` may be a
    recording ``--only`` some runs); 0 when all are the same, 1 otherwise."""
    folders = sorted(p.parent.relative_to(b) for p in b.rglob("eval.csv"))
    missing = [f for f in folders if not (a / f / "eval.csv").exists()]
    if missing or not folders:
        print(f"{a} lacks the run folders {missing} of {b}" if missing else f"{b}: no runs")
        return 1
    bad = 0
    for rel in folders:
        diffs = compare_run(a / rel, b / rel)
        bad += bool(diffs)
        print(f"{rel}: {'same' if not diffs else 'DIFFERENT: ' + '; '.join(diffs[:5])}")
    print(f"{len(folders) - bad} of {len(folders)} run folders bitwise the same "
          "(eval.csv but wall_s, last checkpoint, buffer chunks)")
    return int(bad > 0)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m benchmarks.same_runs",
                                     description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True,
                                help="record: train the runs; compare: two recordings")
    rec = sub.add_parser("record", help="train the matrix of short runs into OUT")
    rec.add_argument("out", type=Path, help="a folder that does not exist yet")
    rec.add_argument("--tree", type=Path, default=Path("."),
                     help="the checkout whose code trains (default: this one)")
    rec.add_argument("--python", default=sys.executable,
                     help="the interpreter (default: this one)")
    rec.add_argument("--only", nargs="+", default=[], metavar="PREFIX",
                     help="only the runs whose name starts so (e.g. numpy- batched-ddpg)")
    cmp = sub.add_parser("compare", help="compare two recorded folders")
    cmp.add_argument("a", type=Path, help="the recording to compare against (e.g. before)")
    cmp.add_argument("b", type=Path, help="the recording compared (e.g. after; --only allowed)")
    args = parser.parse_args(argv)
    if args.command == "record":
        record(args.out, args.tree, args.python, args.only)
        return 0
    return compare(args.a, args.b)


if __name__ == "__main__":
    sys.exit(main())
