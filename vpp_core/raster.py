"""Primary visibility by z-buffer rasterisation of face ids at pixel centres (numba).

For a pinhole camera, "the first face hit by the ray through each pixel centre" is exactly
the face whose projected triangle contains the pixel centre and is nearest there. Per view:

1. vertices to the camera frame; faces with a vertex behind the plane z = Z_CLIP are clipped
   against it (Sutherland-Hodgman), the rest projected to pixel coordinates u = x/z fx + cx;
2. each triangle is scanned row by row over its exact span; a pixel centre is inside when all
   three edge functions are > 0, or = 0 on a top-left edge (the shared-edge rule: each edge
   is evaluated from its lexicographically smaller end, so neighbours get the same value of
   opposite sign and exactly one of them owns the pixel); the z-buffer holds 1/z, which is
   linear in the ray direction (x, y, 1) for a plane: 1/z = n.d / n.v0;
3. the SPEC §3 checks per pixel (near <= z <= far, |cos incidence| >= cos_min) on the winner.

Arithmetic is float64 throughout. It answers the same question as `EmbreeBackend` up to
floating-point ties: pixel centres on a shared edge (top-left rule here, Embree's own rule
there) and faces at equal depth (lower face id wins here).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from vpp_core.embree import EmbreeBackend
from vpp_core.mesh import Part
from vpp_core.rays import Block, Hits

kernel = njit(nogil=True, cache=True, error_model="numpy")
"""Compiled once per machine (cached next to this file); releases the GIL; x/0 gives inf/nan."""

Z_CLIP = 1e-6
"""Near clipping plane (mm) of the rasteriser: rays start at the camera, t > 0."""


class RasterBackend:
    """Pixel rays by rasterisation (one task per view); other rays through `EmbreeBackend`."""

    name = "raster"
    block_rays = 1 << 62  # a whole view per task: the rasteriser's cost is per face and view

    def __init__(self, part: Part) -> None:
        self._part = part
        self._vertices = np.ascontiguousarray(part.vertices, dtype=np.float64)
        self._faces = np.ascontiguousarray(part.faces, dtype=np.int32)
        self._normals = np.ascontiguousarray(part.normals, dtype=np.float64)
        self._embree: EmbreeBackend | None = None

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Arbitrary rays (candidate checks, diagnostics): Embree's answer, scene built once."""
        if self._embree is None:
            self._embree = EmbreeBackend(self._part)
        return self._embree.first_hits(origin, directions, t_max)

    def valid_hits(self, block: Block) -> Hits:
        """Faces of the block's valid pixel rays and their counts, by z-buffer (GIL released)."""
        sensor = block.sensor
        scale = np.array(
            [sensor.fx, sensor.fy, sensor.width_px / 2 - 0.5, sensor.height_px / 2 - 0.5]
        )
        window = np.array([*block.rows, *block.cols], dtype=np.int64)
        cos_min = math.cos(math.radians(sensor.max_incidence_deg))
        return view_valid_faces(
            self._vertices,
            self._faces,
            self._normals,
            np.asarray(block.position, dtype=np.float64),
            np.ascontiguousarray(block.rotation, dtype=np.float64),
            sensor.pixel_x,
            sensor.pixel_y,
            scale,
            window,
            sensor.near_mm,
            sensor.far_mm,
            cos_min,
        )


@kernel
def view_valid_faces(
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    position: np.ndarray,
    rotation: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    scale: np.ndarray,
    window: np.ndarray,
    near: float,
    far: float,
    cos_min: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Faces (k,) int32 seen by valid pixel rays of one view's window (SPEC §3), and how many
    rays each (k,) int32. normals (M, 3) float64 world unit normals; the rest as `view_first_hits`.
    """
    ids, inv_z = view_first_hits(vertices, faces, position, rotation, px, py, scale, window, far)
    return _valid_counts(ids, inv_z, normals, rotation, px, py, window, near, cos_min)


@kernel
def view_first_hits(
    vertices: np.ndarray,
    faces: np.ndarray,
    position: np.ndarray,
    rotation: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    scale: np.ndarray,
    window: np.ndarray,
    far: float,
) -> tuple[np.ndarray, np.ndarray]:
    """First face (h, w) int32 (-1 = none within far) and its 1/depth (h, w) float64 (1/mm).

    vertices (V, 3) float64 mm, faces (M, 3) int32; position (3,) and rotation (3, 3) (columns
    = camera x, y, z in world); px (W,), py (H,) camera-frame ray x, y at z = 1 of each pixel
    column and row (the rays sampled: exactly Embree's); scale (4,) = fx, fy, cx, cy with
    column = x fx + cx (only bounds the scan); window (4,) int64 = rows v0:v1, columns u0:u1.
    """
    v0, v1, u0, u1 = window[0], window[1], window[2], window[3]
    inv_z = np.full((max(v1 - v0, 0), max(u1 - u0, 0)), 1.0 / far)
    ids = np.full(inv_z.shape, -1, np.int32)
    if inv_z.size == 0:
        return ids, inv_z
    cam = _to_camera(vertices, position, rotation)
    img = np.empty((cam.shape[0], 2))  # image-plane x/z, y/z of vertices in front
    for i in range(cam.shape[0]):
        if cam[i, 2] > Z_CLIP:
            img[i, 0], img[i, 1] = cam[i, 0] / cam[i, 2], cam[i, 1] / cam[i, 2]
    poly = np.empty((4, 3))
    for f in range(faces.shape[0]):
        i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
        front = (cam[i, 2] > Z_CLIP) + (cam[j, 2] > Z_CLIP) + (cam[k, 2] > Z_CLIP)
        if front == 0:
            continue
        if front == 3:
            xs = (img[i, 0], img[j, 0], img[k, 0])
            ys = (img[i, 1], img[j, 1], img[k, 1])
            if _bounds(xs, ys, scale, window)[0] < 0:
                continue
        plane = _inverse_depth_plane(cam[i], cam[j], cam[k])
        if not math.isfinite(plane[0] + plane[1] + plane[2]):
            continue  # plane through the camera: seen edge-on
        if front == 3:
            _fill(xs, ys, plane, f, px, py, scale, window, inv_z, ids)
            continue
        n = _clip(cam[i], cam[j], cam[k], poly)
        for t in range(1, n - 1):
            xs = (poly[0, 0] / poly[0, 2], poly[t, 0] / poly[t, 2], poly[t + 1, 0] / poly[t + 1, 2])
            ys = (poly[0, 1] / poly[0, 2], poly[t, 1] / poly[t, 2], poly[t + 1, 1] / poly[t + 1, 2])
            _fill(xs, ys, plane, f, px, py, scale, window, inv_z, ids)
    return ids, inv_z


@kernel
def _to_camera(vertices: np.ndarray, position: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """(V, 3) float64 camera-frame coordinates: (vertex - position) @ rotation."""
    out = np.empty(vertices.shape)
    for i in range(vertices.shape[0]):
        dx = vertices[i, 0] - position[0]
        dy = vertices[i, 1] - position[1]
        dz = vertices[i, 2] - position[2]
        for k in range(3):
            out[i, k] = dx * rotation[0, k] + dy * rotation[1, k] + dz * rotation[2, k]
    return out


@kernel
def _inverse_depth_plane(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[float, float, float]:
    """(A, B, C) with 1/z = A x + B y + C on the ray (x, y, 1) through plane a, b, c (camera)."""
    nx = (b[1] - a[1]) * (c[2] - a[2]) - (b[2] - a[2]) * (c[1] - a[1])
    ny = (b[2] - a[2]) * (c[0] - a[0]) - (b[0] - a[0]) * (c[2] - a[2])
    nz = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    d = nx * a[0] + ny * a[1] + nz * a[2]
    return nx / d, ny / d, nz / d


@kernel
def _bounds(
    xs: tuple[float, float, float],
    ys: tuple[float, float, float],
    scale: np.ndarray,
    window: np.ndarray,
) -> tuple[int, int, int, int]:
    """Rows r0..r1 and columns c0..c1 of the window's pixel centres in the triangle's bounding
    box; r0 = -1 when there are none."""
    r0 = _first(min(ys[0], ys[1], ys[2]) * scale[1] + scale[3], window[0])
    r1 = _last(max(ys[0], ys[1], ys[2]) * scale[1] + scale[3], window[1] - 1)
    c0 = _first(min(xs[0], xs[1], xs[2]) * scale[0] + scale[2], window[2])
    c1 = _last(max(xs[0], xs[1], xs[2]) * scale[0] + scale[2], window[3] - 1)
    if r0 > r1 or c0 > c1:
        return -1, -1, -1, -1
    return r0, r1, c0, c1


@kernel
def _clip(a: np.ndarray, b: np.ndarray, c: np.ndarray, poly: np.ndarray) -> int:
    """Triangle a, b, c clipped to z >= Z_CLIP into `poly` (4, 3); returns its vertex count."""
    if a[2] > Z_CLIP and b[2] > Z_CLIP and c[2] > Z_CLIP:
        poly[0], poly[1], poly[2] = a, b, c
        return 3
    k = 0
    pts = (a, b, c)
    for i in range(3):
        p, q = pts[i], pts[(i + 1) % 3]
        if p[2] > Z_CLIP:
            poly[k] = p
            k += 1
        if (p[2] > Z_CLIP) != (q[2] > Z_CLIP):
            s = (Z_CLIP - p[2]) / (q[2] - p[2])
            poly[k] = p + s * (q - p)
            k += 1
    return k


@kernel
def _fill(
    xs: tuple[float, float, float],
    ys: tuple[float, float, float],
    plane: tuple[float, float, float],
    face: int,
    px: np.ndarray,
    py: np.ndarray,
    scale: np.ndarray,
    window: np.ndarray,
    inv_z: np.ndarray,
    ids: np.ndarray,
) -> None:
    """Z-buffer one triangle, image-plane vertices (xs, ys), into the window's inv_z and ids.

    Inside tests run in image-plane coordinates (x/z, y/z) against the pixel rays px, py. On
    each row the inside pixels form one run (each edge function, rounding included, is
    monotonic in x); the run is found from the edges' crossings by testing its ends only.
    """
    area = (xs[1] - xs[0]) * (ys[2] - ys[0]) - (ys[1] - ys[0]) * (xs[2] - xs[0])
    r0, r1, c0, c1 = _bounds(xs, ys, scale, window)
    if area == 0.0 or not math.isfinite(area) or r0 < 0:
        return
    sign = 1.0 if area > 0 else -1.0
    e0 = _edge_setup(xs[0], ys[0], xs[1], ys[1], sign)
    e1 = _edge_setup(xs[1], ys[1], xs[2], ys[2], sign)
    e2 = _edge_setup(xs[2], ys[2], xs[0], ys[0], sign)
    fx, cx, v0, u0 = scale[0], scale[2], window[0], window[2]
    for row in range(r0, r1 + 1):
        y = float(py[row])
        lo, hi = _span(e0, y, -math.inf, math.inf)
        lo, hi = _span(e1, y, lo, hi)
        lo, hi = _span(e2, y, lo, hi)
        first = max(_first(lo * fx + cx, c0), c0)
        last = min(_last(hi * fx + cx, c1), c1)
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
        base = plane[1] * y + plane[2]
        zrow, idrow = inv_z[row - v0], ids[row - v0]
        for col in range(first, last + 1):
            iz = plane[0] * px[col] + base
            if iz > zrow[col - u0]:
                zrow[col - u0] = iz
                idrow[col - u0] = face


Edge = tuple[float, float, float, float, float, bool]
"""(ax, ay, ex, ey, s, owns): edge from its lexicographically smaller end a, direction (ex, ey),
s = +-1 so that s (ex (y - ay) - ey (x - ax)) >= 0 inside, owns = top-left (owns its zeros)."""


@kernel
def _edge_setup(ax: float, ay: float, bx: float, by: float, sign: float) -> Edge:
    """The edge a->b of a triangle wound as `sign`, in canonical (watertight) form."""
    top_left = (by - ay) * sign < 0 or ((by - ay) == 0 and (bx - ax) * sign > 0)
    if bx < ax or (bx == ax and by < ay):
        return bx, by, ax - bx, ay - by, -sign, top_left
    return ax, ay, bx - ax, by - ay, sign, top_left


@kernel
def _row_term(e: Edge, y: float) -> float:
    """The edge function's part that depends on y only: ex (y - ay)."""
    return e[2] * (y - e[1])


@kernel
def _outside(e: Edge, row_term: float, x: float) -> bool:
    """Whether image-plane x on the current row lies outside edge e (top-left rule on it)."""
    value = e[4] * (row_term - e[3] * (x - e[0]))
    return value < 0.0 or (value == 0.0 and not e[5])


@kernel
def _span(e: Edge, y: float, lo: float, hi: float) -> tuple[float, float]:
    """Image-plane x range lo..hi at height y narrowed to the inner side of edge e."""
    if e[3] == 0.0:
        return lo, hi
    x = e[0] + e[2] * (y - e[1]) / e[3]
    if e[3] * e[4] > 0:  # the edge function falls as x grows: inside is x <= crossing
        return lo, min(hi, x)
    return max(lo, x), hi


SCAN_MARGIN_PX = 0.01
"""Slack (pixels) of the scan bounds: covers the float32 rounding of the pixel rays (~1e-4 px);
the inside test itself is exact on the rays."""


@kernel
def _first(u: float, lo: int) -> int:
    """First pixel index at or after coordinate u (less the margin), at least lo (inf-safe)."""
    k = np.ceil(u - SCAN_MARGIN_PX)
    return lo if not k > lo else (1 << 62 if k > 1e18 else int(k))


@kernel
def _last(u: float, hi: int) -> int:
    """Last pixel index at or before coordinate u (plus the margin), at most hi (inf-safe)."""
    k = np.floor(u + SCAN_MARGIN_PX)
    return hi if not k < hi else (-(1 << 62) if k < -1e18 else int(k))


@kernel
def _valid_counts(
    ids: np.ndarray,
    inv_z: np.ndarray,
    normals: np.ndarray,
    rotation: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    window: np.ndarray,
    near: float,
    cos_min: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Faces (k,) int32 whose pixels are valid (depth >= near, incidence) and their counts (k,)."""
    counts = np.zeros(normals.shape[0], np.int32)
    h, w = ids.shape
    cos2 = cos_min * cos_min
    for i in range(h):
        y = float(py[window[0] + i])
        row = (
            rotation[0, 1] * y + rotation[0, 2],
            rotation[1, 1] * y + rotation[1, 2],
            rotation[2, 1] * y + rotation[2, 2],
        )
        for j in range(w):
            f = ids[i, j]
            if f < 0 or inv_z[i, j] * near > 1.0:
                continue
            x = float(px[window[2] + j])
            dot = (
                normals[f, 0] * (rotation[0, 0] * x + row[0])
                + normals[f, 1] * (rotation[1, 0] * x + row[1])
                + normals[f, 2] * (rotation[2, 0] * x + row[2])
            )
            if dot * dot >= cos2 * (x * x + y * y + 1.0):
                counts[f] += 1
    faces = np.flatnonzero(counts).astype(np.int32)
    return faces, counts[faces]
