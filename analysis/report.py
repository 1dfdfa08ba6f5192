"""The reproduction report: a Markdown table per setting next to what the paper reports.

    python -m analysis.report RUNS_ROOT [--out report.md]

For each (region, joints): final and best test successes (mean and confidence interval over
seeds), the training episode where each seed first hits 90 of 100 goals, and the paper's
statement; then whether the paper's orderings hold in these runs.
"""

from __future__ import annotations

import argparse
import enum
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.paper import (
    HIGH_SUCCESS,
    PAPER_EPISODES,
    PAPER_GRID,
    PAPER_RESULTS,
    PAPER_SEEDS,
)
from analysis.readings import run_choices
from analysis.runs import (
    CONFIDENCE,
    PERCENT,
    Run,
    add_runs_arguments,
    aligned_successes,
    mean_ci,
    settings_from_args,
)
from regions.registry import paper_order

READING_NOTE = (
    "Defaults and why: docs/design.md, open points 3-6; what the other readings do to each "
    "claim: results/sensitivity (python -m analysis.sensitivity).")
"""Where the report sends a reader for the reading's reasons and the other readings."""


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
    choices: tuple[dict[str, str], ...] = ()
    """Per seed, the paper's unstated choices it was trained under (`analysis.readings.
    run_choices`)."""


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
                          as_tuple(final), as_tuple(best), tuple(first),
                          tuple(run_choices(r.spec) for r in runs))


def reading_lines(summaries: dict[tuple[str, int], SettingSummary]) -> list[str]:
    """Markdown: the unstated choices the runs were trained under, one row per choice.

    A choice whose value differs between runs lists each value with its settings, and the
    section warns that the claims then compare settings trained under different readings.
    """
    rows, mixed = [], False
    names = [n for s in summaries.values() for c in s.choices for n in c]
    for name in dict.fromkeys(names):
        where: dict[str, list[str]] = {}
        for key in sorted(summaries, key=lambda k: (*paper_order(k[0]), k[1])):
            for value in dict.fromkeys(c[name] for c in summaries[key].choices):
                where.setdefault(value, []).append(f"{key[0]} {key[1]}")
        if len(where) == 1:
            rows.append(f"| {name} | {next(iter(where))} |")
        else:
            mixed = True
            rows.append(f"| {name} | " + "; ".join(f"**{v}** ({', '.join(s)})"
                                                   for v, s in where.items()) + " |")
    if not rows:
        return []
    lines = ["## The reading of the paper's unstated choices", "",
             "What these runs chose where the paper is silent (their `spec.json`). "
             + READING_NOTE, "", "| choice | value |", "|---|---|", *rows]
    if mixed:
        lines += ["", "**These runs mix readings**: a claim below may compare settings trained "
                      "under different choices."]
    return [*lines, ""]


def _fmt(stat: tuple[float, float, float]) -> str:
    mean, low, high = stat
    return f"{mean:.1f} [{low:.1f}, {high:.1f}]" if high > low else f"{mean:.1f}"


def _first_high(first: tuple[int | None, ...]) -> str:
    reached = sorted(e for e in first if e is not None)
    if not reached:
        return f"never (0/{len(first)})"
    return f"median {int(np.median(reached))} ({len(reached)}/{len(first)} seeds)"


class Verdict(str, enum.Enum):
    """Whether one of the paper's claims holds in these runs, judged on the confidence intervals."""

    YES = "yes"
    NO = "**no**"
    NOISE = "within noise"
    """The intervals overlap: these seeds can't tell."""
    NOT_RUN = "not run"


_CLAIM_JOINTS = range(3, 7)

ORDERING_CLAIMS: dict[str, tuple[tuple[tuple[str, int], ...], tuple[tuple[str, int], ...],
                                 float]] = {
    "farbox far above unconstrained (3-6 joints)": (
        tuple(("farbox", n) for n in _CLAIM_JOINTS),
        tuple(("unconstrained", n) for n in _CLAIM_JOINTS), 20.0),
    "unconstrained (3-6 joints) above zheight and closebox": (
        tuple(("unconstrained", n) for n in _CLAIM_JOINTS),
        tuple((r, n) for r in ("zheight", "closebox") for n in _CLAIM_JOINTS), 0.0),
}
"""The paper's orderings (section IV): claim -> (settings claimed higher, settings claimed
lower, the gap in successes per 100 goals the claim needs: "far above" reads as 20)."""

HIGH_CLAIM: tuple[str, tuple[str, int]] = ("2 joints high (unconstrained)", ("unconstrained", 2))
"""The paper's "highly capable policy" with 2 joints: the setting's interval against
`HIGH_SUCCESS`."""


def _stat(name: tuple[str, int], stat: tuple[float, float, float]) -> str:
    return f"{name[0]} {name[1]} {_fmt(stat)}"


def ordering_checks(
    summaries: dict[tuple[str, int], SettingSummary],
) -> list[tuple[str, Verdict, str]]:
    """The paper's claims, each as (claim, verdict, detail), on the final successes'
    Student-t intervals (see `judge_claims`)."""
    return judge_claims({k: s.final for k, s in summaries.items()})


def judge_claims(
    final: dict[tuple[str, int], tuple[float, float, float]],
) -> list[tuple[str, Verdict, str]]:
    """The paper's claims, each as (claim, verdict, detail), on one interval per setting.

    Parameters
    ----------
    final : {(region, joints): (estimate, low, high)}, successes per 100 test goals
        Any point estimate with its interval: the mean with its Student-t interval (the
        report), or a bootstrap interval of the mean or the IQM (analysis.sensitivity).

    "A above B" compares the weakest setting of A with the strongest of B (by estimate): YES
    when their intervals are apart in the claimed order and the estimates differ by at least
    the claim's margin; NO when the order is reversed with intervals apart, or when even the
    intervals' far ends are less than the margin apart; otherwise NOISE. "2 joints high": YES
    when the interval lies at or above `HIGH_SUCCESS`, NO when it lies below, else NOISE.
    """
    checks = []

    def compare(claim: str, high: list[tuple[str, int]], low: list[tuple[str, int]],
                margin: float) -> None:
        hi = [k for k in high if k in final]
        lo = [k for k in low if k in final]
        missing = [f"{r} {n}" for r, n in high + low if (r, n) in PAPER_GRID
                   and (r, n) not in final]
        if not hi or not lo:
            checks.append((claim, Verdict.NOT_RUN, "settings missing: " + ", ".join(missing)))
            return
        h = min(hi, key=lambda k: final[k][0])
        lo_k = max(lo, key=lambda k: final[k][0])
        (h_mean, h_low, h_high), (l_mean, l_low, l_high) = final[h], final[lo_k]
        if h_low > l_high and h_mean - l_mean >= margin:
            verdict = Verdict.YES
        elif l_low > h_high or h_high - l_low < margin:
            verdict = Verdict.NO
        else:
            verdict = Verdict.NOISE
        detail = (f"weakest of the first: {_stat(h, final[h])}; strongest of the second: "
                  f"{_stat(lo_k, final[lo_k])}"
                  + (f"; the claim needs a gap of {margin:g}" if margin else ""))
        if missing:
            detail += "; on the settings run only, missing: " + ", ".join(missing)
        checks.append((claim, verdict, detail))

    for claim, (high, low, margin) in ORDERING_CLAIMS.items():
        compare(claim, list(high), list(low), margin)
    claim, key = HIGH_CLAIM
    if key in final:
        _, low, high = final[key]
        verdict = (Verdict.YES if low >= HIGH_SUCCESS else
                   Verdict.NO if high < HIGH_SUCCESS else Verdict.NOISE)
        checks.append((claim, verdict, f"{_stat(key, final[key])} against {HIGH_SUCCESS:g}"))
    else:
        checks.append((claim, Verdict.NOT_RUN, "setting missing"))
    return checks


def claim_settings() -> dict[str, tuple[tuple[str, int], ...]]:
    """Each claim of `judge_claims` -> the (region, joints) settings it looks at."""
    out = {claim: (*high, *low) for claim, (high, low, _) in ORDERING_CLAIMS.items()}
    out[HIGH_CLAIM[0]] = (HIGH_CLAIM[1],)
    return out


def render(summaries: dict[tuple[str, int], SettingSummary], level: float) -> str:
    episodes = sorted({s.episodes for s in summaries.values()})
    seeds = sorted({s.seeds for s in summaries.values()})
    span = lambda v: f"{v[0]:,}" if len(v) == 1 else f"{v[0]:,}-{v[-1]:,}"  # noqa: E731
    in_grid = sum(k in PAPER_GRID for k in summaries)
    others = len(summaries) - in_grid
    budget = (f"Budget: {span(episodes)} training episodes per run "
              f"({'up to ' if len(episodes) > 1 else ''}{episodes[-1] / PAPER_EPISODES:.1%} of the "
              f"paper's {PAPER_EPISODES:,}), "
              f"{span(seeds)} seeds per setting (the paper: {PAPER_SEEDS}); {in_grid} of the "
              f"paper's {len(PAPER_GRID)} settings" + (f" and {others} others." if others else "."))
    lines = ["# Reproduction report: Lewis, Moll and Kavraki (2019)", "", budget, "",
             f"Successes per 100 test goals; mean over seeds with a {level:.0%} Student-t "
             "confidence interval in brackets.", "",
             "| region | joints | seeds | episodes | final | best | first >= "
             f"{HIGH_SUCCESS:g} | paper |",
             "|---|---|---|---|---|---|---|---|"]
    order = sorted(summaries, key=lambda k: (*paper_order(k[0]), k[1]))
    for key in order:
        s = summaries[key]
        paper = PAPER_RESULTS.get(key)
        lines.append(f"| {s.region} | {s.joints} | {s.seeds} | {s.episodes} | {_fmt(s.final)} | "
                     f"{_fmt(s.best)} | {_first_high(s.first_high)} | "
                     f"{paper.text if paper else 'not in the paper'} |")
    lines += ["", *reading_lines(summaries), "## The paper's orderings", "",
              "Judged on the final successes' confidence intervals: *yes* when they lie apart in "
              "the claimed order (and as far apart as the claim says), ***no*** when they lie "
              "apart the other way or can't be as far apart as claimed, *within noise* when "
              "they overlap.", "",
              "| claim | holds here | detail |", "|---|---|---|"]
    for claim, verdict, detail in ordering_checks(summaries):
        lines.append(f"| {claim} | {verdict.value} | {detail} |")
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
