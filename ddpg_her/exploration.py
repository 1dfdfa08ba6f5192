"""Exploration noise of the K agents, each agent drawing from its own generator."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from ddpg_her.config import AgentConfig, Exploration


class Explorer:
    """Perturbs the actors' actions during training, as set by ``config.exploration``.

    Agent k draws from ``rngs[k]`` only at the steps where its own episode is running, so its
    random stream does not depend on how long the other agents' episodes last.
    """

    def __init__(self, config: AgentConfig, rngs: Sequence[np.random.Generator], act_dim: int):
        self.kind, self.nu, self.theta = config.exploration, config.exploration_rate, \
            config.ou_theta
        self.rngs = rngs
        self.ou = np.zeros((len(rngs), act_dim))

    def reset(self) -> None:
        """Start of an episode: the OU processes restart at 0."""
        self.ou[:] = 0.0

    def __call__(self, u: np.ndarray, active: np.ndarray, *, uniform: bool) -> np.ndarray:
        """u : (K, act_dim) actor actions in [-1, 1], active : (K,) bool -> (K, act_dim) in
        [-1, 1]. With ``uniform`` (warm-up) the action is uniformly random."""
        u = u.copy()
        for k in np.flatnonzero(active):
            rng = self.rngs[k]
            if uniform:
                u[k] = rng.uniform(-1.0, 1.0, u.shape[1])
            elif self.kind is Exploration.GAUSSIAN:
                u[k] += self.nu * rng.standard_normal(u.shape[1])
            elif self.kind is Exploration.OU:
                self.ou[k] += -self.theta * self.ou[k] + self.nu * rng.standard_normal(u.shape[1])
                u[k] += self.ou[k]
            elif rng.random() < self.nu:
                u[k] = rng.uniform(-1.0, 1.0, u.shape[1])
        return np.clip(u, -1.0, 1.0)


class TorchExplorer:
    """`Explorer` on the device, for the torch env backend: agent k draws from its own
    ``torch.Generator`` (on the actions' device) at every step of every episode, whether its
    episode still runs or not, so its stream depends on its seed alone and is never read back.

    Its draws are not `Explorer`'s (numpy's generators, drawn only while an episode runs):
    the two backends explore alike in law, not sample by sample.
    """

    def __init__(self, config: AgentConfig, generators: Sequence[torch.Generator],
                 act_dim: int, device: torch.device):
        self.kind, self.nu, self.theta = config.exploration, config.exploration_rate, \
            config.ou_theta
        self.generators, self.act_dim, self.device = generators, act_dim, device
        self.ou = torch.zeros((len(generators), act_dim), dtype=torch.float64, device=device)

    def reset(self) -> None:
        """Start of an episode: the OU processes restart at 0."""
        self.ou.zero_()

    def _draw(self, fn, size: int) -> torch.Tensor:
        return torch.stack([fn(size, generator=g, dtype=torch.float64, device=self.device)
                            for g in self.generators])

    def __call__(self, u: torch.Tensor, *, uniform: bool) -> torch.Tensor:
        """u : (K, act_dim) float64 actor actions in [-1, 1] -> (K, act_dim) in [-1, 1].
        With ``uniform`` (warm-up) the action is uniformly random."""
        if uniform:
            u = 2.0 * self._draw(torch.rand, self.act_dim) - 1.0
        elif self.kind is Exploration.GAUSSIAN:
            u = u + self.nu * self._draw(torch.randn, self.act_dim)
        elif self.kind is Exploration.OU:
            self.ou += -self.theta * self.ou + self.nu * self._draw(torch.randn, self.act_dim)
            u = u + self.ou
        else:
            draw = self._draw(torch.rand, self.act_dim + 1)
            u = torch.where(draw[:, :1] < self.nu, 2.0 * draw[:, 1:] - 1.0, u)
        return torch.clamp(u, -1.0, 1.0)
