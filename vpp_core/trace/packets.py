"""Embree packet tracing of pixel rays: `rtcIntersect16` on coherent 4 x 4 pixel tiles.

Embree is called through ctypes, no compiler needed: the scene is built from Python once per
part, and a numba kernel (GIL released) fills one packet per 4 x 4 tile of a view's window and
calls `rtcIntersect16` with the coherent flag: one C call per 16 rays. The library is the
system's Embree 3 where installed (Debian/Ubuntu `libembree3-3`), else the Embree 4 that the
embreex wheel ships: Embree 4.4 ignores the coherent flag and traces packets no faster than
single rays, Embree 3's coherent traversal is 3-4x faster on pixel tiles (docs/raytrace.md).

The rays are bit for bit those of `vpp_core.trace.embree.block_directions` (float32 (x, y, 1) turned
to world), so the face hit through each pixel is Embree's answer (tests/test_raster.py). The
structures follow Embree's public ABI (rtcore_ray.h, rtcore_scene.h, rtcore_common.h, alike
in 3 and 4): RTCRayHit16 is 12 ray fields then 7 hit fields (+ instance ids) of 16 lanes each,
64-byte aligned; Embree 3 takes an RTCIntersectContext (flags, filter, instID) before the
packet, Embree 4 RTCIntersectArguments (flags, feature mask, pointers) after it.
"""

from __future__ import annotations

import ctypes
import glob
import math
import os
import threading
from dataclasses import dataclass
from functools import cache, cached_property
from typing import Any

import numpy as np

from vpp_core.errors import VppError
from vpp_core.jit import inline, kernel
from vpp_core.mesh.part import Part
from vpp_core.trace.pixels import Triple, row_direction, window_of
from vpp_core.trace.rays import Block, Hits, PixelHits

# enum values shared by Embree 3 and 4 (rtcore_common.h, rtcore_geometry.h, rtcore_scene.h)
_GEOMETRY_TRIANGLE = 0
_BUFFER_INDEX, _BUFFER_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_SCENE_ROBUST = 1 << 2
_COHERENT = 1 << 0  # RTC_INTERSECT_CONTEXT_FLAG_COHERENT (3), RTC_RAY_QUERY_FLAG_COHERENT (4)
_FEATURES_ALL = 0xFFFFFFFF
_INVALID_ID = 0xFFFFFFFF

# float / uint lanes of RTCRayHit16: ray org xyz, tnear, dir xyz, time, tfar, mask, id, flags;
# hit Ng xyz, u, v, primID, geomID, instID[1] (Embree 4.3+ may add instPrimID after it)
_LANES = 16
_TNEAR, _DIR, _TIME, _TFAR, _MASK, _ID, _FLAGS = 3, 4, 7, 8, 9, 10, 11
_NG, _PRIM, _GEOM = 12, 17, 18
_PACKET_WORDS = 21 * _LANES  # room for instID and instPrimID

GROUP = 64
"""Faces per mark of trace_window's hit faces: reading them back in ascending order costs a
scan of M / GROUP marks plus GROUP counters per marked group, no sort and no O(M) scan."""

EMBREE3 = ("libembree3.so.3", "libembree3.3.dylib", "embree3.dll")
"""Where the system's Embree 3 is looked for (Debian/Ubuntu: `apt install libembree3-3`)."""


@dataclass(frozen=True)
class Library:
    """An Embree shared library, its major version and its rtcIntersect16 for numba."""

    cdll: ctypes.CDLL
    major: int  # 3: rtcIntersect16(valid, scene, context, rayhit); 4: (valid, scene, rayhit, args)
    path: str

    @cached_property
    def intersect16(self) -> Any:
        """rtcIntersect16 as a ctypes function of four pointers, which numba calls directly."""
        address = ctypes.cast(self.cdll.rtcIntersect16, ctypes.c_void_p).value
        assert address is not None
        return ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 4)(address)

    def query(self, coherent: bool) -> np.ndarray:
        """(16,) uint32: Embree 3's RTCIntersectContext or Embree 4's RTCIntersectArguments,
        pointers NULL."""
        out = np.zeros(16, np.uint32)
        out[0] = _COHERENT if coherent else 0
        if self.major == 3:
            out[4] = _INVALID_ID  # instID[0], after the filter pointer
        else:
            out[1] = _FEATURES_ALL
        return out


@cache
def library(major: int | None = None) -> Library:
    """Embree `major` (3 or 4); by default the system's Embree 3 where installed (its coherent
    packets are 3-4x faster on pixel tiles: docs/raytrace.md), else the embreex wheel's 4."""
    names = {3: EMBREE3, 4: (_embree4_path(),)}
    errors = []
    for version in (3, 4) if major is None else (major,):
        for name in names.get(version, ()):
            try:
                return _declare(Library(ctypes.CDLL(name), version, name))
            except OSError as exc:
                errors.append(str(exc))
    raise VppError(f"no Embree {major or ''} for the packets backend {errors or ''}")


def _embree4_path() -> str:
    """The libembree4 that the embreex wheel ships."""
    import embreex

    root = os.path.dirname(os.path.dirname(embreex.__file__))
    for pattern in ("embreex.libs/libembree4*.so*", "embreex/.dylibs/libembree4*.dylib"):
        found = sorted(glob.glob(os.path.join(root, pattern)))
        if found:
            return found[0]
    return "libembree4.so.4"


def _declare(lib: Library) -> Library:
    """Set the ctypes signatures of the few functions used here."""
    vp, uint, enum, size = ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_size_t
    signatures: dict[str, tuple[Any, list[Any]]] = {
        "rtcNewDevice": (vp, [ctypes.c_char_p]),
        "rtcGetDeviceError": (enum, [vp]),
        "rtcReleaseDevice": (None, [vp]),
        "rtcNewScene": (vp, [vp]),
        "rtcSetSceneFlags": (None, [vp, enum]),
        "rtcCommitScene": (None, [vp]),
        "rtcReleaseScene": (None, [vp]),
        "rtcNewGeometry": (vp, [vp, enum]),
        "rtcSetNewGeometryBuffer": (vp, [vp, enum, uint, enum, size, size]),
        "rtcCommitGeometry": (None, [vp]),
        "rtcAttachGeometry": (uint, [vp, vp]),
        "rtcReleaseGeometry": (None, [vp]),
    }
    for name, (restype, argtypes) in signatures.items():
        fn = getattr(lib.cdll, name)
        fn.restype, fn.argtypes = restype, argtypes
    return lib


class _Scene:
    """An Embree device and robust triangle scene over one mesh, released with the object."""

    def __init__(self, lib: Library, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.library, c = lib, lib.cdll
        self.device = c.rtcNewDevice(None)
        if not self.device:
            raise VppError("Embree could not create a device")
        self.scene = c.rtcNewScene(self.device)
        c.rtcSetSceneFlags(self.scene, _SCENE_ROBUST)
        geometry = c.rtcNewGeometry(self.device, _GEOMETRY_TRIANGLE)
        for kind, fmt, array in (
            (_BUFFER_VERTEX, _FORMAT_FLOAT3, np.ascontiguousarray(vertices, np.float32)),
            (_BUFFER_INDEX, _FORMAT_UINT3, np.ascontiguousarray(faces, np.uint32)),
        ):
            buffer = c.rtcSetNewGeometryBuffer(geometry, kind, 0, fmt, 12, len(array))
            if not buffer:
                error = c.rtcGetDeviceError(self.device)
                raise VppError(f"Embree refused a buffer (error {error})")
            ctypes.memmove(buffer, array.ctypes.data, array.nbytes)
        c.rtcCommitGeometry(geometry)
        c.rtcAttachGeometry(self.scene, geometry)
        c.rtcReleaseGeometry(geometry)
        c.rtcCommitScene(self.scene)
        if error := c.rtcGetDeviceError(self.device):
            raise VppError(f"Embree could not build the scene (error {error})")

    def __del__(self) -> None:
        c = self.library.cdll
        if getattr(self, "scene", None):
            c.rtcReleaseScene(self.scene)
        if getattr(self, "device", None):
            c.rtcReleaseDevice(self.device)


class PacketBackend:
    """Pixel rays as coherent Embree packets of 16 (tasks of block_rays pixels); arbitrary
    rays as incoherent packets."""

    name = "packets"
    block_rays = 1 << 18  # tasks of a few ms: every thread stays busy to the last view

    def __init__(self, part: Part, embree: int | None = None) -> None:
        self.library = library(embree)
        self._scene = _Scene(self.library, part.vertices, part.faces)
        self._tiles, self._rays = self.library.query(True), self.library.query(False)
        self._n_faces = part.n_faces
        self._idle: list[tuple[np.ndarray, np.ndarray]] = []  # counters not in use, all zero
        self._lock = threading.Lock()

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Face id (n,) int32 (-1 = miss) and hit parameter t (n,) float32 of rays from origin."""
        return trace_rays(
            *self._call(self._rays),
            np.asarray(origin, dtype=np.float32).reshape(3),
            np.ascontiguousarray(directions, dtype=np.float32).reshape(-1, 3),
            np.float32(t_max),
        )

    def valid_hits(self, block: Block) -> Hits:
        """Faces of the block's valid pixel rays (ascending) and their counts (GIL released)."""
        faces, counts, _, _, _ = self._trace(block, store=False)
        return faces, counts

    def pixel_hits(self, block: Block) -> PixelHits:
        """The block's valid pixel rays one by one, row-major: pixel, face and depth."""
        _, _, pixels, faces, depth = self._trace(block, store=True)
        order = np.argsort(pixels)
        return PixelHits(pixels[order], faces[order], depth[order])

    def _trace(self, block: Block, store: bool) -> tuple[np.ndarray, ...]:
        """trace_window over the block, with a pair of counters no other thread is using."""
        sensor = block.sensor
        counters = self._take_counters()
        out = trace_window(
            *self._call(self._tiles),
            np.ascontiguousarray(block.position, dtype=np.float32),
            np.ascontiguousarray(block.rotation, dtype=np.float32),
            np.ascontiguousarray(block.rotation, dtype=np.float64),
            *counters,
            sensor.pixel_x,
            sensor.pixel_y,
            window_of(block),
            sensor.near_mm,
            sensor.far_mm,
            math.cos(math.radians(sensor.max_incidence_deg)),
            store,
        )
        with self._lock:  # zero again: trace_window leaves them so (dropped if it raised)
            self._idle.append(counters)
        return out

    def _take_counters(self) -> tuple[np.ndarray, np.ndarray]:
        """A per-face counter (M,) int32 and its marks per GROUP faces (ceil(M / GROUP),)
        uint8, all zero: kept across calls and threads (fresh pages would fault on every
        call)."""
        with self._lock:
            if self._idle:
                return self._idle.pop()
        return np.zeros(self._n_faces, np.int32), np.zeros(-(-self._n_faces // GROUP), np.uint8)

    def _call(self, query: np.ndarray) -> tuple[Any, int, int, np.ndarray]:
        """What the kernels need to call rtcIntersect16: function, ABI, scene, query."""
        return self.library.intersect16, self.library.major, self._scene.scene, query


@inline
def _intersect(
    intersect16: Any,
    major: int,
    scene: int,
    query: np.ndarray,
    valid: np.ndarray,
    packet: np.ndarray,
) -> None:
    """One rtcIntersect16 call, arguments in the order of Embree `major`."""
    if major == 3:
        intersect16(valid.ctypes.data, scene, query.ctypes.data, packet.ctypes.data)
    else:
        intersect16(valid.ctypes.data, scene, packet.ctypes.data, query.ctypes.data)


@inline
def _packet() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An empty RTCRayHit16 as float (words,) and uint (words,) views, and its valid mask (16,)
    int32, all 64-byte aligned (Embree 3 loads them as AVX-512 words)."""
    raw = np.zeros(_PACKET_WORDS + 2 * _LANES, np.float32)
    start = ((64 - raw.ctypes.data % 64) % 64) // 4
    packet = raw[start : start + _PACKET_WORDS]
    valid = raw[start + _PACKET_WORDS : start + _PACKET_WORDS + _LANES].view(np.int32)
    return packet, packet.view(np.uint32), valid


@inline
def _set_ray(
    packet: np.ndarray, lanes: np.ndarray, lane: int, o: np.ndarray, d: tuple[Any, ...], far: Any
) -> None:
    """Lane `lane` of the packet: origin o (3,), direction d, segment [0, far], no hit yet."""
    for k in range(3):
        packet[k * _LANES + lane] = o[k]
        packet[(_DIR + k) * _LANES + lane] = d[k]
    packet[_TNEAR * _LANES + lane] = 0.0
    packet[_TIME * _LANES + lane] = 0.0
    packet[_TFAR * _LANES + lane] = far
    lanes[_MASK * _LANES + lane] = _INVALID_ID
    lanes[_ID * _LANES + lane] = 0
    lanes[_FLAGS * _LANES + lane] = 0
    lanes[_GEOM * _LANES + lane] = _INVALID_ID


@inline
def _incidence_ok(packet: np.ndarray, lane: int, d: Triple, d2: float, cos2: float) -> bool:
    """|cos| of the angle between ray direction d (|d|² = d2) and the hit's geometric normal
    (Embree's Ng: the face's own normal, unnormalised, read from the packet rather than
    looked up per face: no cache miss per hit on big meshes) is at least cos_min."""
    nx = float(packet[_NG * _LANES + lane])
    ny = float(packet[(_NG + 1) * _LANES + lane])
    nz = float(packet[(_NG + 2) * _LANES + lane])
    dot = nx * d[0] + ny * d[1] + nz * d[2]
    return bool(dot * dot >= cos2 * (nx * nx + ny * ny + nz * nz) * d2)


@kernel
def trace_rays(
    intersect16: Any,
    major: int,
    scene: int,
    query: np.ndarray,
    origin: np.ndarray,
    directions: np.ndarray,
    far: np.float32,
) -> tuple[np.ndarray, np.ndarray]:
    """Face id (n,) int32 (-1 = miss) and t (n,) float32 of rays from origin (3,) float32 along
    directions (n, 3) float32, within [0, far], 16 at a time."""
    n = directions.shape[0]
    prim = np.full(n, -1, np.int32)
    t = np.full(n, np.inf, np.float32)
    packet, lanes, valid = _packet()
    for s in range(0, n, _LANES):
        for lane in range(_LANES):
            valid[lane] = -1 if s + lane < n else 0
            if s + lane < n:
                d = directions[s + lane]
                _set_ray(packet, lanes, lane, origin, (d[0], d[1], d[2]), far)
        _intersect(intersect16, major, scene, query, valid, packet)
        for lane in range(min(_LANES, n - s)):
            if lanes[_GEOM * _LANES + lane] != _INVALID_ID:
                prim[s + lane] = lanes[_PRIM * _LANES + lane]
                t[s + lane] = packet[_TFAR * _LANES + lane]
    return prim, t


@kernel
def trace_window(
    intersect16: Any,
    major: int,
    scene: int,
    query: np.ndarray,
    position: np.ndarray,
    rotation32: np.ndarray,
    rotation: np.ndarray,
    counts: np.ndarray,
    marks: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    window: np.ndarray,
    near: float,
    far: float,
    cos_min: float,
    store: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The window's pixel rays traced as coherent 4 x 4 packets and checked (SPEC §3): the
    faces hit by valid rays (k,) int32, ascending, and their ray counts (k,) int32; with `store`
    also each valid ray, in tile order: its pixel (n,) int64 (row-major index within the
    window), face (n,) int32 and depth (n,) float32 mm (else three empty arrays).

    intersect16: rtcIntersect16 of Embree `major` (3 or 4), its scene and query (16,) uint32
    (context or arguments); position (3,) float32 mm; rotation32 / rotation (3, 3) float32 /
    float64 camera-to-world; counts (M,) int32 and marks (ceil(M / GROUP),) uint8 all zero
    (left so); px (W,), py (H,) float32
    ray x, y at z = 1; window (4,) int64 = rows v0:v1, columns u0:u1; near, far mm; cos_min of the
    largest incidence angle. Ray directions are block_directions' own float32 values,
    x R[:, 0] + (y R[:, 1] + R[:, 2]); depth t >= near, and incidence on Embree's Ng.
    """
    v0, v1, u0, u1 = window[0], window[1], window[2], window[3]
    h, w = max(v1 - v0, 0), max(u1 - u0, 0)
    size = h * w if store else 0
    pixels, faces, depth = (
        np.empty(size, np.int64),
        np.empty(size, np.int32),
        np.empty(size, np.float32),
    )
    n = 0
    packet, lanes, valid = _packet()
    for lane in range(_LANES):  # the fields Embree only reads, once
        _set_ray(packet, lanes, lane, position, (0.0, 0.0, 0.0), far)
    row32, row, xs = np.zeros((4, 3), np.float32), np.zeros((4, 3)), np.zeros(4, np.float32)
    far32, cos2 = np.float32(far), cos_min * cos_min
    for ti in range(0, h, 4):
        for a in range(4):
            y = py[v0 + min(ti + a, h - 1)]
            for c in range(3):
                row32[a, c] = y * rotation32[c, 1] + rotation32[c, 2]
            row[a] = row_direction(rotation, float(y))
        for tj in range(0, w, 4):
            edge = ti + 4 > h or tj + 4 > w  # a tile with lanes outside the window
            for b in range(4):
                xs[b] = px[u0 + min(tj + b, w - 1)]
            for a in range(4):  # lane 4a + b is pixel (ti + a, tj + b)
                for b in range(4):
                    lane = 4 * a + b
                    valid[lane] = -1 if not edge or (ti + a < h and tj + b < w) else 0
                    for c in range(3):
                        packet[(_DIR + c) * _LANES + lane] = xs[b] * rotation32[c, 0] + row32[a, c]
            for lane in range(_LANES):
                packet[_TFAR * _LANES + lane] = far32
                lanes[_GEOM * _LANES + lane] = _INVALID_ID
            _intersect(intersect16, major, scene, query, valid, packet)
            for lane in range(_LANES):
                if not valid[lane] or lanes[_GEOM * _LANES + lane] == _INVALID_ID:
                    continue
                a, b = lane // 4, lane % 4
                f, t = lanes[_PRIM * _LANES + lane], packet[_TFAR * _LANES + lane]
                x, y = float(px[u0 + tj + b]), float(py[v0 + ti + a])
                r = (row[a, 0], row[a, 1], row[a, 2])
                d = (
                    rotation[0, 0] * x + r[0],
                    rotation[1, 0] * x + r[1],
                    rotation[2, 0] * x + r[2],
                )
                if t < near or not _incidence_ok(packet, lane, d, x * x + y * y + 1.0, cos2):
                    continue
                marks[f // GROUP] = 1
                counts[f] += 1
                if store:
                    pixels[n], faces[n], depth[n] = (ti + a) * w + tj + b, f, t
                    n += 1
    hit, hits = _collect(counts, marks, min(counts.shape[0], h * w))
    return hit, hits, pixels[:n], faces[:n], depth[:n]


@inline
def _collect(counts: np.ndarray, marks: np.ndarray, most: int) -> tuple[np.ndarray, np.ndarray]:
    """The faces (k,) int32 with a nonzero count, ascending, and their counts (k,) int32, at
    most `most` of them; counts (M,) int32 and marks (ceil(M / GROUP),) uint8 are left zero."""
    hit, hits = np.empty(most, np.int32), np.empty(most, np.int32)
    k = 0
    for g in range(marks.shape[0]):
        if marks[g]:
            marks[g] = 0
            for f in range(g * GROUP, min((g + 1) * GROUP, counts.shape[0])):
                if counts[f]:
                    hit[k], hits[k] = f, counts[f]
                    counts[f] = 0
                    k += 1
    return hit[:k].copy(), hits[:k].copy()  # compact: R's columns keep these until assembly
