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
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ddpg_her.config import usage_errors
from ddpg_her.runfolder import Run, RunFolderError, is_run_spec, read_run
from ur5kin.checks import number

__all__ = ["CONFIDENCE", "PERCENT", "Group", "Run", "RunFolderError", "add_runs_arguments",
           "aligned_successes", "configuration", "differences", "find_runs", "group_by_setting",
           "group_runs", "groups_from_args", "mean_ci", "read_run", "settings_from_args"]

PERCENT = (0.0, 100.0)
"""Feasible range of a success percentage; confidence intervals are clipped to it."""

CONFIDENCE = 0.65
"""Two-sided confidence level of the interval over seeds (the paper's figures use 65 %)."""

LEVEL = number(0, 1, above=True, below=True)
"""A two-sided confidence level."""


def find_runs(roots: Iterable[str | Path]) -> list[Run]:
    """Every run below the given folders, in (region, joints, seed) order.

    A ``spec.json`` that is a JSON object without a ``ddpg_her-run-*`` format belongs to
    something else and is passed over; every other ``spec.json`` must be a readable run.

    Raises
    ------
    FileNotFoundError
        When a root is not a folder.
    RunFolderError
        (a ValueError) When a run folder cannot be read (a truncated or garbled ``spec.json``,
        a malformed ``eval.csv``); the message names the folder or file.
    """
    runs = []
    for root in roots:
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"runs root {root} " + ("is not a folder (of runs)"
                                    if root.exists() else "does not exist"))
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
    common = set.intersection(*(set(r.episode.tolist()) for r in runs))
    episode = np.array(sorted(common), dtype=int)
    table = np.array([[100.0 * r.success_rate[np.searchsorted(r.episode, e)] for e in episode]
                      for r in runs], dtype=float).reshape(len(runs), len(episode))
    return episode, table


NOT_CONFIGURATION = ("seed", "versions", "git", "command", "created", "format", "dims",
                     "env_kwargs")
"""Sections of ``spec.json`` that do not make runs different: the seed, the record of where and
when, and what is derived from (or repeats) the task."""

ALIASES = {"backend": ("env_backend", "numpy")}
"""Grouping names for spec fields, and the value of runs that do not record them."""


def configuration(run: Run) -> dict[str, str]:
    """Every recorded field of ``run``'s spec.json that makes runs different, flattened
    (``task.region``, ``agent.gamma``, ``env_backend``, ``program.matmul``) -> its JSON text;
    not the seed, the budget (``agent.episodes``: runs extended or cut compare on their common
    sessions) or `NOT_CONFIGURATION`."""
    flat: dict[str, str] = {}

    def walk(key: str, value: object) -> None:
        if isinstance(value, dict) and value:
            for k, v in value.items():
                walk(f"{key}.{k}", v)
        else:
            flat[key] = json.dumps(value, sort_keys=True)

    for key, value in run.spec.items():
        if key not in NOT_CONFIGURATION:
            walk(key, value)
    flat.pop("agent.episodes", None)
    return flat


def field_value(run: Run, field: str) -> str:
    """``run``'s value of a grouping field: ``region``, ``joints``, ``folder`` (the run
    folder's parent), ``reading`` (the paper's unstated choices, `analysis.readings`),
    ``algorithm``, ``backend`` or any flattened spec field of `configuration`."""
    if field in ("region", "joints"):
        return str(getattr(run, field))
    if field == "folder":
        return str(run.path.parent)
    if field == "reading":
        from analysis.readings import run_choices

        return ", ".join(f"{k}={v}" for k, v in run_choices(run.spec).items())
    if field == "algorithm":  # the ensemble is DDPG's agents in cells: an algorithm apart
        agent = run.spec.get("agent", {})
        ensemble = int(agent.get("ensemble", 1) or 1)
        return agent.get("algo", "ddpg") + (f" ensemble of {ensemble}" if ensemble > 1 else "")
    key, missing = ALIASES.get(field, (field, None))
    value = configuration(run).get(key)
    if value is None and missing is None:
        raise ValueError(f"--group-by {field}: {run.path}/spec.json records no {key!r}; a field "
                         "is region, joints, folder, reading, algorithm, backend or a spec "
                         "field such as agent.gamma or task.contact_model")
    return missing if value is None else value.strip('"')


def differences(runs: Sequence[Run]) -> dict[str, list[str]]:
    """The configuration fields whose values differ between ``runs`` -> their values (a field
    some runs do not record reads "(not recorded)")."""
    configs = [configuration(r) for r in runs]
    keys = sorted({k for c in configs for k in c})
    values = {k: sorted({c.get(k, "(not recorded)") for c in configs}) for k in keys}
    return {k: v for k, v in values.items() if len(v) > 1}


@dataclass(frozen=True)
class Group:
    """Runs compared as the seeds of one thing."""

    label: str
    runs: list[Run]
    pooled: dict[str, list[str]]
    """What differs between the group's runs besides their seeds (`differences`): empty
    unless pooling was asked for."""

    @property
    def setting(self) -> tuple[str, int]:
        return self.runs[0].setting


def group_runs(runs: Sequence[Run], by: Sequence[str] = (), pool: bool = False
               ) -> list[Group]:
    """Runs in groups: by the values of the fields ``by`` (`field_value`), or by default by
    their whole configuration, so that runs which differ in any recorded field but the seed
    are never pooled; their label is the setting and, where several configurations share a
    setting, what differs. ``pool``: by setting alone, whatever else differs (said in each
    group's ``pooled``)."""
    keys: dict[tuple, list[Run]] = {}
    for run in runs:
        key = (tuple(field_value(run, f) for f in by) if by else
               (run.region, run.joints) if pool else
               (run.region, run.joints, tuple(sorted(configuration(run).items()))))
        keys.setdefault(key, []).append(run)
    groups = []
    for key, members in keys.items():
        if by:
            label = ", ".join(f"{f} {v}" for f, v in zip(by, key, strict=True))
        else:
            label = f"{key[0]} {key[1]}"
            alike = [r for k, v in keys.items() if k[:2] == key[:2] for r in v[:1]]
            if len(alike) > 1:
                mine = configuration(members[0])
                label += " (" + ", ".join(f"{f}={mine.get(f, '(not recorded)')}"
                                          for f in differences(alike)) + ")"
        groups.append(Group(label, members, differences(members) if by or pool else {}))
    return groups


def differences_text(differ: dict[str, list[str]], most: int = 6) -> str:
    """`differences` as one line: the first ``most`` fields with their values (each cut to 40
    characters), then how many more."""
    cut = [f"{k} ({' / '.join(x if len(x) <= 40 else x[:37] + '...' for x in v)})"
           for k, v in differ.items()]
    return "; ".join(cut[:most]) + (f"; and {len(cut) - most} more" if len(cut) > most else "")


def pooled_lines(groups: Sequence[Group]) -> list[str]:
    """One line per group that pools runs of different configurations, naming what differs."""
    return [f"{g.label}: pools {len(g.runs)} runs that differ in {differences_text(g.pooled)}"
            for g in groups if g.pooled]


def add_runs_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags every study over run folders shares: the roots, how runs are grouped, and the
    confidence level."""
    parser.add_argument("roots", nargs="*", metavar="RUNS_ROOT",
                        help="folders searched (recursively) for run folders with spec.json")
    parser.add_argument("--group-by", nargs="+", default=[], metavar="FIELD",
                        help="compare groups of runs by these fields: region, joints, folder "
                             "(the run folder's parent), reading, algorithm, backend, or any "
                             "spec.json field (e.g. --group-by task.contact_model); by default "
                             "runs are grouped by their whole recorded configuration but the "
                             "seed")
    parser.add_argument("--groups", nargs="+", default=[], metavar="NAME=DIR",
                        help="compare named groups, each the runs below a folder (e.g. "
                             "--groups mine=runs/a theirs=runs/b); instead of RUNS_ROOT")
    parser.add_argument("--pool", action="store_true",
                        help="pool the runs of a setting (region, joints) that differ in other "
                             "recorded fields as its seeds, saying what differs")
    parser.add_argument("--confidence", type=LEVEL.read, default=CONFIDENCE,
                        help="two-sided confidence level of the interval over seeds (fraction)")


def groups_from_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[Group]:
    """The groups of runs with evaluations that ``args`` ask for (`group_runs`, or the named
    ``--groups``), each with its runs' common evaluations.

    Exits through ``parser.error`` (status 2, with the reason) on a bad confidence level, a
    missing root, a run folder that cannot be read, an unknown field, or no run with
    evaluations.
    """
    if bool(args.groups) == bool(args.roots):
        parser.error("give RUNS_ROOT folders or --groups NAME=DIR ..., one of the two")
    if args.groups and (args.group_by or args.pool):
        parser.error("--groups names the groups itself: drop --group-by and --pool")
    with usage_errors(parser, FileNotFoundError, RunFolderError, ValueError):
        if args.groups:
            named = [g.partition("=") for g in args.groups]
            if any(not name or not sep or not folder for name, sep, folder in named):
                parser.error(f"--groups takes NAME=DIR; got {args.groups}")
            groups = []
            for name, _, folder in named:
                found = [r for r in find_runs([folder]) if len(r.episode)]
                if found:
                    groups.append(Group(name, found, differences(found)))
        else:
            found = [r for r in find_runs(args.roots) if len(r.episode)]
            groups = group_runs(found, args.group_by, args.pool)
    if not groups:
        parser.error("no run with evaluations below "
                     f"{', '.join(map(str, args.roots or args.groups))}")
    return groups


def settings_from_args(parser: argparse.ArgumentParser,
                       args: argparse.Namespace) -> dict[tuple[str, int], list[Run]]:
    """The runs below ``args.roots`` that have evaluations, grouped by setting (the paper's
    claims compare settings): a setting whose runs differ in another recorded field is refused
    naming what differs, unless ``args.pool`` (each pool then said on stderr).
    """
    groups = groups_from_args(parser, args)
    settings: dict[tuple[str, int], list[Group]] = {}
    for g in groups:
        settings.setdefault(g.setting, []).append(g)
    mixed = [f"{k[0]} {k[1]}: "
             + differences_text(differences([r for g in gs for r in g.runs]))
             for k, gs in settings.items() if len(gs) > 1]
    if mixed:
        parser.error("runs of one setting differ in more than their seed, so they are not "
                     "pooled: " + " | ".join(mixed) + ". Compare them with --group-by FIELD "
                     "(or --groups NAME=DIR ...), or pool them with --pool")
    for line in pooled_lines(groups):
        print(f"note: {line}", file=sys.stderr)
    return {k: gs[0].runs for k, gs in settings.items()}
