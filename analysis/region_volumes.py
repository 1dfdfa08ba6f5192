"""How much of the UR5's reachable workspace each goal constraint region covers, per joint count.

``python -m analysis.region_volumes`` prints, for the paper's regions and 2..6 controlled
joints: the region's volume, the reachable workspace of the sub-chain above the plane (a voxel
estimate with its error bar), the part of it inside the region, the goal acceptance of the
paper's joint-space sampler, the mean distance from the start's end effector to the goals, and
whether the start's end effector lies in the region. Run with ``--help`` for the other outputs
(JSON, a figure, a 3D page, the estimate's convergence).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import pathlib
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np
from scipy.spatial import ConvexHull
from tqdm import tqdm

import regions
import ur5kin
from analysis import outputs
from ddpg_her.config import Parser
from envs.spec import GOAL_SAMPLERS, N_JOINTS_RANGE
from regions.coverage import (
    DEFAULT_RESOLUTION,
    DEFAULT_SAMPLES,
    CoverageRow,
    VoxelWorkspace,
    WorkspaceSamples,
    coverage_row,
    sample_workspace,
)
from regions.registry import BASE_HEIGHT, DEFAULT_BASE_HEIGHT, PAPER_REGIONS
from regions.samplers import CartesianSampler, UnreachableRegionError
from ur5kin.checks import COUNT, SEED, integer, number

START_CHOICES = ("paper", "zero", "constrained")
"""``--start`` values: the paper's per-region choice, or one start for every region."""

CONVERGENCE_RESOLUTIONS = (0.1, 0.07, 0.05, 0.035, 0.025)
"""Voxel edges (m) of ``--convergence``; the samples grow like edge^-3 from ``--samples`` at
``--resolution``, so that every step has as many samples per voxel."""

IK_REFERENCE_GOALS = 20_000
"""Goals of the Cartesian (IK) sampler behind the independent workspace volume that
``--convergence`` prints beside the voxel estimates."""

PLOT_CLOUD_POINTS = 4000
"""Workspace samples drawn (grey) per panel of ``--plot``."""

PLOT_GOAL_POINTS = 1500
"""Accepted goals drawn (coloured) per panel of ``--plot``."""


@dataclass(frozen=True)
class Settings:
    """What the study computes; every field is a command-line flag."""

    regions: tuple[str, ...] = PAPER_REGIONS
    """Region strings (names or regions.parse forms)."""
    joints: tuple[int, ...] = tuple(range(N_JOINTS_RANGE[0], N_JOINTS_RANGE[1] + 1))
    """Controlled joint counts (every count the task allows)."""
    samples: int = DEFAULT_SAMPLES
    """Uniform joint-space samples per joint count and held-joint angles."""
    seed: int = 0
    """Seed of every generator of the study."""
    resolution: float = DEFAULT_RESOLUTION
    """Voxel edge (m) of the workspace estimate."""
    base_height: float = DEFAULT_BASE_HEIGHT
    """Height (m) of the robot base above the plane."""
    start: str = "paper"
    """Start pose: paper (zero for unconstrained, constrained otherwise), zero or constrained."""
    sampler: str = "joint"
    """Sampler behind goal_acceptance and mean_goal_distance_m."""
    goals: int = 5000
    """Goals drawn per row with --sampler cartesian."""


def start_for(region_name: str, choice: str) -> tuple[float, ...]:
    """Start configuration (rad) of a region's rows.

    ``paper``: docs/design.md's choice, the zero start for ``unconstrained`` and the constrained
    start for every other region (user regions included).
    """
    if choice not in START_CHOICES:
        raise ValueError(f"start must be one of {START_CHOICES}; got {choice!r}")
    return {"paper": regions.default_start(region_name), "zero": regions.UNCONSTRAINED_START,
            "constrained": regions.CONSTRAINED_START}[choice]


def start_label(start_q: Sequence[float]) -> str:
    """Short name of a start configuration for the table."""
    names = {regions.UNCONSTRAINED_START: "zero", regions.CONSTRAINED_START: "constrained"}
    return names.get(tuple(start_q), "[" + ", ".join(f"{x:.3g}" for x in start_q) + "]")


def _rng(seed: int, *key: object) -> np.random.Generator:
    """A generator for one part of the study, fixed by the seed and the part's key alone (so a
    row does not change when other regions or joint counts are added)."""
    digest = hashlib.sha256(repr(key).encode()).digest()
    return np.random.default_rng([seed, int.from_bytes(digest[:8], "little")])


def _workspace_key(n_joints: int, start_q: Sequence[float]) -> tuple[int, tuple[float, ...]]:
    """Samples depend on the joint count and the held joints n+1..6 only."""
    return n_joints, tuple(start_q[n_joints:])


@dataclass
class Study:
    """The study's results: rows, and the samples behind them (for plots)."""

    rows: list[CoverageRow]
    samples: dict[tuple[int, tuple[float, ...]], WorkspaceSamples]
    region_objects: dict[str, regions.Region]
    seconds: float


def run_study(settings: Settings, progress: bool = True) -> Study:
    """Compute every row of the table (``progress``: a tqdm bar on stderr)."""
    t0 = time.perf_counter()
    objs = {spec: regions.parse(spec, settings.base_height) for spec in settings.regions}
    keys: dict[tuple[int, tuple[float, ...]], tuple[float, ...]] = {}
    for spec in settings.regions:
        for n in settings.joints:
            start_q = start_for(objs[spec].name, settings.start)
            keys.setdefault(_workspace_key(n, start_q), start_q)
    samples, voxels = {}, {}
    steps = len(keys) + len(settings.regions) * len(settings.joints)
    with tqdm(total=steps, desc="region volumes", disable=not progress, file=sys.stderr) as bar:
        for key, start_q in keys.items():
            n = key[0]
            bar.set_postfix_str(f"workspace n={n}")
            ws = sample_workspace(n, start_q, settings.base_height, settings.samples,
                                  _rng(settings.seed, "workspace", *key))
            samples[key] = ws
            voxels[key] = VoxelWorkspace.from_points(ws.goals[ws.clear], settings.resolution)
            bar.update()
        rows = []
        for spec in settings.regions:
            region = objs[spec]
            for n in settings.joints:
                bar.set_postfix_str(f"{region.name} n={n}")
                start_q = start_for(region.name, settings.start)
                key = _workspace_key(n, start_q)
                row = coverage_row(region, samples[key], voxels[key], start_q)
                if settings.sampler == "cartesian":
                    row = _with_cartesian(row, region, start_q, settings)
                rows.append(row)
                bar.update()
    return Study(rows, samples, objs, time.perf_counter() - t0)


def _with_cartesian(row: CoverageRow, region: regions.Region, start_q: tuple[float, ...],
                    settings: Settings) -> CoverageRow:
    """Replace the joint-space acceptance and distance by the Cartesian sampler's.

    Acceptance is then the fraction of uniform points of the region that IK reaches with a
    plane-clear configuration; NaN with fewer joints than the sampler needs.
    """
    values = {"goal_acceptance": math.nan, "mean_goal_distance_m": math.nan}
    if row.joints >= CartesianSampler.MIN_JOINTS:
        try:
            sampler = CartesianSampler(region, row.joints, start_q, settings.base_height)
            batch = sampler.sample(settings.goals, _rng(settings.seed, "cartesian", region.name,
                                                        row.joints))
            origin = ur5kin.fk_world(start_q, settings.base_height)
            values = {"goal_acceptance": batch.reachable_fraction,
                      "mean_goal_distance_m": float(np.linalg.norm(batch.goals - origin,
                                                                   axis=1).mean())}
        except UnreachableRegionError:
            values["goal_acceptance"] = 0.0
    return CoverageRow(**{**asdict(row), **values})


def _fmt(value: float, digits: int = 3) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def format_table(study: Study, settings: Settings) -> str:
    """The rows as an aligned text table, with the notes that qualify them."""
    header = ("region", "n", "start", "region m3", "workspace m3", "covered m3", "fraction",
              "acceptance", "mean dist m", "start in")
    lines = []
    for r in study.rows:
        volume = _fmt(r.region_volume_m3) + ("" if r.region_volume_exact else "~")
        workspace = f"{_fmt(r.workspace_volume_m3)}±{_fmt(r.workspace_volume_error_m3)}"
        covered = f"{_fmt(r.covered_volume_m3)}±{_fmt(r.covered_volume_error_m3)}"
        lines.append((r.region, str(r.joints) + ("*" if r.workspace_is_surface else ""),
                      start_label(r.start_q), volume, workspace, covered,
                      _fmt(r.workspace_fraction), _fmt(r.goal_acceptance, 4),
                      _fmt(r.mean_goal_distance_m), "yes" if r.start_inside else "no"))
    widths = [max(len(h), *(len(line[i]) for line in lines)) for i, h in enumerate(header)]
    out = ["  ".join(c.ljust(w) for c, w in zip(line, widths, strict=True))
           for line in (header, ["-" * w for w in widths], *lines)]
    sampler = ("joint-space sampler (paper): accepted / uniform joint samples"
               if settings.sampler == "joint" else
               f"Cartesian sampler: reachable fraction of uniform region points "
               f"({settings.goals} goals per row)")
    out += [
        "",
        f"workspace: voxel occupancy of {settings.samples} uniform joint samples per joint count "
        f"(plane-clear), voxel edge {settings.resolution} m; ± is half the boundary voxels' "
        "volume (interior only .. every occupied voxel)",
        "fraction = covered / workspace; acceptance: " + sampler,
        "mean dist: from the start's tool0 to the goals; start in: the start's tool0 lies in the "
        "region",
        "start: zero = " + str(list(regions.UNCONSTRAINED_START)) + ", constrained = "
        + "[0, -pi/4, pi/2, 0, 0, 0] rad (docs/design.md open point 1)",
        f"base height {settings.base_height} m; seed {settings.seed}; "
        f"{study.seconds:.1f} s",
    ]
    if any(r.workspace_is_surface for r in study.rows):
        out.append("n*: with 2 joints tool0 moves on a surface: its 'volume' is a shell about one "
                   "voxel thick (-> 0 as the voxels shrink)")
    if any(not r.region_volume_exact for r in study.rows):
        out.append("~: region volume estimated on a grid (no closed form)")
    return "\n".join(out)


def convergence(settings: Settings, progress: bool = True) -> list[dict[str, float]]:
    """Workspace volume as the voxel edge shrinks, samples growing like edge^-3.

    For 3+ joints each row also carries an independent estimate: the Cartesian (IK) sampler's
    reachable fraction of the reach ball above the plane times its exact volume (a binomial
    standard error; for 4+ joints a lower bound, see CartesianSampler).
    """
    ball = regions.get("unconstrained", settings.base_height)
    out = []
    jobs = [(n, res) for n in settings.joints for res in CONVERGENCE_RESOLUTIONS]
    reference: dict[int, tuple[float, float]] = {}
    for n, res in tqdm(jobs, desc="convergence", disable=not progress, file=sys.stderr):
        start_q = start_for("unconstrained", settings.start)
        if n >= CartesianSampler.MIN_JOINTS and n not in reference:
            batch = CartesianSampler(ball, n, start_q, settings.base_height).sample(
                IK_REFERENCE_GOALS, _rng(settings.seed, "ik-reference", n))
            f = batch.reachable_fraction
            reference[n] = (f * ball.volume,
                            math.sqrt(f * (1 - f) / batch.in_region) * ball.volume)
        count = round(settings.samples * (settings.resolution / res) ** 3)
        ws = sample_workspace(n, start_q, settings.base_height, count,
                              _rng(settings.seed, "convergence", n, res))
        vox = VoxelWorkspace.from_points(ws.goals[ws.clear], res)
        ref, ref_err = reference.get(n, (math.nan, math.nan))
        out.append({"joints": n, "resolution_m": res, "samples": count,
                    "workspace_volume_m3": vox.volume, "workspace_volume_error_m3": vox.error,
                    "ik_reference_m3": ref, "ik_reference_error_m3": ref_err})
    return out


def _outline(points: np.ndarray) -> np.ndarray:
    """Closed convex outline ``(k + 1, 2)`` of 2-D points (a region's projected mesh)."""
    loop = points[ConvexHull(points).vertices]
    return np.vstack([loop, loop[:1]])


def plot(study: Study, settings: Settings, path: pathlib.Path, n_joints: int) -> list[pathlib.Path]:
    """Draw each region over the reachable workspace: side view (x-z) above, top view (x-y)
    below, like the paper's region figures; save the drawn data beside the figure.

    Returns the written paths: the figure, ``<stem>.json`` (rows, outlines, start positions,
    settings) and ``<stem>.csv`` (the drawn samples with per-region acceptance).
    """
    from matplotlib.lines import Line2D

    names = list(study.region_objects)
    fig, axes = outputs.pyplot().subplots(2, len(names), figsize=(3.6 * len(names), 6.4),
                                          squeeze=False)
    rng = _rng(settings.seed, "plot")
    table_rows: list[dict[str, object]] = []
    outlines: dict[str, dict[str, list[list[float]]]] = {}
    starts: dict[str, list[float]] = {}
    for col, spec in enumerate(names):
        region = study.region_objects[spec]
        start_q = start_for(region.name, settings.start)
        ws = study.samples[_workspace_key(n_joints, start_q)]
        clear = np.flatnonzero(ws.clear)
        cloud = rng.choice(clear, size=min(PLOT_CLOUD_POINTS, len(clear)), replace=False)
        accepted = clear[region.contains(ws.goals[clear])]
        goals = rng.choice(accepted, size=min(PLOT_GOAL_POINTS, len(accepted)), replace=False)
        tip = ur5kin.fk_world(start_q, settings.base_height)
        starts[region.name] = tip.tolist()
        outlines[region.name] = {}
        for row, (i, j, label) in enumerate(((0, 2, "x-z side"), (0, 1, "x-y top"))):
            ax = axes[row, col]
            ax.scatter(ws.goals[cloud, i], ws.goals[cloud, j], s=1, c="0.75", lw=0,
                       rasterized=True)
            ax.scatter(ws.goals[goals, i], ws.goals[goals, j], s=1.5, c="tab:blue", lw=0,
                       rasterized=True)
            if region.is_bounded:
                try:
                    ring = _outline(np.asarray(region.mesh.vertices)[:, [i, j]])
                    outlines[region.name][label] = ring.tolist()
                    ax.plot(ring[:, 0], ring[:, 1], c="tab:red", lw=1.2)
                except ValueError:
                    pass
            ax.plot(tip[i], tip[j], marker="*", ms=11, c="tab:orange", mec="k")
            ax.plot(0.0, settings.base_height if j == 2 else 0.0, marker="s", c="k", ms=5)
            if j == 2:
                ax.axhline(0.0, c="k", lw=0.8)
            ax.set_aspect("equal")
            ax.set_xlabel("x (m)")
            ax.set_ylabel("z (m)" if j == 2 else "y (m)")
            ax.set_title(f"{region.name}, {n_joints} joints, {label}", fontsize=9)
        table_rows += [r.full_row() for r in study.rows
                       if r.region == region.name and r.joints == n_joints]
    handles = [Line2D([], [], ls="", marker="o", ms=4, c="0.75", label="workspace samples"),
               Line2D([], [], ls="", marker="o", ms=4, c="tab:blue", label="accepted goals"),
               Line2D([], [], c="tab:red", label="region outline"),
               Line2D([], [], ls="", marker="*", ms=10, c="tab:orange", mec="k",
                      label="start tool0"),
               Line2D([], [], ls="", marker="s", ms=5, c="k", label="robot base"),
               Line2D([], [], c="k", lw=0.8, label="plane z = 0")]
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=8,
               frameon=False)
    fig.suptitle(f"Goal regions over the reachable workspace ({n_joints} joints, base at "
                 f"{settings.base_height} m; start: {settings.start})", fontsize=10)
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    outputs.save_figure(fig, path, dpi=130)

    data_json = path.with_suffix(".json")
    outputs.write_text(data_json, json.dumps({
        "settings": asdict(settings), "plot_joints": n_joints, "rows": table_rows,
        "outlines": outlines, "start_tool0_m": starts,
        "regions": {r.name: r.to_dict() for r in study.region_objects.values()
                    if not isinstance(r, regions.MeshRegion)},
    }, indent=1))
    data_csv = path.with_suffix(".csv")
    samples = []
    for key in sorted({_workspace_key(n_joints, start_for(r.name, settings.start))
                       for r in study.region_objects.values()}):
        ws = study.samples[key]
        idx = rng.choice(ws.count, size=min(PLOT_CLOUD_POINTS, ws.count), replace=False)
        inside = [r.contains(ws.goals[idx]) for r in study.region_objects.values()]
        samples += [[" ".join(f"{x:.6g}" for x in key[1]), *(f"{v:.6f}" for v in ws.goals[k]),
                     int(ws.clear[k]), *(int(col[m]) for col in inside)]
                    for m, k in enumerate(idx)]
    outputs.write_csv(data_csv, ["held_joints_rad", "x_m", "y_m", "z_m", "clear",
                                 *[f"in_{r.name}" for r in study.region_objects.values()]],
                      samples)
    return [path, data_json, data_csv]


VIEW_CAMERA_OFFSET = (1.6, -2.8, 1.7)
"""Camera position (m) of ``--view`` relative to the point it looks at: farther than the
replay's, so that the reach ball (0.95 m radius) fits."""

START_OPACITY = (1.0, 0.5)
"""Opacity of the first start pose's arm, and of every further one's (translucent, so that
both read where they overlap)."""


def view(settings: Settings, path: pathlib.Path, meshes: str = "collision") -> int:
    """Draw the regions and their start poses in the 3D viewer (``analysis.scene``) into one
    self-contained HTML page; returns its size (bytes).

    Each region is drawn as what it is (a box, a z-limit cut to the reach ball, a mesh) in its
    own colour; each distinct start pose of the regions (``settings.start``) as the arm in that
    pose with a dot at its tool0. Every drawn thing is a node of the viewer's scene tree
    ("Open Controls", Scene), where it can be hidden.
    """
    from analysis import scene as scenes

    scene = scenes.Scene(scenes.offline_visualizer(), settings.base_height)
    scene.setup(offset=VIEW_CAMERA_OFFSET)
    scene.ground()
    names = []
    starts: dict[tuple[float, ...], list[str]] = {}
    for i, spec in enumerate(settings.regions):
        region = regions.parse(spec, settings.base_height)
        colour, colour_name = scenes.REGION_COLOURS[i % len(scenes.REGION_COLOURS)]
        scene.region(region, f"regions/{region.name}", colour)
        names.append(f"{region.name} ({colour_name})")
        starts.setdefault(start_for(region.name, settings.start), []).append(region.name)
    labels = []
    for k, (start_q, owners) in enumerate(starts.items()):
        label = start_label(start_q)
        scene.arm(f"starts/{label}", start_q, meshes, START_OPACITY[min(k, 1)])
        scene.marker(f"starts/{label}_tool0", ur5kin.fk_world(start_q, settings.base_height),
                     scenes.START_COLOUR)
        labels.append(f"{label} start ({', '.join(owners)})" + (", translucent" if k else ""))
    caption = ("goal regions: " + ", ".join(names) + "\narm: " + "; ".join(labels)
               + "; black dot: its tool0\n"
               + f"world frame: plane z = 0, base at (0, 0, {settings.base_height}) m")
    return scene.write_html(path, "UR5 goal regions", caption)


def build_parser() -> argparse.ArgumentParser:
    """The command line; every flag's help gives its unit."""
    d = Settings()
    parser = Parser(
        prog="python -m analysis.region_volumes",
        description=__doc__.split("\n\n")[0] + " World frame: plane z = 0, base at "
        "(0, 0, base height), m.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--regions", nargs="+", default=list(d.regions), metavar="REGION",
                        help="regions, space-separated; each one of: " + regions.spec_help())
    parser.add_argument("--joints", nargs="+", type=JOINTS.read, default=list(d.joints),
                        metavar="N",
                        help="controlled joint counts (joints 1..N move, the rest stay at the "
                        "start angles), 1-6")
    parser.add_argument("--samples", type=COUNT.read, default=d.samples,
                        help="uniform joint-space samples per joint count (and held-joint "
                        "angles); the workspace estimate wants >= 10 per voxel of the reach "
                        "ball's 6.9 m^3 box (see --convergence)")
    parser.add_argument("--seed", type=SEED.read, default=d.seed, help="seed of every generator")
    parser.add_argument("--resolution", type=number(0, above=True, note="m").read,
                        default=d.resolution, help="voxel edge of the workspace estimate (m)")
    parser.add_argument("--base-height", type=BASE_HEIGHT.read, default=d.base_height,
                        help="height of the robot base above the plane (m)")
    parser.add_argument("--start", choices=START_CHOICES, default=d.start,
                        help="start pose of the rows: paper = zero start [0,0,0,0,0,0] rad for "
                        "'unconstrained' and the constrained start [0,-pi/4,pi/2,0,0,0] rad for "
                        "every other region (docs/design.md); zero or constrained for all")
    parser.add_argument("--sampler", choices=GOAL_SAMPLERS, default=d.sampler,
                        help="sampler of the acceptance and distance columns: joint = the "
                        "paper's (accepted / uniform joint samples); cartesian = uniform in the "
                        "region, kept where IK reaches it (acceptance = reachable fraction of the "
                        "region; needs N >= 3)")
    parser.add_argument("--goals", type=COUNT.read, default=d.goals,
                        help="goals per row drawn by --sampler cartesian")
    parser.add_argument("--json", action="store_true",
                        help="print a JSON list of rows (keys: " + ", ".join(CoverageRow.JSON_KEYS)
                        + "; volumes in m^3, distances in m) instead of the table")
    parser.add_argument("--plot", type=pathlib.Path, metavar="FILE.png",
                        help="draw the regions over the workspace (x-z side and x-y top views); "
                        "writes FILE.json and FILE.csv with the drawn data beside it")
    parser.add_argument("--view", type=pathlib.Path, metavar="FILE.html",
                        help="write the regions and their start poses (the arm and its tool0) "
                        "as a 3D page that opens offline in a browser (needs meshcat: pip "
                        "install -e '.[view]'); written before the table is computed")
    parser.add_argument("--plot-joints", type=int, default=None, metavar="N",
                        help="joint count of the plotted workspace; None: 3 if listed in "
                        "--joints, else the largest")
    parser.add_argument("--convergence", action="store_true",
                        help="instead of the table, print the workspace volume for voxel edges "
                        + ", ".join(map(str, CONVERGENCE_RESOLUTIONS)) + " m (samples scaled "
                        "like edge^-3 from --samples at --resolution) beside an independent IK "
                        "estimate")
    return parser


VOXEL_GRID_COPIES = 4
"""Bytes per voxel of the grids one workspace holds at once (occupied, filled, masks): an
upper estimate, for refusing a --resolution that cannot fit."""


def voxel_bytes(resolution: float, base_height: float) -> float:
    """Bytes of the voxel grids of one workspace at ``resolution`` (m): its bounding box is
    at most the reach ball's, 2 R x 2 R wide and R + base_height (+ the shoulder) high."""
    from regions.reach import reach_radius

    r = reach_radius()
    cells = (2 * r / resolution + 2) ** 2 * ((r + base_height + 0.1) / resolution + 2)
    return cells * VOXEL_GRID_COPIES


JOINTS = integer(1, 6, note="joints 1..n move")
"""A --joints count."""


def _settings(args: argparse.Namespace, parser: argparse.ArgumentParser) -> Settings:
    need, have = voxel_bytes(args.resolution, args.base_height), outputs.available_bytes()
    if have is not None and need > have:
        parser.error(f"--resolution {args.resolution} m: the workspace's voxel grids would need "
                     f"about {need / 2 ** 30:.3g} GiB, more than the {have / 2 ** 30:.3g} GiB "
                     "of memory available; use a coarser voxel edge")
    for spec in args.regions:
        with outputs.usage_errors(parser, ValueError):
            regions.parse(spec, args.base_height)
    flags = {f.name: getattr(args, f.name) for f in fields(Settings)}  # one flag per field
    return Settings(**{**flags, "regions": tuple(args.regions),
                       "joints": tuple(dict.fromkeys(args.joints))})


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m analysis.region_volumes``."""
    parser = build_parser()
    outputs.add_force(parser, "with --plot or --view: replace files that hold something else "
                              "(refused by default: nothing is written, the files are named)")
    args = parser.parse_args(argv)
    settings = _settings(args, parser)
    progress = sys.stderr.isatty()
    if args.convergence:
        rows = convergence(settings, progress)
        if args.json:
            print(json.dumps([{k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                               for k, v in r.items()} for r in rows], indent=1))
            return 0
        print("joints  voxel m  samples     workspace m3      IK reference m3")
        for r in rows:
            print(f"{r['joints']:>6}  {r['resolution_m']:<7}  {r['samples']:>9}  "
                  f"{r['workspace_volume_m3']:.3f} ± {r['workspace_volume_error_m3']:.3f}  "
                  f"{_fmt(r['ik_reference_m3'])} ± {_fmt(r['ik_reference_error_m3'])}")
        return 0
    n_plot = args.plot_joints or (3 if 3 in settings.joints else max(settings.joints))
    if args.plot is not None and n_plot not in settings.joints:
        parser.error(f"--plot-joints {n_plot} must be one of --joints {list(settings.joints)}")
    if args.plot is not None:  # before the study
        plots = outputs.figure_outputs(parser, args.plot, "--plot", ".json", ".csv")
        if args.view is not None and args.view.resolve() in {p.resolve() for p in plots}:
            parser.error(f"--view {args.view} is also a file --plot writes; give it its own")
        args.plot = plots[0]
    if args.view is not None:
        with outputs.usage_errors(parser, ImportError, outputs.OutputError):
            outputs.check_writable(pathlib.Path(args.view), "--view")
            with outputs.write_errors(parser, args.force, "--view"):
                size = view(settings, args.view)
        print(f"wrote {args.view} ({size / 1e6:.1f} MB)", file=sys.stderr)
    study = run_study(settings, progress)
    if args.json:
        print(json.dumps([r.json_row() for r in study.rows], indent=1))
    else:
        print(format_table(study, settings))
    if args.plot is not None:
        with outputs.write_errors(parser, args.force, "--plot"):
            written = plot(study, settings, args.plot, n_plot)
        print("wrote " + ", ".join(map(str, written)), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
