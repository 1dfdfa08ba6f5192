"""Bit-for-bit fingerprints of the envs' behaviour, to hold a refactor against the code before it.

``python -m benchmarks.fingerprint record OUT.json`` steps fixed-seed rollouts of every dynamics
backend (pinocchio and numba on the CPU; the single env) under several tasks
(held joints locked and pd; zheight and unconstrained; 3 and 6 joints; the compliant contact;
velocity and torque control) with random actions from a fixed generator (a third of them outside
the action box), and hashes every step's observation, reward, flags and info (SHA-256 of the
arrays' bytes: equal hashes mean equal bits). With ``--train`` it also runs a short
``python -m ddpg_her.train`` under each ``--env-backend`` and hashes its ``eval.csv`` without
the ``wall_s`` column. ``python -m benchmarks.fingerprint compare A.json B.json`` names every
entry that differs (exit 1) or says that all are equal.
"""

from __future__ import annotations

import csv
import hashlib
import json
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ddpg_her.config import Parser

STEPS = 220
"""Steps per rollout: over two episodes of 100 steps, so every rollout crosses an autoreset."""

COPIES = 3
"""Copies of the batched envs."""

TASKS: dict[str, dict[str, Any]] = {
    "zheight3_locked": dict(region="zheight", n_joints=3, held_joints="locked"),
    "zheight3_pd": dict(region="zheight", n_joints=3, held_joints="pd"),
    "zheight6_locked": dict(region="zheight", n_joints=6, held_joints="locked"),
    "unconstrained3_locked": dict(region="unconstrained", n_joints=3, held_joints="locked"),
    "unconstrained3_pd": dict(region="unconstrained", n_joints=3, held_joints="pd"),
    "unconstrained6_pd": dict(region="unconstrained", n_joints=6, held_joints="pd"),
    "zheight3_velocity": dict(region="zheight", n_joints=3, control_mode="velocity"),
    "unconstrained3_torque_pd": dict(region="unconstrained", n_joints=3, control_mode="torque",
                                     held_joints="pd"),
}
"""The tasks every backend is stepped in (stop contact model; unconstrained starts at the zero
pose, where random commands hit the plane and the joint limits often)."""

COMPLIANT: dict[str, dict[str, Any]] = {
    "zheight3_compliant": dict(region="zheight", n_joints=3, contact_model="compliant"),
    "unconstrained6_compliant_pd": dict(region="unconstrained", n_joints=6, held_joints="pd",
                                        contact_model="compliant"),
}
"""Tasks of the compliant contact model (the Pinocchio loop only)."""

TRAIN = ["--region", "zheight", "--joints", "3", "--seeds", "0", "1", "--episodes", "6",
         "--eval-every", "3", "--no-progress", "--threads", "1", "--device", "cpu"]
"""The short training run whose eval.csv is compared, under each --env-backend."""


class Digest:
    """A running SHA-256 of arrays (their dtype, shape and bytes)."""

    def __init__(self) -> None:
        self.sha = hashlib.sha256()

    def add(self, value: Any) -> None:
        if isinstance(value, dict):
            for key in sorted(value):
                self.sha.update(key.encode())
                self.add(value[key])
            return
        if hasattr(value, "detach"):
            value = value.detach().cpu().numpy()
        array = np.ascontiguousarray(np.asarray(value))
        self.sha.update(f"{array.dtype}{array.shape}".encode())
        self.sha.update(array.tobytes())

    def hexdigest(self) -> str:
        return self.sha.hexdigest()


def actions(box: Any, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    """Random commands: uniform over 1.5 times the action box (a third outside it)."""
    low, high = np.asarray(box.low, dtype=float), np.asarray(box.high, dtype=float)
    mid, half = (high + low) / 2, (high - low) / 2
    return mid + 1.5 * half * rng.uniform(-1.0, 1.0, (*shape, len(low)))


def batched_rollout(fields: dict[str, Any], dynamics: str) -> str:
    import envs

    env = envs.BatchedReach(COPIES, dynamics=dynamics, **fields)
    rng, digest = np.random.default_rng(1), Digest()
    obs, info = env.reset(seed=7)
    digest.add(obs)
    digest.add(info)
    for _ in range(STEPS):
        step = env.step(actions(env.single_action_space, rng, (COPIES,)))
        for part in step:
            digest.add(part)
    return digest.hexdigest()


def single_rollout(fields: dict[str, Any]) -> str:
    import gymnasium

    import envs  # noqa: F401  (registers the ids)

    env = gymnasium.make("UR5Reach-v0", **fields)
    rng, digest = np.random.default_rng(2), Digest()
    obs, info = env.reset(seed=3)
    digest.add(obs)
    digest.add(info)
    for _ in range(STEPS):
        obs, reward, terminated, truncated, info = env.step(
            actions(env.action_space, rng, ()))
        digest.add(obs)
        digest.add(np.float64(reward))
        digest.add(np.array([terminated, truncated]))
        digest.add(info)
        if terminated or truncated:
            obs, info = env.reset()
            digest.add(obs)
            digest.add(info)
    digest.add(env.unwrapped.joint_angles)
    return digest.hexdigest()


def train_eval(backend: str, root: Path) -> str:
    out = root / backend
    subprocess.run([sys.executable, "-m", "ddpg_her.train", *TRAIN, "--env-backend", backend,
                    "--out", str(out / "{seed}")], check=True, stdout=subprocess.DEVNULL)
    digest = Digest()
    files = sorted(out.rglob("eval.csv"))
    if not files:
        raise RuntimeError(f"no eval.csv under {out}")
    for path in files:
        with path.open() as f:
            rows = [{k: v for k, v in row.items() if k != "wall_s"} for row in csv.DictReader(f)]
        digest.sha.update(str(path.relative_to(out)).encode())
        digest.sha.update(json.dumps(rows, sort_keys=True).encode())
    return digest.hexdigest()


def record(train: bool) -> dict[str, str]:
    result: dict[str, str] = {}
    for name, fields in TASKS.items():
        for dynamics in ("pinocchio", "numba"):
            result[f"batched/{dynamics}/{name}"] = batched_rollout(fields, dynamics)
            print(f"batched/{dynamics}/{name}", flush=True)
        result[f"single/{name}"] = single_rollout(fields)
        print(name, flush=True)
    for name, fields in COMPLIANT.items():
        result[f"batched/pinocchio/{name}"] = batched_rollout(fields, "pinocchio")
        result[f"single/{name}"] = single_rollout(fields)
        print(name, flush=True)
    if train:
        with tempfile.TemporaryDirectory() as tmp:
            for backend in ("numpy", "batched"):
                result[f"train/{backend}"] = train_eval(backend, Path(tmp))
                print(f"train/{backend}", flush=True)
    return result


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m benchmarks.fingerprint",
                                     description=__doc__.split("\n\n")[0])
    verbs = parser.add_subparsers(dest="verb", required=True,
                                  help="record: hash this tree's behaviour; compare: two records")
    rec = verbs.add_parser("record", help="record the fingerprints into a JSON file")
    rec.add_argument("out", type=Path, help="the JSON file to write")
    rec.add_argument("--train", action="store_true",
                     help="also the short training runs' eval.csv (minutes)")
    cmp_ = verbs.add_parser("compare", help="compare two recorded files")
    cmp_.add_argument("a", type=Path, help="a recorded JSON file (the reference)")
    cmp_.add_argument("b", type=Path, help="another recorded JSON file")
    args = parser.parse_args(argv)
    if args.verb == "record":
        args.out.write_text(json.dumps(record(args.train), indent=1, sort_keys=True) + "\n")
        return 0
    a, b = json.loads(args.a.read_text()), json.loads(args.b.read_text())
    differ = sorted(k for k in set(a) & set(b) if a[k] != b[k])
    only = sorted(set(a) ^ set(b))
    for key in differ:
        print(f"DIFFERS {key}")
    for key in only:
        print(f"ONLY IN ONE {key}")
    print(f"{len(set(a) & set(b)) - len(differ)} equal, {len(differ)} differ, {len(only)} in one "
          "file only")
    return 1 if differ or only else 0


if __name__ == "__main__":
    sys.exit(main())
