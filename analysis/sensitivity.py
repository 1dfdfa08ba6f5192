"""The sensitivity study (issue 13): which of the paper's claims hold under each reading of the
choices it leaves unstated.

    python -m analysis.sensitivity --collect DEST          # finished units' spec.json, eval.csv
    python -m analysis.sensitivity report ROOT [--out DIR] # curves, verdicts, report.md
    python -m analysis.sensitivity --readings actor_penalty --setting zheight:3 --dry-run

A *reading* is a named set of extra ``ddpg_her.train`` arguments (`READINGS`, or your own with
``--reading NAME=ARGS`` or ``--readings-file``); a *setting* a (region, joints) pair. A unit is
one reading x one setting x all seeds in one training process (with ``--one-process``, all
units in one ``ddpg_her.train_many`` process: readings of one joint count and agent
configuration share one stacked agent), into
``ROOT/<reading>/<region>-j<joints>/s<seed>``: normal run folders, resumed when unfinished and
skipped when every seed's eval.csv reaches the budget (units started by hand with that layout
count as the study's own). The report judges each of the paper's claims
(`analysis.report.judge_claims`, by the rule `analysis.report` states and prints) for each
reading at the budget: each seed's mean over its last 5 test sessions at or below it, on the 65 %
Student-t interval of the paper and on percentile bootstrap intervals of the mean and the IQM
(drawn from a `numpy.random.Generator` seeded by ``--bootstrap-seed``, so the same runs give the
same bytes), with a Welch p-value for every comparison and the confounds it carries. A claim
about where training ends is *not judgeable* below the paper's 20,000 episodes. A run counts
for the reading its ``spec.json`` records: a run whose recorded choices are not those of the
reading its folder names is refused, naming it.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis import sweep
from analysis.curves import CSV_COLUMNS as SETTING_CURVE_COLUMNS
from analysis.curves import curve_rows as setting_curve_rows
from analysis.outputs import (
    add_force,
    check_files,
    check_folder,
    pyplot,
    save_figure,
    usage_errors,
    write_bytes,
    write_csv,
    write_errors,
    write_text,
)
from analysis.paper import PAPER_EPISODES
from analysis.readings import CHOICES, READINGS, Reading, missing_fields, run_choices
from analysis.report import (
    LAST_SESSIONS,
    Check,
    Curves,
    Interval,
    Verdict,
    claim_settings,
    comparisons_line,
    judge_claims,
    p_text,
    rule_lines,
    student_t,
)
from analysis.runs import CONFIDENCE, LEVEL, PERCENT, Group, Run, find_runs
from ddpg_her.config import Parser
from ddpg_her.units import split_passthrough
from ur5kin.checks import COUNT, integer, known_fields

# --- readings -----------------------------------------------------------------------------------


SETTINGS: tuple[tuple[str, int], ...] = (("unconstrained", 2), ("unconstrained", 3), ("zheight", 3),
                                         ("closebox", 3), ("farbox", 3), ("farbox", 6))
"""Default (region, joints) settings: one or more settings of each of the paper's claims.
Far box 3 beside far box 6: the paper's far-box claim covers both, and only far box 3 compares
with the 3-joint regions at one joint count (far box 6 against unconstrained 3 changes the
joint count too)."""

STUDY_EPISODES = 1000
"""Default training budget per run (episodes): the paper's far box learns within 1,000."""

STUDY_SEEDS = 5
"""Seeds per unit, trained together in one process (the paper: 5 runs per setting)."""

READING_FILE = "reading.json"
"""Below ``ROOT/<reading>/``: the reading's name, arguments and words, written when its units
are first started, so a report of the root knows what each folder means."""

COLLECTED_FILES = ("spec.json", "eval.csv")
"""What ``--collect`` copies of each run folder (no checkpoints, buffers or logs)."""

BOOTSTRAP_REPS = 10_000
"""Default bootstrap resamples per interval (rliable's default is 50,000; with 5 seeds the
percentile interval's ends move by under 0.5 successes per 100 between 10,000 and 50,000)."""

WORTH_GOALS = 200
"""Default goals per setting and reading of the worth-reaching diagnostic (0: skip it)."""


def parse_reading(text: str) -> Reading:
    """``NAME=ARGS`` (ARGS split like a shell line) -> a Reading."""
    name, sep, args = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(
            f"expected NAME=ARGS, e.g. 'tau01=--tau 0.01'; got {text!r}")
    try:
        return Reading(name, tuple(shlex.split(args)), ours=f"ddpg_her.train {args.strip()}")
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err)) from err


def load_readings(path: Path) -> list[Reading]:
    """Readings from a JSON or TOML file: ``{NAME: {"args": [...] or "...", "paper": "...",
    "ours": "..."}}`` (TOML: one ``[NAME]`` table each).

    Raises
    ------
    ValueError
        When the file is not such a mapping.
    """
    text = path.read_text()
    if path.suffix == ".toml":
        try:
            import tomllib
        except ModuleNotFoundError as err:  # Python 3.10
            raise ValueError(f"{path}: TOML needs Python >= 3.11; use JSON") from err
        data = tomllib.loads(text)
    else:
        data = json.loads(text)
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping NAME -> {{args, paper, ours}}")
    out = []
    for name, entry in data.items():
        if not isinstance(entry, dict) or "args" not in entry:
            raise ValueError(f"{path}: reading {name!r} needs an 'args' list or string")
        args = shlex.split(entry["args"]) if isinstance(entry["args"], str) else entry["args"]
        try:
            known_fields(Reading, {"name": name, **entry}, "reading")
            out.append(Reading(**{**entry, "name": name, "args": args}))
        except ValueError as err:
            raise ValueError(f"{path}: reading {name!r}: {err}") from None
    return out


def write_reading(root: Path, reading: Reading) -> None:
    """Record ``reading`` in ``root/<name>/reading.json``.

    Raises
    ------
    ValueError
        When the folder already records other arguments under that name.
    """
    path = root / reading.name / READING_FILE
    if path.exists():
        old = json.loads(path.read_text())
        if tuple(old.get("args", ())) != reading.args:
            raise ValueError(f"{path} records reading {reading.name!r} with arguments "
                             f"{old.get('args')}, not {list(reading.args)}: choose another "
                             "name or --out")
        return
    write_text(path, json.dumps({**asdict(reading), "args": list(reading.args)}, indent=2) + "\n")


def missing_task_fields(reading: Reading, extra: Sequence[str] = ()) -> list[str]:
    """The ``--task KEY=...`` keys of ``reading`` that this code's TaskSpec lacks
    (`analysis.readings.missing_fields`); none when ``--env-id`` in the reading or ``extra``
    names another env, whose task fields may differ."""
    if "--env-id" in (*reading.args, *extra):
        return []
    return missing_fields(sweep.task_keys(reading.args))


def units_for(readings: Sequence[Reading], settings: Sequence[tuple[str, int]], seeds: int,
              root: Path, episodes: int) -> list[sweep.Unit]:
    """One unit per reading and setting, reading-major."""
    return [sweep.Unit(region, joints, tuple(range(seeds)), root / r.name, episodes, r.args, r.name)
            for r in readings for region, joints in settings]


def collect(units: Sequence[sweep.Unit], dest: Path) -> tuple[int, list[str]]:
    """Copy every finished unit's `COLLECTED_FILES` (and its reading.json) to
    ``dest/runs/<reading>/<region>-j<joints>/s<seed>``.

    Returns
    -------
    copied : int
        Units copied.
    skipped : list of str
        The unfinished units, each with its seeds' statuses.
    """
    copied, skipped = 0, []
    for unit in units:
        status = [unit.status(s) for s in unit.seeds]
        if any(st != "done" for st in status):
            skipped.append(f"{unit.name} ({', '.join(status)})")
            continue
        base = dest / "runs" / unit.tag
        for seed in unit.seeds:  # each copy whole or not at all, by the one atomic writer
            target = base / unit.setting / f"s{seed}"
            for name in COLLECTED_FILES:
                write_bytes(target / name, (unit.run_dir(seed) / name).read_bytes())
        if (unit.root / READING_FILE).exists():
            write_bytes(base / READING_FILE, (unit.root / READING_FILE).read_bytes())
        copied += 1
    return copied, skipped


# --- the report ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Cell:
    """One reading x one setting at the budget: the seeds' successes and their intervals."""

    reading: str
    region: str
    joints: int
    episode: int
    """The evaluation judged: the last one common to every seed at or below the budget."""
    levels: tuple[float, ...]
    """Per seed, goals hit per 100 test goals, the mean over its last `LAST_SESSIONS` test
    sessions up to ``episode``."""
    t: Interval
    """Mean with the Student-t interval (analysis.report.student_t)."""
    boot_mean: Interval | None
    """Mean with its percentile bootstrap interval (`bootstrap_intervals`)."""
    boot_iqm: Interval | None
    """Interquartile mean with its percentile bootstrap interval."""
    partial: str = ""
    """Why the cell falls short of the study (fewer seeds, fewer episodes); empty when not."""
    worth: Interval | None = None
    """Share of goals worth reaching (analysis.optimality), percent, with its interval."""

    @property
    def setting(self) -> tuple[str, int]:
        return self.region, self.joints


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean of all of ``scores``: rliable's ``metrics.aggregate_iqm`` (scipy's
    ``trim_mean`` cutting ``int(0.25 n)`` values at each end), in numpy: ten times faster, which
    is most of a bootstrap's time."""
    a = np.sort(np.asarray(scores, dtype=float), axis=None)
    cut = int(0.25 * a.size)
    return float(a[cut:a.size - cut].mean())


def bootstrap_intervals(values: np.ndarray, level: float, reps: int,
                        seed: int) -> tuple[Interval, Interval]:
    """Mean and IQM of one setting's seeds with percentile bootstrap intervals.

    Parameters
    ----------
    values : (n_seeds,) float, successes per 100 test goals
    level : float in (0, 1)
        Two-sided coverage (the same as the Student-t interval's, so they compare).
    reps : int
        Bootstrap resamples.
    seed : int
        Seed of the resampling. The draws come from ``numpy.random.default_rng([seed,
        crc32(values)])``: the same values and seed give the same intervals in any order and
        process, and no global random state is read or changed.

    Returns
    -------
    mean, iqm : (estimate, low, high)
        The seeds resampled with replacement, the percentile interval of each statistic: for
        one task this is rliable's stratified bootstrap (whose resampling draws from numpy's
        global generator, whatever its ``random_state``, so it is not used). With one seed,
        both intervals are the value itself.
    """
    values = np.asarray(values, dtype=float).reshape(-1)
    n = len(values)
    if n < 2:
        v = float(values[0])
        return (v, v, v), (v, v, v)
    rng = np.random.default_rng([seed, zlib.crc32(values.tobytes())])
    draws = np.sort(values[rng.integers(0, n, size=(reps, n))], axis=1)  # (reps, n)
    cut = int(0.25 * n)
    stats_ = (draws.mean(axis=1), draws[:, cut:n - cut].mean(axis=1))
    q = 100.0 * np.array([(1.0 - level) / 2.0, (1.0 + level) / 2.0])
    mean, iqm_ = ((float(point), *map(float, np.percentile(drawn, q)))
                  for point, drawn in zip((values.mean(), iqm(values)), stats_, strict=True))
    return mean, iqm_


def reading_settings(reading: Reading) -> dict[tuple[str, str], str | list[str]]:
    """What a reading's ``ddpg_her.train`` arguments set: (spec section, field) -> value as
    text (``--task K=V`` -> ("task", K); ``--flag-name V...`` -> ("agent", "flag_name"); a
    switch ``--flag-name`` -> "True", ``--no-flag-name`` -> "False")."""
    out: dict[tuple[str, str], str | list[str]] = {}
    args, i = list(reading.args), 0
    while i < len(args):
        flag, eq, value = args[i].partition("=")
        i += 1
        if not flag.startswith("--"):
            continue
        values = [value] if eq else []
        while not eq and i < len(args) and not args[i].startswith("--"):
            values.append(args[i])
            i += 1
        if flag == "--task":
            out.update((("task", key), text) for key, _, text in (v.partition("=") for v in values))
            continue
        # a switch: --flag-name on (e.g. --batch-norm), --no-flag-name off (BooleanOptionalAction)
        off = not values and flag.startswith("--no-")
        out[("agent", flag[5 if off else 2:].replace("-", "_"))] = (
            (values[0] if len(values) == 1 else values) if values else str(not off))
    return out


def _same(recorded: Any, text: str | list[str]) -> bool:
    if isinstance(text, list):
        return (isinstance(recorded, list | tuple) and len(recorded) == len(text)
                and all(_same(r, t) for r, t in zip(recorded, text, strict=True)))
    try:
        return float(recorded) == float(text)
    except (TypeError, ValueError):
        return str(recorded).lower() == str(text).lower()


def _defaults() -> dict[tuple[str, str], Any]:
    """(spec section, field) -> this code's default, for every TaskSpec and AgentConfig field."""
    import dataclasses
    import enum

    from ddpg_her.config import AgentConfig
    from envs.spec import TaskSpec

    return {(section, f.name): f.default.value if isinstance(f.default, enum.Enum) else f.default
            for section, cls in (("task", TaskSpec), ("agent", AgentConfig))
            for f in dataclasses.fields(cls) if f.default is not dataclasses.MISSING}


def reading_mismatches(reading: Reading, spec: dict[str, Any]) -> list[str]:
    """How a run's ``spec.json`` differs from ``reading``: each choice of
    `analysis.readings.CHOICES` (the reading's value; where it sets none, this code's default or
    the value of runs written before the field existed) and each other field the reading sets
    that the spec records; [] when it is the reading's run."""
    sets = reading_settings(reading)
    recorded = run_choices(spec)
    defaults = _defaults()
    problems = []
    for name, section, field_, before in CHOICES:
        if (section, field_) in sets:
            wants = [sets[(section, field_)]]
        else:
            wants = [before] + ([str(defaults[(section, field_)])]
                                if (section, field_) in defaults else [])
        if not any(_same(recorded[name], want) for want in wants):
            problems.append(f"{section}.{field_} = {recorded[name]} where the reading has "
                            + " or ".join(dict.fromkeys(map(str, wants))))
    checked = {(section, field_) for _, section, field_, _ in CHOICES}
    for (section, field_), want in sets.items():
        have = spec.get(section, {})
        if (section, field_) not in checked and isinstance(have, dict) and field_ in have \
                and not _same(have[field_], want):
            problems.append(f"{section}.{field_} = {have[field_]} where the reading has {want}")
    return problems


def group_runs(root: Path, known: Mapping[str, Reading] | None = None,
               ) -> dict[str, dict[tuple[str, int], list[Run]]]:
    """The runs with evaluations below ``root``, by reading folder and (region, joints).

    Raises
    ------
    ValueError
        When a run's ``spec.json`` records choices other than those of the reading its folder
        names (``known``: the readings by name, default the built-in ones), or, for a folder of
        an unknown reading, other choices than the folder's other runs: a study pools a run by
        what it was trained under, not by where it lies.
    """
    known = READINGS if known is None else known
    out: dict[str, dict[tuple[str, int], list[Run]]] = {}
    first: dict[str, tuple[Run, dict[str, str]]] = {}
    for run in find_runs([root]):
        parts = run.path.resolve().relative_to(root.resolve()).parts  # <reading>/.../run
        if len(parts) < 2 or not len(run.episode):
            continue
        reading = parts[0]
        if reading in known:
            problems = reading_mismatches(known[reading], run.spec)
            if problems:
                raise ValueError(
                    f"{run.path}: its spec.json records {'; '.join(problems)}: it was not "
                    f"trained under the reading {reading!r} its folder names "
                    f"({' '.join(known[reading].args) or 'the defaults'}); move it to the folder "
                    "of its reading")
        else:
            choices = run_choices(run.spec)
            seen = first.setdefault(reading, (run, choices))
            if seen[1] != choices:
                diff = [f"{k}: {seen[1][k]} in {seen[0].path}, {v} in {run.path}"
                        for k, v in choices.items() if seen[1][k] != v]
                raise ValueError(f"reading folder {root / reading} mixes runs trained under "
                                 f"other choices ({'; '.join(diff)})")
        out.setdefault(reading, {}).setdefault(run.setting, []).append(run)
    return out


def make_cell(reading: str, runs: Sequence[Run], budget: int, seeds: int, level: float,
              reps: int, boot_seed: int) -> Cell:
    """The statistics of one reading x setting at the budget (see `Cell`)."""
    curves = cut_curves(runs, budget)
    values = curves.level()
    short = []
    if len(runs) < seeds:
        short.append(f"{len(runs)} of {seeds} seeds")
    if curves.end < budget:
        short.append(f"{curves.end:,} of {budget:,} episodes")
    return Cell(reading, runs[0].region, runs[0].joints, curves.end,
                tuple(float(v) for v in values), student_t(level)(values, PERCENT),
                *bootstrap_intervals(values, level, reps, boot_seed), "; ".join(short))


def cut_curves(runs: Sequence[Run], budget: int) -> Curves:
    """The runs' common test sessions at or below the budget (the first session when none is:
    judged there, and marked partial)."""
    curves = Curves.of(runs)
    return curves.until(max(budget, int(curves.episode[0])))


def worth_shares(cells: Sequence[Cell], groups: Mapping[str, Mapping[tuple[str, int], list[Run]]],
                 goals: int, seed: int) -> tuple[dict[tuple[str, str, int], Interval], str]:
    """Each cell's share of goals worth reaching (``analysis.optimality.worth_reaching`` on the
    task its runs recorded, with their discount), in percent; and a note for the report.

    Cells with the same task and discount share one computation. When ``goals`` is 0, no
    shares and a note saying so.
    """
    if goals <= 0:
        return {}, "worth-reaching diagnostic skipped (--worth-goals 0)"
    from analysis import optimality  # Pinocchio and the env: only when shares are asked for
    from envs.spec import TaskSpec

    cache: dict[str, Interval | None] = {}
    out, problems = {}, []
    for cell in cells:
        spec = groups[cell.reading][cell.setting][0].spec
        gamma = float(spec.get("agent", {}).get("gamma", 0.98))
        key = json.dumps([spec.get("task"), gamma], sort_keys=True)
        if key not in cache:
            try:
                task = TaskSpec.from_record(spec["task"])
                result = optimality.worth_reaching(task, goals=goals, gamma=gamma, seed=seed)
                low, high = result.share_worth_ci
                cache[key] = 100.0 * result.share_worth, 100.0 * low, 100.0 * high
            except (KeyError, TypeError, ValueError) as err:
                problems.append(f"{cell.reading} {cell.region} {cell.joints}: {err}")
                cache[key] = None
        if cache[key] is not None:
            out[(cell.reading, *cell.setting)] = cache[key]
    note = (f"worth reaching: analysis.optimality.worth_reaching, {goals} goals per setting, "
            f"seed {seed}, the runs' own task and discount")
    if problems:
        note += "; not computed for " + "; ".join(problems)
    return out, note


@dataclass(frozen=True)
class VerdictRow:
    """One claim x one reading: the verdict on each kind of interval."""

    claim: str
    reading: str
    t: Verdict
    boot_mean: Verdict | None
    boot_iqm: Verdict | None
    detail_t: str
    detail_boot_mean: str
    detail_boot_iqm: str
    partial: str = ""
    """The claim's settings of this reading that fall short of the study, with why."""
    p_value: float | None = None
    """Two-sided Welch p-value over seeds of the claim's comparison (None: not a comparison)."""
    confounds: tuple[str, ...] = ()
    """What differs between the compared settings besides their regions."""


def verdicts(cells: Sequence[Cell], groups: Mapping[str, Mapping[tuple[str, int], Sequence[Run]]],
             readings: Sequence[str], budget: int, level: float, reps: int,
             boot_seed: int) -> list[VerdictRow]:
    """Every claim of `analysis.report.judge_claims` for every reading, claim-major, judged on
    each setting's sessions at or below ``budget``; ``cells`` say which settings are partial."""
    needs = claim_settings()

    def boot(which: int) -> Any:
        return lambda values, bounds: bootstrap_intervals(values, level, reps, boot_seed)[which]

    per: dict[str, list[VerdictRow]] = {}
    for reading in readings:
        mine = {k: cut_curves(runs, budget) for k, runs in groups.get(reading, {}).items()}
        short = {c.setting: c.partial for c in cells if c.reading == reading}
        checks = [judge_claims(mine, fn) for fn in (student_t(level), boot(0), boot(1))]
        for a, b, c in zip(*checks, strict=True):
            partial = [f"{r} {j}: {short[(r, j)]}" for r, j in needs[a.claim] if short.get((r, j))]
            per.setdefault(a.claim, []).append(VerdictRow(
                a.claim, reading, a.verdict, b.verdict, c.verdict, a.detail, b.detail, c.detail,
                "; ".join(partial) if a.verdict is not Verdict.NOT_RUN else "", a.p_value,
                a.confounds))
    return [row for rows in per.values() for row in rows]


def word(verdict: Verdict | None, partial: str = "") -> str:
    """A verdict as the tables print it (``(partial)`` appended when it rests on a setting
    that falls short of the study)."""
    if verdict is None:
        return "-"
    return verdict.value + (" (partial)" if partial else "")


VERDICT_COLUMNS = ("claim", "reading", "verdict_t", "verdict_bootstrap_mean",
                   "verdict_bootstrap_iqm", "welch_p", "partial", "confounds", "detail_t",
                   "detail_bootstrap_mean", "detail_bootstrap_iqm")
"""Columns of verdicts.csv: one row per claim and reading; verdicts read holds | fails |
within noise | not judgeable | not run; welch_p is the comparison's two-sided Welch p-value
over seeds (empty: not a comparison, nan: undefined); partial names the claim's settings below
the study's seeds or budget; confounds what else differs between the settings compared."""

FINAL_COLUMNS = ("reading", "region", "joints", "seeds", "episode", "partial", "levels",
                 "mean", "t_low", "t_high", "boot_mean_low", "boot_mean_high", "iqm",
                 "boot_iqm_low", "boot_iqm_high", "worth_reaching", "worth_low", "worth_high")
"""Columns of finals.csv: per reading and setting, each seed's mean successes per 100 test goals
over its last 5 test sessions up to the judged evaluation (';'-separated), their intervals, and
the worth-reaching share (%)."""

CURVE_COLUMNS = ("reading", *SETTING_CURVE_COLUMNS[1:])
"""Columns of curves.csv: `analysis.curves`' with the reading for the group, successes per 100
test goals."""


def _r(x: float | None) -> str:
    return "" if x is None else f"{x:.4g}"


def write_csvs(cells: Sequence[Cell], rows: Sequence[VerdictRow], curves: Sequence[dict],
               out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "verdicts.csv", VERDICT_COLUMNS, (
        [r.claim, r.reading, word(r.t), word(r.boot_mean), word(r.boot_iqm),
         "" if r.p_value is None else f"{r.p_value:.4g}", r.partial, "; ".join(r.confounds),
         r.detail_t, r.detail_boot_mean, r.detail_boot_iqm] for r in rows))
    none = (None,) * 3
    write_csv(out / "finals.csv", FINAL_COLUMNS, (
        [c.reading, c.region, c.joints, len(c.levels), c.episode, c.partial,
         ";".join(f"{v:g}" for v in c.levels),
         *map(_r, (*c.t, *(c.boot_mean or none)[1:], *(c.boot_iqm or none), *(c.worth or none)))]
        for c in cells))
    write_csv(out / "curves.csv", CURVE_COLUMNS, curves)


def curve_rows(groups: Mapping[str, Mapping[tuple[str, int], list[Run]]],
               level: float) -> list[dict]:
    """Per reading, setting and evaluation episode: mean successes and interval over seeds
    (`analysis.curves.curve_rows` with the reading)."""
    return [{"reading": reading, **{k: v for k, v in row.items() if k != "group"}}
            for reading, settings in groups.items()
            for row in setting_curve_rows([Group(f"{r} {j}", runs, {})
                                           for (r, j), runs in settings.items()], level)]


def plot_curves(rows: Sequence[dict], settings: Sequence[tuple[str, int]],
                readings: Sequence[str], budget: int, level: float, out: Path) -> None:
    """One panel per setting, one line per reading (mean, band = interval), the budget dotted."""
    cols = min(len(settings), 3)
    nrows = -(-len(settings) // cols)
    fig, axes = pyplot().subplots(nrows, cols, squeeze=False, sharey=True,
                                  figsize=(3.6 * cols + 0.4, 2.8 * nrows + 0.9))
    for ax, (region, joints) in zip(axes.flat, settings, strict=False):
        for k, reading in enumerate(readings):
            mine = [r for r in rows if r["reading"] == reading and r["region"] == region
                    and r["joints"] == joints]
            if not mine:
                continue
            e = [r["episode"] for r in mine]
            ax.fill_between(e, [r["ci_low"] for r in mine], [r["ci_high"] for r in mine],
                            color=f"C{k}", alpha=0.2, lw=0)
            ax.plot(e, [r["mean_successes"] for r in mine], color=f"C{k}", lw=1.5,
                    label=f"{reading} ({mine[0]['seeds']} seeds)")
        ax.axvline(budget, color="0.5", ls=":", lw=1)
        ax.set_title(f"{region}, joints 1-{joints}", fontsize=9)
        ax.set_ylim(-2, 102)
        ax.grid(alpha=0.3)
        ax.set_xlabel("training episodes")
        ax.legend(fontsize=6, loc="upper left")
    for ax in axes.flat[len(settings):]:
        ax.set_visible(False)
    for row in axes:
        row[0].set_ylabel("goals hit / 100")
    fig.suptitle(f"Test successes per reading: mean and {level:.0%} Student-t interval over "
                 f"seeds (budget {budget:,} episodes dotted)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    save_figure(fig, out, dpi=120)


def plot_worth(cells: Sequence[Cell], settings: Sequence[tuple[str, int]],
               readings: Sequence[str], out: Path) -> None:
    """Grouped bars: per setting, each reading's share of goals worth reaching (%) with its
    interval, drawn as ``analysis.optimality.plot`` draws its shares."""
    from analysis.optimality import plot

    worth = {(c.reading, c.setting): c.worth for c in cells if c.worth is not None}
    plot([{"region": s[0], "joints": s[1], "reading": r, "share_reachable": np.nan, **dict(zip(
        ("share_worth", "ci_low", "ci_high"), np.divide(worth[(r, s)], 100.0), strict=True))}
        for s in settings for r in readings if (r, s) in worth], out=out)


def _fmt(stat: Interval | None) -> str:
    return "-" if stat is None else "{:.1f} [{:.1f}, {:.1f}]".format(*stat)


def render(cells: Sequence[Cell], rows: Sequence[VerdictRow], readings: Sequence[str],
           known: Mapping[str, Reading], budget: int, seeds: int, level: float, reps: int,
           worth_note: str, boot_seed: int = 0) -> str:
    """report.md: the readings, the rule, the verdict tables and each cell's statistics."""
    boot = (f"a percentile bootstrap over seeds ({reps:,} resamples, numpy Generator seeded "
            f"by --bootstrap-seed {boot_seed})")
    lines = [
        "# Sensitivity of the paper's claims to the reproduction's unstated choices", "",
        f"Budget {budget:,} training episodes and {seeds} seeds per unit; every claim judged on "
        f"each seed's mean over its last {LAST_SESSIONS} test sessions at or below the budget. "
        f"Intervals are two-sided {level:.0%}: Student-t of the mean over seeds (the paper's), "
        f"and {boot} of the mean and the interquartile mean (IQM). Successes per 100 test "
        "goals. Settings with fewer seeds or episodes than the study are marked *partial*.", ""]
    if budget < PAPER_EPISODES:
        lines += [f"**At {budget:,} episodes ({budget / PAPER_EPISODES:.0%} of the paper's "
                  f"{PAPER_EPISODES:,}) every claim about where training ends is not "
                  "judgeable**; the tables show what the runs reach so far as information.", ""]
    lines += ["## Readings", "", "| reading | the paper | this reading | ddpg_her.train "
              "arguments |", "|---|---|---|---|"]
    for name in readings:
        r = known.get(name)
        lines.append(f"| {name} | {r.paper if r else '?'} | {r.ours if r else '?'} | "
                     f"{' '.join(r.args) if r and r.args else '(none)' if r else '?'} |")
    lines += ["", *rule_lines(level), "## The paper's claims, per reading", "",
              "Each cell: the verdict on the Student-t interval / on the bootstrap interval of "
              "the mean / of the IQM, then the Welch p-value of the comparison (p, where the "
              "claim compares settings).", "",
              "| claim | " + " | ".join(readings) + " |",
              "|---|" + "---|" * len(readings)]
    for claim in dict.fromkeys(r.claim for r in rows):
        cells_ = []
        for name in readings:
            row = next(r for r in rows if r.claim == claim and r.reading == name)
            if row.t in (Verdict.NOT_RUN, Verdict.NOT_JUDGEABLE) and row.boot_mean is row.t:
                text = word(row.t)
            else:
                text = (f"{word(row.t, row.partial)} / {word(row.boot_mean)} / "
                        f"{word(row.boot_iqm)}")
            if row.p_value is not None:
                text += f"; p {p_text(row.p_value)}"
            cells_.append(text)
        lines.append(f"| {claim} | " + " | ".join(cells_) + " |")
    judged = [Check(r.claim, r.t, r.detail_t, r.p_value) for r in rows]
    lines += ["", comparisons_line(judged), "", "## Confounds", "",
              "The comparisons whose settings differ in more than the goal region (per reading: "
              "the settings each compares depend on which were run).", "",
              "| claim | reading | confounds |", "|---|---|---|"]
    lines += [f"| {r.claim} | {r.reading} | {'; '.join(r.confounds)} |" for r in rows
              if r.confounds] or ["| (none) | | |"]
    lines += ["", f"## Levels at {budget:,} episodes", "",
              f"Each seed's mean over its last {LAST_SESSIONS} test sessions at or below the "
              "budget, then over seeds.", "",
              "| reading | setting | seeds | episode | mean [t] | mean [bootstrap] | "
              "IQM [bootstrap] | worth reaching (%) | partial |",
              "|---|---|---|---|---|---|---|---|---|"]
    for c in cells:
        lines.append(f"| {c.reading} | {c.region} {c.joints} | {len(c.levels)} | "
                     f"{c.episode:,} | {_fmt(c.t)} | {_fmt(c.boot_mean)} | "
                     f"{_fmt(c.boot_iqm)} | {_fmt(c.worth)} | {c.partial or '-'} |")
    lines += ["", worth_note + ".", "", "## Verdict details", "",
              "| claim | reading | Student-t | bootstrap mean | bootstrap IQM |",
              "|---|---|---|---|---|"]
    lines += [f"| {r.claim} | {r.reading} | not run: {r.detail_t} | - | - |"
              if r.t is Verdict.NOT_RUN else
              f"| {r.claim} | {r.reading} | {word(r.t, r.partial)}: {r.detail_t} | "
              f"{word(r.boot_mean)}: {r.detail_boot_mean} | "
              f"{word(r.boot_iqm)}: {r.detail_boot_iqm} |" for r in rows]
    lines += ["", "Figures: `curves.png` (numbers in `curves.csv`)"
              + (", `worth_reaching.png`" if any(c.worth for c in cells) else "")
              + "; tables: `verdicts.csv`, `finals.csv`."]
    return "\n".join(lines) + "\n"


@dataclass
class StudyReport:
    """What `report` computed (also written to disk)."""

    cells: list[Cell]
    rows: list[VerdictRow]
    readings: list[str]
    text: str
    files: list[Path] = field(default_factory=list)


def known_readings(root: Path, extra: Sequence[Reading] = ()) -> dict[str, Reading]:
    """Built-in readings, those recorded below ``root`` (reading.json) and ``extra``; a
    reading.json that is not a reading record is a ValueError naming it."""
    known = dict(READINGS)
    for path in sorted(root.glob(f"*/{READING_FILE}")):
        try:
            data = json.loads(path.read_text())
            known.setdefault(data["name"], Reading(**data))
        except (KeyError, ValueError, TypeError) as err:
            raise ValueError(f"{path}: not a reading record ({err!r}); expected the JSON "
                             "object of name, args, paper and ours that a study writes") from err
    known.update({r.name: r for r in extra})
    return known


def report(root: Path, out: Path, budget: int = STUDY_EPISODES, seeds: int = STUDY_SEEDS,
           level: float = CONFIDENCE, reps: int = BOOTSTRAP_REPS, boot_seed: int = 0,
           worth_goals: int = WORTH_GOALS, readings: Sequence[str] | None = None,
           extra: Sequence[Reading] = ()) -> StudyReport:
    """Judge every claim for every reading below ``root`` and write report.md, verdicts.csv,
    finals.csv, curves.png/csv (and worth_reaching.png) to ``out``.

    ``readings`` orders and filters the readings shown (default: the built-in ones, run or not,
    then any other folder below ``root`` with runs).

    Raises
    ------
    FileNotFoundError
        When ``root`` does not exist.
    """
    known = known_readings(root, extra)
    groups = group_runs(root, known)
    names = list(readings) if readings else [*READINGS, *sorted(set(groups) - set(READINGS))]
    settings = [*(s for s in SETTINGS if any(s in groups.get(r, {}) for r in names)),
                *sorted({s for r in names for s in groups.get(r, {})} - set(SETTINGS))]
    cells = [make_cell(r, groups[r][s], budget, seeds, level, reps, boot_seed)
             for r in names for s in settings if s in groups.get(r, {})]
    shares, note = worth_shares(cells, groups, worth_goals, boot_seed)
    cells = [Cell(**{**asdict(c), "worth": shares.get((c.reading, *c.setting))}) for c in cells]
    rows = verdicts(cells, groups, names, budget, level, reps, boot_seed)
    run = [r for r in names if r in groups]
    curve_table = curve_rows({r: groups[r] for r in run}, level)
    write_csvs(cells, rows, curve_table, out)
    files = [out / "verdicts.csv", out / "finals.csv", out / "curves.csv"]
    if settings:
        plot_curves(curve_table, settings, run, budget, level, out / "curves.png")
        files.append(out / "curves.png")
    if shares:
        plot_worth(cells, settings, run, out / "worth_reaching.png")
        files.append(out / "worth_reaching.png")
    text = render(cells, rows, names, known, budget, seeds, level, reps, note, boot_seed)
    write_text(out / "report.md", text)
    files.append(out / "report.md")
    return StudyReport(cells, rows, names, text, files)


# --- command line -------------------------------------------------------------------------------


def _add_reading_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--reading", type=parse_reading, action="append", default=[],
                        metavar="NAME=ARGS",
                        help="define a reading: ddpg_her.train arguments as one shell-quoted "
                             "string, e.g. --reading tau01=--tau=0.01 (quote ARGS that hold "
                             "spaces: 'tau01=--tau 0.01'); repeatable")
    parser.add_argument("--readings-file", type=Path, default=None,
                        help="define readings from a JSON or TOML file: {NAME: {args: [...] or "
                             "'...', paper: '...', ours: '...'}}")


def _user_readings(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[Reading]:
    user = list(args.reading)
    if args.readings_file is not None:
        try:
            user += load_readings(args.readings_file)
        except (OSError, ValueError) as err:
            parser.error(f"--readings-file: {err}")
    clash = [r.name for r in user if r.name in READINGS and READINGS[r.name].args != r.args]
    if clash:
        parser.error(f"reading(s) {clash} are built in with other arguments; choose another name")
    return user


def report_main(argv: Sequence[str]) -> int:
    parser = Parser(
        prog="python -m analysis.sensitivity report",
        description="Judge the paper's claims for every reading below ROOT (ROOT/<reading>/"
                    "<region>-j<joints>/s<seed>, e.g. runs/sensitivity or a --collect "
                    "DEST/runs) and write report.md, verdicts.csv, finals.csv, curves.png/csv.",
        formatter_class=sweep.HelpFormatter)
    parser.add_argument("root", type=Path, metavar="ROOT", help="the study's runs root")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder of the report's files (default: ROOT)")
    parser.add_argument("--episodes", type=COUNT.read, default=STUDY_EPISODES,
                        help="the budget (training episodes, >= 1): claims are judged at the "
                             "last evaluation at or below it; less is partial")
    parser.add_argument("--seeds", type=COUNT.read, default=STUDY_SEEDS,
                        help="seeds a complete setting has (count, >= 1); fewer is partial")
    parser.add_argument("--confidence", type=LEVEL.read, default=CONFIDENCE,
                        help="two-sided level of every interval (fraction in (0, 1); the "
                             "paper's figures: 0.65)")
    parser.add_argument("--reps", type=COUNT.read, default=BOOTSTRAP_REPS,
                        help="bootstrap resamples per interval (count, >= 1)")
    parser.add_argument("--bootstrap-seed", type=int, default=0,
                        help="seed of the bootstrap resampling and of the worth-reaching goals")
    parser.add_argument("--worth-goals", type=integer(0).read, default=WORTH_GOALS,
                        help="goals per setting and reading for analysis.optimality's "
                             "worth-reaching share (count, >= 0; 0 skips it)")
    parser.add_argument("--readings", nargs="+", default=None, metavar="NAME",
                        help="readings shown, in this order (default: the built-in ones, then "
                             "any other folder with runs)")
    _add_reading_arguments(parser)
    add_force(parser, "replace report files in --out that hold another report (refused by "
              "default, naming them)")
    args = parser.parse_args(argv)
    out = args.out or args.root
    with usage_errors(parser):  # before any computing
        check_files(out, ("verdicts.csv", "finals.csv", "curves.csv", "curves.png",
                          "worth_reaching.png", "report.md"), "--out" if args.out else "ROOT")
    with usage_errors(parser, FileNotFoundError, ValueError), \
            write_errors(parser, args.force, f"report {args.root} --out {out}"):
        result = report(args.root, out, args.episodes, args.seeds, args.confidence, args.reps,
                        args.bootstrap_seed, args.worth_goals, args.readings,
                        _user_readings(parser, args))
    print(result.text, end="")
    print("wrote " + ", ".join(map(str, result.files)), file=sys.stderr)
    return 0


def add_study_arguments(parser: argparse.ArgumentParser, settings: Sequence[tuple[str, int]],
                        default_out: Path, what: str) -> None:
    """The flags of a study of readings x settings (this one, `analysis.algorithms`): the
    settings, `analysis.sweep`'s execution flags at the study's budget, and ``--collect``;
    ``what`` names the study's readings in the help."""
    parser.add_argument("--setting", type=sweep.parse_setting, action="append",
                        metavar="REGION:JOINTS",
                        help="a (region, joints) setting, joints in 2..6; repeatable (default: "
                             + ", ".join(f"{r}:{j}" for r, j in settings) + ")")
    sweep.add_execution_arguments(parser, default_out, unit_word="unit")
    parser.set_defaults(episodes=STUDY_EPISODES, seeds=STUDY_SEEDS)
    parser.add_argument("--collect", type=Path, default=None, metavar="DEST",
                        help="train nothing: copy each finished unit's spec.json and eval.csv to "
                             f"DEST/runs/<{what}>/<region>-j<joints>/s<seed> (no checkpoints); "
                             "files there that hold other runs are not replaced without --force")
    add_force(parser, "with --collect: replace runs in DEST that differ (refused by default, "
              "naming them)")


def run_study(parser: argparse.ArgumentParser, args: argparse.Namespace,
              readings: Sequence[Reading], settings: Sequence[tuple[str, int]],
              extra: Sequence[str]) -> int:
    """What a study's command line asks of the units of ``readings`` x (``args.setting`` or
    ``settings``): a dry run, ``--collect``, or training them with each reading recorded
    (`write_reading`) in the root."""
    threads = sweep.check_execution_arguments(parser, args)
    if args.collect is not None:
        with usage_errors(parser):
            check_folder(args.collect / "runs", "--collect")
    units = units_for(readings, args.setting or settings, args.seeds, args.out, args.episodes)
    if args.dry_run:
        sweep.dry_run(units, args, threads, extra)
        return 0
    if args.collect is None:
        sweep.refuse_problems(units, extra, args)  # a run it would refuse leaves no reading.json
        with usage_errors(parser, ValueError):
            for reading in readings:
                write_reading(args.out, reading)
        return sweep.execute(units, args, threads, extra, unit_word="units")
    root = args.collect / "runs"
    with usage_errors(parser, ValueError), \
            write_errors(parser, args.force, f"--collect {args.collect}"):  # nothing half-written
        copied, skipped = collect(units, args.collect)
        done = {u.tag for u in units if all(u.status(s) == "done" for s in u.seeds)}
        for reading in readings:  # units started by hand have no reading.json of their own
            if reading.name in done or (root / reading.name).is_dir():
                write_reading(root, reading)
    print(f"copied {copied} finished unit(s) to {root}; {len(skipped)} not finished"
          + (": " + ", ".join(skipped) if skipped else ""), file=sys.stderr)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["report"]:
        return report_main(argv[1:])
    argv, extra = split_passthrough(argv)
    parser = Parser(
        prog="python -m analysis.sensitivity", description=__doc__.split("\n\n")[0],
        epilog="Arguments after -- pass to every python -m ddpg_her.train (after the reading's "
               "own). 'python -m analysis.sensitivity report --help' explains the report. "
               "Readings: " + "; ".join(f"{r.name}: {' '.join(r.args) or '(defaults)'}"
                                        for r in READINGS.values()),
        formatter_class=sweep.HelpFormatter)
    parser.add_argument("--readings", nargs="+", default=None, metavar="NAME",
                        help="readings to run (default: the built-in ones, "
                             f"{', '.join(READINGS)}, and every --reading/--readings-file one)")
    _add_reading_arguments(parser)
    add_study_arguments(parser, SETTINGS, Path("runs/sensitivity"), "reading")
    args = parser.parse_args(argv)
    user = _user_readings(parser, args)
    known = {**READINGS, **{r.name: r for r in user}}
    names = args.readings or list(known)
    unknown = [n for n in names if n not in known]
    if unknown:
        parser.error(f"unknown reading(s) {unknown}; known: {', '.join(known)} (define one "
                     "with --reading NAME=ARGS)")
    lacking = {name: missing_task_fields(known[name], extra) for name in names}
    for name in (n for n in names if lacking[n]):
        print(f"reading {name}: this code's TaskSpec has no field {', '.join(lacking[name])}; "
              "skipped", file=sys.stderr)
    readings = [known[n] for n in names if not lacking[n]]
    return run_study(parser, args, readings, SETTINGS, extra)


if __name__ == "__main__":
    sys.exit(main())
