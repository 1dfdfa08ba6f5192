"""The UR5's collision geometry and its clearance above the ground plane z = 0, batched and fast.

The robot base sits at (0, 0, ``base_height``) of the world (:mod:`ur5kin.world`), so a point
``p`` of link ``k`` (in the link's own frame) lies at world height ``base_height + row_k(q) .
[p, 1]``, where ``row_k`` is the third row of the link's pose in ``base_link``. Two answers are
offered:

- :func:`link_heights`: the exact lowest point of each link's URDF collision geometry. The lowest
  point of a mesh is one of its convex-hull vertices, so it is a min over those. Every height is
  linear in 13 trigonometric features of ``q`` (:data:`FEATURES`), so all candidate vertices'
  heights are one ``(V, 13) @ (13, B)`` product (V = 359 vertices that can be lowest).
- :func:`capsule_heights`: a conservative lower bound, from one capsule per link fitted around
  the same geometry (a capsule's lowest point is an end point's height minus the radius).

:func:`plane_clear` uses the capsules as a filter and a link's exact hull only where its capsule
dips below the margin, so its answer is the exact one at nearly the capsules' cost.

The base link is reported but never checked: it is fixed to its mount at ``base_height``, so its
clearance is a property of the mounting, not of ``q`` (its mesh reaches 3 mm below
``base_link``'s origin, so it touches the plane when ``base_height`` < 0.003 m). The shoulder
link only turns about the vertical axis, so its height never changes either; it is checked
anyway, at no cost.

Self-collisions are not checked: the paper's task has only the plane.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh
from scipy.optimize import minimize
from scipy.spatial import ConvexHull

from ur5kin.checks import joint_array, number
from ur5kin.closed_form import chunked
from ur5kin.meshes import geometry_model
from ur5kin.model import (
    LINK_NAMES,
    UR5Geometry,
    geometry,
)
from ur5kin.world import check_base_height, height_to_world

N_LINKS = 7
"""Links checked: base_link, shoulder_link, upper_arm_link, forearm_link, wrist_1..3_link."""

MOVING_LINKS = slice(1, N_LINKS)
"""Links whose clearance depends on ``q`` (all but the fixed base link): the ones checked."""

CHUNK = 8192
"""Configurations per block of :func:`link_heights` and :func:`capsule_heights` (through
:func:`ur5kin.closed_form.chunked`): bounds the ``(V, block)`` vertex heights (V = 359) to 24 MB."""

FILTER_CHUNK = 32768
"""Configurations per block of :func:`plane_clear` on large batches. Its temporaries are
smaller (at most the 100 witnesses' heights per configuration), and fewer, larger matrix
products matter: a multi-threaded BLAS pays a fixed cost per product, which grows sharply on a
machine whose cores are busy."""

PREFILTER_MIN = 256
"""Batches at least this large go through the capsule filter first in :func:`plane_clear`;
smaller ones straight to the exact heights, which then cost no more than the filter."""

LOOP_MIN = 64
"""From this batch size on, the exact kernel takes each link's minimum in its own call (fast
contiguous reductions) instead of one ``reduceat`` (fewer calls, but slow on large arrays)."""

CIRCLE_FIT_TOL = 1e-9
"""Tolerance (m) of the Nelder-Mead search for a capsule's axis position. The radius is then the
largest distance actually found, so the capsule contains every vertex whatever the search's
accuracy; the tolerance only affects how tight it is."""

CAPSULE_PAD = 1e-9
"""Added to each fitted capsule radius (m): the vertex that sets the radius would otherwise sit
on the surface, where rounding (1e-17 m) can put it outside."""


@dataclass(frozen=True)
class Capsule:
    """A capsule in a link's frame: the points within ``radius`` of the segment ``a``-``b``.

    Attributes
    ----------
    a, b : (3,) float, m, link frame
        End points of the axis segment.
    radius : float, m
    """

    a: tuple[float, float, float]
    b: tuple[float, float, float]
    radius: float

    def distance(self, points: Any) -> np.ndarray:
        """Distance (m) of ``points (..., 3)`` (m, link frame) from the axis segment."""
        p = np.asarray(points, dtype=float)
        a, b = np.asarray(self.a), np.asarray(self.b)
        ab = b - a
        length2 = float(ab @ ab)
        t = np.zeros(p.shape[:-1]) if length2 == 0.0 else np.clip((p - a) @ ab / length2, 0, 1)
        return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)

    def contains(self, points: Any) -> np.ndarray:
        """Whether ``points (..., 3)`` (m, link frame) lie inside the capsule, ``(...) bool``."""
        return self.distance(points) <= self.radius


@dataclass(frozen=True)
class LinkGeometry:
    """The collision geometry of one link, expressed in the link's frame (Pinocchio's ``oMi``).

    Attributes
    ----------
    name : str
        URDF link name.
    vertices : (m, 3) float, m, link frame
        Every vertex of the link's collision meshes (and box corners), as the URDF places them.
    hull : (k, 3) float, m, link frame
        The vertices of their convex hull: the only candidates for the lowest point.
    capsule : Capsule
        A capsule containing every vertex (hence the whole geometry, a capsule being convex).
    """

    name: str
    vertices: np.ndarray
    hull: np.ndarray
    capsule: Capsule


def _geometry_vertices(obj: Any) -> np.ndarray:
    """Vertices ``(m, 3)`` (m) of one Pinocchio collision object in its parent joint's frame."""
    kind = type(obj.geometry).__name__
    if kind == "Box":
        half = np.asarray(obj.geometry.halfSide, dtype=float)
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1], indexing="ij")).reshape(3, -1).T
        local = corners * half
    elif obj.meshPath and obj.meshPath.lower().endswith((".stl", ".dae", ".obj", ".ply")):
        local = np.asarray(trimesh.load(obj.meshPath, force="mesh").vertices, dtype=float)
        local = local * np.asarray(obj.meshScale, dtype=float)
    else:
        raise NotImplementedError(
            f"collision geometry {obj.name!r} is a {kind} ({obj.meshPath!r}); only meshes and "
            "boxes are supported"
        )
    placement = obj.placement
    return local @ np.asarray(placement.rotation).T + np.asarray(placement.translation)


def _fit_capsule(points: np.ndarray) -> Capsule:
    """The smallest-volume capsule, over a few candidate axes, that contains ``points (m, 3)``.

    Candidate axis directions are the link frame's axes and the points' principal axes. For each,
    the axis line goes through the centre of the (numerically) smallest circle around the points
    projected across it; the radius is the largest distance from that line; the segment is then
    as short as containment allows: a point at axial coordinate ``t`` and distance ``rho`` from
    the line is inside iff the segment reaches ``t -+ sqrt(r^2 - rho^2)``.
    """
    centred = points - points.mean(axis=0)
    _, _, principal = np.linalg.svd(centred, full_matrices=False)
    best: tuple[float, Capsule] | None = None
    for axis in np.vstack([np.eye(3), principal]):
        axis = axis / np.linalg.norm(axis)
        helper = np.eye(3)[np.argmin(np.abs(axis))]
        u = np.cross(axis, helper)
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        flat = points @ np.stack([u, v], axis=1)

        def spread(c: np.ndarray, flat: np.ndarray = flat) -> float:
            return float(np.max(np.linalg.norm(flat - c, axis=1)))

        start = 0.5 * (flat.min(axis=0) + flat.max(axis=0))
        res = minimize(spread, start, method="Nelder-Mead",
                       options={"xatol": CIRCLE_FIT_TOL, "fatol": CIRCLE_FIT_TOL})
        centre2 = res.x if spread(res.x) <= spread(start) else start
        fit = spread(centre2)
        rho = np.linalg.norm(flat - centre2, axis=1)
        t = points @ axis
        half_chord = np.sqrt(np.maximum(fit**2 - rho**2, 0.0))
        radius = fit + CAPSULE_PAD
        lo, hi = float(np.min(t + half_chord)), float(np.max(t - half_chord))
        lo, hi = min(lo, hi), max(lo, hi)
        origin = centre2[0] * u + centre2[1] * v
        volume = np.pi * radius**2 * (hi - lo) + 4.0 / 3.0 * np.pi * radius**3
        cap = Capsule(tuple(origin + lo * axis), tuple(origin + hi * axis), radius)
        if best is None or volume < best[0]:
            best = (volume, cap)
    assert best is not None
    return best[1]


@functools.cache
def collision_geometry() -> tuple[LinkGeometry, ...]:
    """The collision geometry of the 7 links, read from the URDF through Pinocchio (cached).

    Returns
    -------
    links : tuple of 7 LinkGeometry
        base_link .. wrist_3_link, in the order of :data:`ur5kin.LINK_NAMES`. Geometry on links
        fixed to a joint's link (``ee_link``'s box on ``wrist_3_link``) joins that link.
    """
    geom = geometry_model("collision")
    per_link: list[list[np.ndarray]] = [[] for _ in range(N_LINKS)]
    for obj in geom.geometryObjects:
        per_link[obj.parentJoint].append(_geometry_vertices(obj))
    links = []
    for name, parts in zip(LINK_NAMES, per_link, strict=True):
        if not parts:
            raise RuntimeError(f"the URDF gives {name} no collision geometry")
        vertices = np.vstack(parts)
        hull = vertices[ConvexHull(vertices).vertices]
        links.append(LinkGeometry(name, vertices, hull, _fit_capsule(hull)))
    return tuple(links)


FEATURES = ("1", "sa", "ca", "sb", "cb", "sc", "cc", "sc*c5", "sc*s5", "sc*c5*c6", "cc*s6",
            "cc*c6", "sc*c5*s6")
"""Trigonometric features of ``q`` that every link's height row is linear in (see
:func:`_row_coefficients`): ``a``, ``b``, ``c`` are the absolute pitches of the upper arm, the
forearm and the wrist (``a = q2 + lift_offset``, ``b = a + q3``, ``c = b + q4 + wrist_offset``),
``s``/``c`` prefixes their sines/cosines, ``s5, c5, s6, c6`` those of joints 5 and 6."""


def _row_coefficients(g: UR5Geometry) -> np.ndarray:
    """Constant ``A (13, 7, 4)`` with ``rows = features @ A``: the third row of each link's pose in
    ``base_link`` (``z = row . [p, 1]`` for a point ``p`` of the link, m, in its frame).

    Written out for the chain of :class:`ur5kin.UR5Geometry`: the shoulder pan turns about z, so
    no height depends on joint 1; the third rows of ``Ry(a)``, ``Ry(c) Rz(q5)`` and
    ``Ry(c) Rz(q5) Ry(q6)`` are ``(-sa, 0, ca)``, ``(-sc c5, sc s5, cc)`` and
    ``(-sc c5 c6 - cc s6, sc s5, cc c6 - sc c5 s6)``; the origins' heights add the upper arm, the
    forearm and the wrist-2 link along their pitches.
    """
    f = {name: i for i, name in enumerate(FEATURES)}
    A = np.zeros((len(FEATURES), N_LINKS, 4))
    A[f["1"], 0, 2] = 1.0  # base_link: fixed
    A[f["1"], 1, 2], A[f["1"], 1, 3] = 1.0, g.d1  # shoulder_link: turns about z only
    A[f["sa"], 2, 0], A[f["ca"], 2, 2], A[f["1"], 2, 3] = -1.0, 1.0, g.d1  # upper_arm_link
    A[f["sb"], 3, 0], A[f["cb"], 3, 2] = -1.0, 1.0  # forearm_link
    A[f["1"], 3, 3], A[f["ca"], 3, 3] = g.d1, g.upper_arm
    for k in (4, 5, 6):  # wrist_1..3 origins share the forearm's end height
        A[f["1"], k, 3], A[f["ca"], k, 3], A[f["cb"], k, 3] = g.d1, g.upper_arm, g.forearm
    A[f["sc"], 4, 0], A[f["cc"], 4, 2] = -1.0, 1.0  # wrist_1_link
    A[f["sc*c5"], 5, 0], A[f["sc*s5"], 5, 1], A[f["cc"], 5, 2] = -1.0, 1.0, 1.0  # wrist_2_link
    A[f["sc*c5*c6"], 6, 0], A[f["cc*s6"], 6, 0] = -1.0, -1.0  # wrist_3_link
    A[f["sc*s5"], 6, 1] = 1.0
    A[f["cc*c6"], 6, 2], A[f["sc*c5*s6"], 6, 2] = 1.0, -1.0
    A[f["cc"], 6, 3] = g.wrist_2
    return A


@functools.cache
def _angle_offsets() -> tuple[float, float]:
    """Offsets (rad) of the pitches ``a = q2 + lift`` and ``c = q2 + q3 + q4 + lift + wrist``."""
    g = geometry()
    return g.lift_offset, g.wrist_offset


def _features(q: np.ndarray) -> np.ndarray:
    """The :data:`FEATURES` of ``q (B, 6)`` rad, as ``(13, B)`` (one contiguous row each).

    Written with ``out=`` operations into one array: on the env's ``(20, 6)`` batches the cost
    is the number of numpy calls, not the arithmetic.
    """
    lift, wrist = _angle_offsets()
    qt = q.T
    angles = np.empty((5, len(q)))
    np.add(qt[1], lift, out=angles[0])  # a
    np.add(angles[0], qt[2], out=angles[1])  # b
    np.add(angles[1], qt[3], out=angles[2])  # c, before its offset
    angles[2] += wrist
    angles[3:] = qt[4:6]
    s, c = np.sin(angles), np.cos(angles)
    out = np.empty((len(FEATURES), len(q)))
    out[0] = 1.0
    out[1:7:2] = s[:3]  # sa, sb, sc
    out[2:7:2] = c[:3]  # ca, cb, cc
    np.multiply(s[2], c[3], out=out[7])  # sc*c5
    np.multiply(s[2], s[3], out=out[8])  # sc*s5
    np.multiply(out[7], c[4], out=out[9])  # sc*c5*c6
    np.multiply(c[2], s[4], out=out[10])  # cc*s6
    np.multiply(c[2], c[4], out=out[11])  # cc*c6
    np.multiply(out[7], s[4], out=out[12])  # sc*c5*s6
    return out


def _lowest_candidates(points: np.ndarray, coefficients: np.ndarray) -> np.ndarray:
    """The points of one link that can be its lowest for some ``q``.

    ``coefficients (13, 4)`` is the link's slice of :func:`_row_coefficients`. Only the
    coordinates whose row entry varies with ``q`` matter: the lowest point is a vertex of the hull
    of the points projected onto them (a single point when the row is constant).
    """
    varying = [j for j in range(3) if np.any(coefficients[1:, j])]
    if not varying:
        heights = points @ coefficients[0, :3]
        return points[[int(np.argmin(heights))]]
    flat = points[:, varying]
    if len(varying) == 1:
        return points[[int(np.argmin(flat[:, 0])), int(np.argmax(flat[:, 0]))]]
    return points[ConvexHull(flat).vertices]


WITNESS_DIRECTIONS = np.array(
    [d for d in np.ndindex(3, 3, 3) if d != (1, 1, 1)], dtype=float) - 1.0
"""The 26 directions (faces, edges and corners of a cube, in a link's frame) along which each
link's extreme vertices become its *witnesses*: real vertices, so the lowest of them is an upper
bound of the link's lowest point."""


@dataclass(frozen=True)
class _Kernels:
    """Constant matrices of the height kernels: each height is one product with the features.

    ``vertex_heights (V, 13) @ features (13, B)`` gives the height above ``base_link`` of every
    vertex that can be a link's lowest, link after link (rows ``bounds[k]:bounds[k + 1]``);
    ``witness_heights`` and ``witness_bounds`` the same for each link's witnesses;
    ``end_heights (14, 13)`` for the capsules' end points (rows 2k, 2k + 1); ``radii (7, 1)``.
    """

    vertex_heights: np.ndarray
    bounds: np.ndarray
    witness_heights: np.ndarray
    witness_bounds: np.ndarray
    end_heights: np.ndarray
    radii: np.ndarray


def _stack(blocks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    bounds = np.concatenate([[0], np.cumsum([len(b) for b in blocks])]).astype(np.intp)
    return np.vstack(blocks), bounds


@functools.cache
def _kernels() -> _Kernels:
    """Build the :class:`_Kernels` once from the collision geometry."""
    A = _row_coefficients(geometry())
    links = collision_geometry()
    vertices, witnesses, ends = [], [], np.ones((N_LINKS, 4, 2))
    for k, link in enumerate(links):
        points = _lowest_candidates(link.hull, A[:, k])
        extreme = np.unique(np.argmax(points @ WITNESS_DIRECTIONS.T, axis=0))
        for block, chosen in ((vertices, points), (witnesses, points[extreme])):
            block.append(np.hstack([chosen, np.ones((len(chosen), 1))]) @ A[:, k].T)
        ends[k, :3, 0], ends[k, :3, 1] = link.capsule.a, link.capsule.b
    end_heights = np.einsum("fkj,kje->kef", A, ends).reshape(2 * N_LINKS, len(FEATURES))
    radii = np.array([[link.capsule.radius] for link in links])
    return _Kernels(*_stack(vertices), *_stack(witnesses), end_heights, radii)


def height_table() -> tuple[np.ndarray, np.ndarray, float, float]:
    """The exact check's constants, for code that evaluates :func:`link_heights` itself (the
    compiled dynamics): ``vertex_heights (V, 13)`` m, the height above ``base_link`` of every
    vertex that can be a link's lowest as a product with the :data:`FEATURES` of ``q``;
    ``bounds (8,) int``, link k's rows ``bounds[k]:bounds[k + 1]``; and the pitch offsets
    ``lift, wrist`` (rad) the features use (``a = q2 + lift``, ``c = q2 + q3 + q4 + lift +
    wrist``)."""
    kernels = _kernels()
    lift, wrist = _angle_offsets()
    return kernels.vertex_heights, kernels.bounds, float(lift), float(wrist)


def _link_minima(heights: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Per-link minima ``(7, B)`` of stacked per-vertex heights ``(V, B)``."""
    if heights.shape[1] < LOOP_MIN:
        return np.minimum.reduceat(heights, bounds[:-1], axis=0)
    out = np.empty((len(bounds) - 1, heights.shape[1]))
    for k in range(len(bounds) - 1):
        np.min(heights[bounds[k] : bounds[k + 1]], axis=0, out=out[k])
    return out


def _exact(flat: np.ndarray) -> np.ndarray:
    """Exact lowest height of each link above ``base_link``, ``(B, 7)``, for ``flat (B, 6)``."""
    kernels = _kernels()
    return _link_minima(kernels.vertex_heights @ _features(flat), kernels.bounds).T


def _capsule_lows(features: np.ndarray) -> np.ndarray:
    """Lowest capsule point of each link above ``base_link``, ``(7, B)``, from ``(13, B)``."""
    kernels = _kernels()
    ends = kernels.end_heights @ features
    return np.minimum(ends[0::2], ends[1::2]) - kernels.radii


def _capsules(flat: np.ndarray) -> np.ndarray:
    """Lowest capsule point of each link above ``base_link``, ``(B, 7)``, for ``flat (B, 6)``."""
    return _capsule_lows(_features(flat)).T


def _clear_filtered(flat: np.ndarray, threshold: float) -> np.ndarray:
    """Exact clearance ``(B,) bool`` of the moving links, at ``threshold`` m above base_link.

    Three tiers, each deciding what it can: a capsule above the threshold proves its link clear;
    a witness vertex below it proves the configuration blocked; each (configuration, link) pair
    left gets the exact min over that link's vertices.
    """
    kernels = _kernels()
    features = _features(flat)
    unsure = _capsule_lows(features)[MOVING_LINKS] < threshold  # (6, B)
    rows = np.flatnonzero(unsure.any(axis=0))
    clear = np.ones(len(flat), dtype=bool)
    if not len(rows):
        return clear
    sub = features[:, rows]
    witnessed = _link_minima(kernels.witness_heights @ sub, kernels.witness_bounds)
    blocked = (witnessed[MOVING_LINKS] < threshold).any(axis=0)
    open_rows = ~blocked
    # Lower links first: the wrist is the likeliest to reach the plane, and the cheapest.
    for k in reversed(range(MOVING_LINKS.start, N_LINKS)):
        idx = np.flatnonzero(unsure[k - MOVING_LINKS.start, rows] & open_rows)
        if len(idx):
            block = kernels.vertex_heights[kernels.bounds[k] : kernels.bounds[k + 1]]
            open_rows[idx] = (block @ sub[:, idx]).min(axis=0) >= threshold
    clear[rows] = open_rows
    return clear


def link_heights(q: Any, base_height: float) -> np.ndarray:
    """Exact height of each link's lowest collision-geometry point above the plane.

    Parameters
    ----------
    q : (..., 6) float array_like, rad
        Joint angles, joints 1-6.
    base_height : float, m
        Height of ``base_link``'s origin above the plane (world z = 0).

    Returns
    -------
    heights : (..., 7) float, m, world frame
        Lowest point of base_link, shoulder_link, upper_arm_link, forearm_link, wrist_1_link,
        wrist_2_link, wrist_3_link (with ``ee_link``'s box); negative = below the plane.

    Raises
    ------
    ValueError
        When ``q`` is not ``(..., 6)`` finite or ``base_height`` is not a finite number >= 0.
    """
    q = joint_array(q)
    return height_to_world(chunked(_exact, q, (N_LINKS,), CHUNK), base_height)


def capsule_heights(q: Any, base_height: float) -> np.ndarray:
    """Lowest point of each link's capsule: a lower bound of :func:`link_heights`, ``(..., 7)`` m.

    Conservative by construction (each capsule contains its link's geometry); a few times cheaper
    than the exact heights for large batches. Parameters as :func:`link_heights`.
    """
    q = joint_array(q)
    return height_to_world(chunked(_capsules, q, (N_LINKS,), CHUNK), base_height)


def plane_clear(q: Any, base_height: float, margin: float = 0.0) -> np.ndarray:
    """Whether every moving link stays at least ``margin`` above the plane.

    Parameters
    ----------
    q : (..., 6) float array_like, rad
    base_height : float, m
        Height of ``base_link``'s origin above the plane.
    margin : float, m
        Required clearance; a link exactly ``margin`` above the plane counts as clear.

    Returns
    -------
    clear : (...) bool
        ``link_heights(q, base_height)[..., 1:].min(-1) >= margin`` (the fixed base link is not
        checked). Batches of :data:`PREFILTER_MIN` or more are evaluated on the capsules first,
        and on a link's exact geometry only where its capsule reaches below ``margin``.
    """
    q = joint_array(q)
    h = check_base_height(base_height)
    margin = number(note="m")("margin", margin)
    threshold = margin - h  # the margin as a height above base_link (ur5kin.world)

    def clear(flat: np.ndarray) -> np.ndarray:
        if len(flat) < PREFILTER_MIN:
            return _exact(flat)[:, MOVING_LINKS].min(axis=-1) >= threshold
        return _clear_filtered(flat, threshold)

    return chunked(clear, q, (), FILTER_CHUNK, dtype=bool)
