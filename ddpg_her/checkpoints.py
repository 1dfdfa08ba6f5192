"""The run folders of one trainer: what ``spec.json`` records, the locks, checkpoints and resume.

A trainer's K agents write K run folders (`ddpg_her.runfolder.RunFolder`). `RunFolders` opens
them (each locked by this process; a run continues only with the task and agent it was trained
with), picks the latest checkpoint that every folder can read, restores the replay buffers from
their chunks, and at every save writes a buffer chunk, then the checkpoint, then ``eval.csv``.
What a checkpoint holds besides the bookkeeping is the trainer's (`Trainer.state`).
"""

from __future__ import annotations

import contextlib
import datetime
import json
import sys
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ddpg_her.buffer import ReplayBuffer
from ddpg_her.config import BEFORE, AgentConfig
from ddpg_her.runfolder import FORMAT, RunFolder, RunFolderError, git_revision, versions
from ddpg_her.units import json_equal

DEFAULT_BACKEND = "numpy"
"""The env backend a ``spec.json`` without ``env_backend`` was trained with."""

REMOVED_SETTINGS: dict[tuple[str, str], str] = {
    ("env_backend", "torch"): "--env-backend torch (the torch env backend)",
    ("update_graph", "on"): "--update-graph on (the captured update step)",
}
"""(spec key, value) of runs trained by a path that issue 35's training program replaced ->
that path, named for the message that refuses to resume them (their folders stay readable:
``ddpg_her.load``, ``analysis``)."""

REMOVED_AT = "a6dcb59"
"""The last revision with those paths, where such a run can still be continued."""

RESUMABLE_CHANGES = ("episodes", "flush_denormals")
"""Agent fields a resumed run may change: the budget, and how the CPU rounds subnormals
(an execution setting like the thread count; runs from before the field existed resume)."""

CONFIG_KEYS = ("format", "env_id", "env_kwargs", "task", "seed", "agent", "dims",
               "env_backend", "program")
"""Keys of the spec that each checkpoint carries as its ``config``: what it was trained
with, compared with the command's on resume (``program``: the training program's streams and
matmul precision, so a TF32 run does not resume in float32, issue 41)."""


def run_spec(*, env_backend: str, env_id: str, env_kwargs: dict[str, Any],
             task: dict[str, Any], seed: int, config: AgentConfig, dims: dict[str, Any],
             command: Sequence[str] | None) -> dict[str, Any]:
    """A run's ``spec.json``: the same whether it trains alone or beside others."""
    backend = {} if env_backend == DEFAULT_BACKEND else {"env_backend": env_backend}
    return {**backend,
            "format": FORMAT,
            "env_id": env_id,
            "env_kwargs": env_kwargs,
            "task": task,
            "seed": seed,
            "agent": config.to_dict(),
            "dims": dims,
            "versions": versions(),
            "git": git_revision(),
            "command": list(command) if command is not None else sys.argv,
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            }


def differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """Keys that make two specs different tasks or agents."""
    diffs = [key for key in CONFIG_KEYS
             if key != "agent" and not json_equal(old.get(key), new.get(key))]
    # a field added after the run was written reads as what such runs did (config.BEFORE)
    old_agent = {k: v for k, v in {**BEFORE, **old.get("agent", {})}.items()
                 if k not in RESUMABLE_CHANGES}
    new_agent = {k: v for k, v in new["agent"].items() if k not in RESUMABLE_CHANGES}
    diffs += [f"agent.{k}" for k in sorted(set(old_agent) | set(new_agent))
              if not json_equal(old_agent.get(k), new_agent.get(k))]
    return diffs


def check_continues(where: Any, old: dict[str, Any], new: dict[str, Any]) -> None:
    """Raise ValueError if ``new`` may not continue the run ``old`` (a spec or config)."""
    if lookup(old, "program.window"):
        raise ValueError(
            f"{where} holds a window run (--window: no replay buffer or checkpoint was saved "
            "before its end), which cannot be resumed; train it afresh in another --out")
    if lookup(new, "program.window"):
        raise ValueError(f"a window run starts afresh; {where} holds a run: choose another "
                         "--out, or drop --window to continue it")
    for (key, value), path in REMOVED_SETTINGS.items():
        if old.get(key) == value:
            raise ValueError(
                f"{where} was trained with {path}, which the training program (--env-backend "
                f"program) replaced: the run stays readable but does not resume here; "
                f"continue it at revision {REMOVED_AT}, or train it afresh")
    # a spec records env_backend only when it is not the default; name the default too
    old, new = ({"env_backend": DEFAULT_BACKEND, **x} for x in (old, new))
    diffs = differences(old, new)
    if diffs:
        raise ValueError(
            f"{where} holds a run of another task or agent; differing: "
            + ", ".join(f"{d} (was {lookup(old, d)!r}, now {lookup(new, d)!r})"
                        for d in diffs))
    was = lookup(old, "agent.episodes")
    if was is not None and new["agent"]["episodes"] < was:
        raise ValueError(
            f"{where} was planned for {was} episodes; a resumed run's --episodes may only "
            f"grow (got {new['agent']['episodes']}); copy the folder to train a shorter run")


Restore = Callable[[int, list[dict[str, Any]], list[list[tuple[int, Any]]]], None]
"""``restore(episode, states, chunks)``: continue from the checkpoints ``states`` (one per
folder) of ``episode`` and their buffer chunks ``[(first transition, rows), ...]``."""


class RunFolders:
    """The run folders ``run_dirs`` of K agents with the specs ``specs`` (`run_spec`), whose
    replay buffers hold ``config.buffer_size`` transitions each."""

    def __init__(self, run_dirs: Sequence[str | Path], specs: list[dict[str, Any]],
                 config: AgentConfig):
        self.folders = [RunFolder(d) for d in run_dirs]
        self.specs, self.buffer_size, self.eval_every = specs, config.buffer_size, config.eval_every
        self._locked: list[RunFolder] = []
        self._saved_total = np.zeros(len(specs), dtype=np.int64)
        self._kept_totals: list[np.ndarray] = []

    def open(self, resume: bool, restore: Restore) -> None:
        """Check the run folders against the specs, pick the checkpoint, then write; with a
        checkpoint, ``restore`` it (under the folders' locks: a failure releases them)."""
        existing = [f for f in self.folders if f.exists()]
        if existing and not resume:
            what = "a run" if existing[0].spec_path.exists() else \
                "checkpoints of a run (its spec.json is missing)"
            raise ValueError(f"{existing[0].path} already holds {what}; pass --resume to "
                             "continue it, or choose another --out")
        made = [not f.path.exists() for f in self.folders]
        locked: list[RunFolder] = []
        try:
            for f in self.folders:
                f.lock()
                locked.append(f)
            self._open_locked(restore)
        except BaseException:
            for f, new in zip(self.folders, made, strict=True):
                if f in locked:
                    f.unlock()
                    if new:  # a refused start leaves no folder behind
                        with contextlib.suppress(OSError):
                            f.path.rmdir()
            raise
        self._locked = locked

    def _open_locked(self, restore: Restore) -> None:
        """`open` once this process holds every folder's lock."""
        olds: list[dict[str, Any] | None] = []
        for f, spec in zip(self.folders, self.specs, strict=True):
            old = f.read_spec() if f.spec_path.exists() else None
            if old is not None:
                check_continues(f.path, old, spec)
            olds.append(old)
        have = [set(f.checkpoints()) for f in self.folders]
        first = interrupted_first_save(have, self.eval_every) and None not in olds
        episode, states, chunks = (None, [], []) if first else self._readable_checkpoint(have)
        if episode is None:
            for f, old, h in zip(self.folders, olds, have, strict=True):
                if old is not None and not h:
                    _refuse_lost_checkpoints(f)
        for f, spec, old in zip(self.folders, self.specs, olds, strict=True):
            # temporary files of writes that a kill interrupted; only now that this process
            # has the folder's run (a refused start touches nothing)
            f.clean()
            if old is not None:
                for key in RESUMABLE_CHANGES:
                    old["agent"][key] = spec["agent"][key]
                f.write_spec(old)
            else:
                f.write_spec(spec)
                f.write_eval([])
        if episode is None:  # afresh, from episode 0 (see `interrupted_first_save`)
            for f in self.folders:
                for path in f.checkpoints().values():
                    path.unlink(missing_ok=True)
                f.write_eval([])
                f.prune(upto=0, keep_from=0)
            return
        restore(episode, states, chunks)

    def _readable_checkpoint(self, have: list[set[int]]) -> tuple[
            int | None, list[dict[str, Any]], list[list[tuple[int, Any]]]]:
        """The latest common checkpoint of ``have`` that every folder can read, and its chunks.

        A checkpoint or chunk that cannot be read (truncated, empty) makes the run fall back to
        the older kept checkpoint, with a warning naming the file; a checkpoint trained with
        another configuration is an error.
        """
        if not any(have):
            return None, [], []
        common = set.intersection(*have)
        if not common:
            raise ValueError(
                "the run folders have no checkpoint at a common episode ("
                + ", ".join(f"{f.path}: {sorted(h)}" for f, h in zip(self.folders, have,
                                                                     strict=True))
                + "); resume them separately")
        candidates = sorted(common, reverse=True)
        for i, episode in enumerate(candidates):
            try:
                states = [f.load_checkpoint(episode) for f in self.folders]
                for f, spec, state in zip(self.folders, self.specs, states, strict=True):
                    if "config" in state:  # checkpoints from before the field have none
                        # nor, before issue 41, the program section, which spec.json compares
                        check_continues(f.checkpoints()[episode],
                                        {"program": spec.get("program"), **state["config"]}, spec)
                chunks = [f.chunks(upto=episode) for f in self.folders]
                for f, state, rows in zip(self.folders, states, chunks, strict=True):
                    _check_coverage(f.path / "buffer", episode, rows, int(state["buffer_total"]),
                                    self.buffer_size)
            except RunFolderError as err:
                if i + 1 == len(candidates):
                    raise
                warnings.warn(f"{err}; resuming from the older checkpoint of episode "
                              f"{candidates[i + 1]} instead", stacklevel=4)
                continue
            return episode, states, chunks
        raise AssertionError("unreachable")

    def restore_buffer(self, episode: int, states: list[dict[str, Any]],
                       chunks: list[list[tuple[int, Any]]], buffer: ReplayBuffer) -> None:
        """Fill ``buffer`` from the chunks of the checkpoints ``states`` of ``episode``, and
        set each folder's files to that checkpoint (its eval rows; the abandoned future
        pruned)."""
        for k, (f, s) in enumerate(zip(self.folders, states, strict=True)):
            for start, rows in chunks[k]:
                buffer.put(k, start, rows)
            if buffer.total[k] != s["buffer_total"]:
                raise RuntimeError(f"{f.path}: the buffer chunks hold {buffer.total[k]} "
                                   f"transitions, the checkpoint expects {s['buffer_total']}")
            # only the abandoned future: the older checkpoint kept beside this one needs the
            # chunks before this one's window, should this one be found corrupt later (the
            # next save prunes them, when it deletes that older checkpoint)
            f.prune(upto=episode, keep_from=0)
            f.write_eval(s["rows"])
        self._saved_total = buffer.total.copy()
        self._kept_totals = [self._saved_total]

    def save(self, episode: int, states: list[dict[str, Any]], buffer: ReplayBuffer | None,
             checkpoint: bool = True) -> None:
        """Buffer chunk, then checkpoint (``states[k]``, with the episode, the spec's config
        and the buffer's count added), then eval.csv (``states[k]["rows"]``), per folder.
        Without ``buffer`` (a window run's, `ddpg_her.loop.Loop`): no chunk, and a checkpoint
        only with ``checkpoint`` (at the run's end: such a run does not resume)."""
        if buffer is not None:
            self._kept_totals = [*self._kept_totals[-1:], buffer.total.copy()]
        for k, (f, state) in enumerate(zip(self.folders, states, strict=True)):
            count = {}
            if buffer is not None:
                start, rows = buffer.since(k, int(self._saved_total[k]))
                f.save_chunk(episode, start, rows)
                count = {"buffer_total": int(buffer.total[k])}
            if checkpoint:
                f.save_checkpoint(episode, {
                    "episode": episode,
                    "config": {key: self.specs[k][key] for key in CONFIG_KEYS
                               if key in self.specs[k]},
                    **state, **count})
            f.write_eval(state["rows"])
            if buffer is not None:
                f.prune(upto=episode, keep_from=int(self._kept_totals[0][k]) - self.buffer_size)
        if buffer is not None:
            self._saved_total = buffer.total.copy()

    def close(self) -> None:
        """Release the folders' locks."""
        for f in self._locked:
            f.unlock()
        self._locked = []


def interrupted_first_save(have: Sequence[set[int]], eval_every: int) -> bool:
    """Whether the checkpoint episodes ``have`` (one set per run folder of a stack) are those
    of a first save that a kill interrupted between two folders: some hold the checkpoint of
    episode ``eval_every`` (the first one a run writes), the others none. The stack has no
    common checkpoint, and nothing to lose by starting again from episode 0 (its test sessions
    are those of that first checkpoint alone), which gives the uninterrupted run's bytes. The
    caller also asks that every folder holds a spec.json (the killed process opened them all):
    a folder new to the stack means runs started apart, which are not rolled back."""
    return set().union(*have) == {eval_every} and not all(have)


def _refuse_lost_checkpoints(f: RunFolder) -> None:
    """Raise ValueError when the run in ``f`` has finished work (test sessions) but no
    checkpoint: resuming would train it again from episode 0 over its eval.csv. A run killed
    before or during its first checkpoint (its buffer chunk may be whole, its checkpoint a
    temporary file) has no test session: nothing to lose, it starts afresh (issue 37)."""
    sessions = len(f.read_eval())
    chunks = sorted(p.name for p in (f.path / "buffer").glob("episode-*.npz"))
    if sessions:
        raise ValueError(
            f"{f.path} holds a run with {sessions} test session(s) in eval.csv"
            + (f" and {len(chunks)} buffer chunk(s)" if chunks else "")
            + f" but no checkpoint in {f.path / 'checkpoints'} (deleted or moved?); --resume "
            "would start it again from episode 0. Restore the checkpoints, or move the folder "
            "away (or choose another --out) to train the run anew")


def check_recorded(env_id: str, given: dict[str, Any], task: dict[str, Any]) -> None:
    """Raise ValueError unless every task field in ``given`` (the env's keyword arguments) is
    the value the env's task holds, which ``spec.json`` records and every tool rebuilds the
    task from. A given None asks the task for its derived value (e.g. ``start_q``)."""
    wrong = [f"{key}={value!r} (the task holds {task[key]!r})" for key, value in given.items()
             if key in task and value is not None and plain(value) != plain(task[key])]
    if wrong:
        raise ValueError(f"{env_id} did not take the task field(s) given: {', '.join(wrong)}; "
                         "the run would train one task and record another")


def plain(x: Any) -> Any:
    """``x`` as JSON holds it, numbers as floats: 1 and 1.0 are one value, (1, 2) and [1, 2]."""
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if isinstance(x, (int, float, np.integer, np.floating)):
        return float(x)
    if isinstance(x, dict):
        return {str(k): plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [plain(v) for v in x]
    return json.loads(json.dumps(x, default=str))


def _check_coverage(where: Path, episode: int, chunks: Sequence[tuple[int, Any]], total: int,
                    capacity: int) -> None:
    """Raise RunFolderError unless ``chunks`` hold every transition that a checkpoint with
    ``total`` transitions keeps in a buffer of ``capacity``: numbers ``total - capacity``
    (or 0) to ``total - 1``, without a gap. A gap would leave rows that were never written."""
    need = max(0, total - capacity)
    covered = need
    for start, rows in chunks:
        end = start + len(rows)
        if end <= covered:
            continue
        if start > covered:
            raise RunFolderError(
                f"{where}: the checkpoint of episode {episode} needs transitions {need} to "
                f"{total - 1}, but no chunk holds {covered} to {start - 1} (deleted or lost)")
        covered = end
    if covered != total:
        raise RunFolderError(
            f"{where}: the chunks up to episode {episode} end at transition {covered}, its "
            f"checkpoint expects {total}")


def lookup(d: dict[str, Any], dotted: str) -> Any:
    for part in dotted.split("."):
        d = d.get(part) if isinstance(d, dict) else None
    return d
