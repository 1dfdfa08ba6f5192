"""What a trainer reports: eval rows, the progress bar and TensorBoard scalars."""

from __future__ import annotations

import datetime
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch


def eval_rows(episode: int, m: int, env_steps: np.ndarray, success: np.ndarray,
              returns: np.ndarray, distance: np.ndarray) -> list[dict[str, Any]]:
    """One eval row per agent, without its ``wall_s``, from a test session of ``m`` episodes
    per agent: success, returns, distance (K * m,), agent-major (`Collector.test_session`)."""
    rows = []
    for k in range(len(env_steps)):
        sl = slice(k * m, (k + 1) * m)
        rows.append({
            "episode": episode,
            "successes": int(success[sl].sum()),
            "tests": m,
            "mean_return": round(float(np.mean(returns[sl])), 6),
            "mean_final_distance_m": round(float(np.mean(distance[sl])), 6),
            "env_steps": int(env_steps[k]),
        })
    return rows


def postfix(bar, rows: list[list[dict[str, Any]]]) -> str:
    """Latest success counts and the projected finish (clock time)."""
    text = "hits " + ("/".join(str(r[-1]["successes"]) for r in rows)
                      + f" of {rows[0][-1]['tests']}" if rows[0] else "-")
    rate = bar.format_dict.get("rate")
    if rate:
        left = (bar.total - bar.n - 1) / rate
        finish = datetime.datetime.now() + datetime.timedelta(seconds=left)
        text += f", done ~{finish:%a %H:%M}"
    return text


def _tb_writer(path: Path, episode: int):
    """A TensorBoard writer in ``path/tb``, or None when tensorboard is not installed."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        return None
    return SummaryWriter(str(path / "tb"), purge_step=episode + 1)


class Interval:
    """Training statistics between two test sessions, written to TensorBoard at each: one
    writer per run folder of ``paths`` (none without ``tensorboard``), from ``episode`` on."""

    def __init__(self, k: int, device: torch.device, paths: Sequence[Path], episode: int,
                 tensorboard: bool):
        self.k = k
        self.writers = [_tb_writer(p, episode) if tensorboard else None for p in paths]
        self.losses = torch.zeros(2, k, dtype=torch.float64, device=device)
        self.successes = np.zeros(k)
        self.updates = self.episodes = self.learning = 0
        self.start = time.perf_counter()

    def write(self, rows: list[list[dict[str, Any]]], episode: int) -> None:
        seconds = time.perf_counter() - self.start
        episodes = max(self.episodes, 1)
        losses = (self.losses / max(self.learning, 1)).cpu().numpy()
        stats = {
            "train/critic_loss": losses[0],
            "train/actor_loss": losses[1],
            "train/success_rate": self.successes / episodes,
            "perf/agent_updates_per_wall_s": np.full(self.k, self.k * self.updates / seconds),
        }
        for k, w in enumerate(self.writers):
            if w is None:
                continue
            row = rows[k][-1]
            w.add_scalar("eval/success_rate", row["successes"] / row["tests"], episode)
            w.add_scalar("eval/mean_return", row["mean_return"], episode)
            w.add_scalar("eval/mean_final_distance_m", row["mean_final_distance_m"], episode)
            for name, v in stats.items():
                if math.isfinite(float(v[k])):
                    w.add_scalar(name, float(v[k]), episode)
            w.flush()
        self.losses.zero_()
        self.successes[:] = 0
        self.updates = self.episodes = self.learning = 0
        self.start = time.perf_counter()

    def close(self) -> None:
        for w in self.writers:
            if w is not None:
                w.close()
