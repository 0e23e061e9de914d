"""Exact distances from points to triangle meshes (mm), for the setup's clearances.

Candidate triangles per point come from a KD-tree of triangle centroids (those within
`within` plus the largest centroid-to-corner radius); the distance to each candidate is the
closest point on the triangle by Voronoi regions (Ericson, Real-Time Collision Detection
§5.1.5), vectorised over point-triangle pairs.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

PAIRS_CHUNK = 1 << 20
"""Point-triangle pairs evaluated at a time."""


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(n, 3) closest points on triangles (a, b, c) (n, 3 each) to points p (n, 3)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = _dot(ab, ap), _dot(ac, ap)
    bp = p - b
    d3, d4 = _dot(ab, bp), _dot(ac, bp)
    cp = p - c
    d5, d6 = _dot(ab, cp), _dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    safe = np.where(np.abs(denom) > 1e-300, denom, 1.0)
    v, w = vb / safe, vc / safe
    out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
    cases = [
        ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b, c - b, _ratio(d4 - d3, d5 - d6)),
        ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a, ac, _ratio(d2, -d6)),
        ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a, ab, _ratio(d1, -d3)),
        ((d6 >= 0) & (d5 <= d6), c, np.zeros_like(a), np.zeros(len(a))),
        ((d3 >= 0) & (d4 <= d3), b, np.zeros_like(a), np.zeros(len(a))),
        ((d1 <= 0) & (d2 <= 0), a, np.zeros_like(a), np.zeros(len(a))),
    ]
    for mask, start, edge, t in cases:  # later cases (vertices) take precedence
        out[mask] = start[mask] + edge[mask] * t[mask, None]
    return np.asarray(out)


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.asarray(np.einsum("ij,ij->i", x, y))


def _ratio(num: np.ndarray, other: np.ndarray) -> np.ndarray:
    """num / (num + other), 0 where that is 0/0."""
    den = num + other
    return np.asarray(np.where(np.abs(den) > 1e-300, num / np.where(den == 0, 1.0, den), 0.0))


class MeshDistance:
    """Distances from points to one triangle mesh (vertices (n, 3), faces (m, 3))."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.triangles = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
        self.centroids = self.triangles.mean(axis=1)
        corner = np.linalg.norm(self.triangles - self.centroids[:, None, :], axis=2)
        self.radius = float(corner.max()) if len(corner) else 0.0
        self.tree = cKDTree(self.centroids)

    def __call__(self, points: np.ndarray, within: float) -> np.ndarray:
        """(k,) distance (mm) of each point to the surface: exact where it is <= within,
        else some value > within (inf)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.full(len(points), np.inf)
        near = self.tree.query_ball_point(points, within + self.radius)
        counts = np.array([len(n) for n in near], dtype=np.int64)
        if not counts.sum():
            return out
        pi = np.repeat(np.arange(len(points)), counts)
        ti = np.fromiter((t for n in near for t in n), dtype=np.int64, count=int(counts.sum()))
        for s in range(0, len(pi), PAIRS_CHUNK):
            p, t = points[pi[s : s + PAIRS_CHUNK]], self.triangles[ti[s : s + PAIRS_CHUNK]]
            q = closest_on_triangles(p, t[:, 0], t[:, 1], t[:, 2])
            np.minimum.at(out, pi[s : s + PAIRS_CHUNK], np.linalg.norm(p - q, axis=1))
        out[out > within] = np.inf
        return out
