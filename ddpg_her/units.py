"""What a unit of training is, for every command that builds one: its settings (`Setting`), the
``--task KEY=VALUE`` pairs and the env fields they give (``ddpg_her.train``), and plan files of
units (``ddpg_her.train_many --plan``, written by ``analysis.sweep``)."""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from ddpg_her.config import AgentConfig
from envs import ENV_IDS
from envs.spec import make_task
from ur5kin.checks import SEED, Kind, check_fields, kinds

DEFAULT_JOINTS = 3
"""Controlled joints when neither --joints nor --task n_joints is given."""

DEFAULT_THREADS = 1
"""torch CPU threads of a training process when --threads is not given (``ddpg_her.train``,
``ddpg_her.train_many``, and each process of the studies). torch's own choice, one per core,
lets two trainers' thread pools fight over the cores: on 2 cores two 200-episode far-box runs
took 303 s each together against 41 s alone, and 48 s together, 43 s alone with one thread each
(issue 37); the networks are too small for more threads to pay (results/throughput)."""


@dataclasses.dataclass(frozen=True)
class Setting:
    """One unit's runs, as one ``ddpg_her.train`` command line asks for them (checked, not
    started): ``gymnasium.make(env_id, **env_kwargs)``, agent ``config``, one run folder per
    seed (``run_dirs[i]`` for ``seeds[i]``)."""

    env_id: str
    env_kwargs: dict[str, Any]
    config: AgentConfig
    seeds: tuple[int, ...]
    run_dirs: tuple[str, ...]
    note: str | None = dataclasses.field(default=None, compare=False)
    """What the command should say about the setting (a budget kept on resume), or None."""

    def __post_init__(self) -> None:
        check_fields(self, SETTING, "unit of training", (
            ("run_dirs", "one run folder per seed", lambda s: len(s.run_dirs) == len(s.seeds)),))
        if self.env_id.rpartition(":")[2] in ENV_IDS:  # the task's own gate, in every path
            make_task(None, self.env_kwargs)
        contradictions(self.config)

    @property
    def name(self) -> str:
        """The task in a few words, for messages: its env kwargs."""
        return ", ".join(f"{k}={v}" for k, v in self.env_kwargs.items())


SETTING = kinds(
    (Kind("an env id (text)", lambda v: isinstance(v, str) and v), "env_id"),
    (Kind("the env's keyword arguments (a dict)", lambda v: isinstance(v, dict)), "env_kwargs"),
    (Kind("an AgentConfig", lambda v: isinstance(v, AgentConfig)), "config"),
    (Kind("one or more distinct seeds, integers >= 0", lambda v: 0 < len(set(v)) == len(v)
          and all(SEED.test(x) for x in v), tuple), "seeds"),
    (Kind("distinct run folders (text)", lambda v: len(set(v)) == len(v) and all(
        isinstance(d, str) and d for d in v), tuple), "run_dirs"))
"""A unit of training as a gate record (`ur5kin.checks.check_fields`): every command that
starts or lists one (train, train_many, sweep and the studies, their dry runs) builds it."""


def contradictions(config: AgentConfig) -> None:
    """Raise ValueError for agent flags that contradict each other: a value given to a flag
    that the others make unused (``--her-k`` without ``--her-strategy future``, ``--ou-theta``
    without ``--exploration ou``, ``--obs-clip`` or ``--norm-eps`` with
    ``--no-normalize-obs``), or a budget whose last episodes no test session would score (the
    run would never count as finished)."""
    default = AgentConfig()
    unused = [
        ("--her-k", config.her_k != default.her_k and config.her_strategy.value != "future",
         f"--her-strategy {config.her_strategy.value} (--her-k counts the copies of 'future')"),
        ("--ou-theta", config.ou_theta != default.ou_theta and config.exploration.value != "ou",
         f"--exploration {config.exploration.value} (--ou-theta is OU noise's)"),
        ("--obs-clip", config.obs_clip != default.obs_clip and not config.normalize_obs,
         "--no-normalize-obs"),
        ("--norm-eps", config.norm_eps != default.norm_eps and not config.normalize_obs,
         "--no-normalize-obs"),
    ]
    for flag, contradicted, other in unused:
        if contradicted:
            raise ValueError(f"{flag} has no effect with {other}; drop one of them")
    if config.episodes % config.eval_every:
        raise ValueError(
            f"--episodes {config.episodes} is not a multiple of --eval-every "
            f"{config.eval_every}: its last {config.episodes % config.eval_every} episode(s) "
            "would have no test session and the run would never count as finished")


def task_fields(region: str, joints: int | None, overrides: Sequence[tuple[str, Any]]
                ) -> dict[str, Any]:
    """The env's keyword arguments from --region, --joints and the --task KEY=VALUE pairs.

    Raises
    ------
    ValueError
        When a field is given twice with different values (``--joints 3 --task n_joints=4``,
        ``--region farbox --task region=zheight``, ``--task a=1 --task a=2``): the run folder
        is named after --region and --joints, so a silent override would mislabel it.
    """
    given: dict[str, tuple[str, Any]] = {"region": ("--region", region)}
    if joints is not None:
        given["n_joints"] = ("--joints", joints)
    for key, value in overrides:
        flag = f"--task {key}={json.dumps(value)}"
        if key in given and not json_equal(given[key][1], value):
            raise ValueError(f"{given[key][0]} and {flag} give the task field {key!r} two "
                             f"values ({given[key][1]!r}, {value!r}); give it once")
        given.setdefault(key, (flag, value))
    fields = {key: value for key, (_, value) in given.items()}
    fields.setdefault("n_joints", DEFAULT_JOINTS)
    return fields


def json_equal(a: Any, b: Any) -> bool:
    """Equality of two values as JSON would store them (tuples are lists)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def task_option(text: str) -> tuple[str, Any]:
    """One ``--task KEY=VALUE``: VALUE read as JSON, else kept as a string."""
    key, sep, value = text.partition("=")
    if not sep or not key.isidentifier():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value


PLAN_KEY = "units"
"""A plan file is a JSON object ``{"units": [[ARG, ...], ...]}``: each unit's ddpg_her.train
arguments as a list of strings."""


def read_plan(path: Path) -> list[list[str]]:
    """The units of a plan file (see `PLAN_KEY`).

    Raises
    ------
    ValueError
        When the file is not JSON of that shape; the message names the file.
    """
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"{path} cannot be read as a plan ({err})") from err
    units = data.get(PLAN_KEY) if isinstance(data, dict) else None
    if not isinstance(units, list) or not all(
            isinstance(u, list) and all(isinstance(a, str) for a in u) for u in units):
        raise ValueError(f"{path}: expected {{\"{PLAN_KEY}\": [[ARG, ...], ...]}}, each unit a "
                         "list of ddpg_her.train arguments")
    return units


def split_passthrough(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """Split a command line at the first ``--``: (own arguments, arguments passed on to every
    unit's ``ddpg_her.train``)."""
    argv = list(argv)
    if "--" in argv:
        cut = argv.index("--")
        return argv[:cut], argv[cut + 1 :]
    return argv, []


def option_dests(parser: argparse.ArgumentParser, args: Sequence[str]) -> list[tuple[str, str]]:
    """(option as typed, its dest) for each option of ``args`` that ``parser`` knows, with
    argparse's unique-prefix abbreviations (``--reg``) resolved as argparse resolves them."""
    strings = parser._option_string_actions
    out = []
    for arg in args:
        if not arg.startswith("-") or arg == "--" or len(arg) < 2:
            continue
        name = arg.partition("=")[0] if arg.startswith("--") else arg
        if name in strings:
            out.append((name, strings[name].dest))
            continue
        if name.startswith("--"):
            dests = {strings[s].dest for s in strings if s.startswith(name)}
            if len(dests) == 1:
                out.append((name, dests.pop()))
    return out


def overrides(parser: argparse.ArgumentParser, own: Sequence[str], added: Sequence[str]
              ) -> list[str]:
    """The options of ``added`` (arguments appended to a unit's command line from outside it)
    that set what the unit's ``own`` arguments set, as typed: appended, they would silently win
    (argparse keeps the last), so every caller refuses them (issue 41: ``train_many -- --region
    zheight`` trained every unit in z-height). ``--seed`` and ``--seeds`` count as one;
    ``--task`` is left to `task_fields`, which refuses a field given two values."""
    alias = {"seed": "seeds"}
    own_dests = {alias.get(d, d) for _, d in option_dests(parser, own)} - {"task"}
    return [flag for flag, dest in option_dests(parser, added)
            if alias.get(dest, dest) in own_dests]


def shared_folders(runs: Iterable[tuple[str | Path, str]]) -> list[str]:
    """One line for each run folder that two or more of ``runs`` ((folder, the run in a few
    words)) would train in, the folders compared resolved: ``A and B would all train in F``."""
    owners: dict[Path, list[str]] = {}
    for folder, name in runs:
        owners.setdefault(Path(folder).resolve(), []).append(name)
    return [f"{' and '.join(names)} would all train in {folder}"
            for folder, names in owners.items() if len(names) > 1]


def write_plan(path: Path, units: Sequence[Sequence[str]]) -> None:
    """Write a plan file that `read_plan` reads back as ``units``."""
    from ddpg_her.runfolder import atomic_write, make_folder

    make_folder(path.parent)
    atomic_write(path, (json.dumps({PLAN_KEY: [list(u) for u in units]}, indent=1) + "\n")
                 .encode())


def check_device(device: str) -> None:
    """Raise ValueError for ``--device cuda`` where torch sees no CUDA device."""
    import torch

    if device == "cuda" and not torch.cuda.is_available():
        raise ValueError("--device cuda: no CUDA device is available to torch")
