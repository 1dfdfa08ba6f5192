"""Many settings in one process: settings grouped into stacked agents, the groups trained in turn.

A `Setting` is one task (env id and kwargs: region, joints, reward reading, ...) with its agent
configuration, seeds and run folders. Settings that share the env id, the observation and action
layout (`GoalVecEnv.dims`), the whole `AgentConfig` and the checkpoint they resume from share one
stacked agent: one `Trainer` whose K is the sum of their seeds, agent k with its own task. The
others form further groups, each its own `Trainer`; every round, each unfinished group trains one
episode (updates, test session and checkpoint included) in turn (`ddpg_her.loop.run`). The
training program (``env_backend="program"``) takes every setting as one stack instead.

Nothing is padded and no stack mixes agent configurations or Adam step counts, so every run
folder is the one the run gets alone (README, "Training many seeds fast", says to what precision).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from ddpg_her.loop import Loop, run
from ddpg_her.runfolder import RunFolder
from ddpg_her.trainer import Trainer
from ddpg_her.units import Setting, shared_folders
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
    return all(f.spec_path.exists() for f in folders) and \
        all(n in (base, base + group[0].config.eval_every) for n in latest)


def group_settings(settings: Sequence[Setting], resume: bool, env_backend: str = "numpy"
                   ) -> list[list[Setting]]:
    """The settings grouped into stacks: under ``env_backend`` program one stack; else equal
    env id, layout and agent configuration and (with ``resume``) one resume point: a group
    whose folders `one_stack` accepts stays whole, another is split by each setting's
    `resume_point`; groups in the order of their first setting."""
    if len(settings) == 1 or (settings and env_backend == "program"):
        return [list(settings)]
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
    """Trains every setting of ``settings`` in this process: with ``env_backend`` ``program``
    as one `ddpg_her.program.Program` (``program`` its own keyword arguments: tf32, window,
    budget), otherwise one `Trainer` per group of `group_settings`; the other keyword
    arguments are theirs."""

    def __init__(self, settings: Sequence[Setting], *, resume: bool = False,
                 device: str = "cpu", env_backend: str = "numpy",
                 dtype: torch.dtype = torch.float32, progress: bool = True,
                 tensorboard: bool = True, command: Sequence[str] | None = None,
                 **program: Any):
        if not settings:
            raise ValueError("need one or more settings")
        shared = shared_folders((d, f"{s.name} seed={seed}") for s in settings
                                for seed, d in zip(s.seeds, s.run_dirs, strict=True))
        if shared:
            raise ValueError("; ".join(shared))
        self.groups = group_settings(settings, resume, env_backend)
        self.progress = progress
        self.trainers: list[Loop] = []
        engine: type[Loop] = Trainer
        kwargs = dict(resume=resume, device=device, dtype=dtype, progress=False, command=command)
        if env_backend == "program":
            from ddpg_her.program import Program

            engine, kwargs = Program, {**kwargs, **program}
        else:
            kwargs.update(env_backend=env_backend, tensorboard=tensorboard)
        try:
            for group in self.groups:
                self.trainers.append(engine.of_settings(group, **kwargs))
        except BaseException:
            self.close()
            raise

    @property
    def agents(self) -> int:
        return sum(t.k for t in self.trainers)

    def run(self) -> list[list[list[dict[str, Any]]]]:
        """Train every group to its budget; returns each setting's runs' eval rows, in the order
        of the settings within `groups` (``rows[g][i]``: setting i of group g)."""
        n = len(self.trainers)
        run(self.trainers, self.progress, f"{self.trainers[0].desc}: {self.agents} agent"
            f"{'s' if self.agents > 1 else ''}" + (f" in {n} groups" if n > 1 else ""))
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
