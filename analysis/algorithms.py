"""The algorithm study (issue 25): is the goal region's effect DDPG's alone, and does a regional
ensemble help? DDPG, TD3, SAC (each with HER) and a regional ensemble of 4 DDPG agents, on the
paper's 3-joint settings, resumable unit by unit.

    python -m analysis.algorithms --dry-run                 # every unit, its state and command
    python -m analysis.algorithms --workers 2 --threads 1   # train what is missing (resumable)
    python -m analysis.algorithms --collect results/algorithms   # spec.json, eval.csv of units
    python -m analysis.sensitivity report results/algorithms/runs --readings ddpg td3 sac ensemble

A unit is one algorithm x one setting x all seeds in one ``ddpg_her.train`` process, into
``ROOT/<algorithm>/<region>-j<joints>/s<seed>``: the layout, execution flags and report of
`analysis.sensitivity`, whose readings here are the algorithms (`ALGORITHMS`); its report (the
last line) draws the curves and judges the paper's claims per algorithm.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from analysis.readings import Reading
from analysis.sensitivity import add_study_arguments, run_study
from analysis.sweep import HelpFormatter
from ddpg_her.config import Parser
from ddpg_her.units import split_passthrough

ALGORITHMS: dict[str, Reading] = {r.name: r for r in (
    Reading("ddpg", ("--algo", "ddpg"),
            paper="DDPG + HER, Table I",
            ours="the paper's agent, every default"),
    Reading("td3", ("--algo", "td3"),
            paper="the paper asks whether the effect is \"general across Deep RL algorithms\"",
            ours="TD3 (Fujimoto et al. 2018: twin critics, target smoothing 0.2 clipped at 0.5, "
                 "actor every 2nd update); Table I's gamma, tau, rates, batch, buffer and "
                 "exploration noise; all else the defaults"),
    Reading("sac", ("--algo", "sac", "--exploration-rate", "0"),
            paper="the paper asks whether the effect is \"general across Deep RL algorithms\"",
            ours="SAC (Haarnoja et al. 2018: squashed Gaussian, twin critics, alpha tuned to "
                 "entropy -dim(A)), exploring by its own policy alone (no added noise); Table "
                 "I's gamma, tau, rates, batch and buffer; all else the defaults"),
    Reading("ensemble", ("--algo", "ddpg", "--ensemble", "4"),
            paper="\"a regional Deep RL ensemble algorithm may perform better\" (the paper's "
                  "closing section, on the unconstrained task)",
            ours="4 DDPG agents per seed, each owning one cell of a k-means partition of the "
                 "task's goals; the desired goal picks the agent in training and at test; a "
                 "transition, real or relabelled, trains the owner of its goal's cell; one "
                 "agent's budget (buffer, episodes, 100 updates per episode in all, 25 each); "
                 "all else the defaults"),
)}
"""The study's algorithms, as readings: the ``ddpg_her.train`` arguments of each."""

SETTINGS: tuple[tuple[str, int], ...] = (
    ("unconstrained", 3), ("zheight", 3), ("closebox", 3), ("farbox", 3))
"""The paper's regions with 3 joints: every region claim, one joint count (no confound)."""


def main(argv: Sequence[str] | None = None) -> int:
    argv, extra = split_passthrough(list(sys.argv[1:] if argv is None else argv))
    parser = Parser(
        prog="python -m analysis.algorithms", description=__doc__.split("\n\n")[0],
        epilog="Arguments after -- pass to every python -m ddpg_her.train (after the "
               "algorithm's own). Algorithms: " + "; ".join(
                   f"{r.name}: {' '.join(r.args)}" for r in ALGORITHMS.values()),
        formatter_class=HelpFormatter)
    parser.add_argument("--algos", nargs="+", choices=list(ALGORITHMS), default=list(ALGORITHMS),
                        metavar="NAME", help="algorithms to run, of " + ", ".join(ALGORITHMS)
                        + " (default: all)")
    add_study_arguments(parser, SETTINGS, Path("runs/algorithms"), "algorithm")
    args = parser.parse_args(argv)
    algos = [ALGORITHMS[name] for name in dict.fromkeys(args.algos)]
    return run_study(parser, args, algos, SETTINGS, extra)


if __name__ == "__main__":
    sys.exit(main())
