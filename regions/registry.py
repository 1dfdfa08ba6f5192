"""The paper's goal constraint regions by name, and the parser of region strings for CLIs.

The numbers are docs/design.md's table (world frame: ground plane z = 0, robot base at
(0, 0, base_height)). Users build their own regions from a string (:func:`parse`) without
editing code.
"""

from __future__ import annotations

import json
import math
import pathlib
from collections.abc import Callable

from regions.reach import reach_ball
from regions.shapes import Box, Intersection, MeshRegion, Region, ZLimit, region_from_dict
from ur5kin.world import BASE_HEIGHT, DEFAULT_BASE_HEIGHT

UNCONSTRAINED_REGION = "unconstrained"
"""The region whose default start pose is :data:`UNCONSTRAINED_START` (all zeros); every other
region, user regions included, starts from :data:`CONSTRAINED_START` (docs/design.md, open
point 1)."""

UNCONSTRAINED_START = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
"""The paper's start configuration (rad) of the unconstrained task: the arm stretched along +x."""

CONSTRAINED_START = (0.0, -math.pi / 4, math.pi / 2, 0.0, 0.0, 0.0)
"""Start configuration (rad) of the constrained tasks: the paper's [0, pi/2, pi/4, 0, 0, 0] read
as docs/design.md's open point 1 explains (elbow pi/2, shoulder lift pi/4 upwards, i.e. -pi/4
in this URDF); tool0 sits near (0.51, 0.19, 0.15) m in the world (base at 0.1 m), inside zheight,
closebox and farbox."""

def default_start(region: str) -> tuple[float, ...]:
    """The start pose (6 angles, rad) of a task in ``region`` (a region string) by default."""
    start = UNCONSTRAINED_START if region == UNCONSTRAINED_REGION else CONSTRAINED_START
    return tuple(float(x) for x in start)


PLANE_Z = 0.0
"""Height (m) of the ground plane, the floor of every paper region."""

ZHEIGHT_MAX = 0.4
"""Top (m) of the z-height region: "below a height of 0.4 meters from the plane"."""

CLOSEBOX_LIMITS = (0.0, 0.9, -0.4, 0.4, 0.0, 0.4)
"""xmin, xmax, ymin, ymax, zmin, zmax (m) of the close box: "0.9 x 0.8 x 0.4 m box that includes
the robot's base" (placement x in [0, 0.9]: docs/design.md open point 2)."""

FARBOX_LIMITS = (0.5, 0.9, -0.4, 0.4, 0.0, 0.4)
"""Limits (m) of the far box: "0.4 x 0.8 x 0.4 m box 0.5 m along the X-axis from the base"."""

FARBOX_TALL_LIMITS = (0.5, 0.9, -0.4, 0.4, 0.0, 1.0)
"""Limits (m) of the far box extended to 1.0 m height ("similar success")."""


def cut_to_reach(zmin: float, zmax: float, base_height: float, name: str) -> Intersection:
    """A z-limit ``zmin <= z <= zmax`` (m) cut to the arm's reach ball: bounded, exact volume."""
    return Intersection((ZLimit(zmin, zmax, name="zlimit"), reach_ball(base_height)), name=name)


_BUILDERS: dict[str, Callable[[float], Region]] = {
    UNCONSTRAINED_REGION: lambda h: cut_to_reach(PLANE_Z, math.inf, h, UNCONSTRAINED_REGION),
    "zheight": lambda h: cut_to_reach(PLANE_Z, ZHEIGHT_MAX, h, "zheight"),
    "closebox": lambda h: Box.from_limits(CLOSEBOX_LIMITS, "closebox"),
    "farbox": lambda h: Box.from_limits(FARBOX_LIMITS, "farbox"),
    "farbox_tall": lambda h: Box.from_limits(FARBOX_TALL_LIMITS, "farbox_tall"),
}

PAPER_REGIONS: tuple[str, ...] = tuple(_BUILDERS)
"""Names of the paper's regions, in the paper's order."""


def paper_order(name: str) -> tuple[int, str]:
    """Sort key of region names: the paper's regions in the paper's order, then the others
    alphabetically (figure rows and tables)."""
    rank = PAPER_REGIONS.index(name) if name in PAPER_REGIONS else len(PAPER_REGIONS)
    return rank, name


def names() -> tuple[str, ...]:
    """Names accepted by :func:`get`."""
    return PAPER_REGIONS


def get(name: str, base_height: float = DEFAULT_BASE_HEIGHT) -> Region:
    """One of the paper's regions.

    Parameters
    ----------
    name : str
        ``unconstrained`` (the reach ball above the plane: every tool0 position the arm can
        take clear of it), ``zheight``, ``closebox``, ``farbox`` or ``farbox_tall``.
    base_height : float, m
        Height of the robot base; it places the reach ball of ``unconstrained`` and ``zheight``.

    Raises
    ------
    ValueError
        For an unknown name; the message lists the known ones.
    """
    if name not in _BUILDERS:
        raise ValueError(f"unknown region {name!r}; known regions: {', '.join(PAPER_REGIONS)}")
    return _BUILDERS[name](BASE_HEIGHT("base_height", base_height))


SPEC_FORMS = (
    "a registered name ({names})",
    "box:XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX (m, world frame)",
    "zmax:ZMAX (0 <= z <= ZMAX m) or z:ZMIN,ZMAX, cut to the arm's reach",
    "mesh:PATH (a closed mesh file, m, world frame)",
    "json:PATH or PATH.json (a region's to_dict() saved as JSON), or inline JSON {{...}}",
)
"""The forms :func:`parse` accepts, for help texts."""


def spec_help() -> str:
    """One line listing the region strings :func:`parse` accepts."""
    return "; ".join(SPEC_FORMS).format(names=", ".join(PAPER_REGIONS))


def _numbers(text: str, count: int, spec: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError as err:
        raise ValueError(f"region {spec!r}: expected {count} comma-separated numbers (m) after "
                         f"the colon; got {text!r}") from err
    if len(values) != count:
        raise ValueError(f"region {spec!r}: expected {count} numbers (m); got {len(values)}")
    return values


def _from_json_text(text: str, spec: str) -> Region:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise ValueError(f"region {spec!r:.200}: not valid JSON ({err})") from err
    return region_from_dict(data)


def parse(spec: str, base_height: float = DEFAULT_BASE_HEIGHT) -> Region:
    """A region from a command-line string (the ``--region`` flag of the env and the trainer).

    Parameters
    ----------
    spec : str
        One of: a registered name (``farbox``); ``box:XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX``;
        ``zmax:ZMAX`` or ``z:ZMIN,ZMAX`` (a z-limit cut to the arm's reach ball); ``mesh:PATH``;
        ``json:PATH`` or a path ending in ``.json``; inline JSON ``{"kind": ...}``. Lengths in m,
        world frame.
    base_height : float, m
        Height of the robot base (places the reach ball of z-limits).

    Returns
    -------
    Region
        Named by ``spec`` itself for the box and z-limit forms, so the string can be read back
        from a run's record.

    Raises
    ------
    ValueError
        For a string of none of these forms, naming it and listing the forms.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"a region string is needed; got {spec!r}. Forms: {spec_help()}")
    spec, base_height = spec.strip(), BASE_HEIGHT("base_height", base_height)
    if spec in _BUILDERS:
        return get(spec, base_height)
    if spec.startswith("{"):
        return _from_json_text(spec, spec)
    head, sep, rest = spec.partition(":")
    if sep and head == "box":
        return Box.from_limits(_numbers(rest, 6, spec), name=spec)
    if sep and head == "zmax":
        (zmax,) = _numbers(rest, 1, spec)
        return cut_to_reach(PLANE_Z, zmax, base_height, spec)
    if sep and head == "z":
        zmin, zmax = _numbers(rest, 2, spec)
        return cut_to_reach(zmin, zmax, base_height, spec)
    if sep and head == "mesh":
        return MeshRegion.from_file(rest)
    path = rest if sep and head == "json" else (spec if spec.endswith(".json") else None)
    if path is not None:
        if not pathlib.Path(path).is_file():
            raise ValueError(f"region {spec!r}: JSON file {path!r} does not exist")
        return _from_json_text(pathlib.Path(path).read_text(), spec)
    raise ValueError(f"cannot read region {spec!r}. Forms: {spec_help()}")
