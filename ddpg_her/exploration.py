"""Exploration noise of the K agents, each agent drawing from its own generator.

`Explorer` holds the noise's arithmetic, written once on float64 tensors; where the random
numbers come from is the caller's choice (`NumpyDraws` for the trainer's envs on the host,
``ddpg_her.program.CounterDraws`` for the training program), and only the draws differ. Both
draw (K, act_dim) float64 tensors on their ``device`` in actor units: ``drawing(active)`` says
which agents draw at a step (active : (K,) bool, the agents whose episode runs), ``uniform``
and ``normal`` draw for those rows (the others are unused), and ``coin(rows, p, dim)`` gives
(K,) bool, True with probability p, and where True a uniform action.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from ddpg_her.config import AgentConfig, Exploration

F64 = torch.float64


class NumpyDraws:
    """`Draws` of ``numpy.random.Generator`` s on the host: agent k draws from ``rngs[k]`` only
    at the steps where its own episode runs, so its stream does not depend on how long the
    other agents' episodes last."""

    device = torch.device("cpu")

    def __init__(self, rngs: Sequence[np.random.Generator]):
        self.rngs = rngs

    def drawing(self, active: torch.Tensor) -> torch.Tensor:
        return active

    def _each(self, rows: torch.Tensor, dim: int, draw) -> torch.Tensor:
        out = np.zeros((len(self.rngs), dim))
        for k in np.flatnonzero(rows.numpy()):
            out[k] = draw(self.rngs[k])
        return torch.from_numpy(out)

    def uniform(self, rows: torch.Tensor, dim: int) -> torch.Tensor:
        return self._each(rows, dim, lambda rng: rng.uniform(-1.0, 1.0, dim))

    def normal(self, rows: torch.Tensor, dim: int) -> torch.Tensor:
        return self._each(rows, dim, lambda rng: rng.standard_normal(dim))

    def coin(self, rows: torch.Tensor, p: float, dim: int) -> tuple[torch.Tensor, torch.Tensor]:
        hit = np.array([bool(r) and g.random() < p for r, g in zip(rows.numpy(), self.rngs,
                                                                   strict=True)], dtype=bool)
        return torch.from_numpy(hit), self.uniform(torch.from_numpy(hit), dim)


class Explorer:
    """Perturbs the actors' actions during training, as set by ``config.exploration``, with
    the random numbers of ``draws``."""

    def __init__(self, config: AgentConfig, draws: Any, k: int, act_dim: int):
        self.kind, self.nu, self.theta = config.exploration, config.exploration_rate, \
            config.ou_theta
        self.draws, self.act_dim = draws, act_dim
        self.ou = torch.zeros((k, act_dim), dtype=F64, device=draws.device)

    def reset(self) -> None:
        """Start of an episode: the OU processes restart at 0."""
        self.ou.zero_()

    def __call__(self, u: torch.Tensor, active: torch.Tensor, *, uniform: bool) -> torch.Tensor:
        """u : (K, act_dim) float64 actor actions in [-1, 1] on the draws' device, active :
        (K,) bool -> (K, act_dim) in [-1, 1]. With ``uniform`` (warm-up) the action is
        uniformly random. Agents that do not draw keep their action."""
        rows, d = self.draws.drawing(active), self.act_dim
        if uniform:
            noisy = self.draws.uniform(rows, d)
        elif self.kind is Exploration.GAUSSIAN:
            noisy = u + self.nu * self.draws.normal(rows, d)
        elif self.kind is Exploration.OU:
            step = self.ou + (-self.theta * self.ou + self.nu * self.draws.normal(rows, d))
            self.ou = torch.where(rows.unsqueeze(-1), step, self.ou)
            noisy = u + self.ou
        else:
            hit, value = self.draws.coin(rows, self.nu, d)
            noisy = torch.where(hit.unsqueeze(-1), value, u)
        return torch.clamp(torch.where(rows.unsqueeze(-1), noisy, u), -1.0, 1.0)
