"""Embree ray backend: one independent ray per pixel through embreex (Embree 4), checks in numpy."""

from __future__ import annotations

import math

import numpy as np

from vpp_core.mesh.part import Part
from vpp_core.trace.rays import Block, Hits, PixelHits, RayBackend

CHUNK_RAYS = 1 << 18
"""Rays per task: small enough for cache and memory, big enough to amortise Python."""


class EmbreeBackend:
    """Embree 4 (embreex) single-ray intersection, robust (watertight) scene."""

    name = "embree"
    block_rays = CHUNK_RAYS

    def __init__(self, part: Part, robust: bool = True) -> None:
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, part.vertices.astype(np.float32), part.faces.astype(np.int32))
        self._normals = np.ascontiguousarray(part.normals, dtype=np.float32)

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Face id (n,) int32 (-1 = miss) and hit parameter t (n,) float32 of rays from
        `origin` (3,), or from one origin each (n, 3) (vpp_core.cover.access); releases the
        GIL."""
        origins = np.broadcast_to(origin.astype(np.float32), directions.shape)
        out = self._scene.run(origins, directions, dists=float(t_max), output=1)
        return out["primID"], out["tfar"]

    def valid_hits(self, block: Block) -> Hits:
        """One ray per pixel through Embree, the checks in numpy; ids repeat (counts None)."""
        return valid_pixels(self, block, self._normals).faces, None

    def pixel_hits(self, block: Block) -> PixelHits:
        """The block's valid pixel rays one by one: pixel, face and depth."""
        return valid_pixels(self, block, self._normals)


def valid_pixels(backend: RayBackend, block: Block, normals: np.ndarray) -> PixelHits:
    """The valid hits of a block's pixel rays, traced by `first_hits`; tracing stops at
    t = far, which is exact (a first hit beyond far is invalid whatever lies behind it).

    `normals` (M, 3) float32 are the part's, converted once. No BLAS here: a float32 matmul
    from a worker thread wakes OpenBLAS's own thread pool, whose spinning threads fight the
    tracer for the cores.
    """
    sensor, (v0, v1), (u0, u1) = block.sensor, block.rows, block.cols
    directions = block_directions(block)
    norms = sensor.camera_ray_norms[v0:v1, u0:u1]
    prim, depth = backend.first_hits(block.position, directions, sensor.far_mm)
    hit = np.flatnonzero(prim >= 0)
    prim, depth = prim[hit], depth[hit]
    # take(axis=0) is several times faster than fancy indexing of (n, 3) rows
    cos = np.einsum("ij,ij->i", normals.take(prim, axis=0), directions.take(hit, axis=0))
    cos_min = math.cos(math.radians(sensor.max_incidence_deg))
    ok = (depth >= sensor.near_mm) & (np.abs(cos, out=cos) >= cos_min * norms.reshape(-1)[hit])
    return PixelHits(hit[ok], np.asarray(prim[ok]), depth[ok])


def block_directions(block: Block) -> np.ndarray:
    """(h*w, 3) float32 world directions (x, y, 1) of a block's pixel rays, row-major."""
    rotation = block.rotation.astype(np.float32)
    (v0, v1), (u0, u1) = block.rows, block.cols
    xs, ys = block.sensor.pixel_x[u0:u1], block.sensor.pixel_y[v0:v1]
    # x*X + y*Y + Z, built plane by plane
    out = np.empty((v1 - v0, u1 - u0, 3), dtype=np.float32)
    for k in range(3):
        np.add(
            (ys * rotation[k, 1] + rotation[k, 2])[:, None],
            (xs * rotation[k, 0])[None, :],
            out=out[..., k],
        )
    return out.reshape(-1, 3)
