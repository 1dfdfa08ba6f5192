"""Goal constraint regions of the UR5 Reacher task, their goal samplers and coverage statistics.

World frame throughout: ground plane z = 0, robot base at (0, 0, base_height), m (see
DESIGN.md). The paper's regions are registered by name; users build their own from a string.

>>> import regions
>>> regions.names()
('unconstrained', 'zheight', 'closebox', 'farbox', 'farbox_tall')
>>> round(regions.get("closebox").volume, 6)
0.288
>>> regions.parse("box:0.3,0.7,-0.2,0.2,0,0.5").contains([[0.5, 0.0, 0.25]])
array([ True])
"""

from regions.clearance import capsule_heights, collision_geometry, link_heights, plane_clear
from regions.coverage import (
    CoverageRow,
    VoxelWorkspace,
    WorkspaceSamples,
    coverage_row,
    sample_workspace,
)
from regions.reach import reach_ball, reach_radius
from regions.registry import (
    CONSTRAINED_START,
    DEFAULT_BASE_HEIGHT,
    PAPER_REGIONS,
    UNCONSTRAINED_START,
    get,
    names,
    parse,
    spec_help,
)
from regions.samplers import (
    CartesianSampler,
    GoalBatch,
    GoalSampler,
    JointSpaceSampler,
    SamplingLimits,
    UnreachableRegionError,
    sampler_from_dict,
)
from regions.shapes import Ball, Box, Intersection, MeshRegion, Region, ZLimit, region_from_dict

__all__ = [
    "CONSTRAINED_START",
    "DEFAULT_BASE_HEIGHT",
    "PAPER_REGIONS",
    "UNCONSTRAINED_START",
    "Ball",
    "Box",
    "CartesianSampler",
    "CoverageRow",
    "GoalBatch",
    "GoalSampler",
    "Intersection",
    "JointSpaceSampler",
    "MeshRegion",
    "Region",
    "SamplingLimits",
    "UnreachableRegionError",
    "VoxelWorkspace",
    "WorkspaceSamples",
    "ZLimit",
    "capsule_heights",
    "collision_geometry",
    "coverage_row",
    "get",
    "link_heights",
    "names",
    "parse",
    "plane_clear",
    "reach_ball",
    "reach_radius",
    "region_from_dict",
    "sample_workspace",
    "sampler_from_dict",
    "spec_help",
]
