"""Learning curves: successes over seeds against training episodes, one panel per setting.

    python -m analysis.curves RUNS_ROOT... --out fig.png
    python -m analysis.curves RUNS_ROOT... --group-by region --out fig.png   # groups, one axis

Each panel is a (region, joints) setting (runs of one setting that differ in another recorded field
are drawn apart in it, each labelled with what differs), laid out like the paper's figures (a row
per region, a column per joint count): the mean over seeds with a 65 % Student-t confidence
interval, each seed faintly, and the paper's stated asymptote dashed where it gives one. The plotted
numbers go to a CSV beside the figure (``fig.csv``). With ``--group-by FIELD`` or ``--groups
NAME=DIR ...`` every group is drawn on one axis, each in its colour.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from analysis.outputs import add_force, figure_outputs, pyplot, save_figure, write_csv, write_errors
from analysis.paper import PAPER_RESULTS
from analysis.runs import (
    PERCENT,
    Group,
    add_runs_arguments,
    aligned_successes,
    groups_from_args,
    mean_ci,
    pooled_lines,
)
from ddpg_her.config import Parser
from regions.registry import paper_order

CSV_COLUMNS = ("group", "region", "joints", "episode", "seeds", "mean_successes", "ci_low",
               "ci_high")
"""Columns of the CSV beside the figure; successes are per 100 test goals, the interval is clipped
to 0-100."""


def curve_rows(groups: list[Group], level: float) -> list[dict]:
    """The plotted numbers: one row per group and evaluation episode (a group's region and
    joints: those of its first run)."""
    rows = []
    for group in groups:
        runs, (region, joints) = group.runs, group.setting
        episode, successes = aligned_successes(runs)
        if len(episode) == 0:
            continue
        stats = zip(episode, *mean_ci(successes, level, PERCENT), strict=True)
        rows += [{"group": group.label, "region": region, "joints": joints, "episode": int(e),
                  "seeds": len(runs), "mean_successes": round(float(mean), 4),
                  "ci_low": round(float(low), 4), "ci_high": round(float(high), 4)}
                 for e, mean, low, high in stats]
    return rows


def plot(groups: list[Group], out: Path, level: float, overlay: bool = False) -> None:
    """Draw the groups to ``out`` (any matplotlib format): a panel per setting, or with
    ``overlay`` every group on one axis."""
    panels: dict[tuple[str, int], list[Group]] = {}
    for g in groups:
        panels.setdefault(("", 0) if overlay else g.setting, []).append(g)
    regions = sorted({r for r, _ in panels}, key=paper_order)  # figure rows
    joints = sorted({j for _, j in panels})
    fig, axes = pyplot().subplots(
        len(regions), len(joints), squeeze=False, sharex=True, sharey=True,
        figsize=(max(3.2 * len(joints) + 0.6, 6.5), 2.6 * len(regions) + 0.8))
    for i, region in enumerate(regions):
        for j, n in enumerate(joints):
            ax = axes[i][j]
            inside = panels.get((region, n))
            if not inside:
                ax.set_visible(False)
                continue
            for c, group in enumerate(inside):
                runs, color = group.runs, f"C{c}"
                episode, successes = aligned_successes(runs)
                for seed_curve in successes:
                    ax.plot(episode, seed_curve, color=color if len(inside) > 1 else "0.6",
                            lw=0.6, alpha=0.35, label="each seed" if len(inside) == 1 else None)
                mean, low, high = mean_ci(successes, level, PERCENT)
                ax.fill_between(episode, low, high, color=color, alpha=0.25, lw=0,
                                label=f"{level:.0%} CI" if c == 0 else None)
                ax.plot(episode, mean, color=color, lw=1.6, label=(
                    f"{group.label}: mean of {len(runs)} seeds" if overlay or len(inside) > 1
                    else f"mean of {len(runs)} seeds"))
            paper = PAPER_RESULTS.get((region, n))
            if paper is not None and paper.approx_success is not None:
                ax.axhline(paper.approx_success, color="C3", ls="--", lw=1,
                           label="the paper's asymptote")
            ax.set_title("one axis, each group its colour" if overlay else
                         f"{region}, joints 1-{n}", fontsize=9)
            ax.set_ylim(-2, 102)
            ax.grid(alpha=0.3)
    # shared axes label only the outer panels; with panels missing from the grid, label each
    # panel that has no panel below it (x) or to its left (y) instead
    shown = [[ax.get_visible() for ax in row] for row in axes]
    for i, row in enumerate(axes):
        for j, ax in enumerate(row):
            if not shown[i][j]:
                continue
            if not any(shown[b][j] for b in range(i + 1, len(axes))):
                ax.tick_params(labelbottom=True)
                ax.set_xlabel("training episodes")
            if not any(shown[i][:j]):
                ax.tick_params(labelleft=True)
                ax.set_ylabel("goals hit / 100")
    legend: dict[str, object] = {}  # every label once, whichever panel first has it
    for ax in (a for row in axes for a in row if a.get_visible()):
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            legend.setdefault(label, handle)
    first = next(a for row in axes for a in row if a.get_visible())
    first.legend(list(legend.values()), list(legend), loc="upper left", fontsize=7,
                 framealpha=0.8)
    fig.suptitle(f"Test successes, mean and {level:.0%} confidence interval over seeds",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    save_figure(fig, out, dpi=120)


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(
        prog="python -m analysis.curves", description=__doc__.split("\n\n")[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    add_runs_arguments(parser)
    parser.add_argument("--out", type=Path, default=Path("curves.png"),
                        help="figure file (.png, .pdf, .svg); the CSV goes beside it")
    add_force(parser)
    args = parser.parse_args(argv)
    out, csv_path = figure_outputs(parser, args.out, "--out", ".csv")  # before any reading
    groups = groups_from_args(parser, args)
    for line in pooled_lines(groups):
        print(f"note: {line}", file=sys.stderr)
    rows = curve_rows(groups, args.confidence)
    with write_errors(parser, args.force):
        plot(groups, out, args.confidence, overlay=bool(args.group_by or args.groups))
        write_csv(csv_path, CSV_COLUMNS, rows)
    print(f"{sum(len(g.runs) for g in groups)} runs in {len(groups)} groups -> {out} and "
          f"{csv_path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
