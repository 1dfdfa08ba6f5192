"""A probe of bad inputs across the entry points (issue 37): each case runs one command's
``main`` in this process and records what kind of answer it gave: ``python -m
benchmarks.reliability_probe --out results/reliability/probe.csv``.

Kinds of answer: ``refusal`` (expected: either of the next two), ``usage`` (exit 2 with an
``error:`` line naming the problem), ``error``
(another non-zero exit with a message), ``ok`` (exit 0), ``traceback`` (an exception escaped
``main``), ``hang`` (over ``--limit-s``; the case is abandoned). A case is *as expected* when
the kind matches and, for refusals, the message holds the case's key words. Every case here
is cheap: no training runs (dry runs, refusals before work), so the probe takes minutes.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import importlib
import io
import sys
import tempfile
import traceback
from collections.abc import Sequence
from pathlib import Path

FARBOX = ["--setting", "farbox:3", "--dry-run"]
STUDY = ["--setting", "farbox:3", "--dry-run"]


def cases(tmp: Path) -> list[tuple[str, str, list[str], str, str]]:
    """(case, module, argv, expected kind, key words of the expected message)."""
    blocker = tmp / "blocker"
    blocker.write_text("x")
    out = []
    sweep_root = ["--out", str(tmp / "sw"), "--episodes", "200", "--seeds", "1"]
    # kind 2: what follows -- may not set what the study sets itself
    for flag, value in (("--region", "zheight"), ("--out", str(tmp / "x")), ("--seeds", "3"),
                        ("--seed", "3"), ("--episodes", "5"), ("--joints", "6"),
                        ("--threads", "4"), ("--device", "cpu"), ("--env-backend", "batched"),
                        ("--resume", None), ("--no-progress", None), ("--reg", "zheight"),
                        ("--epi", "5"), ("--env-dyn", "numba")):
        extra = [flag] if value is None else [flag, value]
        out.append((f"sweep -- {' '.join(extra)}", "analysis.sweep",
                    [*FARBOX, *sweep_root, "--", *extra], "usage", flag))
        out.append((f"sensitivity -- {' '.join(extra)}", "analysis.sensitivity",
                    [*STUDY, "--readings", "ours", "--out", str(tmp / "se"), "--", *extra],
                    "usage", flag))
        out.append((f"algorithms -- {' '.join(extra)}", "analysis.algorithms",
                    [*STUDY, "--algos", "td3", "--out", str(tmp / "al"), "--", *extra],
                    "usage", flag))
    for task in ("region=zheight", "n_joints=6"):
        out.append((f"sweep -- --task {task}", "analysis.sweep",
                    [*FARBOX, *sweep_root, "--", "--task", task], "usage", "--task"))
    out += [
        ("algorithms td3 -- --algo sac", "analysis.algorithms",
         [*STUDY, "--algos", "td3", "--out", str(tmp / "al"), "--", "--algo", "sac"], "usage",
         "--algo"),
        ("algorithms sac -- --exploration-rate 0.1", "analysis.algorithms",
         [*STUDY, "--algos", "sac", "--out", str(tmp / "al"), "--", "--exploration-rate",
          "0.1"], "usage", "--exploration-rate"),
        ("algorithms ensemble -- --ensemble 2", "analysis.algorithms",
         [*STUDY, "--algos", "ensemble", "--out", str(tmp / "al"), "--", "--ensemble", "2"],
         "usage", "--ensemble"),
        ("sensitivity actor_penalty -- --task action_penalty_unit=command",
         "analysis.sensitivity", [*STUDY, "--readings", "actor_penalty", "--out",
                                  str(tmp / "se"), "--", "--task",
                                  "action_penalty_unit=command"], "usage", "action_penalty_unit"),
        ("sensitivity lillicrap_nets -- --no-batch-norm", "analysis.sensitivity",
         [*STUDY, "--readings", "lillicrap_nets", "--out", str(tmp / "se"), "--",
          "--no-batch-norm"], "usage", "--no-batch-norm"),
        ("sensitivity reading --out", "analysis.sensitivity",
         [*STUDY, "--reading", "m=--out elsewhere", "--readings", "m", "--out",
          str(tmp / "se")], "usage", "--out"),
        ("sensitivity reading --region", "analysis.sensitivity",
         [*STUDY, "--reading", "m=--region zheight", "--readings", "m", "--out",
          str(tmp / "se")], "usage", "--region"),
        ("sweep -- --tau 0.01 (left open)", "analysis.sweep",
         [*FARBOX, *sweep_root, "--", "--tau", "0.01"], "ok", ""),
        ("sweep -- --task action_weight=0.5 (left open)", "analysis.sweep",
         [*FARBOX, *sweep_root, "--", "--task", "action_weight=0.5"], "ok", ""),
    ]
    # kind 3: output paths checked before work
    for module, args in (("analysis.sweep", ["--setting", "farbox:3", "--episodes", "200",
                                             "--seeds", "1"]),
                         ("analysis.sensitivity", ["--setting", "farbox:3", "--readings",
                                                   "ours"]),
                         ("analysis.algorithms", ["--setting", "farbox:3", "--algos", "td3"])):
        out.append((f"{module.split('.')[1]} --out under a file", module,
                    [*args, "--out", str(blocker / "r")], "usage", "is a file"))
    out += [
        ("sensitivity --collect under a file", "analysis.sensitivity",
         ["--setting", "farbox:3", "--readings", "ours", "--out", str(tmp / "se"),
          "--collect", str(blocker / "c")], "usage", "--collect"),
        ("sensitivity report --out under a file", "analysis.sensitivity",
         ["report", str(tmp), "--out", str(blocker / "r")], "usage", "is a file"),
        ("optimality --out under a file", "analysis.optimality",
         ["--out", str(blocker / "o"), "--goals", "2"], "usage", "is a file"),
        ("curves --out a folder", "analysis.curves", [str(tmp), "--out", str(tmp)], "usage",
         "is a folder"),
        ("curves --out .xyz", "analysis.curves", [str(tmp), "--out", str(tmp / "f.xyz")],
         "usage", ".xyz"),
        ("success_map --out under a file", "analysis.success_map",
         [str(tmp), "--out", str(blocker / "m.png")], "usage", "is a file"),
    ]
    # kind 4: values handed to another library checked in our words
    for template in ("runs/{foo}", "runs/{0}", "runs/{seed", "runs/{region!x}"):
        out.append((f"train --out {template}", "ddpg_her.train",
                    ["--region", "farbox", "--out", template], "usage", "--out"))
    for task, words in (("nosuch=1", "no field"), ("region=zheight", "the study sets it"),
                        ("n_joints=3", "the study sets it"),
                        ("action_penalty_unit=command", "set it themselves"),
                        ("action_weight=-1", "--task"), ("success_radius=0", "--task")):
        out.append((f"optimality --task {task}", "analysis.optimality",
                    ["--settings", "unconstrained:2", "--goals", "2", "--readings", "ours",
                     "actor_penalty", "--out", str(tmp / "opt"), "--no-progress", "--task",
                     task], "usage", words))
    for address, words in (("127.0.0.1:6999", "no Ray cluster answers"),
                           ("ray://127.0.0.1:6999", "no Ray cluster answers"),
                           ("nohost", "HOST:PORT"), ("127.0.0.1:0", "1..65535")):
        out.append((f"sweep --ray-address {address}", "analysis.sweep",
                    ["--setting", "farbox:3", *sweep_root, "--ray-address", address], "usage",
                    words))
    # kind 7: analysis commands end bad input in one line
    out += [
        ("contact --seed -1", "analysis.contact", ["--seed", "-1"], "usage", "--seed"),
        ("contact unreachable region", "analysis.contact",
         ["--region", "box:5,6,5,6,5,6", "--goals", "2", "--steps", "2", "--rounds", "1"],
         "usage", "no goals reachable"),
        ("contact --goals 0", "analysis.contact", ["--goals", "0"], "usage", "--goals"),
        ("contact --friction nan", "analysis.contact", ["--friction", "nan"], "usage",
         "--friction"),
        ("contact --region nowhere", "analysis.contact", ["--region", "nowhere"], "usage",
         "nowhere"),
        ("optimality --seed -1", "analysis.optimality", ["--seed", "-1"], "usage", "--seed"),
        ("optimality --grid 1", "analysis.optimality", ["--grid", "1"], "usage", "--grid"),
        ("optimality --gamma 2", "analysis.optimality", ["--gamma", "2"], "usage", "gamma"),
    ]
    # the training command's own checks (before any training)
    for args, words in ((["--region", "nowhere"], "nowhere"),
                        (["--region", "farbox", "--joints", "7"], "--joints"),
                        (["--region", "farbox", "--seeds", "1", "1"], "distinct"),
                        (["--region", "farbox", "--threads", "0"], "--threads"),
                        (["--region", "farbox", "--gamma", "nan"], "gamma"),
                        (["--region", "farbox", "--episodes", "150"], "--eval-every"),
                        (["--region", "farbox", "--task", "n_joints=4", "--joints", "3"],
                         "two values"),
                        (["--region", "farbox", "--env-dynamics", "numba"], "--env-dynamics"),
                        (["--region", "farbox", "--her-k", "8", "--her-strategy", "final"],
                         "--her-k")):
        out.append((f"train {' '.join(args)}", "ddpg_her.train",
                    [*args, "--out", str(tmp / "train" / "r")], "usage", words))
    out += reader_cases(tmp, blocker)
    return out


def reader_cases(tmp: Path, blocker: Path) -> list[tuple[str, str, list[str], str, str]]:
    """Run folders that are not whole (kind 6), and other entry points' bad input: expected a
    ``refusal`` (exit 2 or 1 with an error line) naming the bad value."""
    norun = tmp / "norun"
    norun.mkdir()
    garbage = tmp / "garbage" / "s0"
    garbage.mkdir(parents=True)
    (garbage / "spec.json").write_text("{")
    listed = tmp / "listed" / "s0"
    listed.mkdir(parents=True)
    (listed / "spec.json").write_text("[1, 2]")
    locked = tmp / "locked"
    locked.mkdir()
    (locked / "lock.json").write_text("garbage")
    bad_json = tmp / "bad.json"
    bad_json.write_text("{")
    out = []
    for folder, words in ((norun, "norun"), (garbage, "spec.json"), (listed, "spec.json")):
        name = folder.relative_to(tmp)
        out += [
            (f"summary {name}", "ddpg_her.summary", [str(folder)], "refusal", words),
            (f"replay {name}", "analysis.replay", [str(folder), "--out",
                                                   str(tmp / "r.html")], "refusal", words),
        ]
    out += [
        ("curves of a folder of garbage spec", "analysis.curves",
         [str(garbage.parent), "--out", str(tmp / "c.png")], "refusal", "spec.json"),
        ("success_map of a garbage spec", "analysis.success_map",
         [str(garbage), "--out", str(tmp / "m.png")], "refusal", "spec.json"),
        ("replay --episodes 0", "analysis.replay", [str(norun), "--episodes", "0"], "refusal",
         "--episodes"),
        ("replay --seed -1", "analysis.replay", [str(norun), "--seed", "-1"], "refusal",
         "--seed"),
        ("region_volumes --samples 0", "analysis.region_volumes",
         ["--regions", "farbox", "--samples", "0"], "refusal", "--samples"),
        ("region_volumes unknown region", "analysis.region_volumes",
         ["--regions", "nowhere", "--samples", "1000"], "refusal", "nowhere"),
        ("sb3 --seed -1", "analysis.sb3", ["--region", "farbox", "--seed", "-1"], "refusal",
         "--seed"),
        ("sb3 --episodes 0", "analysis.sb3", ["--region", "farbox", "--episodes", "0"],
         "refusal", "--episodes"),
        ("sb3 --hyperparams not JSON", "analysis.sb3",
         ["--region", "farbox", "--hyperparams", str(bad_json), "--out", str(tmp / "sb")],
         "refusal", "bad.json"),
        ("sb3 --algo ppo", "analysis.sb3", ["--region", "farbox", "--algo", "ppo"], "refusal",
         "ppo"),
        ("train_many --plan missing", "ddpg_her.train_many",
         ["--plan", str(tmp / "nosuch.json")], "refusal", "nosuch.json"),
        ("train_many --plan not JSON", "ddpg_her.train_many", ["--plan", str(bad_json)],
         "refusal", "bad.json"),
        ("sweep --workers 0", "analysis.sweep", ["--workers", "0", "--dry-run"], "refusal",
         "--workers"),
        ("sweep --seeds 0", "analysis.sweep", ["--seeds", "0", "--dry-run"], "refusal",
         "--seeds"),
        ("sweep --episodes 0", "analysis.sweep", ["--episodes", "0", "--dry-run"], "refusal",
         "--episodes"),
        ("sweep --setting farbox:9", "analysis.sweep", ["--setting", "farbox:9", "--dry-run"],
         "refusal", "farbox:9"),
        ("sweep --project without --dry-run", "analysis.sweep", ["--project"], "refusal",
         "--project"),
        ("sweep unknown region", "analysis.sweep", ["--setting", "nowhere:3", "--dry-run"],
         "refusal", "nowhere"),
        ("sensitivity --readings nosuch", "analysis.sensitivity",
         ["--readings", "nosuch", "--dry-run"], "refusal", "nosuch"),
        ("sensitivity --reading bad name", "analysis.sensitivity",
         ["--reading", "a b=--tau 1", "--dry-run"], "refusal", "a b"),
        ("browser missing page", "analysis.browser", [str(tmp / "nosuch.html")], "refusal",
         "nosuch.html"),
        ("train --resume on a garbage lock", "ddpg_her.train",
         ["--region", "farbox", "--out", str(locked), "--resume"], "refusal",
         "not a lock this code wrote"),
        ("report --out under a file", "analysis.report",
         [str(norun), "--out", str(blocker / "r.md")], "refusal", "r.md"),
    ]
    return out


def run_case(module: str, argv: list[str]) -> tuple[str, str]:
    """(kind of answer, its first message line) of ``module.main(argv)``."""
    err, std = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(std):
            code = importlib.import_module(module).main(list(argv))
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else 1
    except BaseException as exc:
        lines = traceback.format_exception_only(type(exc), exc)
        return "traceback", lines[-1].strip()
    message = next((ln for ln in err.getvalue().splitlines() if "error" in ln.lower()), "")
    if code in (0, None):
        return "ok", ""
    return ("usage" if code == 2 else "error"), message.strip()


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.reliability_probe",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/reliability/probe.csv"),
                        help="the table written (CSV)")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="probe-") as tmp:
        for case, module, case_argv, expected, words in cases(Path(tmp)):
            got, message = run_case(module, case_argv)
            good = (got in ("usage", "error") if expected == "refusal" else got == expected) \
                and words in message
            rows.append({"case": case.replace(tmp, "TMP"), "entry_point": module,
                         "expected": expected,
                         "got": got, "as_expected": good,
                         "message": message.replace(tmp, "TMP")[:300]})
            print(f"{'ok ' if good else 'BAD'} {module:<22} {case}: {got}", flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    bad = [r for r in rows if not r["as_expected"]]
    print(f"{len(rows)} cases, {len(rows) - len(bad)} as expected; "
          f"{sum(r['got'] == 'traceback' for r in rows)} tracebacks -> {args.out}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
