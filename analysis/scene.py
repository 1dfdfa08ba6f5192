"""The 3D scene of the arm, its goals and goal regions in MeshCat, for the replay and region views.

MeshCat (the ``meshcat`` package, Pinocchio's own viewer) draws a three.js scene in the
browser. :class:`Scene` draws onto a MeshCat ``Visualizer`` of either kind:

- :func:`offline_visualizer`: a recorder that keeps the scene as MeshCat's server keeps it and
  writes it as one self-contained HTML file (:meth:`Scene.write_html`), the viewer's script and
  every mesh embedded, which opens offline. This is what ``Visualizer.static_html()`` returns,
  made without starting the server (tested equal to it).
- :func:`live_visualizer`: a local MeshCat server (``--serve``), which the browser opens at the
  printed address.

The arm is ur5kin's: the parts of :func:`ur5kin.mesh_parts` (the URDF's collision meshes by
default, about 100 kB in the page; the visual ones make it 9 MB) posed by
:func:`ur5kin.part_poses`. World frame as in the task: plane z = 0, base at (0, 0, base height), m.
"""

from __future__ import annotations

import html
import math
import pathlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

import ur5kin
from analysis.outputs import write_text

if TYPE_CHECKING:
    import meshcat

    import regions

INSTALL_HINT = "pip install meshcat (or the project's extra: pip install -e '.[view]')"
"""What to run when meshcat is missing."""

REACHED_COLOUR = 0x2CA02C
"""Goals reached and their paths (green)."""

MISSED_COLOUR = 0xD62728
"""Goals missed and their paths (red)."""

ARM_COLOURS = (0x5A6470, 0xB8C2CC)
"""Alternating colours of the arm's links (dark and light grey), so that each link stands out."""

REGION_COLOURS = ((0x1F77B4, "blue"), (0xFF7F0E, "orange"), (0x9467BD, "purple"),
                  (0x8C564B, "brown"), (0x17BECF, "cyan"), (0xBCBD22, "olive"))
"""Colours of goal regions in the order drawn, with their names for captions."""

START_COLOUR = 0x222222
"""Colour of the marker at a start pose's tool0 (black)."""

REGION_OPACITY = 0.25
"""Opacity of a region's faces (0: invisible, 1: opaque), so that the arm shows through."""

EDGE_ANGLE = 20.0
"""Angle (degrees) between two faces of a region's mesh above which their shared edge is
outlined."""

GOAL_OPACITY = 0.35
"""Opacity of a goal's success ball."""

GOAL_DOT_RADIUS = 0.012
"""Radius (m) of the solid dot at each goal's centre."""

GROUND_EXTENT = 2.4
"""Edge (m) of the square of ground plane drawn around the base (the reach is 0.95 m)."""

GROUND_COLOUR = 0xD8D2C4
"""Colour of the ground plane."""

GROUND_DROP = 0.002
"""Depth (m) of the drawn ground's top below z = 0, so that faces on the plane (a region's
floor) do not flicker against it in the depth buffer."""

BACKGROUND = ((0.97, 0.97, 0.97), (0.80, 0.84, 0.88))
"""Top and bottom colours (RGB in [0, 1]) of the viewer's background gradient."""

CAMERA_OFFSET = (1.1, -1.9, 1.1)
"""Default camera position (m) relative to the point it looks at, world axes: in front of and
to the right of the arm, looking at it from above."""

CAMERA_TARGET = (0.3, 0.0, 0.2)
"""The point (m, world frame) the default camera looks at and orbits: in front of the base."""

CAMERA_FOV = 40.0
"""Vertical field of view (degrees) of the camera; MeshCat's default (75) distorts the arm."""


def meshcat_module() -> Any:
    """The ``meshcat`` package, or ``ImportError`` saying how to install it."""
    try:
        import meshcat
        import meshcat.animation
        import meshcat.geometry
    except ImportError as err:
        raise ImportError(f"the 3D views need meshcat: {INSTALL_HINT}") from err
    return meshcat


# ------------------------------------------------------------------ the offline recorder
class RecordingWindow:
    """Stands in for MeshCat's ``ViewerWindow``: keeps each command as MeshCat's server does.

    The server keeps one node per path with its object, transform, properties and animation
    (a new object drops the node's properties; ``delete`` removes the subtree), and writes the
    tree as drawing commands into its viewer page; ``meshcat_page(commands())`` does that here.
    """

    def __init__(self) -> None:
        from meshcat.servers.tree import SceneTree

        self.tree = SceneTree()

    def send(self, command: Any) -> None:
        """Record one MeshCat command (``SetObject``, ``SetTransform``, ``SetProperty``,
        ``SetAnimation``, ``Delete``, or an object that lowers to one)."""
        import umsgpack
        from meshcat.servers.tree import SceneTree, find_node

        data = command.lower()
        kind = data["type"]
        path = [p for p in data["path"].split("/") if p]
        packed = umsgpack.packb(data)
        if kind == "delete":
            if path:
                find_node(self.tree, path[:-1]).pop(path[-1], None)
            else:
                self.tree = SceneTree()
            return
        node = find_node(self.tree, path)
        if kind == "set_object":
            node.object, node.properties = packed, []
        elif kind == "set_transform":
            node.transform = packed
        elif kind == "set_property":
            node.properties.append(packed)
        elif kind == "set_animation":
            node.animation = packed
        else:
            raise ValueError(f"unsupported MeshCat command {kind!r}")

    def commands(self) -> list[bytes]:
        """The recorded commands in MeshCat's order: per node (depth first), its object, its
        properties, its transform, its animation."""
        from meshcat.servers.tree import walk

        return [c for node in walk(self.tree)
                for c in (node.object, *node.properties, node.transform, node.animation)
                if c is not None]


def meshcat_page(commands: Sequence[bytes], title: str = "MeshCat", caption: str = "") -> str:
    """A self-contained viewer page: MeshCat's viewer script, then ``commands`` (msgpack bytes,
    each embedded as base64). With the default title and no caption it is, byte for byte, the
    page MeshCat's server writes for ``static_html()``."""
    from meshcat.servers.zmqserver import VIEWER_ROOT, create_command

    script = pathlib.Path(VIEWER_ROOT, "main.min.js").read_text()
    page = _PAGE.format(mainminjs=script, commands="".join(create_command(c) for c in commands))
    if title != "MeshCat":
        page = page.replace("<title>MeshCat</title>", f"<title>{html.escape(title)}</title>", 1)
    if caption:
        page = page.replace('<div id="meshcat-pane">', _CAPTION.format(html.escape(caption))
                            + '<div id="meshcat-pane">', 1)
    return page


# MeshCat 0.3.2's page (meshcat/servers/zmqserver.py, "get_scene"), kept verbatim so that the
# pages compare equal; meshcat has no function that returns it without a running server.
_PAGE = """
                <!DOCTYPE html>
                <html>
                    <head> <meta charset=utf-8> <title>MeshCat</title> </head>
                    <body>
                        <div id="meshcat-pane">
                        </div>
                        <script>
                            {mainminjs}
                        </script>
                        <script>
                            var viewer = new MeshCat.Viewer(document.getElementById("meshcat-pane"));
                            {commands}
                        </script>
                         <style>
                            body {{margin: 0; }}
                            #meshcat-pane {{
                                width: 100vw;
                                height: 100vh;
                                overflow: hidden;
                            }}
                        </style>
                        <script id="embedded-json"></script>
                    </body>
                </html>
            """  # noqa: E501

_CAPTION = ('<div id="caption" style="position: absolute; left: 8px; top: 8px; z-index: 1; '
            'max-width: 60vw; font: 13px/1.35 sans-serif; color: #222; '
            'background: rgba(255, 255, 255, 0.8); padding: 4px 8px; white-space: pre-line">'
            '{}</div>')


def offline_visualizer() -> meshcat.Visualizer:
    """A MeshCat ``Visualizer`` that records the scene for :meth:`Scene.write_html` (no server,
    no network)."""
    return meshcat_module().Visualizer(window=RecordingWindow())


def live_visualizer() -> meshcat.Visualizer:
    """A MeshCat ``Visualizer`` on a new local server (a subprocess; its address is printed)."""
    return meshcat_module().Visualizer()


# ------------------------------------------------------------------ the scene
def _translation(p: Sequence[float]) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = p
    return t


def _material(colour: int, opacity: float = 1.0) -> Any:
    import meshcat.geometry as g

    return g.MeshLambertMaterial(color=colour, opacity=opacity,
                                 depthWrite=opacity >= 1.0)


def _triangles(mesh: Any) -> Any:
    import meshcat.geometry as g

    return g.TriangularMeshGeometry(np.asarray(mesh.vertices), np.asarray(mesh.faces))


@dataclass
class Arm:
    """An arm drawn in a :class:`Scene`: the MeshCat paths of its parts."""

    path: str
    """Path of the arm's group (its transform puts the base at its height)."""
    kind: str
    """``collision`` or ``visual`` (:data:`ur5kin.meshes.KINDS`)."""
    parts: list[str] = field(default_factory=list)
    """Path of each part, in the order of :func:`ur5kin.mesh_parts`."""


class Scene:
    """Draws the task world onto a MeshCat ``Visualizer`` (offline or live).

    Parameters
    ----------
    vis : meshcat.Visualizer
        From :func:`offline_visualizer` or :func:`live_visualizer`.
    base_height : float, m
        Height of the robot base above the plane.
    """

    def __init__(self, vis: meshcat.Visualizer, base_height: float) -> None:
        self.vis = vis
        self.base_height = ur5kin.world.check_base_height(base_height)

    # --- the world
    def setup(self, target: Sequence[float] = CAMERA_TARGET,
              offset: Sequence[float] = CAMERA_OFFSET) -> None:
        """A light background, no axes or grid, and the default camera at ``offset`` (m) from
        ``target`` (m, world frame), looking at it.

        MeshCat's orbit controls turn about the origin of the viewer's world, so the drawn
        world (the node ``/meshcat``) is shifted by ``-target`` to put ``target`` there.
        """
        import meshcat.geometry as g

        for name, colour in zip(("top_color", "bottom_color"), BACKGROUND, strict=True):
            self.vis["/Background"].set_property(name, list(colour))
        self.vis["/Axes"].set_property("visible", False)
        self.vis["/Grid"].set_property("visible", False)  # the ground plane is drawn instead
        self.vis.set_transform(_translation(-np.asarray(target, dtype=float)))
        camera = self.vis["/Cameras/default/rotated"]
        camera.set_object(g.PerspectiveCamera(fov=CAMERA_FOV, near=0.01, far=100.0))
        dx, dy, dz = offset
        # the camera's node is y-up, turned +90 degrees about x into the world's z-up
        camera["<object>"].set_property("position", [dx, dz, -dy])

    def ground(self, extent: float = GROUND_EXTENT) -> None:
        """The ground plane z = 0: a thin slab ``extent`` (m) on a side, its top a hair below
        z = 0 (:data:`GROUND_DROP`)."""
        import meshcat.geometry as g

        thickness = 0.004
        self.vis["ground"].set_object(g.Box([extent, extent, thickness]),
                                      _material(GROUND_COLOUR))
        self.vis["ground"].set_transform(_translation([0.0, 0.0, -GROUND_DROP - thickness / 2]))

    # --- the arm
    def arm(self, name: str, q: Sequence[float], kind: str = "collision",
            opacity: float = 1.0) -> Arm:
        """Draw the arm at configuration ``q (6,)`` (rad) under the path ``name``: each part of
        :func:`ur5kin.mesh_parts` (``kind``), its links in alternating greys (a COLLADA mesh in
        its own materials unless translucent)."""
        arm = Arm(name, kind)
        self.vis[name].set_transform(_translation([0.0, 0.0, self.base_height]))
        for part in ur5kin.mesh_parts(kind):
            path = f"{name}/{part.name}"
            colour = ARM_COLOURS[part.joint % len(ARM_COLOURS)]
            if part.path is not None and part.path.suffix.lower() == ".dae":
                from pinocchio.visualize.meshcat_visualizer import DaeMeshGeometry

                dae = DaeMeshGeometry(str(part.path))
                dae.path = self.vis[path].path
                dae.set_scale(part.scale)
                if opacity < 1.0:
                    dae.material = _material(colour, opacity)
                self.vis.window.send(dae)
            else:
                self.vis[path].set_object(_triangles(part.local_mesh()),
                                          _material(colour, opacity))
            arm.parts.append(path)
        self.pose(arm, q)
        return arm

    def pose(self, arm: Arm, q: Sequence[float]) -> None:
        """Set the drawn arm's configuration ``q (6,)`` (rad)."""
        for path, pose in zip(arm.parts, ur5kin.part_poses(np.asarray(q, dtype=float),
                                                           arm.kind), strict=True):
            self.vis[path].set_transform(pose)

    # --- goals, paths, regions
    def region(self, region: regions.Region, name: str, colour: int,
               opacity: float = REGION_OPACITY) -> None:
        """Draw a goal region as what it is: its own mesh (a box, a z-limit cut to the reach
        ball, a mesh), faces translucent with its edges outlined. A region with no mesh of its
        own (a bare z-limit, unbounded) is drawn cut to the arm's reach ball."""
        import meshcat.geometry as g

        mesh = region_mesh(region, self.base_height)
        self.vis[name]["faces"].set_object(_triangles(mesh), _material(colour, opacity))
        # the outline: edges between faces that meet at more than EDGE_ANGLE (a box's 12
        # edges, a cut ball's rims), not the triangulation of flat or gently curved faces
        sharp = mesh.face_adjacency_angles > math.radians(EDGE_ANGLE)
        edges = mesh.vertices[mesh.face_adjacency_edges[sharp]]
        if len(edges):
            self.vis[name]["edges"].set_object(g.LineSegments(
                g.PointsGeometry(np.asarray(edges, dtype=np.float32).reshape(-1, 3).T),
                g.LineBasicMaterial(color=colour)))

    def goal(self, name: str, position: Sequence[float], radius: float,
             reached: bool) -> None:
        """A goal (m, world frame): its success ball of ``radius`` (m), translucent, and a dot
        at its centre, green if reached and red if not."""
        import meshcat.geometry as g

        colour = REACHED_COLOUR if reached else MISSED_COLOUR
        self.vis[name].set_transform(_translation(position))
        self.vis[name]["ball"].set_object(g.Sphere(radius), _material(colour, GOAL_OPACITY))
        self.vis[name]["dot"].set_object(g.Sphere(GOAL_DOT_RADIUS), _material(colour))

    def marker(self, name: str, position: Sequence[float], colour: int,
               radius: float = GOAL_DOT_RADIUS) -> None:
        """A solid ball of ``radius`` (m) at ``position`` (m, world frame)."""
        import meshcat.geometry as g

        self.vis[name].set_transform(_translation(position))
        self.vis[name].set_object(g.Sphere(radius), _material(colour))

    def path(self, name: str, points: Any, colour: int) -> None:
        """A polyline through ``points (k, 3)`` (m, world frame)."""
        import meshcat.geometry as g

        pts = np.asarray(points, dtype=np.float32)
        self.vis[name].set_object(g.Line(g.PointsGeometry(pts.T),
                                          g.LineBasicMaterial(color=colour, linewidth=2)))

    # --- output
    def write_html(self, out: pathlib.Path, title: str, caption: str = "") -> int:
        """Write the recorded scene as one self-contained HTML page; returns its size (bytes).

        Raises
        ------
        TypeError
            When the scene is live (draws onto a server, not a recorder).
        """
        window = self.vis.window
        if not isinstance(window, RecordingWindow):
            raise TypeError("write_html needs a scene of offline_visualizer()")
        page = meshcat_page(window.commands(), title, caption)
        write_text(pathlib.Path(out), page)  # whole or not at all
        return len(page.encode())


def region_mesh(region: regions.Region, base_height: float) -> Any:
    """The trimesh a region is drawn as (m, world frame): its own mesh, or, for a region with
    none (a bare z-limit), its part inside the arm's reach ball.

    Raises
    ------
    ValueError
        When neither has a mesh (e.g. a mesh region intersected with a ball); names the region.
    """
    import regions as regions_pkg

    try:
        return region.mesh
    except ValueError as first:
        cut = regions_pkg.Intersection((region, regions_pkg.reach_ball(base_height)),
                                       name=region.name)
        try:
            return cut.mesh
        except ValueError:
            raise ValueError(f"region {region.name!r} cannot be drawn: {first}") from first


class Timeline:
    """Keyframes of a MeshCat animation at ``fps`` frames per second (the control rate).

    The viewer interpolates between keys (poses linearly, rotations by slerp); a visibility
    switches at its key.
    """

    def __init__(self, fps: float) -> None:
        import meshcat.animation

        self.fps = float(fps)
        self.animation = meshcat.animation.Animation(default_framerate=self.fps)

    def poses(self, vis: meshcat.Visualizer, arm: Arm, first: int, q: Any) -> None:
        """Key configurations ``q (T, 6)`` (rad) at frames ``first .. first + T - 1``."""
        q = np.asarray(q, dtype=float)
        poses = ur5kin.part_poses(q, arm.kind)
        for t in range(len(q)):
            with self.animation.at_frame(vis, first + t) as at:
                for path, pose in zip(arm.parts, poses[t], strict=True):
                    at[path].set_transform(pose)

    def visible(self, vis: meshcat.Visualizer, path: str, frame: int, shown: bool) -> None:
        """Key the visibility of ``path`` at ``frame``."""
        with self.animation.at_frame(vis, frame) as at:
            at[path].set_property("visible", "boolean", bool(shown))

    def play(self, vis: meshcat.Visualizer, loop: bool = True) -> None:
        """Hand the animation to the viewer, playing at once (over and over if ``loop``)."""
        vis.set_animation(self.animation, play=True, repetitions=(2**31 - 1) if loop else 1)
