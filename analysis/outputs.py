"""Output files of the analysis commands: checked before any computing, written whole or not at
all, and reported by the names they really have.

A figure path must end in a suffix matplotlib can write (``.png``, ``.pdf``, ``.svg``, ...); one
without a suffix gets ``.png`` (and the command reports that name); an existing folder is an
error, not ``FOLDER.png`` beside it. Every output's folder must be creatable and writable before
the work starts, and each file is written to a temporary name and moved into place.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import os
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from ddpg_her import config

DEFAULT_FIGURE_SUFFIX = ".png"
"""The suffix a figure path without one gets (matplotlib's own default format)."""


class OutputError(ValueError):
    """An output path that cannot be written; the message names it and says why."""


def figure_suffixes() -> list[str]:
    """The suffixes matplotlib can write, e.g. ``['.eps', '.jpg', ..., '.svg']``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    return sorted("." + s for s in FigureCanvasAgg(Figure()).get_supported_filetypes())


def figure_path(path: str | os.PathLike, flag: str) -> Path:
    """The figure file that ``path`` (given as ``flag``) names, checked for writing.

    Raises
    ------
    OutputError
        When ``path`` is an existing folder, has a suffix matplotlib cannot write, or cannot
        be written (see `check_writable`).
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{flag} {path} is a folder; give a figure file, e.g. "
                          f"{path / ('figure' + DEFAULT_FIGURE_SUFFIX)}")
    if not path.suffix:
        path = path.with_name(path.name + DEFAULT_FIGURE_SUFFIX)
    elif path.suffix.lower() not in figure_suffixes():
        raise OutputError(f"{flag} {path}: matplotlib cannot write {path.suffix!r} files; use "
                          f"one of {', '.join(figure_suffixes())}")
    check_writable(path, flag)
    return path


def figure_outputs(parser: argparse.ArgumentParser, path: str | os.PathLike, flag: str,
                   *beside: str) -> list[Path]:
    """The figure file ``path`` names (`figure_path`), then the file beside it of each suffix
    ``beside`` (e.g. ``.csv``), each checked for writing; a bad one is ``parser.error``."""
    with usage_errors(parser):
        figure = figure_path(path, flag)
        return [figure, *(check_writable(figure.with_suffix(s), flag) for s in beside)]


def check_writable(path: str | os.PathLike, flag: str) -> Path:
    """Check that the file ``path`` (named by ``flag``) can be created or replaced: its
    nearest existing ancestor is a writable folder, and it is not itself a folder.

    Raises
    ------
    OutputError
        Naming the path and the reason (a file where a folder should be, read-only, no
        permission).
    """
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{flag} {path} is a folder, expected a file")
    check_folder(path.parent, flag, of=path)
    return path


def check_folder(folder: str | os.PathLike, flag: str, of: Path | None = None) -> Path:
    """Check that ``folder`` exists as a writable folder or can be created.

    Raises
    ------
    OutputError
        When an ancestor is a file, or the nearest existing one is not writable.
    """
    folder = Path(folder)
    what = f"{flag} {of if of is not None else folder}"
    probe = folder.absolute()
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{what}: {probe} is a file, not a folder")
    if not os.access(probe, os.W_OK | os.X_OK):
        reason = "a read-only file system" if _read_only(probe) else "no write permission"
        raise OutputError(f"{what}: cannot write in {probe} ({reason})")
    return folder


def check_files(folder: str | os.PathLike, names: Iterable[str], flag: str) -> None:
    """`check_folder` of ``folder``, then `check_writable` of each file ``names`` in it."""
    check_folder(folder, flag)
    for name in names:
        check_writable(Path(folder) / name, flag)


def usage_errors(parser: argparse.ArgumentParser, *kinds: type[Exception]
                 ) -> contextlib.AbstractContextManager[None]:
    """An exception of ``kinds`` (default: an OutputError, an output checked before any work)
    raised in the block is a usage error: ``parser.error`` (status 2)."""
    return config.usage_errors(parser, *(kinds or (OutputError,)))


def add_force(parser: argparse.ArgumentParser, help: str = "replace output files that hold "
              "something else (refused by default: nothing is written, the files are named)"
              ) -> None:
    """The ``--force`` flag of a command whose writes go through `write_errors`."""
    parser.add_argument("--force", action="store_true", help=help)


@contextlib.contextmanager
def write_errors(parser: argparse.ArgumentParser, force: bool, what: str = "--out"
                 ) -> Iterator[None]:
    """The block's writes, held back by `unless_replacing` (none replaces a file that holds
    other bytes unless ``force``, the command's ``--force``; ``what`` names the outputs). An
    OutputError ends the command with ``error: ...``: status 1 (a failed write), or 2 where
    `unless_replacing` refused (`WouldReplace`, a usage error)."""
    try:
        with unless_replacing(force, what):
            yield
    except (OutputError, OSError) as err:  # OSError: e.g. an output there that cannot be read
        parser.exit(2 if isinstance(err, WouldReplace) else 1, f"error: {err}\n")


def _read_only(path: Path) -> bool:
    with contextlib.suppress(OSError):
        return bool(os.statvfs(path).f_flag & os.ST_RDONLY)
    return False


class WouldReplace(OutputError):
    """`unless_replacing` refused: a usage error (exit 2), not a failed write."""


_STAGED: list[dict[Path, bytes]] = []
"""The writes held back by `unless_replacing` (innermost last)."""


@contextlib.contextmanager
def unless_replacing(force: bool, what: str) -> Iterator[None]:
    """Hold back every `write_bytes` of the block, then write them all, unless one would
    replace a file that holds other bytes and ``force`` is false: then write nothing and raise
    `WouldReplace` naming the files (a viewer page over a viewer page is not refused: its ids
    are random). ``what`` names the command's outputs and its override flag for the message."""
    _STAGED.append({})
    try:
        yield
        staged = _STAGED[-1]
    finally:
        _STAGED.pop()
    page = b"new MeshCat.Viewer("  # a viewer page (random ids each time) may replace another
    old = {p: p.read_bytes() for p in staged if p.is_file()}  # compared; put back on a failure
    changed = [p for p, data in staged.items() if p in old and old[p] != data
               and not (page in old[p] and page in data)]
    if changed and not force:
        raise WouldReplace(
            f"{what} would replace {len(changed)} file(s) that hold something else, e.g. "
            + ", ".join(map(str, changed[:3])) + ("" if len(changed) <= 3 else ", ...")
            + "; nothing was written: give --force to replace them, or another destination")
    for i, (p, data) in enumerate(staged.items()):
        try:
            write_bytes(p, data)
        except BaseException:  # a failed write or Ctrl-C: the files written before it as they were
            for q in list(staged)[:i]:
                if q in old:
                    write_bytes(q, old[q])
                else:
                    q.unlink()
            raise


def write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all, by the one atomic writer
    (`ddpg_her.runfolder.atomic_write`: a temporary name, then a move); a file there before
    stays as it was when the write fails. Inside `unless_replacing`, held back until its end.

    Raises
    ------
    OutputError
        When the write fails (full disk, ...); nothing is left of it.
    """
    from ddpg_her.runfolder import RunFolderWriteError, atomic_write

    path = Path(path)
    if _STAGED:
        _STAGED[-1][path] = bytes(data)
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f"cannot create the folder of {path}: {err.strerror or err}") from err
    try:
        atomic_write(path, data)
    except RunFolderWriteError as err:
        raise OutputError(str(err)) from err


def write_text(path: Path, text: str) -> None:
    """`write_bytes` of text (UTF-8)."""
    write_bytes(path, text.encode())


def write_csv(path: Path, columns: Sequence[str],
              rows: Iterable[Sequence[Any] | Mapping[str, Any]]) -> None:
    """A CSV file (``\\n`` line ends) of the header ``columns`` and ``rows``, each a list in
    column order or a dict by column (``csv.DictWriter``'s rules), written whole by
    `write_text`."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(columns)
    by_name = csv.DictWriter(buf, columns, lineterminator="\n")
    for row in rows:
        (by_name if isinstance(row, Mapping) else writer).writerow(row)
    write_text(path, buf.getvalue())


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend: the commands write files, never a window."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, path: Path, **kwargs: Any) -> None:
    """``fig.savefig(path, **kwargs)``, rendered in memory and written by `write_bytes`; the
    format is ``path``'s suffix. The figure is closed afterwards."""
    buf = io.BytesIO()
    try:
        fig.savefig(buf, format=path.suffix.lstrip(".").lower() or "png", **kwargs)
    finally:
        pyplot().close(fig)
    write_bytes(path, buf.getvalue())


def available_bytes() -> int | None:
    """The host's available memory (``MemAvailable``), or None where it cannot be read."""
    with contextlib.suppress(OSError, ValueError, IndexError), open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    return None
