"""What the ground-contact model does to the task: goals reached by their own configuration, cost.

``python -m analysis.contact`` measures, for each contact model (``stop``, ``compliant``):

- reach: the share of goals for which commanding the goal's own sampled joint configuration
  from the start (position control, one episode) brings tool0 within ``success_radius`` of the
  goal at some step; the rest stick on the plane or are pushed off their path;
- contact: the share of steps with ``info["contact"]`` under uniform random actions (the
  agent's warm-up), and the deepest any link went below the plane at the end of a step;
- cost: env steps/s of ``UR5Reach-v0`` under the same random actions, the models interleaved in
  rounds so that a shared machine's load hits both alike, and their ratio.

Run with ``--help`` for every flag.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields

import gymnasium
import numpy as np

import ur5kin
from ddpg_her.config import Parser, field_docs, usage_errors
from envs.checks import validate
from envs.physics import make_dynamics
from envs.spec import CONTACT_MODELS, TaskSpec
from envs.task import task_sampler
from ur5kin.checks import SEED, integer, kinds, number


@dataclass(frozen=True)
class ContactConfig:
    """What ``python -m analysis.contact`` measures (each field is a command-line flag)."""

    region: str = "zheight"
    """Goal region (any TaskSpec region string)."""
    n_joints: int = 3
    """Controlled joints (2-6)."""
    goals: int = 200
    """Goals per contact model for the reach share."""
    steps: int = 1000
    """Random-action env steps per round for the contact share and the cost."""
    rounds: int = 3
    """Interleaved timing rounds; the cost is each model's median over them."""
    friction: float = -1.0
    """Coulomb coefficient of the compliant model (dimensionless); negative: TaskSpec's
    default."""
    seed: int = 0
    """Seed of the goals and the actions."""
    json: bool = False
    """Print JSON instead of text."""


@dataclass(frozen=True)
class ContactRow:
    """One contact model's figures."""

    contact_model: str
    reached: float
    """Share of goals reached by commanding their own configuration (0-1)."""
    contact_share: float
    """Share of random-action steps with contact (0-1)."""
    depth_stops: float
    """Share of random-action steps that fell back to the stop (0-1; compliant only)."""
    deepest: float
    """Deepest end-of-step point of any link below the plane (m) under random actions."""
    steps_per_s: float
    """Median env steps/s of UR5Reach-v0 under random actions."""


def reach_share(task: TaskSpec, goals: int, seed: int) -> float:
    """Share of ``goals`` goals reached by commanding their own sampled configuration.

    All goals run as one batch of the Pinocchio loop's copies
    (:func:`envs.physics.make_dynamics`) for ``max_episode_steps`` steps; a goal counts when
    tool0 comes within ``success_radius`` (m) of it at the end of some step (the episode's
    success).
    """
    batch = task_sampler(task).sample(goals, np.random.default_rng(seed))
    dyn = make_dynamics(validate(task), goals, "pinocchio")
    command = batch.q[:, : task.n_joints]
    tool = np.zeros((goals, 3))
    reached = np.zeros(goals, dtype=bool)
    for _ in range(task.max_episode_steps):
        dyn.step(command)
        dyn.tool_positions(tool)
        reached |= np.linalg.norm(tool - batch.goals, axis=1) <= task.success_radius
    return float(reached.mean())


def random_steps(task: TaskSpec, steps: int, seed: int) -> tuple[float, float, float, float]:
    """Contact share, depth-stop share, deepest end-of-step depth (m) and steps/s of
    ``UR5Reach-v0`` under uniform random actions (episodes restarted as they end)."""
    env = gymnasium.make("UR5Reach-v0", task=task)
    space = env.action_space
    actions = np.random.default_rng(seed).uniform(space.low, space.high, (steps, *space.shape))
    dyn = env.unwrapped.dynamics
    env.reset(seed=seed)
    contacts = stops = 0
    deepest = 0.0
    start = time.perf_counter()
    for a in actions:
        _, _, terminated, truncated, info = env.step(a)
        contacts += info["contact"]
        stops += bool(dyn.depth_stop[0])
        if info["contact"]:
            heights = ur5kin.link_heights(env.unwrapped.joint_angles, task.base_height)[1:]
            deepest = max(deepest, task.plane_margin - float(heights.min()))
        if terminated or truncated:
            env.reset()
    elapsed = time.perf_counter() - start
    env.close()
    return contacts / steps, stops / steps, deepest, steps / elapsed


def measure(config: ContactConfig) -> list[ContactRow]:
    """One :class:`ContactRow` per contact model."""
    base = TaskSpec(region=config.region, n_joints=config.n_joints)
    friction = {"contact_friction": config.friction} if config.friction >= 0.0 else {}
    tasks = {m: base.replace(contact_model=m, **(friction if m == "compliant" else {}))
             for m in CONTACT_MODELS}
    reached = {m: reach_share(t, config.goals, config.seed) for m, t in tasks.items()}
    runs: dict[str, list[tuple[float, float, float, float]]] = {m: [] for m in tasks}
    for _ in range(config.rounds):
        for model, task in tasks.items():
            runs[model].append(random_steps(task, config.steps, config.seed))
    # shares and depth: the first round's (each round replays the seed); speed: the median
    return [ContactRow(m, reached[m], *runs[m][0][:3], statistics.median(r[3] for r in runs[m]))
            for m in tasks]


KINDS = kinds((integer(1), "goals", "steps", "rounds"), (SEED, "seed"),
              (number(note="dimensionless"), "friction"))
"""The checked flags' kinds (their words are in --help)."""


def _parser() -> argparse.ArgumentParser:
    parser = Parser(prog="python -m analysis.contact", description=__doc__,
                    formatter_class=argparse.RawDescriptionHelpFormatter)
    docs = field_docs(ContactConfig)
    for f in fields(ContactConfig):
        flag = "--joints" if f.name == "n_joints" else "--" + f.name.replace("_", "-")
        if f.type == "bool":
            parser.add_argument(flag, action="store_true", help=docs[f.name])
        else:
            kind = KINDS.get(f.name)
            valid = f" Valid: {kind.words}." if kind else ""
            parser.add_argument(flag, dest=f.name, default=f.default,
                                type=kind.read if kind else {"int": int, "str": str}[f.type],
                                help=f"{docs[f.name]}{valid} (default: {f.default})")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = _parser()
    args = parser.parse_args(argv)
    with usage_errors(parser, ValueError):
        TaskSpec(region=args.region, n_joints=args.n_joints)
    config = ContactConfig(**vars(args))
    from regions.samplers import UnreachableRegionError

    try:
        rows = measure(config)  # its first step samples the goals: no work is lost
    except UnreachableRegionError as err:
        parser.error(f"--region {args.region}: {err}")
    if config.json:
        print(json.dumps({"config": asdict(config), "rows": [asdict(r) for r in rows]},
                         indent=2))
        return 0
    stop = next(r for r in rows if r.contact_model == "stop")
    print(f"{config.region}, {config.n_joints} joints; {config.goals} goals, "
          f"{config.steps} random steps x {config.rounds} rounds, seed {config.seed}")
    print(f"{'model':<10} {'reached':>8} {'contact':>8} {'depth stop':>10} {'deepest m':>10} "
          f"{'steps/s':>8} {'vs stop':>8}")
    for r in rows:
        print(f"{r.contact_model:<10} {r.reached:>8.3f} {r.contact_share:>8.3f} "
              f"{r.depth_stops:>10.4f} {r.deepest:>10.4f} {r.steps_per_s:>8.0f} "
              f"{r.steps_per_s / stop.steps_per_s:>8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
