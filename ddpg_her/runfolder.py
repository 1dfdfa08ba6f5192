"""The run folder: its format, its files, and the `Run` record analysis reads. Free of torch.

A run folder holds

- ``spec.json``: env id and arguments, the task specification, the agent configuration, the seed,
  package versions, git revision and the command line (format `FORMAT`);
- ``eval.csv``: one row per test session, columns `EVAL_COLUMNS`;
- ``checkpoints/episode-NNNNNN.pt``: the last two checkpoints (networks, optimisers, normaliser,
  random generator states, eval rows so far, and the configuration they were trained with);
- ``buffer/episode-NNNNNN.FIRST-END.npz``: the transitions FIRST to END - 1 (numbers since the
  run's start) that each checkpoint interval added to the replay buffer, so a checkpoint need
  not rewrite the whole buffer; chunks that the buffer has since overwritten are deleted, told
  by their names alone (folders written before the span was named, ``episode-NNNNNN.npz``,
  still read: their chunks are opened to learn it);
- ``tb/``: TensorBoard logs, when tensorboard is installed;
- ``lock.json``: while a trainer runs, its pid and host (`RunFolder.lock`): a second trainer on
  the folder is refused, a lock of a process that has ended is taken over with a warning.

Every file is written to a temporary name (`TEMPORARY`) and moved into place with
``os.replace``, so a run killed at any moment leaves each file either complete or as it was, plus
perhaps a temporary file that the next start of the run deletes (:meth:`RunFolder.clean`). A
checkpoint is written before the ``eval.csv`` that shows its rows, and ``eval.csv`` is rewritten
from the checkpoint on resume, so no row is ever lost, repeated or skipped.

Reading a folder (:func:`read_run`, :meth:`RunFolder.read_spec`, :meth:`RunFolder.read_eval`)
imports neither torch nor Pinocchio; only checkpoints need torch, imported when one is read or
written. Every file that cannot be read raises :class:`RunFolderError` naming it.
"""

from __future__ import annotations

import contextlib
import csv
import datetime
import io
import json
import math
import os
import re
import socket
import subprocess
import sys
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

FORMAT = "ddpg_her-run-1"
"""``spec.json``'s ``format`` value written by this version."""

RUN_FORMAT_PREFIX = "ddpg_her-run"
"""``spec.json`` ``format`` values this module reads (``ddpg_her-run-*``)."""

EVAL_COLUMNS = ("episode", "successes", "tests", "mean_return", "mean_final_distance_m",
                "env_steps", "wall_s")
"""Columns of eval.csv: training episodes so far, test episodes that reached the goal, test
episodes, mean undiscounted return, mean final end-effector distance to the goal (m), training
env steps so far (test steps not counted), wall-clock seconds of training so far (the only
column that differs between two runs of one seed)."""

TEMPORARY = re.compile(r"^\..+\.tmp\d+$")
"""Names of the temporary files of :func:`atomic_write` (``.NAME.tmpPID``)."""

SUBFOLDERS = ("checkpoints", "buffer")
"""Subfolders of a run folder that hold files written by :func:`atomic_write`."""

_CKPT = re.compile(r"episode-(\d{6,})\.pt$")
_CHUNK = re.compile(r"episode-(\d{6,})(?:\.(\d+)-(\d+))?\.npz$")


class RunFolderError(ValueError):
    """A run folder, or one of its files, that cannot be read or does not fit the request."""


_EVAL_WHOLE = ("episode", "successes", "tests", "env_steps")
"""Columns of eval.csv that count something: whole numbers."""


def _check_eval_row(path: Path, line: int, row: dict[str, str], last: int | None) -> int:
    """Check one eval.csv row (see `RunFolder.read_eval`); return its episode."""
    def bad(what: str) -> RunFolderError:
        return RunFolderError(f"{path} line {line}: {what}; the run folder {path.parent} "
                              "cannot be trusted")

    values: dict[str, float] = {}
    for name, text in row.items():
        whole = name in _EVAL_WHOLE
        try:
            value = int(text) if whole else float(text)
        except ValueError:
            raise bad(f"{name} is {text!r}, expected "
                      + ("a whole number" if whole else "a number")) from None
        if not np.isfinite(value):
            raise bad(f"{name} is {text!r}, expected a finite number")
        values[name] = value
    episode, successes, tests = (int(values[k]) for k in ("episode", "successes", "tests"))
    if tests < 1:
        raise bad(f"tests is {tests}, expected at least 1 test episode")
    if not 0 <= successes <= tests:
        raise bad(f"successes is {successes}, expected 0 to tests = {tests}")
    if episode < 0 or (last is not None and episode <= last):
        raise bad(f"episode is {episode}, expected more than the row before"
                  + (f" ({last})" if last is not None else " and >= 0"))
    return episode


LOCK = "lock.json"
"""The run folder's lock file, held by the one process that trains the run: its pid, host and
start time (JSON)."""


class RunFolderBusy(RunFolderError):
    """A run folder that another live process trains (it holds the folder's `LOCK`)."""


def _alive(pid: int) -> bool:
    """Whether a Python process ``pid`` lives on this host (a pid reused by a process of
    another program, e.g. a kernel thread, does not count where /proc tells)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's process
        pass
    try:
        return b"python" in Path(f"/proc/{pid}/cmdline").read_bytes()
    except FileNotFoundError:
        return not Path("/proc/self").exists()  # gone in between, or no /proc at all
    except OSError:
        return True


class RunFolderWriteError(RunFolderError):
    """A file of a run folder that cannot be written (read-only, full disk, no permission, a
    file where a folder should be); the file as it was is left in place."""


NONFINITE = {"inf": math.inf, "-inf": -math.inf, "nan": math.nan}
"""How ``spec.json`` writes a non-finite number (strict JSON has none): as Python's ``float``
spells it, the text a flag takes (``--obs-clip inf``). Files written before read their
``Infinity`` as before."""

NONFINITE_SECTIONS = ("agent", "task", "env_kwargs")
"""The ``spec.json`` sections whose values may be non-finite numbers, written as `NONFINITE`'s
strings; none of their string fields takes one of those words."""


def _nonfinite_text(value: Any) -> Any:
    """``value``, or its `NONFINITE` string when it is a non-finite float."""
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return value


def write_failure(path: Path, err: OSError, what: str = "write") -> RunFolderWriteError:
    """The `RunFolderWriteError` of an ``OSError`` while writing ``path``: names the path and
    the system's reason."""
    reason = err.strerror or type(err).__name__
    return RunFolderWriteError(f"cannot {what} {path}: {reason} (errno {err.errno})")


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that a reader sees the old file or the new, never a part:
    the one writer of every file the commands write (run folders, and the analysis outputs
    through `analysis.outputs.write_bytes`).

    Raises
    ------
    RunFolderWriteError
        When the file cannot be written (its temporary file is removed, the old file kept; the
        temporary file is removed on any other exception too, Ctrl-C included).
    """
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if isinstance(err, OSError):
            raise write_failure(path, err) from err
        raise


def make_folder(path: Path) -> None:
    """``path.mkdir(parents=True, exist_ok=True)``, its failure a `RunFolderWriteError`."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise write_failure(path, err, "create the folder") from err


def versions() -> dict[str, str]:
    """Versions of Python and of the packages a run depends on."""
    from importlib import metadata

    out = {"python": sys.version.split()[0]}
    for name in ("torch", "numpy", "gymnasium", "pin", "ur5-reacher"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[name] = metadata.version(name)
    return out


def git_revision() -> dict[str, Any]:
    """The git revision of the source tree of this package, and whether it has edits."""
    root = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()

    try:
        return {"revision": git("rev-parse", "HEAD"),
                "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}
    except (OSError, subprocess.SubprocessError):
        return {"revision": None, "dirty": None}


class RunFolder:
    """Reads and writes one agent's run folder (see the module docstring).

    Every read raises :class:`RunFolderError` naming the file when it is missing, truncated or
    not what this module wrote.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    @property
    def spec_path(self) -> Path:
        return self.path / "spec.json"

    def exists(self) -> bool:
        """Whether the folder holds a run: a ``spec.json`` or a checkpoint."""
        return self.spec_path.exists() or bool(self.checkpoints())

    def clean(self) -> list[Path]:
        """Delete the temporary files that interrupted writes left behind; returns their paths.

        Only for the one process that writes the run (the trainer, at its start, holding the
        `lock`); a temporary file whose writer (the pid in its name) still lives on this host
        is left alone all the same.
        """
        removed = []
        for folder in (self.path, *(self.path / s for s in SUBFOLDERS)):
            if not folder.is_dir():
                continue
            for p in folder.iterdir():
                m = TEMPORARY.match(p.name)
                if m and p.is_file():
                    pid = int(p.name.rsplit(".tmp", 1)[1])
                    if pid != os.getpid() and _alive(pid):
                        continue
                    p.unlink(missing_ok=True)
                    removed.append(p)
        return removed

    # --- the lock -------------------------------------------------------------------------------
    @property
    def lock_path(self) -> Path:
        return self.path / LOCK

    def holder(self) -> dict[str, Any] | None:
        """Who holds the folder's lock (``pid``, ``host``, ``since``), or None when nobody
        does; a lock left by a dead process of this host counts as nobody's."""
        try:
            holder = json.loads(self.lock_path.read_text())
            pid, host = int(holder["pid"]), str(holder["host"])
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError):
            return {"pid": None, "host": None, "since": None, "unreadable": True}
        if host == socket.gethostname() and not _alive(pid):
            return None
        return holder

    def lock(self) -> None:
        """Take the folder's lock for this process (creating the folder).

        A lock of a dead process of this host is taken over with a warning naming it.

        Raises
        ------
        RunFolderBusy
            When a live process holds it (or one of another host, which cannot be checked);
            the message names its pid and host and how to free a stale lock.
        """
        make_folder(self.path)
        me = {"pid": os.getpid(), "host": socket.gethostname(),
              "since": datetime.datetime.now().isoformat(timespec="seconds")}
        for _ in range(3):
            try:
                fd = os.open(self.lock_path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self.holder()
                if holder is not None and holder.get("pid") == os.getpid() and \
                        holder.get("host") == me["host"]:
                    return  # this process holds it already
                if holder is not None and holder.get("unreadable"):
                    try:
                        text = repr(self.lock_path.read_text()[:80])
                    except (OSError, UnicodeDecodeError) as err:
                        text = f"unreadable: {err}"
                    raise RunFolderBusy(
                        f"{self.lock_path} is not a lock this code wrote (JSON with pid and "
                        f"host; it holds {text}): another program, or a write cut short, left "
                        f"it. If no process trains {self.path}, delete it") from None
                if holder is not None:
                    raise RunFolderBusy(
                        f"{self.path} is being trained by process {holder.get('pid')} on host "
                        f"{holder.get('host')} (since {holder.get('since')}; its lock "
                        f"{self.lock_path}); wait for it to end, or delete the lock if that "
                        "process is gone") from None
                try:
                    stale = self.lock_path.read_text()
                except FileNotFoundError:
                    continue
                warnings.warn(f"{self.lock_path}: taking over the lock of a process that has "
                              f"ended ({stale.strip()})", stacklevel=2)
                try:
                    self.lock_path.unlink(missing_ok=True)
                except OSError as err:
                    raise write_failure(self.lock_path, err, "delete the stale lock") from err
                continue
            except OSError as err:
                raise write_failure(self.lock_path, err, "create") from err
            try:
                with os.fdopen(fd, "w") as f:
                    json.dump(me, f)
            except OSError as err:
                with contextlib.suppress(OSError):
                    self.lock_path.unlink()
                raise write_failure(self.lock_path, err) from err
            return
        raise RunFolderBusy(f"{self.lock_path}: could not take the lock (another process "
                            "took it in between); try again")

    def unlock(self) -> None:
        """Release this process's lock on the folder (nothing if another holds it)."""
        try:
            holder = json.loads(self.lock_path.read_text())
        except (OSError, ValueError):
            return
        if holder.get("pid") == os.getpid() and holder.get("host") == socket.gethostname():
            with contextlib.suppress(OSError):  # a folder made read-only meanwhile
                self.lock_path.unlink(missing_ok=True)

    def read_spec(self) -> dict[str, Any]:
        """``spec.json`` as a dict.

        Raises
        ------
        RunFolderError
            When the file is missing, is not JSON (e.g. truncated), is not a JSON object, is not
            a ddpg_her run's (its ``format`` is not ``ddpg_her-run-*``), or is a run of another
            format version than `FORMAT`. Every reader goes through here (summary, load,
            replay, --resume, `read_run`), so none reads another program's spec as a run.
        """
        path = self.spec_path
        try:
            spec = json.loads(path.read_text())
        except FileNotFoundError:
            raise RunFolderError(f"{self.path} is not a run folder (no spec.json)") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
            raise RunFolderError(f"{path} cannot be read as JSON ({err}); it may be truncated "
                                 "by an interrupted copy") from err
        if not isinstance(spec, dict):
            raise RunFolderError(f"{path} holds a JSON {type(spec).__name__}, not a run "
                                 "specification (a JSON object)")
        if not is_run_spec(spec):
            raise RunFolderError(f"{path} is not a ddpg_her run (format "
                                 f"{spec.get('format')!r}, expected {RUN_FORMAT_PREFIX}-*)")
        if spec["format"] != FORMAT:  # every reader, --resume included
            raise RunFolderError(f"{path} is a run of format {spec['format']!r}, written by "
                                 f"another version of this code; this one reads {FORMAT!r} "
                                 "(read it with the version that wrote it)")
        for key in NONFINITE_SECTIONS:
            if isinstance(spec.get(key), dict):
                spec[key] = {k: NONFINITE.get(v, v) if isinstance(v, str) else v
                             for k, v in spec[key].items()}
        return spec

    def write_spec(self, spec: dict[str, Any]) -> None:
        """Write ``spec.json`` as strict JSON (RFC 8259): a non-finite number of a section of
        `NONFINITE_SECTIONS` is written as the string of `NONFINITE` (``--obs-clip inf`` as
        ``"inf"``, not ``Infinity``, which strict readers refuse); `read_spec` reads it back.

        Raises
        ------
        ValueError
            For a non-finite number elsewhere in ``spec``, which no reader could tell apart.
        """
        make_folder(self.path)
        strict = {key: {k: _nonfinite_text(v) for k, v in value.items()}
                  if key in NONFINITE_SECTIONS and isinstance(value, dict) else value
                  for key, value in spec.items()}
        try:
            text = json.dumps(strict, indent=2, allow_nan=False)
        except ValueError as err:
            raise ValueError(f"{self.spec_path}: a non-finite number outside the sections "
                             f"{', '.join(NONFINITE_SECTIONS)} cannot be written as JSON "
                             f"({err})") from None
        atomic_write(self.spec_path, (text + "\n").encode())

    def write_eval(self, rows: Sequence[dict[str, Any]]) -> None:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=EVAL_COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        atomic_write(self.path / "eval.csv", buf.getvalue().encode())

    def read_eval(self) -> list[dict[str, str]]:
        """The rows of ``eval.csv`` (strings; [] when there is no ``eval.csv`` yet), checked.

        Every tool that reads test sessions (``analysis``, ``ddpg_her.summary``) reads them
        here, so a row that cannot be is refused once for all of them.

        Raises
        ------
        RunFolderError
            When it is empty (not even a header), its header is not `EVAL_COLUMNS`, a row has
            another number of cells, or a row
            cannot be a test session: ``episode``, ``successes``, ``tests`` or ``env_steps`` not
            a whole number, another column not a finite number, ``tests`` < 1, ``successes``
            outside [0, tests], or ``episode`` not above the row before. The message names the
            file, the line and the value.
        """
        path = self.path / "eval.csv"
        if not path.exists():
            return []
        try:
            with open(path, newline="") as f:
                reader = csv.reader(f)
                header = next(reader, None)
                body = list(reader)
        except (OSError, UnicodeDecodeError, csv.Error) as err:
            raise RunFolderError(f"{path} cannot be read ({err})") from err
        if header is None:  # the trainer writes the header before any row, atomically
            raise RunFolderError(f"{path} is empty, not even its header: truncated by an "
                                 "interrupted copy? (a run writes its header at its start)")
        if tuple(header) != EVAL_COLUMNS:
            raise RunFolderError(f"{path} has columns {header}, expected {list(EVAL_COLUMNS)}")
        rows, last = [], None
        for i, cells in enumerate(body, start=2):
            if len(cells) != len(EVAL_COLUMNS):
                raise RunFolderError(f"{path} line {i} has {len(cells)} cells, expected "
                                     f"{len(EVAL_COLUMNS)}")
            row = dict(zip(EVAL_COLUMNS, cells, strict=True))
            last = _check_eval_row(path, i, row, last)
            rows.append(row)
        return rows

    # --- checkpoints and buffer chunks ---------------------------------------------------------
    def _listing(self, sub: str, pattern: re.Pattern) -> dict[int, Path]:
        folder = self.path / sub
        if not folder.is_dir():
            return {}
        found = {}
        for p in folder.iterdir():
            m = pattern.match(p.name)
            if m:
                found[int(m.group(1))] = p
        return dict(sorted(found.items()))

    def checkpoints(self) -> dict[int, Path]:
        """{episode: path} of the checkpoints present, in episode order."""
        return self._listing("checkpoints", _CKPT)

    def save_checkpoint(self, episode: int, state: dict[str, Any], keep: int = 2) -> None:
        import torch

        folder = self.path / "checkpoints"
        make_folder(folder)
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write(folder / f"episode-{episode:06d}.pt", buf.getvalue())
        for old in list(self.checkpoints().values())[:-keep]:
            old.unlink(missing_ok=True)

    def load_checkpoint(self, episode: int) -> dict[str, Any]:
        """The checkpoint of ``episode`` (tensors on the CPU).

        Raises
        ------
        RunFolderError
            When there is none at ``episode``, or its file is empty, truncated or not a
            checkpoint; the message names the file.
        """
        import torch

        ckpts = self.checkpoints()
        if episode not in ckpts:
            raise RunFolderError(f"no checkpoint at episode {episode} in {self.path}; have "
                                 f"{list(ckpts)}")
        path = ckpts[episode]
        try:
            state = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as err:  # torch raises RuntimeError, EOFError, pickle errors, ...
            raise RunFolderError(f"{path} cannot be read as a checkpoint ({type(err).__name__}: "
                                 f"{err}); it may be truncated by an interrupted write or copy"
                                 ) from err
        if not isinstance(state, dict) or "agent" not in state:
            raise RunFolderError(f"{path} is not a ddpg_her checkpoint (no 'agent' entry)")
        return state

    def save_chunk(self, episode: int, start: int, rows: np.ndarray) -> None:
        """Write the transitions ``start .. start + len(rows) - 1`` of ``episode``'s interval,
        their span in the file's name (`prune` reads nothing to learn it)."""
        folder = self.path / "buffer"
        make_folder(folder)
        buf = io.BytesIO()
        np.savez(buf, start=np.int64(start), rows=rows)
        atomic_write(folder / f"episode-{episode:06d}.{start}-{start + len(rows)}.npz",
                     buf.getvalue())

    @staticmethod
    def _read_chunk(path: Path) -> tuple[int, np.ndarray]:
        try:
            with np.load(path) as z:
                return int(z["start"]), z["rows"]
        except Exception as err:  # zipfile.BadZipFile, EOFError, KeyError, ValueError, ...
            raise RunFolderError(f"{path} cannot be read as a buffer chunk ({type(err).__name__}"
                                 f": {err}); it may be truncated by an interrupted write or "
                                 "copy") from err

    def chunks(self, upto: int) -> list[tuple[int, np.ndarray]]:
        """(first transition number, rows) of the chunks saved up to episode ``upto``.

        Raises
        ------
        RunFolderError
            When a chunk cannot be read, naming its file.
        """
        return [self._read_chunk(p) for episode, p in self._listing("buffer", _CHUNK).items()
                if episode <= upto]

    def prune(self, upto: int, keep_from: int) -> None:
        """Delete chunks saved after episode ``upto`` (an abandoned future after a resume), and
        chunks whose transitions all come before number ``keep_from`` (overwritten)."""
        for episode, p in self._listing("buffer", _CHUNK).items():
            if episode > upto:
                p.unlink(missing_ok=True)
                continue
            span = _CHUNK.match(p.name)
            if span.group(3) is not None:
                end = int(span.group(3))
            else:  # a chunk named before its span was: read it
                start, rows = self._read_chunk(p)
                end = start + len(rows)
            if end <= keep_from:
                p.unlink(missing_ok=True)


@dataclass(frozen=True)
class Run:
    """One finished or unfinished training run, as its ``spec.json`` and ``eval.csv`` say."""

    path: Path
    region: str
    """Region as given to ``--region`` (a registered name or a spec string)."""
    joints: int
    seed: int
    episodes_planned: int
    """Training episodes the run was asked for."""
    episode: np.ndarray
    """(T,) int: training episodes at each evaluation."""
    successes: np.ndarray
    """(T,) int: test episodes that reached the goal."""
    tests: np.ndarray
    """(T,) int: test episodes per evaluation."""
    final_distance_m: np.ndarray
    """(T,) float, m: mean final end-effector distance to the goal."""
    spec: dict[str, Any]

    @property
    def setting(self) -> tuple[str, int]:
        return self.region, self.joints

    @property
    def finished(self) -> bool:
        return len(self.episode) > 0 and int(self.episode[-1]) >= self.episodes_planned

    @property
    def success_rate(self) -> np.ndarray:
        """(T,) float in [0, 1]: successes / tests."""
        return self.successes / np.maximum(self.tests, 1)


def is_run_spec(spec: dict[str, Any]) -> bool:
    """Whether a ``spec.json``'s content claims to be a ddpg_her run (its ``format``)."""
    return str(spec.get("format", "")).startswith(RUN_FORMAT_PREFIX)


def read_run(path: str | os.PathLike) -> Run:
    """Read the run in folder ``path`` (its ``spec.json`` and ``eval.csv``).

    Raises
    ------
    RunFolderError
        When ``spec.json`` is missing, unreadable or not a ddpg_her run specification, or
        ``eval.csv`` is malformed; the message names the folder or file.
    """
    folder = RunFolder(path)
    spec = folder.read_spec()
    rows = folder.read_eval()
    try:
        kwargs = spec.get("env_kwargs", {})
        region = kwargs.get("region", spec.get("task", {}).get("region"))
        if isinstance(region, dict):
            region = region.get("name", json.dumps(region, sort_keys=True))
        joints = int(kwargs.get("n_joints", spec.get("task", {}).get("n_joints", 0)))
        seed, planned = int(spec["seed"]), int(spec["agent"]["episodes"])
    except (KeyError, TypeError, ValueError, AttributeError) as err:
        raise RunFolderError(f"{folder.spec_path} lacks a run's fields ({type(err).__name__}: "
                             f"{err})") from err
    if str(spec.get("env_id", "")).startswith("UR5"):  # a task of the gate's description
        from envs.spec import TaskSpec

        try:
            TaskSpec.from_record(spec.get("task", {}))
        except ValueError as err:
            raise RunFolderError(f"{folder.spec_path}: {err}") from None

    def column(name: str, kind: type) -> np.ndarray:
        try:
            return np.array([kind(r[name]) for r in rows], dtype=kind)
        except ValueError as err:
            raise RunFolderError(f"{folder.path / 'eval.csv'} column {name!r}: {err}") from err

    return Run(
        path=folder.path, region=str(region), joints=joints, seed=seed, episodes_planned=planned,
        episode=column("episode", int), successes=column("successes", int),
        tests=column("tests", int), final_distance_m=column("mean_final_distance_m", float),
        spec=spec,
    )


def run_status(folder: str | os.PathLike, episodes: int) -> str:
    """'done' (eval.csv reaches ``episodes``), 'resume' (a run folder, unfinished or not
    readable yet) or 'new': what a command that trains units does with a run folder."""
    if not RunFolder(folder).exists():
        return "new"
    try:
        run = read_run(folder)
    except (RunFolderError, KeyError, OSError):
        return "resume"
    return "done" if len(run.episode) and int(run.episode[-1]) >= episodes else "resume"
