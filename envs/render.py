"""Drawings of the Reacher: the arm, the goal and the goal region, in a side and a top view.

The arm is the polyline through the link origins (base_link ... tool0, world frame); the goal is
a star inside its success circle (dotted, solid on success); the region is its axis-aligned
bounding box (dashed), cut to the view; the ground plane is the line z = 0.

Matplotlib, off screen (Agg) for ``rgb_array`` frames; a pyplot window for ``human``. The
figure is built once per renderer and only its line data change between frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import ur5kin
from envs.spec import TaskSpec

RENDER_MODES = ("human", "rgb_array")
"""Render modes of the envs: a matplotlib window, or frames as ``(H, W, 3) uint8`` arrays."""


def check_render_mode(render_mode: str | None) -> str | None:
    """``render_mode`` (one of :data:`RENDER_MODES` or None), or a ValueError."""
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {list(RENDER_MODES)} or None; got "
                         f"{render_mode!r}")
    return render_mode


@dataclass(frozen=True)
class RenderConfig:
    """How frames look; none of it affects the task."""

    width_in: float = 8.0
    """Figure width (inches)."""
    height_in: float = 4.0
    """Figure height (inches)."""
    dpi: int = 80
    """Pixels per inch: 8 x 4 in at 80 dpi is a 640 x 320 frame."""
    half_width: float = 1.1
    """The views show x and y in [-half_width, half_width] m (the arm reaches about 1 m)."""
    z_range: tuple[float, float] = (-0.1, 1.2)
    """Heights (m) shown in the side view."""
    arm_color: str = "tab:blue"
    """Colour of the arm's polyline through the link origins."""
    goal_color: str = "tab:green"
    """Colour of the goal and its success circle."""
    region_color: str = "tab:orange"
    """Colour of the goal region's bounding box."""
    contact_color: str = "tab:red"
    """Colour of the arm in a step that ended on the plane."""


class ArmRenderer:
    """Draws one copy of the task.

    Parameters
    ----------
    task : TaskSpec
    human : bool
        Show a pyplot window (True) or render off screen and return frames (False).
    config : RenderConfig
    """

    def __init__(self, task: TaskSpec, human: bool = False,
                 config: RenderConfig | None = None) -> None:
        import matplotlib

        self.task, self.human = task, human
        self.config = config = config or RenderConfig()
        if human:
            import matplotlib.pyplot as plt

            self._plt = plt
            fig = plt.figure(figsize=(config.width_in, config.height_in), dpi=config.dpi)
        else:
            from matplotlib.backends.backend_agg import FigureCanvasAgg
            from matplotlib.figure import Figure

            fig = Figure(figsize=(config.width_in, config.height_in), dpi=config.dpi)
            FigureCanvasAgg(fig)
        del matplotlib
        self.fig = fig
        side, top = fig.subplots(1, 2)
        self._views = ((side, (0, 2), "x (m)", "z (m)", "side"), (top, (0, 1), "x (m)", "y (m)",
                                                                   "top"))
        bounds = np.asarray(task.goal_region.bounds, dtype=float)
        w = config.half_width
        shown = np.array([[-w, -w, config.z_range[0]], [w, w, config.z_range[1]]])
        bounds = np.clip(bounds, shown[0], shown[1])
        self._arm: list = []
        self._tool: list = []
        self._goal: list = []
        self._circle: list = []
        theta = np.linspace(0.0, 2.0 * np.pi, 64)
        self._unit_circle = np.stack([np.cos(theta), np.sin(theta)], axis=1) * task.success_radius
        for ax, (i, j), xlabel, ylabel, title in self._views:
            lo, hi = bounds[0], bounds[1]
            ax.plot([lo[i], hi[i], hi[i], lo[i], lo[i]], [lo[j], lo[j], hi[j], hi[j], lo[j]],
                    ls="--", color=config.region_color, lw=1)
            if title == "side":
                ax.axhline(0.0, color="k", lw=1)
                ax.set_ylim(*config.z_range)
            else:
                ax.set_ylim(-w, w)
            ax.set_xlim(-w, w)
            ax.set_aspect("equal")
            ax.set_xlabel(xlabel)
            ax.set_ylabel(ylabel)
            ax.set_title(title)
            self._arm.append(ax.plot([], [], "-o", color=config.arm_color, lw=3, ms=3)[0])
            self._tool.append(ax.plot([], [], "s", color=config.arm_color, ms=5)[0])
            self._goal.append(ax.plot([], [], "*", color=config.goal_color, ms=10)[0])
            self._circle.append(ax.plot([], [], "-", color=config.goal_color, lw=1)[0])
        self._title = fig.suptitle("")
        fig.tight_layout()

    def region_name(self) -> str:
        """A short name of the task's region (its string, or the region's name if long)."""
        region = self.task.region
        return region if len(region) <= 24 else self.task.goal_region.name

    def draw(self, q: np.ndarray, goal: np.ndarray, success: bool = False,
             contact: bool = False, title: str = "") -> np.ndarray | None:
        """Draw configuration ``q (6,)`` rad and ``goal (3,)`` m (world frame).

        ``success`` draws the goal's success circle solid, ``contact`` the arm in red;
        ``title`` goes above both views.

        Returns
        -------
        frame : (H, W, 3) uint8, or None in human mode
        """
        base_points = np.asarray(ur5kin.link_poses(np.asarray(q, dtype=float)))[:, :3, 3]
        points = ur5kin.to_world(base_points, self.task.base_height)
        goal = np.asarray(goal, dtype=float)
        color = self.config.contact_color if contact else self.config.arm_color
        for k, (_, (i, j), *_rest) in enumerate(self._views):
            self._arm[k].set_data(points[:, i], points[:, j])
            self._arm[k].set_color(color)
            self._tool[k].set_data(points[-1:, i], points[-1:, j])
            self._goal[k].set_data([goal[i]], [goal[j]])
            ring = self._unit_circle + goal[[i, j]]
            self._circle[k].set_data(ring[:, 0], ring[:, 1])
            self._circle[k].set_linestyle("-" if success else ":")
        self._title.set_text(title)
        if self.human:
            self._plt.pause(1.0 / self.task.control_hz)
            return None
        self.fig.canvas.draw()
        return np.asarray(self.fig.canvas.buffer_rgba())[..., :3].copy()

    def close(self) -> None:
        """Release the figure."""
        if self.human:
            self._plt.close(self.fig)
        self.fig = None  # type: ignore[assignment]
