"""Primary visibility by z-buffer rasterisation of face ids at pixel centres (numba).

For a pinhole camera, "the first face hit by the ray through each pixel centre" is exactly
the face whose projected triangle contains the pixel centre and is nearest there. Per view:

1. vertices to the camera frame and the image; faces with a vertex behind the plane
   z = Z_CLIP are clipped against it (Sutherland-Hodgman); faces whose bounding box holds no
   pixel centre are dropped;
2. each triangle is scanned row by row: a pixel centre is inside when all three edge
   functions are > 0, or = 0 on a top-left edge (each edge is evaluated from its
   lexicographically smaller end, so neighbours get the same value of opposite sign and
   exactly one of them owns the pixel); the z-buffer holds 1/z, which is linear in the ray
   direction (x, y, 1) for a plane: 1/z = n.d / n.v0; at equal depth the lower id wins;
3. the SPEC §3 checks per pixel (near <= z <= far, |cos incidence| >= cos_min) on the winner.

Arithmetic is float64 on Embree's own float32 pixel rays, so the two agree but for pixel
centres on edges and coplanar overlapping faces (tests/test_raster.py). Faces are drawn in a
Morton order of their centroids (memory locality); a view with more than one face per 4
pixels goes to Embree packets (MAX_FACES_PER_PIXEL). Method and figures: docs/raytrace.md.
"""

from __future__ import annotations

import math

import numpy as np

from vpp_core.camera.sensor import Sensor
from vpp_core.jit import inline, kernel
from vpp_core.mesh.part import Part
from vpp_core.trace.packets import PacketBackend
from vpp_core.trace.pixels import FirstHits, Triple, window_of
from vpp_core.trace.rays import Block, Hits, PixelHits

Z_CLIP = 1e-6
"""Near clipping plane (mm) of the rasteriser: rays start at the camera, t > 0."""


MAX_FACES_PER_PIXEL = 0.25
"""A view whose window has fewer pixels than faces / MAX_FACES_PER_PIXEL is traced by Embree
packets instead (`vpp_core.trace.packets`): drawing costs per face, tracing per ray
(bench/raytrace.py; docs/raytrace.md)."""


class RasterBackend:
    """Pixel rays by rasterisation (one task per view); views with faces dense on the image
    (MAX_FACES_PER_PIXEL) and arbitrary rays go to `PacketBackend`."""

    name = "raster"
    block_rays = 1 << 62  # a whole view per task: the rasteriser's cost is per face and view

    def __init__(self, part: Part, max_faces_per_pixel: float = MAX_FACES_PER_PIXEL) -> None:
        self._part, self._max_faces_per_pixel = part, max_faces_per_pixel
        self._labels, self._vertices, self._faces = spatial_order(part.vertices, part.faces)
        # a copy of its own: numba compiles a kernel again for a read-only argument, and a
        # Part's normals are read-only or not depending on how it was made
        self._normals = np.array(part.normals, dtype=np.float64, order="C")
        self._packets: PacketBackend | None = None

    @property
    def packets(self) -> PacketBackend:
        """The Embree packet backend over the same part, built on first use."""
        if self._packets is None:
            self._packets = PacketBackend(self._part)
        return self._packets

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Arbitrary rays (candidate checks, diagnostics): Embree's answer."""
        return self.packets.first_hits(origin, directions, t_max)

    def valid_hits(self, block: Block) -> Hits:
        """Faces of the block's valid pixel rays and their counts, by z-buffer (GIL released)."""
        if self._by_packets(block):
            return self.packets.valid_hits(block)
        return self.draw(block).counts(self._normals)

    def pixel_hits(self, block: Block) -> PixelHits:
        """The block's valid pixel rays one by one, from the same z-buffer `valid_hits` counts."""
        if self._by_packets(block):
            return self.packets.pixel_hits(block)
        return self.draw(block).valid(self._normals)

    def _by_packets(self, block: Block) -> bool:
        """Whether the block has fewer pixels than faces / max_faces_per_pixel (inf: never)."""
        pixels = (block.rows[1] - block.rows[0]) * (block.cols[1] - block.cols[0])
        return len(self._faces) > self._max_faces_per_pixel * pixels

    def draw(self, block: Block) -> FirstHits:
        """The z-buffer of the block: first face and 1/depth per pixel."""
        sensor = block.sensor
        ids, inv_z = view_first_hits(
            self._vertices,
            self._faces,
            self._labels,
            np.ascontiguousarray(block.position, dtype=np.float64),  # one signature
            np.ascontiguousarray(block.rotation, dtype=np.float64),
            sensor.pixel_x,
            sensor.pixel_y,
            pixel_scale(sensor),
            window_of(block),
            sensor.far_mm,
        )
        return FirstHits(block, ids, inv_z)


def pixel_scale(sensor: Sensor) -> np.ndarray:
    """(4,) fx, fy, cx, cy: pixel column = x fx + cx and row = y fy + cy of image-plane (x, y)."""
    return np.array([sensor.fx, sensor.fy, sensor.width_px / 2 - 0.5, sensor.height_px / 2 - 0.5])


MORTON_BITS = 10
"""Bits per axis of the Morton code that orders faces (a 1024^3 grid over the bounding box)."""


def spatial_order(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(order (M,) int32, vertices (V, 3) float64, faces (M, 3) int32): faces sorted along a
    Morton curve of their centroids and vertices renumbered by first use, so that faces drawn
    one after another touch nearby memory (a file's own order can be random: twice as slow).
    faces[k] of the result is the input's face order[k]."""
    centroids = vertices[faces].mean(axis=1)
    lo, span = centroids.min(axis=0), np.ptp(centroids, axis=0).max() or 1.0
    cells = ((centroids - lo) / span * ((1 << MORTON_BITS) - 1)).astype(np.uint64)
    code = np.zeros(len(faces), dtype=np.uint64)
    for bit in range(MORTON_BITS):
        for axis in range(3):
            code |= ((cells[:, axis] >> np.uint64(bit)) & np.uint64(1)) << np.uint64(3 * bit + axis)
    order = np.argsort(code, kind="stable").astype(np.int32)
    ordered = faces[order]
    used, first = np.unique(ordered.reshape(-1), return_index=True)
    renumber = np.empty(len(vertices), dtype=np.int64)
    renumber[used[np.argsort(first)]] = np.arange(len(used))
    new_vertices = np.zeros((len(vertices), 3))
    new_vertices[renumber[used]] = vertices[used]
    return order, new_vertices, renumber[ordered].astype(np.int32)


@kernel
def view_first_hits(
    vertices: np.ndarray,
    faces: np.ndarray,
    labels: np.ndarray,
    position: np.ndarray,
    rotation: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    scale: np.ndarray,
    window: np.ndarray,
    far: float,
) -> tuple[np.ndarray, np.ndarray]:
    """First face (h, w) int32 (-1 = none within far) and its 1/depth (h, w) float64 (1/mm).

    vertices (V, 3) float64 mm, faces (M, 3) int32 and their ids (M,) int32 (what `ids` holds;
    at equal depth the lower id wins, whatever the drawing order); position (3,) and rotation
    (3, 3) (columns = camera x, y, z in world); px (W,), py (H,) camera-frame ray x, y at z = 1
    of each pixel column and row (the rays sampled: exactly Embree's); scale (4,) = fx, fy, cx,
    cy with column = x fx + cx (only bounds the scan); window (4,) int64 = rows v0:v1, columns
    u0:u1.
    """
    v0, v1, u0, u1 = window[0], window[1], window[2], window[3]
    inv_z = np.full((max(v1 - v0, 0), max(u1 - u0, 0)), 1.0 / far)
    ids = np.full(inv_z.shape, -1, np.int32)
    if inv_z.size == 0:
        return ids, inv_z
    cam = _to_view(vertices, position, rotation, scale)
    poly = np.empty((4, 3))
    for f in range(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        front = (cam[i, 2] > Z_CLIP) + (cam[j, 2] > Z_CLIP) + (cam[k, 2] > Z_CLIP)
        if front == 0:
            continue
        if front == 3:
            box = _bounds(
                (cam[i, 5], cam[j, 5], cam[k, 5]), (cam[i, 6], cam[j, 6], cam[k, 6]), window
            )
            if box[0] < 0:
                continue
            xs = (cam[i, 3], cam[j, 3], cam[k, 3])
            ys = (cam[i, 4], cam[j, 4], cam[k, 4])
        a = (cam[i, 0], cam[i, 1], cam[i, 2])
        b = (cam[j, 0], cam[j, 1], cam[j, 2])
        c = (cam[k, 0], cam[k, 1], cam[k, 2])
        plane = _inverse_depth_plane(a, b, c)
        if not math.isfinite(plane[0] + plane[1] + plane[2]):
            continue  # plane through the camera: seen edge-on
        parts = 1 if front == 3 else _clip(a, b, c, poly) - 2
        for t in range(1, parts + 1):  # one call site of _fill: it is inlined once
            if front < 3:  # the clipped polygon's fan, triangle t
                xs = (
                    poly[0, 0] / poly[0, 2],
                    poly[t, 0] / poly[t, 2],
                    poly[t + 1, 0] / poly[t + 1, 2],
                )
                ys = (
                    poly[0, 1] / poly[0, 2],
                    poly[t, 1] / poly[t, 2],
                    poly[t + 1, 1] / poly[t + 1, 2],
                )
                us = (
                    xs[0] * scale[0] + scale[2],
                    xs[1] * scale[0] + scale[2],
                    xs[2] * scale[0] + scale[2],
                )
                vs = (
                    ys[0] * scale[1] + scale[3],
                    ys[1] * scale[1] + scale[3],
                    ys[2] * scale[1] + scale[3],
                )
                box = _bounds(us, vs, window)
                if box[0] < 0:
                    continue
            _fill(xs, ys, box, plane, labels[f], px, py, scale, window, inv_z, ids)
    return ids, inv_z


@kernel
def _to_view(
    vertices: np.ndarray, position: np.ndarray, rotation: np.ndarray, scale: np.ndarray
) -> np.ndarray:
    """(V, 8) float64 per vertex, one cache line each: camera-frame x, y, z, then image-plane
    x/z, y/z and pixel column, row (those four meaningful for vertices with z > Z_CLIP)."""
    out = np.zeros((vertices.shape[0], 8))
    for i in range(vertices.shape[0]):
        dx = vertices[i, 0] - position[0]
        dy = vertices[i, 1] - position[1]
        dz = vertices[i, 2] - position[2]
        for k in range(3):
            out[i, k] = dx * rotation[0, k] + dy * rotation[1, k] + dz * rotation[2, k]
        if out[i, 2] > Z_CLIP:
            x, y = out[i, 0] / out[i, 2], out[i, 1] / out[i, 2]
            out[i, 3], out[i, 4] = x, y
            out[i, 5], out[i, 6] = x * scale[0] + scale[2], y * scale[1] + scale[3]
    return out


@inline
def _inverse_depth_plane(a: Triple, b: Triple, c: Triple) -> Triple:
    """(A, B, C) with 1/z = A x + B y + C on the ray (x, y, 1) through plane a, b, c (camera)."""
    nx = (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1])
    ny = (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2])
    nz = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    d = nx * a[0] + ny * a[1] + nz * a[2]
    return nx / d, ny / d, nz / d


@inline
def _bounds(us: Triple, vs: Triple, window: np.ndarray) -> tuple[int, int, int, int]:
    """Rows r0..r1 and columns c0..c1 of the window's pixel centres in the bounding box of a
    triangle with pixel coordinates (us, vs); r0 = -1 when there are none (sub-pixel and
    off-window faces: the cheap test that drops most faces of fine meshes)."""
    r0 = _first(min(vs[0], vs[1], vs[2]), window[0])
    r1 = _last(max(vs[0], vs[1], vs[2]), window[1] - 1)
    if r0 > r1:
        return -1, -1, -1, -1
    c0 = _first(min(us[0], us[1], us[2]), window[2])
    c1 = _last(max(us[0], us[1], us[2]), window[3] - 1)
    if c0 > c1:
        return -1, -1, -1, -1
    return r0, r1, c0, c1


@kernel
def _clip(a: Triple, b: Triple, c: Triple, poly: np.ndarray) -> int:
    """Triangle a, b, c (camera frame) clipped to z >= Z_CLIP into `poly` (4, 3); returns its
    vertex count (Sutherland-Hodgman against one plane: 0, 3 or 4)."""
    k = 0
    pts = (a, b, c)
    for i in range(3):
        p, q = pts[i], pts[(i + 1) % 3]
        if p[2] > Z_CLIP:
            poly[k, 0], poly[k, 1], poly[k, 2] = p[0], p[1], p[2]
            k += 1
        if (p[2] > Z_CLIP) != (q[2] > Z_CLIP):
            t = (Z_CLIP - p[2]) / (q[2] - p[2])
            for d in range(3):
                poly[k, d] = p[d] + t * (q[d] - p[d])
            k += 1
    return k


@inline
def _fill(
    xs: Triple,
    ys: Triple,
    box: tuple[int, int, int, int],
    plane: Triple,
    face: int,
    px: np.ndarray,
    py: np.ndarray,
    scale: np.ndarray,
    window: np.ndarray,
    inv_z: np.ndarray,
    ids: np.ndarray,
) -> None:
    """Z-buffer one triangle, image-plane vertices (xs, ys), pixel centres in `box` (_bounds),
    into the window's inv_z and ids.

    Inside tests run in image-plane coordinates (x/z, y/z) against the pixel rays px, py. On
    each row the inside pixels form one run (each edge function, rounding included, is
    monotonic in x); the run is found from the edges' crossings by testing its ends only.
    """
    area = (xs[1] - xs[0]) * (ys[2] - ys[0]) - (ys[1] - ys[0]) * (xs[2] - xs[0])
    if area == 0.0 or not math.isfinite(area):
        return
    r0, r1, c0, c1 = box
    sign = 1.0 if area > 0 else -1.0
    e0 = _edge_setup(xs[0], ys[0], xs[1], ys[1], sign)
    e1 = _edge_setup(xs[1], ys[1], xs[2], ys[2], sign)
    e2 = _edge_setup(xs[2], ys[2], xs[0], ys[0], sign)
    if (r1 - r0 + 1) * (c1 - c0 + 1) <= SMALL_BOX_PX:
        _fill_box(e0, e1, e2, plane, face, px, py, r0, r1, c0, c1, window, inv_z, ids)
        return
    s0, s1, s2 = _crossing(e0, scale), _crossing(e1, scale), _crossing(e2, scale)
    lo0, hi0 = c0 - 1.0, c1 + 1.0
    for row in range(r0, r1 + 1):
        y = float(py[row])
        lo, hi = _narrow(s0, y, lo0, hi0)
        lo, hi = _narrow(s1, y, lo, hi)
        lo, hi = _narrow(s2, y, lo, hi)
        first = max(int(math.ceil(min(lo, hi0) - SCAN_MARGIN_PX)), c0)  # clamped: no overflow
        last = min(int(math.floor(max(hi, lo0) + SCAN_MARGIN_PX)), c1)
        k0, k1, k2 = _row_term(e0, y), _row_term(e1, y), _row_term(e2, y)
        while first <= last and (
            _outside(e0, k0, px[first])
            or _outside(e1, k1, px[first])
            or _outside(e2, k2, px[first])
        ):
            first += 1
        while last > first and (
            _outside(e0, k0, px[last]) or _outside(e1, k1, px[last]) or _outside(e2, k2, px[last])
        ):
            last -= 1
        _fill_run(plane, face, px, y, row, first, last, window, inv_z, ids)


SMALL_BOX_PX = 6
"""Triangles whose bounding box holds at most this many pixel centres test each of them
(no per-row crossings): most faces of fine meshes."""


@inline
def _fill_box(
    e0: Edge,
    e1: Edge,
    e2: Edge,
    plane: Triple,
    face: int,
    px: np.ndarray,
    py: np.ndarray,
    r0: int,
    r1: int,
    c0: int,
    c1: int,
    window: np.ndarray,
    inv_z: np.ndarray,
    ids: np.ndarray,
) -> None:
    """Z-buffer the pixel centres of rows r0..r1, columns c0..c1 inside edges e0, e1, e2."""
    for row in range(r0, r1 + 1):
        y = float(py[row])
        k0, k1, k2 = _row_term(e0, y), _row_term(e1, y), _row_term(e2, y)
        for col in range(c0, c1 + 1):
            x = px[col]
            if not (_outside(e0, k0, x) or _outside(e1, k1, x) or _outside(e2, k2, x)):
                _fill_run(plane, face, px, y, row, col, col, window, inv_z, ids)


@inline
def _fill_run(
    plane: Triple,
    face: int,
    px: np.ndarray,
    y: float,
    row: int,
    first: int,
    last: int,
    window: np.ndarray,
    inv_z: np.ndarray,
    ids: np.ndarray,
) -> None:
    """Z-buffer columns first..last of `row` (all inside the face), 1/z from its plane."""
    base = plane[1] * y + plane[2]
    i, u0 = row - window[0], window[2]
    for col in range(first, last + 1):
        iz = plane[0] * px[col] + base
        z = inv_z[i, col - u0]
        if iz > z or (iz == z and face < ids[i, col - u0]):  # a tie goes to the lower id
            inv_z[i, col - u0] = iz
            ids[i, col - u0] = face


Edge = tuple[float, float, float, float, float, bool]
"""(ax, ay, ex, ey, s, owns): edge from its lexicographically smaller end a, direction (ex, ey),
s = +-1 so that s (ex (y - ay) - ey (x - ax)) >= 0 inside, owns = top-left (owns its zeros)."""


@inline
def _edge_setup(ax: float, ay: float, bx: float, by: float, sign: float) -> Edge:
    """The edge a->b of a triangle wound as `sign`, in canonical (watertight) form."""
    top_left = (by - ay) * sign < 0 or ((by - ay) == 0 and (bx - ax) * sign > 0)
    if bx < ax or (bx == ax and by < ay):
        return bx, by, ax - bx, ay - by, -sign, top_left
    return ax, ay, bx - ax, by - ay, sign, top_left


Crossing = tuple[float, float, int]
"""(A, B, kind): edge e's line meets image-plane height y at pixel column A + B y; kind 1 when
the inside lies left of it (an upper bound on the column), -1 right of it, 0 never (level)."""


@inline
def _crossing(e: Edge, scale: np.ndarray) -> Crossing:
    """Where edge e crosses each row, in pixel columns (approximate: bounds the exact tests)."""
    if e[3] == 0.0:
        return 0.0, 0.0, 0
    slope = e[2] / e[3]
    a, b = (e[0] - slope * e[1]) * scale[0] + scale[2], slope * scale[0]
    if not (math.isfinite(a) and math.isfinite(b)):
        return 0.0, 0.0, 0  # nearly level: leave the row to the exact tests
    kind = 1 if e[3] * e[4] > 0 else -1  # the edge function falls as x grows: inside is left
    return a, b, kind


@inline
def _narrow(c: Crossing, y: float, lo: float, hi: float) -> tuple[float, float]:
    """Columns lo..hi narrowed to the inner side of an edge's crossing at height y."""
    if c[2] == 0:
        return lo, hi
    u = c[0] + c[1] * y
    if c[2] > 0:
        return lo, min(hi, u)
    return max(lo, u), hi


@inline
def _row_term(e: Edge, y: float) -> float:
    """The edge function's part that depends on y only: ex (y - ay)."""
    return e[2] * (y - e[1])


@inline
def _outside(e: Edge, row_term: float, x: float) -> bool:
    """Whether image-plane x on the current row lies outside edge e (top-left rule on it)."""
    value = e[4] * (row_term - e[3] * (x - e[0]))
    return value < 0.0 or (value == 0.0 and not e[5])


SCAN_MARGIN_PX = 0.01
"""Slack (pixels) of the scan bounds: covers the float32 rounding of the pixel rays (~1e-4 px);
the inside test itself is exact on the rays."""


@inline
def _first(u: float, lo: int) -> int:
    """First pixel index at or after coordinate u (less the margin), at least lo (inf-safe)."""
    k = np.ceil(u - SCAN_MARGIN_PX)
    return lo if not k > lo else (1 << 62 if k > 1e18 else int(k))


@inline
def _last(u: float, hi: int) -> int:
    """Last pixel index at or before coordinate u (plus the margin), at most hi (inf-safe)."""
    k = np.floor(u + SCAN_MARGIN_PX)
    return hi if not k < hi else (-(1 << 62) if k < -1e18 else int(k))
