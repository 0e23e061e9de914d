"""The ray-count matrix R: every view's pixel rays traced by a ray backend, counted per face.

Only the pixels inside the image of the part's hull are traced (the rest cannot hit); each
view is split into blocks of rows as its backend likes them (`vpp_core.rays`), the blocks run
on a thread pool, and a view's column of R is reduced as soon as its last block is in.
"""

from __future__ import annotations

import os
import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import get_args
from weakref import WeakKeyDictionary

import numpy as np
import scipy.sparse as sp

from vpp_core.embree import EmbreeBackend
from vpp_core.errors import VppError
from vpp_core.mesh import Part
from vpp_core.packets import PacketBackend
from vpp_core.pose import Viewpoints
from vpp_core.raster import RasterBackend
from vpp_core.rays import DEFAULT_BACKEND, BackendName, Block, Hits, RayBackend
from vpp_core.sensor import Sensor

Progress = Callable[[int], None]
"""Called with the number of viewpoints just finished."""


BACKENDS: tuple[BackendName, ...] = get_args(BackendName)
"""Ray backends by name; the first, DEFAULT_BACKEND, is the fastest (bench/raytrace.py)."""


def make_backend(part: Part, name: str | None = None) -> RayBackend:
    """The ray backend called `name` (default DEFAULT_BACKEND), built over the part's mesh."""
    name = name or DEFAULT_BACKEND
    if name == "embree":
        return EmbreeBackend(part)
    if name == "raster":
        return RasterBackend(part)
    if name == "packets":
        return PacketBackend(part)
    raise VppError(f"unknown ray backend {name!r}; available: {', '.join(BACKENDS)}")


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
    hull = part_hull(part) if cull else None
    windows = [_window(sensor, views.positions[j], rotations[j], hull) for j in range(len(views))]
    tasks = [c for j, w in enumerate(windows) for c in _chunks(j, *w, backend.block_rays)]
    tasks.sort(key=lambda c: -c.size)
    empty = (np.empty(0, np.int32), np.empty(0, np.int32))
    columns: list[tuple[np.ndarray, np.ndarray]] = [empty] * len(views)
    pending: dict[int, list[Hits]] = {}
    left = np.bincount([c.view for c in tasks], minlength=len(views))
    if progress and (done := int((left == 0).sum())):
        progress(done)

    def work(chunk: _Chunk) -> Hits:
        j = chunk.view
        block = Block(sensor, views.positions[j], rotations[j], chunk.rows, chunk.cols)
        return backend.valid_hits(block)

    workers = threads or _cpu_count()
    with ThreadPoolExecutor(workers) as pool:
        for chunk, hits in zip(tasks, _bounded_map(pool, work, tasks, 2 * workers), strict=True):
            pending.setdefault(chunk.view, []).append(hits)
            left[chunk.view] -= 1
            if left[chunk.view] == 0:  # reduce at once: memory grows with nnz(R), not rays
                columns[chunk.view] = _column(pending.pop(chunk.view), part.representative)
                if progress:
                    progress(1)
    counts = _assemble(columns, part.n_faces)
    pixels = len(views) * sensor.n_pixels
    rays = sum(c.size for c in tasks)
    return Trace(counts, rays, pixels, backend.name, time.perf_counter() - start)


def view_blocks(
    part: Part, sensor: Sensor, views: Viewpoints, block_rays: int
) -> Iterator[tuple[int, Block]]:
    """(view index, Block) over each view's pixels that can reach the part, view after view."""
    hull = part_hull(part)
    rotations = views.rotations()
    for j in range(len(views)):
        window = _window(sensor, views.positions[j], rotations[j], hull)
        for c in _chunks(j, *window, block_rays):
            yield j, Block(sensor, views.positions[j], rotations[j], c.rows, c.cols)


_HULLS: WeakKeyDictionary[Part, np.ndarray] = WeakKeyDictionary()


def part_hull(part: Part) -> np.ndarray:
    """`_hull_points` of the part's vertices, computed once per Part object."""
    hull = _HULLS.get(part)
    if hull is None:
        hull = _HULLS[part] = _hull_points(part.vertices)
    return hull


HULL_CELLS = 32
"""Cells per bounding-box axis of the grid whose occupied cells stand in for the vertices."""


def _hull_points(vertices: np.ndarray) -> np.ndarray:
    """(h, 3) points whose convex hull contains the part: the hull of its occupied grid cells.

    Exact hulls of big smooth meshes (every vertex on the hull) cost seconds in Qhull; the
    corners of the occupied cells of a HULL_CELLS³ grid bound the part just as surely.
    """
    from scipy.spatial import ConvexHull, QhullError

    # per column: a reduction along axis 0 of an (n, 3) array is several times slower
    lo = np.array([vertices[:, k].min() for k in range(3)])
    hi = np.array([vertices[:, k].max() for k in range(3)])
    size = np.maximum(hi - lo, 1e-9) / HULL_CELLS
    ijk = ((vertices - lo) * (1.0 / size)).astype(np.intp)  # >= 0: truncation is floor
    np.minimum(ijk, HULL_CELLS - 1, out=ijk)
    occupied = np.zeros((HULL_CELLS,) * 3, dtype=bool)  # a grid, not np.unique: no sort of V
    occupied[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    corner = np.zeros((HULL_CELLS + 1,) * 3, dtype=bool)
    for di in (0, 1):
        for dj in (0, 1):
            for dk in (0, 1):
                corner[di : di + HULL_CELLS, dj : dj + HULL_CELLS, dk : dk + HULL_CELLS] |= occupied
    corners = np.argwhere(corner) * size + lo
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


def _column(hits: list[Hits], representative: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One view's (faces hit, valid-ray counts), both (k,) int32, faces ascending, from its
    blocks' hits; duplicate faces counted on their representative."""
    faces = representative.take(np.concatenate([f for f, _ in hits]))
    if all(c is None for _, c in hits):  # one id per ray: O(M + rays) beats sorting rays
        counts = np.bincount(faces, minlength=len(representative))
        nz = np.flatnonzero(counts)
        return nz.astype(np.int32), counts[nz].astype(np.int32)
    counts = np.concatenate([np.ones(len(f), np.int32) if c is None else c for f, c in hits])
    if len(hits) > 1 or not (faces[1:] > faces[:-1]).all():  # merge: O(k log k), not O(M)
        order = np.argsort(faces, kind="stable")  # runs of sorted blocks: a cheap merge
        faces, counts = faces[order], counts[order]
        starts = np.flatnonzero(np.r_[True, faces[1:] != faces[:-1]])
        faces, counts = faces[starts], np.add.reduceat(counts, starts)
    return faces.astype(np.int32), counts.astype(np.int32)


def _assemble(columns: list[tuple[np.ndarray, np.ndarray]], n_faces: int) -> sp.csc_array:
    """(M, N) int32 csc count matrix from each view's (faces, counts)."""
    indptr = np.zeros(len(columns) + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(f) for f, _ in columns])
    indices = np.concatenate([f for f, _ in columns] or [np.empty(0, np.int32)])
    data = np.concatenate([c for _, c in columns] or [np.empty(0, np.int32)])
    return sp.csc_array((data, indices, indptr), shape=(n_faces, len(columns)))


def _chunks(view: int, v0: int, v1: int, u0: int, u1: int, size: int) -> Iterator[_Chunk]:
    """One view's pixel window split into runs of whole rows of about `size` rays, in
    multiples of 4 rows (the packet backend's tiles)."""
    rows = max(4, size // max(u1 - u0, 1) // 4 * 4)
    for start in range(v0, v1, rows):
        yield _Chunk(view, (start, min(start + rows, v1)), (u0, u1))


def _bounded_map(
    pool: ThreadPoolExecutor, fn: Callable[[_Chunk], Hits], items: list[_Chunk], window: int
) -> Iterator[Hits]:
    """pool.map in order, with at most `window` tasks in flight (bounded memory)."""
    futures: deque[Future[Hits]] = deque()
    for item in items:
        futures.append(pool.submit(fn, item))
        if len(futures) >= window:
            yield futures.popleft().result()
    for future in futures:
        yield future.result()


def _cpu_count() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
