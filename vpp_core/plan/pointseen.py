"""Views added where the plan leaves area its candidates see, judged at points on the surface.

A patch counts as seen where a selected view lands 3 rays on it (docs/quality.md, stage 6),
whichever part of the patch those rays sample. Where every selected view sees the same part of
a patch, the rest stays unseen although the patch is "seen": on a Hirth coupling, the strips of
the tooth flanks next to the valley floors (0.6 % of its area, seen by more than a hundred of
1 000 view-sphere views and by one candidate that the patch rows never ask for). So the plan is
also judged at POINTS points spread uniformly by area over the counted faces (seeded): a point
is seen by a camera when it lies in the image and the depth of field, within the incidence limit,
and the straight line from the camera reaches it first (SPEC §3's valid ray, without the pixel
grid). Candidates are then added greedily, the one seeing the most points the plan does not
first, while one sees at least MIN_GAIN of the points more (by more than the points' noise):
area that a single view brings in bulk is worth a view; the slivers that each need a view of
their own (between a gear's teeth) are not (docs/quality.md, stage 6b).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cover.density import CoverModel
from vpp_core.cover.partial import PartialCover, grown, prune, seen_need
from vpp_core.cover.problem import coverage
from vpp_core.mesh.part import Part
from vpp_core.plan.document import PointsInfo
from vpp_core.trace.rays import RayBackend

POINTS = 20_000
"""Points the plan is judged at (0.1 % of the area: 20 of them)."""
MIN_GAIN = 0.001
"""A candidate is added where it sees at least this share of the points more than the plan..."""
NOISE = 3.0
"""...and this many Poisson deviations of that more (33 of 20 000 points): on 20 000 points a
view that truly brings 0.08 % of the area passes 0.1 % one time in five, and where hundreds of
candidates bring that much (between a gear's teeth), some always would."""
SEED = 0
"""The points' seed: the service and the CLI judge the same points."""


@dataclass(frozen=True)
class SurfacePoints:
    """Points (n, 3) mm on the part, the faces (n,) they lie on and those faces' unit normals."""

    xyz: np.ndarray
    faces: np.ndarray
    normals: np.ndarray


@dataclass(frozen=True)
class PointsSeen:
    """What the plan sees of `points` points: `seen` of them, `reach` seen by some candidate,
    the candidates `added` for them (ids, in the order added) and `matrix` (points, N): 1
    where a selected or added view sees a point."""

    points: int
    seen: int
    reach: int
    added: list[int]
    matrix: sp.csr_array


def surface_points(part: Part, wanted: np.ndarray, count: int = POINTS) -> SurfacePoints:
    """`count` points uniform by area over the faces `wanted` (n_faces,) bool, seeded."""
    rng = np.random.default_rng(SEED)
    w = np.where(wanted, part.areas, 0.0)
    faces = rng.choice(part.n_faces, size=count, p=w / w.sum())
    a, b = rng.random(count), rng.random(count)
    flip = a + b > 1
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    v = part.vertices[part.faces[faces]]
    xyz = v[:, 0] + a[:, None] * (v[:, 1] - v[:, 0]) + b[:, None] * (v[:, 2] - v[:, 0])
    return SurfacePoints(xyz, faces, part.normals[faces])


def sees(
    sensor: Sensor,
    position: np.ndarray,
    rotation: np.ndarray,
    pts: SurfacePoints,
    backend: RayBackend,
) -> np.ndarray:
    """(n,) bool: the points the camera at `position` (3,) mm, camera-to-world `rotation`
    (3, 3), sees (in its image and depth of field, within the incidence limit, and first
    along the line from the camera: the face they lie on, or as deep)."""
    d = pts.xyz - position
    x, y, z = (d @ rotation).T
    dist = np.sqrt(np.einsum("ij,ij->i", d, d))
    cos = np.abs(np.einsum("ij,ij->i", pts.normals, d)) / np.maximum(dist, 1e-12)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = sensor.fx * x / z + sensor.width_px / 2
        v = sensor.fy * y / z + sensor.height_px / 2
    ok = (z >= sensor.near_mm) & (z <= sensor.far_mm)
    ok &= cos >= math.cos(math.radians(sensor.max_incidence_deg))
    ok &= (u >= 0) & (u < sensor.width_px) & (v >= 0) & (v < sensor.height_px)
    idx = np.flatnonzero(ok)
    out = np.zeros(len(d), dtype=bool)
    if len(idx):
        dirs = (d[idx] / dist[idx, None]).astype(np.float32)
        prim, t = backend.first_hits(position, dirs, float(dist[idx].max() * 1.001))
        near = np.abs(t - dist[idx]) <= 1e-5 * dist[idx] + 1e-4
        out[idx[(prim == pts.faces[idx]) | near]] = True
    return out


def least_gain(n: int) -> float:
    """Points of n a candidate must see more than the plan to be added (MIN_GAIN, NOISE)."""
    return MIN_GAIN * n + NOISE * math.sqrt(MIN_GAIN * n)


def fill(
    sensor: Sensor,
    views: Viewpoints,
    selected: np.ndarray,
    pts: SurfacePoints,
    backend: RayBackend,
) -> PointsSeen:
    """Candidates of `views` added to `selected` (K,) ids greedily, the one seeing the most
    points `pts` the plan does not first, while one sees least_gain of them more."""
    n, pos, rot = len(pts.faces), views.positions, views.rotations()
    full = {int(j): sees(sensor, pos[j], rot[j], pts, backend) for j in selected}
    seen = np.zeros(n, dtype=bool)
    for mask in full.values():
        seen |= mask
    rest = np.flatnonzero(~seen)
    left = SurfacePoints(pts.xyz[rest], pts.faces[rest], pts.normals[rest])
    others = np.setdiff1d(np.arange(len(views)), selected)
    more = np.array([sees(sensor, pos[j], rot[j], left, backend) for j in others])
    more = more.reshape(len(others), len(rest))
    reach = int(seen.sum() + more.any(axis=0).sum())
    added: list[int] = []
    while len(others) and (gain := more.sum(axis=1)).max() >= least_gain(n):
        k = int(gain.argmax())
        added.append(int(others[k]))
        more &= ~more[k]
    full |= {j: sees(sensor, pos[j], rot[j], pts, backend) for j in added}
    cols = np.array(list(full), dtype=np.int64)
    hits = np.array(list(full.values())).reshape(len(cols), n)
    point, col = np.nonzero(hits.T)
    matrix = sp.csr_array((np.ones(len(point)), (point, cols[col])), shape=(n, len(views)))
    return PointsSeen(n, int(hits.any(axis=0).sum()), reach, added, matrix)


class PointJudge:
    """A plan's covers judged at surface points `pts`: grown by the candidates of `views` that
    see what they leave (fill), each one's figures kept for the document (`info`)."""

    def __init__(
        self,
        sensor: Sensor,
        views: Viewpoints,
        pts: SurfacePoints,
        backend: RayBackend,
        seen_share: float,
    ) -> None:
        self.sensor, self.views, self.pts, self.backend = sensor, views, pts, backend
        self.seen_share = seen_share  # of the seen rows' weight (CoverModel.seen_rows)
        self.of: dict[tuple[int, ...], PointsSeen] = {}  # by the grown cover's selection

    def grow(
        self, model: CoverModel, weights: np.ndarray, cover: PartialCover, costs: np.ndarray | None
    ) -> PartialCover:
        """`cover` (of model's rows, weighing `weights`) with the candidates fill adds, then
        pruned of views no rule needs: the cover's rows, the seen rows (seen_share of their
        weight sampled) and the points (those dropped lose at most MIN_GAIN of them in all)."""
        selected = cover.result.selected
        seen = fill(self.sensor, self.views, selected, self.pts, self.backend)
        if seen.added:
            c = np.ones(model.matrix.shape[1]) if costs is None else costs
            V, v = model.seen_rows(), model.row_weights()
            checks = [
                (model.matrix, weights, cover.required),
                (V, v, seen_need(V, v, self.seen_share)),
                (seen.matrix, np.ones(seen.points), seen.seen - MIN_GAIN * seen.points),
            ]
            kept = prune(checks, np.union1d(selected, seen.added), c)
            cover = grown(model.matrix, weights, cover, kept, c)
        self.of[tuple(int(j) for j in cover.result.selected)] = seen
        return cover

    def info(self, selected: np.ndarray) -> PointsInfo | None:
        """The document's figures for the cover that selected `selected` (None: not judged)."""
        seen = self.of.get(tuple(int(j) for j in selected))
        if seen is None:
            return None
        n = seen.points
        got = int((coverage(seen.matrix, selected) > 0).sum())
        kept = set(selected.tolist())
        added = [j for j in seen.added if j in kept]
        return PointsInfo(
            points=n, seen_fraction=got / n, reach_fraction=seen.reach / n, added=added
        )
