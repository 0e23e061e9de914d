"""PNG pictures of plans and studies (matplotlib, headless: Figure + Agg, no pyplot state).

Every function takes documents or arrays and returns PNG bytes; the shells decide where
they go. Units are on every axis; the target resolution is marked where it applies.

Colours speak the viewer's language (viewer/src/palette.js, kept equal by a test): blue to
green for r* that meets the target r̄, yellow to red for r* that misses it, magenta for
uncovered surface. The two formulations are told apart by colours outside that language.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, NullFormatter, ScalarFormatter

from vpp_core.candidates.generator import planning_mesh
from vpp_core.mesh.part import Part
from vpp_core.plan.document import PlanDocument
from vpp_core.plan.metrics import Histogram
from vpp_core.report.pointcloud import CloudStats
from vpp_core.report.studies import DecimationRow, Study, SweepRow

PALETTE: dict[str, Any] = {
    "met": [(8, 69, 148), (66, 146, 198), (116, 196, 118)],
    "unmet": [(254, 224, 139), (253, 141, 60), (189, 0, 38)],
    "uncovered": (208, 28, 139),
    "uncoverable": (85, 85, 85),
    "excluded": (176, 160, 128),
}
"""sRGB bytes: the met ramp (finest → just meets r̄), the unmet ramp (just misses → worst) and
the fixed face states, as in viewer/src/palette.js."""
STYLE = {"density": ("#5e3c99", "-", "o"), "visibility": ("#252525", "--", "D")}
"""Colour, line and marker per formulation: violet and black, outside the r* colours."""
DPI = 110
MAX_DRAWN_FACES = 20_000
"""The 3D view draws a decimated copy of bigger parts (matplotlib draws each polygon)."""


SCALE_PERCENTILE = 0.02
"""The r* scale's ends: this share of the met (unmet) faces lies beyond each (palette.js)."""
SCALE_SPAN = (1.25, 100.0)
"""Least and most ratio of r* each half of the scale covers (palette.js MIN_SPAN, MAX_SPAN)."""
STATE_CODES = ("met", "unmet", "uncovered", "uncoverable", "excluded")
"""Face states by their code in the plan scene (vpp_core.report.scene)."""
FaceColours = tuple[np.ndarray, np.ndarray] | None
"""(state, resolution_mm) per face of the part (vpp_core.report.scene), or None: grey."""


def _png(fig: Figure) -> bytes:
    """The figure as PNG bytes."""
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, bbox_inches="tight")
    return buf.getvalue()


def rgb(c: Sequence[int]) -> tuple[float, float, float]:
    """An sRGB byte triple as matplotlib's 0–1 floats."""
    return (c[0] / 255, c[1] / 255, c[2] / 255)


def ramp_colour(stops: Sequence[Sequence[int]], t: float) -> tuple[float, float, float]:
    """The colour at t in [0, 1] along piecewise-linear sRGB stops (palette.js `ramp`)."""
    x = min(max(t, 0.0), 1.0) * (len(stops) - 1)
    i = min(int(x), len(stops) - 2)
    a, b = np.asarray(stops[i], float), np.asarray(stops[i + 1], float)
    return rgb(np.round(a + (b - a) * (x - i)).astype(int).tolist())


def _quantile(values: np.ndarray, q: float) -> float:
    """palette.js `quantile`: the value at floor(q n) of the float32 values sorted."""
    ordered = np.sort(values.astype(np.float32))
    return float(ordered[min(len(ordered) - 1, int(np.floor(q * len(ordered))))])


def face_colours(state: np.ndarray, resolution_mm: np.ndarray, target_mm: float) -> np.ndarray:
    """(M, 3) uint8 sRGB colour of each face as the viewer draws it (palette.js `fitScale` and
    `faceColours`): met faces on the met ramp from the plan's finest r* (2nd percentile) to r̄,
    unmet ones on the unmet ramp from r̄ to their 98th percentile, log within each half; the
    other states in their fixed colours."""
    state = np.asarray(state)
    r = np.asarray(resolution_mm, dtype=np.float64)
    met, unmet = r[state == 0], r[(state == 1) & np.isfinite(r)]
    lo_span, hi_span = SCALE_SPAN
    lo, hi = target_mm / 2, 2 * target_mm  # without met (unmet) faces, as palette.js
    if len(met):
        lo = target_mm / np.clip(target_mm / _quantile(met, SCALE_PERCENTILE), lo_span, hi_span)
    if len(unmet):
        hi = target_mm * np.clip(
            _quantile(unmet, 1 - SCALE_PERCENTILE) / target_mm, lo_span, hi_span
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        below = 0.5 * (1 - np.log(target_mm / np.maximum(r, 1e-12)) / np.log(target_mm / lo))
        above = 0.5 * (1 + np.log(r / target_mm) / np.log(hi / target_mm))
    t = np.clip(np.where(r <= target_mm, below, above), 0.0, 1.0)
    t = np.nan_to_num(t, nan=1.0)
    out = np.zeros((len(state), 3), np.uint8)
    for code, name in enumerate(STATE_CODES):
        pick = state == code
        if name == "met":
            out[pick] = _ramp(PALETTE["met"], 2 * t[pick])
        elif name == "unmet":
            out[pick] = _ramp(PALETTE["unmet"], 2 * t[pick] - 1)
        else:
            out[pick] = PALETTE[name]
    return out


def _ramp(stops: Sequence[Sequence[int]], t: np.ndarray) -> np.ndarray:
    """palette.js `ramp` on an array: sRGB bytes at t in [0, 1] along piecewise-linear stops."""
    x = np.clip(t, 0.0, 1.0) * (len(stops) - 1)
    knots = np.arange(len(stops))
    channels = [np.interp(x, knots, [c[k] for c in stops]) for k in range(3)]
    return np.floor(np.stack(channels, axis=1) + 0.5).astype(np.uint8)


def bin_colours(edges: np.ndarray, target_mm: float) -> list[tuple[float, float, float]]:
    """Colour of each histogram bin (edges in mm) on the viewer's scale: the met ramp (log) from
    the first bin to r̄, the unmet ramp (log) from r̄ to the last edge."""
    centres = np.sqrt(np.maximum(edges[:-1], 1e-9) * edges[1:])
    lo, hi = max(centres[0], 1e-9), max(edges[-1], target_mm * 1.25)
    out = []
    for c in centres:
        if c <= target_mm:
            t = 1 - np.log(target_mm / c) / np.log(target_mm / lo) if lo < target_mm else 1.0
            out.append(ramp_colour(PALETTE["met"], t))
        else:
            out.append(
                ramp_colour(PALETTE["unmet"], np.log(c / target_mm) / np.log(hi / target_mm))
            )
    return out


def sweep_png(study: Study, name: str | None = None) -> bytes:
    """`sweep_figure` as PNG bytes."""
    return _png(sweep_figure(study, name))


def sweep_figure(study: Study, name: str | None = None) -> Figure:
    """Per target resolution, for both formulations: #OVP (paper Fig. 3 right) and the share
    of the area that meets the target and that is seen (%). `name`: the mesh file's name."""
    fig = Figure(figsize=(11, 4.2))
    views_ax, area_ax = fig.subplots(1, 2)
    for formulation, (colour, line, marker) in STYLE.items():
        rows = sorted((r for r in study.rows if r.formulation == formulation), key=_resolution)
        x = [_resolution(r) for r in rows]
        big = formulation == "density"  # the other's marker is drawn smaller, on top
        style = {"color": colour, "marker": marker, "ms": 8 if big else 4.5, "mfc": "white"}
        views_ax.plot(x, [r.viewpoints for r in rows], line, label=formulation, **style)
        met = [100 * r.resolution.met_area for r in rows]
        area_ax.plot(x, met, line, label=f"{formulation}: area at r* ≤ r̄", **style)
        seen_ = [100 * r.coverage.area for r in rows]
        area_ax.plot(x, seen_, ":", color=colour, lw=1, label=f"{formulation}: area seen")
        open_ = [k for k, r in enumerate(rows) if r.solver.status != "optimal"]
        if open_:
            views_ax.plot(
                [x[k] for k in open_],
                [rows[k].viewpoints for k in open_],
                "s",
                ms=12,
                mfc="none",
                color="#999999",
                label="not proven optimal" if big else None,
            )
    views_ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    views_ax.set_ylabel("selected viewpoints (#OVP)")
    views_ax.set_title("viewpoints")
    area_ax.set_ylabel("share of the counted area (%)")
    area_ax.set_ylim(0, 105)
    area_ax.set_title("resolution met and coverage")
    for ax in (views_ax, area_ax):
        ax.set_xlabel("target resolution r̄ (mm)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(_title("resolution sweep", study, name))
    return fig


def decimation_png(study: Study, name: str | None = None) -> bytes:
    """Coverage and resolution met on the original against the planning mesh's faces
    (paper Fig. 3 left): solid = density, dashed = visibility. `name`: the mesh file's name."""
    fig = Figure(figsize=(10, 4.2))
    cover_ax, met_ax = fig.subplots(1, 2)
    for name, (colour, line, marker) in STYLE.items():
        rows = sorted(
            (r for r in study.rows if r.formulation == name),
            key=lambda r: getattr(r, "planning_faces", 0),
        )
        x = [getattr(r, "planning_faces", 0) for r in rows]
        cover_ax.plot(x, [100 * r.coverage.area for r in rows], line, color=colour, marker=marker)
        met_ax.plot(
            x,
            [100 * r.resolution.met_area for r in rows],
            line,
            color=colour,
            marker=marker,
            label=name,
        )
        for xi, r in zip(x, rows, strict=True):
            cover_ax.annotate(
                str(r.viewpoints),
                (xi, 100 * r.coverage.area),
                fontsize=7,
                color=colour,
                textcoords="offset points",
                xytext=(3, 3),
            )
    target = study.request.target.resolution_mm
    cover_ax.set_ylabel("area seen on the original (%)")
    met_ax.set_ylabel(f"area at r* ≤ {target:g} mm on the original (%)")
    for ax in (cover_ax, met_ax):
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xticks(sorted({getattr(r, "planning_faces", 1) for r in study.rows}))
        ax.tick_params(axis="x", labelrotation=45)
        ax.set_xlabel("faces of the planning mesh")
        ax.grid(alpha=0.3, which="both")
    cover_ax.set_title("coverage (numbers: #OVP)")
    met_ax.set_title("resolution met")
    met_ax.legend()
    fig.suptitle(_title("decimation study", study, name))
    return _png(fig)


def histogram_png(
    histograms: Sequence[tuple[str, Histogram]], target_mm: float, title: str = ""
) -> bytes:
    """`histogram_figure` as PNG bytes."""
    return _png(histogram_figure(histograms, target_mm, title))


def histogram_figure(
    histograms: Sequence[tuple[str, Histogram]], target_mm: float, title: str = ""
) -> Figure:
    """Area per achieved-resolution bin, one series per (formulation, histogram), with the
    target marked (paper Fig. 5); overflow and unseen area in the legend. One series: bars in
    the viewer's r* colours; several: outlines in the formulations' colours (no blend)."""
    fig = Figure(figsize=(6.4, 4.2))
    ax = fig.add_subplot()
    for name, h in histograms:
        edges = np.asarray(h.edges_mm)
        total = sum(h.area_mm2) + h.overflow_area_mm2 + h.unseen_area_mm2 or 1.0
        colour, line, _ = STYLE.get(name, ("#252525", "-", "o"))
        share = 100 * np.asarray(h.area_mm2) / total
        extra = 100 * (h.overflow_area_mm2 / total), 100 * (h.unseen_area_mm2 / total)
        label = f"{name} (beyond {edges[-1]:g} mm: {extra[0]:.1f} %, unseen {extra[1]:.1f} %)"
        if len(histograms) == 1:
            ax.bar(
                edges[:-1], share, np.diff(edges), align="edge", color=bin_colours(edges, target_mm)
            )
            ax.plot([], [], " ", label=label)
        else:
            ax.stairs(share, edges, color=colour, ls=line, lw=1.8, label=label)
    ax.axvline(target_mm, color="k", lw=1.5, label=f"target r̄ = {target_mm:g} mm")
    ax.set_xlabel("achieved resolution r* per face (mm)")
    ax.set_ylabel("share of the counted area (%)")
    ax.set_title(title or "resolution per surface element")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def regions_png(doc: PlanDocument) -> bytes:
    """One histogram of r* per region of the plan (the counted ones, then `default`), each
    against the region's own target, in the viewer's colours."""
    shown = [r for r in doc.metrics.regions if not r.ignored and r.faces]
    cols = min(len(shown), 2) or 1
    rows = max(1, -(-len(shown) // cols))
    fig = Figure(figsize=(6.4 * cols, 3.6 * rows))
    for k, r in enumerate(shown):
        ax = fig.add_subplot(rows, cols, k + 1)
        h, target = r.histogram, float(r.resolution_mm or doc.target.resolution_mm)
        edges = np.asarray(h.edges_mm)
        total = sum(h.area_mm2) + h.overflow_area_mm2 + h.unseen_area_mm2 or 1.0
        share = 100 * np.asarray(h.area_mm2) / total
        ax.bar(edges[:-1], share, np.diff(edges), align="edge", color=bin_colours(edges, target))
        ax.axvline(target, color="k", lw=1.5, label=f"r̄ = {target:g} mm")
        ax.set_title(
            f"{r.name}: {r.faces:,} faces, {r.area_mm2:,.0f} mm², met {100 * r.met_area:.1f} %",
            fontsize=9,
        )
        ax.set_xlabel("achieved resolution r* per face (mm)")
        ax.set_ylabel("share of the region's area (%)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"resolution per region: {len(doc.viewpoints)} viewpoints")
    return _png(fig)


def neighbours_png(stats: CloudStats, title: str = "") -> bytes:
    """Distribution of neighbour counts within r̄ over the simulated point cloud (Fig. 4)."""
    fig = Figure(figsize=(6.4, 4.2))
    ax = fig.add_subplot()
    counts = np.asarray(stats.histogram, dtype=float)
    share = 100 * counts / max(stats.points, 1)
    ax.bar(np.arange(len(share)), share, width=0.9, color="tab:red")
    ax.axvline(stats.neighbours_mean, color="k", ls="--", label=f"mean {stats.neighbours_mean:.2f}")
    ax.set_xlabel(f"neighbours within r̄ = {stats.radius_mm:g} mm (points)")
    ax.set_ylabel("share of the points (%)")
    spacing = f", mean spacing {stats.spacing_mean_mm:.4g} mm" if stats.spacing_mean_mm else ""
    ax.set_title(title or f"simulated point cloud: {stats.points:,} points{spacing}")
    ax.grid(alpha=0.3)
    ax.legend()
    return _png(fig)


def cameras_png(part: Part, doc: PlanDocument, faces: FaceColours = None) -> bytes:
    """`cameras_figure` as PNG bytes."""
    return _png(cameras_figure(part, doc, faces))


def cameras_figure(part: Part, doc: PlanDocument, faces: FaceColours = None) -> Figure:
    """Left: the part and the selected cameras' depth-of-field frusta, numbered in visiting
    order, with the tour. Right: close-up of the part, each camera's gaze and the point where
    its central ray meets the part, numbered. With `faces` the part wears the viewer's r*
    colours (a light shading them), else grey."""
    fig = Figure(figsize=(13, 6.2))
    overview = fig.add_subplot(1, 2, 1, projection="3d")
    close = fig.add_subplot(1, 2, 2, projection="3d")
    mesh = part.trimesh()
    if len(mesh.faces) > MAX_DRAWN_FACES:
        mesh = planning_mesh(part, MAX_DRAWN_FACES / len(mesh.faces))
    frusta = _frusta(doc)
    positions = np.array([vp.position for vp in doc.viewpoints]).reshape(-1, 3)
    gazes = np.array([vp.gaze for vp in doc.viewpoints]).reshape(-1, 3)
    aims = _aim_points(mesh, positions, gazes, doc.sensor.working_distance)
    colours = None
    if faces is not None:
        colours = face_colours(*faces, doc.target.resolution_mm)[_original_faces(part, mesh)]
    for ax in (overview, close):
        _draw_part(ax, mesh, colours)
    _draw_lines(overview, frusta, "#1f6fb2", 0.5)
    if len(positions):
        overview.plot(*positions.T, color="#7048e8", lw=1.2, marker="o", ms=3, label="tour")
        overview.legend(loc="upper left")
    # the gaze of each camera, from a part's size away up to its aim point on the part
    lo, hi = mesh.bounds
    size = float(np.linalg.norm(hi - lo))
    _draw_lines(
        close, [(a - g * 0.6 * size, a) for a, g in zip(aims, gazes, strict=True)], "#1f6fb2", 1.0
    )
    _fit(overview, np.vstack([mesh.vertices, positions, np.asarray(frusta).reshape(-1, 3)]))
    _fit(close, np.vstack([mesh.vertices, aims - gazes * 0.6 * size]))
    for ax, points in ((overview, positions), (close, aims)):
        _numbers(fig, ax, points)
    overview.set_title(
        f"{len(doc.viewpoints)} viewpoints ({doc.target.formulation}, r̄ = "
        f"{doc.target.resolution_mm:g} mm): depth-of-field frusta, visiting order"
    )
    close.set_title(
        "close-up: gaze and aim point of each viewpoint"
        + ("\nfaces coloured by achieved resolution r* (as in the viewer)" if faces else "")
    )
    return fig


def _original_faces(part: Part, mesh: Any) -> np.ndarray:
    """For each face of `mesh` (the part or a decimated copy) the part's face it stands for:
    the one whose centroid is nearest its own."""
    if len(mesh.faces) == part.n_faces:
        return np.arange(part.n_faces)
    from scipy.spatial import cKDTree

    centroids = part.vertices[part.faces].mean(axis=1)
    return np.asarray(cKDTree(centroids).query(mesh.triangles_center)[1])


def _frusta(doc: PlanDocument) -> list[tuple[np.ndarray, np.ndarray]]:
    """Line segments of each selected camera's frustum between its near and far planes."""
    sensor, lines = doc.sensor, []
    tx, ty = sensor.half_tangents
    corners = np.array([[-tx, -ty, 1], [tx, -ty, 1], [tx, ty, 1], [-tx, ty, 1]])
    for vp in doc.viewpoints:
        c2w = np.asarray(vp.camera_to_world)
        near, far = (
            corners * d @ c2w[:3, :3].T + c2w[:3, 3] for d in (sensor.near_mm, sensor.far_mm)
        )
        for q in (near, far):
            lines += [(q[i], q[(i + 1) % 4]) for i in range(4)]
        lines += [(near[i], far[i]) for i in range(4)]
    return lines


def _aim_points(mesh: Any, positions: np.ndarray, gazes: np.ndarray, wd: float) -> np.ndarray:
    """(K, 3) mm: where each camera's central ray first meets the mesh, else the face centre
    nearest the point at the working distance `wd` (mm) along its gaze."""
    from scipy.spatial import cKDTree

    aims = positions + gazes * wd
    if len(aims):
        centres = mesh.triangles_center
        aims = centres[cKDTree(centres).query(aims)[1]]
        hits, rays, _ = mesh.ray.intersects_location(positions, gazes, multiple_hits=False)
        aims[rays] = hits
    return np.asarray(aims, float).reshape(-1, 3)


def _numbers(fig: Figure, ax: Any, points: np.ndarray) -> None:
    """Number the 3D points 1… in `ax`, each label at the first free spot near its point
    (greedy, in display pixels), a thin leader line where it had to move."""
    from mpl_toolkits.mplot3d import proj3d

    if not len(points):
        return
    FigureCanvasAgg(fig).draw()  # type: ignore[no-untyped-call]  # settles the projection
    x2, y2, _ = proj3d.proj_transform(*points.T, ax.get_proj())
    anchors = ax.transData.transform(np.column_stack([x2, y2]))
    placed: list[np.ndarray] = []
    w, h = 18.0, 13.0  # a label's box in display pixels, with its gap
    rings = [(0.0, 0.0)] + [
        (r * w * np.cos(a), r * h * np.sin(a))
        for r in (1, 2, 3)
        for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)
    ]
    for k, anchor in enumerate(anchors):
        spot = next(
            (anchor + d for d in rings if all(
                abs(anchor[0] + d[0] - q[0]) >= w or abs(anchor[1] + d[1] - q[1]) >= h
                for q in placed
            )),
            anchor,
        )  # fmt: skip
        placed.append(spot)
        moved = bool(np.any(spot != anchor))
        ax.annotate(
            str(k + 1),
            xy=(x2[k], y2[k]),
            xytext=tuple(spot - anchor) if moved else (0, 0),
            textcoords="offset pixels",
            ha="center",
            va="center",
            fontsize=8,
            weight="bold",
            color="white",
            bbox={"boxstyle": "round,pad=0.15", "fc": "#1f6fb2", "ec": "none"},
            arrowprops={"arrowstyle": "-", "color": "#1f6fb2", "lw": 0.6} if moved else None,
            zorder=1000,  # above the part, whatever depth order mplot3d gives its collections
            annotation_clip=False,
        )


def _draw_part(ax: Any, mesh: Any, colours: np.ndarray | None = None) -> None:
    """The mesh with a fixed directional light: grey, or `colours` (M, 3) sRGB bytes per face
    (lit more gently, so that the colours stay readable)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    light = np.abs(mesh.face_normals @ np.array([0.3, 0.4, 0.87]))
    if colours is None:
        shade = (0.35 + 0.6 * light)[:, None] * np.array([0.75, 0.75, 0.78])
    else:
        shade = (0.6 + 0.4 * light)[:, None] * (colours / 255.0)
    ax.add_collection3d(Poly3DCollection(mesh.triangles, facecolors=shade, linewidths=0))


def _draw_lines(
    ax: Any, lines: Sequence[tuple[np.ndarray, np.ndarray]], colour: str, lw: float
) -> None:
    """Line segments in 3D."""
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    if len(lines):
        ax.add_collection3d(Line3DCollection(lines, colors=colour, linewidths=lw, alpha=0.7))


def _fit(ax: Any, points: np.ndarray) -> None:
    """Axis limits around the points, true aspect, labelled in mm."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(np.maximum(hi - lo, 1e-9 + 0.02 * (hi - lo).max()))
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4))
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")


def _resolution(row: SweepRow | DecimationRow) -> float:
    return row.resolution_mm


def _title(what: str, study: Study, name: str | None = None) -> str:
    """`what: name (faces)`, the mesh's id standing in for a name not given."""
    return f"{what}: {name or 'mesh ' + study.mesh.id[:12]} ({study.mesh.faces:,} faces)"


def plan_plots(
    part: Part, doc: PlanDocument, cloud: CloudStats | None = None, faces: FaceColours = None
) -> dict[str, bytes]:
    """A plan's pictures by file name: histogram, cameras (its part coloured by r* given the
    faces' state and r*), with regions, regions (one histogram per region against its own
    target) and, with a point cloud, neighbours."""
    pngs = {
        "histogram.png": histogram_png(
            [(doc.target.formulation, doc.metrics.resolution.histogram)],
            doc.target.resolution_mm,
            f"resolution per surface element: {len(doc.viewpoints)} viewpoints",
        ),
        "cameras.png": cameras_png(part, doc, faces),
    }
    if doc.metrics.regions:
        pngs["regions.png"] = regions_png(doc)
    if cloud is not None:
        pngs["neighbours.png"] = neighbours_png(cloud)
    return pngs


def study_plots(study: Study, name: str | None = None) -> dict[str, bytes]:
    """A study's pictures by file name: its curves and, per resolution, the two histograms.
    `name`: the mesh file's name for the titles (else its id)."""
    if study.kind == "decimation":
        pngs = {"decimation.png": decimation_png(study, name)}
    else:
        pngs = {"sweep.png": sweep_png(study, name)}
    for key in sorted({(getattr(r, "ratio", None), _resolution(r)) for r in study.rows}, key=str):
        rows = [r for r in study.rows if (getattr(r, "ratio", None), _resolution(r)) == key]
        ratio, res = key
        name = f"histogram-{res:g}mm.png" if ratio is None else f"histogram-ratio-{ratio:g}.png"
        where = f"ratio {ratio:g}, " if ratio is not None else ""
        pngs[name] = histogram_png(
            [(r.formulation, r.histogram) for r in rows],
            res,
            f"resolution per surface element ({where}r̄ = {res:g} mm): "
            + ", ".join(f"{r.formulation} {r.viewpoints} views" for r in rows),
        )
    return pngs
