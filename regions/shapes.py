"""Goal constraint regions as geometry: boxes, z-limits, balls, meshes and their intersections.

Every region lives in the task's world frame (ground plane z = 0, m). A region answers
``contains``, has axis-aligned ``bounds``, a ``volume`` (``volume_is_exact`` says whether it is
analytic or estimated), a trimesh ``mesh`` for drawing and export, and a JSON form
(:meth:`Region.to_dict` / :func:`region_from_dict`) that round-trips.
"""

from __future__ import annotations

import abc
import functools
import math
import pathlib
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from ur5kin.checks import Combination, check_fields, kinds, number, real_array, vector

if TYPE_CHECKING:
    import trimesh

VOLUME_GRID_CELLS = 128
"""Cells per axis of the midpoint grid over the bounds that estimates a volume with no closed
form (an intersection of a mesh or ball with something it only partly overlaps). The error is
about (surface area) x (cell size) / 2 at worst, and usually far less as errors of either sign
cancel."""

REVOLVE_SECTIONS = 128
"""Angular sections of the surfaces of revolution that mesh balls and cut balls. The meshed
volume falls short of the exact one by a factor of about 1 - (2 pi / 128)^2 / 6 = 4e-4."""

ARC_SEGMENTS = 64
"""Segments of the meridian arc of a ball's mesh (from its lowest to its highest point)."""

AXIS_SNAP = 1e-6
"""Profile points closer to the axis of revolution than this fraction of the radius are put on
it (cos(pi/2) is 6e-17, not 0, and a cut a hair below a pole leaves a cap of radius ~1e-8), so
that the revolved mesh closes instead of keeping a sliver of degenerate triangles."""

WINDING_CHUNK = 1 << 21
"""Point x triangle pairs per block of the winding-number test of :class:`MeshRegion`."""

WINDING_INSIDE = 0.5
"""Generalised winding number above which a point is inside a mesh (1 inside, 0 outside)."""


def as_points(points: Any, name: str = "points") -> np.ndarray:
    """Return ``points`` as a float ``(..., 3)`` array (m), or raise ``ValueError``."""
    arr = real_array(points, name, "positions in m")
    if arr.ndim == 0 or arr.shape[-1] != 3:
        raise ValueError(f"{name} must have shape (n, 3) (x, y, z in m, world frame); "
                         f"got shape {arr.shape}")
    if np.isnan(arr).any():
        raise ValueError(f"{name} must not contain NaN")
    return arr


LIMITS = vector(2, "lo, hi in m, world frame")
"""A box's limits along one axis."""

Z_LIMIT = number(finite=False, note="m, world frame; null or inf: unbounded")
"""A z-limit's zmin or zmax."""


def ordered(*pairs: tuple[str, str]) -> list[Combination]:
    """The rules ``lo < hi`` of a region's bounds, for :func:`check_fields`: each ``(field of
    lo, field of hi)``, or an axis field holding both as ``(axis, "")``."""
    return [(f"{lo}, {hi}" if hi else lo, f"{lo} < {hi} (m)" if hi else "lo < hi (m)",
             lambda r, lo=lo, hi=hi: (
        getattr(r, lo)[0] < getattr(r, lo)[1] if not hi else getattr(r, lo) < getattr(r, hi)))
        for lo, hi in pairs]


class Region(abc.ABC):
    """A goal constraint region: a set of positions in the world frame (m).

    Subclasses are frozen dataclasses with a ``name`` field; :attr:`kind` names the class in the
    JSON form.
    """

    kind: ClassVar[str]
    name: str

    @abc.abstractmethod
    def contains(self, points: Any) -> np.ndarray:
        """Which points lie in the region (boundary included).

        Parameters
        ----------
        points : (..., 3) float array_like, m, world frame

        Returns
        -------
        inside : (...) bool
        """

    @property
    @abc.abstractmethod
    def bounds(self) -> np.ndarray:
        """Axis-aligned bounds, ``(2, 3) float, m, world frame``: ``[[xmin, ymin, zmin],
        [xmax, ymax, zmax]]``; infinite where the region is unbounded."""

    @property
    def volume(self) -> float:
        """Volume (m^3); ``inf`` when unbounded. See :attr:`volume_is_exact`."""
        return float(self.mesh.volume)

    @property
    def volume_is_exact(self) -> bool:
        """Whether :attr:`volume` is analytic (else a grid estimate, see VOLUME_GRID_CELLS)."""
        return True

    @property
    @abc.abstractmethod
    def mesh(self) -> trimesh.Trimesh:
        """A closed triangle mesh of the region (m, world frame), for drawing and export.

        Raises
        ------
        ValueError
            When the region is unbounded.
        """

    @abc.abstractmethod
    def _params(self) -> dict[str, Any]:
        """The JSON-ready parameters of the region (without ``kind`` and ``name``)."""

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description; :func:`region_from_dict` rebuilds an equal region."""
        return {"kind": self.kind, "name": self.name, **self._params()}

    @property
    def is_bounded(self) -> bool:
        """Whether every bound is finite."""
        return bool(np.all(np.isfinite(self.bounds)))


@dataclass(frozen=True)
class Box(Region):
    """An axis-aligned box ``x[0] <= x <= x[1]``, ``y[0] <= y <= y[1]``, ``z[0] <= z <= z[1]``.

    Parameters
    ----------
    x, y, z : (2,) float, m, world frame
        Lower and upper limits, finite, lower < upper.
    name : str
    """

    x: tuple[float, float]
    y: tuple[float, float]
    z: tuple[float, float]
    name: str = "box"
    kind: ClassVar[str] = "box"

    def __post_init__(self) -> None:
        check_fields(self, kinds((LIMITS, "x", "y", "z")), "Box",
                     ordered(("x", ""), ("y", ""), ("z", "")))

    @classmethod
    def from_limits(cls, limits: Any, name: str = "box") -> Box:
        """A box from six numbers ``xmin, xmax, ymin, ymax, zmin, zmax`` (m)."""
        values = np.asarray(limits, dtype=float).ravel().tolist()  # floats the message shows
        if len(values) != 6:
            raise ValueError(f"a box needs six numbers xmin, xmax, ymin, ymax, zmin, zmax (m); "
                             f"got {len(values)}: {limits!r}")
        return cls(tuple(values[0:2]), tuple(values[2:4]), tuple(values[4:6]), name)

    def contains(self, points: Any) -> np.ndarray:
        p = as_points(points)
        inside = p[..., 0] >= self.x[0]  # column by column: 3x faster than all(axis=-1)
        for axis, (lo, hi) in enumerate((self.x, self.y, self.z)):
            if axis:
                inside &= p[..., axis] >= lo
            inside &= p[..., axis] <= hi
        return inside

    @property
    def bounds(self) -> np.ndarray:
        return np.array([self.x, self.y, self.z]).T

    @property
    def volume(self) -> float:
        return float(np.prod(np.diff(self.bounds, axis=0)))

    @property
    def mesh(self) -> trimesh.Trimesh:
        import trimesh  # on first use: importing regions stays light

        return trimesh.creation.box(bounds=self.bounds)

    def _params(self) -> dict[str, Any]:
        return {"x": list(self.x), "y": list(self.y), "z": list(self.z)}


@dataclass(frozen=True)
class ZLimit(Region):
    """A horizontal slab ``zmin <= z <= zmax``, unbounded in x and y (a z-limit).

    Parameters
    ----------
    zmin, zmax : float, m, world frame
        ``zmax`` may be ``inf`` (a half-space above ``zmin``); in JSON an infinite limit is
        ``null``.
    name : str

    Intersect it with a bounded region (for instance :func:`regions.reach_ball`) for a finite
    volume and a mesh.
    """

    zmin: float = 0.0
    zmax: float = math.inf
    name: str = "zlimit"
    kind: ClassVar[str] = "zlimit"

    def __post_init__(self) -> None:
        for name, unbounded in (("zmin", -math.inf), ("zmax", math.inf)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, unbounded)
        check_fields(self, kinds((Z_LIMIT, "zmin", "zmax")), "ZLimit", ordered(("zmin", "zmax")))

    def contains(self, points: Any) -> np.ndarray:
        z = as_points(points)[..., 2]
        return (z >= self.zmin) & (z <= self.zmax)

    @property
    def bounds(self) -> np.ndarray:
        return np.array([[-np.inf, -np.inf, self.zmin], [np.inf, np.inf, self.zmax]])

    @property
    def volume(self) -> float:
        return math.inf

    @property
    def mesh(self) -> trimesh.Trimesh:
        raise ValueError(f"region {self.name!r} (z in [{self.zmin}, {self.zmax}] m) is unbounded "
                         "and has no mesh; intersect it with a bounded region")

    def _params(self) -> dict[str, Any]:
        return {"zmin": self.zmin if np.isfinite(self.zmin) else None,
                "zmax": self.zmax if np.isfinite(self.zmax) else None}


def _revolved(center: np.ndarray, radius: float, z_lo: float, z_hi: float) -> trimesh.Trimesh:
    """Mesh of the part of a ball (centre, radius, m) with z_lo <= z <= z_hi, by revolution."""
    import trimesh  # on first use: importing regions stays light

    t_lo = math.asin(np.clip((z_lo - center[2]) / radius, -1.0, 1.0))
    t_hi = math.asin(np.clip((z_hi - center[2]) / radius, -1.0, 1.0))
    theta = np.linspace(t_lo, t_hi, ARC_SEGMENTS + 1)
    arc = np.column_stack([radius * np.cos(theta), center[2] + radius * np.sin(theta)])
    arc[np.abs(arc[:, 0]) <= AXIS_SNAP * radius, 0] = 0.0  # the poles lie on the axis exactly
    profile = np.vstack([[0.0, arc[0, 1]], arc, [0.0, arc[-1, 1]]])
    profile = profile[np.r_[True, np.any(np.diff(profile, axis=0) != 0.0, axis=1)]]
    mesh = trimesh.creation.revolve(profile, sections=REVOLVE_SECTIONS)
    mesh.apply_translation([center[0], center[1], 0.0])
    return mesh


def _ball_zone_volume(center_z: float, radius: float, z_lo: float, z_hi: float) -> float:
    """Exact volume (m^3) of the part of a ball between two heights (m)."""
    a = np.clip(z_lo - center_z, -radius, radius)
    b = np.clip(z_hi - center_z, -radius, radius)
    return float(np.pi * (radius**2 * (b - a) - (b**3 - a**3) / 3.0))


@dataclass(frozen=True)
class Ball(Region):
    """The closed ball of ``radius`` (m) around ``center`` (m, world frame)."""

    center: tuple[float, float, float]
    radius: float
    name: str = "ball"
    kind: ClassVar[str] = "ball"

    def __post_init__(self) -> None:
        check_fields(self, {"center": vector(3, "m, world frame"),
                            "radius": number(0, above=True, note="m")}, "Ball")

    def contains(self, points: Any) -> np.ndarray:
        d = as_points(points) - np.asarray(self.center)
        return np.einsum("...i,...i->...", d, d) <= self.radius**2

    @property
    def bounds(self) -> np.ndarray:
        c = np.asarray(self.center)
        return np.array([c - self.radius, c + self.radius])

    @property
    def volume(self) -> float:
        return 4.0 / 3.0 * np.pi * self.radius**3

    @property
    def mesh(self) -> trimesh.Trimesh:
        c = np.asarray(self.center)
        return _revolved(c, self.radius, c[2] - self.radius, c[2] + self.radius)

    def _params(self) -> dict[str, Any]:
        return {"center": list(self.center), "radius": self.radius}


def _box_bounds(bounds: np.ndarray) -> np.ndarray:
    return np.array([np.max(bounds[:, 0], axis=0), np.min(bounds[:, 1], axis=0)])


@dataclass(frozen=True)
class Intersection(Region):
    """The points inside every one of ``parts``.

    ``volume`` is exact when the parts are boxes and z-limits (a box), or those and one ball
    whose x-y extent the box part spans (a ball cut by two heights: a closed form), or when the
    box part lies inside the ball; otherwise it is estimated on a midpoint grid of
    :data:`VOLUME_GRID_CELLS` cells per axis. ``mesh`` is available in the exact cases.
    """

    parts: tuple[Region, ...]
    name: str = "intersection"
    kind: ClassVar[str] = "intersection"

    def __post_init__(self) -> None:
        parts = tuple(self.parts)
        if not parts or not all(isinstance(p, Region) for p in parts):
            raise ValueError(f"Intersection needs one or more Region parts; got {self.parts!r}")
        object.__setattr__(self, "parts", parts)

    def contains(self, points: Any) -> np.ndarray:
        p = as_points(points)
        inside = np.ones(p.shape[:-1], dtype=bool)
        for part in self.parts:
            inside &= part.contains(p)
        return inside

    @property
    def bounds(self) -> np.ndarray:
        return _box_bounds(np.stack([part.bounds for part in self.parts]))

    def _closed_form(self) -> tuple[str, np.ndarray, Ball | None] | None:
        """The intersection as a known shape, when it is one.

        Returns ``("empty", box, None)``, ``("box", box, None)`` (an axis-aligned box, maybe
        unbounded), ``("zone", box, ball)`` (the ball between the heights ``box[:, 2]``) or None
        (anything else: a mesh, two balls, a box cutting a ball's sides).
        """
        boxes = [p for p in self.parts if isinstance(p, Box | ZLimit)]
        balls = [p for p in self.parts if isinstance(p, Ball)]
        if len(boxes) + len(balls) != len(self.parts) or len(balls) > 1:
            return None
        box = _box_bounds(np.stack([b.bounds for b in boxes])) if boxes else np.array(
            [[-np.inf] * 3, [np.inf] * 3])
        if not balls:
            return ("empty" if np.any(box[1] <= box[0]) else "box"), box, None
        ball = balls[0]
        c, r = np.asarray(ball.center), ball.radius
        box = np.array([np.maximum(box[0], c - r), np.minimum(box[1], c + r)])
        if np.any(box[1] <= box[0]):
            return "empty", box, None
        if np.all(box[0, :2] <= c[:2] - r) and np.all(box[1, :2] >= c[:2] + r):
            return "zone", box, ball
        corners = np.array(np.meshgrid(*box.T, indexing="ij")).reshape(3, -1).T
        if np.all(ball.contains(corners)):
            return "box", box, None
        return None

    @property
    def volume(self) -> float:
        form = self._closed_form()
        if form is None:
            return _grid_volume(self)
        kind, box, ball = form
        if kind == "empty":
            return 0.0
        if kind == "zone":
            assert ball is not None
            return _ball_zone_volume(ball.center[2], ball.radius, box[0, 2], box[1, 2])
        return float(np.prod(box[1] - box[0]))

    @property
    def volume_is_exact(self) -> bool:
        return self._closed_form() is not None

    @property
    def mesh(self) -> trimesh.Trimesh:
        import trimesh  # on first use: importing regions stays light

        form = self._closed_form()
        if form is not None and form[0] == "zone":
            _, box, ball = form
            assert ball is not None
            return _revolved(np.asarray(ball.center), ball.radius, box[0, 2], box[1, 2])
        if form is not None and form[0] == "box" and np.all(np.isfinite(form[1])):
            return trimesh.creation.box(bounds=form[1])
        raise ValueError(
            f"no mesh for intersection {self.name!r} of {[p.kind for p in self.parts]}: only "
            "boxes, z-limits and a ball cut by heights (or containing the box) are meshed"
        )

    def _params(self) -> dict[str, Any]:
        return {"parts": [part.to_dict() for part in self.parts]}


def _grid_volume(region: Region) -> float:
    """Midpoint-grid estimate (m^3) of a region's volume over its bounds."""
    bounds = region.bounds
    if not np.all(np.isfinite(bounds)):
        return math.inf
    if np.any(bounds[1] <= bounds[0]):
        return 0.0
    n = VOLUME_GRID_CELLS
    step = (bounds[1] - bounds[0]) / n
    axes = [lo + (np.arange(n) + 0.5) * h for lo, h in zip(bounds[0], step, strict=True)]
    inside = 0
    for x in axes[0]:  # one x-slab at a time keeps the memory at n^2 points
        slab = np.stack(np.meshgrid([x], axes[1], axes[2], indexing="ij"), axis=-1)
        inside += int(np.count_nonzero(region.contains(slab.reshape(-1, 3))))
    return float(inside * np.prod(step))


class MeshRegion(Region):
    """The inside of a closed (watertight) triangle mesh, in the world frame (m).

    ``contains`` uses the generalised winding number (exact for closed meshes, no spatial
    index needed): a point is inside when the triangles' solid angles add up to a full sphere.
    Convex meshes use their face planes instead. ``volume`` is the mesh's exact volume.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        Watertight, consistently wound; it is copied and oriented outwards.
    name : str
    source : str or None
        Where the mesh came from (a file path), recorded in the JSON form.
    """

    kind: ClassVar[str] = "mesh"

    def __init__(self, mesh: trimesh.Trimesh, name: str = "mesh", source: str | None = None):
        import trimesh  # on first use: importing regions stays light

        if not isinstance(mesh, trimesh.Trimesh):
            raise ValueError(f"MeshRegion needs a trimesh.Trimesh; got {type(mesh).__name__}")
        mesh = mesh.copy()
        if len(mesh.faces) == 0 or not mesh.is_watertight or not mesh.is_winding_consistent:
            raise ValueError(
                f"mesh region {name!r} must be a closed (watertight) and consistently wound "
                f"triangle mesh; got {len(mesh.faces)} faces, watertight={mesh.is_watertight}, "
                f"winding consistent={mesh.is_winding_consistent}"
            )
        if mesh.volume < 0.0:
            mesh.invert()
        if not mesh.volume > 0.0:
            raise ValueError(f"mesh region {name!r} encloses no volume ({mesh.volume} m^3)")
        self._mesh = mesh
        self.name = name
        self.source = source
        self._convex = bool(mesh.is_convex)

    @classmethod
    def from_file(cls, path: str | pathlib.Path, name: str | None = None) -> MeshRegion:
        """Load a mesh file (STL, OBJ, PLY, ...; coordinates in m, world frame)."""
        import trimesh  # on first use: importing regions stays light

        path = pathlib.Path(path)
        if not path.is_file():
            raise ValueError(f"mesh file {str(path)!r} does not exist")
        try:
            mesh = trimesh.load(str(path), force="mesh")
        except Exception as err:  # trimesh raises many types for unreadable files
            raise ValueError(f"could not read a triangle mesh from {str(path)!r}: {err}") from err
        return cls(mesh, name=name or path.stem, source=str(path))

    def __repr__(self) -> str:
        return (f"MeshRegion(name={self.name!r}, faces={len(self._mesh.faces)}, "
                f"volume={self._mesh.volume:.6g} m^3)")

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, MeshRegion) and self.name == other.name
                and np.array_equal(self._mesh.vertices, other._mesh.vertices)
                and np.array_equal(self._mesh.faces, other._mesh.faces))

    __hash__ = None  # type: ignore[assignment]

    def contains(self, points: Any) -> np.ndarray:
        p = as_points(points)
        flat = p.reshape(-1, 3)
        if self._convex:
            normals, origins = self._mesh.face_normals, self._mesh.triangles[:, 0]
            offsets = np.einsum("fi,fi->f", normals, origins)
            inside = np.all(flat @ normals.T <= offsets, axis=-1)
        else:
            inside = self._winding(flat) > WINDING_INSIDE
        return inside.reshape(p.shape[:-1])

    def _winding(self, points: np.ndarray) -> np.ndarray:
        """Generalised winding numbers ``(n,)`` (Van Oosterom and Strackee's solid angles)."""
        tri = self._mesh.triangles
        out = np.empty(len(points))
        step = max(1, WINDING_CHUNK // len(tri))
        for start in range(0, len(points), step):
            d = tri[None, :, :, :] - points[start : start + step, None, None, :]
            a, b, c = d[..., 0, :], d[..., 1, :], d[..., 2, :]
            la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
            dot = functools.partial(np.einsum, "...i,...i->...")
            det = dot(a, np.cross(b, c))
            den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb
            out[start : start + step] = np.arctan2(det, den).sum(axis=-1) / (2.0 * np.pi)
        return out

    @property
    def bounds(self) -> np.ndarray:
        return np.array(self._mesh.bounds, dtype=float)

    @property
    def volume(self) -> float:
        return float(self._mesh.volume)

    @property
    def mesh(self) -> trimesh.Trimesh:
        return self._mesh.copy()

    def _params(self) -> dict[str, Any]:
        return {"vertices": self._mesh.vertices.tolist(), "faces": self._mesh.faces.tolist(),
                "source": self.source}


KINDS: dict[str, type[Region]] = {cls.kind: cls for cls in (Box, ZLimit, Ball, Intersection,
                                                           MeshRegion)}
"""The region classes by their JSON ``kind``."""


def region_from_dict(data: Any) -> Region:
    """Rebuild a region from :meth:`Region.to_dict` output (for instance parsed JSON).

    Raises
    ------
    ValueError
        When ``data`` is not a dict with a known ``kind`` and that kind's parameters.
    """
    import trimesh  # on first use: importing regions stays light

    if not isinstance(data, dict) or "kind" not in data:
        raise ValueError(f"a region description must be a dict with a 'kind' key "
                         f"({sorted(KINDS)}); got {data!r:.200}")
    kind = data["kind"]
    if kind not in KINDS:
        raise ValueError(f"unknown region kind {kind!r}; known kinds: {sorted(KINDS)}")
    params = {k: v for k, v in data.items() if k != "kind"}
    try:
        if kind == "intersection":
            parts = tuple(region_from_dict(p) for p in params.pop("parts"))
            return Intersection(parts, **params)
        if kind == "mesh":
            mesh = trimesh.Trimesh(np.asarray(params.pop("vertices"), dtype=float),
                                   np.asarray(params.pop("faces"), dtype=np.int64), process=False)
            return MeshRegion(mesh, **params)
        return KINDS[kind](**params)
    except (KeyError, TypeError) as err:
        raise ValueError(f"bad parameters for a region of kind {kind!r}: {err}; "
                         f"got keys {sorted(data)}") from err
