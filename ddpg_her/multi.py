"""Many settings in one process: settings grouped into stacked agents, the groups trained in turn.

A `Setting` is one task (env id and kwargs: region, joints, reward reading, ...) with its agent
configuration, seeds and run folders. Settings that share the env id, the observation and action
layout (`GoalVecEnv.dims`), the whole `AgentConfig` and the checkpoint they resume from share one
stacked agent: one `Trainer` whose K is the sum of their seeds, agent k with its own task. The
others form further groups, each its own `Trainer`; every round, each unfinished group trains one
episode (updates, test session and checkpoint included) in turn.

Nothing is padded and no stack mixes agent configurations or Adam step counts, so every run
folder is the one the run gets alone (README, "Training many seeds fast", says to what precision).
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from ddpg_her.logs import progress_bar
from ddpg_her.runfolder import RunFolder
from ddpg_her.trainer import Trainer
from ddpg_her.units import Setting
from ddpg_her.vecenv import GoalVecEnv


def resume_point(run_dirs: Sequence[str | Path]) -> int | None:
    """The latest checkpoint episode common to the folders; None when none has a checkpoint,
    -1 when they have checkpoints but none in common (their Trainer will say so)."""
    have = [set(RunFolder(d).checkpoints()) for d in run_dirs]
    if not any(have):
        return None
    common = set.intersection(*have)
    return max(common) if common else -1


def layout(env_id: str, env_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The observation and action layout of the task (`GoalVecEnv.dims`), from one env copy."""
    envs = GoalVecEnv(env_id, 1, 1, **env_kwargs)
    try:
        return envs.dims
    finally:
        envs.close()


def one_stack(group: Sequence[Setting]) -> bool:
    """Whether the run folders of ``group`` (settings of one configuration) are where one
    stack leaves them, a kill included: each folder's latest checkpoint is the stack's common
    one or the save after it (a kill between two folders' checkpoint writes), no checkpoint
    counting as episode 0, and every folder holding a spec.json where they differ (one process
    opened them all). Such settings resume as one stack from the common checkpoint (their
    `Trainer` picks it), which gives the uninterrupted run's bytes; split into stacks by resume
    point, they trained otherwise from there on (issue 37)."""
    folders = [RunFolder(d) for s in group for d in s.run_dirs]
    have = [set(f.checkpoints()) for f in folders]
    latest = [max(h) if h else 0 for h in have]
    if len(set(latest)) == 1:
        return True
    common = set.intersection(*have)
    base = max(common) if common else 0
    every = group[0].config.eval_every
    return all(f.spec_path.exists() for f in folders) and \
        all(n in (base, base + every) for n in latest)


def group_settings(settings: Sequence[Setting], resume: bool) -> list[list[Setting]]:
    """The settings grouped into stacks: equal env id, layout and agent configuration and
    (with ``resume``) one resume point: a group whose folders `one_stack` accepts stays whole,
    another is split by each setting's `resume_point`; groups in the order of their first
    setting."""
    groups: dict[str, list[Setting]] = {}
    for s in settings:
        key = json.dumps([s.env_id, layout(s.env_id, s.env_kwargs), s.config.to_dict()],
                         sort_keys=True)
        groups.setdefault(key, []).append(s)
    out: list[list[Setting]] = []
    for group in groups.values():
        if not resume or one_stack(group):
            out.append(group)
            continue
        by_point: dict[int | None, list[Setting]] = {}
        for s in group:
            by_point.setdefault(resume_point(s.run_dirs), []).append(s)
        out += by_point.values()
    return out


class MultiTrainer:
    """Trains every setting of ``settings`` in this process, one `Trainer` per group of
    `group_settings`; the keyword arguments are `Trainer`'s."""

    def __init__(self, settings: Sequence[Setting], *, resume: bool = False,
                 device: str = "cpu", env_backend: str = "numpy",
                 dtype: torch.dtype = torch.float32, progress: bool = True,
                 tensorboard: bool = True, command: Sequence[str] | None = None):
        if not settings:
            raise ValueError("need one or more settings")
        dirs = [Path(d).resolve() for s in settings for d in s.run_dirs]
        if len(set(dirs)) != len(dirs):
            raise ValueError("two settings share a run folder: "
                             f"{sorted({str(d) for d in dirs if dirs.count(d) > 1})}")
        self.groups = group_settings(settings, resume)
        self.progress = progress
        self.trainers: list[Trainer] = []
        try:
            for group in self.groups:
                self.trainers.append(Trainer(
                    group[0].env_id, [s.env_kwargs for s in group for _ in s.seeds],
                    group[0].config, [seed for s in group for seed in s.seeds],
                    [d for s in group for d in s.run_dirs], resume=resume, device=device,
                    env_backend=env_backend, dtype=dtype,
                    progress=False,
                    tensorboard=tensorboard, command=command))
        except BaseException:
            self.close()
            raise

    @property
    def agents(self) -> int:
        return sum(t.k for t in self.trainers)

    def run(self) -> list[list[list[dict[str, Any]]]]:
        """Train every group to its budget; returns each setting's runs' eval rows, in the order
        of the settings within `groups` (``rows[g][i]``: setting i of group g)."""
        bar = _progress(self.progress, self.trainers)
        for t in self.trainers:
            t.start()
        try:
            while not all(t.done for t in self.trainers):
                for t in self.trainers:
                    if not t.done:
                        t.step()
                        if bar is not None:
                            bar.update(t.k)
        finally:
            if bar is not None:
                bar.close()
            for t in self.trainers:
                t.finish()
        out = []
        for group, t in zip(self.groups, self.trainers, strict=True):
            rows, i = [], 0
            for s in group:
                rows.append(t.rows[i:i + len(s.seeds)])
                i += len(s.seeds)
            out.append(rows)
        return out

    def close(self) -> None:
        for t in self.trainers:
            t.close()


def _progress(enabled: bool, trainers: Sequence[Trainer]):
    """One bar over the agent-episodes of every group (a group's episode counts K)."""
    bar = progress_bar(enabled, sum(t.k * t.config.episodes for t in trainers),
                       sum(t.k * t.episode for t in trainers), "agent-ep",
                       f"train {sum(t.k for t in trainers)} agents in {len(trainers)} group"
                       f"{'s' if len(trainers) > 1 else ''}")
    if bar is not None:
        bar.set_postfix_str(f"started {datetime.datetime.now():%a %H:%M}", refresh=False)
    return bar
