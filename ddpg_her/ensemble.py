"""The regional ensemble (issue 25; the paper's closing suggestion): per seed, M agents of
``AgentConfig.algo``, each owning one cell of a k-means partition of the task's goals
(`regions.partition`); the desired goal picks the agent, in training and at test.

The rules (routing, replay and HER across cells, budget, normaliser, initial weights,
resume), each chosen once here, and why: docs/design.md, "The regional ensemble".
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from ddpg_her.buffer import Layout, PrioritizedBuffer, ReplayBuffer
from ddpg_her.config import AgentConfig
from regions.partition import KMEANS, KMeansSettings, Partition, fit_partition


def task_goals(env_id: str, env_kwargs: dict[str, Any], n: int, seed: int) -> np.ndarray:
    """``n`` goals (n, goal_dim) of the task's own distribution: the desired goals of ``n``
    resets of ``gymnasium.make(env_id, **env_kwargs)``, reset i seeded from (seed, i)."""
    import gymnasium

    from ddpg_her.vecenv import register_env

    env = gymnasium.make(register_env(env_id), **env_kwargs)
    try:
        seeds = np.random.SeedSequence(seed).generate_state(n)
        return np.array([env.reset(seed=int(s))[0]["desired_goal"] for s in seeds])
    finally:
        env.close()


def task_partitions(env_id: str, env_kwargs: Sequence[dict[str, Any]], cells: int,
                    settings: KMeansSettings = KMEANS) -> list[Partition]:
    """One `Partition` into ``cells`` cells per agent's task (``env_kwargs[k]``); agents of one
    task share it (it is fitted once per distinct task)."""
    fitted: dict[str, Partition] = {}
    out = []
    for kwargs in env_kwargs:
        key = json.dumps(kwargs, sort_keys=True, default=str)
        if key not in fitted:
            goals = task_goals(env_id, kwargs, settings.goals, settings.seed)
            fitted[key] = fit_partition(goals, cells, settings)
        out.append(fitted[key])
    return out


def goal_cells(goals: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    """The cell of each goal, the index of its nearest centre (ties: the lowest), computed in
    float64 as `regions.partition.nearest_cell`.

    goals : (K, n, d); centres : (K, M, d), agent k's goals against agent k's centres
    -> (K, n) long.
    """
    g = goals.to(torch.float64)
    return (g[:, :, None, :] - centres[:, None, :, :]).square().sum(-1).argmin(-1)


class _CellQueue:
    """The transition numbers (ascending) of one seed's buffer that lie in one cell, on the
    buffer's device: a slice ``data[head:tail]`` of a tensor that grows by doubling."""

    def __init__(self, device: torch.device):
        self.data = torch.empty(64, dtype=torch.long, device=device)
        self.head = self.tail = 0

    @property
    def size(self) -> int:
        return self.tail - self.head

    def append(self, numbers: torch.Tensor) -> None:
        n = len(numbers)
        if self.tail + n > len(self.data):
            live = self.data[self.head:self.tail]
            grown = torch.empty(max(2 * len(self.data), 2 * (live.numel() + n)),
                                dtype=torch.long, device=self.data.device)
            grown[:live.numel()] = live
            self.data, self.tail, self.head = grown, live.numel(), 0
        self.data[self.tail:self.tail + n] = numbers
        self.tail += n

    def drop_below(self, first: int) -> None:
        """Forget the numbers < ``first`` (overwritten in the ring buffer)."""
        if self.size and int(self.data[self.head]) < first:
            live = self.data[self.head:self.tail]
            self.head += int(torch.searchsorted(live, torch.tensor(
                [first], device=live.device)).item())


class CellBuffer(ReplayBuffer):
    """`ReplayBuffer` of K seeds whose minibatches go to the K x M members: member (k, c)
    samples uniformly from seed k's stored transitions whose desired goal lies in cell c.

    centres : (K, M, goal_dim) float64 on the buffer's device, seed k's partition.
    `sample` returns minibatches (K * M, batch, ...), member (k, c) at row k * M + c, each
    drawn from seed k's generator (members in turn), so the buffer's state, chunks and
    checkpoints are those of a single agent's buffer.
    """

    def __init__(self, k: int, capacity: int, layout: Layout, centres: torch.Tensor, *,
                 dtype: torch.dtype, device):
        super().__init__(k, capacity, layout, dtype=dtype, device=device)
        self.centres = centres.to(self.rows.device, torch.float64)
        self.m = self.centres.shape[1]
        goal_dim = self.centres.shape[2]
        self._goal = slice(layout.in_dim - goal_dim, layout.in_dim)
        self._queues = [[_CellQueue(self.rows.device) for _ in range(self.m)] for _ in range(k)]
        self._owners = torch.arange(k, device=self.rows.device).repeat_interleave(self.m)[:, None]

    def put(self, k: int, start: int, rows: np.ndarray | torch.Tensor) -> None:
        before = int(self.total[k])
        super().put(k, start, rows)
        self._index(k, before, start, torch.as_tensor(rows))  # a device tensor stays there

    def _index(self, k: int, before: int, start: int, rows: torch.Tensor) -> None:
        """File the rows just written (numbers ``start ..``) under their cells."""
        first = max(0, int(self.total[k]) - self.capacity)
        queues = self._queues[k]
        if start == before:  # appended (training): file the new rows, forget overwritten ones
            rows = rows[-self.capacity:]
            numbers = torch.arange(int(self.total[k]) - len(rows), int(self.total[k]),
                                   device=self.rows.device)
            cells = self.cells(k, rows[:, self._goal].to(self.rows.device))
            for c, q in enumerate(queues):
                q.append(numbers[cells == c])
                q.drop_below(first)
            return
        # written elsewhere (a restore from chunks): file the whole stored window anew
        numbers = torch.arange(first, int(self.total[k]), device=self.rows.device)
        cells = self.cells(k, self.rows[k, numbers % self.capacity, self._goal])
        for c in range(self.m):
            queues[c] = _CellQueue(self.rows.device)
            queues[c].append(numbers[cells == c])

    def cells(self, k: int, goals: torch.Tensor) -> torch.Tensor:
        """Cells (n,) long of seed k's goals (n, goal_dim)."""
        return goal_cells(goals[None], self.centres[k:k + 1])[0]

    def sample(self, batch_size: int,
               generators: Sequence[torch.Generator]) -> tuple[torch.Tensor, ...]:
        """Minibatches x, u, r, x2, terminated of the K x M members, each (K * M, batch, ...)."""
        device = self.rows.device
        idx = []
        for k, g in enumerate(generators):
            for q in self._queues[k]:
                if q.size:
                    pick = torch.randint(q.size, (batch_size,), generator=g, device=device)
                    idx.append(q.data[q.head + pick] % self.capacity)
                else:  # no transition with a goal in this cell yet
                    idx.append(torch.randint(self.size(k), (batch_size,), generator=g,
                                             device=device))
        return self.layout.split(self.rows[self._owners, torch.stack(idx)])


class _RoutedNormalizer:
    """The ensemble's ``normalizer.update(k, x)``: seed k's rows go to the statistics of the
    member whose cell holds each row's desired goal."""

    def __init__(self, ensemble: Ensemble):
        self._ensemble = ensemble

    def update(self, k: int, x: np.ndarray | torch.Tensor) -> None:
        e = self._ensemble
        rows = torch.as_tensor(x)
        cells = goal_cells(rows[None, :, e.goal], e.centres[k:k + 1].to(rows.device))[0]
        for c in range(e.m):
            sel = cells == c
            e.members.normalizer.update(k * e.m + c, x[sel.cpu().numpy()] if isinstance(
                x, np.ndarray) else x[sel])


class Ensemble:
    """K regional ensembles of M members each (K seeds x M cells), behind the interface of
    the stacked agents (`ddpg_her.agent.DDPG`): ``act``, ``update``, ``normalizer.update``,
    ``agent_state(k)``, ``load_agent_states``.

    config : ``config.ensemble`` = M; partitions : K partitions of M cells, seed k's;
    member_class : the algorithm's stacked class (`ddpg_her.agents.ALGORITHMS`);
    init_generators : K CPU generators; member (k, c)'s weights come from a generator seeded
    by the c-th draw from ``init_generators[k]``. ``members`` holds the K x M stacked agents,
    member (k, c) at index k * M + c.
    """

    def __init__(self, config: AgentConfig, in_dim: int, act_dim: int, *,
                 partitions: Sequence[Partition], member_class: type,
                 init_generators: Sequence[torch.Generator], dtype: torch.dtype = torch.float32,
                 device: str | torch.device = "cpu"):
        self.k, self.m = len(init_generators), config.ensemble
        if len(partitions) != self.k or any(p.cells != self.m for p in partitions):
            raise ValueError(f"need {self.k} partitions of {self.m} cells (one per seed), got "
                             f"{[p.cells for p in partitions]}")
        goal_dim = partitions[0].centres.shape[1]
        if 2 * goal_dim > in_dim or any(p.centres.shape[1] != goal_dim for p in partitions):
            raise ValueError(
                f"the partitions' goals must be the last goal_dim of in_dim = {in_dim} inputs; "
                f"got centres of {[p.centres.shape for p in partitions]}")
        self.config, self.in_dim, self.act_dim = config, in_dim, act_dim
        self.device = torch.device(device)
        self.partitions = list(partitions)
        self.centres = torch.stack([torch.as_tensor(p.centres) for p in partitions]).to(
            self.device, torch.float64)
        self.goal = slice(in_dim - goal_dim, in_dim)
        member_generators = [
            torch.Generator().manual_seed(int(torch.randint(0, 2**62, (1,), generator=g)))
            for g in init_generators for _ in range(self.m)]
        self.members = member_class(config, in_dim, act_dim, init_generators=member_generators,
                                    dtype=dtype, device=device)
        self.normalizer = _RoutedNormalizer(self)

    def cells(self, x: torch.Tensor) -> torch.Tensor:
        """The cell (K, n) long of each raw network input x (K, n, in_dim)."""
        return goal_cells(x[..., self.goal], self.centres)

    @torch.no_grad()
    def act(self, x: torch.Tensor, explore: bool = False) -> torch.Tensor:
        """x (K, n, in_dim) raw -> (K, n, act_dim): row i of seed k by the member of its goal's
        cell. Every member computes every row (a stochastic member draws for all of them, so
        its generator advances alike whatever the routing); the routed ones are kept."""
        k, n = x.shape[:2]
        out = self.members.act(x.repeat_interleave(self.m, 0), explore=explore)
        out = out.reshape(k, self.m, n, -1)
        pick = self.cells(x)[:, None, :, None].expand(k, 1, n, out.shape[-1])
        return out.gather(1, pick)[:, 0]

    def update(self, x: torch.Tensor, u: torch.Tensor, r: torch.Tensor, x2: torch.Tensor,
               terminated: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One step of every member on its minibatch (K * M, N, ...) (`CellBuffer.sample`);
        returns each seed's critic and actor losses averaged over its members, (K,) each."""
        critic, actor = self.members.update(x, u, r, x2, terminated)
        return critic.reshape(self.k, self.m).mean(1), actor.reshape(self.k, self.m).mean(1)

    def agent_state(self, k: int) -> dict[str, Any]:
        """Seed k's ensemble: its members' states (cell order) and the partition's centres."""
        return {"ensemble": [self.members.agent_state(k * self.m + c) for c in range(self.m)],
                "centres": self.centres[k].cpu().clone()}

    def load_agent_states(self, states: Sequence[dict[str, Any]]) -> None:
        """Inverse of `agent_state` for all K seeds.

        Raises
        ------
        ValueError
            When a state is not an ensemble of M members, or its partition is not this one
            (the centres are fitted anew from the task; another partition would route the
            goals to members trained on other cells).
        """
        if len(states) != self.k:
            raise ValueError(f"need {self.k} agent states, got {len(states)}")
        for k, s in enumerate(states):
            if len(s.get("ensemble", ())) != self.m:
                raise ValueError(f"agent state {k} is not an ensemble of {self.m} members")
            if not torch.equal(torch.as_tensor(s["centres"]).to(self.centres),
                               self.centres[k]):
                raise ValueError(
                    f"agent state {k} was trained on another partition (centres "
                    f"{torch.as_tensor(s['centres']).tolist()}, now {self.centres[k].tolist()})")
        self.members.load_agent_states([m for s in states for m in s["ensemble"]])


class RoutedPolicy(torch.nn.Module):
    """One seed's ensemble as the deterministic test policy of `ddpg_her.run.load`: raw inputs
    x (1, B, in_dim) -> actions (1, B, act_dim) in actor units, each by the member of its
    goal's cell, normalised by that member's statistics (``load`` gives it no normaliser of
    its own). ``l1`` is the members' first layer (``load`` reads its dtype and device).

    actor : the M members' test policy, stacked; normalizer : their M statistics;
    centres : (M, goal_dim) the partition's.
    """

    def __init__(self, actor: torch.nn.Module, normalizer: Any, centres: torch.Tensor,
                 in_dim: int):
        super().__init__()
        self.actor, self.normalizer, self.l1 = actor, normalizer, actor.l1
        self.centres = centres.to(actor.l1.weight.device, torch.float64)
        self.goal = slice(in_dim - self.centres.shape[1], in_dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        m, b = len(self.centres), x.shape[1]
        out = self.actor(self.normalizer(x.expand(m, -1, -1)))  # (M, B, act_dim)
        cells = goal_cells(x[..., self.goal], self.centres[None])  # (1, B)
        return out.gather(0, cells[..., None].expand(1, b, out.shape[-1]))


def make_buffer(config: AgentConfig, k: int, layout: Layout, agent: Any, *,
                dtype: torch.dtype, device: torch.device) -> ReplayBuffer:
    """The trainer's replay buffer: a `CellBuffer` for an `Ensemble`, else a `ReplayBuffer`."""
    if isinstance(agent, Ensemble):
        return CellBuffer(k, config.buffer_size, layout, agent.centres, dtype=dtype,
                          device=device)
    if config.prioritized_replay:
        return PrioritizedBuffer(k, config.buffer_size, layout, alpha=config.per_alpha,
                                 eps=config.per_eps, dtype=dtype, device=device)
    return ReplayBuffer(k, config.buffer_size, layout, dtype=dtype, device=device)


def spec_entry(agent: Any, k: int) -> dict[str, Any]:
    """What seed k's ``spec.json`` records of the ensemble: ``{"partition": ...}``, or {}."""
    if isinstance(agent, Ensemble):
        return {"partition": agent.partitions[k].to_dict()}
    return {}
