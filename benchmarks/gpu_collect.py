"""``python -m benchmarks.gpu_collect``: pack a grid's results small enough to bring back from a
GPU machine (at most 8 files of 16 MiB each, issue 24).

Writes into OUT:

- ``grid.tar.gz``: every run folder's ``spec.json`` and ``eval.csv`` below ROOT (paths relative
  to ROOT), and ROOT's ``logs/`` and ``grid_time*.json`` (one per part of the grid,
  ``benchmarks/gpu_grid.sh`` writes them) where present;
- ``policies.tar.gz``: for the runs of the settings given by ``--policies`` (default the
  unconstrained 3-joint runs, whose success maps are the paper's Fig. 4), a slim copy of the
  latest checkpoint holding only what `ddpg_her.load` reads (the actor and the normaliser),
  beside the run's ``spec.json`` and ``eval.csv``: ``ddpg_her.load(folder)`` loads it as the
  full folder;
- a file larger than ``--max-mib`` is split into ``NAME.partNN`` pieces (``cat NAME.part* >
  NAME`` joins them).

Prints one line per file written, with its size.
"""

from __future__ import annotations

import argparse
import io
import sys
import tarfile
from collections.abc import Sequence
from pathlib import Path

from ddpg_her.config import Parser

MAX_FILES = 8
"""Files a device run may bring back (the device tool's limit); ``--max-files`` leaves room
for the other files of a GPU window (its smoke log and figures)."""


def run_folders(root: Path) -> list[Path]:
    """Folders below ``root`` that hold a run (a ``spec.json`` beside an ``eval.csv``)."""
    return sorted(p.parent for p in root.rglob("spec.json") if (p.parent / "eval.csv").exists())


def setting_of(folder: Path) -> tuple[str, int]:
    """(region, joints) of a run folder, read from its spec.json."""
    from ddpg_her.runfolder import read_run

    return read_run(folder).setting


def slim_checkpoint(folder: Path) -> tuple[str, bytes] | None:
    """The latest checkpoint of ``folder`` as (file name, bytes) with only the actor and the
    normaliser (what `ddpg_her.load` reads), or None without a checkpoint."""
    import torch

    from ddpg_her.runfolder import RunFolder

    f = RunFolder(folder)
    ckpts = f.checkpoints()
    if not ckpts:
        return None
    episode = max(ckpts)
    state = f.load_checkpoint(episode)
    slim = {"episode": state.get("episode", episode),
            "agent": {"actor": state["agent"]["actor"],
                      "normalizer": state["agent"]["normalizer"]}}
    buf = io.BytesIO()
    torch.save(slim, buf)
    return ckpts[episode].name, buf.getvalue()


def _add_bytes(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    tar.addfile(info, io.BytesIO(data))


def pack(root: Path, out: Path, policies: Sequence[tuple[str, int]],
         max_bytes: int, max_files: int = MAX_FILES) -> list[Path]:
    """Write grid.tar.gz and policies.tar.gz (split where larger than ``max_bytes``) into
    ``out``; returns the files written. Raises ValueError when ROOT holds no run, or when the
    pieces would be more than ``max_files``."""
    folders = run_folders(root)
    if not folders:
        raise ValueError(f"no run folder (spec.json beside eval.csv) below {root}")
    out.mkdir(parents=True, exist_ok=True)
    grid = out / "grid.tar.gz"
    with tarfile.open(grid, "w:gz") as tar:
        for folder in folders:
            for name in ("spec.json", "eval.csv"):
                tar.add(folder / name, arcname=str((folder / name).relative_to(root)))
        for extra in [root / "logs", *sorted(root.glob("grid_time*.json"))]:
            if extra.exists():
                tar.add(extra, arcname=extra.name)
    written = [grid]
    chosen = [f for f in folders if setting_of(f) in set(policies)]
    if chosen:
        pol = out / "policies.tar.gz"
        with tarfile.open(pol, "w:gz") as tar:
            for folder in chosen:
                rel = folder.relative_to(root)
                for name in ("spec.json", "eval.csv"):
                    tar.add(folder / name, arcname=str(rel / name))
                slim = slim_checkpoint(folder)
                if slim is not None:
                    _add_bytes(tar, str(rel / "checkpoints" / slim[0]), slim[1])
        written.append(pol)
    pieces: list[Path] = []
    for path in written:
        pieces += split(path, max_bytes)
    if len(pieces) > max_files:
        raise ValueError(f"{len(pieces)} files to bring back, more than {max_files}: "
                         f"{[p.name for p in pieces]}")
    return pieces


def split(path: Path, max_bytes: int) -> list[Path]:
    """``path`` itself when it is at most ``max_bytes``, else ``path.part00``, ``.part01`` ...
    of at most ``max_bytes`` each (the original removed)."""
    size = path.stat().st_size
    if size <= max_bytes:
        return [path]
    parts = []
    with open(path, "rb") as f:
        for i in range(-(-size // max_bytes)):
            part = path.with_name(f"{path.name}.part{i:02d}")
            part.write_bytes(f.read(max_bytes))
            parts.append(part)
    path.unlink()
    return parts


def setting_arg(text: str) -> tuple[str, int]:
    region, _, joints = text.partition(":")
    if not region or not joints.isdigit():
        raise argparse.ArgumentTypeError(f"expected REGION:JOINTS such as unconstrained:3, "
                                         f"got {text!r}")
    return region, int(joints)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(
        prog="python -m benchmarks.gpu_collect",
        description="Pack a grid's run folders (spec.json, eval.csv, slim policy checkpoints) "
                    "into at most 8 files of at most --max-mib each, to bring back from a GPU "
                    "machine.")
    parser.add_argument("root", type=Path, help="root folder of the grid's runs")
    parser.add_argument("out", type=Path, help="folder to write the files into (e.g. $OUT)")
    parser.add_argument("--policies", type=setting_arg, action="append", default=None,
                        metavar="REGION:JOINTS",
                        help="settings whose latest policies to pack (repeatable; default: "
                             "unconstrained:3, the runs of the paper's Fig. 4)")
    parser.add_argument("--max-mib", type=float, default=15.0,
                        help="largest file written, MiB (> 0; default: %(default)s, under the "
                             "16 MiB a device run brings back)")
    parser.add_argument("--max-files", type=int, default=MAX_FILES,
                        help="most files written, 1..%(default)s (default: %(default)s, the "
                             "device tool's limit; less leaves room for a window's other files)")
    args = parser.parse_args(argv)
    if args.max_mib <= 0:
        parser.error(f"--max-mib must be > 0, got {args.max_mib}")
    if not 1 <= args.max_files <= MAX_FILES:
        parser.error(f"--max-files must be in 1..{MAX_FILES}, got {args.max_files}")
    try:
        files = pack(args.root, args.out, args.policies or [("unconstrained", 3)],
                     int(args.max_mib * 2**20), args.max_files)
    except ValueError as e:
        parser.error(str(e))
    for f in files:
        print(f"{f}  {f.stat().st_size / 2**20:.2f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
