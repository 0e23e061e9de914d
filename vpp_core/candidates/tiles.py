"""Head-on cameras that tile a part's large flat faces, beside the generated candidates.

A flat face many frames across is covered with the fewest views by frames laid side by side,
head-on, in one orientation. The generated candidates aim at spaced samples with tilted gazes
and fitted rolls, so their frames lie on such a face at every offset and angle, and the cover
cannot assemble a tiling from them (a 2 000 × 1 000 mm panel: 139 views; with these tiles in
the pool, 112; docs/quality.md, stage 2c).

Each facet (trimesh's groups of coplanar adjacent faces, and the lone faces) longer than two
frames at the stand-off, each stretched as far as a tilted gaze still meets the target
(`stretch`: where a head-on pixel is r̄ / m, a gaze at θ meets r̄ up to cos θ = 1 / m², on a
frame 1 / cos θ = m² as long; 1.44 at the default stand-off), gets a grid of cameras over the
smallest rectangle around it in its plane (`trimesh.bounds.oriented_bounds_2D`): frames of
the sensor's size at the stand-off, neighbours overlapping by OVERLAP, in whichever of the two
orientations takes fewer, spread evenly over the rectangle; one camera per grid cell whose
frame holds some of the facet, on the side from which a line reaches the facet first,
`clearance_mm` away from the part and where `allowed` lets it be. A shorter face is covered as
well by the tilted candidates, and tiles there lead the cover's greedy start astray (a
300 × 200 mm plate: 8 views with tiles, 6 without).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.reach import Allowed
from vpp_core.mesh.part import Part
from vpp_core.trace.rays import RayBackend

OVERLAP = 0.05
"""Share of a frame's width (and height) that neighbouring tiles overlap."""
SAMPLES_PER_FRAME = 400
"""Points sampled on a facet per cell of its grid, to tell which cells hold some of it."""
PROBES = 8
"""Points of a cell tried for a clear line of sight from its camera."""


@dataclass(frozen=True)
class Facet:
    """A flat face of the part: its faces' ids, their area-weighted unit normal, and the
    smallest rectangle around it in its plane: unit axes (a, b), extents along them (mm) and
    centre (mm)."""

    faces: np.ndarray
    normal: np.ndarray
    axes: tuple[np.ndarray, np.ndarray]
    extents: tuple[float, float]
    centre: np.ndarray


def facets(mesh: trimesh.Trimesh, longer_mm: float) -> list[np.ndarray]:
    """Face ids of each group of coplanar adjacent faces (trimesh's facets), then of each
    face in none as a group of its own, whose corners span more than `longer_mm` (the
    diagonal of their box, never shorter than the facet)."""
    groups = [np.asarray(f, dtype=np.int64) for f in mesh.facets]
    alone = np.ones(len(mesh.faces), dtype=bool)
    for f in groups:
        alone[f] = False
    tri = mesh.triangles
    span = np.linalg.norm(tri.max(axis=1) - tri.min(axis=1), axis=1)
    long = [f for f in groups if _span(mesh.vertices[mesh.faces[f]]) > longer_mm]
    return long + [np.array([i]) for i in np.flatnonzero(alone & (span > longer_mm))]


def _span(corners: np.ndarray) -> float:
    """The diagonal (mm) of the box around (..., 3) points."""
    flat = corners.reshape(-1, 3)
    return float(np.linalg.norm(flat.max(axis=0) - flat.min(axis=0)))


def facet(mesh: trimesh.Trimesh, faces: np.ndarray) -> Facet:
    """The Facet of the coplanar `faces` of `mesh`."""
    area = mesh.area_faces[faces]
    normal = mesh.face_normals[faces].T @ area
    normal /= np.linalg.norm(normal)
    corners = mesh.vertices[np.unique(mesh.faces[faces])]
    origin = corners.mean(axis=0)
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(normal, u)
    flat = (corners - origin) @ np.stack([u, v], axis=1)
    to_rect, extents = trimesh.bounds.oriented_bounds_2D(flat)  # type: ignore[no-untyped-call]
    rot = np.linalg.inv(to_rect)  # rectangle frame -> (u, v) plane
    a = rot[0, 0] * u + rot[1, 0] * v
    b = rot[0, 1] * u + rot[1, 1] * v
    centre = origin + rot[0, 2] * u + rot[1, 2] * v
    return Facet(faces, normal, (a, b), (float(extents[0]), float(extents[1])), centre)


def grid(extents: tuple[float, float], frame: tuple[float, float]) -> tuple[int, int, bool]:
    """(cells along a, cells along b, whether the frame's width lies along b) tiling a
    rectangle of `extents` (mm) with frames (width, height) mm overlapping by OVERLAP."""
    w, h = (f * (1 - OVERLAP) for f in frame)
    along = (math.ceil(extents[0] / w), math.ceil(extents[1] / h))
    across = (math.ceil(extents[0] / h), math.ceil(extents[1] / w))
    if across[0] * across[1] < along[0] * along[1]:
        return max(across[0], 1), max(across[1], 1), True
    return max(along[0], 1), max(along[1], 1), False


def tiles(
    part: Part,
    sensor: Sensor,
    standoff_mm: float,
    backend: RayBackend,
    clearance: Callable[[], cKDTree],
    clearance_mm: float,
    stretch: float,
    allowed: Allowed | None = None,
    limit: int | None = None,
) -> Viewpoints:
    """Head-on cameras at `standoff_mm` tiling each facet of the part longer than two frames
    `stretch`ed along their width (module docstring), largest facets first, at most `limit`
    cameras (a facet whose grid has more cells than are left gets none: a face a hundred
    metres across is not sampled cell by cell); `clearance()` a KD-tree of points on the part
    for the `clearance_mm` test (asked for only where a camera is placed)."""
    frame = sensor.frame_mm(standoff_mm)
    longest = 2 * stretch * max(frame)  # what two stretched frames span
    left, rng = math.inf if limit is None else limit, np.random.default_rng(0)
    found: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    large = _large(part, longest) if _span(part.vertices) > longest else []  # else none is
    for f in large:
        cells = grid(f.extents, frame)
        if cells[0] * cells[1] > left:  # a face is tiled whole or not at all
            continue
        points = _samples(part, f, cells[0] * cells[1], rng)
        for cam, gaze, up in _cells(f, frame, cells, standoff_mm, points, backend):
            if clearance().query(cam)[0] >= clearance_mm and (
                allowed is None or allowed(cam[None])[0]
            ):
                found.append((cam, gaze, up))
                left -= 1
    cams, gazes, ups = (np.array([t[k] for t in found]).reshape(-1, 3) for k in range(3))
    return make_viewpoints(cams, gazes, ups)


def _large(part: Part, longest_mm: float) -> list[Facet]:
    """The part's facets of counted faces whose rectangle is longer than `longest_mm`, the
    largest (by area) first."""
    mesh, out = part.trimesh(), []
    for faces in facets(mesh, longest_mm):
        counted = faces[part.counted[faces]]
        if len(counted) and max((f := facet(mesh, counted)).extents) > longest_mm:
            out.append(f)
    return sorted(out, key=lambda f: -float(part.areas[f.faces].sum()))


def _samples(part: Part, f: Facet, cells: int, rng: np.random.Generator) -> np.ndarray:
    """(k, 3) points on the facet, SAMPLES_PER_FRAME per cell of its grid, and its corners."""
    sub = trimesh.Trimesh(part.vertices, part.faces[f.faces], process=False)
    points, _ = trimesh.sample.sample_surface(sub, SAMPLES_PER_FRAME * cells, seed=rng)
    return np.vstack([points, sub.vertices[np.unique(sub.faces)]])


def _cells(
    f: Facet,
    frame: tuple[float, float],
    cells: tuple[int, int, bool],
    standoff: float,
    points: np.ndarray,
    backend: RayBackend,
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(camera, gaze, up) of each cell of the grid `cells` (grid()) over the facet whose frame
    holds some of `points` (on the facet) with a clear line of sight to one of them."""
    na, nb, swap = cells
    width, height = (frame[1], frame[0]) if swap else frame
    a, b = f.axes
    xy = (points - f.centre) @ np.stack([a, b], axis=1)
    up = a if swap else b  # the image's x (its width) along the other axis
    out = []
    for i in range(na):
        for j in range(nb):
            x = (i + 0.5) / na * f.extents[0] - f.extents[0] / 2
            y = (j + 0.5) / nb * f.extents[1] - f.extents[1] / 2
            inside = (np.abs(xy[:, 0] - x) <= width / 2) & (np.abs(xy[:, 1] - y) <= height / 2)
            if not inside.any():
                continue
            target = f.centre + x * a + y * b
            probes = points[np.flatnonzero(inside)[:: max(1, int(inside.sum()) // PROBES)]]
            for side in (1.0, -1.0):
                cam = target + side * standoff * f.normal
                if _sees(backend, cam, probes):
                    out.append((cam, -side * f.normal, up))
                    break
    return out


def _sees(backend: RayBackend, cam: np.ndarray, probes: np.ndarray) -> bool:
    """Whether a straight line from `cam` (3,) mm first meets the part at one of `probes`."""
    d = probes - cam
    dist = np.linalg.norm(d, axis=1)
    _, t = backend.first_hits(cam, (d / dist[:, None]).astype(np.float32), float(dist.max() * 1.01))
    return bool((np.abs(t - dist) <= 1e-4 * dist + 1e-3).any())
