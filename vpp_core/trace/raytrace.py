"""The ray-count matrix R: every view's pixel rays traced by a ray backend, counted per face.

Only the pixels inside the image of the part's hull are traced (the rest cannot hit); each
view is split into blocks of rows as its backend likes them (`vpp_core.trace.rays`), the blocks run
on the process's thread pool (started once; a forked child starts its own), and a view's
column of R is reduced as soon as its last block is in.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable, Generator, Iterator, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import closing
from dataclasses import dataclass, replace
from typing import get_args
from weakref import WeakKeyDictionary

import numpy as np
import scipy.sparse as sp

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.scene import Occluders
from vpp_core.errors import VppError
from vpp_core.mesh.part import Part
from vpp_core.mesh.refine import Elements
from vpp_core.trace.embree import EmbreeBackend
from vpp_core.trace.occluded import OccludedBackend, scene_part
from vpp_core.trace.packets import PacketBackend
from vpp_core.trace.raster import RasterBackend
from vpp_core.trace.rays import DEFAULT_BACKEND, BackendName, Block, Hits, RayBackend

Progress = Callable[[int], None]
"""Called with the number of viewpoints just finished."""
ORDER_VIEWS_PER_THREAD = 8
"""Tracing tasks go out largest first (the last ones keep every thread busy) within groups of
this many consecutive views per thread, group after group: views are done, reported and
reduced as the trace goes, not all at its end (then every view's hits waited in memory)."""


BACKENDS: tuple[BackendName, ...] = get_args(BackendName)
"""Ray backends by name; the first, DEFAULT_BACKEND, is the fastest (bench/raytrace.py)."""


def make_backend(
    part: Part, name: str | None = None, occluders: Occluders | None = None
) -> RayBackend:
    """The ray backend called `name` (default DEFAULT_BACKEND), built over the part's mesh;
    with `occluders` (the setup's floor and fixtures), over both, hits on them blocked."""
    name = name or DEFAULT_BACKEND
    if occluders is not None:
        return OccludedBackend(make_backend(scene_part(part, occluders), name), part.n_faces)
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
    elements: sp.csc_array | None = None  # (E, N) int32 R of the elements `counts` sums
    element_mm2: float | None = None  # the elements' largest area (vpp_core.mesh.refine), mm²


def join_traces(parts: Sequence[Trace], seconds: float) -> Trace:
    """One trace from traces of consecutive view ranges (columns side by side), `seconds` wall."""
    counts = sp.hstack([t.counts for t in parts], format="csc").astype(np.int32)
    elements = None
    if parts[0].elements is not None:
        stacked = sp.hstack([t.elements for t in parts], format="csc")
        elements = sp.csc_array(stacked, dtype=np.int32)
    return Trace(
        sp.csc_array(counts),
        sum(t.rays_cast for t in parts),
        sum(t.pixels for t in parts),
        parts[0].backend,
        seconds,
        elements,
        parts[0].element_mm2,
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
    tick: Callable[[], None] | None = None,
    elements: Elements | None = None,
) -> Trace:
    """R for every view; with `cull`, only pixels inside the image of the part's hull are traced.
    `tick()` is called as each block of rays is done; an exception it raises stops the trace.
    With the part's `elements` (`backend` over elements.part), the elements are traced: their
    R is Trace.elements, its per-face sums Trace.counts."""
    if elements is not None:
        t = trace_counts(
            elements.part,
            sensor,
            views,
            backend=backend,
            threads=threads,
            progress=progress,
            cull=cull,
            tick=tick,
        )
        lifted = elements.lift(t.counts)
        return replace(t, counts=lifted, elements=t.counts, element_mm2=elements.max_area_mm2)
    start = time.perf_counter()
    backend = backend or make_backend(part)
    rotations = views.rotations()
    windows = view_windows(sensor, views, part_hull(part) if cull else None)
    duplicates = part.representative if has_duplicates(part) else None
    workers = threads or _cpu_count()
    tasks = [c for j, w in enumerate(windows) for c in _chunks(j, *w, backend.block_rays)]
    group = ORDER_VIEWS_PER_THREAD * workers  # largest first within each group of views
    tasks.sort(key=lambda c: (c.view // group, -c.size))
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

    with closing(_bounded_map(_pool(workers), work, tasks, 2 * workers)) as results:
        for chunk, hits in zip(tasks, results, strict=True):
            if tick:
                tick()
            pending.setdefault(chunk.view, []).append(hits)
            left[chunk.view] -= 1
            if left[chunk.view] == 0:  # reduce at once: memory grows with nnz(R), not rays
                columns[chunk.view] = _column(pending.pop(chunk.view), part.n_faces, duplicates)
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
    rotations = views.rotations()
    for j, window in enumerate(view_windows(sensor, views, part_hull(part))):
        for c in _chunks(j, *window, block_rays):
            yield j, Block(sensor, views.positions[j], rotations[j], c.rows, c.cols)


_HULLS: WeakKeyDictionary[Part, np.ndarray] = WeakKeyDictionary()


def part_hull(part: Part) -> np.ndarray:
    """`_hull_points` of the part's vertices, computed once per Part object."""
    hull = _HULLS.get(part)
    if hull is None:
        hull = _HULLS[part] = _hull_points(part.vertices)
    return hull


_DUPLICATES: WeakKeyDictionary[Part, bool] = WeakKeyDictionary()


def has_duplicates(part: Part) -> bool:
    """Whether some face of the part duplicates an earlier one, computed once per Part object."""
    dup = _DUPLICATES.get(part)
    if dup is None:
        own = np.arange(part.n_faces, dtype=part.representative.dtype)
        dup = _DUPLICATES[part] = bool((part.representative != own).any())
    return dup


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


def view_windows(
    sensor: Sensor, views: Viewpoints, hull: np.ndarray | None
) -> list[tuple[int, int, int, int]]:
    """Per view, pixel rows v0:v1 and columns u0:u1 whose rays can hit the part (exact: the
    image of its hull, (h, 3) points; None: the whole frame), WINDOW_VIEWS views at a time."""
    if hull is None:
        return [(0, sensor.height_px, 0, sensor.width_px)] * len(views)
    rotations = views.rotations()
    return [
        w
        for s in range(0, len(views), WINDOW_VIEWS)
        for w in _windows(
            sensor, views.positions[s : s + WINDOW_VIEWS], rotations[s : s + WINDOW_VIEWS], hull
        )
    ]


WINDOW_VIEWS = 256
"""Views projected together by view_windows: (views, hull points, 3) floats at a time."""


def _windows(
    sensor: Sensor, positions: np.ndarray, rotations: np.ndarray, hull: np.ndarray
) -> list[tuple[int, int, int, int]]:
    """view_windows of cameras at positions (n, 3) mm turned by rotations (n, 3, 3)."""
    cam = (hull[None, :, :] - positions[:, None, :]) @ rotations  # (n, h, 3) camera frames
    z = cam[:, :, 2]
    behind = (z <= 1e-6).any(axis=1)  # the camera inside the hull: every pixel may hit
    z = np.where(behind[:, None], 1.0, z)
    u = cam[:, :, 0] / z * sensor.fx + sensor.width_px / 2 - 0.5
    v = cam[:, :, 1] / z * sensor.fy + sensor.height_px / 2 - 0.5
    u0 = np.clip(np.floor(u.min(axis=1)) - 1, 0, sensor.width_px).astype(int)
    u1 = np.clip(np.ceil(u.max(axis=1)) + 2, 0, sensor.width_px).astype(int)
    v0 = np.clip(np.floor(v.min(axis=1)) - 1, 0, sensor.height_px).astype(int)
    v1 = np.clip(np.ceil(v.max(axis=1)) + 2, 0, sensor.height_px).astype(int)
    full = (0, sensor.height_px, 0, sensor.width_px)
    return [
        full if behind[j] else (int(v0[j]), int(v1[j]), int(u0[j]), int(u1[j]))
        for j in range(len(positions))
    ]


def _column(
    hits: list[Hits], n_faces: int, representative: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray]:
    """One view's (faces hit, valid-ray counts), both (k,) int32, faces ascending, from its
    blocks' hits; duplicate faces counted on their representative (None: there are none)."""
    ids = [f for f, _ in hits]
    faces = ids[0] if len(ids) == 1 else np.concatenate(ids)
    if representative is not None:
        faces = representative.take(faces)
    if all(c is None for _, c in hits):  # one id per ray: O(M + rays) beats sorting rays
        per_face = np.bincount(faces, minlength=n_faces)
        nz = np.flatnonzero(per_face)
        return nz.astype(np.int32), per_face[nz].astype(np.int32)
    per: list[np.ndarray] = [np.ones(len(f), np.int32) if c is None else c for f, c in hits]
    counts = per[0] if len(per) == 1 else np.concatenate(per)
    if len(faces) and (len(hits) > 1 or not (faces[1:] > faces[:-1]).all()):  # merge: O(k log k)
        order = np.argsort(faces, kind="stable")  # runs of sorted blocks: a cheap merge
        faces, counts = faces[order], counts[order]
        starts = np.flatnonzero(np.r_[True, faces[1:] != faces[:-1]])
        faces, counts = faces[starts], np.add.reduceat(counts, starts)
    return faces.astype(np.int32, copy=False), counts.astype(np.int32, copy=False)


def _assemble(columns: list[tuple[np.ndarray, np.ndarray]], n_faces: int) -> sp.csc_array:
    """(M, N) int32 csc count matrix from each view's (faces, counts); int32 indices while
    the entries fit them (half the memory of int64)."""
    sizes = [len(f) for f, _ in columns]
    indptr = np.zeros(len(columns) + 1, dtype=np.int32 if sum(sizes) < 2**31 else np.int64)
    np.cumsum(sizes, out=indptr[1:])
    indices = np.concatenate([f for f, _ in columns] or [np.empty(0, np.int32)])
    data = np.concatenate([c for _, c in columns] or [np.empty(0, np.int32)])
    return sp.csc_array(
        (data, indices.astype(indptr.dtype, copy=False), indptr), shape=(n_faces, len(columns))
    )


def _chunks(view: int, v0: int, v1: int, u0: int, u1: int, size: int) -> Iterator[_Chunk]:
    """One view's pixel window split into runs of whole rows of about `size` rays, in
    multiples of 4 rows (the packet backend's tiles)."""
    rows = max(4, size // max(u1 - u0, 1) // 4 * 4)
    for start in range(v0, v1, rows):
        yield _Chunk(view, (start, min(start + rows, v1)), (u0, u1))


def _bounded_map(
    pool: ThreadPoolExecutor, fn: Callable[[_Chunk], Hits], items: list[_Chunk], window: int
) -> Generator[Hits, None, None]:
    """pool.map in order, with at most `window` tasks in flight (bounded memory); the tasks
    not yet started are cancelled if the caller stops early (the pool outlives the trace)."""
    futures: deque[Future[Hits]] = deque()
    try:
        for item in items:
            futures.append(pool.submit(fn, item))
            if len(futures) >= window:
                yield futures.popleft().result()
        while futures:
            yield futures.popleft().result()
    finally:
        for future in futures:
            future.cancel()


_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _pool(workers: int) -> ThreadPoolExecutor:
    """The process's pool of `workers` tracing threads, started once: a trace of a few small
    views takes milliseconds, of which starting threads would be several percent."""
    with _POOLS_LOCK:
        pool = _POOLS.get(workers)
        if pool is None:
            pool = _POOLS[workers] = ThreadPoolExecutor(workers, thread_name_prefix="vpp-trace")
        return pool


def _forget_pools() -> None:
    """In a forked child: the parent's pool threads do not exist here."""
    global _POOLS_LOCK
    _POOLS.clear()
    _POOLS_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools)


def _cpu_count() -> int:
    """Cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
