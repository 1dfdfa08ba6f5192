"""ur5kin.collision: capsules contain the meshes; heights match a brute-force Pinocchio
reference."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
import trimesh

import regions
import ur5kin
from ur5kin import collision

pytestmark = pytest.mark.xdist_group("test_collision")
"""Under pytest-xdist one worker runs this module, so that the brute-force reference (`reference`)
is computed once."""

CAPSULE_SLACK = 0.08
"""Largest allowed gap (m) between a capsule's lowest point and its mesh's: the capsules are
conservative, but not absurdly so (the worst measured is 0.065 m, the base link's disc)."""


def _brute_force(q: np.ndarray, base_height: float) -> np.ndarray:
    """Lowest world z of every vertex of each link's collision geometry, via Pinocchio's oMi."""
    model = ur5kin.load_model()
    data = model.createData()
    links = collision.collision_geometry()
    out = np.empty((len(q), len(links)))
    for i, qi in enumerate(q):
        pin.forwardKinematics(model, data, qi)
        for k, link in enumerate(links):
            placement = data.oMi[k]
            world = link.vertices @ np.asarray(placement.rotation).T + placement.translation
            out[i, k] = world[:, 2].min() + base_height
    return out


@pytest.fixture(scope="module")
def configurations() -> np.ndarray:
    rng = np.random.default_rng(7)
    q = rng.uniform(-np.pi, np.pi, (300, 6))
    # Add near-plane cases: the arm folded down and stretched along the plane.
    q[:20, 1] = rng.uniform(-0.3, 0.3, 20)
    return q


@pytest.fixture(scope="module")
def reference(configurations: np.ndarray) -> np.ndarray:
    return _brute_force(configurations, 0.1)


def test_collision_geometry_comes_from_every_urdf_mesh() -> None:
    links = collision.collision_geometry()
    assert [link.name for link in links] == list(ur5kin.LINK_NAMES)
    model = ur5kin.load_model()
    package_root = ur5kin.resolve_package_uri("package://example-robot-data/").parent
    geom = pin.buildGeomFromUrdf(model, str(ur5kin.urdf_path()), pin.GeometryType.COLLISION,
                                 package_dirs=[str(package_root)])
    for obj in geom.geometryObjects:
        if obj.meshPath.endswith(".stl"):
            mesh = trimesh.load(obj.meshPath, force="mesh")
            assert len(links[obj.parentJoint].vertices) >= len(mesh.vertices)


def test_capsules_contain_every_collision_vertex() -> None:
    for link in collision.collision_geometry():
        distance = link.capsule.distance(link.vertices)
        assert np.all(distance <= link.capsule.radius), link.name
        # And they are fitted, not loose: some vertex lies within a millimetre of the surface.
        assert link.capsule.radius - distance.max() < 1e-3, link.name


def test_capsules_contain_the_meshes_surfaces_too() -> None:
    # Points on the hull's triangles, not only its vertices (a capsule is convex: it must hold).
    rng = np.random.default_rng(0)
    for link in collision.collision_geometry():
        hull = trimesh.convex.convex_hull(link.vertices)
        points, _ = trimesh.sample.sample_surface(hull, 2000, seed=rng.integers(1 << 31))
        assert link.capsule.contains(points).all(), link.name


def test_height_rows_equal_link_poses(configurations: np.ndarray) -> None:
    # third row of each link's pose in base_link, from the 13 features: the kernels' model
    A = collision._row_coefficients(ur5kin.geometry()).reshape(len(collision.FEATURES), -1)
    rows = (collision._features(configurations).T @ A).reshape(-1, collision.N_LINKS, 4)
    np.testing.assert_allclose(rows, ur5kin.link_poses(configurations)[..., :7, 2, :],
                               atol=1e-12)


def test_link_heights_are_the_exact_mesh_minimum(configurations, reference) -> None:
    np.testing.assert_allclose(collision.link_heights(configurations, 0.1), reference,
                               atol=1e-12)


def test_capsule_heights_are_conservative_and_tight(configurations, reference) -> None:
    capsule = collision.capsule_heights(configurations, 0.1)
    assert np.all(capsule <= reference + 1e-12)
    assert np.all(reference - capsule <= CAPSULE_SLACK)


def test_plane_clear_is_the_exact_answer(configurations, reference) -> None:
    expected = reference[:, 1:].min(axis=1) >= 0.0
    assert 0.05 < expected.mean() < 0.95  # both answers occur
    # Large batches take the capsule filter; small ones the exact heights directly.
    big = np.tile(configurations, (2, 1))
    assert len(big) >= collision.PREFILTER_MIN
    np.testing.assert_array_equal(collision.plane_clear(big, 0.1), np.tile(expected, 2))
    small = configurations[:20]
    np.testing.assert_array_equal(collision.plane_clear(small, 0.1), expected[:20])
    # A margin is a raised plane.
    raised = reference[:, 1:].min(axis=1) >= 0.05
    np.testing.assert_array_equal(collision.plane_clear(big, 0.1, margin=0.05),
                                  np.tile(raised, 2))


def test_base_link_is_reported_not_checked() -> None:
    q = np.zeros((1, 6))
    heights = collision.link_heights(q, 0.0)
    assert heights[0, 0] < 0.0  # the base mesh reaches 3 mm below base_link
    assert collision.plane_clear(q, 0.0)[0] == (heights[0, 1:].min() >= 0.0)


def test_batch_shapes_are_kept() -> None:
    q = np.zeros((4, 5, 6))
    assert collision.link_heights(q, 0.1).shape == (4, 5, 7)
    assert collision.capsule_heights(q, 0.1).shape == (4, 5, 7)
    assert collision.plane_clear(q, 0.1).shape == (4, 5)
    assert collision.plane_clear(np.zeros(6), 0.1).shape == ()


def test_start_poses_are_clear() -> None:
    starts = np.array([regions.UNCONSTRAINED_START, regions.CONSTRAINED_START])
    assert collision.plane_clear(starts, regions.DEFAULT_BASE_HEIGHT).all()


def test_an_arm_pointing_down_is_not_clear() -> None:
    # Shoulder lift +pi/2 turns the stretched arm straight down (a positive lift lowers it).
    q = np.array([0.0, np.pi / 2, 0.0, 0.0, 0.0, 0.0])
    assert not collision.plane_clear(q, 0.1)
    assert collision.link_heights(q, 0.1)[6] < -0.5


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"base_height": -0.1}, "base_height"),
    ({"base_height": float("nan")}, "base_height"),
    ({"base_height": 0.1, "margin": "a"}, "margin"),
])
def test_bad_arguments_are_named(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        collision.plane_clear(np.zeros(6), **kwargs)


def test_q_shape_is_checked() -> None:
    with pytest.raises(ValueError, match=r"\(\.\.\., 6\)"):
        collision.link_heights(np.zeros((3, 5)), 0.1)
