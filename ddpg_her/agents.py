"""The stacked agents by name: ``make_agent`` builds K agents of ``AgentConfig.algo`` (or K
regional ensembles of them, `ddpg_her.ensemble`), and ``check_memory`` refuses a stack (with
its replay buffers) larger than the device's memory.

Apart from `ddpg_her.algos`, which TD3 and SAC import, so that no module imports itself back
through a lazy import.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import torch

from ddpg_her.agent import DDPG
from ddpg_her.buffer import Layout
from ddpg_her.config import AgentConfig
from ddpg_her.ensemble import Ensemble
from ddpg_her.sac import SAC
from ddpg_her.td3 import TD3
from regions.partition import Partition

ALGORITHMS = {"ddpg": DDPG, "td3": TD3, "sac": SAC}
"""The classes of ``AgentConfig.algo``'s values."""


def make_agent(config: AgentConfig, in_dim: int, act_dim: int, *,
               init_generators: Sequence[torch.Generator], dtype: torch.dtype = torch.float32,
               device: str | torch.device = "cpu",
               partitions: Sequence[Partition] | None = None) -> Any:
    """K stacked agents of ``config.algo`` (ddpg, td3, sac); arguments as `DDPG`'s. With
    ``config.ensemble`` = M > 1, K regional ensembles of M such agents (`Ensemble`), seed k's
    goals split by ``partitions[k]``."""
    member = ALGORITHMS[config.algo.value]
    if config.ensemble > 1:
        if partitions is None:
            raise ValueError(f"an ensemble of {config.ensemble} needs the partitions of the "
                             "tasks' goals (ddpg_her.ensemble.task_partitions)")
        return Ensemble(config, in_dim, act_dim, partitions=partitions, member_class=member,
                        init_generators=init_generators, dtype=dtype, device=device)
    return member(config, in_dim, act_dim, init_generators=init_generators, dtype=dtype,
                  device=device)


BYTES_PER_PARAMETER = 6
"""Copies of each network parameter in memory: the weight, its target, its gradient, Adam's
two moments, and one for the update's scratch (an upper estimate)."""


def check_memory(config: AgentConfig, layout: Layout, k: int, dtype: torch.dtype,
                 device: torch.device, test_copy_bytes: int = 0,
                 copies: int = BYTES_PER_PARAMETER) -> None:
    """Refuse, before allocating, replay buffers, networks and test episodes larger than the
    memory of ``device`` (the host's available memory for the CPU, the GPU's free memory): the
    one estimate of every training path (`ddpg_her.trainer.Trainer`, `ddpg_her.program.check`).
    ``test_copy_bytes``: bytes per test episode copy (k x eval_episodes of them); ``copies``:
    of each network parameter.

    Raises
    ------
    ValueError
        Naming --buffer-size, --hidden-sizes or --eval-episodes and the memory they would need.
    """
    size = torch.empty((), dtype=dtype).element_size()
    buffer = k * config.buffer_size * layout.width * size
    h1, h2 = config.hidden_sizes
    params = (layout.in_dim * h1 + h1 + h1 * h2 + h2 + h2 * layout.act_dim + layout.act_dim
              + layout.in_dim * h1 + h1 + (h1 + layout.act_dim) * h2 + h2 + h2 + 1)
    networks = k * params * size * copies
    tests = k * config.eval_episodes * test_copy_bytes
    available = available_memory(device)
    if available is None:
        return
    gib = 2.0 ** 30
    for flag, need in (("--buffer-size", buffer), ("--hidden-sizes", networks),
                       ("--eval-episodes", tests),
                       ("--buffer-size, --hidden-sizes and --eval-episodes",
                        buffer + networks + tests)):
        if need > available:
            raise ValueError(
                f"{flag}: {k} agent(s) would need {need / gib:.3g} GiB ({buffer / gib:.3g} GiB "
                f"of replay buffers: {config.buffer_size} transitions x {layout.width} "
                f"values x {size} bytes each; {networks / gib:.3g} GiB of networks "
                f"{config.hidden_sizes}; {tests / gib:.3g} GiB of {config.eval_episodes} test "
                f"episodes each), more than the {available / gib:.3g} GiB available on {device}")


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
