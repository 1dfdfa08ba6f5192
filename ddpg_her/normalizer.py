"""Running mean and standard deviation of the network input, one set of statistics per agent."""

from __future__ import annotations

import numpy as np
import torch


class RunningNormalizer:
    """``normalize(x) = clip((x - mean) / max(std, eps), -clip, clip)``, per agent and feature.

    The sums are kept in float64 on the CPU, so the statistics do not depend on the device; the
    mean and std used by the networks are refreshed after each `update`. With ``enabled=False``
    the input passes through unchanged.
    """

    def __init__(self, k: int, dim: int, *, eps: float, clip: float, enabled: bool,
                 dtype: torch.dtype, device):
        self.k, self.dim = k, dim
        self.eps, self.clip, self.enabled = eps, clip, enabled
        self.count = np.zeros(k)
        self.sum = np.zeros((k, dim))
        self.sumsq = np.zeros((k, dim))
        self.mean = torch.zeros(k, 1, dim, dtype=dtype, device=device)
        self.std = torch.ones(k, 1, dim, dtype=dtype, device=device)

    def update(self, k: int, x: np.ndarray | torch.Tensor) -> None:
        """Add rows ``x : (L, dim)`` to agent k's statistics. For a tensor, the sums are taken
        on its device and only they are read back (2 dim numbers)."""
        if isinstance(x, torch.Tensor):
            x = x.to(torch.float64).reshape(-1, self.dim)
            sums = torch.stack([x.sum(0), (x**2).sum(0)]).cpu().numpy()
        else:
            x = np.asarray(x, dtype=np.float64).reshape(-1, self.dim)
            sums = (x.sum(axis=0), (x**2).sum(axis=0))
        self.count[k] += len(x)
        self.sum[k] += sums[0]
        self.sumsq[k] += sums[1]
        if self.enabled and self.count[k] > 0:
            n = self.count[k]
            mean = self.sum[k] / n
            var = np.maximum(self.sumsq[k] / n - mean**2, 0.0)
            std = np.maximum(np.sqrt(var), self.eps)
            self.mean[k, 0] = torch.from_numpy(mean).to(self.mean)
            self.std[k, 0] = torch.from_numpy(std).to(self.std)

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        """x : (K, B, dim) raw input -> (K, B, dim) normalised."""
        if not self.enabled:
            return x
        return torch.clamp((x - self.mean) / self.std, -self.clip, self.clip)

    def state(self, k: int) -> dict[str, torch.Tensor]:
        """Agent k's sums, float64 CPU tensors (``torch.load(weights_only=True)`` reads them)."""
        return {"count": torch.tensor(self.count[k]), "sum": torch.from_numpy(self.sum[k].copy()),
                "sumsq": torch.from_numpy(self.sumsq[k].copy())}

    def load_state(self, k: int, state: dict[str, torch.Tensor]) -> None:
        self.count[k] = float(state["count"])
        self.sum[k] = np.asarray(state["sum"])
        self.sumsq[k] = np.asarray(state["sumsq"])
        self.update(k, np.zeros((0, self.dim)))
