"""Every claim of the paper in one table, judged on the committed results by the project's rule.

    python -m analysis.claims [--results results] [--out results/claims] [--readme README.md]

Sixteen claims: the thirteen of section IV (`analysis.paper.CLAIMS`, judged by
`analysis.report.judge_claims` with the plateau rule) and three of sections III-IV that the
paper states without a figure (`EXTRA`), one row each (`COLUMNS`), by docs/design.md's "The
verdict rule". It reads `SOURCES` and `VARIANTS` below ``--results``, the longest run of a
setting winning; a claim whose runs are absent is *not run*.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from analysis import report
from analysis.outputs import (
    add_force,
    check_files,
    usage_errors,
    write_csv,
    write_errors,
    write_text,
)
from analysis.paper import CLAIMS, PAPER_EPISODES
from analysis.plateau import plateau
from analysis.report import Check, Curves, Verdict
from analysis.runs import PERCENT, find_runs, group_by_setting
from ddpg_her.config import Parser

SOURCES = ("sensitivity/runs/ours", "paper_long/runs", "claims/farbox_tall/runs")
"""Run roots of the paper's settings under the default reading (below ``--results``)."""

VARIANTS = {"velocity": "velocity control", "torque": "torque control",
            "sparse": "the sparse reward", "per": "prioritised replay"}
"""Far box 3 variants, each compared with the default far box 3: folder below ``claims/`` (its
runs in ``claims/<folder>/runs``) -> what it changes."""

NEGLIGIBLE = 10.0
"""Successes per 100 below which a success rate is "negligible" (our reading; the paper gives
no number: as far from 0 as "nearly 100 %" (90) is from 100)."""

EXTRA = (
    ("only position control non-negligible", "in our experiments only joint position control "
     "resulted in a non-negligible success rate", "IV (opening)", ("velocity", "torque")),
    ("dense reward above sparse", "sparse rewards give rise to better learning than dense "
     "rewards, but we found the opposite to be true", "III-A", ("sparse",)),
    ("prioritised replay destabilised learning", "Prioritized Experience Replay ... tended to "
     "destabilize or prevent learning", "III-A", ("per",)),
)
"""The three claims outside section IV: name, the paper's words, section, variants compared
against far box 3."""

EXTRA_EPISODES = 1000
"""The budget of the three claims outside section IV (the far box's own, IV-C: where the
paper's far box has converged); both sides are compared at the same number of episodes."""

RULES = ["seeds hitting 90 by 1,000 vs the paper's misses"] * 2 + [
    "weakest A above strongest B (65 % t, apart)", "at least 90 (65 % t)",
    "under 50 (65 % t)", "within 40 +- 10 (65 % t)", "within a band 10 wide (65 % t)",
    "within 20 +- 10 (65 % t)", "within a band 10 wide (65 % t)",
    "weakest A above strongest B (65 % t, apart)",
    "episode converged, 6 above 3 joints (65 % t)", "within a band 10 wide (65 % t)",
    "success maps of converged policies",
    f"velocity, torque under {NEGLIGIBLE:g} (65 % t)", "dense above sparse (65 % t, apart)",
    "uniform above prioritised (65 % t, apart)"]
"""The rule of each claim, in table order (`analysis.report.rule_lines` states them in full)."""

WORDS = {**{v: v.value for v in Verdict}, Verdict.NO: "contradicted"}
"""The verdicts' words in the table: `analysis.report.Verdict`'s, a failed claim contradicted."""
COLUMNS = ("claim", "section", "our figure", "rule", "budget run", "verdict", "budget needed")


def load(results: Path) -> tuple[dict[tuple[str, int], Curves], dict[str, Curves]]:
    """The settings' curves (longest run of each) and the variants' curves found below
    ``results`` (absent roots are skipped: their claims are *not run*)."""
    curves: dict[tuple[str, int], Curves] = {}
    for source in SOURCES:
        if (results / source).is_dir():
            for key, runs in group_by_setting(find_runs([results / source])).items():
                c = Curves.of(runs)
                if key not in curves or c.end > curves[key].end:
                    curves[key] = c
    variants = {}
    for name in VARIANTS:
        root = results / "claims" / name / "runs"
        runs = find_runs([root]) if root.is_dir() else []
        if runs:
            if {r.setting for r in runs} != {("farbox", 3)}:
                raise ValueError(f"{root}: expected far box 3 runs only; found settings "
                                 f"{sorted({r.setting for r in runs})}")
            variants[name] = Curves.of(runs)
    return curves, variants


def judge_extra(curves: dict[tuple[str, int], Curves], variants: dict[str, Curves]
                ) -> list[Check]:
    """The three claims of `EXTRA`, each comparing variants with the default far box 3 cut to
    the variant's budget (each Welch p named in the detail); a variant short of
    `EXTRA_EPISODES` gives *not judgeable* (what it shows so far is said, not judged)."""
    interval, out = report.student_t(), []
    base = curves.get(("farbox", 3))
    for name, _, _, names in EXTRA:
        have = [n for n in names if n in variants]
        if base is None or len(have) < len(names):
            lack = [n for n in names if n not in variants] + (["farbox 3"] if base is None else [])
            out.append(Check(name, Verdict.NOT_RUN, "runs missing: " + ", ".join(lack)))
            continue
        each, parts = [], []
        for n in have:  # each comparison's Welch p named in its part: a claim may have two
            end = min(base.end, variants[n].end)
            b_level, v_level = base.until(end).level(), variants[n].until(end).level()
            b, v = interval(b_level, PERCENT), interval(v_level, PERCENT)
            against = {"sparse": "dense", "per": "uniform"}.get(n, "position")
            parts.append(f"at {end:,} episodes: far box 3 (position, dense, uniform) "
                         f"{report.fmt_interval(b)}, {VARIANTS[n]} {report.fmt_interval(v)} "
                         f"({len(v_level)} seeds; {n} vs {against}: Welch p "
                         f"{report.welch_p(b_level, v_level):.2g})")
            each.append(report.apart(b, v) if name != EXTRA[0][0] else
                        Verdict.YES if v[2] < NEGLIGIBLE else Verdict.NO if v[1] >= NEGLIGIBLE
                        else Verdict.NOISE)
        verdict = report.overall(each)
        short = min(variants[n].end for n in have) < EXTRA_EPISODES
        if short:
            parts.insert(0, f"runs short of {EXTRA_EPISODES:,} episodes; so far "
                         f"({WORDS[verdict]} so far, not a verdict)")
        out.append(Check(name, Verdict.NOT_JUDGEABLE if short else verdict, "; ".join(parts)))
    return out


def table(results: Path) -> list[dict[str, str]]:
    """The sixteen claims' rows (keys: `COLUMNS`) from the results below ``results``."""
    curves, variants = load(results)
    needs = report.claim_settings()
    checks, cut = [], {}
    for i, claim in enumerate(CLAIMS):
        # every setting a claim compares cut to the shortest one's budget: one budget per claim
        keys = [k for k in needs[claim.name] if k in curves]
        end = min((curves[k].end for k in keys), default=0)
        cut[claim.name] = {k: curves[k].until(end) for k in keys}
        plateaus = {k: plateau(c.episode, c.percent) for k, c in cut[claim.name].items()}
        checks.append(report.judge_claims(cut[claim.name], plateaus=plateaus)[i])
    checks += judge_extra(curves, variants)
    where = {c.name: (c.where, c.at_end) for c in CLAIMS} | {e[0]: (e[2], False) for e in EXTRA}
    rows = []
    for check, rule in zip(checks, RULES, strict=True):
        section, at_end = where[check.claim]
        if check.claim in needs:
            ends = sorted({c.end for c in cut[check.claim].values()})
        else:
            base_end = curves[("farbox", 3)].end if ("farbox", 3) in curves else 10**9
            ends = sorted({min(variants[n].end, base_end) for e in EXTRA
                           if e[0] == check.claim for n in e[3] if n in variants})
        need = (f"{PAPER_EPISODES:,}" if at_end else "the run's" if check.claim == CLAIMS[2].name
                else "1,000") + (" and success maps" if check.claim == CLAIMS[-1].name else "")
        if check.verdict is Verdict.NOT_RUN:
            ends = []
        figure = check.detail + (f" (Welch p {check.p_value:.2g})" if check.p_value is not None
                                 and check.p_value == check.p_value else "")
        at = f" at {check.plateau_at:,}" if check.plateau_at else ""
        rows.append({"claim": check.claim, "section": section, "our figure": figure,
                     "rule": rule, "budget run": "-" if not ends else
                     f"{ends[0]:,}" + (f"-{ends[-1]:,}" if len(ends) > 1 else ""),
                     "verdict": WORDS[check.verdict] + at, "budget needed": need})
    return rows


def markdown(rows: Sequence[dict[str, str]]) -> str:
    """The rows as a Markdown table."""
    cell = lambda s: s.replace("|", "/")  # noqa: E731
    return "\n".join(["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS),
                      *("| " + " | ".join(cell(r[c]) for c in COLUMNS) + " |" for r in rows)])


BEGIN, END = "<!-- claims:begin -->", "<!-- claims:end -->"


def readme_block(text: str) -> str:
    """What a README holds between `BEGIN` and `END` (ValueError naming them when absent)."""
    if BEGIN not in text or END not in text.split(BEGIN, 1)[1]:
        raise ValueError(f"the README has no {BEGIN} ... {END} markers")
    return text.split(BEGIN, 1)[1].split(END, 1)[0]


def block(rows: Sequence[dict[str, str]]) -> str:
    """The README's block: the command, then the table."""
    return (f"\n*Written by `python -m analysis.claims --readme README.md`; rules: docs/design.md, "
            f"\"The verdict rule\" and \"The plateau rule\".*\n\n{markdown(rows)}\n")


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m analysis.claims", description=__doc__.split("\n\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"),
                        help="the committed results folder to read (default: results)")
    parser.add_argument("--out", type=Path, default=None,
                        help="write claims.md and claims.csv into this folder")
    parser.add_argument("--readme", type=Path, default=None,
                        help=f"replace what this file holds between {BEGIN} and {END}")
    add_force(parser)
    args = parser.parse_args(argv)
    if not args.results.is_dir():
        parser.error(f"--results {args.results}: not a folder")
    if args.out is not None:
        with usage_errors(parser):  # before reading anything
            check_files(args.out, ("claims.md", "claims.csv"), "--out")
    try:
        rows = table(args.results)
        if args.readme is not None:  # read and checked now, written last
            text = args.readme.read_text()
            text = text.replace(BEGIN + readme_block(text) + END, BEGIN + block(rows) + END)
    except (OSError, ValueError) as err:
        parser.exit(1, f"error: {err}\n")
    if args.out is not None:
        with write_errors(parser, args.force):
            write_text(args.out / "claims.md", markdown(rows) + "\n")
            write_csv(args.out / "claims.csv", COLUMNS, rows)
    if args.readme is not None:  # its block is --readme's to replace: after --out, not refused
        with write_errors(parser, True, "--readme"):
            write_text(args.readme, text)
    print(markdown(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
