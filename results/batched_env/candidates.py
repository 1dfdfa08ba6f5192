"""The candidates for the batched dynamics, timed in one process with interleaved rounds.

    python results/batched_env/candidates.py            # from the repository root

Rows: the forward dynamics alone (B calls of ABA) through Pinocchio (a Python loop over
``pin.aba``; ``abaInParallel`` on one thread, what PinocchioDynamics uses) and the numba kernel of
envs.physics.numba_kernel; then a whole control step (20 substeps, PD + gravity, clips, plane and
limit stops) of PinocchioDynamics against NumbaDynamics. Times are per copy (per copy-step for the
steps), medians over the rounds, with each row's ratio to the Pinocchio reference.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import pinocchio as pin

import ur5kin
from envs.physics import numba_kernel
from envs.physics.pinocchio_loop import PinocchioDynamics
from envs.spec import TaskSpec
from envs.task import action_bounds


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--batch", type=int, default=64, help="copies B")
    parser.add_argument("--rounds", type=int, default=7, help="interleaved rounds")
    parser.add_argument("--steps", type=int, default=40, help="control steps per round")
    args = parser.parse_args(argv)
    B, rng = args.batch, np.random.default_rng(0)
    model = ur5kin.load_model()
    data, pool = model.createData(), pin.ModelPool(model, 1)
    q = rng.uniform(-np.pi, np.pi, (B, 6))
    v = rng.uniform(-3, 3, (B, 6))
    tau = rng.uniform(-1, 1, (B, 6)) * ur5kin.effort_limits()
    qT, vT, tT, out = q.T.copy(), v.T.copy(), tau.T.copy(), np.zeros((6, B))
    task = TaskSpec(region="unconstrained", n_joints=3)
    low, high = action_bounds(task)
    commands = rng.uniform(low, high, (args.steps, B, 3))
    arms = {"PinocchioDynamics (pinocchio)": PinocchioDynamics(task, B),
            "NumbaDynamics (numba)": numba_kernel.NumbaDynamics(task, B)}

    def aba_loop() -> None:
        for i in range(B):
            pin.aba(model, data, q[i], v[i], tau[i])

    def steps(dyn) -> None:
        for command in commands:
            dyn.step(command)

    rows = {
        "aba: pin.aba Python loop": (aba_loop, B),
        "aba: pin.abaInParallel (1 thread)": (
            lambda: pin.abaInParallel(1, pool, qT, vT, tT, out), B),
        "aba: numba_kernel.aba (numba)": (lambda: numba_kernel.aba(q, v, tau), B),
        **{f"step: {name}": (lambda d=dyn: steps(d), B * args.steps)
           for name, dyn in arms.items()},
    }
    for func, _ in rows.values():
        func()  # compile / warm up off the clock
    samples: dict[str, list[float]] = {name: [] for name in rows}
    for _ in range(args.rounds):
        for name, (func, count) in rows.items():
            start = time.perf_counter()
            func()
            samples[name].append((time.perf_counter() - start) / count * 1e6)
    reference = {"aba": statistics.median(samples["aba: pin.abaInParallel (1 thread)"]),
                 "step": statistics.median(samples["step: PinocchioDynamics (pinocchio)"])}
    print(f"B = {B}, {args.rounds} rounds; microseconds per copy (median, min-max)")
    for name, values in samples.items():
        med = statistics.median(values)
        print(f"{name:<40} {med:9.2f} us  ({min(values):.2f}-{max(values):.2f})  "
              f"x{reference[name.split(':')[0]] / med:5.2f} vs pinocchio")


if __name__ == "__main__":
    main()
