"""``python -m ddpg_her.train_many``: many ``ddpg_her.train`` units in one process, stacked.

Each unit is the arguments of one ``ddpg_her.train`` command (task, seeds, agent flags, --out);
the process flags (--device, --threads, --resume, progress, TensorBoard) are given once, here.
Units of one layout and agent configuration share one stacked agent; the others train beside
them as further stacks, in turn (see `ddpg_her.multi`). Every run folder is the one the unit's
own ``ddpg_her.train`` command would write, and ``--resume`` continues them.

Examples::

    python -m ddpg_her.train_many --unit="--region farbox --seeds 0 1" --unit="--region zheight"
    python -m ddpg_her.train_many --unit="--region farbox --seeds 0 1" -- --episodes 1000
    python -m ddpg_her.train_many --plan runs/sweep/logs/plan.json --device cuda --resume
    python -m ddpg_her.train_many --unit="--region farbox --joints 6 --seeds 0 1 2" --dry-run
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from ddpg_her import train
from ddpg_her.config import Parser, usage_errors
from ddpg_her.units import option_dests, overrides, read_plan, shared_folders, split_passthrough


def make_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="python -m ddpg_her.train_many",
        description="Train several ddpg_her.train units (settings x seeds) in one process: "
                    "units of one observation/action layout and agent configuration share one "
                    "stacked agent, the others form further stacks trained in turn. Each run "
                    "folder is the one the unit's own ddpg_her.train command writes.",
        epilog="Arguments after -- are appended to every unit (e.g. -- --episodes 1000). A "
               "unit's own --device, --env-backend, --threads, --resume, --no-progress or "
               "--no-tensorboard is an error: give them once, to this command.")
    parser.add_argument("--unit", type=unit_arguments, action="append", default=[],
                        metavar="ARGS",
                        help="one ddpg_her.train command line without 'python -m "
                             "ddpg_her.train', shell-quoted, e.g. --unit='--region farbox "
                             "--seeds 0 1'; repeatable")
    parser.add_argument("--plan", type=Path, action="append", default=[],
                        help="a JSON file {\"units\": [[ARG, ...], ...]} of units (as "
                             "analysis.sweep writes it); repeatable, adds to --unit")
    parser.add_argument("--resume", action="store_true",
                        help="continue the units' runs from their last checkpoints; finished "
                             "units are skipped (a folder that does not exist starts afresh)")
    train.add_process_flags(parser, what="every stack's networks and replay buffers")
    parser.add_argument("--dry-run", action="store_true",
                        help="print one line per run (status, stack, folder) and each stack's "
                             "agents, and exit without training")
    return parser


def settings_of(units: Sequence[Sequence[str]], resume: bool = False,
                common: Sequence[str] = ()):
    """The `ddpg_her.units.Setting` of each unit, parsed by ddpg_her.train's parser with
    ``common`` appended (the arguments after ``--``; with ``resume``, a unit without
    --episodes keeps the budget its run folders record).

    Raises
    ------
    ValueError
        When a unit does not parse, gives a process flag (any value, the default too: the
        process's own would silently replace it), has an option of ``common`` of its own (a
        unit's own arguments are never overridden, `ddpg_her.units.overrides`), or asks for an
        invalid run; the message names the unit and the flag.
    """
    unit_parser = train.make_parser()
    out = []
    for i, unit in enumerate(units, start=1):
        where = f"unit {i} ({shlex.join(unit)})"
        process = [flag for flag, dest in option_dests(unit_parser, [*unit, *common])
                   if dest in train.PROCESS_FLAGS]
        if process:
            raise ValueError(f"{where} sets the process flag(s) {', '.join(process)}; give "
                             "them once, to ddpg_her.train_many")
        over = overrides(unit_parser, unit, common)
        if over:
            raise ValueError(f"{where}: {', '.join(over)} after -- would replace the unit's "
                             "own value; a unit's own arguments are never overridden (give "
                             "it in the units that lack it)")
        try:
            args = train.parse_args(unit_parser, [*unit, *common])
        except SystemExit:
            raise ValueError(f"{where} is not a ddpg_her.train command line (see above)"
                             ) from None
        try:
            out.append(train.request(args, resume=resume))
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from None
    return out


def unit_arguments(text: str) -> list[str]:
    """One ``--unit``'s command line split like a shell's; argparse's error naming it when it
    cannot be split (an unclosed quote, a trailing escape)."""
    try:
        return shlex.split(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be split like a shell line "
                                         f"({err}); quote each argument whole") from None


def main(argv: Sequence[str] | None = None) -> int:
    started = time.monotonic()  # --budget-seconds counts from here
    own, common = split_passthrough(sys.argv[1:] if argv is None else argv)
    parser = make_parser()
    train.refuse_removed(parser, own)
    args = parser.parse_args(own)
    args.started = started
    train.check_process_flags(parser, args)
    units = list(args.unit)
    for path in args.plan:
        with usage_errors(parser, ValueError):
            units += read_plan(path)
    if not units:
        parser.error("give one or more --unit or --plan")
    with usage_errors(parser, ValueError):
        settings = settings_of(units, resume=args.resume, common=common)
    for line in shared_folders((d, f"{s.name} seed={seed}") for s in settings  # dry run too
                               for seed, d in zip(s.seeds, s.run_dirs, strict=True)):
        parser.error(f"{line}; give each unit its own --out")

    import gymnasium

    from ddpg_her.multi import group_settings, layout
    from ddpg_her.runfolder import run_status

    train.register_envs(parser, sorted({s.env_id for s in settings}))
    status = [[run_status(d, s.config.episodes) for d in s.run_dirs] for s in settings]
    pending = [not args.resume or any(st != "done" for st in sts) for sts in status]
    todo = [s for s, p in zip(settings, pending, strict=True) if p]
    device, tf32 = args.device, args.tf32
    try:  # the dry run refuses what the real run refuses, with its message (issue 41)
        train.check_device(args.device)
    except ValueError as err:
        if not args.dry_run:
            parser.error(str(err))
        print(f"note: {err}: the real run here would refuse; listed as a machine with one "
              "would run it", file=sys.stderr)
        device, tf32 = "cpu", False
    with usage_errors(parser, ValueError):
        if args.env_backend == "program" and todo:
            train.check_stack(todo, device, tf32)
    if args.dry_run:
        try:  # each unit's task built as the real run builds it (one stack groups none)
            for s in todo if args.env_backend != "program" else ():
                layout(s.env_id, s.env_kwargs)
            groups = group_settings(todo, args.resume, args.env_backend)
        except (ValueError, TypeError, gymnasium.error.Error) as e:
            parser.error(f"{type(e).__name__}: {e}")
        stack = {id(s): g for g, group in enumerate(groups, start=1) for s in group}
        for s, sts in zip(settings, status, strict=True):
            where = f"stack={stack[id(s)]}" if id(s) in stack else "skipped"
            for seed, d, st in zip(s.seeds, s.run_dirs, sts, strict=True):
                print(f"{st:<6} {where} {s.name} seed={seed} {d}")
        print(f"{sum(len(s.seeds) for s in settings)} runs in {len(settings)} units; "
              f"{sum(len(s.seeds) for s in todo)} to train in one process as "
              f"{len(groups)} stack(s) of "
              f"{', '.join(str(sum(len(s.seeds) for s in g)) for g in groups) or 'no'} agents",
              file=sys.stderr)
        return 0
    for s, p in zip(settings, pending, strict=True):
        if not p:
            print(f"{s.name}: finished, skipped", file=sys.stderr)
    if not todo:
        return 0
    train.start_process(parser, args)
    command = ["python", "-m", "ddpg_her.train_many",
               *(argv if argv is not None else sys.argv[1:])]
    trainer = train.build(parser, args, todo, command)
    print(f"{trainer.agents} agents of {len(todo)} units in {len(trainer.groups)} stack(s): "
          + ", ".join(f"{t.k}" for t in trainer.trainers), file=sys.stderr)
    return train.run_to_end(trainer, named=True)


if __name__ == "__main__":
    sys.exit(main())
