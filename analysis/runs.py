"""Finding training runs below a folder, grouping them by setting, and statistics over seeds.

A run is any folder holding a ``spec.json`` written by ``python -m ddpg_her.train`` (format
``ddpg_her-run-*``) next to its ``eval.csv``; `Run` and `read_run` come from
`ddpg_her.runfolder`. Its *setting* is (region, joints): the region as given to ``--region`` and
the number of controlled joints.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from ddpg_her.runfolder import RUN_FORMAT_PREFIX, Run, RunFolderError, is_run_spec, read_run

__all__ = ["CONFIDENCE", "PERCENT", "RUN_FORMAT_PREFIX", "Run", "RunFolderError",
           "add_runs_arguments", "aligned_successes", "find_runs", "group_by_setting",
           "mean_ci", "read_run", "settings_from_args"]

PERCENT = (0.0, 100.0)
"""Feasible range of a success percentage; confidence intervals are clipped to it."""

CONFIDENCE = 0.65
"""Two-sided confidence level of the interval over seeds (the paper's figures use 65 %)."""

def find_runs(roots: Iterable[str | Path]) -> list[Run]:
    """Every run below the given folders, in (region, joints, seed) order.

    A ``spec.json`` that is a JSON object without a ``ddpg_her-run-*`` format belongs to
    something else and is passed over; every other ``spec.json`` must be a readable run.

    Raises
    ------
    FileNotFoundError
        When a root does not exist.
    RunFolderError
        (a ValueError) When a run folder cannot be read (a truncated or garbled ``spec.json``,
        a malformed ``eval.csv``); the message names the folder or file.
    """
    runs = []
    for root in roots:
        root = Path(root)
        if not root.exists():
            raise FileNotFoundError(f"runs root {root} does not exist")
        for spec in sorted(root.rglob("spec.json")):
            try:
                content = json.loads(spec.read_text())
            except (OSError, UnicodeDecodeError, json.JSONDecodeError):
                content = None  # read_run says what is wrong with it
            if isinstance(content, dict) and not is_run_spec(content):
                continue  # a spec.json of something else
            runs.append(read_run(spec.parent))
    unique = {run.path.resolve(): run for run in runs}
    return sorted(unique.values(), key=lambda r: (r.region, r.joints, r.seed, str(r.path)))


def group_by_setting(runs: Sequence[Run]) -> dict[tuple[str, int], list[Run]]:
    """Runs keyed by (region, joints), in the order of ``runs``."""
    groups: dict[tuple[str, int], list[Run]] = {}
    for run in runs:
        groups.setdefault(run.setting, []).append(run)
    return groups


def mean_ci(values: np.ndarray, level: float = CONFIDENCE,
            bounds: tuple[float, float] = (-np.inf, np.inf),
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean and two-sided Student-t confidence interval over the first axis (the seeds).

    Parameters
    ----------
    values : (n_seeds, ...) float
    level : float
        Confidence level in (0, 1).

    Returns
    -------
    mean, low, high : (...) float
        With one seed the interval is the mean itself (no spread to estimate). ``bounds``
        clips the interval to a feasible range (e.g. 0-100 successes).
    """
    from scipy import stats

    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must be in (0, 1); got {level}")
    values = np.asarray(values, dtype=float)
    n = values.shape[0]
    mean = values.mean(axis=0)
    if n < 2:
        return mean, mean.copy(), mean.copy()
    half = float(stats.t.ppf(0.5 + level / 2.0, n - 1)) * values.std(axis=0, ddof=1) / math.sqrt(n)
    return mean, np.clip(mean - half, *bounds), np.clip(mean + half, *bounds)


def aligned_successes(runs: Sequence[Run]) -> tuple[np.ndarray, np.ndarray]:
    """Success percentages of several seeds on their common evaluation episodes.

    Returns
    -------
    episode : (T,) int
        Evaluation episodes present in every run (the shortest run bounds T).
    percent : (n_runs, T) float
        Goals hit per 100 test episodes (the paper's "successes out of 100", whatever the
        number of test episodes of the run).
    """
    common = set(runs[0].episode.tolist())
    for run in runs[1:]:
        common &= set(run.episode.tolist())
    episode = np.array(sorted(common), dtype=int)
    table = np.array([[100.0 * r.success_rate[np.searchsorted(r.episode, e)] for e in episode]
                      for r in runs], dtype=float).reshape(len(runs), len(episode))
    return episode, table


def add_runs_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags every study over run folders shares: the roots and the confidence level."""
    parser.add_argument("roots", nargs="+", metavar="RUNS_ROOT",
                        help="folders searched (recursively) for run folders with spec.json")
    parser.add_argument("--confidence", type=float, default=CONFIDENCE,
                        help="two-sided confidence level of the interval over seeds (fraction)")


def settings_from_args(parser: argparse.ArgumentParser,
                       args: argparse.Namespace) -> dict[tuple[str, int], list[Run]]:
    """The runs below ``args.roots`` that have evaluations, grouped by setting.

    Exits through ``parser.error`` (status 2, with the reason) on a bad confidence level, a
    missing root, a run folder that cannot be read, or no run with evaluations.
    """
    if not 0.0 < args.confidence < 1.0:
        parser.error(f"--confidence must be in (0, 1); got {args.confidence}")
    try:
        runs = find_runs(args.roots)
    except (FileNotFoundError, RunFolderError) as err:
        parser.error(str(err))
    groups = {k: v for k, v in group_by_setting(runs).items() if any(len(r.episode) for r in v)}
    if not groups:
        parser.error(f"no run with evaluations below {', '.join(map(str, args.roots))}")
    return groups
