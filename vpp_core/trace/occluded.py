"""A ray backend over the part and the setup's occluders (vpp_core.cell.scene): one scene.

The inner backend (any of raster, packets, embree) is built over one mesh: the part's faces
first, then the occluders' (floor quad, fixtures). A ray whose first hit is an occluder is
blocked: it counts for no face, `pixel_hits` drops it and `first_hits` reports it as a miss
(-1), so the candidate checks see a blocked gaze and R holds part faces only. The backends
agree on the combined scene as they do on a part (tests/test_setup.py).
"""

from __future__ import annotations

import numpy as np

from vpp_core.cell.scene import Occluders
from vpp_core.mesh.part import Part
from vpp_core.trace.rays import Block, Hits, PixelHits, RayBackend


def scene_part(part: Part, occluders: Occluders) -> Part:
    """The part with the occluders' triangles appended (ids >= part.n_faces), for tracing
    only: occluder faces are not counted, and their normals are their own."""
    vertices = np.vstack([part.vertices, occluders.vertices])
    faces = np.vstack([part.faces, occluders.faces + len(part.vertices)])
    tri = occluders.vertices[occluders.faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    normals = cross / np.where(norm > 0, norm, 1.0)[:, None]
    n = len(occluders.faces)
    return Part(
        vertices=vertices,
        faces=faces,
        areas=np.concatenate([part.areas, norm / 2]),
        normals=np.vstack([part.normals, normals]),
        counted=np.concatenate([part.counted, np.zeros(n, dtype=bool)]),
        representative=np.concatenate([part.representative, np.arange(n) + part.n_faces]),
        id=f"{part.id}+occluders",
        warnings=part.warnings,
    )


class OccludedBackend:
    """`inner`, built over scene_part(part, occluders), with occluder hits taken as blocked."""

    def __init__(self, inner: RayBackend, n_faces: int) -> None:
        self.inner, self.n_faces = inner, n_faces
        self.name = inner.name
        self.block_rays = inner.block_rays

    def first_hits(
        self, origin: np.ndarray, directions: np.ndarray, t_max: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """Face id (n,) int32 (-1 = miss or blocked by the setup) and t (n,) float32."""
        prim, t = self.inner.first_hits(origin, directions, t_max)
        blocked = prim >= self.n_faces
        if blocked.any():
            prim, t = np.where(blocked, -1, prim).astype(np.int32), t.copy()
            t[blocked] = np.inf
        return prim, t

    def valid_hits(self, block: Block) -> Hits:
        """The inner backend's valid hits on part faces."""
        faces, counts = self.inner.valid_hits(block)
        keep = faces < self.n_faces
        if keep.all():
            return faces, counts
        return faces[keep], None if counts is None else counts[keep]

    def pixel_hits(self, block: Block) -> PixelHits:
        """The inner backend's valid pixel rays that hit part faces."""
        hits = self.inner.pixel_hits(block)
        keep = hits.faces < self.n_faces
        if keep.all():
            return hits
        return PixelHits(hits.pixels[keep], hits.faces[keep], hits.depth[keep])
