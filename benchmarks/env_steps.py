"""Steps per second of ``UR5Reach-v0`` next to a peer env (FetchReach-v4) measured in the same run.

Rows: the single env (``gymnasium.make``), the batched path (:class:`envs.BatchedReach`, N
copies in one call, on the compiled kernel of :mod:`envs.physics.numba_kernel`), the same batched
env on the reference Pinocchio dynamics, Gymnasium's ``SyncVectorEnv`` of N single envs (the Python
loop the batched path replaces) and the peer. Every env gets the same protocol: uniform random
actions drawn before the clock starts, an episode restarted whenever one ends, and several
rounds interleaved across the envs so that the load of a shared machine hits all of them alike.
The table gives each env's median over the rounds, the median over rounds of its ratio to the
single env's steps/s in the same round, and its ratio to the peer's median. Vector rows count
copy-steps (N per call).

``--device`` and its rows of the dynamics alone (the torch kernel on a device, the numba one on
the CPU beside it) went with ``envs.physics.torch_kernel`` after commit 401ca32, the last that
runs them.

    python -m benchmarks.env_steps                 # the table
    python -m benchmarks.env_steps --json          # machine-readable
    python -m benchmarks.env_steps --num-envs 4096 --peer none --sync 0   # a large batch
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import statistics
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import gymnasium
import numpy as np

import envs
from ddpg_her.config import Parser
from envs.spec import TaskSpec


@dataclass(frozen=True)
class BenchConfig:
    """What ``python -m benchmarks.env_steps`` measures (each field is a command-line flag)."""

    steps: int = 2000
    """Env steps per round for the single env and the peer (the batched rows take
    ``steps * num_envs // 8`` copy-steps, enough to time them as reliably)."""
    rounds: int = 5
    """Interleaved rounds; the table reports each env's median over them."""
    num_envs: int = 64
    """Copies N of the batched and sync-vector rows (0 skips both)."""
    threads: int = 1
    """CPU threads of the batched env's fast dynamics."""
    batched: bool = True
    """Measure the batched env (its fast dynamics; Pinocchio's where numba is missing, as on
    the GPU machine, where it is too slow at large N to time)."""
    reference: bool = True
    """Also measure the batched env on the reference Pinocchio dynamics."""
    sync: bool = True
    """Also measure Gymnasium's SyncVectorEnv of N single envs (slow at large N)."""
    region: str = "unconstrained"
    """Goal region of UR5Reach-v0 (any TaskSpec region string)."""
    n_joints: int = 3
    """Controlled joints of UR5Reach-v0 (2-6)."""
    control_mode: str = "position"
    """Control mode of UR5Reach-v0: position, velocity or torque."""
    peer: str = "FetchReach-v4"
    """Gymnasium-Robotics env measured alongside ('none' to skip; needs gymnasium-robotics and
    mujoco < 3.12: with gymnasium-robotics 1.4.2, FetchReach-v4 fails to build under mujoco
    3.12 to 3.17 and 4.0)."""
    seed: int = 0
    """Seed of the actions and of every reset."""
    json: bool = False
    """Print JSON instead of the table."""


def _rate(step: Callable[[], Any], count: int) -> float:
    """Calls of ``step`` per second over ``count`` calls."""
    start = time.perf_counter()
    for _ in range(count):
        step()
    return count / (time.perf_counter() - start)


def single_runner(env: gymnasium.Env, steps: int, seed: int) -> Callable[[], float]:
    """A round of ``steps`` random steps of one env; returns steps/s and counts contacts."""
    rng = np.random.default_rng(seed)
    space = env.action_space
    actions = rng.uniform(space.low, space.high, (steps, *space.shape)).astype(space.dtype)
    env.reset(seed=seed)
    state = {"i": 0, "contacts": 0}

    def step() -> None:
        _, _, terminated, truncated, info = env.step(actions[state["i"] % steps])
        state["i"] += 1
        state["contacts"] += bool(info.get("contact", False))
        if terminated or truncated:
            env.reset()

    def round_() -> float:
        return _rate(step, steps)

    round_.state = state  # type: ignore[attr-defined]
    return round_


def vector_runner(env: gymnasium.vector.VectorEnv, copy_steps: int, seed: int
                  ) -> Callable[[], float]:
    """A round of random vector steps; returns copy-steps/s (N per vector step)."""
    calls = max(1, copy_steps // env.num_envs)
    rng = np.random.default_rng(seed)
    space = env.action_space
    actions = rng.uniform(space.low, space.high, (calls, *space.shape)).astype(space.dtype)
    env.reset(seed=seed)
    env.step(actions[0])  # off the clock: a compiled path loads its kernels on the first call
    env.reset(seed=seed)
    state = {"i": 0}

    def step() -> None:
        env.step(actions[state["i"] % calls])
        state["i"] += 1

    return lambda: _rate(step, calls) * env.num_envs


def make_peer(env_id: str) -> gymnasium.Env | str:
    """The peer env, or a sentence saying why it is unavailable."""
    try:
        import gymnasium_robotics
    except ImportError:
        return ("gymnasium-robotics is not installed (pip install gymnasium-robotics "
                "'mujoco>=3.1,<3.12')")
    gymnasium.register_envs(gymnasium_robotics)
    try:
        return gymnasium.make(env_id)
    except Exception as err:  # a peer that fails to build (new mujoco) must not stop the bench
        import mujoco

        return (f"{env_id} failed to build under mujoco {mujoco.__version__} "
                f"({type(err).__name__}: {err}); FetchReach-v4 needs mujoco < 3.12")


def run(config: BenchConfig) -> dict[str, Any]:
    """Measure every row; returns the JSON-ready result."""
    task = TaskSpec(region=config.region, n_joints=config.n_joints,
                    control_mode=config.control_mode)
    rows: dict[str, Callable[[], float]] = {}
    notes: dict[str, str] = {}
    single = gymnasium.make("UR5Reach-v0", task=task)
    rows["UR5Reach-v0"] = single_runner(single, config.steps, config.seed)
    copy_steps = config.steps * max(config.num_envs, 1) // 8
    if config.num_envs > 0:
        if config.batched:
            batched = envs.BatchedReach(config.num_envs, task, threads=config.threads)
            dynamics = type(batched._core.dynamics).__name__
            notes[f"BatchedReach (N={config.num_envs})"] = f"dynamics: {dynamics}"
            rows[f"BatchedReach (N={config.num_envs})"] = vector_runner(batched, copy_steps,
                                                                        config.seed)
        if config.reference:
            reference = envs.BatchedReach(config.num_envs, task, dynamics="pinocchio")
            rows[f"BatchedReach (N={config.num_envs}, pinocchio)"] = vector_runner(
                reference, copy_steps, config.seed)
        if config.sync:
            sync = gymnasium.make_vec("UR5Reach-v0", num_envs=config.num_envs,
                                      vectorization_mode="sync", task=task)
            rows[f"SyncVectorEnv (N={config.num_envs})"] = vector_runner(sync, copy_steps,
                                                                         config.seed)
    peer_name = None
    if config.peer.lower() != "none":
        peer = make_peer(config.peer)
        if isinstance(peer, str):
            notes[config.peer] = peer
        else:
            peer_name = config.peer
            rows[peer_name] = single_runner(peer, config.steps, config.seed)
    samples: dict[str, list[float]] = {name: [] for name in rows}
    for _ in range(config.rounds):
        for name, measure in rows.items():
            samples[name].append(measure())
    medians = {name: statistics.median(values) for name, values in samples.items()}
    single_rounds = samples["UR5Reach-v0"]
    results = []
    for name, values in samples.items():
        ratio = medians[name] / medians[peer_name] if peer_name else None
        to_single = statistics.median(v / s for v, s in zip(values, single_rounds, strict=True))
        results.append({"env": name, "steps_per_s": medians[name], "min": min(values),
                        "max": max(values), "ratio_to_single": to_single,
                        "ratio_to_peer": ratio})
    counted = rows["UR5Reach-v0"].state  # type: ignore[attr-defined]
    return {
        "config": dataclasses.asdict(config),
        "task": task.to_dict(),
        "substeps_per_step": task.substeps,
        "contact_fraction": counted["contacts"] / max(counted["i"], 1),
        "peer": peer_name,
        "notes": notes,
        "machine": {"python": sys.version.split()[0], "platform": platform.platform(),
                    "processor": platform.processor() or platform.machine()},
        "results": results,
    }


NAME_WIDTH = 60
"""Characters of the table's first column (wider than the longest row name)."""


def format_table(result: dict[str, Any]) -> str:
    """The result as a text table."""
    cfg, peer = result["config"], result["peer"]
    lines = [
        f"UR5Reach-v0: region {cfg['region']}, {cfg['n_joints']} joints, {cfg['control_mode']} "
        f"control, {result['substeps_per_step']} substeps/step; random actions, "
        f"{cfg['rounds']} rounds (median, min-max); the arm touched the plane in "
        f"{100 * result['contact_fraction']:.0f} % of the single env's steps",
        "",
        f"{'env':<{NAME_WIDTH}} {'steps/s':>10} {'min':>10} {'max':>10} {'x single':>9} "
        f"{'x ' + (peer or 'peer'):>16}",
    ]
    for row in result["results"]:
        ratio = f"{row['ratio_to_peer']:.2f}" if row["ratio_to_peer"] is not None else "-"
        lines.append(f"{row['env']:<{NAME_WIDTH}} {row['steps_per_s']:>10.0f} {row['min']:>10.0f} "
                     f"{row['max']:>10.0f} {row['ratio_to_single']:>9.2f} {ratio:>16}")
    measured = {row["env"] for row in result["results"]}
    for name, note in result["notes"].items():
        lines.append(f"{name}: {'' if name in measured else 'not measured: '}{note}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """The command line: one flag per :class:`BenchConfig` field."""
    parser = Parser(
        prog="python -m benchmarks.env_steps", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    d = BenchConfig()
    parser.add_argument("--steps", type=int, default=d.steps,
                        help="env steps per round of the single env and the peer (the vector "
                        "rows take steps * num-envs / 8 copy-steps)")
    parser.add_argument("--rounds", type=int, default=d.rounds,
                        help="interleaved rounds; each env's median is reported")
    parser.add_argument("--num-envs", type=int, default=d.num_envs,
                        help="copies N of the batched and sync-vector rows (0 skips them)")
    parser.add_argument("--threads", type=int, default=d.threads,
                        help="CPU threads (>= 1) of the batched env's compiled dynamics")
    parser.add_argument("--batched", type=int, default=int(d.batched), choices=(0, 1),
                        help="0..1; 1: time BatchedReach (N) (default: %(default)s)")
    parser.add_argument("--reference", type=int, default=int(d.reference), choices=(0, 1),
                        help="0..1; 1: also time the batched env on the reference Pinocchio "
                             "dynamics (default: %(default)s)")
    parser.add_argument("--sync", type=int, default=int(d.sync), choices=(0, 1),
                        help="0..1; 1: also time Gymnasium's SyncVectorEnv of N single envs "
                             "(default: %(default)s)")
    parser.add_argument("--region", default=d.region,
                        help="goal region of UR5Reach-v0 (a name or region string)")
    parser.add_argument("--joints", dest="n_joints", type=int, default=d.n_joints,
                        help="controlled joints of UR5Reach-v0 (2-6)")
    parser.add_argument("--control-mode", default=d.control_mode,
                        choices=("position", "velocity", "torque"),
                        help="action meaning: angles (rad), velocities (rad/s), torques (N m)")
    parser.add_argument("--peer", default=d.peer,
                        help="Gymnasium-Robotics env measured in the same run, or 'none'")
    parser.add_argument("--seed", type=int, default=d.seed,
                        help="seed of the random actions and of every reset")
    parser.add_argument("--json", action="store_true", help="print JSON instead of the table")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.steps < 1 or args.rounds < 1 or args.num_envs < 0:
        raise SystemExit("--steps and --rounds must be >= 1 and --num-envs >= 0")
    config = BenchConfig(steps=args.steps, rounds=args.rounds, num_envs=args.num_envs,
                         threads=args.threads,
                         batched=bool(args.batched), reference=bool(args.reference),
                         sync=bool(args.sync), region=args.region, n_joints=args.n_joints,
                         control_mode=args.control_mode, peer=args.peer, seed=args.seed,
                         json=args.json)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the peer's import prints deprecation notices
        result = run(config)
    print(json.dumps(result, indent=2) if config.json else format_table(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
