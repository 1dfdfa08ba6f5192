"""Per-agent replay buffers and Hindsight Experience Replay relabelling.

HER is done once per episode, as the paper describes: after each episode its transitions go into
the buffer together with relabelled copies whose goal is an achieved goal of the episode, with
rewards recomputed by the env's own ``compute_reward``. Every copy ends at its first relabelled
success, as a real episode ends at its first success.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ddpg_her.config import HERStrategy
from ddpg_her.spaces import ActionScale, goal_input

GoalFn = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""``f(achieved_goal (L, goal_dim), desired_goal (L, goal_dim), action (L, act_dim)) -> (L,)``:
the env's reward or its termination test for L transitions, the action in env units."""


@dataclass
class TensorEpisodes:
    """N episodes of at most T steps as float64 tensors on one device, padded to T.

    observation : (N, T + 1, obs_dim), achieved_goal : (N, T + 1, goal_dim),
    desired_goal : (N, goal_dim), action : (N, T, act_dim), reward : (N, T), terminated :
    (N, T) bool (True only on a last step that ended in success; a time-limit truncation is not
    termination, so it keeps bootstrapping), length : (N,) long (episode i is the first
    ``length[i]`` steps; the rest is padding), success : (N,) bool. Everything in env units;
    row t of observation and achieved_goal is the state before action t.
    """

    observation: torch.Tensor
    achieved_goal: torch.Tensor
    desired_goal: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    terminated: torch.Tensor
    length: torch.Tensor
    success: torch.Tensor


def her_goal_steps(strategy: HERStrategy, length: int, her_k: int,
                   rng: np.random.Generator) -> np.ndarray:
    """Which achieved goals the relabelled copies pursue: indices into ``achieved_goal``, 1..L.

    final: ``[L]``; future: ``her_k`` indices uniform in 1..L (the config's ``her_k``, not the
    agent index k of this module); none: empty.
    """
    if strategy is HERStrategy.FINAL:
        return np.array([length])
    if strategy is HERStrategy.FUTURE:
        return rng.integers(1, length + 1, size=her_k)
    return np.zeros(0, dtype=int)


@dataclass(frozen=True)
class Layout:
    """Columns of one packed transition row: ``[x, u, r, x2, terminated]``.

    x, x2 : network inputs before and after the step (see `goal_input`), u : action in actor
    units, r : reward, terminated : 1.0 where the episode ended in success (no bootstrapping).
    """

    in_dim: int
    act_dim: int

    @property
    def width(self) -> int:
        return 2 * self.in_dim + self.act_dim + 2

    def split(self, rows: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """rows : (..., width) -> x, u, r, x2, terminated with shapes (..., in_dim),
        (..., act_dim), (..., 1), (..., in_dim), (..., 1)."""
        i, a = self.in_dim, self.act_dim
        return (rows[..., :i], rows[..., i:i + a], rows[..., i + a:i + a + 1],
                rows[..., i + a + 1:2 * i + a + 1], rows[..., 2 * i + a + 1:])


def pack_tensors(observation: torch.Tensor, achieved_goal: torch.Tensor,
                 desired_goal: torch.Tensor, action: torch.Tensor, reward: torch.Tensor,
                 terminated: torch.Tensor, scale: ActionScale) -> torch.Tensor:
    """Transitions as packed rows: the inputs (`goal_input`) and actions (`ActionScale.to_actor`)
    computed in float64 and rounded to float32.

    observation : (..., L + 1, obs_dim), achieved_goal : (..., L + 1, goal_dim), desired_goal
    : (..., goal_dim), action : (..., L, act_dim) env units, reward : (..., L), terminated :
    (..., L) bool -> (..., L, width) float32 rows on their device.
    """
    x = goal_input(observation, achieved_goal, desired_goal.unsqueeze(-2))
    u = scale.to_actor(action)
    return torch.cat([x[..., :-1, :], u.to(torch.float32), reward.unsqueeze(-1).to(torch.float32),
                      x[..., 1:, :], terminated.unsqueeze(-1).to(torch.float32)], -1)


def her_tensors(eps: TensorEpisodes, copies: np.ndarray, goal_steps: np.ndarray,
                reward_fn: GoalFn, terminated_fn: GoalFn
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """HER copies of many episodes at once, on their device: copy c of episode ``copies[c]``
    pursues its achieved goal at ``goal_steps[c]`` (1..length), with the reward and the
    termination (a success) of reaching each step's achieved goal; the achieved goal at
    ``goal_steps[c]`` is hit exactly by step ``goal_steps[c] - 1``, so with termination at
    success the copy ends there or earlier.

    ``reward_fn`` and ``terminated_fn`` take tensors (..., goal_dim), (..., goal_dim),
    (..., act_dim) -> (...). Returns the copies' goals (C, goal_dim), rewards (C, T) and
    terminations (C, T), and their lengths (C,) long (cut at the first termination, else the
    episode's length), all on the device; rows past a copy's length are padding.
    """
    dev = eps.action.device
    idx = torch.as_tensor(copies, dtype=torch.long, device=dev)
    step = torch.as_tensor(goal_steps, dtype=torch.long, device=dev)
    ag = eps.achieved_goal[idx]
    goal = ag[torch.arange(len(idx), device=dev), step]
    goals = goal.unsqueeze(1).expand_as(ag[:, 1:])
    action = eps.action[idx]
    t = torch.arange(action.shape[1], device=dev)
    inside = t < eps.length[idx].unsqueeze(-1)
    terminated = torch.as_tensor(terminated_fn(ag[:, 1:], goals, action), device=dev) & inside
    first = torch.where(terminated, t, action.shape[1]).amin(-1) + 1
    length = torch.minimum(first, eps.length[idx])
    reward = reward_fn(ag[:, 1:], goals, action)
    return goal, reward, terminated & (t < length.unsqueeze(-1)), length


class ReplayBuffer:
    """K ring buffers of packed transitions, one per agent, preallocated on the device.

    Transition number t (counted from the start of training) of agent k lives in row
    ``t % capacity``; once full the oldest is overwritten. Sampling is uniform over the stored
    rows, agent k drawing its indices from its own generator.
    """

    def __init__(self, k: int, capacity: int, layout: Layout, *, dtype: torch.dtype, device):
        self.k, self.capacity, self.layout = k, capacity, layout
        self.rows = torch.empty(k, capacity, layout.width, dtype=dtype, device=device)
        self.total = np.zeros(k, dtype=np.int64)
        self.filled = torch.zeros(k, dtype=torch.int64, device=device)
        """(K,) rows stored per agent, ``min(total, capacity)``, on the device: what
        `CounterSampler` reads, so a captured update sees each episode's new rows without a
        host value baked into it."""
        self._agents = torch.arange(k, device=device)[:, None]

    def size(self, k: int) -> int:
        return int(min(self.total[k], self.capacity))

    def put(self, k: int, start: int, rows: np.ndarray | torch.Tensor) -> None:
        """Write ``rows : (L, width)`` (an array, or a tensor on any device) as agent k's
        transitions ``start .. start + L - 1``; the positions are computed on the buffer's
        device."""
        if len(rows) > self.capacity:  # only the last `capacity` would survive
            start += len(rows) - self.capacity
            rows = rows[-self.capacity:]
        pos = (start + torch.arange(len(rows), device=self.rows.device)) % self.capacity
        self.rows[k, pos] = torch.as_tensor(rows).to(self.rows)
        self.total[k] = max(self.total[k], start + len(rows))
        self.filled[k] = self.size(k)

    def add(self, k: int, rows: np.ndarray) -> None:
        """Append ``rows : (L, width)`` to agent k's buffer."""
        self.put(k, int(self.total[k]), rows)

    def since(self, k: int, start: int) -> tuple[int, np.ndarray]:
        """Agent k's transitions from number ``start`` on that are still stored:
        (first number, rows (n, width))."""
        first = max(start, int(self.total[k]) - self.capacity)
        pos = (first + np.arange(int(self.total[k]) - first)) % self.capacity
        return first, self.rows[k, torch.from_numpy(pos).to(self.rows.device)].cpu().numpy()

    def sample(self, batch_size: int,
               generators: Sequence[torch.Generator]) -> tuple[torch.Tensor, ...]:
        """Uniform minibatches for all agents: x, u, r, x2, terminated, each (K, batch, ...)."""
        idx = torch.stack([
            torch.randint(self.size(k), (batch_size,), generator=g, device=self.rows.device)
            for k, g in enumerate(generators)
        ])
        return self.layout.split(self.rows[self._agents, idx])


class PrioritizedBuffer(ReplayBuffer):
    """`ReplayBuffer` with proportional prioritised replay (Schaul et al. 2016; the fields
    ``prioritized_replay``, ``per_*`` of `AgentConfig` say every choice).

    ``priority`` : (K, capacity) float64 on the device, p_i^alpha of each stored row (0 where
    none is stored). Sampling is exact: the cumulative sum of the stored priorities, searched
    with one uniform draw per index from the agent's own generator (O(N) per minibatch where
    a sum tree is O(log N); at this project's buffers of <= 1e6 rows it is one pass).
    """

    def __init__(self, k: int, capacity: int, layout: Layout, *, alpha: float, eps: float,
                 dtype: torch.dtype, device):
        super().__init__(k, capacity, layout, dtype=dtype, device=device)
        self.alpha, self.eps = alpha, eps
        self.priority = torch.zeros(k, capacity, dtype=torch.float64, device=device)

    def put(self, k: int, start: int, rows: np.ndarray | torch.Tensor) -> None:
        """`ReplayBuffer.put`; the new rows get the largest stored p^alpha (1 when empty)."""
        top = self.priority[k, :self.size(k)].max() if self.size(k) else 1.0
        super().put(k, start, rows)
        n = min(len(rows), self.capacity)
        pos = (int(self.total[k]) - n + torch.arange(n, device=self.rows.device)) % self.capacity
        self.priority[k, pos] = top

    def sample_prioritized(self, batch_size: int, generators: Sequence[torch.Generator],
                           beta: float) -> tuple[torch.Tensor, ...]:
        """Minibatches drawn with P(i) = p_i^alpha / sum p^alpha: x, u, r, x2, terminated
        (K, batch, ...) as `ReplayBuffer.sample`, then the row indices (K, batch) and the
        importance weights w_i = (P(i) / min_j P(j))^-beta (K, batch, 1) in (0, 1]."""
        sizes = [self.size(k) for k in range(self.k)]
        cdf = self.priority[:, :max(sizes)].cumsum(1)
        last = torch.as_tensor(sizes, device=cdf.device) - 1
        u = torch.stack([torch.rand(batch_size, generator=g, dtype=torch.float64,
                                    device=cdf.device) for g in generators])
        u = u * cdf[self._agents[:, 0], last][:, None]
        idx = torch.minimum(torch.searchsorted(cdf, u, right=True), last[:, None])
        least = torch.stack([self.priority[k, :n].amin() for k, n in enumerate(sizes)])
        w = (self.priority[self._agents, idx] / least[:, None]).pow(-beta)
        return (*self.layout.split(self.rows[self._agents, idx]), idx,
                w.to(self.rows.dtype)[..., None])

    def update_priorities(self, idx: torch.Tensor, td_error: torch.Tensor) -> None:
        """p_i <- |td_error| + eps for the rows idx (K, batch) of the last minibatch; a row
        drawn twice keeps the larger (an order-free rule, so the result is deterministic)."""
        p = (td_error.detach().abs().to(torch.float64) + self.eps).pow(self.alpha)
        self.priority.scatter_reduce_(1, idx, p, "amax", include_self=False)

    def state(self, k: int) -> torch.Tensor:
        """Agent k's stored priorities p^alpha (size(k),), on the CPU, for its checkpoint."""
        return self.priority[k, :self.size(k)].cpu().clone()

    def load_state(self, k: int, priority: torch.Tensor) -> None:
        self.priority[k, :len(priority)] = priority.to(self.priority)


def anneal_beta(beta0: float, episode: int, episodes: int) -> float:
    """Importance-sampling beta for the updates after training episode ``episode`` (0-based):
    linear from ``beta0`` to 1 at the last of ``episodes``."""
    return beta0 + (1.0 - beta0) * min(1.0, (episode + 1) / max(episodes, 1))


MASK32 = 0xFFFFFFFF
"""The low 32 bits: `mix32` keeps every value below 2**32, so a product with a constant below
2**31 stays below 2**63 and no int64 operation overflows (on any device, compiled or not)."""

MIX32_CONSTANTS = (0x21F0AAAD, 0x735A2D97)
"""The multipliers of `mix32` (C. Wellons's "lowbias32" of 2021, shifts 16, 15, 15), both
below 2**31."""


def mix32(x: torch.Tensor | int) -> torch.Tensor | int:
    """A bijective 32-bit integer hash: x ^= x >> 16; x *= c1; x ^= x >> 15; x *= c2;
    x ^= x >> 15, products taken mod 2**32. x : int64 values in [0, 2**32) (a tensor of any
    shape, or a Python int: the tests' reference) -> the same shape and range."""
    c1, c2 = MIX32_CONSTANTS
    x = x ^ (x >> 16)
    x = (x * c1) & MASK32
    x = x ^ (x >> 15)
    x = (x * c2) & MASK32
    return x ^ (x >> 15)


def counter_draws(keys: torch.Tensor | int, counter: torch.Tensor | int,
                  slots: torch.Tensor | int) -> torch.Tensor | int:
    """62 random bits for (key, counter, slot): a counter-based generator (as Philox is, but
    built from `mix32`), so a draw is a pure function of its coordinates, the same on every
    device, and its state is one integer.

    ``h(j) = mix32(mix32(mix32(key) ^ counter) ^ j)`` for j = 2 slot and 2 slot + 1, and the
    draw ``(h(2 slot) >> 2) << 32 | h(2 slot + 1)``, in [0, 2**62). keys, counter : int64 values
    in [0, 2**32) (the counter taken mod 2**32), slots : in [0, 2**31), all broadcasting
    together (or Python ints).
    """
    base = mix32(mix32(keys) ^ (counter & MASK32))
    hi = mix32(base ^ (2 * slots))
    lo = mix32(base ^ (2 * slots + 1))
    return ((hi >> 2) << 32) | lo


class CounterSampler:
    """Uniform replay minibatches drawn on the buffer's device with no host value per draw.

    Agent k's j-th index of update c is ``counter_draws(keys[k], c, j) % filled[k]`` (the
    modulo's bias is below filled / 2**62). ``counter`` is a device tensor that every `sample`
    advances in place, so a CUDA graph replays a fresh minibatch each time, and agent k's
    draws depend on its key and the update count alone (not on K, nor on the device). This is
    the training program's minibatch stream (``ddpg_her.program``); `ReplayBuffer.sample`
    (torch generators, one per agent) stays the trainer's.

    keys : one 32-bit key per agent (``ddpg_her.trainer`` derives them from the seeds).
    """

    def __init__(self, keys: Sequence[int], device: str | torch.device):
        bad = [k for k in keys if not 0 <= int(k) <= MASK32]
        if bad or not keys:
            raise ValueError(f"need one key in [0, 2**32) per agent, got {list(keys)}")
        self.keys = torch.tensor([int(k) for k in keys], dtype=torch.int64,
                                 device=device)[:, None]
        self._mixed_keys = mix32(self.keys)
        self._pairs: dict[int, torch.Tensor] = {}
        self.counter = torch.zeros((), dtype=torch.int64, device=device)
        self.updates = 0
        """The host's count of the draws made, kept equal to ``counter`` by its caller
        (``ddpg_her.program``), so a checkpoint never reads the device."""

    def indices(self, filled: torch.Tensor, batch_size: int, updates: int = 1) -> torch.Tensor:
        """(updates, K, batch_size) int64 row indices, row < filled[k], of the counters
        ``counter .. counter + updates - 1`` (this does not advance it); with ``updates`` 1
        (K, batch_size). filled : (K,) int64 >= 1 on the device.

        `counter_draws` with its two hashes of a slot in one pass over (updates, K, 2
        batch_size) and the keys' first hash kept from the start: one batch of small kernels
        for all the episode's updates (each kernel is a node of a CUDA graph)."""
        j = self._pairs.get(batch_size)
        if j is None:  # 0, 1, ..., 2 batch_size - 1: the hashes' inputs 2 slot and 2 slot + 1
            j = self._pairs[batch_size] = torch.arange(2 * batch_size, dtype=torch.int64,
                                                       device=self.keys.device)
        c = (self.counter + torch.arange(updates, device=self.keys.device)) & MASK32
        h = mix32(mix32(self._mixed_keys ^ c[:, None, None]) ^ j).view(
            updates, len(self.keys), batch_size, 2)
        idx = (((h[..., 0] >> 2) << 32) | h[..., 1]) % filled[:, None]
        return idx[0] if updates == 1 else idx

    def samples(self, buffer: ReplayBuffer, batch_size: int, updates: int
                ) -> list[tuple[torch.Tensor, ...]]:
        """The minibatches of the next ``updates`` `sample` calls, drawn and gathered at once
        (the same rows, bit for bit); advances ``counter`` by ``updates`` on the device."""
        idx = self.indices(buffer.filled, batch_size, updates)
        self.counter.add_(updates)
        rows = buffer.rows[buffer._agents[None], idx.view(updates, -1, batch_size)]
        return [buffer.layout.split(r) for r in rows.unbind(0)]

    def sample(self, buffer: ReplayBuffer, batch_size: int) -> tuple[torch.Tensor, ...]:
        """`ReplayBuffer.sample`'s x, u, r, x2, terminated (K, batch, ...) from this stream;
        advances ``counter`` on the device only (a captured graph replays this without
        Python: whoever replays it adds to ``updates``). Every agent needs a stored row (not
        checked here: that would read the device)."""
        return self.samples(buffer, batch_size, 1)[0]

    def state(self) -> int:
        """The update count, for a checkpoint (the keys come from the seeds)."""
        return self.updates

    def load_state(self, updates: int) -> None:
        self.updates = int(updates)
        self.counter.fill_(self.updates)
