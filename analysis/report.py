"""The reproduction report: our numbers per setting next to the paper's, and every claim of the
paper judged by one stated rule.

    python -m analysis.report RUNS_ROOT [--out report.md]
    python -m analysis.report --groups box=runs/box mesh=runs/mesh   # compare any two groups

For each (region, joints): each seed's mean over its last 5 test sessions and its best session
(mean and confidence interval over seeds), the training episode where each seed first hits 90 of
100 goals, and the paper's statement; then every claim of the paper's section IV
(`analysis.paper.CLAIMS`), each *holds*, *fails*, *within noise*, *not judgeable* or *not run*.

With ``--group-by FIELD`` or ``--groups NAME=DIR ...`` it compares groups instead
(`comparison`): each group's statistics, and every pair judged by the same rule.

The verdict rule is `rule_lines`, printed with every report and stated in docs/design.md ("What
the paper reports"), with the plateau rule (`analysis.plateau`) for runs shorter than the
paper's; `judge_claims` applies it.
"""

from __future__ import annotations

import argparse
import enum
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from analysis.outputs import add_force, check_writable, usage_errors, write_errors, write_text
from analysis.paper import (
    CLAIMS,
    FAST_EPISODES,
    FAST_MISSES,
    HIGH_SUCCESS,
    PAPER_EPISODES,
    PAPER_GRID,
    PAPER_RESULTS,
    PAPER_SEEDS,
    UNDER_SUCCESS,
    PaperClaim,
)
from analysis.plateau import (
    DECIDING_LEVEL,
    MODELS,
    PLATEAU_BAND,
    PLATEAU_MIN_SESSIONS,
    PLATEAU_WINDOW,
    Plateau,
    plateau,
    stages,
)
from analysis.readings import run_choices
from analysis.runs import (
    CONFIDENCE,
    PERCENT,
    Group,
    Run,
    add_runs_arguments,
    aligned_successes,
    groups_from_args,
    mean_ci,
    pooled_lines,
    settings_from_args,
)
from ddpg_her.config import Parser
from regions.registry import default_start, paper_order

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
    """Each seed's mean successes over its last `LAST_SESSIONS` common test sessions: mean
    over seeds, CI low, CI high."""
    best: tuple[float, float, float]
    """Each seed's best evaluation: mean, CI low, CI high."""
    first_high: tuple[int | None, ...]
    """Per seed, the first evaluation episode with >= HIGH_SUCCESS successes (None: never)."""
    choices: tuple[dict[str, str], ...] = ()
    """Per seed, the paper's unstated choices it was trained under (`analysis.readings.
    run_choices`)."""
    curves: Curves | None = None
    """The seeds' common test sessions, which the claims are judged on."""


def summarise(runs: Sequence[Run], level: float = CONFIDENCE) -> SettingSummary:
    """One setting's statistics over its seeds (see `SettingSummary`)."""
    curves = Curves.of(runs)
    interval = student_t(level)
    first = tuple(int(run.episode[hit[0]]) if len(hit) else None for run in runs
                  for hit in [np.nonzero(run.successes >= HIGH_SUCCESS * run.tests / 100.0)[0]])
    return SettingSummary(runs[0].region, runs[0].joints, len(runs), curves.end,
                          interval(curves.level(), PERCENT),
                          interval(curves.percent.max(axis=1), PERCENT), first,
                          tuple(run_choices(r.spec) for r in runs), curves)


def reading_lines(summaries: dict[tuple[str, int], SettingSummary]) -> list[str]:
    """Markdown: the unstated choices the runs were trained under, one row per choice.

    A choice whose value differs between runs lists each value with its settings, and the
    section warns that the claims then compare settings trained under different readings.
    """
    rows, mixed = [], False
    for name in dict.fromkeys(n for s in summaries.values() for c in s.choices for n in c):
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


def fmt_interval(stat: tuple[float, float, float], digits: int = 1) -> str:
    mean, low, high = stat
    return (f"{mean:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]" if high > low
            else f"{mean:.{digits}f}")


def _first_high(first: tuple[int | None, ...]) -> str:
    reached = sorted(e for e in first if e is not None)
    if not reached:
        return f"never (0/{len(first)})"
    return f"median {int(np.median(reached))} ({len(reached)}/{len(first)} seeds)"


class Verdict(str, enum.Enum):
    """Whether one of the paper's claims holds in these runs (the rule: `rule_lines`)."""

    YES = "holds"
    NO = "fails"
    NOISE = "within noise"
    """The intervals overlap: these seeds can't tell."""
    NOT_JUDGEABLE = "not judgeable"
    """The runs cannot show it: below the paper's budget for a claim about where training ends,
    or data the report does not read (success maps)."""
    NOT_RUN = "not run"
    """A setting the claim needs has no runs."""


LAST_SESSIONS = 5
"""Level claims are judged on each seed's mean over its last 5 test sessions at the point
judged (500 episodes at the paper's pace), never on one session of 100 test goals."""

ABOUT_TOLERANCE = 10.0
"""'about X %': the interval must lie within X +- 10 successes per 100 (our reading)."""

ALIKE_TOLERANCE = 10.0
"""'identical', 'approximately equivalent', 'similar': every interval within one band 10
successes per 100 wide (our reading)."""

CONVERGED_GAP = 5.0
"""A seed has converged at its first test session within 5 successes per 100 of its level
(the mean of its last `LAST_SESSIONS` sessions); 'slower to converge' compares those
episodes."""

Interval = tuple[float, float, float]
"""(estimate, low, high)."""

IntervalFn = Callable[[np.ndarray, tuple[float, float]], Interval]
"""Per-seed values (n_seeds,) and their feasible range -> an estimate with its interval."""


def student_t(level: float = CONFIDENCE) -> IntervalFn:
    """The paper's interval: the mean over seeds with its two-sided Student-t interval
    (`analysis.runs.mean_ci`), clipped to the values' feasible range."""
    def interval(values: np.ndarray, bounds: tuple[float, float]) -> Interval:
        return tuple(float(x) for x in mean_ci(np.asarray(values, float), level, bounds))
    return interval


@dataclass(frozen=True)
class Curves:
    """One setting's seeds on their common test sessions, up to the point judged."""

    episode: np.ndarray
    """(T,) int: training episodes at each test session."""
    percent: np.ndarray
    """(n_seeds, T) float: goals hit per 100 test goals."""

    @classmethod
    def of(cls, runs: Sequence[Run], upto: int | None = None) -> Curves:
        """The runs' common sessions (`analysis.runs.aligned_successes`), those after ``upto``
        (training episodes) dropped."""
        curves = cls(*aligned_successes(runs))
        if upto is not None:
            curves = curves.until(upto)
        if not len(curves.episode):
            raise ValueError(f"runs {[str(r.path) for r in runs]} share no test session"
                             + (f" at or below episode {upto}" if upto is not None else ""))
        return curves

    def until(self, end: int) -> Curves:
        """The sessions at or below ``end`` training episodes (settings compared at one
        budget)."""
        keep = self.episode <= end
        return Curves(self.episode[keep], self.percent[:, keep])

    @property
    def end(self) -> int:
        """The last session judged (training episodes)."""
        return int(self.episode[-1])

    def level(self) -> np.ndarray:
        """(n_seeds,) float: each seed's mean successes per 100 over its last
        `LAST_SESSIONS` sessions."""
        return self.percent[:, -LAST_SESSIONS:].mean(axis=1)


@dataclass(frozen=True)
class Check:
    """One claim judged: the verdict, what it rests on, and what else differs."""

    claim: str
    verdict: Verdict
    detail: str
    p_value: float | None = None
    """Two-sided Welch p over seeds of the claim's comparison (None: none, or several, each
    named in the detail: `analysis.claims`)."""
    confounds: tuple[str, ...] = ()
    """What differs between the compared settings besides what the claim is about."""
    plateau_at: int | None = None
    """A claim about where training ends judged below the paper's budget because every setting
    it compares has plateaued (`analysis.plateau`): the budget it was judged at (episodes)."""


def welch_p(a: np.ndarray, b: np.ndarray) -> float:
    """Two-sided Welch t-test p-value of two groups of seeds (nan when it is undefined: fewer
    than 2 seeds, or no spread in either group)."""
    from scipy import stats

    a, b = np.asarray(a, float), np.asarray(b, float)
    if min(len(a), len(b)) < 2 or (a.std() == 0 and b.std() == 0):
        return float("nan")
    with warnings.catch_warnings():
        # a group of equal values (a far box at 100 in every seed) is exact, not imprecise
        warnings.filterwarnings("ignore", "Precision loss occurred", RuntimeWarning)
        return float(stats.ttest_ind(a, b, equal_var=False).pvalue)


ZERO_POSE_TOOL = (0.8173, 0.1915, 0.0945)
"""Where tool0 sits with every joint at 0 rad (m, world frame, base at 0.1 m; tested against
`ur5kin.fk_world`): the command eq. 2's penalty costs nothing for, inside every region of
the paper, the far box the smallest of them."""


def confounds(a: tuple[str, int], b: tuple[str, int]) -> tuple[str, ...]:
    """What differs between settings ``a`` and ``b`` besides their regions."""
    out = []
    if a[1] != b[1]:
        out.append(f"{a[1]} vs {b[1]} joints")
    start = {k: default_start(k[0]) for k in (a, b)}
    if start[a] != start[b]:
        out.append(f"another start pose ({a[0]}: {_pose(start[a])}, {b[0]}: {_pose(start[b])})")
    far = [k[0] for k in (a, b) if k[0].startswith("farbox")]
    if len(far) == 1:
        out.append("the penalty-free command (all joints 0 rad) puts tool0 at "
                   f"({', '.join(f'{x:.2f}' for x in ZERO_POSE_TOOL)}) m, inside the far box "
                   "(the smallest region that holds it)")
    return tuple(out)


def _pose(q: tuple[float, ...]) -> str:
    names = {0.0: "0", np.pi / 4: "pi/4", -np.pi / 4: "-pi/4", np.pi / 2: "pi/2"}
    return "[" + ", ".join(next((n for v, n in names.items() if abs(v - x) < 1e-12), f"{x:.3g}")
                           for x in q) + "]"


FAR = tuple(("farbox", n) for n in range(3, 7))
UNC = tuple(("unconstrained", n) for n in range(3, 7))
CONSTRAINED = tuple((r, n) for r in ("zheight", "closebox") for n in range(3, 7))
"""The settings with 3-6 joints of the far box, the unconstrained region and the two other
constrained regions, which the claims compare."""


def _name(key: tuple[str, int]) -> str:
    return f"{key[0]} {key[1]}"


def _stat(key: tuple[str, int], stat: Interval) -> str:
    return f"{_name(key)} {fmt_interval(stat)}"


def _verdict(yes: bool, no: bool) -> Verdict:
    """YES when ``yes``, else NO when ``no``, else NOISE."""
    return Verdict.YES if yes else Verdict.NO if no else Verdict.NOISE


def apart(a: Interval, b: Interval) -> Verdict:
    """YES when interval ``a`` lies above ``b``, NO when below, NOISE when they overlap."""
    return _verdict(a[1] > b[2], b[1] > a[2])


def overall(each: Sequence[Verdict]) -> Verdict:
    """A claim's verdict from its parts': fails when one fails, holds when all hold."""
    return _verdict(all(v is Verdict.YES for v in each), Verdict.NO in each)


def _least(ps: Sequence[float]) -> float:
    """The smallest of several p-values (nan when one is undefined)."""
    return min(ps) if all(np.isfinite(ps)) else float("nan")


def judge_claims(curves: Mapping[tuple[str, int], Curves],
                 interval: IntervalFn | None = None,
                 plateaus: Mapping[tuple[str, int], Plateau] | None = None) -> list[Check]:
    """Every claim of `analysis.paper.CLAIMS`, in its order, judged by the module's rule.

    Parameters
    ----------
    curves : {(region, joints): Curves}
        Each setting's seeds up to the point judged (the runs' end, or a study's budget).
    interval : IntervalFn
        The interval of the per-seed values (default: the paper's 65 % Student-t,
        `student_t`; `analysis.sensitivity` also passes bootstrap intervals of the mean and
        the IQM). The Welch p-values do not depend on it.
    plateaus : {(region, joints): Plateau}, optional
        The plateau rule applied to each setting at the point judged. Given, a claim about
        where training ends on runs below the paper's budget can *fail* there (labelled with
        the budget) when every setting it compares has plateaued, judged on intervals widened
        by each setting's extrapolated change to the budget (`Plateau.reach`); it never holds
        there, and is *not judgeable at N episodes* otherwise; not given, every such claim is
        not judgeable.
    """
    interval = interval or student_t()
    level = {k: c.level() for k, c in curves.items()}
    now = {k: interval(v, PERCENT) for k, v in level.items()}
    at_budget = dict(now)  # a plateaued short setting's level carried to the paper's budget
    for k, pl in (plateaus or {}).items():
        if k in now and curves[k].end < PAPER_EPISODES and pl.plateaued:
            low, high = pl.reach()
            at_budget[k] = (now[k][0], now[k][1] + min(low, 0.0), now[k][2] + max(high, 0.0))
    stat = dict(now)  # the judges read this; set per claim below

    def present(keys: Sequence[tuple[str, int]]) -> list[tuple[str, int]]:
        return [k for k in keys if k in curves]

    def judged(claim: PaperClaim, keys: Sequence[tuple[str, int]], verdict: Verdict,
               what: str, p: float | None = None, conf: tuple[str, ...] = ()) -> Check:
        """The verdict, or NOT_JUDGEABLE for a claim about the end of training on shorter runs
        (with the verdict so far and what the runs show as information)."""
        short = [k for k in keys if curves[k].end < PAPER_EPISODES]
        if not claim.at_end or not short:
            return Check(claim.name, verdict, what, p, conf)
        ends = sorted({curves[k].end for k in short})
        at = ", ".join(f"{e:,}" for e in ends)
        so_far = f". So far ({VERDICT_WORDS_SO_FAR[verdict]}): {what}"
        if plateaus is not None and all(plateaus[k].plateaued for k in short):
            if verdict is Verdict.NO:
                return Check(claim.name, verdict,
                             f"judged at the plateau of every setting it compares ({at} "
                             f"episodes, the plateau rule; intervals widened by the change "
                             f"extrapolated to {PAPER_EPISODES:,}): {what}", p, conf,
                             plateau_at=max(ends))
            why = (f"every setting it compares has plateaued at {at} episodes, but a claim "
                   f"about where training ends never holds before the paper's {PAPER_EPISODES:,}")
        else:
            why = (f"a claim about where training ends; these runs end at {at} episodes, below "
                   f"the paper's {PAPER_EPISODES:,}")
            if plateaus is not None:
                why += "; not plateaued by the plateau rule: " + ", ".join(
                    _name(k) for k in short if not plateaus[k].plateaued)
        return Check(claim.name, Verdict.NOT_JUDGEABLE, why + so_far, p, conf)

    def missing(keys: Sequence[tuple[str, int]]) -> str:
        lack = [_name(k) for k in keys if k in PAPER_GRID and k not in curves]
        return "; on the settings run only, missing: " + ", ".join(lack) if lack else ""

    def not_run(claim: PaperClaim, keys: Sequence[tuple[str, int]]) -> Check:
        """NOT_RUN, naming the missing settings (of a region in the paper's grid, only the
        joint counts the paper ran)."""
        grid_regions = {r for r, _ in PAPER_GRID}
        keys = [k for k in keys if k in PAPER_GRID or k[0] not in grid_regions]
        return Check(claim.name, Verdict.NOT_RUN,
                     "settings missing: " + ", ".join(_name(k) for k in keys))

    def fast(claim: PaperClaim, joints: int) -> Check:
        key = ("farbox", joints)
        if key not in curves:
            return not_run(claim, [key])
        c = curves[key]
        if c.end < FAST_EPISODES:
            return Check(claim.name, Verdict.NOT_JUDGEABLE,
                         f"these runs end at {c.end:,} episodes, before {FAST_EPISODES:,}")
        early = c.percent[:, c.episode <= FAST_EPISODES]
        reached = int((early >= HIGH_SUCCESS).any(axis=1).sum())
        allowed = FAST_MISSES[joints]
        n = len(c.percent)
        verdict = Verdict.YES if n - reached <= allowed else Verdict.NO
        return Check(claim.name, verdict,
                     f"{reached} of {n} seeds hit >= {HIGH_SUCCESS:g} in a test session by "
                     f"episode {FAST_EPISODES:,} (the claim allows {allowed} to miss); seeds' "
                     f"last {LAST_SESSIONS} sessions to {FAST_EPISODES:,}: "
                     + ", ".join(f"{v:.0f}" for v in early[:, -LAST_SESSIONS:].mean(axis=1)))

    def order(claim: PaperClaim, high: Sequence[tuple[str, int]],
              low: Sequence[tuple[str, int]]) -> Check:
        hi, lo = present(high), present(low)
        if not hi or not lo:
            return not_run(claim, [k for k in (*high, *low) if k not in curves])
        # the weakest of A against the strongest of B with as many joints, the closest such
        # pair deciding; across joint counts (a confound) only when no count has both
        pairs = [(min(h_n, key=lambda k: stat[k][0]), max(l_n, key=lambda k: stat[k][0]))
                 for n in sorted({k[1] for k in hi} & {k[1] for k in lo})
                 for h_n, l_n in [([k for k in hi if k[1] == n], [k for k in lo if k[1] == n])]]
        if not pairs:
            pairs = [(min(hi, key=lambda k: stat[k][0]), max(lo, key=lambda k: stat[k][0]))]
        h, l_ = min(pairs, key=lambda pair: stat[pair[0]][0] - stat[pair[1]][0])
        detail = (f"weakest of the first: {_stat(h, stat[h])}; strongest of the second"
                  f"{' (as many joints)' if h[1] == l_[1] else ''}: {_stat(l_, stat[l_])}"
                  + missing([*high, *low]))
        return judged(claim, [*hi, *lo], apart(stat[h], stat[l_]), detail,
                      welch_p(level[h], level[l_]), confounds(h, l_))

    def threshold(claim: PaperClaim, keys: Sequence[tuple[str, int]], bound: float,
                  above: bool) -> Check:
        have = present(keys)
        if not have:
            return not_run(claim, keys)
        k = (min if above else max)(have, key=lambda k: stat[k][0])
        over, under = stat[k][1] >= bound, stat[k][2] < bound
        verdict = _verdict(over, under) if above else _verdict(under, over)
        return judged(claim, have, verdict, f"{'weakest' if above else 'strongest'}: "
                      f"{_stat(k, stat[k])} against {bound:g}" + missing(keys))

    def about(claim: PaperClaim, keys: Sequence[tuple[str, int]], target: float) -> Check:
        have = present(keys)
        if not have:
            return not_run(claim, keys)
        lo_b, hi_b = target - ABOUT_TOLERANCE, target + ABOUT_TOLERANCE
        each = [_verdict(lo_b <= stat[k][1] and stat[k][2] <= hi_b,
                         stat[k][2] < lo_b or stat[k][1] > hi_b) for k in have]
        return judged(claim, have, overall(each), ", ".join(_stat(k, stat[k]) for k in have)
                      + f" against {lo_b:g}-{hi_b:g}" + missing(keys))

    def alike(claim: PaperClaim, groups: Sequence[Sequence[tuple[str, int]]]) -> Check:
        asked = [k for g in groups for k in g]
        groups = [g for g in (present(g) for g in groups) if len(g) >= 2]
        if not groups:
            return not_run(claim, [k for k in asked if k not in curves])
        each, parts, ps, conf = [], [], [], []
        for g in groups:
            _, lows, highs = zip(*(stat[k] for k in g), strict=True)
            each.append(_verdict(max(highs) - min(lows) <= ALIKE_TOLERANCE,
                                 max(lows) > min(highs)))
            weak, strong = min(g, key=lambda k: stat[k][0]), max(g, key=lambda k: stat[k][0])
            ps.append(welch_p(level[weak], level[strong]))
            conf += [c for c in confounds(weak, strong) if c not in conf]
            parts.append(", ".join(_stat(k, stat[k]) for k in g))
        return judged(claim, [k for g in groups for k in g], overall(each),
                      "; ".join(parts) + f"; the claim allows a band {ALIKE_TOLERANCE:g} wide",
                      _least(ps), tuple(conf))

    def slower(claim: PaperClaim) -> Check:
        pairs = [((r, 6), (r, 3)) for r in ("zheight", "closebox")
                 if (r, 6) in curves and (r, 3) in curves]
        if not pairs:
            return not_run(claim, [(r, n) for r in ("zheight", "closebox") for n in (3, 6)
                                   if (r, n) not in curves])
        at = {}
        for key in {k for pair in pairs for k in pair}:
            c = curves[key]
            near = c.percent >= (c.level() - CONVERGED_GAP)[:, None]
            at[key] = c.episode[near.argmax(axis=1)].astype(float)
        each, parts, ps = [], [], []
        for six, three in pairs:
            s, t = (interval(at[k], (0.0, np.inf)) for k in (six, three))
            each.append(apart(s, t))
            ps.append(welch_p(at[six], at[three]))
            parts.append(f"{six[0]}: converged at episode {fmt_interval(s, 0)} (6 joints) vs "
                         f"{fmt_interval(t, 0)} (3 joints)")
        return judged(claim, [k for pair in pairs for k in pair], overall(each),
                      "; ".join(parts), _least(ps))

    def success_maps(claim: PaperClaim) -> Check:
        key = ("unconstrained", 3)
        ends = f"these runs end at {curves[key].end:,} episodes; " if key in curves else ""
        return Check(claim.name, Verdict.NOT_JUDGEABLE,
                     f"{ends}judgeable only from success maps (python -m analysis.success_map) "
                     f"of two converged (about 40 %) policies at the paper's {PAPER_EPISODES:,} "
                     "episodes; this report reads no success maps")

    judges = [  # in the order of CLAIMS
        lambda c: fast(c, 3),
        lambda c: fast(c, 6),
        lambda c: order(c, FAR, UNC + CONSTRAINED),
        lambda c: threshold(c, [("unconstrained", 2)], HIGH_SUCCESS, above=True),
        lambda c: threshold(c, UNC, UNDER_SUCCESS, above=False),
        lambda c: about(c, UNC, PAPER_RESULTS[("unconstrained", 3)].approx_success),
        lambda c: alike(c, [UNC]),
        lambda c: about(c, CONSTRAINED, PAPER_RESULTS[("zheight", 3)].approx_success),
        lambda c: alike(c, [[("zheight", n), ("closebox", n)] for n in (3, 6)]),
        lambda c: order(c, UNC, CONSTRAINED),
        slower,
        lambda c: alike(c, [[("farbox_tall", n), ("farbox", n)] for n in (3, 6)]),
        success_maps,
    ]
    checks = []
    for judge, claim in zip(judges, CLAIMS, strict=True):
        stat.update(at_budget if claim.at_end else now)
        checks.append(judge(claim))
    return checks


VERDICT_WORDS_SO_FAR = {Verdict.YES: "as claimed so far, not a verdict",
                        Verdict.NO: "not as claimed so far, not a verdict",
                        Verdict.NOISE: "within noise so far"}
"""How a judgement of runs too short to judge is shown: information, not a verdict."""


def _ci(low: float, high: float) -> str:
    return f"[{low:+.1f}, {high:+.1f}]"


def plateau_lines(summaries: Mapping[tuple[str, int], SettingSummary], level: float
                  ) -> list[str]:
    """Markdown: the plateau rule applied to every setting at every stage its runs reached,
    under both variance models, and what it allows at the last stage."""
    rows, judged = [], []
    for key in sorted(summaries, key=lambda k: (*paper_order(k[0]), k[1])):
        c = summaries[key].curves
        for stage in stages(c.end):
            pl = plateau(c.episode, c.percent, stage)
            head = f"| {_name(key)} | {pl.end:,} | {pl.start:,}-{pl.end:,} | {pl.sessions} "
            if pl.slopes is None:
                rows.append(head + f"| - | - | - | - | {pl.verdict()} |")
                continue
            cells = [f"{s.value:+.1f} {_ci(*s.interval(DECIDING_LEVEL))}, p {p_text(s.p_value)}"
                     for s in (pl.slopes[m] for m in MODELS)]
            cells += [_ci(*pl.change(m)[1:]) for m in MODELS]
            rows.append(head + "| " + " | ".join(cells) + " | "
                        + ("**" + pl.verdict() + "**" if pl.plateaued else pl.verdict()) + " |")
        last = pl  # the last stage is the end of the common sessions
        stat = fmt_interval(student_t(level)(c.level(), PERCENT))
        judged.append(f"- {_name(key)} at {last.end:,} episodes, last 5 {stat}: "
                      + ("plateaued; a claim about its asymptote can fail here, never hold."
                         if last.plateaued and last.remaining else
                         "not plateaued; no claim about its asymptote is judgeable here."
                         if last.remaining else "at the paper's budget."))
    return ["## Plateaus", "",
            f"The plateau rule (`analysis.plateau`; docs/design.md): on the last half of the "
            f"run, at most {PLATEAU_WINDOW:,} episodes, the slope (successes per 100 per 1,000 "
            "episodes) under two variance models: *pooled*, the OLS slope of the per-session "
            "mean over seeds (Student-t, sessions - 2 df), and *seeds*, the mean of the seeds' "
            "own OLS slopes (Student-t, seeds - 1 df). The change extrapolated to the paper's "
            f"{PAPER_EPISODES:,} episodes is slope x the episodes left. A setting has "
            f"**plateaued** when the window holds at least {PLATEAU_MIN_SESSIONS} sessions and "
            f"under both models the {DECIDING_LEVEL:.0%} interval of that change lies within "
            f"+- {PLATEAU_BAND:g}; then a claim about its asymptote can fail there (on intervals "
            "widened by that change), never hold.", "",
            "| setting | stage | window | sessions | "
            + " | ".join(f"{what} [{DECIDING_LEVEL:.0%}]" for what in (
                "pooled slope per 1,000", "seeds' slope per 1,000",
                f"change to {PAPER_EPISODES:,}, pooled", f"change to {PAPER_EPISODES:,}, seeds"))
            + " | verdict |",
            "|---|---:|---|---:|---|---|---|---|---|", *rows, "", *judged, ""]


def p_text(p: float | None) -> str:
    """A p-value as the tables print it ('-': not a comparison; 'n/a': undefined)."""
    if p is None:
        return "-"
    return "n/a" if not np.isfinite(p) else f"{p:.2g}" if p >= 0.001 else "< 0.001"


def comparisons_line(checks: Sequence[Check]) -> str:
    """How many comparisons the p-values come from, and what that means for reading them."""
    n = sum(c.p_value is not None for c in checks)
    judged = sum(c.p_value is not None and c.verdict in (Verdict.YES, Verdict.NO, Verdict.NOISE)
                 for c in checks)
    if not n:
        return "No comparison was made (no p-value)."
    return (f"{n} comparisons made ({judged} of them on claims judgeable here), each with a "
            "two-sided Welch p-value over seeds, not corrected for their number (Bonferroni's "
            f"threshold for {n} at 0.05: {0.05 / n:.2g}).")


def claim_settings() -> dict[str, tuple[tuple[str, int], ...]]:
    """Each claim of `judge_claims` -> the (region, joints) settings it looks at."""
    unc, con = UNC, CONSTRAINED
    needs = [(("farbox", 3),), (("farbox", 6),), FAR + unc + con, (("unconstrained", 2),),
             unc, unc, unc, con, con, unc + con, con,
             (("farbox_tall", 3), ("farbox_tall", 6), ("farbox", 3), ("farbox", 6)),
             (("unconstrained", 3),)]
    return {c.name: k for c, k in zip(CLAIMS, needs, strict=True)}


def rule_lines(level: float, plateaus: bool = False) -> list[str]:
    """Markdown: the verdict rule, as `analysis.report` and `analysis.sensitivity` apply it
    (``plateaus``: with the plateau rule's exception, which only `analysis.report` applies)."""
    exception = (" (*not judgeable at N episodes*); when every setting it compares has "
                 "plateaued by the plateau rule (section *Plateaus*) it can fail there, "
                 "labelled with the budget, but never hold" if plateaus else "")
    return [
        "## The rule", "",
        f"- A claim about where training ends (an asymptote, a converged level: \"highly "
        f"capable\", \"under 50 %\", \"about 40 %\", \"about 20 %\", \"identical\", \"alike\", "
        f"\"slower to converge\", Fig. 4) is **not judgeable** when the runs end below the "
        f"paper's {PAPER_EPISODES:,} episodes{exception}; what the runs show so far is printed "
        "beside it as information, never as a verdict.",
        f"- Levels are each seed's mean over its last {LAST_SESSIONS} test sessions at the point "
        f"judged (not one session); the interval is the {level:.0%} Student-t over seeds (the "
        "paper's figures' interval).",
        "- A above B: **holds** when the weakest of A and the strongest of B have intervals "
        "apart in that order, **fails** when apart the other way, **within noise** when they "
        "overlap. Under / over a threshold, \"about X\" (X +- "
        f"{ABOUT_TOLERANCE:g}) and \"alike\" (every interval within a band {ALIKE_TOLERANCE:g} "
        "wide) the same way: holds when the intervals lie inside, fails when they lie outside "
        "(or apart), within noise otherwise. Far box by 1,000 episodes: holds when at most the "
        f"paper's misses (0 of 5 with 3 joints, 1 of 5 with 6) never hit {HIGH_SUCCESS:g} "
        f"in a test session up to episode {FAST_EPISODES:,}.",
        "- Beside every comparison: its two-sided Welch p-value over seeds (scipy "
        "`ttest_ind(equal_var=False)`), uncorrected for the number of comparisons, which is "
        "printed below the table. *not run*: a setting the claim needs has no runs.",
        "- *Confounds*: what differs between the two settings compared besides the regions.",
        ""]


def render(summaries: dict[tuple[str, int], SettingSummary], level: float) -> str:
    """report.md: the settings' table, the reading, the rule and every claim's verdict."""
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
             f"Successes per 100 test goals; *last {LAST_SESSIONS}*: each seed's mean over its "
             f"last {LAST_SESSIONS} common test sessions, then the mean over seeds with a "
             f"{level:.0%} Student-t confidence interval in brackets; *best*: each seed's best "
             "single session.", "",
             f"| region | joints | seeds | episodes | last {LAST_SESSIONS} | best | first >= "
             f"{HIGH_SUCCESS:g} | paper |",
             "|---|---|---|---|---|---|---|---|"]
    for key in sorted(summaries, key=lambda k: (*paper_order(k[0]), k[1])):
        s, paper = summaries[key], PAPER_RESULTS.get(key)
        lines.append(f"| {s.region} | {s.joints} | {s.seeds} | {s.episodes} | "
                     f"{fmt_interval(s.final)} | {fmt_interval(s.best)} | "
                     f"{_first_high(s.first_high)} | "
                     f"{paper.text if paper else 'not in the paper'} |")
    checks = judge_claims({k: s.curves for k, s in summaries.items()}, student_t(level), {
        k: plateau(s.curves.episode, s.curves.percent) for k, s in summaries.items()})
    lines += ["", *reading_lines(summaries), *rule_lines(level, plateaus=True),
              *plateau_lines(summaries, level), "## The paper's claims", "",
              *claim_table(checks), "", comparisons_line(checks)]
    return "\n".join(lines) + "\n"


def claim_table(checks: Sequence[Check]) -> list[str]:
    """Markdown: one row per claim, with the paper's words, the verdict, the Welch p-value,
    the detail and the confounds."""
    words = {c.name: c for c in CLAIMS}
    lines = ["| claim | the paper (section, figure) | verdict | Welch p | detail | confounds |",
             "|---|---|---|---|---|---|"]
    for c in checks:
        claim = words[c.claim]
        at = f" at the plateau ({c.plateau_at:,} episodes)" if c.plateau_at is not None else ""
        lines.append(f"| {c.claim} | \"{claim.words}\" ({claim.where}) | {c.verdict.value}{at} | "
                     f"{p_text(c.p_value)} | {c.detail} | {'; '.join(c.confounds) or '-'} |")
    return lines


def comparison(groups: Sequence[Group], level: float) -> str:
    """report.md of groups: each group's statistics up to the last test session every group
    has, then every pair judged by the rule (`rule_lines`: A above B holds when their
    intervals of each seed's last-5 level are apart in that order), with its Welch p-value."""
    end = min(int(aligned_successes(g.runs)[0][-1]) for g in groups)
    interval = student_t(level)
    curves = {g.label: Curves.of(g.runs, end) for g in groups}
    stat = {k: interval(c.level(), PERCENT) for k, c in curves.items()}
    lines = ["# Comparison of groups of runs", "",
             f"Successes per 100 test goals up to episode {end:,}, the last test session every "
             f"group has; *last {LAST_SESSIONS}*: each seed's mean over its last "
             f"{LAST_SESSIONS} sessions, the mean over seeds with its {level:.0%} Student-t "
             "interval.", "", f"| group | setting | seeds | last {LAST_SESSIONS} | best | "
             f"first >= {HIGH_SUCCESS:g} | runs |", "|---|---|---|---|---|---|---|"]
    for g in groups:
        c = curves[g.label]
        first = tuple(int(c.episode[h.argmax()]) if h.any() else None
                      for h in c.percent >= HIGH_SUCCESS)
        runs = ", ".join(str(r.path) for r in g.runs)
        settings = ", ".join(dict.fromkeys(f"{r.region} {r.joints}" for r in g.runs))
        lines.append(f"| {g.label} | {settings} | {len(g.runs)} | "
                     f"{fmt_interval(stat[g.label])} | "
                     f"{fmt_interval(interval(c.percent.max(axis=1), PERCENT))} "
                     f"| {_first_high(first)} | {runs} |")
    pooled = pooled_lines(groups)
    if pooled:
        lines += ["", "**Pooled**: a group below holds runs that differ in more than their "
                      "seed:", *(f"- {x}" for x in pooled)]
    lines += ["", *rule_lines(level)[:1], "", *rule_lines(level)[3:6], "",
              "| A | B | verdict on \"A above B\" | Welch p |", "|---|---|---|---|"]
    for i, a in enumerate(groups):
        for b in groups[i + 1:]:
            verdict = apart(stat[a.label], stat[b.label])
            p = welch_p(curves[a.label].level(), curves[b.label].level())
            lines.append(f"| {a.label} {fmt_interval(stat[a.label])} | {b.label} "
                         f"{fmt_interval(stat[b.label])} | {verdict.value} | {p_text(p)} |")
    n = len(groups) * (len(groups) - 1) // 2
    return "\n".join([*lines, "", f"{n} comparison(s), Welch p-values not corrected for their "
                      "number."]) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(
        prog="python -m analysis.report", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_runs_arguments(parser)
    parser.add_argument("--out", type=Path, default=None,
                        help="also write the Markdown to this file")
    add_force(parser)
    args = parser.parse_args(argv)

    if args.out is not None:
        with usage_errors(parser):  # before reading any run
            check_writable(args.out, "--out")
    if args.group_by or args.groups:
        text = comparison(groups_from_args(parser, args), args.confidence)
    else:
        groups = settings_from_args(parser, args)
        summaries = {k: summarise(v, args.confidence) for k, v in groups.items()}
        text = render(summaries, args.confidence)
    if args.out is not None:
        with write_errors(parser, args.force):  # whole or not at all
            write_text(args.out, text)
    print(text, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main())
