"""The paper's training protocol, written once for both episode engines (docs/design.md,
"Data flow"): ``config.episodes`` episodes in sessions of ``eval_every``, each episode one
exploring episode per agent and, after the warm-up, ``updates_per_episode`` updates; each
session closed by a test session whose eval row (with the clock, ``wall_s``) and checkpoint
every run folder gets. `Loop` owns the sessions, eval rows, clock, saving and resuming
(`ddpg_her.checkpoints.RunFolders`), a window run's saves and time `Budget`; `run` steps the
loops of a process under one progress bar. The engines, `ddpg_her.trainer.Trainer` (host envs)
and `ddpg_her.program.Program` (one stack on a device), say how an episode, its updates and a
test session run and what a checkpoint holds of their agents.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ddpg_her.checkpoints import RunFolders
from ddpg_her.config import AgentConfig
from ddpg_her.logs import postfix


class Diverged(RuntimeError):
    """Training produced networks with inf or NaN (a diverging run)."""


def agents_of(env_kwargs: dict[str, Any] | Sequence[dict[str, Any]], seeds: Sequence[int],
              run_dirs: Sequence[str | Path]) -> tuple[list[dict[str, Any]], list[int]]:
    """(K env-keyword dicts, K seeds) of a loop's agents: ``env_kwargs`` one dict for all or
    one per seed, seeds >= 0 distinct among the agents of one task, K distinct folders (else
    ValueError naming them)."""
    seeds = [int(s) for s in seeds]
    per_agent = [dict(env_kwargs)] * len(seeds) if isinstance(env_kwargs, dict) else \
        [dict(kw) for kw in env_kwargs]
    runs = {json.dumps([kw, s], sort_keys=True) for kw, s in zip(per_agent, seeds, strict=False)}
    if not seeds or min(seeds) < 0 or not len(runs) == len(per_agent) == len(seeds) == len(
            run_dirs) == len({Path(d).resolve() for d in run_dirs}):
        raise ValueError(f"need one or more seeds >= 0, distinct among the agents of one task, "
                         f"with one env_kwargs dict and one distinct run folder each; got seeds "
                         f"{seeds}, {len(per_agent)} dicts, folders {list(run_dirs)}")
    return per_agent, seeds


@dataclasses.dataclass(frozen=True)
class Budget:
    """A window run's time budget: train the most of ``choices`` episodes (each a multiple of
    ``eval_every``, the largest the configuration's ``episodes``) that `choose_episodes`
    projects to end within ``seconds`` of ``start`` (a ``clock()`` reading, s)."""

    seconds: float
    choices: tuple[int, ...]
    start: float
    clock: Callable[[], float] = time.monotonic


def choose_episodes(elapsed_s: float, episode: int, s_per_episode: float, seconds: float,
                    choices: Sequence[int]) -> tuple[int, float]:
    """(budget, projected s): the largest of ``choices`` not below ``episode`` whose remaining
    episodes at ``s_per_episode`` end within ``seconds`` (``elapsed_s`` spent), or, when none
    does, the smallest of them; its projected end in seconds since the start."""
    left = [c for c in choices if c >= episode]
    if not left:
        raise ValueError(f"episode {episode} is past every budget of {sorted(choices)}")

    def end(c: int) -> float:
        return elapsed_s + (c - episode) * s_per_episode

    fits = [c for c in left if end(c) <= seconds]
    chosen = max(fits) if fits else min(left)
    return chosen, end(chosen)


class Loop:
    """The protocol of K agents (see the module docstring). An engine (a subclass) sets
    ``config``, ``k``, ``specs`` (one spec.json per agent), ``progress``, ``env_steps`` ((K,)
    counts) and ``buffer``, calls `_open` once its agents exist, and writes the hooks that
    `step` and the checkpoints call: ``_train(warm)``, one exploring episode of every agent
    (uniform actions while ``warm``), stored; ``_updates()``, ``updates_per_episode`` updates
    of every agent; ``evaluate()``, a test session's eval rows, one per agent without
    ``wall_s`` (an engine may raise `Diverged` there or in ``_updates``); ``_agent_state(k)``,
    what agent k's checkpoint holds of its agent and streams; ``_load(episode, states,
    chunks)``, their inverse, ``env_steps`` and the buffers included
    (`RunFolders.restore_buffer`). It may write ``_saved_buffer()``, the buffer that
    `RunFolders.save` reads (``buffer``), and ``_logged()``, after each session's rows.

    window : a run for one GPU window: eval.csv at every session, no buffer chunk and no
    checkpoint but the last (the actors and normalisers); it cannot be resumed. budget : with
    ``window``, from the second test session on each session sets the budget to what
    `choose_episodes` projects from the last interval's seconds per episode (test session
    included), rewriting spec.json's ``agent.episodes`` and ``program.budget``.
    """

    config: AgentConfig
    k: int
    specs: list[dict[str, Any]]
    progress: bool
    env_steps: Any
    desc = "train"

    @classmethod
    def of_settings(cls, settings: Sequence[Any], **kwargs: Any) -> Loop:
        """The engine of every run of ``settings`` (`ddpg_her.units.Setting` s; the first's env
        id and configuration), one agent per seed; ``kwargs`` as the constructor's."""
        first = settings[0]
        return cls(first.env_id, [s.env_kwargs for s in settings for _ in s.seeds],
                   first.config, [seed for s in settings for seed in s.seeds],
                   [d for s in settings for d in s.run_dirs], **kwargs)

    def _open(self, run_dirs: Sequence[str | Path], resume: bool, window: bool = False,
              budget: Budget | None = None) -> None:
        """Open the run folders: afresh, or with ``resume`` from their last common checkpoint."""
        cfg = self.config
        if budget is not None and (not window or max(budget.choices) != cfg.episodes or any(
                c < 1 or c % cfg.eval_every for c in budget.choices)):
            raise ValueError(f"a time budget is a window run's (window=True), its choices "
                             f"{list(budget.choices)} multiples of --eval-every "
                             f"{cfg.eval_every}, the largest --episodes {cfg.episodes}")
        self.episode, self.wall_s = 0, 0.0
        self.rows: list[list[dict[str, Any]]] = [[] for _ in range(self.k)]
        self.window, self.budget, self._interval_start = window, budget, None
        self._tick = time.perf_counter()
        self.folders = RunFolders(run_dirs, self.specs, cfg)
        self.folders.open(resume, self._restore)

    def _logged(self) -> None:
        pass

    def _saved_buffer(self) -> Any:
        return self.buffer

    @property
    def done(self) -> bool:
        """Whether the agents have trained ``config.episodes`` episodes."""
        return self.episode >= self.config.episodes

    def start(self) -> None:
        """Start the clock; before the first `step`."""
        self._tick = time.perf_counter()

    def step(self) -> None:
        """One training episode and its updates; then, every ``eval_every`` episodes, a test
        session, its eval rows and a checkpoint (and a checkpoint at the last episode).

        ``wall_s`` counts the clock since `start`, including the time that other loops of the
        process (`run`) spend between two steps of this one.
        """
        cfg = self.config
        warm = self.episode < cfg.warmup_episodes
        self._train(warm)
        if not warm and cfg.updates_per_episode > 0:
            self._updates()
        self.episode += 1
        if self.episode % cfg.eval_every == 0:
            self._session(self.evaluate())
        elif self.episode == cfg.episodes:
            self._save()
        self._clock()

    def _clock(self) -> None:
        now = time.perf_counter()
        self.wall_s += now - self._tick
        self._tick = now

    def _session(self, rows: list[dict[str, Any]]) -> None:
        """Append a test session's eval ``rows`` (one per agent) with the clock, then save."""
        self._clock()
        for mine, row in zip(self.rows, rows, strict=True):
            mine.append({**row, "wall_s": round(self.wall_s, 2)})
        self._logged()
        if self.budget is not None:
            self._choose_budget()
        self._save()

    def _choose_budget(self) -> None:
        """`Budget`: from the last interval's seconds per episode, the budget to train to;
        said on stderr and recorded in every spec.json when it changes."""
        b, now = self.budget, self.budget.clock()
        start, self._interval_start = self._interval_start, now
        if start is None:  # the first session: its interval held the start-up
            return
        rate = (now - start) / self.config.eval_every
        chosen, end = choose_episodes(now - b.start, self.episode, rate, b.seconds, b.choices)
        if chosen == self.config.episodes and "budget" in self.specs[0]["program"]:
            return
        fits = "" if end <= b.seconds else " (none of the choices fits: the smallest left)"
        print(f"window budget: {1e3 * rate:.1f} ms per episode over episodes "
              f"{self.episode - self.config.eval_every + 1}-{self.episode} (its test session "
              f"included) -> {chosen} episodes{fits}, projected to end at {end:.0f} s of the "
              f"{b.seconds:.0f} s budget (choices {'/'.join(map(str, b.choices))})",
              file=sys.stderr, flush=True)
        self.config = dataclasses.replace(self.config, episodes=chosen)
        record = {"seconds": b.seconds, "choices": list(b.choices), "episode": self.episode,
                  "ms_per_episode": round(1e3 * rate, 3), "elapsed_s": round(now - b.start, 1),
                  "projected_s": round(end, 1)}
        for f, spec in zip(self.folders.folders, self.specs, strict=True):
            spec["agent"]["episodes"], spec["program"]["budget"] = chosen, record
            f.write_spec(spec)

    # --- checkpoints --------------------------------------------------------------------------
    def state(self, k: int) -> dict[str, Any]:
        """What agent k's checkpoint holds of this loop (`RunFolders.save` adds the rest)."""
        return {"env_steps": int(self.env_steps[k]), "wall_s": self.wall_s, "rows": self.rows[k],
                **self._agent_state(k)}

    def _save(self) -> None:
        """Every folder's checkpoint and eval.csv; a window run's: its eval.csv, and at the end
        a checkpoint of the actors and normalisers."""
        whole = self.done or not self.window
        states = [self.state(k) if whole else {"rows": self.rows[k]} for k in range(self.k)]
        for state in states if whole and self.window else ():
            state["agent"] = {key: state["agent"][key] for key in ("actor", "normalizer")}
        self.folders.save(self.episode, states, None if self.window else self._saved_buffer(),
                          checkpoint=whole)

    def _restore(self, episode: int, states: list[dict[str, Any]],
                 chunks: list[list[tuple[int, Any]]]) -> None:
        """Continue from the checkpoints ``states`` of ``episode`` (see `state`)."""
        self._load(episode, states, chunks)
        self.rows = [list(s["rows"]) for s in states]
        self.episode, self.wall_s = episode, float(states[0]["wall_s"])

    def run(self) -> list[list[dict[str, Any]]]:
        """Train to ``config.episodes``; returns every agent's eval rows."""
        run([self], self.progress, f"{self.desc}: {self.k} agent{'s' if self.k > 1 else ''}")
        return self.rows

    def close(self) -> None:
        """Release the run folders' locks."""
        self.folders.close()


def run(loops: Sequence[Loop], progress: bool, desc: str) -> None:
    """Train every loop of ``loops`` to its budget, each unfinished one stepping one episode in
    turn, under one progress bar of agent-episodes (a loop's episode counts its K)."""
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(t.k * t.config.episodes for t in loops), unit="agent-ep",
                   initial=sum(t.k * t.episode for t in loops), dynamic_ncols=True, desc=desc)
    for t in loops:
        t.start()
    try:
        while not all(t.done for t in loops):
            for t in loops:
                if not t.done:
                    t.step()
                    if bar is not None:
                        bar.set_postfix_str(postfix(bar, t.rows), refresh=False)
                        bar.update(t.k)
    finally:
        if bar is not None:
            bar.close()
