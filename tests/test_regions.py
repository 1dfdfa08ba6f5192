"""Regions as geometry: volumes (analytic vs meshed), containment, JSON, the registry, parse()."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

import regions
import ur5kin
from regions.shapes import REVOLVE_SECTIONS, Ball, Box, Intersection, MeshRegion, ZLimit

# The meshed volume of a surface of revolution falls short by about (2 pi / sections)^2 / 6.
REVOLVE_RTOL = 2 * (2 * math.pi / REVOLVE_SECTIONS) ** 2 / 6


@pytest.mark.parametrize(("name", "volume"), [
    ("closebox", 0.9 * 0.8 * 0.4), ("farbox", 0.4 * 0.8 * 0.4), ("farbox_tall", 0.4 * 0.8 * 1.0)])
def test_paper_box_volumes_are_exact(name: str, volume: float) -> None:
    region = regions.get(name)
    assert region.volume == pytest.approx(volume, rel=1e-12)
    assert region.volume_is_exact
    assert region.mesh.is_watertight
    assert region.mesh.volume == pytest.approx(volume, rel=1e-12)


def test_the_issue_numbers() -> None:
    assert regions.get("closebox").volume == pytest.approx(0.288, abs=1e-12)
    assert regions.get("farbox").volume == pytest.approx(0.128, abs=1e-12)
    assert regions.get("farbox_tall").volume == pytest.approx(0.32, abs=1e-12)


@pytest.mark.parametrize("name", ["unconstrained", "zheight"])
def test_cut_ball_volume_matches_its_mesh_and_a_grid(name: str) -> None:
    region = regions.get(name)
    assert region.volume_is_exact
    mesh = region.mesh
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(region.volume, rel=REVOLVE_RTOL)
    # A third path: a midpoint grid over the bounds (error ~ surface x cell / 2, far less here).
    lo, hi = region.bounds
    n = 60
    axes = [a + (np.arange(n) + 0.5) * (b - a) / n for a, b in zip(lo, hi, strict=True)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    estimate = region.contains(grid).mean() * np.prod(hi - lo)
    assert estimate == pytest.approx(region.volume, rel=0.01)


def test_zheight_is_the_ball_zone_between_plane_and_04() -> None:
    ball = regions.reach_ball(0.1)
    c, r = ball.center[2], ball.radius
    # Exact zone volume by the disc integral pi (r^2 - (z - c)^2) dz from 0 to 0.4.
    expected = math.pi * (r**2 * 0.4 - ((0.4 - c) ** 3 - (0.0 - c) ** 3) / 3)
    assert regions.get("zheight").volume == pytest.approx(expected, rel=1e-12)
    full = math.pi * (r**2 * (c + r) - ((r) ** 3 - (0.0 - c) ** 3) / 3)
    assert regions.get("unconstrained").volume == pytest.approx(full, rel=1e-12)


def test_reach_ball_holds_every_tool_position_and_is_tight() -> None:
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, (200_000, 6))
    ball = regions.reach_ball(0.0)
    p = ur5kin.fk(q)
    distance = np.linalg.norm(p - np.asarray(ball.center), axis=1)
    assert distance.max() <= ball.radius
    # The stretched arm (q2 = -pi/2 - q3 = 0 ... any pan) reaches within a millimetre of it.
    assert ball.radius - distance.max() < 0.01


def test_box_contains_its_closed_faces_only() -> None:
    box = regions.get("farbox")
    points = np.array([[0.5, -0.4, 0.0], [0.9, 0.4, 0.4], [0.7, 0.0, 0.2], [0.4999, 0, 0.1],
                       [0.7, 0.0, 0.4001], [0.7, 0.41, 0.2]])
    assert box.contains(points).tolist() == [True, True, True, False, False, False]
    assert box.contains(points.reshape(2, 3, 3)).shape == (2, 3)


def test_unconstrained_and_zheight_contain_the_right_heights() -> None:
    pts = np.array([[0.5, 0.0, -0.01], [0.5, 0.0, 0.0], [0.5, 0.0, 0.39], [0.5, 0.0, 0.5],
                    [2.0, 0.0, 0.2]])
    assert regions.get("unconstrained").contains(pts).tolist() == [False, True, True, True, False]
    assert regions.get("zheight").contains(pts).tolist() == [False, True, True, False, False]


def test_regions_round_trip_through_json() -> None:
    cube = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    cube.apply_translation((0.6, 0.0, 0.3))
    custom = [
        *(regions.get(name) for name in regions.names()),
        Box((0.3, 0.7), (-0.2, 0.2), (0.0, 0.5), name="mine"),
        ZLimit(0.2, math.inf),
        Intersection((ZLimit(0.1, 0.3), Box((0, 1), (0, 1), (0, 1))), name="both"),
        MeshRegion(cube, name="cube"),
    ]
    for region in custom:
        text = json.dumps(region.to_dict())
        back = regions.region_from_dict(json.loads(text))
        assert type(back) is type(region)
        assert back == region
        assert back.to_dict() == region.to_dict()


def test_region_from_dict_names_the_problem() -> None:
    with pytest.raises(ValueError, match="unknown region kind 'sphere'"):
        regions.region_from_dict({"kind": "sphere"})
    with pytest.raises(ValueError, match="'kind' key"):
        regions.region_from_dict([1, 2])
    with pytest.raises(ValueError, match="bad parameters for a region of kind 'box'"):
        regions.region_from_dict({"kind": "box", "x": [0, 1]})


@pytest.mark.parametrize(("args", "match"), [
    (((1.0, 0.0), (0, 1), (0, 1)), "lo < hi"),
    (((0.0, math.inf), (0, 1), (0, 1)), "finite"),
    (((0.0, "a"), (0, 1), (0, 1)), "2 finite numbers"),
    # text and flags that float() would take: refused, the field and value named (the hand
    # check cast them and went on)
    ((("0", "1"), (0, 1), (0, 1)), r"invalid Box: x=\('0', '1'\) \(expected 2 finite numbers "
                                   r"\(lo, hi in m"),
    (((0, 1), (True, 2), (0, 1)), r"y=\(True, 2\) \(expected 2 finite numbers"),
])
def test_bad_boxes_are_refused(args: tuple, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        Box(*args)


@pytest.mark.parametrize(("args", "match"), [
    ((0.5, 0.1), r"invalid ZLimit: zmin=0.5, zmax=0.1 \(expected zmin < zmax \(m\)\)"),
    (("0.1", None), r"zmin='0.1' \(expected a number \(m"),
    ((0.0, False), r"zmax=False \(expected a number \(m"),
    ((math.nan, 1.0), "zmin=nan"),
])
def test_bad_z_limits_are_refused_naming_the_field(args: tuple, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        ZLimit(*args)
    assert ZLimit(None, None).bounds[:, 2].tolist() == [-math.inf, math.inf]


def test_box_from_limits_wants_six_numbers() -> None:
    with pytest.raises(ValueError, match="six numbers"):
        Box.from_limits([0, 1, 0, 1, 0])


def test_contains_checks_the_point_shape() -> None:
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        regions.get("farbox").contains(np.zeros((4, 2)))


def test_get_lists_the_known_regions() -> None:
    with pytest.raises(ValueError) as info:
        regions.get("far_box")
    for name in regions.PAPER_REGIONS:
        assert name in str(info.value)


def test_unbounded_region_has_infinite_volume_and_no_mesh() -> None:
    z = ZLimit(0.0, 0.4)
    assert math.isinf(z.volume)
    with pytest.raises(ValueError, match="unbounded"):
        _ = z.mesh


def test_intersection_volumes() -> None:
    a = Box((0, 1), (0, 1), (0, 1))
    b = Box((0.5, 2), (0.25, 1), (-1, 0.5))
    assert Intersection((a, b)).volume == pytest.approx(0.5 * 0.75 * 0.5)
    assert Intersection((a, Box((2, 3), (0, 1), (0, 1)))).volume == 0.0
    # A box inside a ball: the box's volume, exactly.
    inside = Intersection((Ball((0, 0, 0), 1.0), Box((-0.5, 0.5), (-0.5, 0.5), (-0.5, 0.5))))
    assert inside.volume_is_exact and inside.volume == pytest.approx(1.0)
    # A box cutting a ball: no closed form, a grid estimate. The quarter of the ball above
    # z = 0 and x >= 0 has a quarter of its volume.
    part = Intersection((Ball((0, 0, 0), 1.0), Box((0, 2), (-2, 2), (0, 2))))
    assert not part.volume_is_exact
    assert part.volume == pytest.approx(math.pi / 3, rel=0.01)


def test_mesh_region_on_a_non_convex_mesh_uses_winding_numbers() -> None:
    # A ring: the rectangle r in [0.5, 1], z in [0, 1] revolved about z. Its hole is outside.
    ring = trimesh.creation.revolve(
        np.array([[0.5, 0], [1, 0], [1, 1], [0.5, 1], [0.5, 0]]), sections=REVOLVE_SECTIONS)
    region = MeshRegion(ring, name="ring")
    assert not ring.is_convex
    assert region.volume == pytest.approx(math.pi * (1 - 0.25), rel=REVOLVE_RTOL)
    pts = np.array([[0, 0, 0.5], [0.75, 0, 0.5], [0, -0.75, 0.5], [1.2, 0, 0.5],
                    [0.75, 0, 1.2], [0.3, 0.3, 0.5]])
    assert region.contains(pts).tolist() == [False, True, True, False, False, False]


def test_mesh_region_refuses_open_meshes(tmp_path) -> None:
    box = trimesh.creation.box()
    open_mesh = trimesh.Trimesh(box.vertices, box.faces[:-1])
    with pytest.raises(ValueError, match="watertight"):
        MeshRegion(open_mesh)
    with pytest.raises(ValueError, match="does not exist"):
        MeshRegion.from_file(tmp_path / "missing.stl")


def test_parse_every_form(tmp_path) -> None:
    assert regions.parse("farbox") == regions.get("farbox")
    box = regions.parse("box:0.3,0.7,-0.2,0.2,0,0.5")
    assert box.volume == pytest.approx(0.4 * 0.4 * 0.5)
    assert box.name == "box:0.3,0.7,-0.2,0.2,0,0.5"
    zmax = regions.parse("zmax:0.4")
    assert zmax.volume == pytest.approx(regions.get("zheight").volume, rel=1e-12)
    assert regions.parse("z:0,0.4").volume == pytest.approx(zmax.volume, rel=1e-12)
    # A base 0.3 m up moves the reach ball: the z-limit cut to it changes.
    assert regions.parse("zmax:0.4", base_height=0.3).volume != pytest.approx(zmax.volume)

    cube = trimesh.creation.box(bounds=[[0.4, -0.1, 0.1], [0.6, 0.1, 0.3]])
    stl = tmp_path / "goal.stl"
    cube.export(stl)
    mesh = regions.parse(f"mesh:{stl}")
    assert mesh.volume == pytest.approx(0.008)
    assert mesh.contains([[0.5, 0, 0.2], [0.7, 0, 0.2]]).tolist() == [True, False]

    saved = tmp_path / "region.json"
    saved.write_text(json.dumps(box.to_dict()))
    assert regions.parse(str(saved)) == box
    assert regions.parse(f"json:{saved}") == box
    assert regions.parse(json.dumps(box.to_dict())) == box


@pytest.mark.parametrize(("spec", "match"), [
    ("", "region string is needed"),
    ("farbx", "cannot read region 'farbx'"),
    ("box:0,1,2", "expected 6 numbers"),
    ("box:0,1,a,1,0,1", "comma-separated numbers"),
    ("box:1,0,0,1,0,1", "lo < hi"),
    ("zmax:", "comma-separated numbers"),
    ("z:0.5,0.1", "zmin < zmax"),
    ("zmax:-1", r"zmin=0.0, zmax=-1.0 \(expected zmin < zmax"),  # the value typed, named
    ("mesh:/no/such/file.stl", "does not exist"),
    ("json:/no/such.json", "does not exist"),
    ("{not json", "not valid JSON"),
])
def test_parse_errors_name_the_string(spec: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        regions.parse(spec)


def test_parse_error_lists_the_forms() -> None:
    with pytest.raises(ValueError) as info:
        regions.parse("sphere:1")
    for form in ("box:", "zmax:", "mesh:", "json:", "farbox"):
        assert form in str(info.value)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-2, 2, allow_nan=False), min_size=6, max_size=6))
def test_box_contains_agrees_with_its_mesh(limits: list[float]) -> None:
    lo, hi = np.minimum(limits[::2], limits[1::2]), np.maximum(limits[::2], limits[1::2])
    if np.any(hi - lo < 1e-3):
        return
    box = Box.from_limits(np.ravel(np.column_stack([lo, hi])))
    mesh_region = MeshRegion(box.mesh)
    pts = np.random.default_rng(0).uniform(lo - 0.5, hi + 0.5, (500, 3))
    assert np.array_equal(box.contains(pts), mesh_region.contains(pts))
    assert box.volume == pytest.approx(float(np.prod(hi - lo)), rel=1e-12)


def test_the_constrained_start_is_the_one_reading_of_the_papers_pose_inside_the_regions() -> None:
    """docs/design.md, open point 1: of the 8 readings of the paper's [0, pi/2, pi/4, 0, 0, 0]
    (which of lift and elbow takes pi/2, each sign), only CONSTRAINED_START puts tool0 inside
    zheight, closebox and farbox ("the end effector is within the goal constraint region")
    with every link above the plane."""
    import itertools

    from regions.registry import CONSTRAINED_START, DEFAULT_BASE_HEIGHT, get

    inside = []
    for (lift, elbow), (s1, s2) in itertools.product(
            ((np.pi / 2, np.pi / 4), (np.pi / 4, np.pi / 2)), itertools.product((1, -1), (1, -1))):
        q = np.array([0.0, s1 * lift, s2 * elbow, 0.0, 0.0, 0.0])
        tool = np.asarray(ur5kin.fk_world(q, DEFAULT_BASE_HEIGHT)).reshape(1, 3)
        clear = float(np.min(ur5kin.link_heights(q, DEFAULT_BASE_HEIGHT))) >= 0.0
        if clear and all(get(r).contains(tool)[0] for r in ("zheight", "closebox", "farbox")):
            inside.append(tuple(q))
    assert inside == [pytest.approx(CONSTRAINED_START)]
