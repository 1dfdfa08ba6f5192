"""A probe of bad inputs and faults across the entry points (issue 37): every ``python -m``
command of ddpg_her/ and analysis/, the library API (``ur5kin``, ``regions``, the envs,
``ddpg_her.load``) and SIGKILLed runs; ``python -m benchmarks.reliability_probe --out
results/reliability/probe.csv``.

Each case runs in a forked child (the heavy imports are done once, in the parent) with its own
empty working folder, so a command's default outputs land where the probe sees them; a case
that runs past ``--limit-s`` is killed with its process group and counted a ``hang``.

Kinds of answer (``got``): ``usage`` (exit 2, or an API ``ValueError``/``TypeError``/
``FileNotFoundError``), ``error`` (another non-zero exit), ``ok`` (exit 0 or a return),
``traceback`` (any other exception escaped), ``hang``, ``wrong`` (a check of the result
failed: a kill that did not resume to the uninterrupted bytes, an API result that disagrees
with a second path). Expected (``expected``): ``usage``, ``refusal`` (usage or error) or ``ok``.

The verdict: ``as_expected``; ``unclear`` (refused as expected, but the message does not hold
the case's key words, i.e. does not name the bad value); ``silent_wrong`` (it succeeded where
it should have refused, returned a wrong result, or a refused case created, changed or left
files: anything new in its working folder, a ``.tmp`` file anywhere, or a change to the shared
fixtures); ``traceback``; ``hang``; ``other`` (another mismatch).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import importlib
import io
import json
import math
import multiprocessing
import os
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import gymnasium
import numpy as np

from ddpg_her.config import Parser

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"
FARBOX = ["--setting", "farbox:3", "--dry-run"]
STUDY = ["--setting", "farbox:3", "--dry-run"]
TINY_TRAIN = ["--episodes", "2", "--eval-every", "2", "--eval-episodes", "2", "--hidden-sizes",
              "8", "8", "--updates-per-episode", "2", "--warmup-episodes", "1", "--batch-size",
              "8", "--buffer-size", "400", "--no-progress", "--no-tensorboard", "--threads", "1"]
"""A UR5 run of 2 episodes (about 13 s here): the reader fixtures and the training cases."""
TOY = ["--env-id", "toy_goal_env:ToyReach-v0", "--region", "box", "--joints", "2",
       "--episodes", "6", "--eval-every", "2", "--eval-episodes", "2", "--hidden-sizes", "8",
       "8", "--updates-per-episode", "2", "--warmup-episodes", "1", "--batch-size", "8",
       "--buffer-size", "200", "--resume", "--no-progress", "--no-tensorboard", "--threads", "1"]
"""The kill cases' run (tests/test_kills.py's): checkpoints at episodes 2, 4 and 6."""
SB3_TINY = ["--episodes", "2", "--eval-every", "2", "--eval-episodes", "1"]
"""An SB3 run of 2 episodes, should a bad hyperparameter file be accepted."""
PRELOAD = ("torch", "gymnasium", "pinocchio", "matplotlib.pyplot", "envs", "envs.reach",
           "envs.batched", "regions", "ur5kin", "ddpg_her.train", "ddpg_her.train_many",
           "ddpg_her.summary", "ddpg_her.run", "analysis.sweep", "analysis.sensitivity",
           "analysis.algorithms", "analysis.optimality", "analysis.contact", "analysis.curves",
           "analysis.report", "analysis.replay", "analysis.success_map",
           "analysis.region_volumes", "analysis.sb3", "benchmarks.browser")
"""Imported once in the parent, so each forked case starts at once."""


class WrongAnswer(Exception):
    """A case's result failed its check (raised by the case's own code)."""


@dataclasses.dataclass
class Case:
    """One probe case: a command's ``main(argv)`` (``entry`` a module) or a call (``entry``
    the API name, ``call(case_dir)``), run in its own working folder ``case_dir``."""

    name: str
    entry: str
    kind: int
    """The issue's kind of fault (1-8) the case belongs to."""
    expected: str
    words: tuple[str, ...] = ()
    """Each must appear in the refusal's message (they name the bad value)."""
    argv: list[str] | None = None
    call: Callable[[Path], Any] | None = None
    setup: Callable[[Path], None] | None = None
    """Prepares the case's working folder (its inputs) before the snapshot."""


def cli(name: str, module: str, kind: int, argv: list[str], expected: str = "usage",
        words: str | Sequence[str] = (), setup: Callable[[Path], None] | None = None) -> Case:
    words = (words,) if isinstance(words, str) else tuple(words)
    return Case(name, module, kind, expected, tuple(w for w in words if w), argv=argv,
                setup=setup)


def api(name: str, entry: str, kind: int, call: Callable[[Path], Any], expected: str = "usage",
        words: str | Sequence[str] = (), setup: Callable[[Path], None] | None = None) -> Case:
    words = (words,) if isinstance(words, str) else tuple(words)
    return Case(name, entry, kind, expected, tuple(w for w in words if w), call=call,
                setup=setup)


# ---------------------------------------------------------------------------- fixtures
def make_fixtures(fix: Path) -> None:
    """The shared inputs (read-only for the cases; checked unchanged at the end): a blocker
    file, bad JSON, a real 2-episode UR5 run, the toy run of the kill cases (uninterrupted)."""
    (fix / "blocker").write_text("x")
    (fix / "bad.json").write_text("{")
    (fix / "norun").mkdir()
    garbage = fix / "garbage" / "s0"
    garbage.mkdir(parents=True)
    (garbage / "spec.json").write_text("{")
    listed = fix / "listed" / "s0"
    listed.mkdir(parents=True)
    (listed / "spec.json").write_text("[1, 2]")
    (fix / "locked").mkdir()
    (fix / "locked" / "lock.json").write_text("garbage")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), str(ROOT)])}
    for args, out in (([*TINY_TRAIN, "--region", "farbox", "--joints", "3"], "ur5/s0"),
                      (TOY, "toy/run"), ([*TOY, "--seeds", "0", "1"], "toy/s{seed}")):
        subprocess.run([sys.executable, "-m", "ddpg_her.train", *args, "--out", str(fix / out)],
                       check=True, env=env, cwd=ROOT, capture_output=True)
    (fix / "toy" / "plan.json").write_text(json.dumps({"units": [
        [*TOY[:-5], "--seeds", str(s), "--out", f"many/u{s}/s{{seed}}"] for s in (0, 1)]}))
    subprocess.run([sys.executable, "-m", "ddpg_her.train_many", "--plan",
                    str(fix / "toy" / "plan.json"), "--resume", "--no-progress",
                    "--no-tensorboard", "--threads", "1"], check=True, env=env,
                   cwd=fix / "toy", capture_output=True)


def copy_run(fix: Path, edit: Callable[[Path], None] | None = None, name: str = "run"
             ) -> Callable[[Path], None]:
    """A setup: the fixture UR5 run copied to ``CASE/name/s0``, then ``edit``ed."""
    def setup(case_dir: Path) -> None:
        dest = case_dir / name / "s0"
        shutil.copytree(fix / "ur5" / "s0", dest)
        if edit is not None:
            edit(dest)
    return setup


def edit_spec(change: Callable[[dict], None]) -> Callable[[Path], None]:
    def edit(run: Path) -> None:
        spec = json.loads((run / "spec.json").read_text())
        change(spec)
        (run / "spec.json").write_text(json.dumps(spec))
    return edit


def write(rel: str, text: str | bytes) -> Callable[[Path], None]:
    def edit(run: Path) -> None:
        path = run / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return edit


def remove(pattern: str) -> Callable[[Path], None]:
    def edit(run: Path) -> None:
        for p in run.glob(pattern):
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    return edit


def truncate(pattern: str) -> Callable[[Path], None]:
    def edit(run: Path) -> None:
        for p in run.glob(pattern):
            p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    return edit


def broken_runs() -> list[tuple[str, Callable[[Path], None], str | tuple[str, ...]]]:
    """(name, edit of a copied run folder, key words naming what is wrong)."""
    def setk(key: str, value: Any) -> Callable[[dict], None]:
        def change(spec: dict) -> None:
            spec[key] = value
        return change

    def drop(key: str) -> Callable[[dict], None]:
        return lambda spec: spec.pop(key)

    def region(value: str) -> Callable[[dict], None]:
        def change(spec: dict) -> None:
            spec["env_kwargs"]["region"] = value
            if isinstance(spec.get("task"), dict):
                spec["task"]["region"] = value
        return change

    return [
        ("empty spec.json", write("spec.json", ""), "spec.json"),
        ("spec.json NaN", write("spec.json", '{"format": NaN}'), "spec.json"),
        ("spec.json of another format version", edit_spec(setk("format", "ddpg_her-run-2")),
         ("spec.json", "ddpg_her-run-2")),
        ("spec.json of a foreign format", edit_spec(setk("format", 999)), ("spec.json", "999")),
        ("spec.json without format", edit_spec(drop("format")), "spec.json"),
        ("spec.json without env_id", edit_spec(drop("env_id")), "spec.json"),
        ("spec.json without agent", edit_spec(drop("agent")), "spec.json"),
        ("spec.json with dims a string", edit_spec(setk("dims", "x")), "spec.json"),
        ("spec.json region unreadable", edit_spec(region("nowhere")), "nowhere"),
        ("empty eval.csv", write("eval.csv", ""), "eval.csv"),
        ("eval.csv garbage", write("eval.csv", "a,b\n1,2\n"), "eval.csv"),
        ("eval.csv truncated row", truncate("eval.csv"), "eval.csv"),
        ("eval.csv without rows", write("eval.csv", "episode,successes,tests,mean_return,"
                                        "mean_final_distance_m,env_steps,wall_s\n"), "eval.csv"),
        ("no checkpoints", remove("checkpoints"), "checkpoint"),
        ("checkpoint truncated", truncate("checkpoints/*"), "checkpoint"),
        ("checkpoint garbage", lambda r: [p.write_bytes(b"garbage") for p in
                                          (r / "checkpoints").iterdir()], "checkpoint"),
    ]


# ---------------------------------------------------------------------------- CLI cases
def old_cases(fix: Path) -> list[Case]:
    """The first 122 cases (kinds 2, 3, 4, 6, 7 and the commands' own checks)."""
    blocker = fix / "blocker"
    out: list[Case] = []
    sweep_root = ["--out", "sw", "--episodes", "200", "--seeds", "1"]
    for flag, value in (("--region", "zheight"), ("--out", "x"), ("--seeds", "3"),
                        ("--seed", "3"), ("--episodes", "5"), ("--joints", "6"),
                        ("--threads", "4"), ("--device", "cpu"), ("--env-backend", "batched"),
                        ("--resume", None), ("--no-progress", None), ("--reg", "zheight"),
                        ("--epi", "5"), ("--env-dyn", "numba")):
        extra = [flag] if value is None else [flag, value]
        out += [cli(f"sweep -- {' '.join(extra)}", "analysis.sweep", 2,
                    [*FARBOX, *sweep_root, "--", *extra], "usage", flag),
                cli(f"sensitivity -- {' '.join(extra)}", "analysis.sensitivity", 2,
                    [*STUDY, "--readings", "ours", "--out", "se", "--", *extra], "usage", flag),
                cli(f"algorithms -- {' '.join(extra)}", "analysis.algorithms", 2,
                    [*STUDY, "--algos", "td3", "--out", "al", "--", *extra], "usage", flag)]
    for task in ("region=zheight", "n_joints=6"):
        out.append(cli(f"sweep -- --task {task}", "analysis.sweep", 2,
                       [*FARBOX, *sweep_root, "--", "--task", task], "usage", "--task"))
    out += [
        cli("algorithms td3 -- --algo sac", "analysis.algorithms", 2,
            [*STUDY, "--algos", "td3", "--out", "al", "--", "--algo", "sac"], "usage", "--algo"),
        cli("algorithms sac -- --exploration-rate 0.1", "analysis.algorithms", 2,
            [*STUDY, "--algos", "sac", "--out", "al", "--", "--exploration-rate", "0.1"],
            "usage", "--exploration-rate"),
        cli("algorithms ensemble -- --ensemble 2", "analysis.algorithms", 2,
            [*STUDY, "--algos", "ensemble", "--out", "al", "--", "--ensemble", "2"], "usage",
            "--ensemble"),
        cli("sensitivity actor_penalty -- --task action_penalty_unit=command",
            "analysis.sensitivity", 2, [*STUDY, "--readings", "actor_penalty", "--out", "se",
                                        "--", "--task", "action_penalty_unit=command"],
            "usage", "action_penalty_unit"),
        cli("sensitivity lillicrap_nets -- --no-batch-norm", "analysis.sensitivity", 2,
            [*STUDY, "--readings", "lillicrap_nets", "--out", "se", "--", "--no-batch-norm"],
            "usage", "--no-batch-norm"),
        cli("sensitivity reading --out", "analysis.sensitivity", 2,
            [*STUDY, "--reading", "m=--out elsewhere", "--readings", "m", "--out", "se"],
            "usage", "--out"),
        cli("sensitivity reading --region", "analysis.sensitivity", 2,
            [*STUDY, "--reading", "m=--region zheight", "--readings", "m", "--out", "se"],
            "usage", "--region"),
        cli("sweep -- --tau 0.01 (left open)", "analysis.sweep", 2,
            [*FARBOX, *sweep_root, "--", "--tau", "0.01"], "ok"),
        cli("sweep -- --task action_weight=0.5 (left open)", "analysis.sweep", 2,
            [*FARBOX, *sweep_root, "--", "--task", "action_weight=0.5"], "ok"),
    ]
    for module, args in (("analysis.sweep", ["--setting", "farbox:3", "--episodes", "200",
                                             "--seeds", "1"]),
                         ("analysis.sensitivity", ["--setting", "farbox:3", "--readings",
                                                   "ours"]),
                         ("analysis.algorithms", ["--setting", "farbox:3", "--algos", "td3"])):
        out.append(cli(f"{module.split('.')[1]} --out under a file", module, 3,
                       [*args, "--out", str(blocker / "r")], "usage", "is a file"))
    out += [
        cli("sensitivity --collect under a file", "analysis.sensitivity", 3,
            ["--setting", "farbox:3", "--readings", "ours", "--out", "se", "--collect",
             str(blocker / "c")], "usage", "--collect"),
        cli("sensitivity report --out under a file", "analysis.sensitivity", 3,
            ["report", str(fix / "norun"), "--out", str(blocker / "r")], "usage", "is a file"),
        cli("optimality --out under a file", "analysis.optimality", 3,
            ["--out", str(blocker / "o"), "--goals", "2"], "usage", "is a file"),
        cli("curves --out a folder", "analysis.curves", 3,
            [str(fix / "norun"), "--out", str(fix)], "usage", "is a folder"),
        cli("curves --out .xyz", "analysis.curves", 3, [str(fix / "norun"), "--out", "f.xyz"],
            "usage", ".xyz"),
        cli("success_map --out under a file", "analysis.success_map", 3,
            [str(fix / "norun"), "--out", str(blocker / "m.png")], "usage", "is a file"),
    ]
    for template in ("runs/{foo}", "runs/{0}", "runs/{seed", "runs/{region!x}"):
        out.append(cli(f"train --out {template}", "ddpg_her.train", 4,
                       ["--region", "farbox", "--out", template], "usage", "--out"))
    for task, words in (("nosuch=1", "no field"), ("region=zheight", "the study sets it"),
                        ("n_joints=3", "the study sets it"),
                        ("action_penalty_unit=command", "set it themselves"),
                        ("action_weight=-1", "--task"), ("success_radius=0", "--task")):
        out.append(cli(f"optimality --task {task}", "analysis.optimality", 4,
                       ["--settings", "unconstrained:2", "--goals", "2", "--readings", "ours",
                        "actor_penalty", "--out", "opt", "--no-progress", "--task", task],
                       "usage", words))
    for address, words in (("127.0.0.1:6999", "no Ray cluster answers"),
                           ("ray://127.0.0.1:6999", "no Ray cluster answers"),
                           ("nohost", "HOST:PORT"), ("127.0.0.1:0", "1..65535")):
        out.append(cli(f"sweep --ray-address {address}", "analysis.sweep", 4,
                       ["--setting", "farbox:3", *sweep_root, "--ray-address", address],
                       "usage", words))
    out += [
        cli("contact --seed -1", "analysis.contact", 7, ["--seed", "-1"], "usage", "--seed"),
        cli("contact unreachable region", "analysis.contact", 7,
            ["--region", "box:5,6,5,6,5,6", "--goals", "2", "--steps", "2", "--rounds", "1"],
            "usage", "no goals reachable"),
        cli("contact --goals 0", "analysis.contact", 7, ["--goals", "0"], "usage", "--goals"),
        cli("contact --friction nan", "analysis.contact", 7, ["--friction", "nan"], "usage",
            "--friction"),
        cli("contact --region nowhere", "analysis.contact", 7, ["--region", "nowhere"],
            "usage", "nowhere"),
        cli("optimality --seed -1", "analysis.optimality", 7, ["--seed", "-1"], "usage",
            "--seed"),
        cli("optimality --grid 1", "analysis.optimality", 7, ["--grid", "1"], "usage",
            "--grid"),
        cli("optimality --gamma 2", "analysis.optimality", 7, ["--gamma", "2"], "usage",
            "gamma"),
    ]
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
        out.append(cli(f"train {' '.join(args)}", "ddpg_her.train", 8 if "nowhere" in args
                       else 4, [*args, "--out", "train/r"], "usage", words))
    out += old_reader_cases(fix)
    return out


def old_reader_cases(fix: Path) -> list[Case]:
    norun, garbage, listed = fix / "norun", fix / "garbage" / "s0", fix / "listed" / "s0"
    out = []
    for folder, words in ((norun, "norun"), (garbage, "spec.json"), (listed, "spec.json")):
        name = folder.relative_to(fix)
        out += [cli(f"summary {name}", "ddpg_her.summary", 6, [str(folder)], "refusal", words),
                cli(f"replay {name}", "analysis.replay", 6, [str(folder), "--out", "r.html"],
                    "refusal", words)]
    out += [
        cli("curves of a folder of garbage spec", "analysis.curves", 6,
            [str(garbage.parent), "--out", "c.png"], "refusal", "spec.json"),
        cli("success_map of a garbage spec", "analysis.success_map", 6,
            [str(garbage), "--out", "m.png"], "refusal", "spec.json"),
        cli("replay --episodes 0", "analysis.replay", 7, [str(norun), "--episodes", "0"],
            "refusal", "--episodes"),
        cli("replay --seed -1", "analysis.replay", 7, [str(norun), "--seed", "-1"], "refusal",
            "--seed"),
        cli("region_volumes --samples 0", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--samples", "0"], "refusal", "--samples"),
        cli("region_volumes unknown region", "analysis.region_volumes", 7,
            ["--regions", "nowhere", "--samples", "1000"], "refusal", "nowhere"),
        cli("sb3 --seed -1", "analysis.sb3", 4, ["--region", "farbox", "--seed", "-1"],
            "refusal", "--seed"),
        cli("sb3 --episodes 0", "analysis.sb3", 4, ["--region", "farbox", "--episodes", "0"],
            "refusal", "--episodes"),
        cli("sb3 --hyperparams not JSON", "analysis.sb3", 4,
            ["--region", "farbox", "--hyperparams", str(fix / "bad.json"), "--out", "sb"],
            "refusal", "bad.json"),
        cli("sb3 --algo ppo", "analysis.sb3", 4, ["--region", "farbox", "--algo", "ppo"],
            "refusal", "ppo"),
        cli("train_many --plan missing", "ddpg_her.train_many", 4,
            ["--plan", str(fix / "nosuch.json")], "refusal", "nosuch.json"),
        cli("train_many --plan not JSON", "ddpg_her.train_many", 4,
            ["--plan", str(fix / "bad.json")], "refusal", "bad.json"),
        cli("sweep --workers 0", "analysis.sweep", 7, ["--workers", "0", "--dry-run"],
            "refusal", "--workers"),
        cli("sweep --seeds 0", "analysis.sweep", 7, ["--seeds", "0", "--dry-run"], "refusal",
            "--seeds"),
        cli("sweep --episodes 0", "analysis.sweep", 7, ["--episodes", "0", "--dry-run"],
            "refusal", "--episodes"),
        cli("sweep --setting farbox:9", "analysis.sweep", 7,
            ["--setting", "farbox:9", "--dry-run"], "refusal", "farbox:9"),
        cli("sweep --project without --dry-run", "analysis.sweep", 7, ["--project"],
            "refusal", "--project"),
        cli("sweep unknown region", "analysis.sweep", 7,
            ["--setting", "nowhere:3", "--dry-run"], "refusal", "nowhere"),
        cli("sensitivity --readings nosuch", "analysis.sensitivity", 7,
            ["--readings", "nosuch", "--dry-run"], "refusal", "nosuch"),
        cli("sensitivity --reading bad name", "analysis.sensitivity", 7,
            ["--reading", "a b=--tau 1", "--dry-run"], "refusal", "a b"),
        cli("browser missing page", "benchmarks.browser", 7, [str(fix / "nosuch.html")],
            "refusal", "nosuch.html"),
        cli("train --resume on a garbage lock", "ddpg_her.train", 6,
            ["--region", "farbox", "--out", str(fix / "locked"), "--resume"], "refusal",
            "not a lock this code wrote"),
        cli("report --out under a file (h-relfix)", "analysis.report", 3,
            [str(norun), "--out", str(fix / "blocker" / "r.md")], "refusal", "r.md"),
    ]
    return out


READERS = {
    "summary": ("ddpg_her.summary", lambda run: [str(run)]),
    "curves": ("analysis.curves", lambda run: [str(run.parent), "--out", "c.png"]),
    "report": ("analysis.report", lambda run: [str(run.parent), "--out", "r.md"]),
    "replay": ("analysis.replay", lambda run: [str(run), "--episodes", "1", "--out",
                                               "r.html", "--no-progress"]),
    "success_map": ("analysis.success_map", lambda run: [str(run), "--goals", "4", "--batch",
                                                         "4", "--z", "0.1", "0.3", "--out",
                                                         "m.png", "--no-progress"]),
}
"""Commands that read a run folder: (module, argv of the run folder ``CASE/run/s0``)."""
UNUSED = {("spec.json without env_id", r) for r in ("summary", "curves", "report")} | {
    ("spec.json without agent", "summary")} | {
    ("spec.json with dims a string", r) for r in ("summary", "curves", "report")}
"""(broken part, reader) where the reader does not read that part: the command works."""
NOT_A_RUN = ("spec.json NaN", "spec.json of a foreign format", "spec.json without format")
"""Broken specs that are not a ddpg_her run's: the run discovery of curves and report skips
such a folder (a tree may hold other programs' spec.json), so they find no run below it."""
SPEC_READERS = ("summary", "curves", "report", "replay", "success_map")
EVAL_READERS = ("summary", "curves", "report")
POLICY_READERS = ("replay", "success_map")


def reader_cases(fix: Path) -> list[Case]:
    """Kind 6 (and 7): each broken run folder of `broken_runs` read by every command that
    reads what was broken, and by ``train --resume``; each must refuse naming the file."""
    out: list[Case] = []
    run = Path("run") / "s0"
    for name, edit, words in broken_runs():
        broken = "spec" if "spec" in name else "eval" if "eval" in name else "ckpt"
        readers = {"spec": SPEC_READERS, "eval": EVAL_READERS, "ckpt": POLICY_READERS}[broken]
        if name == "spec.json region unreadable":
            readers = POLICY_READERS  # the tables and curves do not build the env
        for reader in readers:
            module, argv = READERS[reader]
            kind = 7 if "region" in name else 6
            expected, said = "refusal", words
            if (name, reader) in UNUSED:
                expected = "ok"  # the reader does not read what was broken
            elif reader in ("curves", "report") and name in NOT_A_RUN:
                said = "no run with evaluations below run"  # their walk skips foreign specs
            elif name == "spec.json without env_id":
                said = "env None"
            elif name == "eval.csv without rows":  # a run before its first test session
                expected, said = ("ok", ()) if reader == "summary" else \
                    ("refusal", "no run with evaluations below run")
            tag = " (h-relfix)" if "region" in name else ""
            out.append(cli(f"{reader} of a run with {name}{tag}", module, kind, argv(run),
                           expected, said, setup=copy_run(fix, edit)))
        if broken == "spec" and "region" not in name:
            out.append(cli(f"train --resume of a run with {name}", "ddpg_her.train", 6,
                           ["--region", "farbox", "--joints", "3", *TINY_TRAIN, "--out",
                            str(run), "--resume"], "refusal", "run/s0",
                           setup=copy_run(fix, edit)))
    # the same commands on the whole run: they work
    for reader in SPEC_READERS:
        module, argv = READERS[reader]
        out.append(cli(f"{reader} of a whole run", module, 6, argv(run), "ok",
                       setup=copy_run(fix)))
    out += [
        cli("replay --episode 99 (no such checkpoint)", "analysis.replay", 7,
            [str(run), "--episode", "99", "--out", "r.html"], "refusal", "99",
            setup=copy_run(fix)),
        cli("success_map --episode 99 (no such checkpoint)", "analysis.success_map", 7,
            [str(run), "--episode", "99", "--goals", "4", "--out", "m.png"], "refusal", "99",
            setup=copy_run(fix)),
        cli("replay --episodes 201", "analysis.replay", 7, [str(run), "--episodes", "201"],
            "refusal", "--episodes", setup=copy_run(fix)),
        cli("replay --out under a file", "analysis.replay", 3,
            [str(run), "--episodes", "1", "--out", str(fix / "blocker" / "r.html")], "refusal",
            "r.html", setup=copy_run(fix)),
        cli("replay --out a folder", "analysis.replay", 3,
            [str(run), "--episodes", "1", "--out", str(fix)], "refusal", "folder",
            setup=copy_run(fix)),
        cli("replay --meshes nosuch", "analysis.replay", 7, [str(run), "--meshes", "nosuch"],
            "usage", "nosuch", setup=copy_run(fix)),
        cli("success_map --goals 0", "analysis.success_map", 7, [str(run), "--goals", "0"],
            "refusal", "--goals", setup=copy_run(fix)),
        cli("success_map --goals -5", "analysis.success_map", 7, [str(run), "--goals", "-5"],
            "refusal", "--goals", setup=copy_run(fix)),
        cli("success_map --z 0.3 0.1 (sorted, as documented)", "analysis.success_map", 7,
            [str(run), "--z", "0.3", "0.1", "--goals", "4", "--batch", "4", "--out", "m.png",
             "--no-progress"], "ok", setup=copy_run(fix)),
        cli("success_map --z 0.2 0.2", "analysis.success_map", 7,
            [str(run), "--z", "0.2", "0.2"], "refusal", "--z", setup=copy_run(fix)),
        cli("success_map --z nan 1", "analysis.success_map", 7, [str(run), "--z", "nan", "1"],
            "refusal", "--z", setup=copy_run(fix)),
        cli("success_map --cell 0", "analysis.success_map", 7, [str(run), "--cell", "0"],
            "refusal", "--cell", setup=copy_run(fix)),
        cli("success_map --cell nan", "analysis.success_map", 7, [str(run), "--cell", "nan"],
            "refusal", "--cell", setup=copy_run(fix)),
        cli("success_map --batch 0", "analysis.success_map", 7, [str(run), "--batch", "0"],
            "refusal", "--batch", setup=copy_run(fix)),
        cli("success_map --seed -1", "analysis.success_map", 7,
            [str(run), "--seed", "-1", "--goals", "4", "--z", "0.1", "0.3"], "refusal",
            "--seed", setup=copy_run(fix)),
        cli("success_map of a run of the toy env", "analysis.success_map", 7,
            [str(fix / "toy" / "run"), "--goals", "4", "--z", "0.1", "0.3", "--out", "m.png"],
            "refusal", "ToyReach-v0"),
        cli("replay of a run of the toy env", "analysis.replay", 7,
            [str(fix / "toy" / "run"), "--episodes", "1", "--out", "r.html"], "refusal",
            "ToyReach-v0"),
        cli("success_map --out .xyz", "analysis.success_map", 3,
            [str(run), "--goals", "4", "--out", "m.xyz"], "refusal", ".xyz",
            setup=copy_run(fix)),
        cli("success_map of a missing run", "analysis.success_map", 7,
            [str(fix / "nosuch"), "--goals", "4"], "refusal", "nosuch"),
        cli("summary --project-to 0", "ddpg_her.summary", 7, [str(run), "--project-to", "0"],
            "refusal", "--project-to", setup=copy_run(fix)),
        cli("summary --project-to -1", "ddpg_her.summary", 7,
            [str(run), "--project-to", "-1"], "refusal", "--project-to", setup=copy_run(fix)),
        cli("summary of a missing folder", "ddpg_her.summary", 7, [str(fix / "nosuch")],
            "refusal", "nosuch"),
        cli("summary of a file", "ddpg_her.summary", 7, [str(fix / "blocker")], "refusal",
            "blocker"),
        cli("curves --confidence 0", "analysis.curves", 7,
            [str(run.parent), "--confidence", "0", "--out", "c.png"], "refusal",
            "--confidence", setup=copy_run(fix)),
        cli("curves --confidence 1", "analysis.curves", 7,
            [str(run.parent), "--confidence", "1", "--out", "c.png"], "refusal",
            "--confidence", setup=copy_run(fix)),
        cli("curves --confidence nan", "analysis.curves", 7,
            [str(run.parent), "--confidence", "nan", "--out", "c.png"], "refusal",
            "--confidence", setup=copy_run(fix)),
        cli("curves of a missing folder", "analysis.curves", 7,
            [str(fix / "nosuch"), "--out", "c.png"], "refusal", "nosuch"),
        cli("curves --out under a file", "analysis.curves", 3,
            [str(run.parent), "--out", str(fix / "blocker" / "c.png")], "refusal", "c.png",
            setup=copy_run(fix)),
        cli("report --confidence 1.5", "analysis.report", 7,
            [str(run.parent), "--confidence", "1.5"], "refusal", "--confidence",
            setup=copy_run(fix)),
        cli("report --confidence nan", "analysis.report", 7,
            [str(run.parent), "--confidence", "nan"], "refusal", "--confidence",
            setup=copy_run(fix)),
        cli("report of a missing folder", "analysis.report", 7, [str(fix / "nosuch")],
            "refusal", "nosuch"),
        cli("report --out a folder (h-relfix)", "analysis.report", 3,
            [str(run.parent), "--out", str(fix)], "refusal", "folder", setup=copy_run(fix)),
        cli("train --resume of a run with a garbage lock.json", "ddpg_her.train", 6,
            ["--region", "farbox", "--joints", "3", *TINY_TRAIN, "--out", str(run),
             "--resume"], "refusal", "lock.json", setup=copy_run(fix, write("lock.json", "{}"))),
        cli("train --resume of a run with lock.json of a list", "ddpg_her.train", 6,
            ["--region", "farbox", "--joints", "3", *TINY_TRAIN, "--out", str(run),
             "--resume"], "refusal", "lock.json",
            setup=copy_run(fix, write("lock.json", "[1]"))),
        cli("train into a finished run without --resume", "ddpg_her.train", 3,
            ["--region", "farbox", "--joints", "3", *TINY_TRAIN, "--out", str(run)],
            "refusal", str(run), setup=copy_run(fix)),
        cli("train --resume with another region than the run's", "ddpg_her.train", 6,
            ["--region", "closebox", "--joints", "3", *TINY_TRAIN, "--out", str(run),
             "--resume"], "refusal", "region", setup=copy_run(fix)),
        cli("train --resume with another --gamma than the run's", "ddpg_her.train", 6,
            ["--region", "farbox", "--joints", "3", *TINY_TRAIN, "--gamma", "0.9", "--out",
             str(run), "--resume"], "refusal", "gamma", setup=copy_run(fix)),
    ]
    return out


def train_cases(fix: Path) -> list[Case]:
    """The training command's checks before any training (kinds 4 and 5, and its flags)."""
    out: list[Case] = []
    base = ["--region", "farbox", "--joints", "3", *TINY_TRAIN, "--out", "r"]
    for flag, value, words in (
            ("--episodes", "-10", "--episodes"),
            ("--eval-every", "0", "--eval-every"), ("--eval-episodes", "0", "--eval-episodes"),
            ("--batch-size", "0", "--batch-size"), ("--buffer-size", "0", "--buffer-size"),
            ("--tau", "0", "tau"), ("--tau", "nan", "tau"), ("--tau", "1.5", "tau"),
            ("--gamma", "-0.1", "gamma"), ("--gamma", "inf", "gamma"),
            ("--actor-lr", "-1", "actor"), ("--critic-lr", "0", "critic"),
            ("--exploration-rate", "nan", "exploration"),
            ("--exploration-rate", "-0.1", "exploration"),
            ("--obs-clip", "-1", "obs"), ("--obs-clip", "nan", "obs"), ("--norm-eps", "0", "eps"),
            ("--final-init", "nan", "final"), ("--critic-l2", "-1", "l2"),
            ("--warmup-episodes", "-1", "warmup"), ("--updates-per-episode", "-1", "updates"),
            ("--her-k", "-1", "her"), ("--ou-theta", "nan", "theta"),
            ("--batch-norm-momentum", "2", "momentum"), ("--ensemble", "0", "ensemble"),
            ("--td3-policy-delay", "0", "delay"), ("--td3-target-noise", "-1", "noise"),
            ("--sac-init-alpha", "0", "alpha"), ("--sac-alpha-lr", "nan", "alpha"),
            ("--seed", "-1", "--seed"), ("--seed", "x", "x"), ("--threads", "-2", "--threads"),
            ("--joints", "1", "--joints"), ("--device", "tpu", "tpu"),
            ("--env-backend", "nosuch", "nosuch"), ("--algo", "ppo", "ppo"),
            ("--her-strategy", "nosuch", "nosuch"), ("--exploration", "nosuch", "nosuch")):
        field = flag.lstrip("-").replace("-", "_")
        out.append(cli(f"train {flag} {value}", "ddpg_her.train", 4, [*base, flag, value],
                       "usage", f"{flag}|{field}" if words == flag else words))
    out.append(cli("train --episodes 0 (a run folder without training, by design)",
                   "ddpg_her.train", 4, [*base, "--episodes", "0"], "ok"))
    for args, words in (
            (["--hidden-sizes", "0", "8"], "hidden"), (["--hidden-sizes", "8"], "hidden"),
            (["--task", "nosuch=1"], "nosuch"), (["--task", "garbage"], "garbage"),
            (["--task", "success_radius=-1"], "success_radius"),
            (["--task", "success_radius=nan"], "success_radius"),
            (["--task", "max_episode_steps=0"], "max_episode_steps"),
            (["--task", "control_hz=0"], "control_hz"),
            (["--task", "base_height=-1"], "base_height"),
            (["--task", "reward_type=nosuch"], "nosuch"),
            (["--task", "kp=1"], "kp"), (["--task", "start_q=[0,0]"], "start_q"),
            (["--task", "region=nowhere"], "nowhere"),
            (["--region", "box:5,6,5,6,5,6"], "box:5,6,5,6,5,6"),
            (["--region", "box:1,0,0,1,0,1"], "x=(1.0, 0.0)"),
            (["--region", "box:a,b,c,d,e,f"], "box:a,b,c,d,e,f"),
            (["--region", "zmax:-1"], "zmax=-1.0"), (["--region", "mesh:/nonexistent.stl"],
                                                   "nonexistent.stl"),
            (["--region", "{bad json"], "bad json"), (["--region", ""], "region"),
            (["--env-id", "NoSuchEnv-v0"], "NoSuchEnv"),
            (["--env-id", "nosuchmodule:X-v0"], "nosuchmodule"),
            (["--out", str(fix / "blocker" / "r")], "blocker"),
            (["--seeds", "0", "-1"], "seeds=(0, -1)"), (["--seeds"], "--seeds"),
            (["--seed", "1", "--seeds", "0", "1"], "--seed")):
        words_t = words
        argv = [*base, *args]
        out.append(cli(f"train {' '.join(args)}", "ddpg_her.train", 4, argv, "usage", words_t))

    def not_strict(constant: str) -> None:
        raise WrongAnswer(f"spec.json holds {constant}: not strict JSON")

    def recorded(key: str, section: str, typed: float) -> Callable[[Path], None]:
        """A check that spec.json (strict JSON) records ``section.key`` as ``typed``."""
        def check(case_dir: Path) -> None:
            spec = json.loads((case_dir / "r" / "spec.json").read_text(),
                              parse_constant=not_strict)
            value = spec[section][key]
            if not (value == typed or (isinstance(value, str) and float(value) == typed)):
                raise WrongAnswer(f"{key} recorded as {value!r}; typed {typed!r}")
        return check

    # kind 5: what is recorded is what was typed (these train 2 episodes each)
    for flag, key, section, typed in (
            ("--exploration-rate", "exploration_rate", "agent", 1e-320),
            ("--obs-clip", "obs_clip", "agent", math.inf),
            ("--critic-l2", "critic_l2", "agent", 5e-324),
            ("--tau", "tau", "agent", 1e-310), ("--actor-lr", "actor_lr", "agent", 1e-320),
            ("--task", "success_radius", "task", 1e-310)):
        typed_arg = f"{key}={typed!r}" if flag == "--task" else repr(typed)
        out.append(Case(f"train {flag} {typed_arg} recorded as typed", "ddpg_her.train", 5,
                        "ok", argv=["--region", "farbox", "--joints", "3", *TINY_TRAIN, flag,
                                    typed_arg, "--out", "r"], call=recorded(key, section, typed)))
    return out


def study_cases(fix: Path) -> list[Case]:
    """The studies (sweep, sensitivity, algorithms, optimality) and the other analysis commands:
    kinds 2, 3, 4 and 7 beyond `old_cases`."""
    out: list[Case] = []
    studies = {"sweep": ("analysis.sweep", [*FARBOX, "--out", "sw", "--episodes", "200"]),
               "sensitivity": ("analysis.sensitivity",
                               [*STUDY, "--readings", "ours", "--out", "se"]),
               "algorithms": ("analysis.algorithms", [*STUDY, "--algos", "td3", "--out", "al"])}
    for study, (module, args) in studies.items():
        # kind 2: the other spellings of a study's own flags after --
        for extra, flag in ((["--region=zheight"], "--region"), (["--out=elsewhere"], "--out"),
                            (["--seeds=3"], "--seeds"), (["--episodes=5"], "--episodes"),
                            (["--task=region=zheight"], "region"),
                            (["--task", "n_joints=4"], "n_joints"),
                            (["--see", "3"], "--see"), (["--joi", "6"], "--joi"),
                            (["--region", "farbox"], "--region"),
                            (["--env-id", "toy_goal_env:ToyReach-v0"], "--env-id")):
            out.append(cli(f"{study} -- {' '.join(extra)}", module, 2, [*args, "--", *extra],
                           "usage", flag) if "--env-id" not in extra else
                       cli(f"{study} -- {' '.join(extra)} (left open: the studies' toy tests)",
                           module, 2, [*args, "--", *extra], "ok"))
        # kind 3/4/7: the execution arguments every study shares
        for extra, words in ((["--threads", "0"], "--threads"), (["--workers", "-1"],
                                                                 "--workers"),
                             (["--seeds", "-2"], "--seeds"), (["--episodes", "x"], "x"),
                             (["--ray-address", "ray://"], "ray://"),
                             (["--ray-address", "host:99999"], "host:99999"),
                             (["--device", "tpu"], "tpu"), (["--setting", "farbox:1"],
                                                            "farbox:1"),
                             (["--setting", "farbox"], "farbox"), (["--setting", ":3"], ":3"),
                             (["--out", str(fix / "blocker")], "blocker")):
            # the dry run does not check the Ray address and the output folder: those run
            undry = [a for a in args if a != "--dry-run"] \
                if extra[0] in ("--ray-address", "--out") else args
            out.append(cli(f"{study} {' '.join(extra)}", module, 7 if "--ray" not in extra[0]
                           else 4, [*undry, *extra], "usage", words))
        out.append(cli(f"{study} --dry-run (a whole plan)", module, 2, args, "ok"))
    for study in ("sensitivity", "algorithms"):
        module = f"analysis.{study}"
        out += [cli(f"{study} --collect a file", module, 3,
                    [*studies[study][1], "--collect", str(fix / "blocker")], "usage",
                    "--collect"),
                cli(f"{study} --project without --dry-run", module, 7,
                    [a for a in studies[study][1] if a != "--dry-run"] + ["--project"],
                    "refusal", "--project")]
    out += [
        cli("sweep --part 7", "analysis.sweep", 7, ["--part", "7", "--dry-run"], "refusal",
            "--part"),
        cli("sweep --grid nosuch", "analysis.sweep", 7, ["--grid", "nosuch", "--dry-run"],
            "usage", "nosuch"),
        cli("sweep --grid paper --dry-run (the paper's 11 settings)", "analysis.sweep", 7,
            ["--grid", "paper", "--dry-run", "--out", "sw"], "ok"),
        cli("sensitivity --readings-file missing", "analysis.sensitivity", 7,
            ["--readings-file", str(fix / "nosuch.json"), "--dry-run"], "refusal",
            "nosuch.json"),
        cli("sensitivity --readings-file not JSON", "analysis.sensitivity", 7,
            ["--readings-file", str(fix / "bad.json"), "--dry-run"], "refusal",
            "--readings-file"),
        cli("sensitivity --readings-file with a reading setting --region",
            "analysis.sensitivity", 2,
            ["--readings-file", "r.json", "--readings", "m", *STUDY, "--out", "se"], "usage",
            "--region", setup=lambda d: (d / "r.json").write_text(
                json.dumps({"m": {"args": ["--region", "zheight"]}}))),
        cli("sensitivity --reading without =", "analysis.sensitivity", 7,
            ["--reading", "noequals", "--dry-run"], "refusal", "noequals"),
        cli("algorithms --algos nosuch", "analysis.algorithms", 7,
            ["--algos", "nosuch", "--dry-run"], "refusal", "nosuch"),
        cli("optimality --goals -1", "analysis.optimality", 7, ["--goals", "-1"], "usage",
            "--goals"),
        cli("optimality --gamma nan", "analysis.optimality", 7, ["--gamma", "nan"], "usage",
            "gamma"),
        cli("optimality --joints 9", "analysis.optimality", 7,
            ["--joints", "9", "--goals", "2", "--out", "o"], "refusal", "9"),
        cli("optimality --regions nowhere", "analysis.optimality", 7,
            ["--regions", "nowhere", "--goals", "2", "--out", "o"], "refusal", "nowhere"),
        cli("optimality --settings farbox", "analysis.optimality", 7,
            ["--settings", "farbox", "--goals", "2"], "usage", "farbox"),
        cli("optimality --readings nosuch", "analysis.optimality", 7,
            ["--readings", "nosuch"], "usage", "nosuch"),
        cli("optimality --curves missing", "analysis.optimality", 7,
            ["--settings", "farbox:3", "--goals", "2", "--out", "o", "--curves",
             str(fix / "nosuch")], "refusal", "nosuch"),
        cli("optimality --from-csv missing", "analysis.optimality", 7,
            ["--from-csv", str(fix / "nosuch.csv"), "--out", "o"], "refusal", "nosuch.csv"),
        cli("optimality --from-csv not a table", "analysis.optimality", 7,
            ["--from-csv", str(fix / "bad.json"), "--out", "o"], "refusal", "bad.json"),
        cli("optimality --task garbage", "analysis.optimality", 4, ["--task", "garbage"],
            "usage", "garbage"),
        cli("contact --joints 7", "analysis.contact", 7, ["--joints", "7"], "usage",
            "7"),
        cli("contact --steps 0", "analysis.contact", 7, ["--steps", "0"], "usage", "--steps"),
        cli("contact --rounds 0", "analysis.contact", 7, ["--rounds", "0"], "usage",
            "--rounds"),
        cli("contact --friction -1 (documented: the TaskSpec default)", "analysis.contact", 7,
            ["--friction", "-1", "--goals", "2", "--steps", "2", "--rounds", "1"], "ok"),
        cli("contact --region box:1,0,0,1,0,1", "analysis.contact", 7,
            ["--region", "box:1,0,0,1,0,1"], "usage", "x=(1.0, 0.0)"),
        cli("contact --goals x", "analysis.contact", 7, ["--goals", "x"], "usage", "x"),
        cli("region_volumes --joints 7", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--joints", "7", "--samples", "1000"], "refusal", "7"),
        cli("region_volumes --resolution 0", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--resolution", "0", "--samples", "1000"], "refusal",
            "--resolution"),
        cli("region_volumes --resolution nan", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--resolution", "nan", "--samples", "1000"], "refusal",
            "--resolution"),
        cli("region_volumes --base-height -1", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--base-height", "-1", "--samples", "1000"], "refusal",
            "base"),
        cli("region_volumes --seed -1", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--seed", "-1", "--samples", "1000"], "refusal", "--seed"),
        cli("region_volumes --sampler cartesian --joints 2 (documented: NaN)",
            "analysis.region_volumes", 7, ["--regions", "farbox", "--sampler", "cartesian",
                                           "--joints", "2", "--goals", "10", "--samples",
                                           "1000"], "ok"),
        cli("region_volumes --goals 0 --sampler cartesian", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--sampler", "cartesian", "--goals", "0"], "refusal",
            "--goals"),
        cli("region_volumes --plot under a file", "analysis.region_volumes", 3,
            ["--regions", "farbox", "--samples", "1000", "--plot",
             str(fix / "blocker" / "p.png")], "refusal", "p.png"),
        cli("region_volumes --view under a file", "analysis.region_volumes", 3,
            ["--regions", "farbox", "--samples", "1000", "--view",
             str(fix / "blocker" / "v.html")], "refusal", "v.html"),
        cli("region_volumes --plot-joints 9", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--samples", "1000", "--plot", "p.png", "--plot-joints",
             "9"], "refusal", "--plot-joints"),
        cli("region_volumes unreachable box", "analysis.region_volumes", 7,
            ["--regions", "box:5,6,5,6,5,6", "--samples", "1000"], "ok"),
        cli("region_volumes a small table", "analysis.region_volumes", 7,
            ["--regions", "farbox", "--joints", "3", "--samples", "2000", "--json"], "ok"),
        cli("sb3 --joints 7", "analysis.sb3", 4, ["--region", "farbox", "--joints", "7"],
            "refusal", "7"),
        cli("sb3 --task nosuch=1", "analysis.sb3", 4,
            ["--region", "farbox", "--task", "nosuch=1"], "refusal", "nosuch"),
        cli("sb3 --eval-every 0", "analysis.sb3", 4,
            ["--region", "farbox", "--eval-every", "0"], "refusal", "--eval-every"),
        cli("sb3 --region nowhere", "analysis.sb3", 4, ["--region", "nowhere"], "refusal",
            "nowhere"),
        cli("sb3 --env-id NoSuch-v0", "analysis.sb3", 4,
            ["--region", "farbox", "--env-id", "NoSuch-v0"], "refusal", "NoSuch-v0"),
        cli("sb3 --out under a file", "analysis.sb3", 3,
            ["--region", "farbox", "--out", str(fix / "blocker" / "sb")], "refusal",
            "blocker"),
        cli("sb3 --hyperparams missing", "analysis.sb3", 4,
            ["--region", "farbox", "--hyperparams", str(fix / "nosuch.json")], "refusal",
            "nosuch.json"),
        cli("sb3 --hyperparams unknown key (h-relfix)", "analysis.sb3", 4,
            ["--region", "farbox", *SB3_TINY, "--hyperparams", "h.json", "--out", "sb"],
            "refusal", "nosuch_key",
            setup=lambda d: (d / "h.json").write_text('{"ddpg": {"nosuch_key": 1}}')),
        cli("sb3 --hyperparams learning_rate a string (h-relfix)", "analysis.sb3", 4,
            ["--region", "farbox", *SB3_TINY, "--hyperparams", "h.json", "--out", "sb"],
            "refusal", "learning_rate",
            setup=lambda d: (d / "h.json").write_text('{"ddpg": {"learning_rate": "fast"}}')),
        cli("sb3 --hyperparams a list", "analysis.sb3", 4,
            ["--region", "farbox", *SB3_TINY, "--hyperparams", "h.json", "--out", "sb"],
            "refusal", "h.json", setup=lambda d: (d / "h.json").write_text("[1, 2]")),
        cli("train_many --unit with a bad flag", "ddpg_her.train_many", 4,
            ["--unit", "--region farbox --nosuch 1 --out u", "--dry-run"], "refusal",
            "--nosuch"),
        cli("train_many --unit with a bad region", "ddpg_her.train_many", 4,
            ["--unit", "--region nowhere --out u", "--dry-run"], "refusal", "nowhere"),
        cli("train_many --unit unbalanced quote", "ddpg_her.train_many", 4,
            ["--unit", "--region 'farbox --out u", "--dry-run"], "refusal", "quot"),
        cli("train_many no units", "ddpg_her.train_many", 4, ["--dry-run"], "refusal",
            "--unit"),
        cli("train_many --plan units not a list", "ddpg_her.train_many", 4,
            ["--plan", "p.json", "--dry-run"], "refusal", "units",
            setup=lambda d: (d / "p.json").write_text('{"units": 3}')),
        cli("train_many --plan empty units", "ddpg_her.train_many", 4,
            ["--plan", "p.json", "--dry-run"], "refusal", "--plan",
            setup=lambda d: (d / "p.json").write_text('{"units": []}')),
        cli("train_many --plan a unit not a list of strings", "ddpg_her.train_many", 4,
            ["--plan", "p.json", "--dry-run"], "refusal", "p.json",
            setup=lambda d: (d / "p.json").write_text('{"units": [[1, 2]]}')),
        cli("train_many two units into one folder", "ddpg_her.train_many", 4,
            ["--unit", "--region farbox --out same", "--unit", "--region closebox --out same",
             "--dry-run"], "refusal", "same"),
        cli("train_many --threads 0", "ddpg_her.train_many", 4,
            ["--unit", "--region farbox --out u", "--threads", "0", "--dry-run"], "usage",
            "--threads"),
        cli("train_many --unit --out under a file", "ddpg_her.train_many", 3,
            ["--unit", f"--region farbox --joints 3 {' '.join(TINY_TRAIN[:-4])} --out "
             f"{fix / 'blocker' / 'u'}", "--no-progress", "--threads", "1"], "refusal",
            "blocker"),
        cli("train_many --dry-run of two units", "ddpg_her.train_many", 4,
            ["--unit", "--region farbox --out u1", "--unit", "--region closebox --out u2",
             "--dry-run"], "ok"),
        cli("browser --at -1", "benchmarks.browser", 7, ["p.html", "--at", "-1"], "refusal",
            "--at", setup=lambda d: (d / "p.html").write_text("<html></html>")),
        cli("browser --at nan", "benchmarks.browser", 7, ["p.html", "--at", "nan"], "refusal",
            "--at", setup=lambda d: (d / "p.html").write_text("<html></html>")),
        cli("browser --size 10 10", "benchmarks.browser", 7, ["p.html", "--size", "10", "10"],
            "refusal", "--size", setup=lambda d: (d / "p.html").write_text("<html></html>")),
        cli("browser --out under a file", "benchmarks.browser", 3,
            ["p.html", "--out", str(fix / "blocker" / "s.png")], "refusal", "s.png",
            setup=lambda d: (d / "p.html").write_text("<html></html>")),
        cli("train --out a file", "ddpg_her.train", 3,
            ["--region", "farbox", "--joints", "3", *TINY_TRAIN, "--out",
             str(fix / "blocker")], "usage", "blocker"),
        cli("success_map --out a folder", "analysis.success_map", 3,
            [str(fix / "ur5" / "s0"), "--goals", "4", "--z", "0.1", "0.3", "--out", str(fix)],
            "refusal", "folder"),
        cli("region_volumes --plot a folder", "analysis.region_volumes", 3,
            ["--regions", "farbox", "--samples", "1000", "--plot", str(fix)], "refusal",
            "folder"),
        cli("optimality --out a file", "analysis.optimality", 3,
            ["--out", str(fix / "blocker"), "--goals", "2"], "usage", "blocker"),
        cli("sensitivity report --out a file", "analysis.sensitivity", 3,
            ["report", str(fix / "ur5"), "--out", str(fix / "blocker")], "usage", "blocker"),
        cli("sensitivity report of a root without the study's runs ('not run')",
            "analysis.sensitivity", 7, ["report", str(fix / "ur5"), "--out", "o"], "ok"),
        cli("browser page a folder", "benchmarks.browser", 7, [str(fix)], "refusal", str(fix)),
    ]
    return out


# ---------------------------------------------------------------------------- library API
TINY_UNIT = [a for a in TINY_TRAIN if a not in ("--no-progress", "--no-tensorboard")][:-2]
"""`TINY_TRAIN` without the process flags (a ``train_many`` unit's arguments)."""


def _mesh(case_dir: Path) -> None:
    """A closed box mesh, ``goal.stl``, in the case's folder (a region the device cannot test)."""
    import trimesh

    trimesh.creation.box(bounds=[[0.4, -0.1, 0.1], [0.6, 0.1, 0.3]]).export(case_dir / "goal.stl")


def gate_cases(fix: Path) -> list[Case]:
    """Issue 41: the training program and the dry runs checked as the real run checks them
    (kind 1), a unit's own arguments never replaced (kind 2), folders and reports not replaced
    or confused (kinds 3 and 4), and the one-line refusals of kinds 6 and 7. Names start with
    ``gate:`` (``--only gate:`` runs them alone)."""
    import torch

    out: list[Case] = []
    refusals: list[tuple[list[str], str]] = [
        (["--algo", "td3"], "--algo td3"), (["--algo", "sac"], "--algo sac"),
        (["--batch-norm"], "--batch-norm"), (["--her-strategy", "future"], "--her-strategy"),
        (["--ensemble", "2"], "--ensemble 2"),
        (["--algo", "td3", "--batch-norm"], "--algo td3"),
        (["--task", "contact_model=compliant"], "contact_model"),
        (["--task", "held_joints=pd"], "held_joints"),
        (["--task", "goal_sampler=cartesian"], "goal_sampler"),
        (["--task", "control_mode=velocity"], "control_mode"),
        (["--eval-episodes", "100000"], "--eval-episodes"),
        (["--buffer-size", "1000000000"], "--buffer-size"),
        (["--buffer-size", "100000000000"], "--buffer-size"),
        (["--hidden-sizes", "100000", "100000"], "--hidden-sizes"),
        (["--hidden-sizes", "10000000", "30"], "--hidden-sizes"),
    ]
    sweep_args = ["--setting", "farbox:3", "--seeds", "1", "--episodes", "200", "--out", "sw",
                  "--program"]
    sens_args = ["--setting", "farbox:3", "--readings", "ours", "--seeds", "1", "--episodes",
                 "200", "--out", "se", "--program"]

    def modes(flags: list[str], region: str = "farbox") -> list[tuple[str, str, list[str]]]:
        unit = shlex.join(["--region", region, *TINY_UNIT, "--out", "r", *flags])
        both = [("train", "ddpg_her.train", ["--region", region, *TINY_TRAIN, "--out", "r",
                                             "--env-backend", "program", *flags]),
                ("train_many", "ddpg_her.train_many",
                 ["--unit", unit, "--env-backend", "program", "--no-progress"]),
                ("train_many --dry-run", "ddpg_her.train_many",
                 ["--unit", unit, "--env-backend", "program", "--dry-run"])]
        if region != "farbox":
            return both
        return [*both,
                ("sweep --program", "analysis.sweep", [*sweep_args, "--", *flags]),
                ("sweep --program --dry-run", "analysis.sweep",
                 [*sweep_args, "--dry-run", "--", *flags]),
                ("sensitivity --program --dry-run", "analysis.sensitivity",
                 [*sens_args, "--dry-run", "--", *flags]),
                ("sensitivity --program", "analysis.sensitivity", [*sens_args, "--", *flags]),
                ("sweep --program --dry-run zheight:6", "analysis.sweep",
                 [*sweep_args[:1], "zheight:6", *sweep_args[2:], "--dry-run", "--", *flags])]

    # kind 1: what the program refuses, refused alike by every path and dry run, its cause named
    for flags, words in refusals:
        for where, module, argv in modes(flags):
            out.append(cli(f"gate: program {where} {' '.join(flags)}", module, 1, argv,
                           "usage", words))
    for where, module, argv in modes([], "mesh:goal.stl"):
        out.append(Case(f"gate: program {where} a mesh region", module, 1, "usage",
                        ("mesh",), argv=argv, setup=_mesh))
    process = [(["--tf32"], "--tf32")]
    if not torch.cuda.is_available():
        process.append((["--device", "cuda"], "no CUDA device"))
    for flags, words in process:
        for where, module, argv in modes([]):
            if where.startswith("train_many"):
                argv = [*argv, *flags]
            elif where.startswith(("sweep", "sensitivity")):
                cut = argv.index("--")
                argv = [*argv[:cut], *flags, *argv[cut:]]
            else:
                argv = [*argv, *flags]
            flagged = "dry-run" in where and flags[0] == "--device"  # noted, listed
            out.append(cli(f"gate: program {where} {' '.join(flags)} on this machine", module, 1,
                           argv, "ok" if flagged else "usage", words))
    # kind 1, the other way: what the program trains, the dry runs accept
    for region in ("farbox", "zheight", "closebox", "unconstrained", "farbox_tall",
                   "box:0.3,0.6,-0.2,0.2,0.1,0.4", "zmax:0.4"):
        for joints in range(2, 7):
            unit = shlex.join(["--region", region, "--joints", str(joints), *TINY_UNIT,
                               "--out", "r"])
            out.append(cli(f"gate: train_many --dry-run program accepts {region}:{joints}",
                           "ddpg_her.train_many", 1,
                           ["--unit", unit, "--env-backend", "program", "--dry-run"], "ok"))
            if ":" not in region:
                out.append(cli(f"gate: sweep --program --dry-run accepts {region}:{joints}",
                               "analysis.sweep", 1,
                               ["--setting", f"{region}:{joints}", "--seeds", "2", "--episodes",
                                "200", "--out", "sw", "--program", "--dry-run"], "ok"))
    # kind 2: arguments after -- never replace a unit's own
    for own, after in ((["--region", "farbox"], ["--region", "zheight"]),
                       (["--region", "farbox"], ["--reg", "zheight"]),
                       (["--out", "mine"], ["--out", "x"]), (["--out", "mine"], ["--out=x"]),
                       (["--seeds", "0", "1"], ["--seeds", "3", "4"]),
                       (["--seed", "0"], ["--seeds", "3", "4"]),
                       (["--seeds", "0", "1"], ["--seed", "3"]),
                       (["--joints", "3"], ["--joints", "6"]),
                       (["--episodes", "4"], ["--episodes", "8"]),
                       (["--episodes", "4"], ["--episodes=8"]),
                       (["--eval-every", "2"], ["--eval-every", "4"]),
                       (["--hidden-sizes", "8", "8"], ["--hidden-sizes", "16", "16"])):
        unit = ["--region", "farbox", *TINY_UNIT, "--out", "r"]
        unit = [a for a in unit if a not in own[:1]] if own[0] != "--region" else unit
        for i, flag in enumerate(unit):  # the unit's own value, replacing TINY_UNIT's
            if flag == own[0]:
                width = 3 if flag == "--hidden-sizes" else 2
                unit = [*unit[:i], *unit[i + width:]]
                break
        unit = [*unit, *own]
        for backend in ("numpy", "program"):
            for dry in ([], ["--dry-run"]):
                out.append(cli(f"gate: train_many {backend}{' --dry-run' if dry else ''} unit "
                               f"{' '.join(own)} -- {' '.join(after)}", "ddpg_her.train_many",
                               2, ["--unit", shlex.join(unit), "--env-backend", backend,
                                   "--no-progress", *dry, "--", *after],
                               "usage", after[0].partition("=")[0]))
    for flag in (["--env-backend", "numpy"], ["--env-backend", "program"], ["--env-back", "numpy"],
                 ["--device", "cpu"], ["--threads", "1"], ["--tf32"], ["--resume"],
                 ["--no-progress"], ["--no-tensorboard"]):
        unit = shlex.join(["--region", "farbox", *TINY_UNIT, "--out", "r", *flag])
        for dry in ([], ["--dry-run"]):
            out.append(cli(f"gate: train_many{' --dry-run' if dry else ''} a unit's own "
                           f"{' '.join(flag)}", "ddpg_her.train_many", 2,
                           ["--unit", unit, "--env-backend", "program", *dry], "usage",
                           flag[0]))
    for unit_args, words in (("--region zheight", "--region"), ("--seeds 3 4", "--seeds"),
                             ("--reg zheight", "--reg"), ("--seeds=3", "--seeds"),
                             ("--out=x", "--out"), ("--episodes=5", "--episodes"),
                             ("--joi 4", "--joi"), ("--warmup-episodes=2", "--warmup-episodes"),
                             ("--eval-every=7", "--eval-every"), ("--threads 2", "--threads"),
                             ("--resume", "--resume"), ("--tf32", "--tf32"),
                             ("--no-progress", "--no-progress"),
                             ("--env-backend=program", "--env-backend"),
                             ("--seed 3", "--seed"), ("--out x", "--out"),
                             ("--joints 4", "--joints"), ("--episodes 5", "--episodes"),
                             ("--eval-every 7", "--eval-every"),
                             ("--warmup-episodes 2", "--warmup-episodes"),
                             ("--hidden-sizes 8 8 '", "cannot be split"),
                             ("--hidden-sizes 8 8 \\", "cannot be split"),
                             ("--env-backend numpy", "--env-backend"),
                             ("--device cpu", "--device")):
        out.append(cli(f"gate: grid_episode --unit-args {unit_args!r}", "benchmarks.grid_episode",
                       2, ["--device", "cpu", "--part", "2", f"--unit-args={unit_args}"],
                       "usage", words))
    # kinds 3 and 4: folders
    for where, module, argv in (
            ("train", "ddpg_her.train", ["--region", "farbox", *TINY_TRAIN]),
            ("train program", "ddpg_her.train", ["--region", "farbox", *TINY_TRAIN,
                                                 "--env-backend", "program"])):
        for value, words in (("", "--out"), (" ", "--out"), ("x" * 256, "255"),
                             ("a/" + "y" * 300 + "/b", "255")):
            out.append(cli(f"gate: {where} --out {value[:12]!r}... ({len(value)} chars)",
                           module, 3, [*argv, "--out", value], "usage", words))
        if where == "train":
            for value, words in (("", "--out"), (" ", "--out"), ("x" * 256, "255"),
                                 ("a/" + "y" * 300 + "/b", "255")):
                out.append(cli(f"gate: train_many unit --out {value[:12]!r}... ({len(value)} "
                               "chars)", "ddpg_her.train_many", 3,
                               ["--unit", shlex.join(["--region", "farbox", *TINY_UNIT,
                                                      "--out", value]), "--dry-run"],
                               "usage", words))
        one_seed = write("one/spec.json", json.dumps({"format": "ddpg_her-run-1", "seed": 0}))
        out.append(cli(f"gate: {where} --seeds 0 1 --resume over a one-seed folder", module, 3,
                       [*argv, "--out", "one", "--seeds", "0", "1", "--resume"], "usage",
                       "one seed", setup=one_seed))
    return out


def _one_line(module: str, argv: list[str]) -> Callable[[Path], Any]:
    """A command run in the case's process whose usage error must be one line: a refusal is
    raised as a ValueError holding that line (``usage``), a longer one is a `WrongAnswer`."""
    def call(_: Path) -> Any:
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                code = importlib.import_module(module).main(argv)
            except SystemExit as stop:
                code = stop.code
        lines = err.getvalue().strip().splitlines()
        if code == 2:
            _check(len(lines) == 1, f"a usage error of {len(lines)} lines: {lines[:2]}")
            raise ValueError(lines[0])
        return code
    return call


def gate2_cases(fix: Path) -> list[Case]:
    """Issue 41, the one gate (names ``gate: g2 ...``): every command's usage error in one line,
    each record (a region's base height, the task, the agent's configuration, a recorded task)
    checked by its one description, and the cases of kinds 5-7 left by the first pass."""
    import regions
    from ddpg_her.config import AgentConfig
    from envs.spec import TaskSpec

    nan, inf = float("nan"), float("inf")
    out: list[Case] = []
    commands = sorted(f"{p.parent.name}.{p.stem}" for package in ("ddpg_her", "analysis")
                      for p in (ROOT / package).glob("*.py") if "= Parser(" in p.read_text())
    for module in commands:
        out.append(api(f"gate: g2 {module} an unknown flag in one line", module, 7,
                       _one_line(module, ["--no-such-flag-41"]), "usage",
                       "--no-such-flag-41|required"))
    bad_flags = [("analysis.replay", [str(fix / "ur5" / "s0"), "--seed", "-1"], "--seed"),
                 ("analysis.replay", [str(fix / "ur5" / "s0"), "--episodes", "0"], "--episodes"),
                 ("analysis.optimality", ["--seed", "x"], "--seed"),
                 ("analysis.optimality", ["--grid", "1"], "--grid"),
                 ("analysis.optimality", ["--gamma", "nan"], "--gamma"),
                 ("analysis.success_map", [str(fix / "ur5" / "s0"), "--goals", "0"], "--goals"),
                 ("analysis.success_map", [str(fix / "ur5" / "s0"), "--cell", "inf"], "--cell"),
                 ("analysis.success_map", [str(fix / "ur5" / "s0"), "--z", "0", "nan"], "--z"),
                 ("analysis.success_map", [str(fix / "ur5" / "s0"), "--batch", "-3"], "--batch"),
                 ("analysis.contact", ["--steps", "0"], "--steps"),
                 ("analysis.contact", ["--rounds", "1.5"], "--rounds"),
                 ("analysis.region_volumes", ["--joints", "0"], "--joints"),
                 ("analysis.region_volumes", ["--resolution", "0"], "--resolution"),
                 ("analysis.region_volumes", ["--base-height", "-1"], "--base-height"),
                 ("analysis.region_volumes", ["--samples", "0"], "--samples"),
                 ("ddpg_her.train", ["--region", "farbox", "--gamma", "2"], "gamma"),
                 ("ddpg_her.train", ["--region", "farbox", "--exploration", "epsilon",
                                     "--exploration-rate", "1.5"], "exploration_rate")]
    for module, argv, words in bad_flags:
        out.append(api(f"gate: g2 {module} {' '.join(argv[-2:])} in one line", module, 7,
                       _one_line(module, argv), "usage", words))
    for name in ("farbox", "closebox", "zheight", "unconstrained", "box:0.5,0.9,-0.4,0.4,0,0.4"):
        for height in (-1.0, nan, inf, "0.1"):
            out.append(api(f"gate: g2 regions.parse({name!r}, base_height={height!r})",
                           "regions.parse", 5,
                           lambda _, n=name, h=height: regions.parse(n, h), "usage",
                           "base_height"))
            if ":" not in name:
                out.append(api(f"gate: g2 regions.get({name!r}, base_height={height!r})",
                               "regions.get", 5,
                               lambda _, n=name, h=height: regions.get(n, base_height=h),
                               "usage", "base_height"))
    for field, value in (("n_joints", 9), ("n_joints", 2.0), ("kp", [1.0] * 5),
                         ("kd", "abcdef"), ("start_q", [nan] * 6), ("sim_hz", 1001),
                         ("control_hz", True), ("success_radius", 0.0),
                         ("contact_stiffness", inf), ("held_joints", "welded"),
                         ("terminate_on_success", "yes"), ("max_episode_steps", 0)):
        out.append(api(f"gate: g2 TaskSpec({field}={value!r})", "envs.TaskSpec", 5,
                       lambda _, f=field, v=value: TaskSpec(**{f: v}), "usage",
                       "sim_hz" if field == "sim_hz" else field))
    for field, value in (("gamma", 1.5), ("tau", 0.0), ("hidden_sizes", (8,)),
                         ("ensemble", 3), ("buffer_size", 8), ("algo", "ppo"),
                         ("normalize_obs", 1), ("obs_clip", nan)):
        out.append(api(f"gate: g2 AgentConfig({field}={value!r})", "ddpg_her.AgentConfig", 5,
                       lambda _, f=field, v=value: AgentConfig(**{f: v}), "usage", field))
    for field, value in (("n_joints", 9), ("base_height", -1), ("region", "nowhere"),
                         ("kp", [1.0])):
        def change(spec: dict, f: str = field, v: Any = value) -> None:
            spec["task"][f] = v
        for module, argv in (("analysis.curves", ["run", "--out", "c.png"]),
                             ("analysis.report", ["run"]),
                             ("analysis.replay", ["run/s0", "--out", "r.mp4"])):
            out.append(cli(f"gate: g2 {module} of a spec.json task {field}={value!r}", module,
                           5, argv, "usage", f"{field}|{value}",
                           setup=copy_run(fix, edit_spec(change))))
    out.append(api("gate: g2 gymnasium.make('UR5StackReach-v0')", "gymnasium.make", 6,
                   lambda _: gymnasium.make("UR5StackReach-v0"), "usage", "StackReach"))
    out.append(cli("gate: g2 optimality --curves over a truncated eval.csv",
                   "analysis.optimality", 6,
                   ["--from-csv", str(ROOT / "results" / "optimality" / "optimality.csv"),
                    "--curves", "run", "--out", "o"], "usage", "eval.csv",
                   setup=copy_run(fix, truncate("eval.csv"))))

    def four_joints(spec: dict) -> None:
        spec["task"]["n_joints"] = spec["env_kwargs"]["n_joints"] = 4
        spec["dims"].update(obs_dim=12, act_dim=4, action_low=[-math.pi] * 4,
                            action_high=[math.pi] * 4)
    out.append(cli("gate: g2 replay of a checkpoint of another joint count", "analysis.replay",
                   6, ["run/s0", "--out", "r.mp4"], "usage", "episode-000002.pt",
                   setup=copy_run(fix, edit_spec(four_joints))))
    out.append(api("gate: g2 ddpg_her.load of a checkpoint of another joint count",
                   "ddpg_her.load", 6, _load("run/s0"), "usage", "does not fit",
                   setup=copy_run(fix, edit_spec(four_joints))))
    out.append(cli("gate: g2 success_map's default slice outside the far box",
                   "analysis.success_map", 7,
                   [str(fix / "ur5" / "s0"), "--goals", "20", "--out", "m.png",
                    "--no-progress"], "usage", "--z 0"))
    return out


def _gym_length(limit: int, **kwargs: Any) -> Callable[[Path], None]:
    """``gymnasium.make(..., max_episode_steps=limit)``: the record says ``limit`` and the env
    underneath truncates at it, as make's TimeLimit does (else WrongAnswer)."""
    def call(_: Path) -> None:
        env = gymnasium.make("UR5Reach-v0", region="zheight", n_joints=2,
                             max_episode_steps=limit, **kwargs)
        inner = env.unwrapped
        _check(inner.task.max_episode_steps == limit, f"task says {inner.task.max_episode_steps}")
        for wrapped in (env, inner):
            wrapped.reset(seed=0)
            ends = [wrapped.step(np.zeros(2))[3] for _ in range(limit)]
            _check(ends == [False] * (limit - 1) + [True], f"{type(wrapped).__name__}: {ends}")
    return call


def gate3_cases(fix: Path) -> list[Case]:
    """Issue 41, the records of the last pass (names ``gate: g3 ...``): SB3's hyperparameters,
    a unit of training (`ddpg_her.units.Setting`), a reading, a region's Box and ZLimit, and
    gymnasium.make's max_episode_steps against the task's record; each through the library
    call and the command that reads it."""
    import regions
    from analysis import sb3
    from analysis.readings import Reading
    from ddpg_her.config import AgentConfig
    from ddpg_her.units import Setting
    from envs.spec import TaskSpec

    nan, inf = float("nan"), float("inf")
    out: list[Case] = []
    base = sb3.load_hyperparams(sb3.DEFAULT_HYPERPARAMS, "ddpg")
    bad_sb3 = [("gamma", 2), ("gamma", -0.1), ("tau", 0), ("tau", 1.5), ("learning_rate", 0),
               ("learning_rate", -1e-3), ("batch_size", 0), ("buffer_size", 0),
               ("learning_starts", -1), ("gradient_steps", 0), ("gradient_steps", -2),
               ("train_freq", [0, "step"]), ("train_freq", [1, "epoch"]), ("train_freq", 0),
               ("action_noise_std", -0.5), ("gamma", "high"), ("batch_size", 64.0),
               ("learning_starts", 2_000_000)]
    for key, value in bad_sb3:
        params = {**base, key: value}
        out.append(api(f"gate: g3 sb3 hyperparameter {key}={value!r}", "analysis.sb3", 5,
                       lambda _, p=params: sb3.check_hyperparams(p, "ddpg"), "usage",
                       [key, json.dumps(value) if isinstance(value, str) else str(value)]))
    for sub, value in (("replay_buffer_kwargs", {"n_sampled_goal": 0}),
                       ("replay_buffer_kwargs", {"goal_selection_strategy": "past"}),
                       ("policy_kwargs", {"net_arch": [0]}),
                       ("policy_kwargs", {"net_arch": [64, -1]})):
        params = {**base, sub: {**base.get(sub, {}), **value}}
        (key,) = value
        out.append(api(f"gate: g3 sb3 hyperparameter {sub}.{key}={value[key]!r}",
                       "analysis.sb3", 5, lambda _, p=params: sb3.check_hyperparams(p, "td3"),
                       "usage", f"{sub}.{key}"))
    out.append(api("gate: g3 sb3.make_model with gamma 2 (the library's way in)",
                   "analysis.sb3.make_model", 5,
                   lambda _: sb3.make_model("ddpg", gymnasium.make("UR5Reach-v0"),
                                            {**base, "gamma": 2}, 0), "usage", "gamma=2"))
    out.append(api("gate: g3 sb3.train with tau 0 (the library's way in), no folder",
                   "analysis.sb3.train", 5,
                   lambda d: sb3.train("td3", "UR5Reach-v0", {"region": "farbox", "n_joints": 3},
                                       0, 2, 1, 1, {**base, "tau": 0}, d / "run"),
                   "usage", "tau=0"))
    for key, value in (("gamma", 2), ("batch_size", 0), ("train_freq", [1, "epoch"])):
        data = {"common": {**base, key: value}, "ddpg": {}}
        out.append(cli(f"gate: g3 analysis.sb3 --hyperparams with {key}={value!r}",
                       "analysis.sb3", 5, ["--region", "farbox", "--hyperparams", "h.json",
                                           "--out", "run"], "usage", [key, "h.json"],
                       setup=write("h.json", json.dumps(data))))
    config = AgentConfig(episodes=100)
    for seeds, dirs, kwargs, cfg, words in (
            ((0, 0), ("a", "b"), {}, {}, "seeds=(0, 0)"),
            ((-1,), ("a",), {}, {}, "seeds=(-1,)"),
            ((), (), {}, {}, "seeds=()"),
            ((0, 1), ("a", "a"), {}, {}, "run_dirs=('a', 'a')"),
            ((0, 1), ("a",), {}, {}, "one run folder per seed"),
            ((0,), ("",), {}, {}, "run_dirs=('',)"),
            ((0,), ("a",), {"n_joints": 9}, {}, "n_joints=9"),
            ((0,), ("a",), {"region": "nowhere"}, {}, "nowhere"),
            ((0,), ("a",), {"max_episode_steps": 0}, {}, "max_episode_steps=0"),
            ((0,), ("a",), {}, {"her_k": 8}, "--her-k"),
            ((0,), ("a",), {}, {"episodes": 150}, "--eval-every")):
        out.append(api(f"gate: g3 Setting(seeds={seeds}, run_dirs={dirs}, {kwargs}, {cfg})",
                       "ddpg_her.units.Setting", 5,
                       lambda _, s=seeds, d=dirs, k=kwargs, c=cfg: Setting(
                           "UR5Reach-v0", {"region": "farbox", "n_joints": 3, **k},
                           AgentConfig(**{"episodes": 100, **c}), s, d), "usage", words))
    out.append(api("gate: g3 Setting of a config that is not an AgentConfig",
                   "ddpg_her.units.Setting", 5,
                   lambda _: Setting("UR5Reach-v0", {"region": "farbox"}, config.to_dict(),
                                     (0,), ("a",)), "usage", "expected an AgentConfig"))
    for dry in (True, False):
        out.append(cli(f"gate: g3 train_many{' --dry-run' if dry else ''} a unit of seeds 0 0",
                       "ddpg_her.train_many", 5,
                       ["--unit", "--region farbox --seeds 0 0 --out u/s{seed} "
                        + " ".join(TINY_UNIT), *(["--dry-run"] if dry else [])],
                       "usage", "seeds=(0, 0)"))
        out.append(cli(f"gate: g3 sweep{' --dry-run' if dry else ''} a box of lo > hi",
                       "analysis.sweep", 5,
                       ["--setting", "box:0.9,0.5,-0.4,0.4,0,0.4:3", "--seeds", "1", "--out",
                        "sw", *(["--dry-run"] if dry else [])], "usage", "lo < hi"))
    for args, words in ((("a b", ()), "name='a b'"), (("x", ("--tau", 1)), "args="),
                        (("x", "--tau 0.1"), "args='--tau 0.1'"),
                        (("x", (), 5), "paper=5"), (("x", (), "", None), "ours=None")):
        out.append(api(f"gate: g3 Reading{args!r}", "analysis.readings.Reading", 5,
                       lambda _, a=args: Reading(*a), "usage", words))
    for entry, words in (({"args": [1, None]}, "args=[1, None]"),
                         ({"args": "--tau 0.1", "paper": 5}, "paper=5"),
                         ({"args": "--tau 0.1", "paepr": "x"}, "paepr"),
                         ({"args": {"--tau": 1}}, "args=")):
        out.append(cli(f"gate: g3 sensitivity --readings-file {json.dumps(entry)}",
                       "analysis.sensitivity", 5,
                       [*STUDY, "--readings-file", "r.json"], "usage", words,
                       setup=write("r.json", json.dumps({"mine": entry}))))
    for x, words in (((1.0, 0.0), "lo < hi"), ((0.0, inf), "x=(0.0, inf)"),
                     ((0.0, nan), "x=(0.0, nan)"), (("0", "1"), "x=('0', '1')"),
                     ((True, 2), "x=(True, 2)"), ((0, 1, 2), "x=(0, 1, 2)"),
                     (None, "x=None"), ("01", "x='01'")):
        out.append(api(f"gate: g3 Box(x={x!r})", "regions.Box", 5,
                       lambda _, v=x: regions.Box(v, (0, 1), (0, 1)), "usage", words))
    for zmin, zmax, words in ((0.5, 0.1, "zmin < zmax"), (nan, 1.0, "zmin=nan"),
                              ("0.1", None, "zmin='0.1'"), (0.0, False, "zmax=False"),
                              (inf, inf, "zmin < zmax"), (0.0, [1.0], "zmax=[1.0]")):
        out.append(api(f"gate: g3 ZLimit({zmin!r}, {zmax!r})", "regions.ZLimit", 5,
                       lambda _, a=zmin, b=zmax: regions.ZLimit(a, b), "usage", words))
    for data, words in (({"kind": "box", "x": ["0", "1"], "y": [0, 1], "z": [0, 1]}, "x="),
                        ({"kind": "zlimit", "zmin": "low", "zmax": None}, "zmin='low'"),
                        ({"kind": "ball", "center": [0, 0, "1"], "radius": 0.2}, "center=")):
        out.append(api(f"gate: g3 region_from_dict({data})", "regions.region_from_dict", 5,
                       lambda _, d=data: regions.region_from_dict(d), "usage", words))
    for spec, words in (("box:1,0,0,1,0,1", "lo < hi"), ("z:0.5,0.1", "zmin < zmax"),
                        ("box:0,1,0,1,0,inf", "z=(0.0, inf)")):
        out.append(api(f"gate: g3 regions.parse({spec!r})", "regions.parse", 5,
                       lambda _, t=spec: regions.parse(t), "usage", words))
    for limit in (7, 50, 150):
        out.append(api(f"gate: g3 gymnasium.make(max_episode_steps={limit}) records and "
                       "truncates alike", "gymnasium.make", 5, _gym_length(limit), "ok"))
    out.append(api("gate: g3 gymnasium.make(max_episode_steps=20) of a task of 20",
                   "gymnasium.make", 5, _gym_length(
                       20, task=TaskSpec(region="zheight", n_joints=2, max_episode_steps=20)),
                   "ok"))
    for length, limit in ((200, 50), (100, 50), (30, 31)):
        out.append(api(f"gate: g3 gymnasium.make(task of {length}, max_episode_steps={limit})",
                       "gymnasium.make", 5, lambda _, n=length, m=limit: gymnasium.make(
                           "UR5Reach-v0", task=TaskSpec(region="zheight", max_episode_steps=n),
                           max_episode_steps=m), "usage",
                       [f"max_episode_steps={limit}", f"max_episode_steps={length}"]))
    for limit, words in ((0, "max_episode_steps=0"), (2.5, "max_episode_steps=2.5"),
                         ("50", "max_episode_steps='50'")):
        out.append(api(f"gate: g3 gymnasium.make(max_episode_steps={limit!r})",
                       "gymnasium.make", 5, lambda _, m=limit: gymnasium.make(
                           "UR5Reach-v0", region="zheight", max_episode_steps=m), "usage", words))
    return out


def _ran(module: str, argv: list[str], then: Callable[[Path], None] | None = None
         ) -> Callable[[Path], None]:
    """A setup: the fixture run copied (`copy_run`), ``module`` run once in the case folder
    with ``argv`` (its outputs are there before the case runs it again), then ``then``."""
    def setup(case_dir: Path) -> None:
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        subprocess.run([sys.executable, "-m", module, *argv], check=True, cwd=case_dir, env=env,
                       capture_output=True)
        if then is not None:
            then(case_dir)
    return setup


def gate4_cases(fix: Path) -> list[Case]:
    """Issue 41, kind 4 for every writer of results (names ``gate: g4 ...``): an output that
    holds something else is not replaced without --force (refused, naming it, nothing
    written); the same output again and --force are fine. And a malformed reading.json."""
    writers = {
        "report": ("analysis.report", ["run", "--out", "o/r.md"], "o/r.md"),
        "curves": ("analysis.curves", ["run", "--out", "o/c.png"], "o/c.csv"),
        "success_map": ("analysis.success_map", ["run/s0", "--goals", "4", "--batch", "4",
                                                 "--z", "0.1", "0.3", "--out", "o/m.png",
                                                 "--no-progress"], "o/m.png"),
        "region_volumes --plot": ("analysis.region_volumes", [
            "--regions", "farbox", "--joints", "3", "--samples", "1000", "--plot", "o/v.png"],
            "o/v.json"),
        "claims": ("analysis.claims", ["--results", str(ROOT / "results"), "--out", "o"],
                   "o/claims.md"),
        "optimality": ("analysis.optimality", ["--settings", "unconstrained:2", "--goals", "2",
                                               "--readings", "ours", "--out", "o",
                                               "--no-progress"], "o/optimality.csv"),
        "sensitivity report": ("analysis.sensitivity", ["report", str(fix / "ur5"), "--out",
                                                        "o", "--worth-goals", "0"],
                               "o/report.md"),
    }
    out: list[Case] = []
    for name, (module, argv, target) in writers.items():
        def other(case_dir: Path, t: str = target) -> None:
            path = case_dir / t
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text("someone else's result\n")
        out.append(cli(f"gate: g4 {name} over a file that holds something else", module, 4,
                       argv, "usage", ["would replace", target, "--force"],
                       setup=lambda d, o=other: (copy_run(fix)(d), o(d))[-1]))
        out.append(cli(f"gate: g4 {name} --force over a file that holds something else",
                       module, 4, [*argv, "--force"], "ok",
                       setup=lambda d, o=other: (copy_run(fix)(d), o(d))[-1]))
        if name != "optimality":  # its table holds each row's seconds: never the same twice
            out.append(cli(f"gate: g4 {name} again over its own output", module, 4, argv, "ok",
                           setup=lambda d, m=module, a=argv: (copy_run(fix)(d),
                                                              _ran(m, a)(d))[-1]))
    for text, words in (("{", "not a reading record"), ('{"args": []}', "'name'"),
                        ('{"name": "x", "args": [], "k": 1}', "k")):
        out.append(cli(f"gate: g4 sensitivity report over a reading.json of {text}",
                       "analysis.sensitivity", 6, ["report", "runs", "--out", "o",
                                                   "--worth-goals", "0"], "usage",
                       ["runs/mine/reading.json", words],
                       setup=lambda d, t=text: (shutil.copytree(fix / "ur5", d / "runs" / "mine"
                                                                / "farbox-j3"),
                                                write("runs/mine/reading.json", t)(d))[-1]))
    return out


def _written_halfway(failure: str) -> Callable[[Path], None]:
    """curves --force over someone else's o/c.png and o/c.csv, the CSV's write failing
    (``failure``: 'full' disk, 'ctrl-c', or 'unreadable': the CSV there cannot be read for the
    comparison): both files must stay as they were, the failure one line."""
    def call(case_dir: Path) -> None:
        import pathlib

        from analysis import curves
        from ddpg_her import runfolder
        before, real, read = snapshot(case_dir / "o"), runfolder.atomic_write, Path.read_bytes

        def failing(path: Path, data: bytes) -> None:
            if path.suffix == ".csv" and failure != "unreadable":
                raise KeyboardInterrupt if failure == "ctrl-c" else \
                    runfolder.write_failure(path, OSError(28, "No space left on device"))
            real(path, data)

        def unreadable(path: Path) -> bytes:
            if path.suffix == ".csv" and path.parent.name == "o":
                raise PermissionError(13, "Permission denied", str(path))
            return read(path)

        runfolder.atomic_write = failing
        pathlib.Path.read_bytes = unreadable if failure == "unreadable" else read
        err = io.StringIO()
        with contextlib.suppress(SystemExit, KeyboardInterrupt), contextlib.redirect_stderr(err):
            curves.main(["run", "--out", "o/c.png", "--force"])
        pathlib.Path.read_bytes = read
        _check(snapshot(case_dir / "o") == before, f"{failure}: the outputs changed")
        lines = [ln for ln in err.getvalue().splitlines() if ln.strip()]
        _check(failure == "ctrl-c" or (len(lines) == 1 and "c.csv" in lines[0]),
               f"not one line naming c.csv: {lines[-3:]}")
    return call


def gate5_cases(fix: Path) -> list[Case]:
    """Issue 41, kind 4, the gaps of the replace check (names ``gate: g5 ...``): claims'
    --readme written before its --out was refused; region_volumes --view and replay --out
    replacing any file; a --view that is also a --plot output; a figure whose CSV alone
    differs."""
    readme = write("R.md", "# r\n<!-- claims:begin -->\nold\n<!-- claims:end -->\n")
    notes = write("notes.md", "# someone's notes\n")
    claims = ["--results", str(ROOT / "results"), "--readme", "R.md", "--out", "o"]
    volumes = ["--regions", "farbox", "--joints", "3", "--samples", "200"]
    replay = ["run/s0", "--episodes", "1", "--no-progress"]
    return [
        cli("gate: g5 claims --readme with an --out holding another table", "analysis.claims",
            4, claims, "usage", ["would replace", "o/claims.md"],
            setup=lambda d: (readme(d), write("o/claims.md", "another\n")(d))[-1]),
        cli("gate: g5 claims --readme with an --out that is a file", "analysis.claims", 4,
            claims, "usage", ["--out", "not a folder"],
            setup=lambda d: (readme(d), write("o", "a file\n")(d))[-1]),
        cli("gate: g5 claims --readme and a new --out", "analysis.claims", 4, claims, "ok",
            setup=readme),
        cli("gate: g5 region_volumes --view over a file that is not a page",
            "analysis.region_volumes", 4, [*volumes, "--view", "notes.md"], "usage",
            ["would replace", "notes.md", "--force"], setup=notes),
        cli("gate: g5 region_volumes --view --force over a file that is not a page",
            "analysis.region_volumes", 4, [*volumes, "--view", "notes.md", "--force"], "ok",
            setup=notes),
        cli("gate: g5 region_volumes --view over its own page", "analysis.region_volumes", 4,
            [*volumes, "--view", "v.html"], "ok",
            setup=_ran("analysis.region_volumes", [*volumes, "--view", "v.html"])),
        cli("gate: g5 region_volumes --view that is --plot's JSON", "analysis.region_volumes",
            4, [*volumes, "--view", "v.json", "--plot", "v.png"], "usage", ["--view", "v.json"]),
        cli("gate: g5 replay --out over a file that is not a page", "analysis.replay", 4,
            [*replay, "--out", "notes.md"], "usage", ["would replace", "notes.md", "--force"],
            setup=lambda d: (copy_run(fix)(d), notes(d))[-1]),
        cli("gate: g5 replay --out over its own page", "analysis.replay", 4,
            [*replay, "--out", "r.html"], "ok",
            setup=lambda d: (copy_run(fix)(d),
                             _ran("analysis.replay", [*replay, "--out", "r.html"])(d))[-1]),
        cli("gate: g5 curves over its own figure, its CSV another", "analysis.curves", 4,
            ["run", "--out", "c.png"], "usage", ["would replace", "c.csv"],
            setup=lambda d: (copy_run(fix)(d), _ran("analysis.curves", ["run", "--out", "c.png"],
                                                    write("c.csv", "someone else's\n"))(d))[-1]),
    ] + [api(f"gate: g5 curves --force, the CSV's write failing ({f}) after the figure's",
             "analysis.curves", 6, _written_halfway(f), "ok",
             setup=lambda d: (copy_run(fix)(d), write("o/c.png", "someone's figure")(d),
                              write("o/c.csv", "someone's table\n")(d))[-1])
         for f in ("full", "ctrl-c", "unreadable")]
def _numba_copies_step_as_the_original(_: Path) -> None:
    """NumbaDynamics builds its kernel's argument tuple once (the state arrays, written in
    place): a deep copy, a pickled copy and a copy reset between steps must step as a fresh one."""
    import copy
    import pickle

    from envs.physics.numba_kernel import NumbaDynamics
    from envs.spec import make_task
    task = make_task(None, dict(region="farbox", n_joints=3))
    fresh, used = NumbaDynamics(task, 2), NumbaDynamics(task, 2)
    for _ in range(3):
        used.step(np.full((2, 3), -0.4))
    used.reset(np.asarray(task.start_q))
    for dyn in (fresh, used, copy.deepcopy(fresh), pickle.loads(pickle.dumps(fresh))):
        for _ in range(2):
            dyn.step(np.full((2, 3), 0.3))
    for dyn in (used, copy.deepcopy(fresh), pickle.loads(pickle.dumps(fresh))):
        _check(np.array_equal(dyn.q, fresh.q) and np.array_equal(dyn.tool, fresh.tool),
               "a copy or a reset NumbaDynamics does not step as a fresh one")


def _copied_vector_env_steps_as_the_original(_: Path) -> None:
    """A deep copy and a pickle of UR5Reach-v0's vector env step as the original does."""
    import copy
    import pickle
    env = gymnasium.make_vec("UR5Reach-v0", num_envs=2, vectorization_mode="vector_entry_point",
                             dynamics="numba", region="farbox", n_joints=3)
    env.reset(seed=0)
    copies, action = [copy.deepcopy(env), pickle.loads(pickle.dumps(env))], np.full((2, 3), 0.3)
    want = env.step(action)[0]["observation"]
    _check(all(np.array_equal(c.step(action)[0]["observation"], want) for c in copies),
           "a copied UR5Reach-v0 vector env observes another state than the original")


def gate5t_cases(fix: Path) -> list[Case]:
    """This session's cuts seen by a hostile user of the training side (names ``gate: g5t
    ...``): the stack twin's Gymnasium reset, copies of the numba dynamics, one folder for
    two units however it is spelled."""
    def stack_reset(_: Path) -> Any:
        return gymnasium.make_vec("UR5StackReach-v0", num_envs=2,
                                  vectorization_mode="vector_entry_point",
                                  tasks=[dict(region="farbox", n_joints=3)]).reset(seed=0)
    out = [api("gate: g5t make_vec('UR5StackReach-v0').reset(seed=0)", "StackReach.reset", 6,
               stack_reset, "usage", ["reset_where", "draw_goals"]),
           api("gate: g5t NumbaDynamics copied or reset steps as a fresh one", "NumbaDynamics",
               8, _numba_copies_step_as_the_original, "ok"),
           api("gate: g5t a deep-copied or pickled UR5Reach-v0 vector env steps as the original",
               "BatchedReach", 8, _copied_vector_env_steps_as_the_original, "ok")]
    for backend in ("numpy", "program"):
        for a, b in (("x", "./x/"), ("x --seeds 0 1", "x/s0")):
            out.append(cli(f"gate: g5t train_many --dry-run {backend} --out {a} and --out {b}",
                           "ddpg_her.train_many", 3, [
                               "--dry-run", "--env-backend", backend, "--unit",
                               f"--region farbox --out {a}", "--unit",
                               f"--region closebox --out {b}"], "usage",
                           ["would all train in", "--out"]))
    return out


def _check(ok: bool, what: str) -> None:
    if not ok:
        raise WrongAnswer(what)


def _fk_batch_matches_rows(_: Path) -> None:
    import numpy as np

    import ur5kin
    q = np.random.default_rng(0).uniform(-3, 3, (5, 6))
    _check(np.allclose(ur5kin.fk(q), np.stack([ur5kin.fk(r) for r in q]), atol=1e-12),
           "fk of a batch differs from fk of its rows")


def _fk_of_empty(_: Path) -> None:
    import numpy as np

    import ur5kin
    _check(ur5kin.fk(np.zeros((0, 6))).shape == (0, 3), "fk of (0, 6) is not (0, 3)")


def _sampled_goals_lie_in_the_region(_: Path) -> None:
    import numpy as np

    import regions
    import ur5kin
    region = regions.get("farbox")
    sampler = regions.JointSpaceSampler(region, 3, regions.default_start("farbox"))
    batch = sampler.sample(20, np.random.default_rng(1))
    _check(bool(region.contains(batch.goals).all()), "a sampled goal lies outside its region")
    _check(np.allclose(ur5kin.fk_world(batch.q, regions.DEFAULT_BASE_HEIGHT), batch.goals,
                       atol=1e-9), "a sampled goal is not where fk puts its q")


def _reach_env(**kwargs: Any) -> Any:
    import gymnasium

    import envs  # noqa: F401  (registers the ids)
    return gymnasium.make("UR5Reach-v0", region="farbox", n_joints=3, **kwargs)


def _reset_env(**kwargs: Any) -> Any:
    env = _reach_env(**kwargs)
    env.reset(seed=0)
    return env


def _step(action: Any) -> Callable[[Path], Any]:
    return lambda _: _reset_env().step(action)


def _reset_with(options: Any) -> Callable[[Path], Any]:
    return lambda _: _reach_env().reset(seed=0, options=options)


def _reward(achieved: Any, desired: Any, info: Any) -> Callable[[Path], Any]:
    return lambda _: _reach_env().unwrapped.compute_reward(achieved, desired, info)


def _invariant(_: Path) -> None:
    """The GoalEnv invariant: the reward of a step equals compute_reward of its goals."""
    import numpy as np
    env = _reset_env()
    obs, reward, *_, info = env.step(np.array([0.1, -0.2, 0.3]))
    again = env.unwrapped.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
    _check(math.isclose(float(again), reward, rel_tol=1e-12), f"{again} != {reward}")


def _reset_to_given_goal(_: Path) -> None:
    import numpy as np
    obs, _info = _reach_env().reset(seed=0, options={"goal": [0.5, 0.2, 0.5]})
    _check(np.allclose(obs["desired_goal"], [0.5, 0.2, 0.5]), "the given goal was not used")


def _vec(options: Any = None, action: Any = None, num_envs: int = 2) -> Callable[[Path], Any]:
    def call(_: Path) -> Any:
        import gymnasium
        import numpy as np

        import envs  # noqa: F401
        env = gymnasium.make_vec("UR5Reach-v0", num_envs=num_envs, region="farbox",
                                 n_joints=3, vectorization_mode="vector_entry_point")
        env.reset(seed=0, options=options)
        if action is not None:
            env.step(np.asarray(action, dtype=float) if not isinstance(action, str) else action)
    return call


def _load(rel: str, **kwargs: Any) -> Callable[[Path], Any]:
    def call(case_dir: Path) -> Any:
        import ddpg_her
        return ddpg_her.load(case_dir / rel, **kwargs)
    return call


def _policy_acts_twice_the_same(case_dir: Path) -> None:
    import numpy as np

    import ddpg_her
    policy = ddpg_her.load(case_dir / "run" / "s0")
    env = policy.make_env()
    obs, _ = env.reset(seed=3)
    a, b = policy(obs), policy(obs)
    _check(a.shape == (3,) and np.array_equal(a, b) and np.isfinite(a).all(),
           f"policy actions {a} {b}")


def _policy_bad_obs(obs: Callable[[Any], Any]) -> Callable[[Path], Any]:
    def call(case_dir: Path) -> Any:
        import ddpg_her
        policy = ddpg_her.load(case_dir / "run" / "s0")
        good, _ = policy.make_env().reset(seed=0)
        return policy(obs(good))
    return call


def api_cases(fix: Path) -> list[Case]:
    """Kind 8 (and 6 for ``ddpg_her.load``): the library's public entry points."""
    import numpy as np
    nan, inf = float("nan"), float("inf")

    def fk(q: Any) -> Callable[[Path], Any]:
        return lambda _: __import__("ur5kin").fk(q)

    def reg(fn: str, *args: Any, **kwargs: Any) -> Callable[[Path], Any]:
        return lambda _: getattr(__import__("regions"), fn)(*args, **kwargs)

    def sampler(cls: str, region: str = "farbox", n: Any = 3, start: Any = None,
                **kwargs: Any) -> Callable[[Path], Any]:
        def call(_: Path) -> Any:
            import regions
            return getattr(regions, cls)(regions.parse(region), n,
                                         regions.default_start("farbox") if start is None
                                         else start, **kwargs)
        return call

    def sample(n: Any, rng: Any = None) -> Callable[[Path], Any]:
        def call(_: Path) -> Any:
            import regions
            s = regions.JointSpaceSampler(regions.get("farbox"), 3,
                                          regions.default_start("farbox"))
            return s.sample(n, np.random.default_rng(0) if rng is None else rng)
        return call

    out = [
        api("fk(None)", "ur5kin.fk", 8, fk(None), "usage", "q"),
        api("fk('abc')", "ur5kin.fk", 8, fk("abc"), "usage", "abc"),
        api("fk of 5 angles", "ur5kin.fk", 8, fk([0.0] * 5), "usage", "6"),
        api("fk of 7 angles", "ur5kin.fk", 8, fk([0.0] * 7), "usage", "6"),
        api("fk of NaN", "ur5kin.fk", 8, fk([nan] * 6), "usage", "nan"),
        api("fk of inf", "ur5kin.fk", 8, fk([0, 0, inf, 0, 0, 0]), "usage", "inf"),
        api("fk of shape (2, 5)", "ur5kin.fk", 8, fk(np.zeros((2, 5))), "usage", "(2, 5)"),
        api("fk of complex", "ur5kin.fk", 8, fk(np.zeros(6, complex)), "usage", "complex"),
        api("fk of objects", "ur5kin.fk", 8, fk([object()] * 6), "usage", "q"),
        api("fk of a scalar", "ur5kin.fk", 8, fk(0.0), "usage", "6"),
        api("fk of a ragged list", "ur5kin.fk", 8, fk([[0] * 6, [0] * 5]), "usage", "q"),
        api("fk of a batch equals fk of its rows", "ur5kin.fk", 8, _fk_batch_matches_rows,
            "ok"),
        api("fk of an empty batch", "ur5kin.fk", 8, _fk_of_empty, "ok"),
        api("fk_world base_height nan", "ur5kin.fk_world", 8,
            lambda _: __import__("ur5kin").fk_world([0] * 6, nan), "usage", "base_height"),
        api("fk_world base_height -1", "ur5kin.fk_world", 8,
            lambda _: __import__("ur5kin").fk_world([0] * 6, -1.0), "usage", "base_height"),
        api("jacobian of NaN", "ur5kin.jacobian", 8,
            lambda _: __import__("ur5kin").jacobian([nan] * 6), "usage", "nan"),
        api("fk_pose of 3 angles", "ur5kin.fk_pose", 8,
            lambda _: __import__("ur5kin").fk_pose([0] * 3), "usage", "6"),
        api("ik of a NaN pose", "ur5kin.ik", 8,
            lambda _: __import__("ur5kin").ik(np.full((4, 4), nan)), "usage", "pose"),
        api("ik of a (3, 3) pose", "ur5kin.ik", 8,
            lambda _: __import__("ur5kin").ik(np.eye(3)), "usage", "pose"),
        api("regions.get('nowhere')", "regions.get", 8, reg("get", "nowhere"), "usage",
            "nowhere"),
        api("regions.get(None)", "regions.get", 8, reg("get", None), "usage", "None"),
        api("regions.get base_height nan", "regions.get", 8,
            reg("get", "zheight", base_height=nan), "usage", "base_height"),
        api("regions.parse(42)", "regions.parse", 8, reg("parse", 42), "usage", "42"),
        api("regions.parse('')", "regions.parse", 8, reg("parse", ""), "usage", "region"),
        api("regions.parse box of 3 numbers", "regions.parse", 8, reg("parse", "box:1,2,3"),
            "usage", "box:1,2,3"),
        api("regions.parse box of letters", "regions.parse", 8,
            reg("parse", "box:a,b,c,d,e,f"), "usage", "box:a,b,c,d,e,f"),
        api("regions.parse box min > max", "regions.parse", 8,
            reg("parse", "box:1,0,0,1,0,1"), "usage", "1"),
        api("regions.parse box of NaN", "regions.parse", 8,
            reg("parse", "box:nan,1,0,1,0,1"), "usage", "nan"),
        api("regions.parse zmax:-1", "regions.parse", 8, reg("parse", "zmax:-1"), "usage",
            "zmax=-1.0"),
        api("regions.parse z:0.5,0.2", "regions.parse", 8, reg("parse", "z:0.5,0.2"),
            "usage", "zmin=0.5, zmax=0.2"),
        api("regions.parse bad inline JSON", "regions.parse", 8, reg("parse", "{bad"),
            "usage", "{bad"),
        api("regions.parse JSON of an unknown kind", "regions.parse", 8,
            reg("parse", '{"kind": "nosuch"}'), "usage", "nosuch"),
        api("regions.parse a missing mesh", "regions.parse", 8,
            reg("parse", "mesh:/nonexistent.stl"), "usage", "nonexistent.stl"),
        api("regions.parse a missing JSON file", "regions.parse", 8,
            reg("parse", "json:/nonexistent.json"), "usage", "nonexistent.json"),
        api("regions.parse a JSON file of garbage", "regions.parse", 8,
            reg("parse", f"json:{fix / 'bad.json'}"), "usage", "bad.json"),
        api("region.contains of NaN", "regions.Region.contains", 8,
            lambda _: __import__("regions").get("farbox").contains([[nan, 0, 0]]), "usage",
            "nan"),
        api("region.contains of shape (3, 2)", "regions.Region.contains", 8,
            lambda _: __import__("regions").get("farbox").contains(np.zeros((3, 2))), "usage",
            "(3, 2)"),
        api("JointSpaceSampler n_joints 0", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", n=0), "usage", "n_joints"),
        api("JointSpaceSampler n_joints 7", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", n=7), "usage", "n_joints"),
        api("JointSpaceSampler n_joints 2.5", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", n=2.5), "usage", "n_joints"),
        api("JointSpaceSampler n_joints '3'", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", n="3"), "usage", "n_joints"),
        api("JointSpaceSampler start_q of 5", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", start=(0.0,) * 5), "usage", "start_q"),
        api("JointSpaceSampler start_q NaN", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", start=(nan,) * 6), "usage", "start_q"),
        api("JointSpaceSampler base_height -1", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", base_height=-1.0), "usage", "base_height"),
        api("JointSpaceSampler a region string", "regions.JointSpaceSampler", 8,
            lambda _: __import__("regions").JointSpaceSampler("farbox", 3, (0.0,) * 6),
            "usage", "region"),
        api("JointSpaceSampler unreachable box", "regions.JointSpaceSampler", 8,
            sampler("JointSpaceSampler", region="box:5,6,5,6,5,6"), "usage",
            "box:5,6,5,6,5,6"),
        api("CartesianSampler 2 joints", "regions.CartesianSampler", 8,
            sampler("CartesianSampler", n=2), "usage", "n_joints"),
        api("CartesianSampler wrist_tries 0", "regions.CartesianSampler", 8,
            sampler("CartesianSampler", n=4, wrist_tries=0), "usage", "wrist_tries"),
        api("CartesianSampler unreachable box", "regions.CartesianSampler", 8,
            sampler("CartesianSampler", region="box:5,6,5,6,5,6"), "usage",
            "box:5,6,5,6,5,6"),
        api("sampler.sample(-1)", "regions.GoalSampler.sample", 8, sample(-1), "usage", "-1"),
        api("sampler.sample(1.5)", "regions.GoalSampler.sample", 8, sample(1.5), "usage",
            "1.5"),
        api("sampler.sample(rng=42)", "regions.GoalSampler.sample", 8, sample(3, 42), "usage",
            "rng"),
        api("sampled goals lie in the region at fk(q)", "regions.GoalSampler.sample", 8,
            _sampled_goals_lie_in_the_region, "ok"),
        api("sampler_from_dict(None)", "regions.sampler_from_dict", 8,
            reg("sampler_from_dict", None), "usage", "None"),
        api("sampler_from_dict without region", "regions.sampler_from_dict", 8,
            reg("sampler_from_dict", {"sampler": "joint"}), "usage", "region"),
        api("SamplingLimits probe_hits 0", "regions.SamplingLimits", 8,
            lambda _: __import__("regions").SamplingLimits(probe_hits=0), "usage",
            "probe_hits"),
        api("make region nowhere", "gymnasium.make", 8,
            lambda _: __import__("gymnasium").make("UR5Reach-v0", region="nowhere"), "usage",
            "nowhere"),
        api("make n_joints 7", "gymnasium.make", 8,
            lambda _: __import__("gymnasium").make("UR5Reach-v0", n_joints=7), "usage",
            "n_joints"),
        api("make n_joints 1", "gymnasium.make", 8,
            lambda _: __import__("gymnasium").make("UR5Reach-v0", n_joints=1), "usage",
            "n_joints"),
        api("make an unknown argument", "gymnasium.make", 8,
            lambda _: __import__("gymnasium").make("UR5Reach-v0", nosuch=1), "usage",
            "nosuch"),
        api("make task with an unknown field", "gymnasium.make", 8,
            lambda _: __import__("gymnasium").make("UR5Reach-v0", task={"nosuch": 1}),
            "usage", "nosuch"),
        api("make render_mode nosuch", "gymnasium.make", 8,
            lambda _: _reach_env(render_mode="nosuch"), "usage", "nosuch"),
        api("make unreachable region", "gymnasium.make", 8,
            lambda _: __import__("gymnasium").make("UR5Reach-v0", region="box:5,6,5,6,5,6"),
            "usage", "box:5,6,5,6,5,6"),
        api("reset goal NaN", "env.reset", 8, _reset_with({"goal": [nan, 0, 0.5]}), "usage",
            "goal"),
        api("reset goal under the plane", "env.reset", 8, _reset_with({"goal": [0.5, 0, -0.1]}),
            "usage", "plane"),
        api("reset goal out of reach", "env.reset", 8, _reset_with({"goal": [5.0, 0, 0.5]}),
            "usage", "shoulder"),
        api("reset goal of 2 numbers", "env.reset", 8, _reset_with({"goal": [0.5, 0.5]}),
            "usage", "goal"),
        api("reset goal a string", "env.reset", 8, _reset_with({"goal": "up"}), "usage",
            "up"),
        api("reset options a string", "env.reset", 8, _reset_with("goal"), "usage", "options"),
        api("reset options an unknown key", "env.reset", 8, _reset_with({"nosuch": 1}),
            "usage", "nosuch"),
        api("reset to a given goal uses it", "env.reset", 8, _reset_to_given_goal, "ok"),
        api("step NaN", "env.step", 8, _step([nan, 0, 0]), "usage", "nan"),
        api("step inf", "env.step", 8, _step([inf, 0, 0]), "usage", "inf"),
        api("step of 2 numbers", "env.step", 8, _step([0.0, 0.0]), "usage", "3"),
        api("step of shape (1, 3)", "env.step", 8, _step(np.zeros((1, 3))), "usage", "3"),
        api("step None", "env.step", 8, _step(None), "usage", "None"),
        api("step a string", "env.step", 8, _step("abc"), "usage", "abc"),
        api("step complex", "env.step", 8, _step(np.zeros(3, complex)), "usage", "3"),
        api("step before reset", "env.step", 8,
            lambda _: _reach_env().step(np.zeros(3)), "refusal", "reset"),
        api("step 1e6 (clipped to the action space)", "env.step", 8, _step([1e6, 0, 0]), "ok"),
        api("the GoalEnv invariant holds", "env.compute_reward", 8, _invariant, "ok"),
        api("compute_reward infos list too short", "env.compute_reward", 8,
            _reward(np.zeros((3, 3)), np.zeros((3, 3)), [{"action": np.zeros(3)}] * 2),
            "usage", "info['action'] (2, 3)"),
        api("compute_reward without action", "env.compute_reward", 8,
            _reward(np.zeros(3), np.zeros(3), {}), "usage", "action"),
        api("compute_reward info None", "env.compute_reward", 8,
            _reward(np.zeros(3), np.zeros(3), None), "usage", "info"),
        api("compute_reward goals of mismatched shapes", "env.compute_reward", 8,
            _reward(np.zeros((2, 3)), np.zeros((3, 3)), {"action": np.zeros((2, 3))}), "usage",
            "shape"),
        api("compute_reward NaN goal", "env.compute_reward", 8,
            _reward([nan, 0, 0], np.zeros(3), {"action": np.zeros(3)}), "usage", "nan"),
        api("compute_reward goals of 2 numbers", "env.compute_reward", 8,
            _reward(np.zeros(2), np.zeros(2), {"action": np.zeros(3)}), "usage", "3"),
        api("compute_reward action of 2", "env.compute_reward", 8,
            _reward(np.zeros(3), np.zeros(3), {"action": np.zeros(2)}), "usage", "action"),
        api("compute_reward action 1e200", "env.compute_reward", 8,
            _reward(np.zeros(3), np.zeros(3), {"action": np.full(3, 1e200)}), "usage",
            "finite"),
        api("vector reset goal of wrong count", "BatchedReach.reset", 8,
            _vec({"goal": np.zeros((3, 3))}), "usage", "goal"),
        api("vector reset goal out of reach", "BatchedReach.reset", 8,
            _vec({"goal": [[5.0, 0, 0.5], [0.5, 0, 0.5]]}), "usage", "shoulder"),
        api("vector reset_mask of ints", "BatchedReach.reset", 8,
            _vec({"reset_mask": np.array([1, 0])}), "usage", "reset_mask"),
        api("vector step NaN", "BatchedReach.step", 8, _vec(action=[[nan, 0, 0], [0, 0, 0]]),
            "usage", "nan"),
        api("vector step inf", "BatchedReach.step", 8,
            _vec(action=[[0, 0, 0], [0, -inf, 0]]), "usage", "inf"),
        api("vector step one action for two copies", "BatchedReach.step", 8,
            _vec(action=[0.0, 0.0, 0.0]), "usage", "(2, 3)"),
        api("vector num_envs 0", "gymnasium.make_vec", 8, _vec(num_envs=0), "usage",
            "num_envs"),
        api("load a missing folder", "ddpg_her.load", 6, _load("nosuch"), "usage", "nosuch"),
        api("load a folder without spec", "ddpg_her.load", 6,
            lambda _: __import__("ddpg_her").load(fix / "norun"), "usage", "norun"),
        api("load episode=99", "ddpg_her.load", 6, _load("run/s0", episode=99), "usage", "99",
            setup=copy_run(fix)),
        api("load episode=-1", "ddpg_her.load", 6, _load("run/s0", episode=-1), "usage", "-1",
            setup=copy_run(fix)),
        api("load device nosuch", "ddpg_her.load", 6, _load("run/s0", device="nosuch"),
            "usage", "nosuch", setup=copy_run(fix)),
        api("load: the policy acts, the same twice", "ddpg_her.load", 6,
            _policy_acts_twice_the_same, "ok", setup=copy_run(fix)),
        api("policy of an obs without desired_goal", "TrainedPolicy", 6,
            _policy_bad_obs(lambda o: {k: v for k, v in o.items() if k != "desired_goal"}),
            "usage", "desired_goal", setup=copy_run(fix)),
        api("policy of an obs of NaN", "TrainedPolicy", 6,
            _policy_bad_obs(lambda o: {**o, "observation": o["observation"] * nan}), "usage",
            "observation", setup=copy_run(fix)),
        api("policy of an obs of wrong size", "TrainedPolicy", 6,
            _policy_bad_obs(lambda o: {**o, "observation": o["observation"][:4]}), "usage",
            "observation", setup=copy_run(fix)),
    ]
    for name, edit, words in broken_runs():
        if "eval" in name or "region" in name:
            continue  # load reads neither eval.csv nor the env
        # load makes the run's env once (ddpg_her.run.run_task): a spec without env_id is refused
        expected = "usage"
        out.append(api(f"load a run with {name}", "ddpg_her.load", 6, _load("run/s0"),
                       expected, words, setup=copy_run(fix, edit)))
    return out


# ---------------------------------------------------------------------------- kills (kind 1)
def _eval_rows(folder: Path) -> list[dict[str, str]]:
    with open(folder / "eval.csv", newline="") as f:
        return [{k: v for k, v in r.items() if k != "wall_s"} for r in csv.DictReader(f)]


def _kill_case(fix: Path, kind: str, kills: Sequence[tuple[str, Any]]) -> Callable[[Path], Any]:
    """SIGKILL the toy run at each of ``kills`` in turn, then run the same command (it has
    --resume) to the end: each eval.csv must equal the uninterrupted run's (`make_fixtures`) in
    every column but wall_s, with no temporary file left. A kill is ``(moment, N)`` of
    tests/kill_at.py or ``("after_s", seconds)`` (a SIGKILL from outside, at a wall time)."""
    def call(case_dir: Path) -> None:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(TESTS), str(ROOT)])}
        if kind == "train":
            module, args, pairs = "ddpg_her.train", [*TOY, "--out", "run"], [("run", "toy/run")]
        elif kind == "seeds":
            module, args = "ddpg_her.train", [*TOY, "--seeds", "0", "1", "--out", "s{seed}"]
            pairs = [("s0", "toy/s0"), ("s1", "toy/s1")]
        else:
            shutil.copy(fix / "toy" / "plan.json", case_dir / "plan.json")
            module, args = "ddpg_her.train_many", ["--plan", "plan.json", *TOY[-5:]]
            pairs = [("many/u0/s0", "toy/many/u0/s0"), ("many/u1/s1", "toy/many/u1/s1")]
        for moment, n in kills:
            if moment == "after_s":
                proc = subprocess.Popen([sys.executable, "-m", module, *args], env=env,
                                        cwd=case_dir, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL)
                time.sleep(float(n))
                proc.send_signal(signal.SIGKILL)
                proc.wait()
            else:
                done = subprocess.run([sys.executable, str(TESTS / "kill_at.py"), moment,
                                       str(n), module, *args], env=env, cwd=case_dir,
                                      capture_output=True, text=True)
                _check(done.returncode == -signal.SIGKILL,
                       f"{moment} {n}: not killed (exit {done.returncode}) "
                       f"{done.stderr.strip().splitlines()[-1:]}")
        done = subprocess.run([sys.executable, "-m", module, *args], env=env, cwd=case_dir,
                              capture_output=True, text=True)
        if done.returncode != 0:
            lines = done.stderr.strip().splitlines()
            raise RuntimeError(f"the resume ended {done.returncode}: {lines[-1:]}")
        for got, want in pairs:
            _check(_eval_rows(case_dir / got) == _eval_rows(fix / want),
                   f"{got}/eval.csv differs from the uninterrupted run's")
        debris = [str(p) for p in case_dir.rglob(".*.tmp*")]
        _check(not debris, f"temporary files left: {debris}")
    return call


def kill_cases(fix: Path) -> list[Case]:
    """Kills tests/test_kills.py does not make (other counts, other moments per kind, two kills
    in a row, kills from outside at wall times)."""
    plan = [("train", [("chunk_tmp", 2)]), ("train", [("before_ckpt", 2)]),
            ("train", [("after_ckpt", 2)]), ("train", [("ckpt_tmp", 3)]),
            ("train", [("chunk_tmp", 3)]), ("train", [("after_row", 3)]),
            ("train", [("ckpt_tmp", 1), ("ckpt_tmp", 1)]),
            ("train", [("before_ckpt", 1), ("prune", 1)]),
            ("train", [("after_s", 2.5)]), ("train", [("after_s", 3.5)]),
            ("train", [("after_s", 2.0), ("after_s", 3.0)]),
            ("seeds", [("chunk_tmp", 1)]), ("seeds", [("after_row", 1)]),
            ("seeds", [("before_ckpt", 1)]), ("seeds", [("after_s", 4.0)]),
            ("many", [("ckpt_tmp", 1)]), ("many", [("chunk_tmp", 2)]),
            ("many", [("after_row", 2)]), ("many", [("after_s", 4.0)])]
    module = {"train": "ddpg_her.train", "seeds": "ddpg_her.train --seeds 0 1",
              "many": "ddpg_her.train_many"}
    return [api(f"kill {kind} at " + " then ".join(f"{m} {n}" for m, n in kills)
                + ", resume", module[kind], 1, _kill_case(fix, kind, kills), "ok")
            for kind, kills in plan]


# ---------------------------------------------------------------------------- the runner
def snapshot(root: Path) -> dict[str, str]:
    """Every file below ``root`` (relative path -> digest of its bytes)."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and not p.is_symlink():
            try:
                out[str(p.relative_to(root))] = hashlib.sha1(p.read_bytes()).hexdigest()
            except OSError:
                out[str(p.relative_to(root))] = "unreadable"
    return out


def first_message(text: str) -> str:
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return next((ln for ln in lines if "error" in ln.lower()), lines[-1] if lines else "")


def run_in_child(case: Case, case_dir: Path, log: Path, conn: Any) -> None:
    """The forked child: its own session (the parent can kill what it starts), its own
    working folder, stdout/stderr to ``log``; sends (got, message) back."""
    os.setsid()
    os.chdir(case_dir)
    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            if case.argv is not None:
                try:
                    code = importlib.import_module(case.entry).main(list(case.argv))
                except SystemExit as stop:
                    code = stop.code if isinstance(stop.code, int) else \
                        (0 if stop.code is None else 1)
                    if not isinstance(stop.code, int | None):
                        err.write(f"{stop.code}\n")
                if code in (0, None) and case.call is not None:
                    case.call(case_dir)
                result = ("ok", "") if code in (0, None) else \
                    ("usage" if code == 2 else "error", first_message(err.getvalue()))
            else:
                case.call(case_dir)
                result = ("ok", "")
    except WrongAnswer as wrong:
        result = ("wrong", str(wrong))
    except (ValueError, TypeError, FileNotFoundError, gymnasium.error.Error) as exc:
        result = ("usage" if case.argv is None else "traceback",
                  f"{type(exc).__name__}: {exc}" if case.argv is None else
                  traceback.format_exception_only(type(exc), exc)[-1].strip())
    except BaseException as exc:
        result = ("traceback", traceback.format_exception_only(type(exc), exc)[-1].strip())
    conn.send(result)
    conn.close()
    os._exit(0)


def said(words: str, message: str) -> bool:
    """Whether ``message`` holds ``words`` (``a|b``: either), ignoring case."""
    return any(w.lower() in message.lower() for w in words.split("|"))


def verdict(case: Case, got: str, message: str, before: dict[str, str], after: dict[str, str]
            ) -> tuple[str, str]:
    """(verdict, detail) of one case; see the module docstring."""
    debris = [p for p in after if ".tmp" in Path(p).name]
    refused_expected = case.expected in ("usage", "refusal")
    refused = got in ("usage", "error")
    if got in ("traceback", "hang"):
        return got, ""
    if got == "wrong":
        return "silent_wrong", message
    if debris:
        return "silent_wrong", f"temporary files left: {debris[:3]}"
    if refused_expected and refused:
        changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
        if changed:
            return "silent_wrong", f"refused, but wrote or changed {changed[:3]}"
        good = (case.expected == "refusal" or got == case.expected)
        named = all(said(w, message) for w in case.words)
        if good and named:
            return "as_expected", ""
        return ("unclear" if good else "other"), \
            f"message lacks {[w for w in case.words if not said(w, message)]}"
    if refused_expected and got == "ok":
        return "silent_wrong", f"succeeded; wrote {sorted(set(after) - set(before))[:3]}"
    if case.expected == "ok" and got == "ok":
        return "as_expected", ""
    return "other", ""


def main(argv: Sequence[str] | None = None) -> int:
    parser = Parser(prog="python -m benchmarks.reliability_probe",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=Path("results/reliability/probe.csv"),
                        help="the table written (CSV)")
    parser.add_argument("--workers", type=int, default=2,
                        help="cases run at once (count, >= 1)")
    parser.add_argument("--limit-s", type=float, default=180.0,
                        help="a case still running after this many seconds is a hang (s, > 0)")
    parser.add_argument("--only", default=None,
                        help="run only the cases whose name holds this text")
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be a count >= 1; got {args.workers}")
    if not args.limit_s > 0:
        parser.error(f"--limit-s must be > 0 s; got {args.limit_s}")
    args.out = args.out.resolve()
    start = time.monotonic()
    for name in PRELOAD:
        importlib.import_module(name)
    ctx = multiprocessing.get_context("fork")
    rows = []
    with tempfile.TemporaryDirectory(prefix="probe-") as tmp:
        fix, work, logs = Path(tmp) / "fix", Path(tmp) / "cases", Path(tmp) / "logs"
        for d in (fix, work, logs):
            d.mkdir()
        make_fixtures(fix)
        all_cases = [*old_cases(fix), *reader_cases(fix), *train_cases(fix),
                     *study_cases(fix), *api_cases(fix), *kill_cases(fix),
                     *gate_cases(fix), *gate2_cases(fix), *gate3_cases(fix),
                     *gate4_cases(fix), *gate5_cases(fix), *gate5t_cases(fix)]
        names = [c.name for c in all_cases]
        dupes = {n for n in names if names.count(n) > 1}
        if dupes:
            raise SystemExit(f"duplicate case names: {sorted(dupes)}")
        if args.only:
            all_cases = [c for c in all_cases if args.only in c.name]
        fixtures = snapshot(fix)
        pending = list(enumerate(all_cases))
        running: dict[int, tuple[Any, Any, float, dict[str, str]]] = {}
        results: dict[int, tuple[str, str, float, dict[str, str]]] = {}
        while pending or running:
            while pending and len(running) < args.workers:
                i, case = pending.pop(0)
                case_dir = work / f"{i:03d}"
                case_dir.mkdir()
                if case.setup is not None:
                    case.setup(case_dir)
                before = snapshot(case_dir)
                receive, send = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=run_in_child,
                                   args=(case, case_dir, logs / f"{i:03d}.log", send))
                proc.start()
                send.close()
                running[i] = (proc, receive, time.monotonic(), before)
            time.sleep(0.05)
            for i, (proc, receive, t0, before) in list(running.items()):
                elapsed = time.monotonic() - t0
                if receive.poll():
                    try:
                        got, message = receive.recv()
                    except EOFError:
                        got, message = "traceback", f"the case's process died ({proc.exitcode})"
                elif not proc.is_alive():
                    got, message = "traceback", f"the case's process died ({proc.exitcode})"
                elif elapsed > args.limit_s:
                    with contextlib.suppress(ProcessLookupError):
                        os.killpg(proc.pid, signal.SIGKILL)
                    got, message = "hang", f"still running after {args.limit_s:.0f} s"
                else:
                    continue
                proc.join(timeout=30)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)  # what the case left running
                del running[i]
                results[i] = (got, message, elapsed, before)
                case = all_cases[i]
                after = snapshot(work / f"{i:03d}")
                seen, detail = verdict(case, got, message, before, after)
                if snapshot(fix) != fixtures:
                    seen, detail = "silent_wrong", "changed the shared fixtures"
                    fixtures = snapshot(fix)
                rows.append({"case": case.name.replace(tmp, "TMP"), "entry_point": case.entry,
                             "issue_kind": case.kind, "expected": case.expected, "got": got,
                             "verdict": seen,
                             "as_expected": seen == "as_expected",
                             "wall_s": f"{elapsed:.1f}",
                             "message": message.replace(tmp, "TMP")[:300],
                             "detail": detail.replace(tmp, "TMP")[:200], "_i": i})
                print(f"{'ok ' if seen == 'as_expected' else 'BAD'} {elapsed:5.1f}s "
                      f"{case.entry:<24} {case.name}: {got} ({seen}) {message[:100]}",
                      flush=True)
        # chmod'ed folders of the cases must be writable again to be removed
        for d in work.rglob("*"):
            if d.is_dir():
                d.chmod(0o700)
    rows.sort(key=lambda r: r.pop("_i"))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]), lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
    counts = {v: sum(r["verdict"] == v for r in rows)
              for v in ("as_expected", "unclear", "silent_wrong", "traceback", "hang", "other")}
    print(f"{len(rows)} cases in {time.monotonic() - start:.0f} s: {counts} -> {args.out}")
    return 0 if counts["as_expected"] == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
