"""The run folder: what a training run writes, how it resumes, and `load` for analysis.

A run folder holds

- ``spec.json``: env id and arguments, the task specification, the agent configuration, the seed,
  package versions, git revision and the command line;
- ``eval.csv``: one row per test session, columns `EVAL_COLUMNS`;
- ``checkpoints/episode-NNNNNN.pt``: the last two checkpoints (networks, optimisers, normaliser,
  random generator states, eval rows so far);
- ``buffer/episode-NNNNNN.npz``: the transitions each checkpoint interval added to the replay
  buffer, so a checkpoint need not rewrite the whole buffer; chunks that the buffer has since
  overwritten are deleted;
- ``tb/``: TensorBoard logs, when tensorboard is installed.

Every file is written to a temporary name and moved into place with ``os.replace``, so a run
killed at any moment leaves each file either complete or as it was. A checkpoint is written
before the ``eval.csv`` that shows its rows, and ``eval.csv`` is rewritten from the checkpoint on
resume, so no row is ever lost, repeated or skipped.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import re
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ddpg_her.config import AgentConfig
from ddpg_her.networks import Actor, load_agent_slices
from ddpg_her.normalizer import RunningNormalizer
from ddpg_her.spaces import ActionScale, goal_input

EVAL_COLUMNS = ("episode", "successes", "tests", "mean_return", "mean_final_distance_m",
                "env_steps", "wall_s")
"""Columns of eval.csv: training episodes so far, test episodes that reached the goal, test
episodes, mean undiscounted return, mean final end-effector distance to the goal (m), training
env steps so far (test steps not counted), wall-clock seconds of training so far (the only
column that differs between two runs of one seed)."""

FORMAT = "ddpg_her-run-1"
_CKPT = re.compile(r"episode-(\d{6,})\.pt$")
_CHUNK = re.compile(r"episode-(\d{6,})\.npz$")


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` so that a reader sees the old file or the new, never a part."""
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def versions() -> dict[str, str]:
    """Versions of Python and of the packages a run depends on."""
    from importlib import metadata

    out = {"python": sys.version.split()[0]}
    for name in ("torch", "numpy", "gymnasium", "pin", "ur5-reacher"):
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[name] = metadata.version(name)
    return out


def git_revision() -> dict[str, Any]:
    """The git revision of the source tree of this package, and whether it has edits."""
    root = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()

    try:
        return {"revision": git("rev-parse", "HEAD"),
                "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}
    except (OSError, subprocess.SubprocessError):
        return {"revision": None, "dirty": None}


class RunFolder:
    """Reads and writes one agent's run folder (see the module docstring)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)

    @property
    def spec_path(self) -> Path:
        return self.path / "spec.json"

    def exists(self) -> bool:
        return self.spec_path.exists()

    def read_spec(self) -> dict[str, Any]:
        return json.loads(self.spec_path.read_text())

    def write_spec(self, spec: dict[str, Any]) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        atomic_write(self.spec_path, (json.dumps(spec, indent=2) + "\n").encode())

    def write_eval(self, rows: Sequence[dict[str, Any]]) -> None:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=EVAL_COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        atomic_write(self.path / "eval.csv", buf.getvalue().encode())

    def read_eval(self) -> list[dict[str, str]]:
        with open(self.path / "eval.csv", newline="") as f:
            return list(csv.DictReader(f))

    # --- checkpoints and buffer chunks ---------------------------------------------------------
    def _listing(self, sub: str, pattern: re.Pattern) -> dict[int, Path]:
        folder = self.path / sub
        if not folder.is_dir():
            return {}
        found = {}
        for p in folder.iterdir():
            m = pattern.match(p.name)
            if m:
                found[int(m.group(1))] = p
        return dict(sorted(found.items()))

    def checkpoints(self) -> dict[int, Path]:
        """{episode: path} of the checkpoints present, in episode order."""
        return self._listing("checkpoints", _CKPT)

    def save_checkpoint(self, episode: int, state: dict[str, Any], keep: int = 2) -> None:
        folder = self.path / "checkpoints"
        folder.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        torch.save(state, buf)
        atomic_write(folder / f"episode-{episode:06d}.pt", buf.getvalue())
        for old in list(self.checkpoints())[:-keep]:
            self.checkpoints()[old].unlink(missing_ok=True)

    def load_checkpoint(self, episode: int) -> dict[str, Any]:
        return torch.load(self.checkpoints()[episode], map_location="cpu", weights_only=True)

    def save_chunk(self, episode: int, start: int, rows: np.ndarray) -> None:
        folder = self.path / "buffer"
        folder.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.savez(buf, start=np.int64(start), rows=rows)
        atomic_write(folder / f"episode-{episode:06d}.npz", buf.getvalue())

    def chunks(self, upto: int) -> list[tuple[int, np.ndarray]]:
        """(first transition number, rows) of the chunks saved up to episode ``upto``."""
        out = []
        for episode, p in self._listing("buffer", _CHUNK).items():
            if episode <= upto:
                with np.load(p) as z:
                    out.append((int(z["start"]), z["rows"]))
        return out

    def prune(self, upto: int, keep_from: int) -> None:
        """Delete chunks saved after episode ``upto`` (an abandoned future after a resume), and
        chunks whose transitions all come before number ``keep_from`` (overwritten)."""
        for episode, p in self._listing("buffer", _CHUNK).items():
            if episode > upto:
                p.unlink(missing_ok=True)
                continue
            with np.load(p) as z:
                end = int(z["start"]) + len(z["rows"])
            if end <= keep_from:
                p.unlink(missing_ok=True)


class TrainedPolicy:
    """A trained agent's deterministic policy, acting on the env's Dict observations.

    ``policy(obs)`` with obs arrays ``observation (obs_dim,)``, ``achieved_goal (goal_dim,)``,
    ``desired_goal (goal_dim,)`` returns the action ``(act_dim,)`` in env units (rad for the
    UR5's joint angles); with a leading batch axis B on every array it returns ``(B, act_dim)``.
    """

    def __init__(self, actor: Actor, normalizer: RunningNormalizer, scale: ActionScale,
                 spec: dict[str, Any], episode: int):
        self.actor, self.normalizer, self.scale = actor, normalizer, scale
        self.spec, self.episode = spec, episode
        self.device = actor.l1.weight.device

    def make_env(self, **kwargs: Any) -> Any:
        """A fresh copy of the env the policy was trained on (``gymnasium.make`` with the run's
        env id and arguments; ``kwargs`` go to ``gymnasium.make`` too, e.g. ``render_mode``)."""
        import gymnasium

        from ddpg_her.vecenv import register_env

        return gymnasium.make(register_env(self.spec["env_id"]), **self.spec["env_kwargs"],
                              **kwargs)

    @torch.no_grad()
    def __call__(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        x = goal_input(obs["observation"], obs["achieved_goal"], obs["desired_goal"])
        single = x.ndim == 1
        xt = torch.as_tensor(x.reshape(1, -1, x.shape[-1]), device=self.device)
        u = self.actor(self.normalizer(xt.to(self.actor.l1.weight.dtype)))[0]
        a = self.scale.to_env(u.cpu().numpy())
        return a[0] if single else a


def load(run_dir: str | os.PathLike, *, episode: int | None = None,
         device: str = "cpu") -> TrainedPolicy:
    """The policy of the run in ``run_dir`` at its latest checkpoint (or at ``episode``)."""
    folder = RunFolder(run_dir)
    if not folder.exists():
        raise FileNotFoundError(f"{run_dir} is not a run folder (no spec.json)")
    spec = folder.read_spec()
    ckpts = folder.checkpoints()
    if not ckpts:
        raise FileNotFoundError(f"{run_dir} has no checkpoint yet")
    episode = max(ckpts) if episode is None else episode
    if episode not in ckpts:
        raise ValueError(f"no checkpoint at episode {episode} in {run_dir}; have {list(ckpts)}")
    state = folder.load_checkpoint(episode)["agent"]
    config = AgentConfig.from_dict(spec["agent"])
    dims = spec["dims"]
    in_dim = dims["obs_dim"] + 2 * dims["goal_dim"]
    actor = Actor(1, in_dim, dims["act_dim"], config.hidden_sizes, dtype=torch.float32,
                  device=torch.device(device))
    load_agent_slices(actor, [state["actor"]])
    normalizer = RunningNormalizer(1, in_dim, eps=config.norm_eps, clip=config.obs_clip,
                                   enabled=config.normalize_obs, dtype=torch.float32,
                                   device=torch.device(device))
    normalizer.load_state(0, state["normalizer"])
    scale = ActionScale(np.array(dims["action_low"]), np.array(dims["action_high"]))
    return TrainedPolicy(actor, normalizer, scale, spec, episode)
