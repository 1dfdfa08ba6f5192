"""``python -m ddpg_her.train``: train DDPG + HER agents on the UR5 Reacher, one run folder each.

Examples::

    python -m ddpg_her.train --region farbox --joints 3 --seed 0 --episodes 1500
    python -m ddpg_her.train --region farbox --joints 3 --seeds 0 1 2 3 4   # 5 agents at once
    python -m ddpg_her.train --region farbox --joints 3 --seed 0 --resume   # continue a run
"""

from __future__ import annotations

import argparse
import dataclasses
import enum
import json
import os
import re
import sys
import time
import typing
from collections.abc import Sequence
from typing import Any

from ddpg_her.config import COMBINATIONS, VALID, AgentConfig, Parser, field_docs, usage_errors
from ddpg_her.units import DEFAULT_JOINTS, Setting, check_device, task_fields, task_option

DEFAULT_OUT = "runs/{region}-j{joints}-s{seed}"


def _add_config_flags(group: argparse._ArgumentGroup) -> None:
    """One flag per AgentConfig field, its docstring as help."""
    docs = field_docs(AgentConfig)
    hints = typing.get_type_hints(AgentConfig)
    for f in dataclasses.fields(AgentConfig):
        flag = "--" + f.name.replace("_", "-")
        kind = hints[f.name]
        valid = ", and ".join([VALID[f.name].words,
                               *(w for n, w, _ in COMBINATIONS if n == f.name)])
        help_text = f"{docs[f.name]} Valid: {valid}.".replace("%", "%%") + " (default: %(default)s)"
        if kind is bool:
            group.add_argument(flag, action=argparse.BooleanOptionalAction, default=f.default,
                               help=help_text)
        elif isinstance(kind, type) and issubclass(kind, enum.Enum):
            group.add_argument(flag, choices=[e.value for e in kind], default=f.default.value,
                               help=help_text)
        elif typing.get_origin(kind) is tuple:
            group.add_argument(flag, type=int, nargs=len(typing.get_args(kind)),
                               default=list(f.default), metavar="N", help=help_text)
        else:
            group.add_argument(flag, type=kind, default=f.default, help=help_text)


def _task_fields_help() -> str:
    """``--help``'s list of the fields ``--task KEY=VALUE`` sets, with their defaults."""
    from envs.spec import TaskSpec  # a plain record: no Pinocchio, --help stays fast

    fields = ", ".join(f"{f.name}={f.default!r}" for f in dataclasses.fields(TaskSpec))
    return (f"Task fields for --task KEY=VALUE (UR5Reach-v0's envs.TaskSpec), with their "
            f"defaults: {fields}. Each field's unit, range and reason: help(envs.TaskSpec) or "
            "docs/design.md.")


def add_process_flags(group: Any, what: str) -> None:
    """The flags of the training process (`PROCESS_FLAGS` but --resume), shared by
    ``ddpg_her.train`` and ``ddpg_her.train_many``; ``what`` says what --device holds."""
    group.add_argument("--device", choices=["cpu", "cuda"], default="cpu",
                       help=f"torch device of {what} (default: cpu); runs are bitwise "
                            "repeatable on the CPU")
    group.add_argument("--env-backend", choices=["numpy", "batched", "program"],
                       default="numpy",
                       help="where the envs live (default: numpy): 'numpy', Gymnasium's envs "
                            "on the host, one group per agent; 'batched', the same envs with "
                            "the copies of all agents whose tasks differ only in their goals "
                            "(region, sampler) in one vector env (UR5Reach-v0: one compiled "
                            "call per step for all of them; the same goals and exploration as "
                            "'numpy', trajectories equal to rounding). 'program': the training "
                            "program "
                            "(ddpg_her.program; DDPG + HER, UR5Reach-v0 with the stop contact, "
                            "locked held joints and the joint goal sampler): every agent of "
                            "the process, whatever its task and joint count, as one stack on "
                            "--device, each episode a few device steps (CUDA graphs on cuda) "
                            "with no host read; goals, exploration and minibatches from "
                            "counter-based streams (spec.json's 'program'), so a seed trains "
                            "otherwise than under the other backends, and alike alone or in "
                            "any stack")
    add_window_flags(group, "--env-backend program", "--episodes-choices")
    group.add_argument("--episodes-choices", type=int, nargs="+", default=None, metavar="N",
                       help="with --budget-seconds: the budgets (episodes, multiples of "
                            "--eval-every) to choose among; the largest must be --episodes "
                            "(default: --episodes and its half, quarter and eighth where they "
                            "are multiples of --eval-every, e.g. 20000 10000 5000 2500)")
    group.add_argument("--threads", type=int, default=None,
                       help="torch CPU threads (count, 1..the cores; default: 1, which keeps a "
                            "fair share of the cores when other work runs and is about as fast "
                            "alone: ddpg_her.units.DEFAULT_THREADS)")
    group.add_argument("--no-progress", action="store_true", help="no progress bar")
    group.add_argument("--no-tensorboard", action="store_true",
                       help="no TensorBoard logs even when tensorboard is installed")


def add_window_flags(group: Any, program: str, choices: str) -> None:
    """--tf32, --window, --budget-seconds (also analysis.sweep's): ``program`` says how the
    command selects the program, ``choices`` the budgets that --budget-seconds chooses among."""
    group.add_argument("--tf32", action="store_true",
                       help=f"with {program} on cuda: let the matrix products round their "
                            "operands to TF32 (10-bit mantissas; faster on Ampere and later, "
                            "recorded in spec.json). Off by default until its effect on "
                            "learning is measured")
    group.add_argument("--window", action="store_true",
                       help=f"with {program}: a run for one GPU window, whose replay buffers "
                            "cannot leave the machine: eval.csv at every test session and the "
                            "actors and normalisers at the end (ddpg_her.load reads them), but "
                            "no replay-buffer chunks and no checkpoints before the end, so the "
                            "run CANNOT BE RESUMED (spec.json records program.window; --resume "
                            "of it is refused)")
    group.add_argument("--budget-seconds", type=float, default=None, metavar="S",
                       help="with --window: wall seconds (> 0) from the training command's "
                            "start (imports, compiling and warm-up included) that the training "
                            "may take; from the second test session on, each session measures "
                            "the last interval's seconds per episode and trains the largest of "
                            f"{choices} projected to end within S (or the smallest left when "
                            "none is), says so on stderr and records it in spec.json "
                            "(agent.episodes, program.budget)")


def check_window_flags(parser: argparse.ArgumentParser, args: argparse.Namespace,
                       program: str) -> None:
    """Refuse the `add_window_flags` given without the program (``program``) or --window."""
    for flag, given in (("--tf32", args.tf32), ("--window", args.window)):
        if given and args.env_backend != "program":
            parser.error(f"{flag} is a setting of {program}")
    if args.budget_seconds is not None and not (args.window and args.budget_seconds > 0):
        parser.error(f"--budget-seconds {args.budget_seconds}: a time budget is a --window "
                     "run's, in seconds > 0")


def make_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m ddpg_her.train",
        description="Train DDPG + HER (Lewis, Moll, Kavraki 2019, Table I) on a goal-reaching "
                    "task. Every --eval-every training episodes, --eval-episodes test episodes "
                    "of the deterministic policy; each seed's run folder gets spec.json, "
                    "eval.csv (episode, successes, tests, mean_return, mean_final_distance_m, "
                    "env_steps, wall_s) and checkpoints.",
        epilog=_task_fields_help(),
    )
    task = parser.add_argument_group("task")
    task.add_argument("--region", required=True,
                      help="goal constraint region: a name (unconstrained, zheight, closebox, "
                           "farbox, farbox_tall) or a spec such as box:... (see regions.parse)")
    from envs.spec import N_JOINTS_RANGE  # numpy and gymnasium only: --help stays fast

    lo, hi = N_JOINTS_RANGE
    task.add_argument("--joints", type=int, default=None, choices=range(lo, hi + 1),
                      metavar=f"{{{lo}..{hi}}}",
                      help=f"controlled joints n, {lo}..{hi}; joints 1..n move (default: "
                           f"{DEFAULT_JOINTS}, or the --task n_joints=N given)")
    task.add_argument("--task", type=task_option, action="append", default=[],
                      metavar="KEY=VALUE",
                      help="override a field of the task specification (VALUE read as JSON, "
                           "else as a string); repeatable, e.g. --task reward_type=sparse; a "
                           "field given twice (also as --region or --joints) must have one "
                           "value")
    task.add_argument("--env-id", default="UR5Reach-v0",
                      help="Gymnasium id of the goal env; 'module:Id' imports module first "
                           "(default: %(default)s)")

    run = parser.add_argument_group("run")
    seeds = run.add_mutually_exclusive_group()
    seeds.add_argument("--seed", type=int, default=0, help="seed of the run (default: 0)")
    seeds.add_argument("--seeds", type=int, nargs="+", metavar="SEED",
                       help="train one independent agent per seed in this process, batched")
    run.add_argument("--out", default=None,
                     help="run folder; may use {region}, {joints}, {seed}. Default "
                          f"{DEFAULT_OUT}, with -algo=A and -KEY=VALUE of each --task before "
                          "-s{seed} when given (runs/farbox-j3-algo=td3-s0). With several "
                          "seeds and no {seed} in it, each seed's folder is OUT/s{seed}")
    run.add_argument("--resume", action="store_true",
                     help="continue the run(s) in the run folder(s) from the last checkpoint "
                          "(a folder that does not exist yet starts afresh); the task and agent "
                          "flags must match the run's, except --episodes, which may grow")
    add_process_flags(run, what="networks and replay buffers")

    _add_config_flags(parser.add_argument_group(
        "agent (Table I of the paper, and our choices where it is silent)"))
    return parser


def run_dirs(out: str | None, region: str, joints: int, seeds: Sequence[int],
             differs: Sequence[str] = ()) -> list[str]:
    """The run folder of each seed (see --out). The default folder's name carries ``differs``
    too (e.g. ``algo=td3``, ``contact_model=compliant``: what else makes these runs differ
    from the plain ones), so that they do not land in a plain run's folder."""
    safe = lambda text: re.sub(r"[^A-Za-z0-9_.=-]+", "_", text).strip("_")  # noqa: E731
    safe_region = safe(region) or "region"
    if out is not None and not out.strip():
        raise ValueError("--out '': give a folder (or leave --out out for the default)")
    tag = "".join(f"-{safe(d)}" for d in differs)
    template = out or DEFAULT_OUT.replace("-s{seed}", tag.replace("{", "{{").replace(
        "}", "}}") + "-s{seed}")
    if len(seeds) > 1 and "{seed}" not in template:
        template = template.rstrip("/") + "/s{seed}"
    try:
        dirs = [template.format(region=safe_region, joints=joints, seed=s) for s in seeds]
    except (KeyError, IndexError, ValueError) as err:  # {foo}, {0}, an unmatched brace
        raise ValueError(f"--out {template!r}: the only fields it may use are {{region}}, "
                         f"{{joints}} and {{seed}} (double a literal brace); got "
                         f"{type(err).__name__}: {err}") from None
    long = [part for d in dirs for part in d.split("/") if len(part.encode()) > NAME_MAX]
    if long:
        raise ValueError(f"--out: the folder name {long[0][:40]}... is {len(long[0].encode())} "
                         f"bytes long; file systems allow at most {NAME_MAX}")
    return dirs


NAME_MAX = 255
"""The longest file or folder name (bytes) of Linux's file systems."""


PROCESS_FLAGS = ("resume", "device", "env_backend", "tf32", "window", "budget_seconds",
                 "episodes_choices", "threads", "no_progress", "no_tensorboard")
"""Flags of the process rather than of the runs (``ddpg_her.train_many`` takes them once)."""


REMOVED_FLAGS: dict[str, str] = {
    "--env-backend torch": "--env-backend program (ddpg_her.program: the training program on "
                           "the device)",
    "--env-dynamics": "--env-backend program (its arm: envs.physics.stack)",
    "--update-graph": "--env-backend program (its updates are one captured step)",
}
"""Flags (or flag values) that issue 35's training program replaced -> what replaced them."""


def refuse_removed(parser: argparse.ArgumentParser, argv: Sequence[str] | None) -> None:
    """A usage error naming a flag of `REMOVED_FLAGS` in ``argv`` (default: ``sys.argv[1:]``)
    and what replaced it, where argparse would only say "invalid choice" or "unrecognized"."""
    words = list(sys.argv[1:] if argv is None else argv)
    for i, word in enumerate(words):
        name, eq, value = word.partition("=")
        if not eq and i + 1 < len(words):
            value = words[i + 1]
        for key in (name, f"{name} {value}"):
            if key in REMOVED_FLAGS:
                parser.error(f"{key} was removed (issue 35); use {REMOVED_FLAGS[key]}")


def parse_args(parser: argparse.ArgumentParser, argv: Sequence[str] | None
               ) -> argparse.Namespace:
    """``parser.parse_args(argv)``, noting in ``args.episodes_given`` whether --episodes was
    given: a resume keeps the recorded budget unless it was (see `request`)."""
    refuse_removed(parser, argv)
    args = parser.parse_args(argv, namespace=argparse.Namespace(episodes=None))
    args.episodes_given = args.episodes is not None
    if not args.episodes_given:
        args.episodes = AgentConfig.episodes
    return args


def recorded_budget(dirs: Sequence[str]) -> int | None:
    """The ``agent.episodes`` that the ``spec.json`` of the folders ``dirs`` record, or None
    when none has one yet (an unreadable one is left to the trainer to name).

    Raises
    ------
    ValueError
        When the folders record different budgets.
    """
    from ddpg_her.runfolder import RunFolder, RunFolderError

    found: dict[int, list[str]] = {}
    for d in dirs:
        folder = RunFolder(d)
        if not folder.spec_path.exists():
            continue
        try:
            episodes = folder.read_spec().get("agent", {}).get("episodes")
        except (RunFolderError, AttributeError):
            continue
        if isinstance(episodes, int) and not isinstance(episodes, bool):
            found.setdefault(episodes, []).append(d)
    if len(found) > 1:
        raise ValueError("--resume: the run folders record different budgets ("
                         + "; ".join(f"{n} episodes: {', '.join(ds)}" for n, ds in found.items())
                         + "); give --episodes")
    return next(iter(found), None)


def request(args: argparse.Namespace, resume: bool | None = None) -> Setting:
    """The runs a parsed command line asks for.

    With ``resume`` (default: ``args.resume``) and no --episodes given (see `parse_args`),
    the budget is the one the existing run folders record, not the default.

    Raises
    ------
    ValueError
        When a task field is given twice, n_joints is out of range, seeds repeat, or the agent
        configuration is invalid; the message names the flag and the expected values.
    """
    from envs.spec import FIELDS

    env_kwargs = task_fields(args.region, args.joints, args.task)
    joints = FIELDS["n_joints"]("n_joints", env_kwargs["n_joints"])
    seeds = args.seeds if args.seeds is not None else [args.seed]
    config = AgentConfig(**{f.name: getattr(args, f.name)
                            for f in dataclasses.fields(AgentConfig)})
    differs = [f"{key}={value}" for key, value in args.task if key not in ("region", "n_joints")]
    if config.algo.value != AgentConfig.algo.value:
        differs.insert(0, f"algo={config.algo.value}")
    dirs = run_dirs(args.out, args.region, joints, seeds, differs)
    if len(seeds) > 1 and args.out and "{seed}" not in args.out:
        from ddpg_her.runfolder import RunFolder

        if RunFolder(args.out.format(region=args.region, joints=joints, seed=seeds[0])
                     ).spec_path.exists():
            raise ValueError(f"--out {args.out} holds a run of one seed; --seeds "
                             f"{' '.join(map(str, seeds))} would train each seed in "
                             f"{args.out}/s{{seed}} beside it (its seed counted twice); give "
                             "another --out")
    note = None
    if (args.resume if resume is None else resume) and not getattr(args, "episodes_given", True):
        budget = recorded_budget(dirs)
        if budget is not None and budget != config.episodes:
            config = dataclasses.replace(config, episodes=budget)
            note = (f"--resume: training to the {budget} episodes that spec.json records "
                    "(give --episodes to extend the run)")
    return Setting(args.env_id, env_kwargs, config, tuple(seeds), tuple(dirs), note)


def build(parser: argparse.ArgumentParser, args: argparse.Namespace,
          settings: Sequence[Setting], command: Sequence[str]) -> Any:
    """The `ddpg_her.multi.MultiTrainer` of every run of ``settings`` under the process flags
    ``args`` (with ``--env-backend program`` one stack: a usage error when the settings'
    agent configurations or env ids differ, or the program refuses them); a setup it refuses
    (bad task, env id or run folders) becomes a usage error through ``parser``."""
    import gymnasium  # late, as in main: --help stays fast

    from ddpg_her.multi import MultiTrainer

    program: dict[str, Any] = {}
    if args.env_backend == "program":
        with usage_errors(parser, ValueError):
            check_stack(settings, args.device, args.tf32)
        from ddpg_her.loop import Budget

        budget = None
        if args.budget_seconds is not None:
            config = settings[0].config
            choices = args.episodes_choices or [config.episodes >> i for i in range(4) if not (
                config.episodes % (1 << i) or (config.episodes >> i) % config.eval_every)]
            budget = Budget(args.budget_seconds, tuple(sorted(set(choices), reverse=True)),
                            args.started)
        program = dict(tf32=args.tf32, window=args.window, budget=budget)
    try:
        return MultiTrainer(settings, resume=args.resume, device=args.device,
                            env_backend=args.env_backend, progress=not args.no_progress,
                            tensorboard=not args.no_tensorboard, command=command, **program)
    except (ValueError, TypeError, gymnasium.error.Error) as e:
        parser.error(f"{type(e).__name__}: {e}" if not isinstance(e, ValueError) else str(e))


def check_stack(settings: Sequence[Setting], device: str, tf32: bool) -> None:
    """Raise ValueError when the training program would refuse the runs of ``settings`` as one
    stack on ``device``: settings of different env ids or agent configurations, or whatever
    `ddpg_her.program.check` refuses (its message). What ``ddpg_her.train``, ``train_many``
    (its dry run too) and ``analysis.sweep --program`` (its dry run too) check alike."""
    configs = {json.dumps(s.config.to_dict(), sort_keys=True) for s in settings}
    if len(configs) > 1 or len({s.env_id for s in settings}) > 1:
        raise ValueError("--env-backend program trains one stack: every unit needs the same "
                         "env id and agent configuration (flags and --episodes)")
    from ddpg_her.program import check

    check(settings[0].env_id, [s.env_kwargs for s in settings for _ in s.seeds],
          settings[0].config, device, tf32)


def run_to_end(trainer: Any, named: bool = False) -> int:
    """Train ``trainer`` (`build`'s) to its budget, close it and print each run's last test
    session (``named``: after its setting's name); the exit status, 130 when interrupted (what
    is finished is on disk, and ``--resume`` continues).

    A run folder that can no longer be written (full disk, made read-only) ends the process
    with status 1 and a message naming the file and the reason; the last checkpoint written
    stays whole, and ``--resume`` continues from it once the disk is fixed.
    """
    from ddpg_her.loop import Diverged
    from ddpg_her.runfolder import RunFolderWriteError

    try:
        rows = trainer.run()
    except KeyboardInterrupt:
        print("interrupted; continue with the same command and --resume", file=sys.stderr)
        return 130
    except RunFolderWriteError as err:
        print(f"error: {err}. Training stopped; the last checkpoint written is whole: free "
              "space or make the folder writable, then run the same command with --resume",
              file=sys.stderr)
        raise SystemExit(1) from None
    except Diverged as err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(1) from None
    finally:
        trainer.close()
    for group, group_rows in zip(trainer.groups, rows, strict=True):
        for s, setting_rows in zip(group, group_rows, strict=True):
            for seed, d, r in zip(s.seeds, s.run_dirs, setting_rows, strict=True):
                print(f"{s.name + ' ' if named else ''}seed {seed}: {last_session(r)} -> {d}")
    return 0


def check_process_flags(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse a --threads outside 1..cores (10,000 made 19,999 threads), and --tf32 without
    --env-backend program (before any unit is parsed)."""
    cores = os.cpu_count() or 1
    if args.threads is not None and not 1 <= args.threads <= cores:
        parser.error(f"--threads must be in 1..{cores} (this machine's cores), got "
                     f"{args.threads}")
    check_window_flags(parser, args, "--env-backend program")
    if args.episodes_choices is not None and args.budget_seconds is None:
        parser.error("--episodes-choices are the budgets --budget-seconds chooses among")


def start_process(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Apply the process flags to torch: --device cuda needs a device, --threads, and
    deterministic algorithms (runs bitwise repeatable on the CPU)."""
    import torch

    with usage_errors(parser, ValueError):
        check_device(args.device)
    from ddpg_her.units import DEFAULT_THREADS

    torch.set_num_threads(args.threads or DEFAULT_THREADS)
    # use_deterministic_algorithms but inductor's unused flag (1.5 CPU-s); test_ddpg_train guards
    torch._C._set_deterministic_algorithms(True, warn_only=args.device != "cpu")


def register_envs(parser: argparse.ArgumentParser, env_ids: Sequence[str]) -> None:
    """Import the modules that register ``env_ids`` (`ddpg_her.vecenv.register_env`); a usage
    error naming the --env-id when one cannot be imported or Gymnasium has no such id (its
    own error would come later, as a traceback in the commands that do not catch it)."""
    import gymnasium

    from ddpg_her.vecenv import register_env

    for env_id in env_ids:
        try:
            gymnasium.spec(register_env(env_id))
        except ImportError as e:
            parser.error(f"--env-id {env_id}: cannot import the module that registers it "
                         f"({type(e).__name__}: {e})")
        except gymnasium.error.Error as e:
            parser.error(f"--env-id {env_id}: not a registered Gymnasium id ({e})")


def last_session(rows: Sequence[dict[str, Any]]) -> str:
    """One run's last test session as text (its eval rows, as ``Trainer.run`` returns them)."""
    if not rows:
        return "no test session yet"
    r = rows[-1]
    return f"{r['successes']}/{r['tests']} at episode {r['episode']}"


def main(argv: Sequence[str] | None = None) -> int:
    started = time.monotonic()  # --budget-seconds counts from here
    parser = make_parser()
    args = parse_args(parser, argv)
    args.started = started
    check_process_flags(parser, args)
    with usage_errors(parser, ValueError):
        req = request(args)
    if req.note:
        print(req.note, file=sys.stderr)
    from ddpg_her.runfolder import run_status

    done = args.resume and all(run_status(d, req.config.episodes) == "done"
                               for d in req.run_dirs)
    start_process(parser, args)
    register_envs(parser, [args.env_id])
    trainer = build(parser, args, [req], ["python", "-m", "ddpg_her.train",
                                          *(argv or sys.argv[1:])])
    if done:  # said once the record is compared: a run of another agent is refused instead
        print(f"--resume: finished already ({req.config.episodes} episodes in "
              f"{', '.join(map(str, req.run_dirs))}); nothing to train (a larger --episodes "
              "extends it)", file=sys.stderr)
    return run_to_end(trainer)


if __name__ == "__main__":
    sys.exit(main())
