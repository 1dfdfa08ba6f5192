"""Run ``python -m MODULE ARGS`` and SIGKILL it at one moment of its run-folder writes, for
tests/test_kills.py (not a test module): ``python tests/kill_at.py MOMENT N MODULE ARGS...``.

MOMENT is where the N-th matching write is cut: ``ckpt_tmp`` and ``chunk_tmp`` die halfway
through a checkpoint's or a buffer chunk's temporary file (half its bytes written), ``before_ckpt``
between a buffer chunk and its checkpoint, ``after_ckpt`` between a checkpoint and eval.csv,
``after_row`` just after an eval.csv with a test row, ``prune`` at a resume's start-up (the
abandoned future being pruned). The process ends by SIGKILL, as a machine's OOM killer or a
lost node would end it: no handler, no ``finally`` runs.
"""

from __future__ import annotations

import os
import runpy
import signal
import sys
from pathlib import Path

from ddpg_her import runfolder

MOMENTS = ("ckpt_tmp", "chunk_tmp", "before_ckpt", "after_ckpt", "after_row", "prune")


def main() -> None:
    moment, n, module, args = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4:]
    if moment not in MOMENTS:
        sys.exit(f"kill_at: MOMENT must be one of {MOMENTS}; got {moment!r}")
    seen = [0]

    def hit() -> bool:
        seen[0] += 1
        return seen[0] == n

    def die() -> None:
        os.kill(os.getpid(), signal.SIGKILL)

    atomic_write = runfolder.atomic_write
    cls = runfolder.RunFolder
    save_checkpoint, write_eval, prune = cls.save_checkpoint, cls.write_eval, cls.prune

    def cut_write(path: Path, data: bytes) -> None:
        suffix = {"ckpt_tmp": ".pt", "chunk_tmp": ".npz"}.get(moment)
        if path.suffix == suffix and hit():
            path.with_name(f".{path.name}.tmp{os.getpid()}").write_bytes(data[:len(data) // 2])
            die()
        atomic_write(path, data)

    def cut_checkpoint(self, episode, state, keep=2):
        if moment == "before_ckpt" and hit():
            die()
        save_checkpoint(self, episode, state, keep)
        if moment == "after_ckpt" and hit():
            die()

    def cut_eval(self, rows):
        write_eval(self, rows)
        if moment == "after_row" and rows and hit():
            die()

    def cut_prune(self, upto, keep_from):
        if moment == "prune" and hit():
            die()
        prune(self, upto, keep_from)

    runfolder.atomic_write = cut_write
    cls.save_checkpoint, cls.write_eval, cls.prune = cut_checkpoint, cut_eval, cut_prune
    sys.argv = [module, *args]
    runpy.run_module(module, run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
