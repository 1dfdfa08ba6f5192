"""The task specification of the UR5 Reacher: every number of the task in one frozen record.

A :class:`TaskSpec` is what a training run records: it is immutable, hashable, checked at
construction, and round-trips through JSON (:meth:`TaskSpec.to_json` / :meth:`TaskSpec.from_json`).
It is a plain record: construction checks types, ranges and choices only, and loads neither
Pinocchio nor meshes. Whether the robot can run the task (start pose within the URDF limits and
clear of the plane, stable gains) is :func:`envs.checks.validate`, which the env calls.
The defaults are docs/design.md's table (the paper's task); every choice the paper leaves open is a
field here, with its reason in the field's docstring.

>>> from envs.spec import TaskSpec
>>> task = TaskSpec(region="farbox", n_joints=3)
>>> task.start_q == TaskSpec(region="zheight").start_q   # the constrained start, resolved
True
>>> TaskSpec.from_json(task.to_json()) == task
True
>>> task.substeps, task.dt
(20, 0.02)
"""

from __future__ import annotations

import dataclasses
import functools
import json
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from regions import registry
from regions.registry import UNCONSTRAINED_REGION, default_start
from regions.samplers import CartesianSampler
from ur5kin import checks as gate
from ur5kin.world import BASE_HEIGHT, DEFAULT_BASE_HEIGHT

if TYPE_CHECKING:
    import regions

N_JOINTS_RANGE = (2, 6)
"""Fewest and most controlled joints (the paper: 2 <= n <= 6)."""

CONTROL_MODES = ("position", "velocity", "torque")
"""Action meanings: desired absolute joint angles (rad), joint velocities (rad/s), joint torques
(N m). The paper used position control (the only mode in which DDPG learned)."""

REWARD_TYPES = ("dense", "sparse")
"""``dense``: the paper's eq. 2; ``sparse``: its success term alone."""

ACTION_PENALTY_UNITS = ("command", "actor")
"""How eq. 2's ``|a|^2`` reads the action a (the paper gives no unit; docs/design.md open point 5).
``command``: in the command's own unit, rad^2 in position mode (the literal reading, the default);
``actor``: in the actor's unit, each joint divided by its command bound (``a / pi`` in position
mode), so ``|a|^2 <= n``."""

DEFAULT_KP = (3920.0, 3600.0, 781.0, 232.0, 228.0, 15.4)
"""Default proportional gains (N m/rad) of joints 1-6; see :attr:`TaskSpec.kp`."""

DEFAULT_KD = (261.0, 240.0, 52.0, 15.5, 15.2, 1.03)
"""Default derivative gains (N m s/rad) of joints 1-6; see :attr:`TaskSpec.kp`."""

CONTACT_MODELS = ("stop", "compliant")
"""How the ground plane acts on the arm (docs/design.md open point 6;
:mod:`envs.physics.pinocchio_loop`). ``stop``: any plane contact stops the whole arm dead for the
rest of the control step (the default); ``compliant``: a penalty contact (spring-damper with Coulomb
friction) pushes each link out of the plane, so the arm can slide along it, as in Gazebo (ROS's
usual simulator; the paper names ROS, not the simulator)."""

HELD_JOINTS = ("locked", "pd")
"""What holds the joints the agent does not control (n+1..6) at their start angles.
``locked``: they are not in the dynamics at all, as if welded at the start angles (the arm's
inertia and gravity are those of the whole arm in that pose; :mod:`envs.physics.pinocchio_loop`), so
they never move; ``pd``: the joint PD controller holds them, and they give way under load (the
behaviour of runs recorded before this field existed)."""

RECORD_DEFAULTS: dict[str, Any] = {"held_joints": "pd"}
"""Fields added after runs began to be recorded whose default changed the behaviour: a recorded
task (a run's ``spec.json``, a checkpoint) that lacks one was made when the behaviour was this
value (:meth:`TaskSpec.from_record`)."""

GOAL_SAMPLERS = ("joint", "cartesian")
"""``joint``: the paper's sampler (uniform in joint space, kept in the region;
:class:`regions.JointSpaceSampler`); ``cartesian``: uniform in the reachable part of the region
(:class:`regions.CartesianSampler`, needs n_joints >= 3)."""


@dataclass(frozen=True)
class TaskSpec:
    """Everything that defines one UR5 Reacher task (docs/design.md), checked at construction.

    Construction checks each field alone (type, range, choice); :func:`envs.checks.validate`
    checks the task against the robot model.

    Lengths in m (world frame: ground plane z = 0, robot base at (0, 0, ``base_height``)),
    angles in rad, torques in N m, rates in Hz.

    Raises
    ------
    ValueError
        When a field is out of its range; the message names the field, the value and the
        expected range.
    """

    region: str = UNCONSTRAINED_REGION
    """Goal constraint region: a registered name (``unconstrained``, ``zheight``, ``closebox``,
    ``farbox``, ``farbox_tall``) or any string :func:`regions.parse` accepts
    (``box:XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX``, ``zmax:Z``, ``mesh:PATH``, inline JSON ...). A
    :class:`regions.Region` object or its ``to_dict()`` form is accepted too and stored as inline
    JSON (or as its registered name when it equals a registered region), so the field is always a
    string that rebuilds the region exactly."""

    n_joints: int = 3
    """Controlled joints n (2-6): joints 1..n move; joints n+1..6 are held at ``start_q``
    (how: :attr:`held_joints`)."""

    held_joints: str = "locked"
    """What holds joints n+1..6 at their start angles: one of :data:`HELD_JOINTS`. The paper's
    "number of joints controlled" and its goal sampler ("the reachable space effected by the
    joints being controlled") both mean that the other joints stay where they start, so
    ``locked`` (the default) takes them out of the dynamics: the controlled joints move the
    whole arm (its inertia and gravity in the held pose) and the held ones never move.
    ``pd``: the PD controller holds them, as before this field existed; the URDF wrists' 28 N m
    cannot hold their 0.6 m inertias during fast shoulder moves: they swing and move tool0
    (measured in results/held_joints/README.md)."""

    start_q: tuple[float, ...] | None = None
    """Start configuration (6 angles, rad) of every episode. ``None`` resolves at construction:
    all zeros for ``unconstrained`` (the paper), else [0, -pi/4, pi/2, 0, 0, 0] (the paper's
    [0, pi/2, pi/4, 0, 0, 0] read as docs/design.md's open point 1). Must lie within the URDF joint
    limits and clear of the plane (:func:`envs.checks.validate`)."""

    base_height: float = DEFAULT_BASE_HEIGHT
    """Height (m) of the robot base above the ground plane (0.1, where ROS's ur_gazebo spawns
    the UR5)."""

    goal_sampler: str = "joint"
    """How goals are drawn: one of :data:`GOAL_SAMPLERS`."""

    control_mode: str = "position"
    """Meaning of the action: one of :data:`CONTROL_MODES`."""

    reward_type: str = "dense"
    """``dense`` (eq. 2 of the paper): ``-distance_weight * d - action_weight * |a|^2 +
    success_reward * 1{d <= success_radius}``; ``sparse``: the last term alone."""

    distance_weight: float = 1.0
    """Weight (1/m) of the tool0-goal distance d in the dense reward (paper: 1)."""

    action_weight: float = 1.0
    """Weight of the squared action norm |a|^2 in the dense reward (paper: 1); the unit of a is
    ``action_penalty_unit``."""

    action_penalty_unit: str = "command"
    """Unit in which eq. 2's action penalty ``|a|^2`` reads the action: one of
    :data:`ACTION_PENALTY_UNITS`. The paper: "-|a|^2", a = the commanded absolute joint angles,
    no unit or scale stated. ``command``: rad^2 in position mode (holding the constrained start
    costs 3.1 per step, comparable with the distance term); ``actor``: ``(a / pi)^2`` per
    joint in position mode (a tenth of that), the reading of an implementation whose actor
    outputs [-1, 1]. Measured to change the paper's speeds several-fold (results/sensitivity_pd,
    and its re-run in results/sensitivity)."""

    success_reward: float = 100.0
    """Reward added when the goal is reached (paper: 100)."""

    success_radius: float = 0.1
    """Success when tool0 is within this distance (m) of the goal (paper: eps = 0.1 m)."""

    terminate_on_success: bool = True
    """End the episode (``terminated``) at the first success (paper: yes)."""

    max_episode_steps: int = 100
    """Control steps after which the episode is truncated (paper: T = 100, 2 s at 50 Hz)."""

    control_hz: int = 50
    """Control rate (Hz): one env step lasts 1 / control_hz s (paper: 50 Hz)."""

    sim_hz: int = 1000
    """Integration rate (Hz) of the dynamics; a multiple of ``control_hz`` (docs/design.md: 1 kHz or
    finer), so each step is ``sim_hz / control_hz`` semi-implicit Euler substeps."""

    kp: tuple[float, ...] = DEFAULT_KP
    """Proportional gains (N m/rad) of the joint PD controller, joints 1-6.

    The defaults place a critically damped pair of poles at 30 rad/s for each joint taken alone
    at its largest diagonal inertia over the joint space, ``I_max = (4.35, 4.01, 0.867, 0.258,
    0.253, 0.0171) kg m^2``: ``kp = I_max w^2``, ``kd = 2 zeta I_max w`` with ``w = 30 rad/s``,
    ``zeta = 1``, rounded. Lighter poses see a faster, more damped loop. With them a commanded
    pose is reached and held to < 1e-4 rad within the 2 s of an episode (the arm moves at its
    3.15 rad/s limit most of the way), and the coupled closed loop linearised at 2000 sampled
    configurations is stable under 1 kHz semi-implicit Euler with margin (largest spectral
    radius of the substep map 0.986; tested)."""

    kd: tuple[float, ...] = DEFAULT_KD
    """Derivative gains (N m s/rad) of the joint PD controller, joints 1-6 (see :attr:`kp`). In
    velocity mode they are the gains on the velocity error of the controlled joints."""

    gravity_compensation: bool = True
    """Add the gravity torque g(q) (Pinocchio's ``computeGeneralizedGravity``) to the command in
    every control mode, so that a PD-held pose does not sag and a zero torque command floats."""

    plane_margin: float = 0.0
    """Clearance (m) every moving link keeps above the ground plane; less counts as contact."""

    contact_model: str = "stop"
    """How the ground plane acts on the arm: one of :data:`CONTACT_MODELS`. The paper says its
    simulation ran under ROS and states no contact model; if it was Gazebo (ROS's usual
    simulator, our assumption, not the paper's words), that contact is compliant: the arm is
    pushed out and slides. ``stop`` (the default, as before): any contact
    stops the whole arm dead for the rest of the control step. ``compliant``: a penalty force
    ``f_n = max(0, k d - c dz/dt)`` at each link's deepest point ``d`` m below
    ``z = plane_margin`` with Coulomb friction (the ``contact_*`` fields;
    :mod:`envs.physics.pinocchio_loop`). Either way no link ends a step more than
    ``contact_max_depth`` below the plane."""

    contact_stiffness: float = 2.0e5
    """Normal stiffness k (N/m) of the compliant contact, per link. 2e5 N/m: the arm's weight
    (about 170 N) presses it 0.9 mm into the plane, a stalled 150 N m joint pushing through a
    0.4 m lever (375 N) 1.9 mm; a near-rigid table, as Gazebo's is. Stable under the 1 kHz
    semi-implicit Euler: ``k h^2 / m = 0.08`` at the smallest effective mass that can touch
    (2.4 kg, a wrist link's point, sampled over the joint space), far below the limit 4 (see
    :func:`envs.gains.contact_stability_violations`)."""

    contact_damping: float = 2.0e3
    """Normal damping c (N s/m) of the compliant contact, also the slope of the regularised
    friction below its Coulomb bound. 2000 N s/m is critical damping ``2 sqrt(k m)`` for an
    effective mass of 5 kg (the median of a wrist point's): impacts do not bounce (damping
    ratio 1.4 at 2.4 kg, 0.7 at 10 kg), like Gazebo's inelastic default; ``c h / m = 0.83``
    at 2.4 kg, below the integrator's limit 2."""

    contact_friction: float = 1.0
    """Coulomb friction coefficient mu (dimensionless) of the compliant contact: the tangential
    force is ``min(mu f_n, c |v_t|)`` against the contact point's tangential velocity v_t (0:
    frictionless). 1 is the pair Gazebo uses for a link on its ground plane (the smaller of the
    two surfaces' ``mu``: the link's default 1, the ground plane's 100)."""

    contact_max_depth: float = 0.02
    """Depth (m) below ``z = plane_margin`` that no link may reach at the end of a control step,
    in every contact model (the plane stays impermeable). The compliant contact keeps links far
    shallower (about 2 mm under a stalled joint); a copy whose step would end deeper falls back
    to the stop model for that step (``PinocchioDynamics.depth_stop``). The stop model never enters
    the plane."""

    def __post_init__(self) -> None:
        base = BASE_HEIGHT("base_height", self.base_height)
        object.__setattr__(self, "region", _region_string(self.region, base))
        if self.start_q is None:
            object.__setattr__(self, "start_q", default_start(self.region))
        gate.check_fields(self, FIELDS, "task", COMBINATIONS)

    # ------------------------------------------------------------------ derived quantities
    @property
    def dt(self) -> float:
        """Duration (s) of one control step, ``1 / control_hz``."""
        return 1.0 / self.control_hz

    @property
    def sim_dt(self) -> float:
        """Duration (s) of one integration substep, ``1 / sim_hz``."""
        return 1.0 / self.sim_hz

    @property
    def substeps(self) -> int:
        """Integration substeps per control step, ``sim_hz / control_hz``."""
        return self.sim_hz // self.control_hz

    @functools.cached_property
    def goal_region(self) -> regions.Region:
        """The region :attr:`region` names, built for :attr:`base_height`."""
        return registry.parse(self.region, self.base_height)

    # ------------------------------------------------------------------ JSON
    def to_dict(self) -> dict[str, Any]:
        """The fields as plain JSON types (tuples become lists); :meth:`from_dict` inverts it."""
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v)
                for f in dataclasses.fields(self)}

    @classmethod
    def from_record(cls, data: Mapping[str, Any]) -> TaskSpec:
        """Rebuild a *recorded* task (a run's ``spec.json`` ``task``, a checkpoint's): like
        :meth:`from_dict`, but a field of :data:`RECORD_DEFAULTS` that the record lacks takes
        the value it had when the record was written, not today's default.

        Raises
        ------
        ValueError
            As :meth:`from_dict`.
        """
        return cls.from_dict({**RECORD_DEFAULTS, **data} if isinstance(data, Mapping) else data)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TaskSpec:
        """Rebuild a task from :meth:`to_dict` output (missing fields take their defaults).

        Raises
        ------
        ValueError
            For a key that is not a field (the message lists the fields), or a bad value.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"a task description must be a mapping of fields; got {data!r:.200}")
        gate.known_fields(cls, data, "task")
        return cls(**data)

    def to_json(self, **kwargs: Any) -> str:
        """JSON text of :meth:`to_dict` (keyword arguments go to :func:`json.dumps`)."""
        return json.dumps(self.to_dict(), **kwargs)

    @classmethod
    def from_json(cls, text: str) -> TaskSpec:
        """Rebuild a task from :meth:`to_json` output."""
        try:
            data = json.loads(text)
        except json.JSONDecodeError as err:
            raise ValueError(f"task JSON is not valid JSON ({err}): {text!r:.200}") from err
        return cls.from_dict(data)

    def replace(self, **overrides: Any) -> TaskSpec:
        """A copy with some fields changed (checked like a new task).

        Raises
        ------
        ValueError
            For an unknown field name (the message lists the fields) or a bad value.
        """
        gate.known_fields(TaskSpec, overrides, "task")
        if ("region" in overrides and "start_q" not in overrides
                and self.start_q == default_start(self.region)):
            overrides["start_q"] = None  # a default start follows the region; a chosen one stays
        return dataclasses.replace(self, **overrides)


FIELDS: dict[str, gate.Kind] = gate.kinds(
    (BASE_HEIGHT, "base_height"), (gate.number(0, note="m"), "plane_margin"),
    (gate.integer(*N_JOINTS_RANGE), "n_joints"),
    *((gate.choice(options), name) for name, options in (
        ("goal_sampler", GOAL_SAMPLERS), ("control_mode", CONTROL_MODES),
        ("reward_type", REWARD_TYPES), ("action_penalty_unit", ACTION_PENALTY_UNITS),
        ("contact_model", CONTACT_MODELS), ("held_joints", HELD_JOINTS))),
    (gate.number(0), "distance_weight", "action_weight", "success_reward"),
    (gate.number(0, above=True, note="N/m"), "contact_stiffness"),
    (gate.number(0, note="N s/m"), "contact_damping"), (gate.number(0), "contact_friction"),
    (gate.number(0, above=True, note="m"), "contact_max_depth", "success_radius"),
    (gate.FLAG, "terminate_on_success", "gravity_compensation"),
    (gate.integer(1), "max_episode_steps", "control_hz", "sim_hz"),
    (gate.vector(6, "N m/rad, joints 1-6", positive=True), "kp"),
    (gate.vector(6, "N m s/rad, joints 1-6", positive=True), "kd"),
    (gate.vector(6, "rad, joints 1-6"), "start_q"))
"""The type and range of each `TaskSpec` field but ``region`` (parsed by :mod:`regions`)."""

COMBINATIONS: tuple[gate.Combination, ...] = (
    ("goal_sampler", f"'joint': 'cartesian' needs n_joints >= {CartesianSampler.MIN_JOINTS} "
     "(with fewer, tool0 reaches only a surface)", lambda t: t.goal_sampler != "cartesian"
     or t.n_joints >= CartesianSampler.MIN_JOINTS),
    ("sim_hz", "a multiple of control_hz (whole substeps per control step)",
     lambda t: t.sim_hz % t.control_hz == 0))
"""What `TaskSpec`'s fields may be combined with."""


# ---------------------------------------------------------------------- field checks
def _region_string(region: Any, base_height: float) -> str:
    """The canonical string form of a region given as a string, a Region or its dict form.

    A registered name is kept as it is without building its region (building the reach ball
    loads the robot model); any other string is parsed, so a bad one fails here.
    """
    from regions.shapes import Region, region_from_dict  # numpy only

    if isinstance(region, Mapping):
        region = region_from_dict(dict(region))
    if isinstance(region, Region):
        if region.name in registry.names():
            try:
                if registry.get(region.name, base_height) == region:
                    return region.name
            except ValueError:
                pass
        return json.dumps(region.to_dict(), separators=(",", ":"))
    if not isinstance(region, str):
        raise ValueError(f"region must be a region name or string ({registry.spec_help()}), a "
                         f"regions.Region or its to_dict() form; got {type(region).__name__}")
    region = region.strip()
    if region not in registry.names():
        registry.parse(region, base_height)  # raises ValueError naming the accepted forms
    return region


def make_task(task: TaskSpec | Mapping[str, Any] | None, overrides: Mapping[str, Any]
              ) -> TaskSpec:
    """The task from a :class:`TaskSpec` (or its dict form) and field overrides: what every
    env does with its ``task=`` and ``**overrides`` keywords.

    ``region`` may be a name, a region string or a :class:`regions.Region`; a changed region
    brings its default start pose unless ``start_q`` is given too. ``spec=`` (the keyword's
    name before it clashed with Gymnasium's ``env.spec``) is read as ``task=``, with a
    DeprecationWarning.

    Raises
    ------
    ValueError
        For an unknown field name or a bad value (see :class:`TaskSpec`), or for both
        ``task=`` and ``spec=``.
    """
    overrides = dict(overrides)
    if "spec" in overrides:
        if task is not None:
            raise ValueError("give the task once: task= (spec= is its deprecated name), not both")
        warnings.warn("the env keyword spec= is deprecated: it is task= (spec clashes with "
                      "Gymnasium's env.spec)", DeprecationWarning, stacklevel=3)
        task = overrides.pop("spec")
    if task is None:
        return TaskSpec.from_dict(overrides)
    if isinstance(task, Mapping):  # a to_dict() form: a record, perhaps of an older version
        task = TaskSpec.from_record(task)
    elif not isinstance(task, TaskSpec):
        raise ValueError(f"task must be a TaskSpec, its to_dict() form or None; got "
                         f"{type(task).__name__}")
    return task.replace(**overrides) if overrides else task
