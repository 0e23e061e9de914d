"""Surface patches: the rows of the default cover, pieces of surface of about one patch area.

A face counts as sampled when pixel rays land on it; on a mesh whose faces are smaller than a
pixel's footprint that is luck, and on a CAD export the faces are slivers of any size. The
default cover therefore asks for the target density on *patches*: counted faces grouped by
where they are and which way they face, each patch about `edge_mm` across (R of a patch is the
sum of its faces' R, its area the sum of their areas: δ_pj = sqrt(R_pj / A_p)).

The edge is PATCH_TARGETS · r̄ (5.8 mm at 0.18 mm): at the default stand-off (a pixel covers
r̄ / 1.2) a patch is about 38 pixels across, 1/50 of the paper camera's image, so one view's
density varies over it by a few per cent except where a shadow edge crosses it, and the rows
stay few enough for the cover to be solved well (docs/quality.md measures 5 r̄ against it).
Small parts get at least MIN_PATCHES patches (not below MIN_PATCH_TARGETS · r̄ across), large
ones at most MAX_PATCHES.

Grouping: each face's normal is smoothed over the faces within SMOOTH_TARGETS · r̄ (not the
patch's size: a small hole's wall must keep its own direction) that face the same side
(area-weighted, SMOOTH_PASSES times), so that a scan's noisy normals do not scatter a smooth
surface; the faces of each normal bin (the nearest of the 26 directions of a cube's faces,
edges and corners, so opposite sides of a thin wall never share a patch) get seeds at least
SEED_SPACING · `edge_mm` apart (largest faces first), and each face joins its bin's nearest
seed. A face larger than a patch is a patch of its own. Given the faces' corners, a patch
is then split into its connected pieces (faces sharing a corner), so that a hole's wall or a
pocket's floor never shares a row with the outer surface that faces the same way: each piece
must be sampled itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from vpp_core.jit import kernel

SMOOTH_NEIGHBOURS = 16
"""Nearest faces a face's normal is smoothed over (within the smoothing radius)."""
SMOOTH_TARGETS = 2.5
"""Smoothing radius in target lengths r̄ (0.45 mm at 0.18 mm)."""
SMOOTH_PASSES = 3
"""Smoothing passes: a scan's noisy normals (turbineblade.ply) need about three to group its
smooth surface into whole patches (1 pass: 17 views, 3 passes: 11; docs/quality.md)."""
SEED_SPACING = 0.7
"""Least seed distance / edge: greedy seeds at least s apart leave Voronoi patches of about
2.1 s² (measured on a plate), so 0.7 edge gives patches of about edge² on average."""
PATCH_TARGETS = 32.0
"""Patch edge in target lengths r̄ (about 1 000 target samples per patch)."""
MIN_PATCH_TARGETS = 5.0
"""Patch edge in target lengths at least (about 25 target samples), on small parts too."""
MIN_PATCHES = 1_000
"""Patches at least, where the edge may shrink to MIN_PATCH_TARGETS · r̄ to give them."""
MAX_PATCHES = 100_000
"""Patches at most: on a large part the edge grows so that rows stay within this."""

_AXES = np.array([(x, y, z) for x in (-1, 0, 1) for y in (-1, 0, 1) for z in (-1, 0, 1)])
DIRECTIONS = _AXES[np.abs(_AXES).sum(axis=1) > 0] / np.linalg.norm(
    _AXES[np.abs(_AXES).sum(axis=1) > 0], axis=1, keepdims=True
)
"""(26, 3) unit normal bins."""


@dataclass(frozen=True, eq=False)
class Patches:
    """A grouping of a part's counted faces into patches."""

    of_face: np.ndarray  # (M,) int64 patch of each face, -1 for faces not counted
    areas: np.ndarray  # (P,) float64 patch areas, mm²
    edge_mm: float  # the patch size asked for, mm
    centres: np.ndarray  # (P, 3) float64 area-weighted centres of the patches' faces, mm
    normals: np.ndarray  # (P, 3) float64 unit area-weighted mean normals of their faces

    @property
    def count(self) -> int:
        """Number of patches P."""
        return len(self.areas)

    def indicator(self) -> sp.csr_array:
        """(P, M) 0/1 matrix: row p holds the faces of patch p."""
        faces = np.flatnonzero(self.of_face >= 0)
        data = np.ones(len(faces))
        shape = (self.count, len(self.of_face))
        return sp.csr_array((data, (self.of_face[faces], faces)), shape=shape)

    def sum_rows(self, counts: sp.sparray) -> sp.csr_array:
        """(P, N) int64 ray counts per patch: the sums of its faces' rows of R (M, N).

        Computed as (Rᵀ Iᵀ)ᵀ: R traced by columns (csc) is Rᵀ by rows, so it is multiplied
        as it is, not first converted (0.93 -> 0.34 s for 27 M entries)."""
        total = (counts.T @ self.indicator().T).T
        return sp.csr_array(total, dtype=np.int64)

    def faces_of(self, patch_ids: np.ndarray) -> np.ndarray:
        """Sorted face ids of the given patches."""
        mask = np.zeros(self.count + 1, dtype=bool)
        mask[np.asarray(patch_ids, dtype=np.int64)] = True
        return np.flatnonzero(mask[self.of_face])


def patch_edge(resolution_mm: float, counted_area_mm2: float) -> float:
    """Patch edge (mm) for target r̄ (mm) on a counted area (mm²): PATCH_TARGETS · r̄, smaller
    where that gives fewer than MIN_PATCHES (never below MIN_PATCH_TARGETS · r̄), larger where
    it gives more than MAX_PATCHES."""
    edge = min(PATCH_TARGETS * resolution_mm, np.sqrt(counted_area_mm2 / MIN_PATCHES))
    edge = max(edge, MIN_PATCH_TARGETS * resolution_mm)
    return float(max(edge, np.sqrt(counted_area_mm2 / MAX_PATCHES)))


def make_patches(
    centres: np.ndarray,
    normals: np.ndarray,
    areas: np.ndarray,
    counted: np.ndarray,
    edge_mm: float,
    smooth_mm: float | None = None,
    corners: np.ndarray | None = None,
    groups: np.ndarray | None = None,
    group_edges: np.ndarray | None = None,
) -> Patches:
    """Group counted faces ((M, 3) centres and unit normals, (M,) areas mm²) into patches
    about `edge_mm` across, normals smoothed within `smooth_mm` (default half an edge), each
    patch split into connected pieces where the faces' (M, 3) vertex ids `corners` are given;
    with `groups` ((M,) int, 0..G-1), faces of different groups (regions with their own
    target) never share a patch, and group g's patches are `group_edges[g]` mm across."""
    radius = edge_mm / 2 if smooth_mm is None else smooth_mm
    of_face = np.full(len(centres), -1, dtype=np.int64)
    smooth = np.zeros_like(normals)
    smooth[counted] = smoothed(centres[counted], normals[counted], areas[counted], radius)
    bins = np.argmax(smooth @ DIRECTIONS.T, axis=1)
    if groups is not None:
        bins = bins + len(DIRECTIONS) * np.asarray(groups, dtype=np.int64)
    edges = np.full(1, edge_mm) if group_edges is None else np.asarray(group_edges)
    next_id = 0
    for b in np.unique(bins[counted]):
        faces = np.flatnonzero(counted & (bins == b))
        edge = float(edges[min(b // len(DIRECTIONS), len(edges) - 1)])
        seeds = _seeds(centres[faces], areas[faces], SEED_SPACING * edge)
        _, nearest = cKDTree(centres[faces][seeds]).query(centres[faces], workers=-1)
        of_face[faces] = next_id + np.asarray(nearest, dtype=np.int64)
        next_id += len(seeds)
    if corners is not None:
        of_face[counted] = connected_pieces(corners[counted], of_face[counted])
    used, of_face[counted] = np.unique(of_face[counted], return_inverse=True)
    patch_areas = np.bincount(of_face[counted], weights=areas[counted], minlength=len(used))
    mean_centres, mean_normals = _means(
        of_face[counted], areas[counted], centres[counted], normals[counted], len(used)
    )
    return Patches(of_face, patch_areas, edge_mm, mean_centres, mean_normals)


def _means(
    of_face: np.ndarray, areas: np.ndarray, centres: np.ndarray, normals: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) area-weighted centres (mm) and unit mean normals of the patches `of_face` (K,)
    of K faces with areas (K,) mm², centres and unit normals (K, 3)."""
    w = areas + 1e-300
    total = np.bincount(of_face, weights=w, minlength=count)[:, None]
    c = np.column_stack(
        [np.bincount(of_face, w * centres[:, k], minlength=count) for k in range(3)]
    )
    n = np.column_stack(
        [np.bincount(of_face, w * normals[:, k], minlength=count) for k in range(3)]
    )
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return c / np.maximum(total, 1e-300), n / np.maximum(norm, 1e-300)


def connected_pieces(corners: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(K,) int64 new labels: faces (K, 3 vertex ids) of one label that share a corner,
    directly or through other faces of that label, keep one label; other pieces get new ones."""
    k = len(labels)
    if k == 0:
        return labels.astype(np.int64)
    # faces and (vertex, label) nodes: a face joins the node of each corner with its own label
    key = corners.reshape(-1).astype(np.int64) * (int(labels.max()) + 1) + np.repeat(labels, 3)
    _, node = np.unique(key, return_inverse=True)
    n_nodes = int(node.max()) + 1
    face = np.repeat(np.arange(k), 3)
    graph = sp.coo_array((np.ones(3 * k), (face, k + node.reshape(-1))), shape=(k + n_nodes,) * 2)
    _, component = connected_components(graph, directed=False)
    return np.asarray(component[:k], dtype=np.int64)


def smoothed(
    centres: np.ndarray,
    normals: np.ndarray,
    areas: np.ndarray,
    radius: float,
    passes: int = SMOOTH_PASSES,
) -> np.ndarray:
    """(M, 3) normals averaged (area-weighted) over the SMOOTH_NEIGHBOURS nearest faces within
    `radius` mm whose normal points to the same side, `passes` times (each pass averages the
    last one's); a face keeps its normal where they cancel. The neighbours are found once."""
    k = min(SMOOTH_NEIGHBOURS, len(centres))
    dist, idx = cKDTree(centres).query(centres, k=k, distance_upper_bound=radius, workers=-1)
    found = np.isfinite(dist)
    idx = np.where(found, idx, np.arange(len(centres))[:, None])
    weights = found * areas[idx]
    for _ in range(passes):
        normals = _averaged(normals, idx, weights, 1e-9 * areas.max())
    return normals


@kernel
def _averaged(normals: np.ndarray, idx: np.ndarray, weights: np.ndarray, tiny: float) -> np.ndarray:
    """(M, 3) one smoothing pass: each normal the `weights`-weighted (M, k) mean of its
    neighbours' `idx` (M, k) that point to its side; its own where the sum's norm is below
    `tiny`."""
    out = np.empty_like(normals)
    for m in range(len(normals)):
        n0, n1, n2 = normals[m, 0], normals[m, 1], normals[m, 2]
        t0 = t1 = t2 = 0.0
        for k in range(idx.shape[1]):
            j = idx[m, k]
            a0, a1, a2 = normals[j, 0], normals[j, 1], normals[j, 2]
            if a0 * n0 + a1 * n1 + a2 * n2 > 0.0:
                w = weights[m, k]
                t0, t1, t2 = t0 + w * a0, t1 + w * a1, t2 + w * a2
        t0, t1, t2 = t0 + n0 * 1e-12, t1 + n1 * 1e-12, t2 + n2 * 1e-12
        norm = np.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
        if norm > tiny:
            out[m, 0], out[m, 1], out[m, 2] = t0 / norm, t1 / norm, t2 / norm
        else:
            out[m, 0], out[m, 1], out[m, 2] = n0, n1, n2
    return out


def _seeds(centres: np.ndarray, areas: np.ndarray, edge_mm: float) -> np.ndarray:
    """Indices of face centres at least `edge_mm` apart, largest faces first: the largest face
    of each cube of side edge/2, thinned greedily."""
    cells = np.floor((centres - centres.min(axis=0)) / (edge_mm / 2)).astype(np.int64)
    span = cells.max(axis=0) + 1
    key = (cells[:, 0] * span[1] + cells[:, 1]) * span[2] + cells[:, 2]  # the cube's number
    order = np.argsort(-areas, kind="stable")
    _, first = np.unique(key[order], return_index=True)
    picks = order[np.sort(first)]  # one per cube, the larger faces' cubes first
    pairs = cKDTree(centres[picks]).query_pairs(edge_mm, output_type="ndarray").reshape(-1, 2)
    lo, hi = pairs.min(axis=1), pairs.max(axis=1)
    sort = np.argsort(hi, kind="stable")
    return np.asarray(picks[_greedy_alive(len(picks), lo[sort], hi[sort])])


@kernel
def _greedy_alive(n: int, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(n,) bool: point i survives unless an earlier survivor lo[k] is its neighbour (pairs
    (lo[k] < hi[k]) sorted by hi)."""
    alive = np.ones(n, dtype=np.bool_)
    k = 0
    for i in range(n):
        while k < len(hi) and hi[k] == i:
            if alive[lo[k]]:
                alive[i] = False
            k += 1
    return alive
