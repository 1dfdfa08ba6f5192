"""The stacked update as one device-resident step (``--update-graph``): a minibatch drawn on the
device, the K agents' update, the loss sums; captured once as a CUDA graph and replayed on CUDA,
run eagerly on the CPU.

Launching an update's small kernels one by one from Python costs far more than their compute
on a GPU (issue 24); a graph replays them as one, on fixed memory, so nothing in the step may be
a host value that changes. What is kept on the device for that: docs/design.md, "Agent".
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ddpg_her.buffer import CounterSampler, ReplayBuffer

MODES = ("auto", "on", "off")
"""``--update-graph``: ``on`` (this module's step), ``off`` (the trainer's own loop of
`ReplayBuffer.sample` and ``agent.update``), ``auto`` (on for CUDA with an algorithm that
supports it, else off)."""

WARMUP_UPDATES = 3
"""Updates run eagerly on a side stream before the capture (real updates, counted as such):
they create Adam's state and let cuBLAS set up its handles, which a capture may not do
(torch.cuda.graph's documented warm-up)."""


def supported(config) -> str | None:
    """Why ``config`` (an `AgentConfig`) cannot take the captured step, or None if it can:
    only the hand-written DDPG update is capturable today (TD3, SAC and batch normalisation
    train through autograd and Python branches)."""
    if config.algo.value != "ddpg":
        return f"--algo {config.algo.value} (only ddpg's update is capturable)"
    if config.batch_norm:
        return "--batch-norm (its update goes through autograd)"
    if config.ensemble > 1:
        return (f"--ensemble {config.ensemble} (its members sample from their own cells of "
                "the buffer)")
    return None


def resolve(mode: str, device: torch.device | str, config) -> bool:
    """Whether ``--update-graph MODE`` takes the captured step on ``device`` for ``config``.

    Raises ValueError for an unknown mode, or for ``on`` with an unsupported config.
    """
    if mode not in MODES:
        raise ValueError(f"--update-graph must be one of {list(MODES)}, got {mode!r}")
    why = supported(config)
    if mode == "auto":
        return torch.device(device).type == "cuda" and why is None
    if mode == "on" and why is not None:
        raise ValueError(f"--update-graph on: not with {why}; use --update-graph off")
    return mode == "on"


class UpdateStep:
    """``updates`` stacked updates per `run`, with minibatches from a `CounterSampler`.

    agent : a `ddpg_her.agent.DDPG` (made `capturable` here); buffer : its `ReplayBuffer`;
    keys : one 32-bit sampler key per agent; graph : capture a CUDA graph (default: on CUDA).
    Call `run` only after every agent has stored a row; build it after any
    ``load_agent_states`` (a graph holds the addresses of the optimiser's state tensors).
    """

    def __init__(self, agent, buffer: ReplayBuffer, keys: Sequence[int], batch_size: int, *,
                 graph: bool | None = None):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.agent, self.buffer, self.batch_size = agent, buffer, batch_size
        self.device = buffer.rows.device
        agent.capturable()
        self.sampler = CounterSampler(keys, self.device)
        self.graph = self.device.type == "cuda" if graph is None else graph
        if self.graph and self.device.type != "cuda":
            raise ValueError(f"a CUDA graph needs a CUDA device, the buffer is on {self.device}")
        self.loss_sum = torch.zeros(2, agent.k, dtype=torch.float64, device=self.device)
        """Critic and actor losses (2, K) summed over the updates of the current `run`."""
        self._cuda_graph: torch.cuda.CUDAGraph | None = None

    def step(self) -> None:
        """One update of every agent: the body a graph captures, and the CPU's whole step.
        Reads and writes device tensors only (no host value, no sync)."""
        batch = self.sampler.sample(self.buffer, self.batch_size)
        critic_loss, actor_loss = self.agent.update(*batch)
        self.loss_sum[0] += critic_loss
        self.loss_sum[1] += actor_loss

    def run(self, updates: int) -> torch.Tensor:
        """``updates`` steps; returns the mean critic and actor losses (2, K) float64 on the
        device (the caller decides when to read them)."""
        if self.buffer.total.min() < 1:
            raise ValueError("every agent needs a stored transition before an update")
        self.loss_sum.zero_()
        todo = updates
        if self.graph and self._cuda_graph is None and todo > WARMUP_UPDATES:
            self._capture()
            todo -= WARMUP_UPDATES
        for _ in range(todo):
            if self._cuda_graph is not None:
                self._cuda_graph.replay()
            else:
                self.step()
        self.sampler.updates += updates
        return self.loss_sum / max(updates, 1)

    def _capture(self) -> None:
        """Warm up with `WARMUP_UPDATES` real updates on a side stream, then capture one."""
        side = torch.cuda.Stream(self.device)
        side.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(side):
            for _ in range(WARMUP_UPDATES):
                self.step()
        torch.cuda.current_stream(self.device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            self.step()
        self._cuda_graph = graph

    def state(self) -> int:
        """The sampler's update count, for a checkpoint."""
        return self.sampler.state()

    def load_state(self, updates: int) -> None:
        self.sampler.load_state(updates)
