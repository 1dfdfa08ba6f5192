"""Goal constraint regions of the UR5 Reacher task, their goal samplers and coverage statistics.

World frame throughout: ground plane z = 0, robot base at (0, 0, base_height), m (see
docs/design.md; the transform is :mod:`ur5kin.world`). The paper's regions are registered by name;
users build their own from a string. The arm's collision geometry and plane clearance belong
to the robot: :mod:`ur5kin.collision`.

Names load on first use (PEP 562), so that ``import regions.registry`` does not load Pinocchio.

>>> import regions
>>> regions.names()
('unconstrained', 'zheight', 'closebox', 'farbox', 'farbox_tall')
>>> round(regions.get("closebox").volume, 6)
0.288
>>> regions.parse("box:0.3,0.7,-0.2,0.2,0,0.5").contains([[0.5, 0.0, 0.25]])
array([ True])
"""

from __future__ import annotations

from ur5kin.lazy import lazy_attributes

_EXPORTS: dict[str, str] = {
    **dict.fromkeys(("CoverageRow", "VoxelWorkspace", "WorkspaceSamples", "coverage_row",
                     "sample_workspace"), "regions.coverage"),
    **dict.fromkeys(("KMEANS", "KMeansSettings", "Partition", "fit_partition", "kmeans",
                     "nearest_cell"), "regions.partition"),
    **dict.fromkeys(("reach_ball", "reach_radius"), "regions.reach"),
    **dict.fromkeys(("CONSTRAINED_START", "DEFAULT_BASE_HEIGHT", "PAPER_REGIONS",
                     "UNCONSTRAINED_REGION", "UNCONSTRAINED_START", "default_start", "get",
                     "names", "paper_order", "parse", "spec_help"), "regions.registry"),
    **dict.fromkeys(("CartesianSampler", "GoalBatch", "GoalSampler", "JointSpaceSampler",
                     "SamplingLimits", "UnreachableRegionError", "sampler_from_dict"),
                    "regions.samplers"),
    **dict.fromkeys(("Ball", "Box", "Intersection", "MeshRegion", "Region", "ZLimit",
                     "region_from_dict"), "regions.shapes"),
}
"""Public name -> the module that defines it."""

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
