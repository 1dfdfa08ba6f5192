"""ur5kin.meshes: the drawn parts sit where Pinocchio puts them, and the collision parts drawn are
the geometry the clearance check uses."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

import ur5kin
from ur5kin import meshes


@pytest.fixture(scope="module")
def configurations() -> np.ndarray:
    return np.random.default_rng(3).uniform(-np.pi, np.pi, (40, 6))


@pytest.mark.parametrize("kind", sorted(meshes.KINDS))
def test_part_poses_equal_pinocchios_geometry_placements(kind, configurations):
    """Two paths: the closed-form link poses times the URDF placements, and Pinocchio's
    updateGeometryPlacements (oMg) on a fresh Data."""
    model, geom = ur5kin.load_model(), meshes.geometry_model(kind)
    data, geom_data = model.createData(), pin.GeometryData(geom)
    batch = meshes.part_poses(configurations, kind)
    assert batch.shape == (len(configurations), len(geom.geometryObjects), 4, 4)
    for q, poses in zip(configurations, batch, strict=True):
        pin.updateGeometryPlacements(model, data, geom, geom_data, q)
        reference = np.stack([m.homogeneous for m in geom_data.oMg])
        np.testing.assert_allclose(poses, reference, atol=1e-12)
        np.testing.assert_allclose(meshes.part_poses(q, kind), reference, atol=1e-12)


def test_drawn_collision_parts_are_the_clearance_checks_geometry(configurations):
    """The lowest drawn vertex of each link equals ur5kin.link_heights (the hull the physics
    and the goal sampler check against the plane)."""
    base_height = 0.1
    parts = meshes.mesh_parts("collision")
    poses = meshes.part_poses(configurations, "collision")
    lowest = np.full((len(configurations), len(ur5kin.LINK_NAMES)), np.inf)
    for p, part in enumerate(parts):
        local = np.asarray(part.local_mesh().vertices)
        world_z = (poses[:, p, 2, :3] @ local.T + poses[:, p, 2, 3:]).min(axis=1) + base_height
        lowest[:, part.joint] = np.minimum(lowest[:, part.joint], world_z)
    np.testing.assert_allclose(lowest, ur5kin.link_heights(configurations, base_height),
                               atol=1e-12)


def test_every_link_has_its_urdf_mesh_in_both_kinds():
    for kind, suffix in (("visual", ".dae"), ("collision", ".stl")):
        parts = [p for p in meshes.mesh_parts(kind) if p.path is not None]
        assert [p.link for p in parts] == list(ur5kin.LINK_NAMES), kind
        assert all(p.path.suffix == suffix and p.path.is_file() for p in parts), kind
    boxes = [p for p in meshes.mesh_parts("collision") if p.half_extents is not None]
    assert [p.link for p in boxes] == ["wrist_3_link"]  # ee_link's box joins its parent
    with pytest.raises(ValueError, match="mesh kind must be one of"):
        meshes.mesh_parts("pretty")
