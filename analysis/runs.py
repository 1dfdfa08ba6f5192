"""Finding training runs below a folder, grouping them by setting, and statistics over seeds.

A run is any folder holding a ``spec.json`` written by ``python -m ddpg_her.train`` (format
``ddpg_her-run-*``) next to its ``eval.csv``. Its *setting* is (region, joints): the region as
given to ``--region`` and the number of controlled joints.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

PERCENT = (0.0, 100.0)
"""Feasible range of a success percentage; confidence intervals are clipped to it."""

CONFIDENCE = 0.65
"""Two-sided confidence level of the interval over seeds (the paper's figures use 65 %)."""

RUN_FORMAT_PREFIX = "ddpg_her-run"
"""``spec.json`` ``format`` values this module reads."""


@dataclass(frozen=True)
class Run:
    """One finished or unfinished training run."""

    path: Path
    region: str
    """Region as given to ``--region`` (a registered name or a spec string)."""
    joints: int
    seed: int
    episodes_planned: int
    """Training episodes the run was asked for."""
    episode: np.ndarray
    """(T,) int: training episodes at each evaluation."""
    successes: np.ndarray
    """(T,) int: test episodes that reached the goal."""
    tests: np.ndarray
    """(T,) int: test episodes per evaluation."""
    final_distance_m: np.ndarray
    """(T,) float, m: mean final end-effector distance to the goal."""
    spec: dict[str, Any]

    @property
    def setting(self) -> tuple[str, int]:
        return self.region, self.joints

    @property
    def finished(self) -> bool:
        return len(self.episode) > 0 and int(self.episode[-1]) >= self.episodes_planned

    @property
    def success_rate(self) -> np.ndarray:
        """(T,) float in [0, 1]: successes / tests."""
        return self.successes / np.maximum(self.tests, 1)


def read_run(path: str | Path) -> Run:
    """Read the run in folder ``path`` (its ``spec.json`` and ``eval.csv``).

    Raises
    ------
    ValueError
        When ``spec.json`` is not a ddpg_her run specification.
    """
    folder = Path(path)
    spec = json.loads((folder / "spec.json").read_text())
    if not str(spec.get("format", "")).startswith(RUN_FORMAT_PREFIX):
        raise ValueError(f"{folder / 'spec.json'} is not a ddpg_her run (format "
                         f"{spec.get('format')!r}, expected {RUN_FORMAT_PREFIX}-*)")
    kwargs = spec.get("env_kwargs", {})
    region = kwargs.get("region", spec.get("task", {}).get("region"))
    if isinstance(region, dict):
        region = region.get("name", json.dumps(region, sort_keys=True))
    joints = int(kwargs.get("n_joints", spec.get("task", {}).get("n_joints", 0)))
    rows: list[dict[str, str]] = []
    eval_path = folder / "eval.csv"
    if eval_path.exists():
        with open(eval_path, newline="") as f:
            rows = list(csv.DictReader(f))

    def column(name: str, kind: type) -> np.ndarray:
        return np.array([kind(r[name]) for r in rows], dtype=kind)

    return Run(
        path=folder, region=str(region), joints=joints, seed=int(spec["seed"]),
        episodes_planned=int(spec["agent"]["episodes"]),
        episode=column("episode", int), successes=column("successes", int),
        tests=column("tests", int), final_distance_m=column("mean_final_distance_m", float),
        spec=spec,
    )


def find_runs(roots: Iterable[str | Path]) -> list[Run]:
    """Every run below the given folders, in (region, joints, seed) order.

    Raises
    ------
    FileNotFoundError
        When a root does not exist.
    """
    runs = []
    for root in roots:
        root = Path(root)
        if not root.exists():
            raise FileNotFoundError(f"runs root {root} does not exist")
        for spec in sorted(root.rglob("spec.json")):
            try:
                runs.append(read_run(spec.parent))
            except (ValueError, KeyError, json.JSONDecodeError):
                continue  # a spec.json of something else
    unique = {run.path.resolve(): run for run in runs}
    return sorted(unique.values(), key=lambda r: (r.region, r.joints, r.seed, str(r.path)))


def group_by_setting(runs: Sequence[Run]) -> dict[tuple[str, int], list[Run]]:
    """Runs keyed by (region, joints), in the order of ``runs``."""
    groups: dict[tuple[str, int], list[Run]] = {}
    for run in runs:
        groups.setdefault(run.setting, []).append(run)
    return groups


def t_quantile(p: float, dof: int) -> float:
    """Quantile of Student's t distribution with ``dof`` degrees of freedom."""
    from scipy import stats

    return float(stats.t.ppf(p, dof))


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
    if not 0.0 < level < 1.0:
        raise ValueError(f"confidence level must be in (0, 1); got {level}")
    values = np.asarray(values, dtype=float)
    n = values.shape[0]
    mean = values.mean(axis=0)
    if n < 2:
        return mean, mean.copy(), mean.copy()
    half = t_quantile(0.5 + level / 2.0, n - 1) * values.std(axis=0, ddof=1) / math.sqrt(n)
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
    missing root, or no run with evaluations.
    """
    if not 0.0 < args.confidence < 1.0:
        parser.error(f"--confidence must be in (0, 1); got {args.confidence}")
    try:
        runs = find_runs(args.roots)
    except FileNotFoundError as err:
        parser.error(str(err))
    groups = {k: v for k, v in group_by_setting(runs).items() if any(len(r.episode) for r in v)}
    if not groups:
        parser.error(f"no run with evaluations below {', '.join(map(str, args.roots))}")
    return groups
