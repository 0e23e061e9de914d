"""Ray tracing: one ray per pixel centre, first hit, SPEC §3 validity, the ray-count matrix R.

A ray is valid on face i when i is its first hit, the hit depth lies in [near, far] and
the angle between ray and face normal is at most `max_incidence` (|cos|, so orientation
does not matter). Rays are built with z = 1 in the camera frame, so the hit parameter t
is the depth; tracing stops at t = far, which is exact (a first hit beyond far is invalid
whatever lies behind it).
"""

from __future__ import annotations

import math
import os
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import scipy.sparse as sp

from vpp_core.errors import VppError
from vpp_core.mesh import Part
from vpp_core.pose import Viewpoints
from vpp_core.sensor import Sensor

CHUNK_RAYS = 1 << 18
"""Rays per task: small enough for cache and memory, big enough to amortise Python."""

Progress = Callable[[int], None]
"""Called with the number of viewpoints just finished."""


class RayBackend(Protocol):
    """First-hit ray caster over one mesh."""

    name: str

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Face id (n,) int32 (-1 = miss) and hit parameter t (n,) float32 of rays from origin."""
        ...


class EmbreeBackend:
    """Embree 4 (embreex) single-ray intersection, robust (watertight) scene."""

    name = "embree"

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, robust: bool = True) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, vertices.astype(np.float32), faces.astype(np.int32))

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Face id (n,) int32 (-1 = miss) and hit parameter t (n,) float32; releases the GIL."""
        origins = np.broadcast_to(origin.astype(np.float32), directions.shape)
        out = self._scene.run(origins, directions, dists=float(t_max), output=1)
        return out["primID"], out["tfar"]


DEFAULT_BACKEND = "embree"
"""The backend every plan uses today (the only one)."""


def make_backend(part: Part, name: str = DEFAULT_BACKEND) -> RayBackend:
    """The ray backend called `name`, built over the part's mesh."""
    if name != "embree":
        raise VppError(f"unknown ray backend {name!r}; available: embree")
    return EmbreeBackend(part.vertices, part.faces)


@dataclass(frozen=True)
class Trace:
    """The ray-count matrix R and what it took."""

    counts: sp.csc_array  # (M faces, N views) int32 valid rays per face and view
    rays_cast: int  # rays actually traced (pixels whose ray can reach the part)
    pixels: int  # N × pixels per view: the rays a plain per-pixel tracer would cast
    backend: str  # name of the RayBackend that traced it
    seconds: float = 0.0  # wall time of the tracing


def join_traces(parts: Sequence[Trace], seconds: float) -> Trace:
    """One trace from traces of consecutive view ranges (columns side by side), `seconds` wall."""
    counts = sp.hstack([t.counts for t in parts], format="csc").astype(np.int32)
    return Trace(
        sp.csc_array(counts),
        sum(t.rays_cast for t in parts),
        sum(t.pixels for t in parts),
        parts[0].backend,
        seconds,
    )


@dataclass(frozen=True)
class _Chunk:
    view: int
    rows: tuple[int, int]  # image rows v0:v1
    cols: tuple[int, int]  # image columns u0:u1

    @property
    def size(self) -> int:
        return (self.rows[1] - self.rows[0]) * (self.cols[1] - self.cols[0])


def trace_counts(
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    *,
    backend: RayBackend | None = None,
    threads: int | None = None,
    progress: Progress | None = None,
    cull: bool = True,
) -> Trace:
    """R for every view; with `cull`, only pixels inside the image of the part's hull are traced."""
    start = time.perf_counter()
    backend = backend or make_backend(part)
    rotations = views.rotations()
    cos_min = math.cos(math.radians(sensor.max_incidence_deg))
    hull = _hull_points(part.vertices) if cull else None
    windows = [_window(sensor, views.positions[j], rotations[j], hull) for j in range(len(views))]
    tasks = [c for j, w in enumerate(windows) for c in _chunks(j, *w)]
    empty = (np.empty(0, np.int32), np.empty(0, np.int32))
    columns: list[tuple[np.ndarray, np.ndarray]] = [empty] * len(views)
    pending: dict[int, list[np.ndarray]] = {}
    left = np.bincount([c.view for c in tasks], minlength=len(views))
    if progress and (done := int((left == 0).sum())):
        progress(done)

    normals = np.ascontiguousarray(part.normals, dtype=np.float32)
    representative = part.representative.astype(np.int32)
    rotations32 = rotations.astype(np.float32)

    def work(chunk: _Chunk) -> np.ndarray:
        j = chunk.view
        return _valid_faces(
            sensor,
            backend,
            views.positions[j],
            rotations32[j],
            chunk,
            cos_min,
            normals,
            representative,
        )

    workers = threads or _cpu_count()
    with ThreadPoolExecutor(workers) as pool:
        for chunk, hits in zip(tasks, _bounded_map(pool, work, tasks, 2 * workers), strict=True):
            pending.setdefault(chunk.view, []).append(hits)
            left[chunk.view] -= 1
            if left[chunk.view] == 0:  # reduce at once: memory grows with nnz(R), not rays
                columns[chunk.view] = _column(np.concatenate(pending.pop(chunk.view)), part.n_faces)
                if progress:
                    progress(1)
    counts = _assemble(columns, part.n_faces)
    pixels = len(views) * sensor.n_pixels
    rays = sum(c.size for c in tasks)
    return Trace(counts, rays, pixels, backend.name, time.perf_counter() - start)


HULL_CELLS = 32
"""Cells per bounding-box axis of the grid whose occupied cells stand in for the vertices."""


def _hull_points(vertices: np.ndarray) -> np.ndarray:
    """(h, 3) points whose convex hull contains the part: the hull of its occupied grid cells.

    Exact hulls of big smooth meshes (every vertex on the hull) cost seconds in Qhull; the
    corners of the occupied cells of a HULL_CELLS³ grid bound the part just as surely.
    """
    from scipy.spatial import ConvexHull, QhullError

    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    size = np.maximum(hi - lo, 1e-9) / HULL_CELLS
    ijk = np.minimum((vertices - lo) // size, HULL_CELLS - 1).astype(np.int64)
    flat = np.unique((ijk[:, 0] * HULL_CELLS + ijk[:, 1]) * HULL_CELLS + ijk[:, 2])
    cells = np.column_stack(np.unravel_index(flat, (HULL_CELLS,) * 3))
    offsets = np.array(np.meshgrid([0, 1], [0, 1], [0, 1])).reshape(3, -1).T
    corners = np.unique((cells[:, None, :] + offsets[None]).reshape(-1, 3), axis=0) * size + lo
    try:
        return np.asarray(corners[ConvexHull(corners).vertices])
    except (QhullError, ValueError):
        return np.asarray(corners)


def _window(
    sensor: Sensor, position: np.ndarray, rotation: np.ndarray, hull: np.ndarray | None
) -> tuple[int, int, int, int]:
    """Pixel rows v0:v1 and columns u0:u1 whose rays can hit the part (exact: its hull's image)."""
    full = (0, sensor.height_px, 0, sensor.width_px)
    if hull is None:
        return full
    cam = (hull - position) @ rotation
    if (cam[:, 2] <= 1e-6).any():
        return full
    u = cam[:, 0] / cam[:, 2] * sensor.fx + sensor.width_px / 2 - 0.5
    v = cam[:, 1] / cam[:, 2] * sensor.fy + sensor.height_px / 2 - 0.5
    u0, u1 = np.clip([np.floor(u.min()) - 1, np.ceil(u.max()) + 2], 0, sensor.width_px)
    v0, v1 = np.clip([np.floor(v.min()) - 1, np.ceil(v.max()) + 2], 0, sensor.height_px)
    return int(v0), int(v1), int(u0), int(u1)


def _valid_faces(
    sensor: Sensor,
    backend: RayBackend,
    position: np.ndarray,
    rotation: np.ndarray,
    chunk: _Chunk,
    cos_min: float,
    normals: np.ndarray,
    representative: np.ndarray,
) -> np.ndarray:
    """Face ids (h,) int32 of the valid hits of one chunk of one view's pixel rays.

    `rotation` (3, 3) float32; `normals` (M, 3) float32 and `representative` (M,) int32 are
    the part's, converted once per trace. No BLAS here: a float32 matmul from a worker thread
    wakes OpenBLAS's own thread pool, whose spinning threads fight the tracer for the cores.
    """
    (v0, v1), (u0, u1) = chunk.rows, chunk.cols
    xs, ys = sensor.pixel_x[u0:u1], sensor.pixel_y[v0:v1]
    # world direction of camera ray (x, y, 1): x*X + y*Y + Z, built plane by plane
    out = np.empty((v1 - v0, u1 - u0, 3), dtype=np.float32)
    for k in range(3):
        np.add(
            (ys * rotation[k, 1] + rotation[k, 2])[:, None],
            (xs * rotation[k, 0])[None, :],
            out=out[..., k],
        )
    directions = out.reshape(-1, 3)
    norms = sensor.camera_ray_norms[v0:v1, u0:u1]
    prim, depth = backend.first_hits(position, directions, sensor.far_mm)
    hit = np.flatnonzero(prim >= 0)
    prim, depth = prim[hit], depth[hit]
    # take(axis=0) is several times faster than fancy indexing of (n, 3) rows
    cos = np.einsum("ij,ij->i", normals.take(prim, axis=0), directions.take(hit, axis=0))
    ok = (depth >= sensor.near_mm) & (np.abs(cos, out=cos) >= cos_min * norms.reshape(-1)[hit])
    return np.asarray(representative.take(prim[ok]))


def _column(faces: np.ndarray, n_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """One view's (faces hit, valid-ray counts), both (k,) int32, from its valid face ids."""
    counts = np.bincount(faces, minlength=n_faces)
    nz = np.flatnonzero(counts)
    return nz.astype(np.int32), counts[nz].astype(np.int32)


def _assemble(columns: list[tuple[np.ndarray, np.ndarray]], n_faces: int) -> sp.csc_array:
    """(M, N) int32 csc count matrix from each view's (faces, counts)."""
    indptr = np.zeros(len(columns) + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(f) for f, _ in columns])
    indices = np.concatenate([f for f, _ in columns] or [np.empty(0, np.int32)])
    data = np.concatenate([c for _, c in columns] or [np.empty(0, np.int32)])
    return sp.csc_array((data, indices, indptr), shape=(n_faces, len(columns)))


def _chunks(view: int, v0: int, v1: int, u0: int, u1: int) -> Iterator[_Chunk]:
    """One view's pixel window split into runs of whole rows of about CHUNK_RAYS rays."""
    rows = max(1, CHUNK_RAYS // max(u1 - u0, 1))
    for start in range(v0, v1, rows):
        yield _Chunk(view, (start, min(start + rows, v1)), (u0, u1))


def _bounded_map(
    pool: ThreadPoolExecutor, fn: Callable[[_Chunk], np.ndarray], items: list[_Chunk], window: int
) -> Iterator[np.ndarray]:
    """pool.map in order, with at most `window` tasks in flight (bounded memory)."""
    futures: deque[Future[np.ndarray]] = deque()
    for item in items:
        futures.append(pool.submit(fn, item))
        if len(futures) >= window:
            yield futures.popleft().result()
    for future in futures:
        yield future.result()


def _cpu_count() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
