"""Candidate viewpoints (SPEC §2, amended): spaced surface samples, cameras looking back at them.

1. Sample the (optionally decimated) planning mesh area-weighted and thin the samples to
   a minimum spacing (Poisson-disk-like), shrinking the spacing until `count` remain.
2. Smooth each sample's normal over the faces within half a spacing (area-weighted, signs
   aligned to the sample's own face, so inconsistent orientation does not cancel out).
3. Put the camera at the stand-off distance along a gaze direction, looking back at the
   sample. Keep it if, on the *original* part, its central ray reaches the surface near the
   sample (not occluded, not inside) and it stays `clearance_mm` away from the part;
   otherwise try the next direction (each one on both sides of the surface); a sample no
   direction serves is dropped.
4. With `fit_roll`, turn each camera about its gaze where that frames more of the surface
   (`vpp_core.candidates.roll`); else SPEC §1's default up.
5. With `tiles`, add head-on cameras laid side by side over each flat face that no frame
   holds whole (`vpp_core.candidates.tiles`), after the others.
Seeded and deterministic.

The directions: with `tilt_deg` > 0, TILT_TRIES directions drawn uniformly by solid angle
within `tilt_deg` of the normal, then the normal itself; with `retry_tilt_deg` > 0, a sample
still unplaced then tries RETRY_TRIES directions within that wider cone (a gaze into a
pocket or past a boss that the normal's gaze cannot make). Along the normal, the candidates
of a machined part look along a handful of face directions, and walls of holes and pockets
are then seen by one candidate or none; tilted gazes see them from many (docs/cad-meshes.md).

The stand-off: `standoff_mm`, or the working distance when None (the paper profile). The
default profile asks `standoff_for` for the distance at which one pixel's footprint is
1 / STANDOFF_MARGIN of the target resolution, so that one view head-on meets the target with
room for obliquity (docs/quality.md); never farther than the working distance, never nearer
than the depth of field allows.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.roll import fitted, surface_samples
from vpp_core.candidates.tiles import tiles
from vpp_core.cell.reach import Allowed
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
RETRY_TRIES = 6
"""Directions within retry_tilt_deg tried for a sample no earlier direction served."""
STANDOFF_MARGIN = 1.2
"""Target resolution / pixel footprint at the default stand-off (head-on density margin)."""
TILE_SHARE = 4
"""Head-on tiles (settings.tiles) are at most the candidate count over this, the largest
flat faces' first."""
DOF_MARGIN = 0.1
"""Share of the depth of field kept free in front of the near limit at the stand-off."""


@dataclass(frozen=True)
class GeneratorSettings:
    """Settings of the default candidate generator."""

    count: int = 500
    seed: int = 0
    decimate: float | None = None  # fraction of faces kept in the planning mesh, (0, 1]
    clearance_mm: float = 20.0
    tilt_deg: float = 0.0  # largest angle between a gaze and the reversed normal, [0, 90)
    retry_tilt_deg: float = 0.0  # wider cone tried before a sample is dropped (0: none)
    standoff_mm: float | None = None  # camera-sample distance (None: the working distance)
    fit_roll: bool = False  # turned where that frames more (vpp_core.candidates.roll)
    tiles: bool = False  # head-on cameras tiling large flat faces too (candidates.tiles)


@dataclass(frozen=True)
class GeneratedCandidates:
    """Generated viewpoints and what happened on the way."""

    views: Viewpoints
    spacing_mm: float
    planning_faces: int
    dropped: int
    standoff_mm: float
    tiles: int = 0  # of views, the last ones: head-on tiles of large flat faces


def standoff_for(sensor: Sensor, resolution_mm: float) -> float:
    """Stand-off (mm) at which a pixel's footprint is resolution / STANDOFF_MARGIN, within
    [near + DOF_MARGIN · depth of field, working distance]."""
    per_mm = max(1 / sensor.fx, 1 / sensor.fy)  # a pixel's footprint per mm of depth
    wanted = resolution_mm / (STANDOFF_MARGIN * per_mm)
    nearest = sensor.near_mm + DOF_MARGIN * (sensor.far_mm - sensor.near_mm)
    return float(min(sensor.working_distance, max(nearest, wanted)))


def generate(
    part: Part,
    sensor: Sensor,
    settings: GeneratorSettings,
    backend: RayBackend | None = None,
    allowed: Allowed | None = None,
) -> GeneratedCandidates:
    """Up to `settings.count` candidate viewpoints around the part (mm, part frame), where
    `allowed` (the setup's vpp_core.cell.reach predicate; None: anywhere) lets a camera be."""
    if settings.count < 1:
        raise VppError("candidate count must be at least 1")
    for name in ("tilt_deg", "retry_tilt_deg"):
        if not 0 <= getattr(settings, name) < 90:
            raise VppError(f"{name} must be in [0, 90), got {getattr(settings, name)}")
    standoff = settings.standoff_mm or sensor.working_distance
    if not sensor.near_mm <= standoff <= sensor.far_mm:
        raise VppError(f"standoff {standoff} mm lies outside the depth of field")
    planning = planning_mesh(part, settings.decimate)
    points, face_index, spacing = spaced_samples(planning, settings.count, settings.seed)
    normals = smoothed_normals(planning, points, face_index, spacing / 2)
    backend = backend or make_backend(part)
    directions = gaze_directions(normals, settings)
    positions, gazes = place(
        part, backend, points, directions, standoff, settings.clearance_mm, allowed
    )
    keep = np.isfinite(positions).all(axis=1)
    views = make_viewpoints(positions[keep], gazes[keep])
    if settings.fit_roll:
        views = fitted(views, sensor, surface_samples(part), standoff)
    laid = make_viewpoints(np.zeros((0, 3)), np.zeros((0, 3)))
    if settings.tiles:
        tree = functools.cache(lambda: _surface_tree(part))  # built where a tile is placed
        limit = settings.count // TILE_SHARE
        stretch = STANDOFF_MARGIN**2  # a tilted frame's reach at the default stand-off
        laid = tiles(
            part, sensor, standoff, backend, tree, settings.clearance_mm, stretch, allowed, limit
        )
    return GeneratedCandidates(
        views=views.then(laid),
        spacing_mm=spacing,
        planning_faces=len(planning.faces),
        dropped=int((~keep).sum()),
        standoff_mm=standoff,
        tiles=len(laid),
    )


def gaze_directions(normals: np.ndarray, settings: GeneratorSettings) -> list[np.ndarray]:
    """The (k, 3) direction sets tried in turn: tilted, the normal, then the wider retries."""
    rng = np.random.default_rng([settings.seed, 1])
    directions = [tilt(normals, settings.tilt_deg, rng) for _ in range(TILT_TRIES)]
    directions = [*directions, normals] if settings.tilt_deg > 0 else [normals]
    if settings.retry_tilt_deg > 0:
        retry = np.random.default_rng([settings.seed, 2])
        directions += [tilt(normals, settings.retry_tilt_deg, retry) for _ in range(RETRY_TRIES)]
    return directions


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


def normal_frames(normals: np.ndarray) -> np.ndarray:
    """(k, 3, 3) rotations whose columns are two unit vectors across each unit normal (k, 3)
    and the normal itself."""
    helper = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    u = np.cross(normals, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(normals, u)
    return np.stack([u, v, normals], axis=2)


def tilt(normals: np.ndarray, max_deg: float, rng: np.random.Generator) -> np.ndarray:
    """(k, 3) unit vectors drawn uniformly by solid angle within `max_deg` of each normal."""
    cos_t = rng.uniform(np.cos(np.radians(max_deg)), 1.0, len(normals))
    phi = rng.uniform(0.0, 2 * np.pi, len(normals))
    frames = normal_frames(normals)
    u, v = frames[:, :, 0], frames[:, :, 1]
    side = np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v
    return np.asarray(cos_t[:, None] * normals + np.sqrt(1 - cos_t * cos_t)[:, None] * side)


def place(
    part: Part,
    backend: RayBackend,
    points: np.ndarray,
    directions: list[np.ndarray],
    wd: float,
    clearance_mm: float,
    allowed: Allowed | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(k, 3) camera positions at `wd` mm (NaN = dropped) and gazes: per set, +d then -d;
    a camera `allowed` refuses (the setup's constraints) is not placed."""
    tree = _surface_tree(part)
    positions = np.full_like(points, np.nan)
    gazes = -directions[-1].copy()
    for d in directions:
        for sign in (1.0, -1.0):
            todo = ~np.isfinite(positions).all(axis=1)
            cams = points[todo] + sign * wd * d[todo]
            ok = _sees_target(backend, cams, -sign * d[todo], wd)
            ok &= tree.query(cams)[0] >= clearance_mm
            if allowed is not None:
                ok[ok] = allowed(cams[ok])
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
