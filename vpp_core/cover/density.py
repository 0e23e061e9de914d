"""From ray counts to the covering model: V, δ, S (SPEC §3) and the uncoverable faces.

δ_ij = sqrt(R_ij / A_i)                 sampling density of face i from view j (1/mm)
δ_i  = Σ_j δ_ij                         best density reachable with all candidates
S_ij = min(1, δ_ij / δ̄)  if δ_i ≥ δ̄,   else V_ij

With patches (vpp_core.cover.patches), R and A are summed over each patch first and the
rows are patches: a face is coverable when its patch is seen, and it is covered when its
patch's row is. `faces` and `face_row` map rows back to faces either way.

Given the cameras, a patch row also counts how much of the patch a view samples: R_pj rays
where the view's pixels would put ρ_pj per mm² on the whole patch (its distance, incidence
and place in the image) sample the share f_pj = min(1, R_pj / (ρ_pj A_p)) of it, at density
sqrt(R_pj / (f_pj A_p)). A patch asks for what its best candidate samples of it, u_p =
max_j f_pj (all of it where one view sees it whole), and a view covers its part of that:
S_pj = min(1, f_pj / u_p · min(1, r̄ sqrt(R_pj / (f_pj A_p)))). A view that sees a third of a
patch that another view sees whole, or of a large CAD facet that is a patch of its own,
covers a third of its row, however fine its pixels there (f = u = 1 gives SPEC §3's S;
docs/quality.md, stage 3b). A view that samples as much as the best one but for the pixel
grid (R_pj ≥ u_p N - 2 sqrt(N), N = ρ_pj A_p: a row of pixels along each side) covers the row
whole: the grid's aliasing does not decide between views.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import scipy.sparse as sp

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cover.patches import Patches

Formulation = Literal["density", "visibility"]

STRAY_RAYS = 3
"""On patch rows, a view that lands fewer rays than this on a patch does not sample it (a
patch holds about 25 samples at the target density; docs/quality.md has the measurement)."""
MET_RTOL = 1e-9
"""Relative slack on δ ≥ δ̄: absorbs float rounding of sums, far below any physical effect."""
GRID = 2.0
"""A view whose rays on a patch fall short of what the patch's best view samples of it (u_p N,
N the rays its pixels would put on the whole patch) by at most GRID · sqrt(N) samples as much:
the pixel grid gains or drops up to a row of pixels along each side of a patch (a square s
pixels a side holds (s - 1)² to (s + 1)² pixel centres); docs/quality.md, stage 3b."""
MIN_DEPTH_MM = 1e-6
"""Least depth (mm) a patch centre is given in Cameras.ray_density: a patch larger than the
stand-off (a part many metres across, its elements capped at MAX_ELEMENTS) can have its
centre beside or behind a view that lands rays on it; there the density is taken as huge
(the view samples a vanishing share) instead of dividing by zero (session 61)."""


@dataclass(frozen=True, eq=False)
class CoverModel:
    """The rows of the set cover (one per coverable face, patch or piece of a patch) and the
    faces they are made of: pairs (faces[k], face_row[k]) with the area areas[k] the face
    brings to that row (a face split into elements may lie in several rows)."""

    matrix: sp.csr_array  # (rows, N) float64 in (0, 1]: S or V restricted to coverable rows
    faces: np.ndarray  # (K,) int64 coverable faces, ascending (repeated per row they lie in)
    face_row: np.ndarray  # (K,) int64 the row of each pair
    density_rows: np.ndarray  # (rows,) bool: row demands the target density (else visibility)
    uncoverable: np.ndarray  # (u,) int64 counted faces seen by no candidate
    areas: np.ndarray  # (K,) float64 mm²: what each pair's face brings to its row
    recessed: np.ndarray | None = None  # (rows,) bool: recessed patches (vpp_core.cover.access)
    reach: np.ndarray | None = None  # (rows,) u_p in (0, 1]: the share its best candidate samples

    def seen_rows(self) -> sp.csr_array:
        """(rows, N) 1 where a view samples a row (STRAY_RAYS rays or more on it, the entries
        of `matrix`), at whatever density."""
        pattern = sp.csr_array(self.matrix, copy=True)
        pattern.eliminate_zeros()  # a stored zero samples nothing
        pattern.data[:] = 1.0
        return pattern

    def row_areas(self) -> np.ndarray:
        """(rows,) mm²: the areas of each row's faces, summed."""
        rows = self.matrix.shape[0]
        return np.asarray(np.bincount(self.face_row, weights=self.areas, minlength=rows))

    def row_weights(self) -> np.ndarray:
        """(rows,) mm²: what each row weighs in a partial cover, the area that can be sampled
        of it (its area times `reach`, where the rows are patches sampled in shares), none for
        a recessed row (vpp_core.cover.access)."""
        area = self.row_areas()
        if self.reach is not None:
            area = area * self.reach
        return area if self.recessed is None else np.where(self.recessed, 0.0, area)

    def faces_of(self, rows: np.ndarray) -> np.ndarray:
        """Ascending distinct face ids of the given rows (ids or a (rows,) bool mask)."""
        mask = np.zeros(self.matrix.shape[0], dtype=bool)
        mask[rows] = True
        return np.unique(self.faces[mask[self.face_row]])

    def lifted(self, parent: np.ndarray) -> CoverModel:
        """This model of elements as one of the faces `parent` (E,) they lie in: the same rows,
        the pairs (parent face, row) with the elements' areas."""
        faces = parent[self.faces]
        order = np.argsort(faces, kind="stable")
        coverable = np.unique(faces)
        uncoverable = np.setdiff1d(np.unique(parent[self.uncoverable]), coverable)
        return replace(
            self,
            faces=faces[order],
            face_row=self.face_row[order],
            areas=self.areas[order],
            uncoverable=uncoverable,
        )


@dataclass(frozen=True, eq=False)
class Cameras:
    """The candidates R was traced from: where each stands and how fine its pixels are."""

    views: Viewpoints
    sensor: Sensor

    def ray_density(self, points: np.ndarray, normals: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(K,) rays per mm² that view cols[k] casts on a plane through points[k] (K, 3) mm
        with unit normal normals[k] (K, 3): cos θ fx fy / (z² cos α), z the depth, α the
        ray's angle off the optical axis, θ its incidence."""
        d = points - self.views.positions[cols]
        r = np.maximum(np.linalg.norm(d, axis=1), MIN_DEPTH_MM)
        z = np.maximum(np.einsum("kj,kj->k", d, self.views.gazes[cols]), MIN_DEPTH_MM)
        cos_theta = np.abs(np.einsum("kj,kj->k", d, normals)) / r
        fxy = self.sensor.fx * self.sensor.fy
        return np.asarray(cos_theta * fxy * r / z**3)  # z² cos α = z³ / r


def seen_share(counts: sp.csr_array, patches: Patches, cameras: Cameras) -> np.ndarray:
    """(nnz,) share f_pj of patch p that view j samples, for each entry of the patch R
    `counts` (P, N): min(1, R_pj / (ρ_pj A_p)), ρ_pj the view's ray density on the patch's
    plane (Cameras.ray_density at its centre and mean normal); the patch's largest share u_p
    where R_pj falls short of u_p N by at most GRID · sqrt(N) rays (N = ρ_pj A_p)."""
    per_row = np.diff(counts.indptr)
    rows = np.repeat(np.arange(counts.shape[0]), per_row)
    rho = cameras.ray_density(patches.centres[rows], patches.normals[rows], counts.indices)
    whole = rho * patches.areas[rows]
    share = np.minimum(np.divide(counts.data, whole, out=np.ones(len(rows)), where=whole > 0), 1)
    best = np.repeat(reach(counts.indptr, share), per_row)
    grid = counts.data >= best * whole - GRID * np.sqrt(whole)  # as much, but for the grid
    return np.asarray(np.where(grid, best, share))


def density_sum(r: sp.csc_array, areas: np.ndarray) -> np.ndarray:
    """(M,) Σ_j δ_ij over the columns of R (M, N) csc: the sampling density sqrt(rays/mm²) the
    views add up on each face (areas (M,) mm²; 0 on faces of zero area), in one pass over R's
    entries with no copy of R by rows (the metrics' sums on the fine coupling stand-in's
    26.5 M entries: 0.47 s, where δ as a csr matrix and its row sums took 1.4-3.2 s)."""
    inv_area = np.divide(1.0, areas, out=np.zeros_like(areas, dtype=np.float64), where=areas > 0)
    rows = r.indices
    delta = np.sqrt(r.data.astype(np.float64) * inv_area[rows])
    return np.bincount(rows, weights=delta, minlength=r.shape[0])


def meets(density: np.ndarray, target_density: float | np.ndarray) -> np.ndarray:
    """(M,) bool: density reaches the target (1/mm: one, or (M,) each its own), up to MET_RTOL."""
    return density >= target_density * (1 - MET_RTOL)


def cover_model(
    counts: sp.sparray,
    areas: np.ndarray,
    counted: np.ndarray,
    resolution_mm: float | np.ndarray,
    formulation: Formulation = "density",
    patches: Patches | None = None,
    ignored: np.ndarray | None = None,
    cameras: Cameras | None = None,
    share: np.ndarray | None = None,
    recessed: np.ndarray | None = None,
) -> CoverModel:
    """The covering rows for a target resolution r̄ (mm; one for all, or (M,) each face's own):
    S for `density`, V for `visibility`; per face, or per patch with each counted face taking
    its patch's row (a patch's faces share one target: vpp_core.plan.regions groups them).
    `ignored` (M,) faces get no row (ignored regions; patches hold counted faces only).
    On patches with the `cameras` of R's columns, S counts the share of each patch a view
    samples (module docstring); `share` (nnz,) gives it per entry of `counts` directly.
    `recessed` (P,) bool marks the patches a partial cover gives no weight
    (vpp_core.cover.access).

    Built on the seen rows' own sparsity pattern, one nnz-sized float array at a time (R of a
    309 k-face, 500-candidate model has 29 M entries, 0.35 GB per float64 CSR copy)."""
    if patches is not None:
        return _patch_model(
            counts, areas, counted, resolution_mm, formulation, patches, cameras, recessed
        )
    r = sp.csr_array(counts)
    seen = np.diff(r.indptr) > 0
    uncoverable = np.flatnonzero(counted & ~seen)
    rows = np.flatnonzero(seen if ignored is None else seen & ~ignored)
    sub = sp.csr_array(r[rows])
    per_row = np.diff(sub.indptr)
    if formulation == "visibility":
        data, dense_enough = np.ones(sub.nnz), np.zeros(len(rows), bool)
    else:
        a = areas[rows]
        res = np.broadcast_to(np.asarray(resolution_mm, dtype=np.float64), areas.shape)[rows]
        data = s_entries(sub, a, res, None if share is None else share[_entries(r, rows)])
        dense_enough = meets(np.add.reduceat(data, sub.indptr[:-1]), 1.0)  # reachable: Σ S ≥ 1
        dense_enough &= a > 0
        data[~np.repeat(dense_enough, per_row)] = 1.0  # V_ij on rows short of δ̄
    matrix = sp.csr_array((data, sub.indices, sub.indptr), shape=sub.shape)
    pairs = np.arange(len(rows))
    return CoverModel(matrix, rows, pairs, dense_enough, uncoverable, areas[rows])


def s_entries(
    counts: sp.csr_array, areas: np.ndarray, resolution_mm: np.ndarray, share: np.ndarray | None
) -> np.ndarray:
    """(nnz,) S_ij of each entry of R `counts` (rows, N) csr, for rows of `areas` (rows,) mm²
    and targets r̄ (rows,) mm: min(1, r̄ sqrt(R_ij / A_i)), or with the sampled `share` f
    (nnz,) min(1, f_ij / u_i · min(1, r̄ sqrt(R_ij / (f_ij A_i)))), u_i = max_j f_ij the
    share of the row its best view samples (the module docstring)."""
    per_row = np.diff(counts.indptr)
    inv_area = np.divide(1.0, areas, out=np.zeros(len(areas)), where=areas > 0)
    data = np.repeat(inv_area, per_row)
    np.multiply(counts.data, data, out=data)  # R_ij / A_i
    if share is not None:  # the rays fall on the share f_ij of the row (none: S_ij = 0)
        data = np.divide(data, share, out=np.zeros_like(data), where=share > 0)
    np.sqrt(data, out=data)  # δ_ij
    np.multiply(data, np.repeat(resolution_mm, per_row), out=data)
    np.minimum(data, 1.0, out=data)  # min(1, δ_ij r̄_i)
    if share is not None:  # f_ij / u_i; a row no view samples any share of gets none
        best = np.repeat(reach(counts.indptr, share), per_row)
        np.multiply(data, np.divide(share, best, out=np.zeros_like(share), where=best > 0), data)
        np.minimum(data, 1.0, out=data)
    return data


def reach(indptr: np.ndarray, share: np.ndarray) -> np.ndarray:
    """(rows,) u_i: the largest share (nnz,) of each row of a csr with `indptr` (1 where the
    row is empty)."""
    out = np.ones(len(indptr) - 1)
    full = np.diff(indptr) > 0
    out[full] = np.maximum.reduceat(share, indptr[:-1][full])
    return out


def _patch_counts(
    counts: sp.sparray, patches: Patches, cameras: Cameras | None
) -> tuple[sp.csr_array, np.ndarray | None]:
    """The patch R (P, N) from the face R `counts` (M, N), stray entries dropped, indices
    sorted, and the share (nnz,) each entry samples where the `cameras` are given."""
    r = stray_free(patches.sum_rows(counts))
    r.sort_indices()
    return r, None if cameras is None else seen_share(r, patches, cameras)


def _entries(r: sp.csr_array, rows: np.ndarray) -> np.ndarray:
    """Positions in r.data (r canonical csr) of the entries of `rows`, in order."""
    starts, ends = r.indptr[rows], r.indptr[rows + 1]
    lengths = ends - starts
    offsets = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
    return np.asarray(np.repeat(starts, lengths) + offsets)


def stray_free(counts: sp.csr_array) -> sp.csr_array:
    """R (rows, N) without the entries of fewer than STRAY_RAYS rays: stray rays grazing a
    patch, which sample nothing of it."""
    r = sp.csr_array(counts)
    r.data = np.where(r.data >= STRAY_RAYS, r.data, 0)
    r.eliminate_zeros()
    return r


def patch_resolution(patches: Patches, resolution_mm: float | np.ndarray) -> np.ndarray:
    """(P,) target resolution of each patch (mm): its faces' (one for all, or (M,) per face;
    the faces of a patch share one)."""
    per_face = np.broadcast_to(np.asarray(resolution_mm, dtype=np.float64), patches.of_face.shape)
    out = np.zeros(patches.count)
    mine = patches.of_face >= 0
    out[patches.of_face[mine]] = per_face[mine]
    return out


def _patch_model(
    counts: sp.sparray,
    areas: np.ndarray,
    counted: np.ndarray,
    resolution_mm: float | np.ndarray,
    formulation: Formulation,
    patches: Patches,
    cameras: Cameras | None,
    recessed: np.ndarray | None = None,
) -> CoverModel:
    """cover_model on patch rows (summed R and A; face areas (M,) mm²), stray entries dropped
    (`stray_free`), with the share each view samples where the `cameras` are given and the
    `recessed` (P,) patches marked; the faces of patches no candidate samples are
    uncoverable."""
    r, share = _patch_counts(counts, patches, cameras)
    per_patch = cover_model(
        r,
        patches.areas,
        np.ones(patches.count, dtype=bool),
        patch_resolution(patches, resolution_mm),
        formulation,
        share=share,
    )
    row_of_patch = np.full(patches.count, -1, dtype=np.int64)
    row_of_patch[per_patch.faces] = np.arange(len(per_patch.faces))
    face_row = np.where(patches.of_face >= 0, row_of_patch[patches.of_face], -1)
    faces = np.flatnonzero(counted & (face_row >= 0))
    uncoverable = np.flatnonzero(counted & (face_row < 0))
    rows = face_row[faces]
    marked = None if recessed is None else np.asarray(recessed)[per_patch.faces]
    u = None if share is None else reach(r.indptr, share)[per_patch.faces]
    return CoverModel(
        per_patch.matrix, faces, rows, per_patch.density_rows, uncoverable, areas[faces], marked, u
    )
