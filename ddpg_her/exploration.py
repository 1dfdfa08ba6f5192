"""Exploration noise of the K agents, each agent drawing from its own generator."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

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
