"""B copies of the Reacher on one device, copy b in its own task (joint count, start pose,
region, penalty unit), stepped by tensor operations alone: the env of the training program
(``ddpg_her.program``; docs/design.md, "The training program").

Every copy is padded to six joints: its observation is ``[theta, theta_dot, theta_ddot]`` of
six joints (18 values) with exact zeros past its own ``n_joints``, and its action six commands
of which the ones past ``n_joints`` are ignored (zero in the reward). Nothing here reads a
device value on the host, so `StackReach.step`, `StackReach.reset_where` and
`StackReach.draw_goals` can be captured in a CUDA graph; every random number comes in as an
argument (the trainer owns the streams).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium
import numpy as np
import torch

import regions
import ur5kin
from envs.physics.model import NJ, PlaneModel, ur5_plane
from envs.reward import goal_distance, reach_reward
from envs.spec import TaskSpec, make_task
from envs.task import action_bounds, action_penalty_scale, task_sampler
from ur5kin.checks import number

PER_COPY_FIELDS = ("region", "n_joints", "start_q", "action_penalty_unit")
"""The task fields in which the copies of one stack may differ; all others must be equal."""

PROPOSAL_CHUNK = 64
"""Proposals per copy tested at once by `StackReach.draw_goals` at least (more while B x
proposals stays within `PROPOSAL_BUDGET`)."""

PROPOSAL_BUDGET = 2**17
"""Proposals of all copies that `StackReach.draw_goals` tests in one pass at most, unless
`PROPOSAL_CHUNK` per copy is more (bounds the memory: the plane test's (B x count, 358) float64
heights, 375 MB at this budget; the paper grid's 55 copies test their 2,112 in one pass)."""

GOAL_MISS_PROBABILITY = 1e-9
"""The largest chance that `StackReach.draw_goals` finds no goal among its proposals for one
copy (the number of proposals is sized from each task's acceptance to stay below it; a miss
keeps the copy's last goal and is counted in `StackReach.goal_misses`)."""


@dataclass(frozen=True)
class TorchPlane:
    """:class:`envs.physics.model.PlaneModel` as tensors, laid out for one matrix product.

    Attributes
    ----------
    vertex_heights : (13, V) float, m
        Per feature, the height above base_link of the candidate lowest vertices of the moving
        links, link by link.
    bounds : tuple of 7 int
        Columns ``bounds[k]:bounds[k + 1]`` belong to moving link k = 0..5 (their sizes differ
        sixfold: one slice each, where padding to the longest tripled the product).
    lift_offset, wrist_offset : float, rad
        Offsets of the pitches the features use.
    """

    vertex_heights: torch.Tensor
    bounds: tuple[int, ...]
    lift_offset: float
    wrist_offset: float

    @classmethod
    def from_plane(cls, plane: PlaneModel, device: torch.device | str,
                   dtype: torch.dtype) -> TorchPlane:
        """The table of ``plane`` (float64 there) without base_link's rows, on ``device`` as
        ``dtype``."""
        bounds = [int(b) for b in plane.bounds]
        vh = np.asarray(plane.vertex_heights, dtype=np.float64)[bounds[1] :]
        table = torch.as_tensor(np.ascontiguousarray(vh.T))
        return cls(table.to(device=device, dtype=dtype), tuple(b - bounds[1] for b in bounds[1:]),
                   float(plane.lift_offset), float(plane.wrist_offset))


def plane_heights(q: torch.Tensor, plane: TorchPlane, base_height: float) -> torch.Tensor:
    """Lowest point ``(B, 6)`` (m, world z) of each moving link at ``q (B, 6)`` rad: the 13
    trigonometric features (:data:`ur5kin.collision.FEATURES`) times the vertex table, the
    minimum per link (the numba kernel's ``copy_link_heights``; :func:`ur5kin.link_heights`
    without the fixed base link)."""
    a = q[:, 1] + plane.lift_offset
    b = a + q[:, 2]
    c = b + q[:, 3] + plane.wrist_offset
    sc, cc = torch.sin(c), torch.cos(c)
    s5, c5, s6, c6 = torch.sin(q[:, 4]), torch.cos(q[:, 4]), torch.sin(q[:, 5]), torch.cos(q[:, 5])
    sc5 = sc * c5
    feat = torch.stack([torch.ones_like(a), torch.sin(a), torch.cos(a), torch.sin(b),
                        torch.cos(b), sc, cc, sc5, sc * s5, sc5 * c6, cc * s6, cc * c6,
                        sc5 * s6], -1)
    heights = torch.matmul(feat, plane.vertex_heights)  # (B, V)
    b = plane.bounds
    return torch.stack([heights[:, b[k] : b[k + 1]].amin(-1) for k in range(NJ)], -1) + base_height


@dataclass(frozen=True)
class RegionBounds:
    """A region as an axis-aligned box cut by a ball: what the device tests for membership.

    lo, hi : (3,) float, m, world frame (+-inf where unbounded); center : (3,) m; radius : m
    (inf: no ball). ``contains(p) = lo <= p <= hi and |p - center| <= radius``.
    """

    lo: tuple[float, float, float]
    hi: tuple[float, float, float]
    center: tuple[float, float, float] = (0.0, 0.0, 0.0)
    radius: float = math.inf

    @classmethod
    def of(cls, region: regions.Region) -> RegionBounds:
        """The bounds of a box, a z-limit, a ball or an intersection of them; ValueError for
        a region of another kind (a mesh), which the device cannot test."""
        lo, hi = [-math.inf] * 3, [math.inf] * 3
        center, radius = (0.0, 0.0, 0.0), math.inf
        parts = region.parts if isinstance(region, regions.Intersection) else (region,)
        for part in parts:
            if isinstance(part, regions.Box):
                limits = (part.x, part.y, part.z)
            elif isinstance(part, regions.ZLimit):
                limits = ((-math.inf, math.inf), (-math.inf, math.inf), (part.zmin, part.zmax))
            elif isinstance(part, regions.Ball) and radius == math.inf:
                center, radius = part.center, part.radius
                continue
            else:
                raise ValueError(f"region {region.name!r}: the device goal sampler tests boxes, "
                                 f"z-limits and one ball; got a part of kind {part.kind!r}")
            for axis, (a, b) in enumerate(limits):
                lo[axis], hi[axis] = max(lo[axis], a), min(hi[axis], b)
        return cls(tuple(lo), tuple(hi), tuple(center), float(radius))


def proposals_for(acceptance: float, miss: float = GOAL_MISS_PROBABILITY) -> int:
    """Proposals per goal so that all miss with probability at most ``miss``: the least P with
    ``(1 - acceptance)^P <= miss``."""
    acceptance = number(0, 1, above=True)("acceptance", acceptance)
    if acceptance == 1.0:
        return 1
    return max(1, math.ceil(math.log(miss) / math.log1p(-acceptance)))


def stack_tasks(tasks: Sequence[TaskSpec | dict[str, Any]]) -> list[TaskSpec]:
    """The tasks as `TaskSpec` (dicts are env keywords), checked to form one stack: equal in
    every field but `PER_COPY_FIELDS`, under the stop contact, locked held joints, the joint
    goal sampler and position control; ValueError naming the first field that breaks it."""
    specs = [t if isinstance(t, TaskSpec) else make_task(None, t) for t in tasks]
    if not specs:
        raise ValueError("need at least one task")
    for field, allowed in (("contact_model", "stop"), ("held_joints", "locked"),
                           ("goal_sampler", "joint"), ("control_mode", "position")):
        bad = [getattr(s, field) for s in specs if getattr(s, field) != allowed]
        if bad:
            raise ValueError(f"the training program runs tasks with {field}={allowed!r}; got "
                             f"{field}={bad[0]!r}")
    first = specs[0].to_dict()
    for spec in specs[1:]:
        other = spec.to_dict()
        for key, value in first.items():
            if key not in PER_COPY_FIELDS and other[key] != value:
                raise ValueError(f"the tasks of one stack may differ only in "
                                 f"{', '.join(PER_COPY_FIELDS)}; {key} differs: {value!r} and "
                                 f"{other[key]!r}")
    return specs


class StackReach:
    """B copies of the Reacher, copy b in ``tasks[b]``, as tensors on ``device``.

    Parameters
    ----------
    num_envs : int
        B, a multiple of ``len(tasks)``: copies ``b`` with ``b // (B / len(tasks)) == i`` run
        ``tasks[i]`` (task-major).
    tasks : sequence of TaskSpec or env-keyword dicts
        One stack (`stack_tasks`).
    device : str or torch.device
    dynamics : callable, optional
        ``dynamics(tasks, device)``: the arm of the B copies, copy b in ``tasks[b]``
        (`envs.physics.stack.StackDynamics` by default; the tests give stand-ins).

    Attributes
    ----------
    joint_mask : (B, 6) bool
        Joint j is controlled in copy b.
    goal : (B, 3) float64, m, world frame
    elapsed : (B,) int64, steps since the copy's reset
    goal_misses : () int64
        Goal draws in which no proposal was accepted (see `GOAL_MISS_PROBABILITY`).
    proposals : int
        Joint-space proposals per goal draw, for the least accepting task.
    """

    metadata: ClassVar[dict[str, Any]] = {"autoreset_mode": gymnasium.vector.AutoresetMode.DISABLED}
    """No autoreset: the caller starts episodes with `reset_where`."""

    def __init__(self, num_envs: int, tasks: Sequence[TaskSpec | dict[str, Any]],
                 device: Any = "cpu", dynamics: Any = None):
        given = stack_tasks(tasks)
        if not isinstance(num_envs, int) or num_envs < 1 or num_envs % len(given):
            raise ValueError(f"num_envs must be a positive multiple of the {len(given)} tasks; "
                             f"got {num_envs!r}")
        self.tasks = [t for t in given for _ in range(num_envs // len(given))]
        self.task = self.tasks[0]
        self.device, self.num_envs = torch.device(device), len(self.tasks)
        f64 = {"dtype": torch.float64, "device": self.device}
        n = torch.tensor([t.n_joints for t in self.tasks], device=self.device)
        self.n_joints = n
        self.joint_mask = torch.arange(NJ, device=self.device) < n[:, None]
        low, high, scale = (np.zeros((self.num_envs, NJ)), np.zeros((self.num_envs, NJ)),
                            np.ones((self.num_envs, NJ)))
        for b, t in enumerate(self.tasks):
            lo, hi = action_bounds(t)
            low[b, :t.n_joints], high[b, :t.n_joints] = lo, hi
            scale[b, :t.n_joints] = action_penalty_scale(t)
        self.action_low, self.action_high = (torch.tensor(low, **f64), torch.tensor(high, **f64))
        self.penalty_scale = torch.tensor(scale, **f64)
        self.start_q = torch.tensor([t.start_q for t in self.tasks], **f64)
        samplers = [task_sampler(t) for t in self.tasks]
        bounds = [RegionBounds.of(s.region) for s in samplers]
        self._lo = torch.tensor([b.lo for b in bounds], **f64)
        self._hi = torch.tensor([b.hi for b in bounds], **f64)
        self._center = torch.tensor([b.center for b in bounds], **f64)
        self._radius2 = torch.tensor([b.radius**2 for b in bounds], **f64)
        self.proposals = proposals_for(min(s.acceptance for s in samplers))
        self._plane = TorchPlane.from_plane(ur5_plane(), self.device, torch.float64)
        self._geometry = ur5kin.model.geometry()
        if dynamics is None:
            from envs.physics.stack import StackDynamics as dynamics
        self.dynamics = dynamics(self.tasks, device=self.device)
        self.goal = torch.zeros(self.num_envs, 3, **f64)
        self.elapsed = torch.zeros(self.num_envs, dtype=torch.int64, device=self.device)
        self.goal_misses = torch.zeros((), dtype=torch.int64, device=self.device)
        self.action = torch.zeros(self.num_envs, NJ, **f64)
        self._copies = torch.arange(self.num_envs, device=self.device)
        # eq. 2 always divides by the per-copy scale: ones under the command unit, which
        # divide exactly, so copies of either unit share one expression
        self._reward_task = self.task.replace(action_penalty_unit="actor")

    # ------------------------------------------------------------------ goals
    def draw_goals(self, uniforms: Callable[[int, int], torch.Tensor]) -> torch.Tensor:
        """Goals ``(B, 3)`` m, world frame, by rejection: ``uniforms(first, count)`` gives the
        numbers ``(B, count, 6)`` in [0, 1) of proposals ``first .. first + count - 1`` of
        each copy (`proposals` in all, ``max(PROPOSAL_CHUNK, PROPOSAL_BUDGET // B)`` at a
        time). Proposal p of copy b sets its controlled joints to ``(2 u - 1) pi`` (the
        others at the start pose), as `regions.JointSpaceSampler`; the first proposal whose
        tool0 lies in the region with every moving link clear of the plane is the goal. A copy
        with none keeps its current goal and adds one to `goal_misses`."""
        b = self.num_envs
        found = torch.zeros(b, dtype=torch.bool, device=self.device)
        goal = self.goal.clone()
        chunk = max(PROPOSAL_CHUNK, PROPOSAL_BUDGET // b)
        for first in range(0, self.proposals, chunk):
            count = min(chunk, self.proposals - first)
            tool, ok = self.accepts(uniforms(first, count))
            pick = torch.argmax(ok.to(torch.uint8), dim=1)  # the first True (0 when none)
            new = ok.any(1) & ~found
            goal = torch.where(new[:, None], tool[self._copies, pick], goal)
            found |= new
        self.goal_misses += (~found).sum()
        return goal

    def accepts(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The proposals of the uniform numbers ``u (B, P, 6)``: tool0's world position
        ``(B, P, 3)`` m, and whether each is a goal (in the copy's region, every moving link
        clear of the plane: `regions.JointSpaceSampler`'s test) ``(B, P)``."""
        b, count = u.shape[:2]
        q = torch.where(self.joint_mask[:, None], (2.0 * u - 1.0) * math.pi,
                        self.start_q[:, None])
        tool = ur5kin.closed_form.position(q, self._geometry)
        tool = torch.cat([tool[..., :2], tool[..., 2:] + self.task.base_height], -1)
        ok = ((tool >= self._lo[:, None]) & (tool <= self._hi[:, None])).all(-1)
        ok &= (tool - self._center[:, None]).square().sum(-1) <= self._radius2[:, None]
        ok &= plane_heights(q.reshape(b * count, NJ), self._plane, self.task.base_height
                            ).amin(-1).reshape(b, count) >= 0.0
        return tool, ok

    # ------------------------------------------------------------------ episodes
    def reset(self, **_: Any) -> None:
        """Refused in one line: the copies start episodes with `reset_where` (no autoreset)."""
        raise ValueError("StackReach has no Gymnasium reset(); start episodes with "
                         "reset_where(mask (B,) bool, goal (B, 3) m), goals from draw_goals")

    def reset_where(self, mask: torch.Tensor, goal: torch.Tensor) -> None:
        """Start new episodes where ``mask (B,) bool``: the arm at rest at its start pose, the
        goal ``goal (B, 3)`` m (rows outside the mask are ignored)."""
        self.dynamics.reset_where(mask)
        self.goal.copy_(torch.where(mask[:, None], goal, self.goal))
        self.elapsed.masked_fill_(mask, 0)
        self.action.masked_fill_(mask[:, None], 0.0)

    def observation(self) -> tuple[torch.Tensor, torch.Tensor]:
        """``(obs (B, 18), achieved_goal (B, 3))``: theta, theta_dot, theta_ddot of six joints
        (zeros past each copy's joint count) and tool0's world position (m), new tensors."""
        d, m = self.dynamics, self.joint_mask
        obs = torch.cat([d.q, d.v, d.acceleration], -1) * m.repeat(1, 3)
        return obs, d.tool.clone()

    def step(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """One control step of every copy: ``action (B, 6)`` in the command's unit, clipped to
        each copy's box (joints past its count: 0). Returns the reward ``(B,)`` (eq. 2, of the
        clipped action and the distance after the step) and the success flags ``(B,)``."""
        torch.clamp(action.to(torch.float64), self.action_low, self.action_high,
                    out=self.action)
        self.dynamics.step(self.action)
        self.elapsed.add_(1)
        distance = goal_distance(self.dynamics.tool, self.goal)
        reward = reach_reward(distance, self.action, self._reward_task, self.penalty_scale)
        return reward, distance <= self.task.success_radius

    def reward(self, achieved_goal: torch.Tensor, goal: torch.Tensor, action: torch.Tensor
               ) -> torch.Tensor:
        """The reward ``(B, ...)`` of transitions of each copy (HER relabelling): goals
        ``(B, ..., 3)`` m, ``action (B, ..., 6)`` as applied (zeros past the joint count)."""
        scale = self.penalty_scale.reshape(self.num_envs, *[1] * (action.ndim - 2), NJ)
        return reach_reward(goal_distance(achieved_goal, goal), action, self._reward_task, scale)

    @property
    def unwrapped(self) -> StackReach:
        """Itself (the Gymnasium convention, so ``gymnasium.make_vec`` can set ``spec``)."""
        return self

    def close(self) -> None:
        """Nothing to release."""

    def success(self, achieved_goal: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Whether tool0 at ``achieved_goal`` reaches ``goal`` (both ``(..., 3)`` m)."""
        return goal_distance(achieved_goal, goal) <= self.task.success_radius
