"""From ray counts to the covering model: V, δ, S (SPEC §3) and the uncoverable faces.

δ_ij = sqrt(R_ij / A_i)                 sampling density of face i from view j (1/mm)
δ_i  = Σ_j δ_ij                         best density reachable with all candidates
S_ij = min(1, δ_ij / δ̄)  if δ_i ≥ δ̄,   else V_ij

With patches (vpp_core.cover.patches), R and A are summed over each patch first and the
rows are patches: a face is coverable when its patch is seen, and it is covered when its
patch's row is. `faces` and `face_row` map rows back to faces either way.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp

from vpp_core.cover.patches import Patches

Formulation = Literal["density", "visibility"]

STRAY_RAYS = 3
"""On patch rows, a view that lands fewer rays than this on a patch does not sample it (a
patch holds about 25 samples at the target density; docs/quality.md has the measurement)."""
MET_RTOL = 1e-9
"""Relative slack on δ ≥ δ̄: absorbs float rounding of sums, far below any physical effect."""


@dataclass(frozen=True, eq=False)
class CoverModel:
    """The rows of the set cover (one per coverable face or patch) and their faces."""

    matrix: sp.csr_array  # (rows, N) float64 in (0, 1]: S or V restricted to coverable rows
    faces: np.ndarray  # (F,) int64 coverable faces, ascending
    face_row: np.ndarray  # (F,) int64 the row of each coverable face
    density_rows: np.ndarray  # (rows,) bool: row demands the target density (else visibility)
    uncoverable: np.ndarray  # (u,) int64 counted faces seen by no candidate

    def row_areas(self, areas: np.ndarray) -> np.ndarray:
        """(rows,) mm²: the areas (M,) of each row's faces, summed."""
        weights = areas[self.faces]
        return np.asarray(
            np.bincount(self.face_row, weights=weights, minlength=self.matrix.shape[0])
        )

    def faces_of(self, rows: np.ndarray) -> np.ndarray:
        """Ascending face ids of the given rows (ids or a (rows,) bool mask)."""
        mask = np.zeros(self.matrix.shape[0], dtype=bool)
        mask[rows] = True
        return np.asarray(self.faces[mask[self.face_row]])


def density_matrix(counts: sp.sparray, areas: np.ndarray) -> sp.csr_array:
    """δ: (M, N) float64 csr, sqrt(R_ij / A_i); rows of zero-area faces are empty."""
    r = sp.csr_array(counts, dtype=np.float64)
    inv_area = np.divide(1.0, areas, out=np.zeros_like(areas, dtype=np.float64), where=areas > 0)
    delta = sp.csr_array(sp.diags_array(inv_area) @ r)
    delta.data = np.sqrt(delta.data)
    delta.eliminate_zeros()
    return delta


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
) -> CoverModel:
    """The covering rows for a target resolution r̄ (mm; one for all, or (M,) each face's own):
    S for `density`, V for `visibility`; per face, or per patch with each counted face taking
    its patch's row (a patch's faces share one target: vpp_core.plan.regions groups them).
    `ignored` (M,) faces get no row (ignored regions; patches hold counted faces only).

    Built on the seen rows' own sparsity pattern, one nnz-sized float array at a time (R of a
    309 k-face, 500-candidate model has 29 M entries, 0.35 GB per float64 CSR copy)."""
    if patches is not None:
        return _patch_model(counts, counted, resolution_mm, formulation, patches)
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
        inv_area = np.divide(1.0, a, out=np.zeros(len(rows)), where=a > 0)
        data = np.repeat(inv_area, per_row)
        np.sqrt(np.multiply(sub.data, data, out=data), out=data)  # δ_ij
        dense_enough = meets(np.add.reduceat(data, sub.indptr[:-1]), 1.0 / res)  # δ_i ≥ 1/r̄_i
        dense_enough &= a > 0
        np.multiply(data, np.repeat(res, per_row), out=data)
        np.minimum(data, 1.0, out=data)  # S_ij = min(1, δ_ij r̄_i)
        data[~np.repeat(dense_enough, per_row)] = 1.0  # V_ij on rows short of δ̄
    matrix = sp.csr_array((data, sub.indices, sub.indptr), shape=sub.shape)
    return CoverModel(matrix, rows, np.arange(len(rows)), dense_enough, uncoverable)


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
    counted: np.ndarray,
    resolution_mm: float | np.ndarray,
    formulation: Formulation,
    patches: Patches,
) -> CoverModel:
    """cover_model on patch rows (summed R and A), stray entries dropped (`stray_free`); the
    faces of patches no candidate samples are uncoverable."""
    per_patch = cover_model(
        stray_free(patches.sum_rows(counts)),
        patches.areas,
        np.ones(patches.count, dtype=bool),
        patch_resolution(patches, resolution_mm),
        formulation,
    )
    row_of_patch = np.full(patches.count, -1, dtype=np.int64)
    row_of_patch[per_patch.faces] = np.arange(len(per_patch.faces))
    face_row = np.where(patches.of_face >= 0, row_of_patch[patches.of_face], -1)
    faces = np.flatnonzero(counted & (face_row >= 0))
    uncoverable = np.flatnonzero(counted & (face_row < 0))
    return CoverModel(per_patch.matrix, faces, face_row[faces], per_patch.density_rows, uncoverable)
