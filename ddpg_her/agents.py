"""The stacked agents by name: ``make_agent`` builds K agents of ``AgentConfig.algo`` (or K
regional ensembles of them, `ddpg_her.ensemble`).

Apart from `ddpg_her.algos`, which TD3 and SAC import, so that no module imports itself back
through a lazy import.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from ddpg_her.agent import DDPG
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
