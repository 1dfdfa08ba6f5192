"""The host engine of the training loop (`ddpg_her.loop.Loop`: sessions, eval rows,
checkpoints, resume) for K independent agents in one process.

Each agent runs its episodes in its own env copies (all K in lockstep, `ddpg_her.collect`) and
stores them with their HER copies in its own buffer; the K make their updates batched.

The K agents may pursue different tasks of one observation and action layout (``env_kwargs``
per agent: regions, reward readings, contact models); they share the agent configuration.
Agent k's randomness comes from its seed alone (env episodes, initial weights, exploration, HER
goals, minibatches), the same for K = 1 and K > 1; its rounding is not (K's batched products round
otherwise: docs/design.md, "Evaluation and seeds"). A resumed run continues exactly.
`ddpg_her.multi` runs several such trainers (other layouts or configurations) in turn."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ddpg_her.agents import check_memory, make_agent
from ddpg_her.buffer import PrioritizedBuffer, ReplayBuffer, anneal_beta
from ddpg_her.checkpoints import check_recorded, run_spec
from ddpg_her.collect import Collector, make_envs
from ddpg_her.config import AgentConfig
from ddpg_her.ensemble import make_buffer, spec_entry, task_partitions
from ddpg_her.logs import Interval, eval_rows
from ddpg_her.loop import Diverged, Loop, agents_of

# Keys of the independent random streams derived from a seed (numpy SeedSequence spawn keys).
INIT_STREAM, EXPLORE_STREAM, SAMPLE_STREAM, TRAIN_ENV_STREAM, EVAL_ENV_STREAM = range(5)
"""``EVAL_ENV_STREAM``: the key of the test sessions' goals, ``stream_seed(seed,
EVAL_ENV_STREAM, session, i)`` for test episode i of a session (public: other trainers, such
as ``analysis.sb3``, test on the same goals)."""


def stream_seed(seed: int, *key: int) -> int:
    """A 32-bit seed for the random stream ``key`` of the run with ``seed``."""
    return int(np.random.SeedSequence(seed, spawn_key=key).generate_state(1)[0])


class Trainer(Loop):
    """Trains one agent per seed, writing one run folder per seed (see `ddpg_her.run`).

    env_id, env_kwargs : ``gymnasium.make(env_id, **env_kwargs)`` makes the task: one dict for
    all agents, or K dicts, agent k's task made with ``env_kwargs[k]`` (all of one layout);
    seeds : (K,) ints, distinct among agents of one task; run_dirs : K distinct folders;
    resume : continue the runs in ``run_dirs`` from their last common checkpoint (runs absent
    there start afresh) instead of refusing existing folders; env_backend : one of
    `ddpg_her.collect.ENV_BACKENDS` (``ddpg_her.train``'s flag, whose ``--help`` says how each
    changes a seed's run).
    """

    def __init__(self, env_id: str, env_kwargs: dict[str, Any] | Sequence[dict[str, Any]],
                 config: AgentConfig, seeds: Sequence[int], run_dirs: Sequence[str | Path], *,
                 resume: bool = False, device: str = "cpu", dtype: torch.dtype = torch.float32,
                 progress: bool = True, tensorboard: bool = True,
                 command: Sequence[str] | None = None, env_backend: str = "numpy"):
        self.env_backend = env_backend
        per_agent, seeds = agents_of(env_kwargs, seeds, run_dirs)
        self.config, self.seeds, self.k = config, seeds, len(seeds)
        self.device = torch.device(device)
        # Set-up in exact arithmetic: the flush is process-wide and reaches Python's floats
        # (1e-310 > 0 would be False, json.dumps(1e-320) '0.0'; issue 37, kind 5); it starts
        # once the set-up (checks, spec.json) is done, and `_train` sets it again each episode.
        torch.set_flush_denormal(False)
        self.progress, self.tensorboard = progress, tensorboard
        self.env_id, self.env_kwargs = env_id, per_agent
        self.envs = envs = make_envs(env_backend, env_id, per_agent, 1)
        self.eval_envs = make_envs(env_backend, env_id, per_agent, config.eval_episodes)
        for k, kwargs in enumerate(per_agent):
            check_recorded(env_id, kwargs, envs.task_of(k))
        self.rngs = [np.random.default_rng(stream_seed(s, EXPLORE_STREAM)) for s in seeds]
        self.sample_generators = [
            torch.Generator(self.device).manual_seed(stream_seed(s, SAMPLE_STREAM)) for s in seeds]
        self.collector = Collector(self.envs, self.eval_envs, config, self.rngs,
                                   device=self.device, dtype=dtype)
        self.layout = self.collector.layout
        check_memory(config, self.layout, self.k, dtype, self.device)
        self.agent = make_agent(
            config, self.layout.in_dim, self.layout.act_dim, dtype=dtype, device=self.device,
            init_generators=[torch.Generator().manual_seed(stream_seed(s, INIT_STREAM))
                             for s in seeds],
            partitions=task_partitions(env_id, per_agent, config.ensemble)
            if config.ensemble > 1 else None)
        self.buffer: ReplayBuffer = make_buffer(config, self.k, self.layout, self.agent,
                                                dtype=dtype, device=self.device)

        self.env_steps = np.zeros(self.k, dtype=np.int64)
        self.specs = [{**spec_entry(self.agent, k),
                       **run_spec(env_backend=env_backend, env_id=env_id,
                                  env_kwargs=per_agent[k], task=envs.task_of(k), seed=seeds[k],
                                  config=config, dims=envs.dims, command=command)}
                      for k in range(self.k)]
        self._log: Interval | None = None
        self._open(run_dirs, resume)
        self._flush_denormals()

    def _flush_denormals(self) -> None:
        """Set the CPU's subnormal flush to this trainer's config: process-wide in torch, so
        set again before each step where trainers of several configurations share a process."""
        if self.device.type == "cpu":
            torch.set_flush_denormal(self.config.flush_denormals)

    # --- checkpoints (`Loop.state`, `Loop._restore`) ----------------------------------------------
    def _agent_state(self, k: int) -> dict[str, Any]:
        return {"agent": self.agent.agent_state(k),
                "rng": {"explore": self.rngs[k].bit_generator.state,
                        "sample": self.sample_generators[k].get_state()},
                **({"priority": self.buffer.state(k)}
                   if isinstance(self.buffer, PrioritizedBuffer) else {})}

    def _load(self, episode: int, states: list[dict[str, Any]],
              chunks: list[list[tuple[int, Any]]]) -> None:
        self.agent.load_agent_states([s["agent"] for s in states])
        for k, s in enumerate(states):
            self.rngs[k].bit_generator.state = s["rng"]["explore"]
            self.sample_generators[k].set_state(s["rng"]["sample"])
            self.env_steps[k] = s["env_steps"]
        self.folders.restore_buffer(episode, states, chunks, self.buffer)
        for k, s in enumerate(states):
            if isinstance(self.buffer, PrioritizedBuffer):
                self.buffer.load_state(k, s["priority"])

    # --- the engine (`Loop.step` calls these) ---------------------------------------------------
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
            + "; ".join(f"seed {self.seeds[k]} ({self.folders.folders[k].path}): critic loss "
                        f"{values[0, k]:.3g}, actor loss {values[1, k]:.3g}" for k in bad)
            + f". The last checkpoint written is from before; lower --critic-lr "
            f"({self.config.critic_lr:g}) or --actor-lr ({self.config.actor_lr:g}), or check "
            "the task's reward scale")

    def _train(self, warm: bool) -> None:
        if self._log is None:  # TensorBoard from the first step on (`close` closes it)
            self._log = Interval(self.k, self.device, [f.path for f in self.folders.folders],
                                 self.episode, self.tensorboard)
        self._flush_denormals()
        self._log.successes += self.train_episode()
        self._log.episodes += 1

    def _updates(self) -> None:
        updates = self.config.updates_per_episode
        losses = self.learn(updates)
        self._check_finite(losses)
        self._log.losses += losses
        self._log.updates += updates
        self._log.learning += 1

    def _logged(self) -> None:
        self._log.write(self.rows, self.episode)

    def train_episode(self) -> np.ndarray:
        """One exploring episode per agent, stored with its HER copies; returns successes (K,)."""
        seeds = [stream_seed(s, TRAIN_ENV_STREAM, self.episode) for s in self.seeds]
        length, success = self.collector.train_episode(
            self.agent, self.buffer, seeds, warm=self.episode < self.config.warmup_episodes)
        self.env_steps += length
        return success

    def learn(self, updates: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``updates`` steps of every agent (its --algo); mean critic and actor losses (K,)."""
        losses = torch.zeros(2, self.k, dtype=torch.float64, device=self.device)
        updates //= self.config.ensemble  # each steps all M members: the M share the budget
        per = isinstance(self.buffer, PrioritizedBuffer)
        for _ in range(updates):
            if per:  # the critic's TD errors become the drawn rows' priorities
                *batch, idx, w = self.buffer.sample_prioritized(
                    self.config.batch_size, self.sample_generators,
                    anneal_beta(self.config.per_beta, self.episode, self.config.episodes))
                critic_loss, actor_loss = self.agent.update(*batch, weight=w)
                self.buffer.update_priorities(idx, self.agent.td_error)
            else:
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
        seeds = [stream_seed(s, EVAL_ENV_STREAM, session, i) for s in self.seeds for i in range(m)]
        return eval_rows(self.episode, m, self.env_steps,
                         *self.collector.test_session(self.agent, seeds))

    def close(self) -> None:
        """Close the TensorBoard logs and the envs and release the run folders' locks."""
        if self._log is not None:
            self._log.close()
        self.envs.close()
        self.eval_envs.close()
        super().close()
