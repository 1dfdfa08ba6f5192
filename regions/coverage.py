"""How much of the arm's reachable workspace a region covers, per joint count and start pose.

The reachable workspace of the n-joint sub-chain (joints 1..n uniform in [-pi, pi], the others
at the start angles, configurations clear of the plane) is estimated by voxel occupancy: the
tool0 positions of uniform joint-space samples mark the cubes of a grid of edge ``resolution``
they fall in. An occupied voxel whose 6 face neighbours are all occupied is *interior*, any
other occupied voxel is *boundary* (the workspace surface passes through it, or sampling left a
hole next to it). The estimate counts interior voxels fully and boundary voxels by half; the
error bar is half the boundary volume, so the interval spans "interior only" to "every occupied
voxel". With enough samples per voxel the estimate converges as the resolution shrinks, the
error bar like the resolution.

With 2 joints (1 joint) tool0 moves on a surface (a curve): the workspace has no volume. The
voxels then all lie on the boundary, and the estimate is a shell about one voxel thick, with an
error bar as large as itself: both shrink with the resolution.
:attr:`CoverageRow.workspace_is_surface` flags these rows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from regions.samplers import draw_joint_space
from regions.shapes import Region
from ur5kin import fk_world, plane_clear
from ur5kin.checks import COUNT, joint_array, joint_count
from ur5kin.world import check_base_height

SURFACE_JOINTS = 2
"""Joint counts up to this one reach only a surface (or a curve): zero volume."""

DEFAULT_RESOLUTION = 0.05
"""Voxel edge (m) of the workspace estimate by default."""

DEFAULT_SAMPLES = 800_000
"""Joint-space samples per (joint count, held-joint angles) by default: about 15 per voxel of the
reach ball's box (6.9 m^3) at the default resolution."""

WORKSPACE_CHUNK = 1 << 16
"""Samples per block of :func:`sample_workspace` (bounds the memory of the clearance check)."""


@dataclass(frozen=True, eq=False)
class WorkspaceSamples:
    """Uniform joint-space samples of an n-joint sub-chain and where they put tool0.

    Attributes
    ----------
    n_joints : int
    start_q : (6,) float, rad
    base_height : float, m
    goals : (m, 3) float, m, world frame
        tool0 position of every sample.
    clear : (m,) bool
        Whether the sample's configuration is clear of the plane.
    """

    n_joints: int
    start_q: tuple[float, ...]
    base_height: float
    goals: np.ndarray
    clear: np.ndarray

    @property
    def count(self) -> int:
        """Number of samples (clear or not)."""
        return len(self.goals)


def sample_workspace(n_joints: int, start_q: Any, base_height: float, count: int,
                     rng: np.random.Generator, chunk: int = WORKSPACE_CHUNK) -> WorkspaceSamples:
    """Draw ``count`` uniform joint-space samples and evaluate their tool0 and plane clearance.

    Parameters
    ----------
    n_joints : int
        Controlled joints 1..n (1-6).
    start_q : (6,) float, rad
        Start configuration; joints n+1..6 stay there.
    base_height : float, m
    count : int
        Samples, >= 1.
    rng : numpy.random.Generator
    chunk : int
        Samples per block (bounds the memory of the clearance check).
    """
    n_joints = joint_count(n_joints)
    count = COUNT("count", count)
    start_q = joint_array(start_q, "start_q")
    if start_q.shape != (6,):
        raise ValueError(f"start_q must have shape (6,) (rad); got shape {start_q.shape}")
    h = check_base_height(base_height)
    goals, clear = np.empty((count, 3)), np.empty(count, dtype=bool)
    for lo in range(0, count, chunk):
        q = draw_joint_space(int(n_joints), start_q, min(chunk, count - lo), rng)
        goals[lo : lo + len(q)] = fk_world(q, h)
        clear[lo : lo + len(q)] = plane_clear(q, h)
    return WorkspaceSamples(int(n_joints), tuple(float(x) for x in start_q), h, goals, clear)


@dataclass(frozen=True, eq=False)
class VoxelWorkspace:
    """Voxel-occupancy estimate of a reachable workspace.

    Attributes
    ----------
    resolution : float, m
        Voxel edge. Voxel ``(i, j, k)`` is the cube ``[i, i+1] x [j, j+1] x [k, k+1]`` times
        ``resolution`` (world frame), so box faces at multiples of it fall on voxel faces.
    offset : (3,) int
        Index of the grid's first voxel.
    occupied, interior : (nx, ny, nz) bool
        Voxels holding a sample; those whose 6 face neighbours hold one too.
    """

    resolution: float
    offset: np.ndarray
    occupied: np.ndarray
    interior: np.ndarray

    @classmethod
    def from_points(cls, points: Any, resolution: float) -> VoxelWorkspace:
        """Voxelise positions ``(m, 3)`` (m, world) at a voxel edge ``resolution`` (m)."""
        resolution = float(resolution)
        if not (np.isfinite(resolution) and resolution > 0):
            raise ValueError(f"resolution must be a voxel edge > 0 (m); got {resolution!r}")
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        if len(p) == 0:
            empty = np.zeros((0, 0, 0), dtype=bool)
            return cls(resolution, np.zeros(3, dtype=int), empty, empty)
        index = np.floor(p / resolution).astype(np.int64)
        offset = index.min(axis=0) - 1  # one empty layer all round: every edge voxel is boundary
        index -= offset
        occupied = np.zeros(tuple(index.max(axis=0) + 2), dtype=bool)
        occupied[tuple(index.T)] = True
        interior = occupied.copy()
        for axis in range(3):
            for shift in (1, -1):
                interior &= np.roll(occupied, shift, axis=axis)
        return cls(resolution, offset, occupied, interior)

    @property
    def voxel_volume(self) -> float:
        """Volume of one voxel (m^3)."""
        return self.resolution**3

    def _estimate(self, mask: np.ndarray | None = None) -> tuple[float, float]:
        occupied = self.occupied if mask is None else self.occupied & mask
        interior = self.interior if mask is None else self.interior & mask
        n_interior = int(np.count_nonzero(interior))
        n_boundary = int(np.count_nonzero(occupied)) - n_interior
        return ((n_interior + 0.5 * n_boundary) * self.voxel_volume,
                0.5 * n_boundary * self.voxel_volume)

    @property
    def volume(self) -> float:
        """Estimated workspace volume (m^3): interior voxels plus half the boundary voxels."""
        return self._estimate()[0]

    @property
    def error(self) -> float:
        """Half-width (m^3) of the estimate's interval: half the boundary voxels' volume."""
        return self._estimate()[1]

    def centres(self) -> np.ndarray:
        """Centres ``(nx, ny, nz, 3)`` (m, world) of every voxel of the grid."""
        axes = [(np.arange(n) + o + 0.5) * self.resolution
                for n, o in zip(self.occupied.shape, self.offset, strict=True)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)

    def covered(self, region: Region) -> tuple[float, float]:
        """Estimated volume (m^3) of the workspace inside ``region``, and its error (m^3).

        Voxels count (as in :attr:`volume`) when their centre lies in the region, so the
        region's own faces add a midpoint-rule error (none where they fall on voxel faces).
        """
        if self.occupied.size == 0:
            return 0.0, 0.0
        mask = np.zeros(self.occupied.shape, dtype=bool)
        mask[self.occupied] = region.contains(self.centres()[self.occupied])
        return self._estimate(mask)


@dataclass(frozen=True)
class CoverageRow:
    """Coverage statistics of one region for one joint count and start pose.

    Attributes
    ----------
    region : str
    joints : int
        Controlled joints 1..n.
    start_q : (6,) float, rad
        Start configuration (its joints n+1..6 are held; ``mean_goal_distance_m`` is measured
        from its tool0).
    region_volume_m3 : float
        The region's volume (exact unless ``region_volume_exact`` is False).
    region_volume_exact : bool
    workspace_volume_m3, workspace_volume_error_m3 : float
        Reachable workspace of the sub-chain above the plane (voxel estimate and half-width).
    covered_volume_m3, covered_volume_error_m3 : float
        The part of that workspace inside the region.
    workspace_fraction : float
        ``covered_volume_m3 / workspace_volume_m3``: the share of the reachable workspace the
        region keeps (0 when the workspace estimate is 0).
    goal_acceptance : float
        Fraction of uniform joint-space samples that the paper's sampler accepts (tool0 in the
        region, configuration plane-clear).
    mean_goal_distance_m : float
        Mean distance from the start's tool0 to those accepted goals (NaN if none).
    start_inside : bool
        Whether the start's tool0 lies in the region.
    resolution_m : float
        Voxel edge of the workspace estimate.
    samples : int
        Joint-space samples behind the row.
    workspace_is_surface : bool
        True for 2 joints or fewer: the workspace is a surface, and its "volume" is a shell of
        about one voxel that tends to 0 with the resolution.
    """

    region: str
    joints: int
    start_q: tuple[float, ...]
    region_volume_m3: float
    region_volume_exact: bool
    workspace_volume_m3: float
    workspace_volume_error_m3: float
    covered_volume_m3: float
    covered_volume_error_m3: float
    workspace_fraction: float
    goal_acceptance: float
    mean_goal_distance_m: float
    start_inside: bool
    resolution_m: float
    samples: int
    workspace_is_surface: bool

    JSON_KEYS: ClassVar[tuple[str, ...]] = (
        "region", "joints", "region_volume_m3", "workspace_volume_m3", "covered_volume_m3",
        "workspace_fraction", "goal_acceptance", "mean_goal_distance_m", "start_inside")
    """Keys of :meth:`json_row` (the contract of ``analysis.region_volumes --json``)."""

    def json_row(self) -> dict[str, Any]:
        """The row with exactly :attr:`JSON_KEYS`; NaN and infinity become ``None``."""
        return {key: _json_value(getattr(self, key)) for key in self.JSON_KEYS}

    def full_row(self) -> dict[str, Any]:
        """Every field, JSON-ready."""
        return {key: _json_value(value) for key, value in self.__dict__.items()}


def _json_value(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_json_value(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


def coverage_row(region: Region, samples: WorkspaceSamples, voxels: VoxelWorkspace,
                 start_q: Any = None) -> CoverageRow:
    """Coverage statistics of ``region`` for the sub-chain behind ``samples``.

    Parameters
    ----------
    region : Region
    samples : WorkspaceSamples
        Uniform joint-space samples of the sub-chain (they give acceptance and distances).
    voxels : VoxelWorkspace
        Voxelisation of ``samples``' plane-clear tool0 positions (the workspace estimate).
    start_q : (6,) float, rad, optional
        Start configuration of the row (distances and ``start_inside`` use its tool0);
        ``samples.start_q`` by default. The samples only depend on its held joints n+1..6, so
        one set of samples serves every start that agrees there.

    Raises
    ------
    ValueError
        When ``start_q``'s held joints differ from those of ``samples``.
    """
    n = samples.n_joints
    if start_q is None:
        start_q = samples.start_q
    start_q = joint_array(start_q, "start_q")
    if start_q.shape != (6,) or not np.array_equal(start_q[n:], samples.start_q[n:]):
        raise ValueError(f"start_q {list(np.ravel(start_q))} must be 6 angles (rad) whose held "
                         f"joints {n + 1}..6 equal the samples' {list(samples.start_q[n:])}")
    start_tool = fk_world(start_q, samples.base_height)
    accepted = samples.clear & region.contains(samples.goals)
    distances = np.linalg.norm(samples.goals[accepted] - start_tool, axis=-1)
    workspace, workspace_err = voxels.volume, voxels.error
    covered, covered_err = voxels.covered(region)
    return CoverageRow(
        region=region.name, joints=n, start_q=tuple(float(x) for x in start_q),
        region_volume_m3=region.volume, region_volume_exact=region.volume_is_exact,
        workspace_volume_m3=workspace, workspace_volume_error_m3=workspace_err,
        covered_volume_m3=covered, covered_volume_error_m3=covered_err,
        workspace_fraction=covered / workspace if workspace > 0 else 0.0,
        goal_acceptance=float(np.count_nonzero(accepted)) / samples.count,
        mean_goal_distance_m=float(distances.mean()) if len(distances) else math.nan,
        start_inside=bool(region.contains(start_tool)), resolution_m=voxels.resolution,
        samples=samples.count, workspace_is_surface=n <= SURFACE_JOINTS)
