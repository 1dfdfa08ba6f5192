"""``python -m benchmarks.save_prune``: what pruning a run folder's buffer chunks costs at a save,
with the chunks' spans in their names (``episode-NNNNNN.FIRST-END.npz``, read from the listing)
against chunks named as before (``episode-NNNNNN.npz``: each opened to learn its span, as
every save did until issue 42), in the same run.

One agent's folder holds the chunks of a full replay buffer: ``--buffer-size`` transitions
(Table I: 10^6) in chunks of one test interval each (``--chunk-rows``: 100 episodes of 100
steps and their HER copies, 20,000 rows), each row of ``--width`` float32 values (35: a
3-joint agent's x, u, r, x', terminated). A save's prune lists them and keeps them all (each
still holds live transitions), so its cost is the listing's, or the listing's and every
chunk's read. Timed: the median of ``--rounds`` prunes of each naming, interleaved; printed as
JSON with ms per agent, the ratio, and the grid's 55 agents per save.

    python -m benchmarks.save_prune
    python -m benchmarks.save_prune --buffer-size 100000 --rounds 3
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ddpg_her.config import Parser

GRID_AGENTS = 55
"""Agents of the paper's grid: one folder each, pruned at every save."""


def fill(folder: Path, buffer_size: int, chunk_rows: int, width: int, old_names: bool) -> int:
    """Write the chunks of a full buffer into ``folder`` (a run folder); their count."""
    from ddpg_her.runfolder import RunFolder

    run = RunFolder(folder)
    rows = np.random.default_rng(0).standard_normal((chunk_rows, width), dtype=np.float32)
    chunks = buffer_size // chunk_rows
    for i in range(chunks):
        run.save_chunk(i + 1, i * chunk_rows, rows)
    if old_names:  # the names every save wrote before issue 42
        for p in (folder / "buffer").glob("episode-*.npz"):
            p.rename(p.with_name(p.name.split(".")[0] + ".npz"))
    return chunks


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m benchmarks.save_prune",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--buffer-size", type=int, default=1_000_000,
                        help="transitions of the full buffer (>= --chunk-rows)")
    parser.add_argument("--chunk-rows", type=int, default=20_000,
                        help="transitions per chunk: one test interval's (>= 1)")
    parser.add_argument("--width", type=int, default=35, help="float32 values per row (>= 1)")
    parser.add_argument("--rounds", type=int, default=5, help="prunes timed per naming (>= 1)")
    args = parser.parse_args(argv)
    if min(args.chunk_rows, args.width, args.rounds) < 1 or args.buffer_size < args.chunk_rows:
        parser.error("--chunk-rows, --width and --rounds must be >= 1 and --buffer-size >= "
                     f"--chunk-rows; got {args.chunk_rows}, {args.width}, {args.rounds}, "
                     f"{args.buffer_size}")
    from ddpg_her.runfolder import RunFolder

    with tempfile.TemporaryDirectory(prefix="save_prune-") as tmp:
        folders = {name: Path(tmp) / name for name in ("spans_named", "opened")}
        chunks = {name: fill(f, args.buffer_size, args.chunk_rows, args.width,
                             name == "opened") for name, f in folders.items()}
        seconds: dict[str, list[float]] = {name: [] for name in folders}
        for _ in range(args.rounds):
            for name, folder in folders.items():
                tic = time.perf_counter()
                RunFolder(folder).prune(upto=chunks[name], keep_from=0)
                seconds[name].append(time.perf_counter() - tic)
        left = {name: len(list((f / "buffer").iterdir())) for name, f in folders.items()}
    ms = {name: 1e3 * statistics.median(s) for name, s in seconds.items()}
    print(json.dumps({
        "chunks_per_agent": chunks["opened"], "chunks_kept": left,
        "mib_per_agent": args.buffer_size * args.width * 4 / 2**20,
        "ms_per_agent": ms, "opened_over_spans_named": ms["opened"] / ms["spans_named"],
        "grid_s_per_save": {name: GRID_AGENTS * v / 1e3 for name, v in ms.items()},
        "rounds": args.rounds, "command": " ".join(["python -m benchmarks.save_prune",
                                                    *(argv or sys.argv[1:])])}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
