"""The reproduction report: a Markdown table per setting next to what the paper reports.

    python -m analysis.report RUNS_ROOT [--out report.md]

For each (region, joints): final and best test successes (mean and confidence interval over
seeds), the training episode where each seed first hits 90 of 100 goals, and the paper's
statement; then whether the paper's orderings hold in these runs.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.curves import REGION_ORDER
from analysis.paper import HIGH_SUCCESS, PAPER_GRID, PAPER_RESULTS
from analysis.runs import (
    CONFIDENCE,
    PERCENT,
    Run,
    add_runs_arguments,
    aligned_successes,
    mean_ci,
    settings_from_args,
)


@dataclass(frozen=True)
class SettingSummary:
    """Statistics of one (region, joints) setting over its seeds."""

    region: str
    joints: int
    seeds: int
    episodes: int
    """Last evaluation episode common to every seed."""
    final: tuple[float, float, float]
    """Successes at the last common evaluation: mean, CI low, CI high."""
    best: tuple[float, float, float]
    """Each seed's best evaluation: mean, CI low, CI high."""
    first_high: tuple[int | None, ...]
    """Per seed, the first evaluation episode with >= HIGH_SUCCESS successes (None: never)."""


def summarise(runs: Sequence[Run], level: float = CONFIDENCE) -> SettingSummary:
    episode, successes = aligned_successes(runs)
    if len(episode) == 0:
        raise ValueError(f"runs {[str(r.path) for r in runs]} share no evaluation episode")
    final = mean_ci(successes[:, -1], level, PERCENT)
    best = mean_ci(successes.max(axis=1), level, PERCENT)
    first = []
    for run in runs:
        hit = np.nonzero(run.successes >= HIGH_SUCCESS * run.tests / 100.0)[0]
        first.append(int(run.episode[hit[0]]) if len(hit) else None)
    as_tuple = lambda t: tuple(float(x) for x in t)  # noqa: E731
    return SettingSummary(runs[0].region, runs[0].joints, len(runs), int(episode[-1]),
                          as_tuple(final), as_tuple(best), tuple(first))


def _fmt(stat: tuple[float, float, float]) -> str:
    mean, low, high = stat
    return f"{mean:.1f} [{low:.1f}, {high:.1f}]" if high > low else f"{mean:.1f}"


def _first_high(first: tuple[int | None, ...]) -> str:
    reached = sorted(e for e in first if e is not None)
    if not reached:
        return f"never (0/{len(first)})"
    return f"median {int(np.median(reached))} ({len(reached)}/{len(first)} seeds)"


def ordering_checks(
    summaries: dict[tuple[str, int], SettingSummary],
) -> list[tuple[str, bool | None, str]]:
    """The paper's claims, each as (claim, holds or None when the settings are missing, detail)."""
    final = {k: s.final[0] for k, s in summaries.items()}
    checks = []

    def compare(claim: str, high: list[tuple[str, int]], low: list[tuple[str, int]],
                margin: float) -> None:
        hi = [final[k] for k in high if k in final]
        lo = [final[k] for k in low if k in final]
        missing = [f"{r} {n}" for r, n in high + low if (r, n) in PAPER_GRID
                   and (r, n) not in final]
        if not hi or not lo:
            checks.append((claim, None, "settings missing: " + ", ".join(missing)))
            return
        holds = min(hi) >= max(lo) + margin
        detail = (f"lowest of the first {min(hi):.1f}, highest of the second {max(lo):.1f} "
                  f"(margin {margin:g})")
        if missing:
            detail += "; on the settings run only, missing: " + ", ".join(missing)
        checks.append((claim, holds, detail))

    joints = range(3, 7)
    compare("farbox far above unconstrained (3-6 joints)",
            [("farbox", n) for n in joints], [("unconstrained", n) for n in joints], 20.0)
    compare("unconstrained (3-6 joints) above zheight and closebox",
            [("unconstrained", n) for n in joints],
            [(r, n) for r in ("zheight", "closebox") for n in joints], 0.0)
    if ("unconstrained", 2) in final:
        holds = final[("unconstrained", 2)] >= HIGH_SUCCESS
        checks.append(("2 joints high (unconstrained)", holds,
                       f"final {final[('unconstrained', 2)]:.1f} vs {HIGH_SUCCESS:g}"))
    else:
        checks.append(("2 joints high (unconstrained)", None, "setting missing"))
    return checks


def render(summaries: dict[tuple[str, int], SettingSummary], level: float) -> str:
    lines = ["# Reproduction report: Lewis, Moll and Kavraki (2019)", "",
             f"Successes per 100 test goals; mean over seeds with a {level:.0%} Student-t "
             "confidence interval in brackets.", "",
             "| region | joints | seeds | episodes | final | best | first >= "
             f"{HIGH_SUCCESS:g} | paper |",
             "|---|---|---|---|---|---|---|---|"]
    order = sorted(summaries, key=lambda k: (
        REGION_ORDER.index(k[0]) if k[0] in REGION_ORDER else 99, k[0], k[1]))
    for key in order:
        s = summaries[key]
        paper = PAPER_RESULTS.get(key)
        lines.append(f"| {s.region} | {s.joints} | {s.seeds} | {s.episodes} | {_fmt(s.final)} | "
                     f"{_fmt(s.best)} | {_first_high(s.first_high)} | "
                     f"{paper.text if paper else 'not in the paper'} |")
    lines += ["", "## The paper's orderings", "", "| claim | holds here | detail |",
              "|---|---|---|"]
    for claim, holds, detail in ordering_checks(summaries):
        verdict = {True: "yes", False: "**no**", None: "not run"}[holds]
        lines.append(f"| {claim} | {verdict} | {detail} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m analysis.report", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_runs_arguments(parser)
    parser.add_argument("--out", type=Path, default=None,
                        help="also write the Markdown to this file")
    args = parser.parse_args(argv)
    groups = settings_from_args(parser, args)
    summaries = {k: summarise(v, args.confidence) for k, v in groups.items()}
    text = render(summaries, args.confidence)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
