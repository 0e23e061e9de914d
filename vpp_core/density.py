"""From ray counts to the covering model: V, δ, S (SPEC §3) and the uncoverable faces.

δ_ij = sqrt(R_ij / A_i)                 sampling density of face i from view j (1/mm)
δ_i  = Σ_j δ_ij                         best density reachable with all candidates
S_ij = min(1, δ_ij / δ̄)  if δ_i ≥ δ̄,   else V_ij
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp

Formulation = Literal["density", "visibility"]

MET_RTOL = 1e-9
"""Relative slack on δ ≥ δ̄: absorbs float rounding of sums, far below any physical effect."""


@dataclass(frozen=True, eq=False)
class CoverModel:
    """The rows of the set cover: one per coverable face."""

    matrix: sp.csr_array  # (rows, N) float64 in (0, 1]: S or V restricted to coverable faces
    faces: np.ndarray  # (rows,) int64 face id of each row
    density_rows: np.ndarray  # (rows,) bool: row demands the target density (else visibility)
    uncoverable: np.ndarray  # (u,) int64 counted faces seen by no candidate


def density_matrix(counts: sp.sparray, areas: np.ndarray) -> sp.csr_array:
    """δ: (M, N) float64 csr, sqrt(R_ij / A_i); rows of zero-area faces are empty."""
    r = sp.csr_array(counts, dtype=np.float64)
    inv_area = np.divide(1.0, areas, out=np.zeros_like(areas, dtype=np.float64), where=areas > 0)
    delta = sp.csr_array(sp.diags_array(inv_area) @ r)
    delta.data = np.sqrt(delta.data)
    delta.eliminate_zeros()
    return delta


def meets(density: np.ndarray, target_density: float) -> np.ndarray:
    """(M,) bool: density reaches the target (1/mm), up to MET_RTOL."""
    return density >= target_density * (1 - MET_RTOL)


def cover_model(
    counts: sp.sparray,
    areas: np.ndarray,
    counted: np.ndarray,
    resolution_mm: float,
    formulation: Formulation = "density",
) -> CoverModel:
    """The covering rows for a target resolution r̄ (mm): S for `density`, V for `visibility`."""
    r = sp.csr_array(counts)
    visible = sp.csr_array(r, dtype=np.float64)
    visible.data[:] = 1.0
    seen = np.diff(r.indptr) > 0
    uncoverable = np.flatnonzero(counted & ~seen)
    rows = np.flatnonzero(seen)
    if formulation == "visibility":
        return CoverModel(visible[rows], rows, np.zeros(len(rows), bool), uncoverable)
    target = 1.0 / resolution_mm
    delta = density_matrix(r, areas)
    dense_enough = meets(np.asarray(delta.sum(axis=1)).ravel(), target) & (areas > 0)
    s = delta.multiply(1.0 / target).tocsr()
    s.data = np.minimum(s.data, 1.0)
    matrix = sp.csr_array(sp.diags_array(dense_enough.astype(float)) @ s) + sp.csr_array(
        sp.diags_array((~dense_enough).astype(float)) @ visible
    )
    return CoverModel(sp.csr_array(matrix[rows]), rows, dense_enough[rows], uncoverable)
