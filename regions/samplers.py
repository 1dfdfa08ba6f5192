"""Goal samplers: where a Reacher episode's goal comes from, for a region and a joint count.

Two ways, sharing one interface (``sample(n, rng) -> GoalBatch``):

- :class:`JointSpaceSampler`, the paper's: joints 1..n uniform in [-pi, pi], the others at the
  start angles; keep the tool0 positions inside the region whose configuration is clear of the
  plane. Every goal is reachable by construction, but goals are dense where the arm's
  Jacobian is small, not uniform in space.
- :class:`CartesianSampler`: positions uniform in the region; keep those that analytic position
  IK reaches with a plane-clear configuration. Uniform over the reachable part of the region.

Both estimate their acceptance first, on a probe of a fixed seed, and raise
:class:`UnreachableRegionError` at once when a region has (almost) no reachable goals, so that
sampling never hangs.
"""

from __future__ import annotations

import abc
import functools
import math
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

import ur5kin  # lazy: Pinocchio loads at the first sample, not on import
from regions.reach import reach_ball
from regions.shapes import Region, region_from_dict
from ur5kin.checks import (
    COUNT,
    MOVING_JOINTS_RANGE,
    Kind,
    check_fields,
    integer,
    kinds,
    number,
    vector,
)
from ur5kin.world import BASE_HEIGHT, DEFAULT_BASE_HEIGHT, to_base

PROBE_SEED = 20190916
"""Seed of the acceptance probe. The probe never touches the caller's generator, so the goals
depend on the caller's seed alone."""


class UnreachableRegionError(ValueError):
    """A region holds no (or almost no) reachable goals for the sampler's joint count."""


@dataclass(frozen=True)
class SamplingLimits:
    """How samplers size their batches and when they give up."""

    probe_rounds: tuple[int, ...] = (4096, 16384, 65536, 262144)
    """Proposals of the successive probe rounds that estimate the acceptance; the probe stops
    after the round in which :attr:`probe_hits` goals have been accepted in all."""
    probe_hits: int = 64
    """Accepted goals after which the probe stops (acceptance known to about +-25 %)."""
    min_acceptance: float = 1e-5
    """Below this estimated acceptance (accepted / proposals) a region counts as unreachable:
    then each goal costs more than 10^5 proposals."""
    max_batch: int = 65536
    """Largest batch of proposals evaluated at once (bounds the memory)."""
    overdraw_sigmas: float = 3.0
    """A batch asks for this many standard deviations of binomial noise more than the goals it
    still needs (plus as many goals), so that one batch nearly always suffices."""
    max_overdraw: float = 50.0
    """``sample`` raises ``RuntimeError`` after this many times the expected proposals (with the
    probe's acceptance), which only an acceptance far below the probe's estimate can cause."""

    def __post_init__(self) -> None:
        check_fields(self, kinds(
            (Kind("counts >= 1", lambda v: len(v) > 0 and all(COUNT.test(r) for r in v), tuple),
             "probe_rounds"), (COUNT, "probe_hits", "max_batch"),
            (number(0, 1, above=True, below=True), "min_acceptance"),
            (number(0), "overdraw_sigmas"), (number(1), "max_overdraw")), "sampling limits")


@dataclass(frozen=True, eq=False)
class GoalBatch:
    """Goals and the arm configurations that reach them.

    Attributes
    ----------
    goals : (n, 3) float, m, world frame
        Goal positions.
    q : (n, 6) float, rad
        A plane-clear configuration whose tool0 lies at each goal (to 1e-9 m).
    proposals : int
        Proposals drawn until the n-th goal was found: joint configurations (joint-space
        sampler) or points of the sampling box (Cartesian sampler).
    in_region : int
        Of those, how many lay inside the region.
    """

    goals: np.ndarray
    q: np.ndarray
    proposals: int
    in_region: int

    @property
    def acceptance(self) -> float:
        """Goals per proposal."""
        return len(self.goals) / self.proposals if self.proposals else math.nan

    @property
    def reachable_fraction(self) -> float:
        """Goals per proposal inside the region: for the Cartesian sampler, the fraction of the
        region's volume that is reachable with a plane-clear configuration."""
        return len(self.goals) / self.in_region if self.in_region else math.nan


def draw_joint_space(n_joints: int, start_q: Any, count: int,
                     rng: np.random.Generator) -> np.ndarray:
    """Configurations with joints 1..n uniform in [-pi, pi] and the others at ``start_q``.

    Parameters
    ----------
    n_joints : int
        Controlled joints (1-6).
    start_q : (6,) float, rad
        Start configuration; its joints n+1..6 are held.
    count : int
    rng : numpy.random.Generator

    Returns
    -------
    q : (count, 6) float, rad
    """
    return ur5kin.SubChain(n_joints, start_q).full(
        rng.uniform(-ur5kin.JOINT_LIMIT, ur5kin.JOINT_LIMIT, size=(count, n_joints)))


@dataclass(frozen=True)
class GoalSampler(abc.ABC):
    """Draws goals in ``region`` reachable by moving joints 1..``n_joints`` from ``start_q``.

    Parameters
    ----------
    region : Region
        Goal constraint region (world frame).
    n_joints : int
        Controlled joints, 1-6 (the paper: 2-6); joints n+1..6 stay at ``start_q``.
    start_q : (6,) float, rad
        Start configuration of the episode (the env's task specification owns the defaults).
    base_height : float, m
        Height of the robot base above the plane (0.1 by default).
    limits : SamplingLimits

    Raises
    ------
    ValueError
        On a bad argument.
    UnreachableRegionError
        When the probe finds (almost) no reachable goals: on construction, not in a loop later.
    """

    region: Region
    n_joints: int
    start_q: tuple[float, ...]
    base_height: float = DEFAULT_BASE_HEIGHT
    limits: SamplingLimits = field(default_factory=SamplingLimits)
    kind: ClassVar[str]

    def __post_init__(self) -> None:
        if not isinstance(self.region, Region):
            raise ValueError(f"region must be a regions.Region; got {type(self.region).__name__}")
        check_fields(self, {"n_joints": integer(*MOVING_JOINTS_RANGE), "base_height": BASE_HEIGHT,
                            "start_q": vector(6, "rad, joints 1-6")}, "goal sampler")
        _ = self.acceptance  # fail fast

    @abc.abstractmethod
    def _propose(self, count: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Draw ``count`` proposals; return ``(goals (k, 3), q (k, 6), kept (k,) int,
        in_region (count,) bool)``: the accepted goals, their configurations, their proposal
        indices (increasing) and which proposals lay in the region."""

    @functools.cached_property
    def acceptance(self) -> float:
        """Estimated goals per proposal, from a probe with the fixed seed :data:`PROBE_SEED`.

        Raises
        ------
        UnreachableRegionError
            When the estimate is below ``limits.min_acceptance``.
        """
        rng = np.random.default_rng(PROBE_SEED)
        proposals = hits = 0
        for count in self.limits.probe_rounds:
            hits += len(self._propose(int(count), rng)[0])
            proposals += int(count)
            if hits >= self.limits.probe_hits:
                break
        estimate = hits / proposals
        if estimate < self.limits.min_acceptance:
            bound = f"< {3.0 / proposals:.2g} at 95 %" if hits == 0 else f"~ {estimate:.2g}"
            raise UnreachableRegionError(
                f"region {self.region.name!r} has {'no' if hits == 0 else 'almost no'} goals "
                f"reachable with {self.n_joints} joints from start_q={list(self.start_q)} rad at "
                f"base height {self.base_height} m: {hits} of {proposals} {self.kind} proposals "
                f"accepted (acceptance {bound}; at least {self.limits.min_acceptance:g} needed). "
                f"Region bounds (m, world): {self.region.bounds.tolist()}; the arm reaches "
                f"{reach_ball(self.base_height).radius:.3f} m from the shoulder at "
                f"{list(reach_ball(self.base_height).center)}, and joints above n_joints stay at "
                "start_q"
            )
        return estimate

    def sample(self, n: int, rng: np.random.Generator) -> GoalBatch:
        """Draw ``n`` goals.

        Parameters
        ----------
        n : int
            Number of goals, >= 0.
        rng : numpy.random.Generator
            The only source of randomness: the same generator state gives the same goals.

        Returns
        -------
        GoalBatch
            ``goals (n, 3)`` m (world) in the region, ``q (n, 6)`` rad reaching them.
        """
        n = integer(0, note="number of goals")("n", n)
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"rng must be a numpy.random.Generator; got {type(rng).__name__}")
        acc, lim = self.acceptance, self.limits
        goals, qs = [np.empty((0, 3))], [np.empty((0, 6))]
        have = proposals = in_region = 0
        budget = lim.max_overdraw * (n + lim.probe_hits) / acc
        while have < n:
            need = n - have
            want = need + lim.overdraw_sigmas * math.sqrt(need) + lim.overdraw_sigmas
            count = int(min(lim.max_batch, max(1, math.ceil(want / acc))))
            g, q, kept, inside = self._propose(count, rng)
            if len(kept) >= need:  # stop the count at the proposal that gave the n-th goal
                last = int(kept[need - 1]) + 1
                g, q, inside = g[:need], q[:need], inside[:last]
                count = last
            goals.append(g)
            qs.append(q)
            have += len(g)
            proposals += count
            in_region += int(np.count_nonzero(inside))
            if have < n and proposals > budget:
                raise RuntimeError(
                    f"{self.kind} sampler for region {self.region.name!r}: {have} of {n} goals "
                    f"after {proposals} proposals, far below the probe's acceptance {acc:.3g}"
                )
        return GoalBatch(np.concatenate(goals), np.concatenate(qs), proposals, in_region)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description; :func:`sampler_from_dict` rebuilds the sampler."""
        return {"sampler": self.kind, "region": self.region.to_dict(),
                "n_joints": self.n_joints, "start_q": list(self.start_q),
                "base_height": self.base_height, **self._extra()}

    def _extra(self) -> dict[str, Any]:
        return {}


@dataclass(frozen=True)
class JointSpaceSampler(GoalSampler):
    """The paper's sampler: uniform in joint space, kept inside the region and clear of the plane.

    See :class:`GoalSampler` for the parameters. A proposal is one configuration;
    ``GoalBatch.q`` holds the configuration each goal came from.
    """

    kind: ClassVar[str] = "joint"

    def _propose(self, count: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        q = draw_joint_space(self.n_joints, self.start_q, count, rng)
        goals = ur5kin.fk_world(q, self.base_height)
        inside = self.region.contains(goals)
        candidates = np.flatnonzero(inside)
        kept = candidates[ur5kin.plane_clear(q[candidates], self.base_height)]
        return goals[kept], q[kept], kept, inside


@dataclass(frozen=True)
class CartesianSampler(GoalSampler):
    """Uniform in the region; kept where position IK finds a plane-clear configuration.

    A proposal is a point uniform in the region's bounds cut to the reach ball's box. Joints 1-3
    are solved analytically (:func:`ur5kin.ik_position`, up to 4 solutions) with the wrist
    joints 4-6 at their start angles (3 joints) or, for joints 4..n, at ``wrist_tries`` random
    draws per point (the others at the start). A point is kept when some solution is
    plane-clear; one of those is picked at random. With 4+ joints the kept points are uniform over
    the region's part that one of ``wrist_tries`` random wrist poses reaches, which tends to
    the reachable part as ``wrist_tries`` grows.

    With 2 (or 1) joints the reachable set is a surface (a curve) of zero volume: no uniform
    distribution over it exists inside a volume, so the constructor raises ``ValueError``; use
    :class:`JointSpaceSampler`.

    Parameters
    ----------
    wrist_tries : int
        Random wrist poses tried per point when 4 or more joints move (8 by default).
    """

    wrist_tries: int = 8
    kind: ClassVar[str] = "cartesian"
    MIN_JOINTS: ClassVar[int] = 3
    """Fewest controlled joints with a reachable set of nonzero volume."""

    def __post_init__(self) -> None:
        if isinstance(self.n_joints, int | np.integer) and self.n_joints < self.MIN_JOINTS:
            raise ValueError(
                f"Cartesian sampling needs n_joints >= {self.MIN_JOINTS}; got {self.n_joints}: "
                "with fewer joints tool0 reaches only a surface, so no goal distribution is "
                "uniform in a volume. Use JointSpaceSampler"
            )
        COUNT("wrist_tries", self.wrist_tries)
        super().__post_init__()

    @functools.cached_property
    def sampling_box(self) -> np.ndarray:
        """Where proposals are drawn, ``(2, 3) m`` (world): the region's bounds cut to the box
        around the reach ball.

        Raises
        ------
        UnreachableRegionError
            When the two do not overlap.
        """
        reach = reach_ball(self.base_height).bounds
        box = np.array([np.maximum(self.region.bounds[0], reach[0]),
                        np.minimum(self.region.bounds[1], reach[1])])
        if np.any(box[1] <= box[0]):
            raise UnreachableRegionError(
                f"region {self.region.name!r} (bounds {self.region.bounds.tolist()} m) lies "
                f"outside the box {reach.tolist()} m that holds every tool0 position"
            )
        return box

    def _propose(self, count: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        lo, hi = self.sampling_box
        points = lo + (hi - lo) * rng.random((count, 3))
        inside = self.region.contains(points)
        candidates = np.flatnonzero(inside & reach_ball(self.base_height).contains(points))
        tries = 1 if self.n_joints == 3 else self.wrist_tries
        shape = (len(candidates), tries)
        arm = np.zeros((*shape, 3))  # joints 1-3 come from the IK below; these are ignored
        bound = ur5kin.JOINT_LIMIT
        drawn = rng.uniform(-bound, bound, size=(*shape, self.n_joints - 3))
        wrist = ur5kin.SubChain(self.n_joints, self.start_q).full(
            np.concatenate([arm, drawn], axis=-1))[..., 3:]
        target = to_base(points[candidates], self.base_height)
        q, valid = ur5kin.ik_position(np.broadcast_to(target[:, None, :], wrist.shape), wrist)
        q, valid = q.reshape(len(candidates), -1, 6), valid.reshape(len(candidates), -1)
        ok = np.zeros_like(valid)
        ok[valid] = ur5kin.plane_clear(q[valid], self.base_height)
        score = np.where(ok, rng.random(ok.shape), -1.0)  # a random clear solution per point
        pick = np.argmax(score, axis=1)
        reached = ok.any(axis=1)
        kept = candidates[reached]
        chosen = q[np.flatnonzero(reached), pick[reached]]
        return points[kept], chosen, kept, inside

    def _extra(self) -> dict[str, Any]:
        return {"wrist_tries": self.wrist_tries}


SAMPLERS: dict[str, type[GoalSampler]] = {
    cls.kind: cls for cls in (JointSpaceSampler, CartesianSampler)}
"""The sampler classes by their JSON ``sampler`` key."""


def sampler_from_dict(data: Any) -> GoalSampler:
    """Rebuild a sampler from :meth:`GoalSampler.to_dict` output."""
    if not isinstance(data, dict) or data.get("sampler") not in SAMPLERS:
        raise ValueError(f"a sampler description must be a dict whose 'sampler' is one of "
                         f"{sorted(SAMPLERS)}; got {data!r:.200}")
    params = {k: v for k, v in data.items() if k != "sampler"}
    try:
        params["region"] = region_from_dict(params["region"])
        params["start_q"] = tuple(params["start_q"])
        return SAMPLERS[data["sampler"]](**params)
    except (KeyError, TypeError) as err:
        raise ValueError(f"bad parameters for a {data['sampler']} sampler: {err}") from err
