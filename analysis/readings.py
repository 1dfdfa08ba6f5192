"""The readings of the paper's unstated choices: one named set of ``ddpg_her.train`` arguments
each, in one place for the sensitivity study and the optimality diagnostic (issue 13)."""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

from ddpg_her.units import task_option
from ur5kin.checks import Kind, check_fields, kinds


@dataclass(frozen=True)
class Reading:
    """One reading of the paper's unstated choices: extra ``ddpg_her.train`` arguments."""

    name: str
    """Folder name below the study root: letters, digits, ``_ . -``."""
    args: tuple[str, ...]
    """Arguments appended to every ``ddpg_her.train`` command of the reading."""
    paper: str = ""
    """What the paper says about the choice (its words where it has any)."""
    ours: str = ""
    """The choice this reading makes."""

    def __post_init__(self) -> None:
        check_fields(self, FIELDS, "reading")


READING_NAME = re.compile(r"[A-Za-z0-9_.-]+")
"""Allowed reading names."""

FIELDS = kinds(
    (Kind(f"a name matching {READING_NAME.pattern} (it names a folder)",
          lambda v: READING_NAME.fullmatch(v)), "name"),
    (Kind("a list of ddpg_her.train arguments (strings)", lambda v: isinstance(v, list | tuple)
          and all(isinstance(a, str) for a in v), tuple), "args"),
    (Kind("text (a string)", lambda v: isinstance(v, str)), "paper", "ours"))
"""The reading as a gate record (`ur5kin.checks.check_fields`)."""

READINGS: dict[str, Reading] = {r.name: r for r in (
    Reading("ours", (),
            paper="eq. 2: R = -|fk - goal| - |a|^2 + 100 * 1{reached}, a the desired absolute "
                  "joint angles, no unit; Table I: exploration rate nu = 0.01, undefined; no "
                  "warm-up stated; contact with the plane not described (simulated 'using "
                  "ROS', the simulator not named)",
            ours="the defaults: |a|^2 in rad^2 with weight 1; Gaussian noise of std 0.01 in "
                 "actor units (0.031 rad); 100 warm-up episodes of random actions; any plane "
                 "contact stops the arm for the rest of the control step; the joints not "
                 "controlled locked at their start angles"),
    Reading("actor_penalty", ("--task", "action_penalty_unit=actor"),
            paper="eq. 2's -|a|^2 with a the absolute joint angles; no unit or scale given",
            ours="|a|^2 in the actor's units, (a / pi)^2 per joint (a tenth of the rad^2 "
                 "penalty); all else the defaults"),
    Reading("compliant", ("--task", "contact_model=compliant"),
            paper="an impermeable plane, simulated 'using ROS' (the simulator is not named; "
                  "Gazebo, ROS's usual one, has a compliant contact: the arm is pushed out and "
                  "slides)",
            ours="a compliant penalty contact through the link Jacobians (the arm slides "
                 "along the plane), impermeable to a stated depth; all else the defaults"),
    Reading("gauss02_nowarmup",
            ("--exploration", "gaussian", "--exploration-rate", "0.2", "--warmup-episodes", "0"),
            paper="Table I: exploration rate nu = 0.01, its meaning not stated; no warm-up stated",
            ours="Gaussian noise of std 0.2 in actor units (0.63 rad), no warm-up episodes; "
                 "all else the defaults"),
    Reading("lillicrap_nets", ("--batch-norm", "--critic-l2", "0.01"),
            paper="\"the same actor and critic networks as [Lillicrap et al.] for "
                  "low-dimensional experiments\"; those had batch normalisation (state input, "
                  "all actor layers, critic layers before the action input) and L2 weight "
                  "decay 1e-2 on the critic; Table I lists neither",
            ours="Lillicrap's networks in full: batch normalisation on the input and before "
                 "the ReLUs of the actor's hidden layers and the critic's first (minibatch "
                 "statistics in the update, running statistics for the targets and every "
                 "action taken) and critic weight decay 1e-2; 400-300 ReLU units, the action "
                 "at the critic's second layer and final layers in +-3e-3 are the defaults "
                 "already; all else the defaults"),
)}
"""The study's built-in readings, in report order: ours today and one change each."""


def task_fields(args: Sequence[str]) -> dict[str, Any]:
    """The TaskSpec fields that ``ddpg_her.train`` arguments set (their ``--task`` pairs)."""
    return dict(task_option(value) for flag, value in itertools.pairwise(args) if flag == "--task")


def missing_fields(fields: Iterable[str]) -> list[str]:
    """The names in ``fields`` that this code's TaskSpec does not have (a reading written for
    a field another branch or a later version adds, e.g. ``contact_model``), in their order."""
    import dataclasses

    from envs.spec import TaskSpec

    known = {f.name for f in dataclasses.fields(TaskSpec)}
    return [name for name in dict.fromkeys(fields) if name not in known]


CHOICES: tuple[tuple[str, str, str, str], ...] = (
    ("action penalty's unit", "task", "action_penalty_unit", "command"),
    ("action penalty's weight", "task", "action_weight", "1.0"),
    ("ground contact", "task", "contact_model", "stop"),
    ("held joints", "task", "held_joints", "pd"),
    ("exploration", "agent", "exploration", "gaussian"),
    ("exploration rate (actor units)", "agent", "exploration_rate", "0.01"),
    ("warm-up episodes", "agent", "warmup_episodes", "100"),
    ("batch normalisation", "agent", "batch_norm", "False"),
    ("critic weight decay", "agent", "critic_l2", "0.0"),
)
"""The paper's unstated choices a run's ``spec.json`` records: (name, spec section, field, value
of runs written before the field existed). The last is what such runs did: the penalty in rad^2,
the stop contact and the PD-held joints were the only behaviour before `action_penalty_unit`,
`contact_model` and `held_joints` were fields (docs/design.md, open points 3-6 and Dynamics)."""


def run_choices(spec: dict[str, Any]) -> dict[str, str]:
    """The unstated choices one run was trained under, as text: name -> value.

    spec : a run's ``spec.json`` content (its ``task`` and ``agent`` sections); a field missing
    from an older run reads as the behaviour it had then (`CHOICES`).
    """
    return {name: before if (value := spec.get(section, {}).get(field)) is None else str(value)
            for name, section, field, before in CHOICES}
