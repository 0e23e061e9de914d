"""The simulated point cloud of a plan (the paper's Fig. 4): one point per valid pixel ray of
the selected views, and per point the number of other points within the target resolution r̄.

Points come from the backend's own valid hits (`RayBackend.pixel_hits`), so a view's points
are exactly its column sum of R. Neighbours are counted by KD-trees over slabs of the points
sorted along their longest axis (each slab's tree also holds the points within a margin of
it), so memory grows with the slab, not the cloud.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import BinaryIO

import numpy as np
from pydantic import BaseModel
from scipy.spatial import cKDTree

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.geometry import Cell, resolve
from vpp_core.errors import LimitError
from vpp_core.mesh.part import Part
from vpp_core.plan.cellplan import scene_occluders
from vpp_core.plan.document import PlanDocument
from vpp_core.plan.pipeline import explicit_viewpoints
from vpp_core.plan.regions import DEFAULT_NAME
from vpp_core.plan.regionsdoc import face_regions
from vpp_core.trace.rays import RayBackend
from vpp_core.trace.raytrace import make_backend, view_blocks

SLAB_POINTS = 2_000_000
"""Points per slab of the neighbour count (its KD-tree holds these plus the margins)."""
SPACING_REACH = 3.0
"""Nearest-neighbour distances are exact up to SPACING_REACH · r̄; points farther from any
other are `isolated` and left out of the mean spacing."""
HIST_MAX = 64
"""Neighbour counts above this go into the histogram's overflow bin."""


@dataclass(frozen=True)
class PointCloud:
    """Hit points of a set of views, in their order."""

    points: np.ndarray  # (P, 3) float32 mm, part frame
    view: np.ndarray  # (P,) int32 index of the view (0..K-1) that sampled the point
    face: np.ndarray | None = None  # (P,) int32 face hit
    region: np.ndarray | None = None  # (P,) int32 region of that face (-1 default), if any


class RegionCloudStats(BaseModel):
    """A region's points (on its faces) and their neighbours within its own r̄."""

    name: str
    resolution_mm: float | None
    """The region's target, the neighbour radius (the default's for an ignored region)."""
    ignored: bool
    points: int
    neighbours_mean: float
    neighbours_median: float
    neighbours_p05: float
    neighbours_p95: float
    without_neighbours: float
    spacing_mean_mm: float | None
    spacing_median_mm: float | None


class CloudStats(BaseModel):
    """Neighbour counts within r̄ (other points, self excluded) and point spacing."""

    points: int
    per_view: list[int]
    radius_mm: float
    neighbours_mean: float
    neighbours_median: float
    neighbours_p05: float
    neighbours_p95: float
    neighbours_max: int
    without_neighbours: float  # fraction of points with no other point within r̄
    histogram: list[int]  # points with 0, 1, ..., HIST_MAX neighbours
    histogram_overflow: int  # points with more than HIST_MAX
    spacing_mean_mm: float | None  # mean distance to the nearest other point
    spacing_median_mm: float | None
    isolated: int  # points with no other within SPACING_REACH · r̄
    regions: list[RegionCloudStats] = []  # per region (plan regions, then `default`)


def hit_points(
    part: Part, sensor: Sensor, views: Viewpoints, backend: RayBackend, max_points: int
) -> PointCloud:
    """The valid hit points of every view (SPEC §5); LimitError beyond `max_points`."""
    points: list[np.ndarray] = []
    owner: list[np.ndarray] = []
    faces: list[np.ndarray] = []
    total = 0
    for j, block in view_blocks(part, sensor, views, backend.block_rays):
        hits = backend.pixel_hits(block)
        total += len(hits.pixels)
        if total > max_points:
            raise LimitError(f"the point cloud exceeds the limit of {max_points} points")
        width = block.cols[1] - block.cols[0]
        rows, cols = np.divmod(hits.pixels, width)
        cam = np.stack(
            [
                sensor.pixel_x[cols + block.cols[0]] * hits.depth,
                sensor.pixel_y[rows + block.rows[0]] * hits.depth,
                np.asarray(hits.depth, dtype=np.float64),
            ],
            axis=1,
        )
        points.append((cam @ block.rotation.T + block.position).astype(np.float32))
        owner.append(np.full(len(hits.pixels), j, dtype=np.int32))
        faces.append(np.asarray(hits.faces, dtype=np.int32))
    if not points:
        empty = np.empty(0, np.int32)
        return PointCloud(np.empty((0, 3), np.float32), empty, empty)
    return PointCloud(np.concatenate(points), np.concatenate(owner), np.concatenate(faces))


def neighbour_counts(
    points: np.ndarray, radius: float | np.ndarray, workers: int = -1
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) int32 other points within `radius` mm of each point (one, or (P,) each point's
    own), and (P,) float32 distance to the nearest other point (inf beyond SPACING_REACH ·
    radius), slab by slab."""
    n = len(points)
    counts = np.zeros(n, np.int32)
    nearest = np.full(n, np.inf, np.float32)
    if n == 0:
        return counts, nearest
    axis = int(np.argmax(np.ptp(points, axis=0)))
    order = np.argsort(points[:, axis], kind="stable")
    keys = points[order, axis]
    per_point = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,))
    margin = SPACING_REACH * float(per_point.max())
    reach = SPACING_REACH * per_point
    for start in range(0, n, SLAB_POINTS):
        own = order[start : start + SLAB_POINTS]
        lo = np.searchsorted(keys, keys[start] - margin, "left")
        hi = np.searchsorted(keys, keys[start + len(own) - 1] + margin, "right")
        tree = cKDTree(points[order[lo:hi]].astype(np.float64))
        query = points[own].astype(np.float64)
        r = per_point[own]
        counts[own] = tree.query_ball_point(query, r, return_length=True, workers=workers) - 1
        dist, _ = tree.query(query, k=2, distance_upper_bound=margin, workers=workers)
        nearest[own] = np.where(dist[:, 1] <= reach[own], dist[:, 1], np.inf)
    return counts, nearest


def cloud_stats(
    cloud: PointCloud, counts: np.ndarray, nearest: np.ndarray, radius: float
) -> CloudStats:
    """Summary of a point cloud's neighbour counts and spacing."""
    n = len(counts)
    per_view = np.bincount(cloud.view, minlength=int(cloud.view.max(initial=-1)) + 1)
    hist = np.bincount(np.minimum(counts, HIST_MAX + 1), minlength=HIST_MAX + 2)
    finite = np.isfinite(nearest)
    q = np.percentile(counts, [5, 50, 95]) if n else np.zeros(3)
    return CloudStats(
        points=n,
        per_view=per_view.tolist(),
        radius_mm=radius,
        neighbours_mean=float(counts.mean()) if n else 0.0,
        neighbours_median=float(q[1]),
        neighbours_p05=float(q[0]),
        neighbours_p95=float(q[2]),
        neighbours_max=int(counts.max(initial=0)),
        without_neighbours=float((counts == 0).mean()) if n else 0.0,
        histogram=hist[: HIST_MAX + 1].tolist(),
        histogram_overflow=int(hist[HIST_MAX + 1]),
        spacing_mean_mm=float(nearest[finite].mean()) if finite.any() else None,
        spacing_median_mm=float(np.median(nearest[finite])) if finite.any() else None,
        isolated=int((~finite).sum()),
    )


PLY_CHUNK = 1_000_000
"""Points per write of the PLY body."""


def write_ply(out: BinaryIO, cloud: PointCloud, counts: np.ndarray) -> None:
    """Binary little-endian PLY: x, y, z (float32 mm), neighbours (int32), view (int32), and
    with regions, region (int32: index into the plan's regions, -1 the default target)."""
    regions = cloud.region is not None
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        "comment vpp simulated point cloud: one point per valid pixel ray, mm\n"
        f"element vertex {len(counts)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property int neighbours\nproperty int view\n"
        + ("property int region\n" if regions else "")
        + "end_header\n"
    )
    out.write(header.encode("ascii"))
    fields = [("xyz", "<f4", 3), ("neighbours", "<i4"), ("view", "<i4")]
    record = np.dtype(fields + ([("region", "<i4")] if regions else []))
    for start in range(0, len(counts), PLY_CHUNK):
        stop = start + PLY_CHUNK
        body = np.empty(len(counts[start:stop]), dtype=record)
        body["xyz"] = cloud.points[start:stop]
        body["neighbours"] = counts[start:stop]
        body["view"] = cloud.view[start:stop]
        if cloud.region is not None:
            body["region"] = cloud.region[start:stop]
        out.write(body.tobytes())


def simulate(
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    backend: RayBackend,
    radius: float,
    *,
    max_points: int,
    workers: int = -1,
) -> tuple[PointCloud, np.ndarray, CloudStats]:
    """The point cloud of `views`, its neighbour counts within `radius` mm, and their summary."""
    cloud = hit_points(part, sensor, views, backend, max_points)
    counts, nearest = neighbour_counts(cloud.points, radius, workers)
    return cloud, counts, cloud_stats(cloud, counts, nearest, radius)


def simulate_plan(
    part: Part, doc: PlanDocument, *, max_points: int, workers: int = -1, cell: Cell | None = None
) -> tuple[PointCloud, np.ndarray, CloudStats]:
    """`simulate` for a plan's selected viewpoints, its sensor, target r̄ and ray backend, with
    its setup's floor and fixtures in the scene (`cell`: the setup with its meshes read; else
    the document's, which must then name no mesh); with regions, each point's neighbours are
    counted within its face's own target, and the points carry their region and are
    summarised per region."""
    cell = cell if cell is not None else resolve(doc.setup)
    views = explicit_viewpoints(doc.viewpoints)
    backend = make_backend(part, doc.rays.backend, scene_occluders(part, doc.sensor, cell))
    radius = doc.target.resolution_mm
    if doc.regions is None:
        return simulate(
            part, doc.sensor, views, backend, radius, max_points=max_points, workers=workers
        )
    region, target, _ = face_regions(doc, part.n_faces)
    cloud = hit_points(part, doc.sensor, views, backend, max_points)
    assert cloud.face is not None
    cloud = replace(cloud, region=region[cloud.face].astype(np.int32))
    counts, nearest = neighbour_counts(cloud.points, target[cloud.face], workers)
    stats = cloud_stats(cloud, counts, nearest, radius)
    stats.regions = _region_stats(doc, cloud, counts, nearest)
    return cloud, counts, stats


def _region_stats(
    doc: PlanDocument, cloud: PointCloud, counts: np.ndarray, nearest: np.ndarray
) -> list[RegionCloudStats]:
    """The cloud's figures per region of the plan, then the default."""
    assert doc.regions is not None and cloud.region is not None
    default = doc.target.resolution_mm
    named = [(r.name, r.resolution_mm, r.ignore) for r in doc.regions.regions]
    out = []
    for k, (name, res, ignore) in enumerate([*named, (DEFAULT_NAME, default, False)]):
        mine = cloud.region == (k if k < len(named) else -1)
        c, d = counts[mine], nearest[mine]
        finite = d[np.isfinite(d)]
        q = np.percentile(c, [5, 50, 95]) if len(c) else np.zeros(3)
        out.append(
            RegionCloudStats(
                name=name,
                resolution_mm=res or default,
                ignored=ignore,
                points=int(mine.sum()),
                neighbours_mean=float(c.mean()) if len(c) else 0.0,
                neighbours_median=float(q[1]),
                neighbours_p05=float(q[0]),
                neighbours_p95=float(q[2]),
                without_neighbours=float((c == 0).mean()) if len(c) else 0.0,
                spacing_mean_mm=float(finite.mean()) if len(finite) else None,
                spacing_median_mm=float(np.median(finite)) if len(finite) else None,
            )
        )
    return out
