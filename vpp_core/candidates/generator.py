"""Candidate viewpoints (SPEC §2): spaced surface samples, camera along the smoothed normal.

1. Sample the (optionally decimated) planning mesh area-weighted and thin the samples to
   a minimum spacing (Poisson-disk-like), shrinking the spacing until `count` remain.
2. Smooth each sample's normal over the faces within half a spacing (area-weighted, signs
   aligned to the sample's own face, so inconsistent orientation does not cancel out).
3. Put the camera at the working distance along the normal, looking back at the sample.
   Keep it if, on the *original* part, its central ray reaches the surface near the
   sample (not occluded, not inside) and it stays `clearance_mm` away from the part;
   otherwise try the opposite side; otherwise drop it.
Seeded and deterministic.

With `tilt_deg` > 0 (not SPEC §2's default), step 3 first tries directions drawn uniformly
by solid angle within `tilt_deg` of the normal (TILT_TRIES of them, each side), then the
normal itself. Along the normal, the candidates of a machined part look along a handful of
face directions, and walls of holes and pockets are then seen by one candidate or none;
tilted gazes see them from many (docs/cad-meshes.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.errors import VppError
from vpp_core.mesh.part import Part
from vpp_core.trace.rays import RayBackend
from vpp_core.trace.raytrace import make_backend

OVERSAMPLE = 8
"""Raw samples drawn per wanted candidate before thinning."""
TARGET_TOL = 0.05
"""The central ray must first hit the part within this fraction of the working distance."""
CLEARANCE_SAMPLES = 20_000
"""Surface samples (plus all vertices) approximating the part for the clearance test."""
TILT_TRIES = 3
"""Tilted directions tried per sample before the plain normal (tilt_deg > 0)."""


@dataclass(frozen=True)
class GeneratorSettings:
    """Settings of the default candidate generator."""

    count: int = 500
    seed: int = 0
    decimate: float | None = None  # fraction of faces kept in the planning mesh, (0, 1]
    clearance_mm: float = 20.0
    tilt_deg: float = 0.0  # largest angle between a gaze and the reversed normal, [0, 90)


@dataclass(frozen=True)
class GeneratedCandidates:
    """Generated viewpoints and what happened on the way."""

    views: Viewpoints
    spacing_mm: float
    planning_faces: int
    dropped: int


def generate(
    part: Part, sensor: Sensor, settings: GeneratorSettings, backend: RayBackend | None = None
) -> GeneratedCandidates:
    """Up to `settings.count` candidate viewpoints around the part (mm, part frame)."""
    if settings.count < 1:
        raise VppError("candidate count must be at least 1")
    if not 0 <= settings.tilt_deg < 90:
        raise VppError(f"tilt_deg must be in [0, 90), got {settings.tilt_deg}")
    planning = planning_mesh(part, settings.decimate)
    points, face_index, spacing = spaced_samples(planning, settings.count, settings.seed)
    normals = smoothed_normals(planning, points, face_index, spacing / 2)
    backend = backend or make_backend(part)
    directions = [normals]
    if settings.tilt_deg > 0:
        rng = np.random.default_rng([settings.seed, 1])
        directions = [*(tilt(normals, settings.tilt_deg, rng) for _ in range(TILT_TRIES)), normals]
    positions, gazes = _place(part, sensor, backend, points, directions, settings.clearance_mm)
    keep = np.isfinite(positions).all(axis=1)
    return GeneratedCandidates(
        views=make_viewpoints(positions[keep], gazes[keep]),
        spacing_mm=spacing,
        planning_faces=len(planning.faces),
        dropped=int((~keep).sum()),
    )


def planning_mesh(part: Part, decimate: float | None) -> trimesh.Trimesh:
    """The part, or a quadric-decimated copy keeping about `decimate` of its faces."""
    mesh = part.trimesh()
    if decimate is None or decimate >= 1:
        return mesh
    if not 0 < decimate < 1:
        raise VppError(f"decimate must be in (0, 1], got {decimate}")
    target = max(4, int(round(len(mesh.faces) * decimate)))
    import fast_simplification

    v, f = fast_simplification.simplify(
        mesh.vertices.astype(np.float32), mesh.faces.astype(np.int32), target_count=target
    )
    small = trimesh.Trimesh(v.astype(np.float64), f, process=False)
    small = trimesh.Trimesh(small.vertices, small.faces[small.area_faces > 0], process=False)
    if len(small.faces) == 0:
        raise VppError(f"decimation to {decimate} left no faces")
    return small


def spaced_samples(
    mesh: trimesh.Trimesh, count: int, seed: int
) -> tuple[np.ndarray, np.ndarray, float]:
    """(k, 3) points, (k,) face ids, spacing mm: area-weighted samples at least `spacing` apart."""
    rng = np.random.default_rng(seed)
    points, faces = trimesh.sample.sample_surface(mesh, OVERSAMPLE * count, seed=rng)
    spacing = float(np.sqrt(mesh.area / count))
    for _ in range(30):
        keep = _thin(points, spacing)
        if len(keep) >= count or spacing < 1e-9:
            break
        spacing *= 0.85
    keep = keep[:count]
    return points[keep], faces[keep], spacing


def _thin(points: np.ndarray, radius: float) -> np.ndarray:
    """Indices of a greedy subset (in input order) with no two points closer than radius."""
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    neighbours = [[] for _ in range(len(points))]  # type: list[list[int]]
    for a, b in pairs:
        neighbours[max(a, b)].append(min(a, b))
    alive = np.ones(len(points), dtype=bool)
    for i in range(len(points)):
        if any(alive[j] for j in neighbours[i]):
            alive[i] = False
    return np.flatnonzero(alive)


def smoothed_normals(
    mesh: trimesh.Trimesh, points: np.ndarray, face_index: np.ndarray, radius: float
) -> np.ndarray:
    """(k, 3) unit normals: area-weighted mean of face normals within `radius` of each point."""
    own = mesh.face_normals[face_index]
    weighted = mesh.face_normals * mesh.area_faces[:, None]
    near = cKDTree(mesh.triangles_center).query_ball_point(points, radius)
    out = own.copy()
    for k, faces in enumerate(near):
        if faces:
            w = weighted[faces]
            total = (w * np.sign(w @ own[k])[:, None]).sum(axis=0) + own[k] * 1e-12
            out[k] = total / np.linalg.norm(total)
    return np.asarray(out)


def tilt(normals: np.ndarray, max_deg: float, rng: np.random.Generator) -> np.ndarray:
    """(k, 3) unit vectors drawn uniformly by solid angle within `max_deg` of each normal."""
    cos_t = rng.uniform(np.cos(np.radians(max_deg)), 1.0, len(normals))
    phi = rng.uniform(0.0, 2 * np.pi, len(normals))
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normals, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normals, u)
    side = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    return np.asarray(cos_t[:, None] * normals + np.sqrt(1 - cos_t * cos_t)[:, None] * side)


def _place(
    part: Part,
    sensor: Sensor,
    backend: RayBackend,
    points: np.ndarray,
    directions: list[np.ndarray],
    clearance_mm: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) camera positions (NaN = dropped) and gazes: per direction set, +d then -d."""
    wd = sensor.working_distance
    tree = _surface_tree(part)
    positions = np.full_like(points, np.nan)
    gazes = -directions[-1].copy()
    for d in directions:
        for sign in (1.0, -1.0):
            todo = ~np.isfinite(positions).all(axis=1)
            cams = points[todo] + sign * wd * d[todo]
            ok = _sees_target(backend, cams, -sign * d[todo], wd)
            ok &= tree.query(cams)[0] >= clearance_mm
            idx = np.flatnonzero(todo)[ok]
            positions[idx] = cams[ok]
            gazes[idx] = -sign * d[idx]
    return positions, gazes


def _sees_target(backend: RayBackend, cams: np.ndarray, gazes: np.ndarray, wd: float) -> np.ndarray:
    """(k,) bool: the central ray of each camera first hits the part near its target depth."""
    ok = np.zeros(len(cams), dtype=bool)
    for k, (c, g) in enumerate(zip(cams, gazes, strict=True)):
        prim, t = backend.first_hits(c, g[None, :].astype(np.float32), wd * (1 + TARGET_TOL))
        ok[k] = prim[0] >= 0 and t[0] >= wd * (1 - TARGET_TOL)
    return ok


def _surface_tree(part: Part) -> cKDTree:
    """KD-tree over the vertices and evenly spread samples of the part (clearance test)."""
    rng = np.random.default_rng(0)
    samples, _ = trimesh.sample.sample_surface(part.trimesh(), CLEARANCE_SAMPLES, seed=rng)
    return cKDTree(np.vstack([part.vertices, samples]))
