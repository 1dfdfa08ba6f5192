"""The paper's training protocol for K independent agents in one process.

Every training episode each agent runs one episode in its own env copy (all K in lockstep),
stores it and its HER copies in its own buffer, then all agents make ``updates_per_episode``
batched updates. Every ``eval_every`` episodes each agent runs ``eval_episodes`` test episodes of
its deterministic policy, and every run folder gets its eval row and a checkpoint.

The K agents may pursue different tasks of one observation and action layout (``env_kwargs``
per agent: regions, reward readings, contact models); they share the agent configuration.
Agent k's randomness comes from its seed alone (env episodes, initial weights, exploration, HER
goals, minibatches), so K = 1 and K > 1 train agent k alike, and a resumed run continues exactly.
`ddpg_her.multi` runs several such trainers (other layouts or configurations) in turn.
"""

from __future__ import annotations

import contextlib
import datetime
import functools
import json
import math
import os
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ddpg_her.agents import make_agent
from ddpg_her.buffer import (
    Layout,
    ReplayBuffer,
    TensorEpisodes,
    her_goal_steps,
    her_tensors,
    pack,
    pack_tensors,
    relabel,
)
from ddpg_her.config import BEFORE, AgentConfig
from ddpg_her.ensemble import make_buffer, spec_entry, task_partitions
from ddpg_her.exploration import Explorer, TorchExplorer
from ddpg_her.runfolder import FORMAT, RunFolder, RunFolderError, git_revision, versions
from ddpg_her.spaces import goal_input
from ddpg_her.update_graph import UpdateStep
from ddpg_her.update_graph import resolve as resolve_update_graph
from ddpg_her.vecenv import GoalVecEnv, TorchGoalVecEnv, rollout, torch_rollout

# Keys of the independent random streams derived from a seed (numpy SeedSequence spawn keys).
_INIT, _EXPLORE, _SAMPLE, _TRAIN_ENV, EVAL_ENV_STREAM = range(5)
"""``EVAL_ENV_STREAM``: the key of the test sessions' goals, ``stream_seed(seed,
EVAL_ENV_STREAM, session, i)`` for test episode i of a session (public: other trainers, such
as ``analysis.sb3``, test on the same goals)."""

ENV_BACKENDS = ("numpy", "batched", "torch")
"""``numpy``: the envs are Gymnasium's (numpy arrays on the host), one group of copies per
agent. ``batched``: the same envs, but the copies of all agents whose tasks differ only in their
goals step in one vector env (``GoalVecEnv(merge=True)``; UR5Reach-v0: one call of the compiled
kernel for all of them), with the same goals and exploration as ``numpy`` and trajectories
equal to rounding. ``torch``: the env id's tensor twin (``vecenv.TORCH_TWINS``, e.g.
``envs.TorchReach``) on the trainer's device, so rollout, HER and the buffer stay on the device
(stop contact model only)."""


class Diverged(RuntimeError):
    """Training produced networks with inf or NaN (a diverging run)."""


BYTES_PER_PARAMETER = 6
"""Copies of each network parameter in memory: the weight, its target, its gradient, Adam's
two moments, and one for the update's scratch (an upper estimate)."""


def check_memory(config: AgentConfig, layout: Layout, k: int, dtype: torch.dtype,
                 device: torch.device) -> None:
    """Refuse, before allocating, replay buffers and networks larger than the memory of
    ``device`` (the host's available memory for the CPU, the GPU's free memory).

    Raises
    ------
    ValueError
        Naming --buffer-size or --hidden-sizes and the memory they would need.
    """
    size = torch.empty((), dtype=dtype).element_size()
    buffer = k * config.buffer_size * layout.width * size
    h1, h2 = config.hidden_sizes
    params = (layout.in_dim * h1 + h1 + h1 * h2 + h2 + h2 * layout.act_dim + layout.act_dim
              + layout.in_dim * h1 + h1 + (h1 + layout.act_dim) * h2 + h2 + h2 + 1)
    networks = k * params * size * BYTES_PER_PARAMETER
    available = available_memory(device)
    if available is None:
        return
    gib = 2.0 ** 30
    for flag, need in (("--buffer-size", buffer), ("--hidden-sizes", networks),
                       ("--buffer-size and --hidden-sizes", buffer + networks)):
        if need > available:
            raise ValueError(
                f"{flag}: {k} agent(s) would need {need / gib:.3g} GiB ({buffer / gib:.3g} GiB "
                f"of replay buffers: {config.buffer_size} transitions x {layout.width} "
                f"values x {size} bytes each; {networks / gib:.3g} GiB of networks "
                f"{config.hidden_sizes}), more than the {available / gib:.3g} GiB available "
                f"on {device}")


def available_memory(device: torch.device) -> int | None:
    """Bytes that can still be allocated on ``device``, or None when it cannot be told."""
    if device.type == "cuda":
        try:
            return int(torch.cuda.mem_get_info(device)[0])
        except (RuntimeError, AssertionError):
            return None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def stream_seed(seed: int, *key: int) -> int:
    """A 32-bit seed for the random stream ``key`` of the run with ``seed``."""
    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1)[0])


class Trainer:
    """Trains one agent per seed, writing one run folder per seed (see `ddpg_her.run`).

    env_id, env_kwargs : ``gymnasium.make(env_id, **env_kwargs)`` makes the task: one dict for
    all agents, or K dicts, agent k's task made with ``env_kwargs[k]`` (all of one layout);
    seeds : (K,) ints, distinct among agents of one task; run_dirs : K distinct folders;
    resume : continue the runs in ``run_dirs`` from their last common checkpoint (runs absent
    there start afresh) instead of refusing existing folders; env_backend : one of
    `ENV_BACKENDS`. With ``torch``, exploration draws from torch generators on the device
    (`TorchExplorer`), so the same seed explores otherwise than with ``numpy``; with no
    exploration draws (no warm-up, rate 0) the two backends train alike to rounding (tested).
    update_graph : ``auto``, ``on`` or ``off`` (`ddpg_her.update_graph.MODES`); on, the updates
    run as one device step (`UpdateStep`, a CUDA graph on CUDA) with their own minibatch stream.
    """

    def __init__(self, env_id: str, env_kwargs: dict[str, Any] | Sequence[dict[str, Any]],
                 config: AgentConfig, seeds: Sequence[int], run_dirs: Sequence[str | Path], *,
                 resume: bool = False, device: str = "cpu", dtype: torch.dtype = torch.float32,
                 progress: bool = True, tensorboard: bool = True,
                 command: Sequence[str] | None = None, env_backend: str = "numpy",
                 update_graph: str = "off"):
        if env_backend not in ENV_BACKENDS:
            raise ValueError(f"env_backend must be one of {list(ENV_BACKENDS)}, got "
                             f"{env_backend!r}")
        self.env_backend = env_backend
        seeds = [int(s) for s in seeds]
        per_agent = [dict(env_kwargs)] * len(seeds) if isinstance(env_kwargs, dict) else \
            [dict(kw) for kw in env_kwargs]
        if len(per_agent) != len(seeds):
            raise ValueError(f"need one env_kwargs dict per seed: {len(seeds)} seeds, "
                             f"{len(per_agent)} dicts")
        runs = [json.dumps([kw, s], sort_keys=True) for kw, s in zip(per_agent, seeds,
                                                                     strict=True)]
        if not seeds or len(set(runs)) != len(runs) or min(seeds) < 0:
            raise ValueError(f"need one or more seeds >= 0, distinct among the agents of one "
                             f"task, got {seeds}")
        if len(run_dirs) != len(seeds):
            raise ValueError(f"need one run folder per seed: {len(seeds)} seeds, "
                             f"{len(run_dirs)} folders")
        if len({Path(d).resolve() for d in run_dirs}) != len(run_dirs):
            raise ValueError(f"need a distinct run folder per agent, got {list(run_dirs)}")
        self.config, self.seeds, self.k = config, seeds, len(seeds)
        self.device = torch.device(device)
        self._flush_denormals()
        self.progress, self.tensorboard = progress, tensorboard
        self.env_id, self.env_kwargs = env_id, per_agent
        if env_backend == "torch":
            self.envs: GoalVecEnv | TorchGoalVecEnv = TorchGoalVecEnv(
                env_id, per_agent, 1, device=self.device)
            self.eval_envs: GoalVecEnv | TorchGoalVecEnv = TorchGoalVecEnv(
                env_id, per_agent, config.eval_episodes, device=self.device)
        else:
            merge = env_backend == "batched"
            self.envs = GoalVecEnv(env_id, per_agent, 1, merge=merge)
            self.eval_envs = GoalVecEnv(env_id, per_agent, config.eval_episodes, merge=merge)
        envs = self.envs
        for k, kwargs in enumerate(per_agent):
            _check_recorded(env_id, kwargs, envs.task_of(k))
        self.scale = envs.scale
        self.layout = Layout(envs.obs_dim + 2 * envs.goal_dim, envs.scale.dim)
        self.folders = [RunFolder(d) for d in run_dirs]
        check_memory(config, self.layout, self.k, dtype, self.device)

        self.agent = make_agent(
            config, self.layout.in_dim, self.layout.act_dim, dtype=dtype, device=self.device,
            init_generators=[torch.Generator().manual_seed(stream_seed(s, _INIT)) for s in seeds],
            partitions=task_partitions(env_id, per_agent, config.ensemble)
            if config.ensemble > 1 else None)
        self.buffer: ReplayBuffer = make_buffer(config, self.k, self.layout, self.agent,
                                                dtype=dtype, device=self.device)
        self.rngs = [np.random.default_rng(stream_seed(s, _EXPLORE)) for s in seeds]
        self.sample_generators = [
            torch.Generator(self.device).manual_seed(stream_seed(s, _SAMPLE)) for s in seeds]
        self.explorer = Explorer(config, self.rngs, envs.scale.dim)
        self.explore_generators = [
            torch.Generator(self.device).manual_seed(stream_seed(s, _EXPLORE)) for s in seeds]
        self.torch_explorer = TorchExplorer(config, self.explore_generators, envs.scale.dim,
                                            self.device)
        # --update-graph (ddpg_her.update_graph): the updates as one device step, minibatches
        # from a counter-based stream keyed by the sampling seeds; None: `learn`'s own loop
        self.update_step = UpdateStep(
            self.agent, self.buffer, [stream_seed(s, _SAMPLE) for s in seeds],
            config.batch_size) if resolve_update_graph(update_graph, self.device, config) \
            else None

        self.episode = 0
        self.env_steps = np.zeros(self.k, dtype=np.int64)
        self.wall_s = 0.0
        self.rows: list[list[dict[str, Any]]] = [[] for _ in seeds]
        self._saved_total = np.zeros(self.k, dtype=np.int64)
        self._kept_totals: list[np.ndarray] = []
        self.specs = [self._spec(k, command) for k in range(self.k)]
        self._locked: list[RunFolder] = []
        self._open(resume)
        self._log: _Interval | None = None
        self._tick = 0.0

    def _flush_denormals(self) -> None:
        """Set the CPU's subnormal flush to this trainer's config: process-wide in torch, so
        set again before each step where trainers of several configurations share a process."""
        if self.device.type == "cpu":
            torch.set_flush_denormal(self.config.flush_denormals)

    # --- run folders ----------------------------------------------------------------------------
    def _spec(self, k: int, command: Sequence[str] | None) -> dict[str, Any]:
        """Agent k's ``spec.json``: the same whether it trains alone or beside others."""
        backend = {} if self.env_backend == "numpy" else {"env_backend": self.env_backend}
        graph = {} if self.update_step is None else {"update_graph": "on"}
        return {**backend, **graph, **spec_entry(self.agent, k),
            "format": FORMAT,
            "env_id": self.env_id,
            "env_kwargs": self.env_kwargs[k],
            "task": self.envs.task_of(k),
            "seed": self.seeds[k],
            "agent": self.config.to_dict(),
            "dims": self.envs.dims,
            "versions": versions(),
            "git": git_revision(),
            "command": list(command) if command is not None else sys.argv,
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        }

    RESUMABLE_CHANGES = ("episodes", "flush_denormals")
    """Agent fields a resumed run may change: the budget, and how the CPU rounds subnormals
    (an execution setting like the thread count; runs from before the field existed resume)."""

    @classmethod
    def _differences(cls, old: dict[str, Any], new: dict[str, Any]) -> list[str]:
        """Keys that make two specs different tasks or agents."""
        diffs = [key for key in ("format", "env_id", "env_kwargs", "task", "seed", "dims",
                                 "env_backend", "update_graph")
                 if not json_equal(old.get(key), new.get(key))]
        # a field added after the run was written reads as what such runs did (config.BEFORE)
        old_agent = {k: v for k, v in {**BEFORE, **old.get("agent", {})}.items()
                     if k not in cls.RESUMABLE_CHANGES}
        new_agent = {k: v for k, v in new["agent"].items() if k not in cls.RESUMABLE_CHANGES}
        diffs += [f"agent.{k}" for k in sorted(set(old_agent) | set(new_agent))
                  if not json_equal(old_agent.get(k), new_agent.get(k))]
        return diffs

    CONFIG_KEYS = ("format", "env_id", "env_kwargs", "task", "seed", "agent", "dims",
                   "env_backend", "update_graph")
    """Keys of the spec that each checkpoint carries as its ``config``: what it was trained
    with, compared with the command's on resume."""

    def _mismatch(self, where: Any, old: dict[str, Any], new: dict[str, Any]) -> None:
        """Raise ValueError if ``new`` may not continue the run ``old`` (a spec or config)."""
        # a spec records env_backend only when it is not the default; name the default too
        old, new = ({"env_backend": ENV_BACKENDS[0], "update_graph": "off", **x}
                    for x in (old, new))
        diffs = self._differences(old, new)
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

    def _open(self, resume: bool) -> None:
        """Check the run folders against the command, pick the checkpoint, then write."""
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
            self._open_locked(resume)
        except BaseException:
            for f, new in zip(self.folders, made, strict=True):
                if f in locked:
                    f.unlock()
                    if new:  # a refused start leaves no folder behind
                        with contextlib.suppress(OSError):
                            f.path.rmdir()
            raise
        self._locked = locked

    def _open_locked(self, resume: bool) -> None:
        """`_open` once this process holds every folder's lock."""
        olds: list[dict[str, Any] | None] = []
        for f, spec in zip(self.folders, self.specs, strict=True):
            old = f.read_spec() if f.spec_path.exists() else None
            if old is not None:
                self._mismatch(f.path, old, spec)
            olds.append(old)
        episode, states, chunks = self._readable_checkpoint()
        if episode is None:
            for f, old in zip(self.folders, olds, strict=True):
                if old is not None:
                    _refuse_lost_checkpoints(f)
        for f, spec, old in zip(self.folders, self.specs, olds, strict=True):
            # temporary files of writes that a kill interrupted; only now that this process
            # has the folder's run (a refused start touches nothing)
            f.clean()
            if old is not None:
                for key in self.RESUMABLE_CHANGES:
                    old["agent"][key] = spec["agent"][key]
                f.write_spec(old)
            else:
                f.write_spec(spec)
                f.write_eval([])
        if episode is None:
            for f in self.folders:
                f.prune(upto=0, keep_from=0)
            return
        self._restore(episode, states, chunks)

    def _readable_checkpoint(self) -> tuple[int | None, list[dict[str, Any]],
                                            list[list[tuple[int, Any]]]]:
        """The latest common checkpoint that every folder can read, with its buffer chunks.

        A checkpoint or chunk that cannot be read (truncated, empty) makes the run fall back to
        the older kept checkpoint, with a warning naming the file; a checkpoint trained with
        another configuration is an error.
        """
        have = [set(f.checkpoints()) for f in self.folders]
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
                        self._mismatch(f.checkpoints()[episode], state["config"], spec)
                chunks = [f.chunks(upto=episode) for f in self.folders]
                for f, state, rows in zip(self.folders, states, chunks, strict=True):
                    _check_coverage(f.path / "buffer", episode, rows, int(state["buffer_total"]),
                                    self.config.buffer_size)
            except RunFolderError as err:
                if i + 1 == len(candidates):
                    raise
                warnings.warn(f"{err}; resuming from the older checkpoint of episode "
                              f"{candidates[i + 1]} instead", stacklevel=3)
                continue
            return episode, states, chunks
        raise AssertionError("unreachable")

    def _restore(self, episode: int, states: list[dict[str, Any]],
                 chunks: list[list[tuple[int, Any]]]) -> None:
        self.agent.load_agent_states([s["agent"] for s in states])
        for k, (f, s) in enumerate(zip(self.folders, states, strict=True)):
            self.rngs[k].bit_generator.state = s["rng"]["explore"]
            self.sample_generators[k].set_state(s["rng"]["sample"])
            if self.update_step is not None:
                self.update_step.load_state(s["rng"]["sample_counter"])
            if "explore_torch" in s["rng"]:
                self.explore_generators[k].set_state(s["rng"]["explore_torch"])
            for start, rows in chunks[k]:
                self.buffer.put(k, start, rows)
            if self.buffer.total[k] != s["buffer_total"]:
                raise RuntimeError(f"{f.path}: the buffer chunks hold {self.buffer.total[k]} "
                                   f"transitions, the checkpoint expects {s['buffer_total']}")
            self.env_steps[k] = s["env_steps"]
            self.rows[k] = list(s["rows"])
            # only the abandoned future: the older checkpoint kept beside this one needs the
            # chunks before this one's window, should this one be found corrupt later (the
            # next save prunes them, when it deletes that older checkpoint)
            f.prune(upto=episode, keep_from=0)
            f.write_eval(self.rows[k])
        self.episode = episode
        self.wall_s = float(states[0]["wall_s"])
        self._saved_total = self.buffer.total.copy()
        self._kept_totals = [self._saved_total]

    def _save(self) -> None:
        """Buffer chunk, then checkpoint, then eval.csv, for every run folder."""
        self._kept_totals = [*self._kept_totals[-1:], self.buffer.total.copy()]
        for k, f in enumerate(self.folders):
            start, rows = self.buffer.since(k, int(self._saved_total[k]))
            f.save_chunk(self.episode, start, rows)
            f.save_checkpoint(self.episode, {
                "episode": self.episode,
                "config": {key: self.specs[k][key] for key in self.CONFIG_KEYS
                           if key in self.specs[k]},
                "env_steps": int(self.env_steps[k]),
                "wall_s": self.wall_s,
                "rows": self.rows[k],
                "buffer_total": int(self.buffer.total[k]),
                "agent": self.agent.agent_state(k),
                "rng": {"explore": self.rngs[k].bit_generator.state,
                        "sample": self.sample_generators[k].get_state(),
                        **({"explore_torch": self.explore_generators[k].get_state()}
                           if self.env_backend == "torch" else {}),
                        **({"sample_counter": self.update_step.state()}
                           if self.update_step is not None else {})},
            })
            f.write_eval(self.rows[k])
            oldest = int(self._kept_totals[0][k]) - self.config.buffer_size
            f.prune(upto=self.episode, keep_from=oldest)
        self._saved_total = self.buffer.total.copy()

    # --- the protocol ---------------------------------------------------------------------------
    def _inputs(self, obs: dict[str, np.ndarray], m: int) -> torch.Tensor:
        """Env observations of K * m copies (agent-major) -> network input (K, m, in_dim)."""
        x = goal_input(obs["observation"], obs["achieved_goal"], obs["desired_goal"])
        return torch.from_numpy(x.reshape(self.k, m, -1)).to(self.device, self.buffer.rows.dtype)

    def _tensor_inputs(self, obs: dict[str, torch.Tensor], m: int) -> torch.Tensor:
        """`_inputs` of device tensors, rounded through float32 as `goal_input` rounds."""
        ag, dg = obs["achieved_goal"], obs["desired_goal"]
        x = torch.cat([obs["observation"], dg - ag, dg], -1).to(torch.float32)
        return x.reshape(self.k, m, -1).to(self.buffer.rows.dtype)

    def _to_env(self, u: torch.Tensor) -> torch.Tensor:
        """`ActionScale.to_env` on float64 tensors (the same operations)."""
        low, high = (torch.as_tensor(v, device=u.device) for v in (self.scale.low,
                                                                   self.scale.high))
        return low + (u + 1.0) * 0.5 * (high - low)

    def _train_episode_torch(self) -> np.ndarray:
        """`train_episode` of the torch env backend. The host reads, per episode, the K
        episode lengths and successes (logged), the lengths of the HER copies and the
        normalizer's sums; transitions never leave the device."""
        warm = self.episode < self.config.warmup_episodes
        explorer = self.torch_explorer
        explorer.reset()

        def policy(obs):
            u = torch.zeros((self.k, self.scale.dim), dtype=torch.float64,
                            device=self.device) if warm else \
                self.agent.act(self._tensor_inputs(obs, 1), explore=True)[:, 0].double()
            return self._to_env(explorer(u, uniform=warm))

        seeds = [stream_seed(s, _TRAIN_ENV, self.episode) for s in self.seeds]
        eps = torch_rollout(self.envs, policy, seeds)
        flags = torch.stack([eps.length, eps.success.long()]).cpu().numpy()
        length, success = flags[0], flags[1].astype(bool)
        steps = [her_goal_steps(self.config.her_strategy, int(length[k]), self.config.her_k,
                                self.rngs[k]) for k in range(self.k)]
        owner = np.concatenate([np.full(len(g), k) for k, g in enumerate(steps)]).astype(int)
        rows = [pack_tensors(eps.observation[k], eps.achieved_goal[k], eps.desired_goal[k],
                             eps.action[k], eps.reward[k], eps.terminated[k],
                             self.scale)[:length[k]] for k in range(self.k)]
        copies: list[list[torch.Tensor]] = [[] for _ in range(self.k)]
        if len(owner):
            # one relabelling call per group, its reward being the group's task
            goal_steps = np.concatenate(steps)
            her_len = torch.zeros(len(owner), dtype=torch.long, device=self.device)
            her = []
            for k in range(self.k):
                sel = np.flatnonzero(owner == k)
                if len(sel):
                    out = her_tensors(eps, owner[sel], goal_steps[sel],
                                      functools.partial(self.envs.reward_fn, group=k),
                                      functools.partial(self.envs.terminated_fn, group=k))
                    her_len[torch.as_tensor(sel, device=self.device)] = out[3]
                    her.append((k, sel, out))
            her_len_host = her_len.cpu().numpy()
            for k, sel, (goal, reward, terminated, _) in her:
                idx = torch.as_tensor(owner[sel], device=self.device)
                packed = pack_tensors(eps.observation[idx], eps.achieved_goal[idx], goal,
                                      eps.action[idx], reward, terminated, self.scale)
                copies[k] += [p[:her_len_host[c]] for p, c in zip(packed, sel, strict=True)]
        for k in range(self.k):
            all_rows = torch.cat([rows[k], *copies[k]])
            self.buffer.put_tensor(k, int(self.buffer.total[k]), all_rows)
            self.agent.normalizer.update(k, all_rows[:, :self.layout.in_dim])
            self.env_steps[k] += int(length[k])
        return success

    def _check_finite(self, losses: torch.Tensor) -> None:
        """Raise `Diverged` when an agent's mean losses (2, K) of this episode's updates are
        not finite: its networks hold inf or NaN, and every later action and eval row would
        be NaN. Before the episode's checkpoint, so the last one written is still finite."""
        finite = torch.isfinite(losses).all(0).cpu().numpy()
        if finite.all():
            return
        bad = np.flatnonzero(~finite)
        values = losses.cpu().numpy()
        raise Diverged(
            "the networks diverged (a loss is not finite) in training episode "
            f"{self.episode + 1}: "
            + "; ".join(f"seed {self.seeds[k]} ({self.folders[k].path}): critic loss "
                        f"{values[0, k]:.3g}, actor loss {values[1, k]:.3g}" for k in bad)
            + f". The last checkpoint written is from before; lower --critic-lr "
            f"({self.config.critic_lr:g}) or --actor-lr ({self.config.actor_lr:g}), or check "
            "the task's reward scale")

    def train_episode(self) -> np.ndarray:
        """One exploring episode per agent, stored with its HER copies; returns successes (K,)."""
        if self.env_backend == "torch":
            return self._train_episode_torch()
        warm = self.episode < self.config.warmup_episodes
        self.explorer.reset()

        def policy(obs, active):
            u = np.zeros((self.k, self.scale.dim)) if warm else \
                self.agent.act(self._inputs(obs, 1), explore=True)[:, 0].double().cpu().numpy()
            return self.scale.to_env(self.explorer(u, active, uniform=warm))

        seeds = [stream_seed(s, _TRAIN_ENV, self.episode) for s in self.seeds]
        episodes, success = rollout(self.envs, policy, seeds)
        for k, ep in enumerate(episodes):
            goals = her_goal_steps(self.config.her_strategy, len(ep), self.config.her_k,
                                   self.rngs[k])
            copies = [relabel(ep, int(j), functools.partial(self.envs.reward_fn, group=k),
                              functools.partial(self.envs.terminated_fn, group=k))
                      for j in goals]
            rows = np.concatenate([pack(e, self.scale) for e in [ep, *copies]])
            self.buffer.add(k, rows)
            self.agent.normalizer.update(k, rows[:, :self.layout.in_dim])
            self.env_steps[k] += len(ep)
        return success

    def learn(self, updates: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``updates`` steps of every agent (its --algo); mean critic and actor losses (K,)."""
        if self.update_step is not None:
            return self.update_step.run(updates)
        losses = torch.zeros(2, self.k, dtype=torch.float64, device=self.device)
        updates //= self.config.ensemble  # each steps all M members: the M share the budget
        for _ in range(updates):
            batch = self.buffer.sample(self.config.batch_size, self.sample_generators)
            critic_loss, actor_loss = self.agent.update(*batch)
            losses[0] += critic_loss
            losses[1] += actor_loss
        return losses / max(updates, 1)

    def evaluate(self) -> list[dict[str, Any]]:
        """A test session: ``eval_episodes`` deterministic episodes per agent, run in parallel.

        The goals of session i come from (seed, i) alone. Returns one eval row per agent,
        without its ``wall_s``.
        """
        m = self.config.eval_episodes
        session = self.episode // self.config.eval_every
        if self.env_backend == "torch":
            return self._evaluate_torch(m, session)

        def policy(obs, active):
            u = self.agent.act(self._inputs(obs, m)).reshape(self.k * m, -1)
            return self.scale.to_env(u.double().cpu().numpy())

        seeds = [stream_seed(s, EVAL_ENV_STREAM, session, i) for s in self.seeds for i in range(m)]
        episodes, success = rollout(self.eval_envs, policy, seeds)
        rows = []
        for k in range(self.k):
            eps = episodes[k * m:(k + 1) * m]
            rows.append({
                "episode": self.episode,
                "successes": int(success[k * m:(k + 1) * m].sum()),
                "tests": m,
                "mean_return": round(float(np.mean([e.reward.sum() for e in eps])), 6),
                "mean_final_distance_m": round(float(np.mean(
                    [np.linalg.norm(e.achieved_goal[-1] - e.desired_goal) for e in eps])), 6),
                "env_steps": int(self.env_steps[k]),
            })
        return rows

    def _evaluate_torch(self, m: int, session: int) -> list[dict[str, Any]]:
        """`evaluate` of the torch env backend; reads back only the logged numbers."""
        def policy(obs):
            u = self.agent.act(self._tensor_inputs(obs, m)).reshape(self.k * m, -1)
            return self._to_env(u.double())

        seeds = [stream_seed(s, EVAL_ENV_STREAM, session, i) for s in self.seeds for i in range(m)]
        eps: TensorEpisodes = torch_rollout(self.eval_envs, policy, seeds)
        n = torch.arange(len(eps.length), device=self.device)
        final = eps.achieved_goal[n, eps.length]
        logged = torch.stack([eps.success.double(), eps.reward.sum(-1),
                              torch.linalg.vector_norm(final - eps.desired_goal, dim=-1)])
        success, returns, distance = logged.cpu().numpy()
        rows = []
        for k in range(self.k):
            sl = slice(k * m, (k + 1) * m)
            rows.append({
                "episode": self.episode,
                "successes": int(success[sl].sum()),
                "tests": m,
                "mean_return": round(float(np.mean(returns[sl])), 6),
                "mean_final_distance_m": round(float(np.mean(distance[sl])), 6),
                "env_steps": int(self.env_steps[k]),
            })
        return rows

    @property
    def done(self) -> bool:
        """Whether the agents have trained ``config.episodes`` episodes."""
        return self.episode >= self.config.episodes

    def start(self) -> None:
        """Open the TensorBoard logs and start the clock; before the first `step`."""
        self._log = _Interval(self.k, self.device,
                              [_tb_writer(f.path, self.episode) if self.tensorboard else None
                               for f in self.folders])
        self._tick = time.perf_counter()

    def step(self) -> None:
        """One training episode and its updates; then, every ``eval_every`` episodes, a test
        session and a checkpoint (and one at the last episode).

        ``wall_s`` counts the clock since `start`, including the time that other trainers of
        the process (`ddpg_her.multi`) spend between two steps of this one.
        """
        cfg, log = self.config, self._log
        if log is None:
            raise RuntimeError("call start() before step()")
        self._flush_denormals()
        log.successes += self.train_episode()
        if self.episode >= cfg.warmup_episodes and cfg.updates_per_episode > 0:
            losses = self.learn(cfg.updates_per_episode)
            self._check_finite(losses)
            log.losses += losses
            log.updates += cfg.updates_per_episode
            log.learning += 1
        self.episode += 1
        log.episodes += 1
        if self.episode % cfg.eval_every == 0:
            new_rows = self.evaluate()
            now = time.perf_counter()
            self.wall_s += now - self._tick
            self._tick = now
            for rows, row in zip(self.rows, new_rows, strict=True):
                rows.append({**row, "wall_s": round(self.wall_s, 2)})
            log.write(self.rows, self.episode)
            self._save()
        elif self.episode == cfg.episodes:
            self._save()
        now = time.perf_counter()
        self.wall_s += now - self._tick
        self._tick = now

    def finish(self) -> None:
        """Close the TensorBoard logs; after the last `step`."""
        if self._log is not None:
            self._log.close()
            self._log = None

    def run(self) -> list[list[dict[str, Any]]]:
        """Train to ``config.episodes``; returns every agent's eval rows."""
        bar = _progress(self.progress, self.config.episodes, self.episode, self.k)
        self.start()
        try:
            while not self.done:
                self.step()
                if bar is not None:
                    bar.set_postfix_str(_postfix(bar, self.rows), refresh=False)
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
            self.finish()
        return self.rows

    def close(self) -> None:
        """Close the envs and release the run folders' locks."""
        self.envs.close()
        self.eval_envs.close()
        for f in self._locked:
            f.unlock()
        self._locked = []


def _refuse_lost_checkpoints(f: RunFolder) -> None:
    """Raise ValueError when the run in ``f`` has finished work (test sessions, buffer chunks)
    but no checkpoint: resuming would train it again from episode 0 over its eval.csv. A run
    killed before its first checkpoint has none of either and starts afresh."""
    sessions = len(f.read_eval())
    chunks = sorted(p.name for p in (f.path / "buffer").glob("episode-*.npz"))
    if sessions or chunks:
        raise ValueError(
            f"{f.path} holds a run with {sessions} test session(s) in eval.csv"
            + (f" and {len(chunks)} buffer chunk(s)" if chunks else "")
            + f" but no checkpoint in {f.path / 'checkpoints'} (deleted or moved?); --resume "
            "would start it again from episode 0. Restore the checkpoints, or move the folder "
            "away (or choose another --out) to train the run anew")


def _check_recorded(env_id: str, given: dict[str, Any], task: dict[str, Any]) -> None:
    """Raise ValueError unless every task field in ``given`` (the env's keyword arguments) is
    the value the env's task holds, which ``spec.json`` records and every tool rebuilds the
    task from. A given None asks the task for its derived value (e.g. ``start_q``)."""
    wrong = [f"{key}={value!r} (the task holds {task[key]!r})" for key, value in given.items()
             if key in task and value is not None and _plain(value) != _plain(task[key])]
    if wrong:
        raise ValueError(f"{env_id} did not take the task field(s) given: {', '.join(wrong)}; "
                         "the run would train one task and record another")


def _plain(x: Any) -> Any:
    """``x`` as JSON holds it, numbers as floats: 1 and 1.0 are one value, (1, 2) and [1, 2]."""
    if isinstance(x, bool) or x is None or isinstance(x, str):
        return x
    if isinstance(x, (int, float, np.integer, np.floating)):
        return float(x)
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_plain(v) for v in x]
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


def json_equal(a: Any, b: Any) -> bool:
    """Equality of two values as JSON would store them (tuples are lists)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def lookup(d: dict[str, Any], dotted: str) -> Any:
    for part in dotted.split("."):
        d = d.get(part) if isinstance(d, dict) else None
    return d


def _progress(enabled: bool, total: int, initial: int, k: int):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="ep", dynamic_ncols=True,
                desc=f"train {k} agent{'s' if k > 1 else ''}")


def _postfix(bar, rows: list[list[dict[str, Any]]]) -> str:
    """Latest success counts and the projected finish (clock time)."""
    text = "hits " + ("/".join(str(r[-1]["successes"]) for r in rows)
                      + f" of {rows[0][-1]['tests']}" if rows[0] else "-")
    rate = bar.format_dict.get("rate")
    if rate:
        left = (bar.total - bar.n - 1) / rate
        finish = datetime.datetime.now() + datetime.timedelta(seconds=left)
        text += f", done ~{finish:%a %H:%M}"
    return text


def _tb_writer(path: Path, episode: int):
    """A TensorBoard writer in ``path/tb``, or None when tensorboard is not installed."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        return None
    return SummaryWriter(str(path / "tb"), purge_step=episode + 1)


class _Interval:
    """Training statistics between two test sessions, written to TensorBoard at each."""

    def __init__(self, k: int, device: torch.device, writers: list):
        self.k, self.writers = k, writers
        self.losses = torch.zeros(2, k, dtype=torch.float64, device=device)
        self.successes = np.zeros(k)
        self.updates = self.episodes = self.learning = 0
        self.start = time.perf_counter()

    def write(self, rows: list[list[dict[str, Any]]], episode: int) -> None:
        seconds = time.perf_counter() - self.start
        episodes = max(self.episodes, 1)
        losses = (self.losses / max(self.learning, 1)).cpu().numpy()
        stats = {
            "train/critic_loss": losses[0],
            "train/actor_loss": losses[1],
            "train/success_rate": self.successes / episodes,
            "perf/agent_updates_per_wall_s": np.full(self.k, self.k * self.updates / seconds),
        }
        for k, w in enumerate(self.writers):
            if w is None:
                continue
            row = rows[k][-1]
            w.add_scalar("eval/success_rate", row["successes"] / row["tests"], episode)
            w.add_scalar("eval/mean_return", row["mean_return"], episode)
            w.add_scalar("eval/mean_final_distance_m", row["mean_final_distance_m"], episode)
            for name, v in stats.items():
                if math.isfinite(float(v[k])):
                    w.add_scalar(name, float(v[k]), episode)
            w.flush()
        self.losses.zero_()
        self.successes[:] = 0
        self.updates = self.episodes = self.learning = 0
        self.start = time.perf_counter()

    def close(self) -> None:
        for w in self.writers:
            if w is not None:
                w.close()
