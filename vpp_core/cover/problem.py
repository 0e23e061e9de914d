"""The cover problem min c·y, A y >= 1, y binary, A (M × N) in [0, 1]: input checks, tolerance.

Tolerance: a row counts as covered when its coverage is >= 1 - 1e-9 (`COVER_TOL`); the
covers this package builds reach 1 - BUILD_TOL, a margin so that sums taken in another
order still pass `is_cover`.
"""

from __future__ import annotations

from typing import Any, TypeAlias

import numpy as np
import scipy.sparse as sp

from vpp_core.errors import SolverError

COVER_TOL = 1e-9
"""A row i is covered by y when sum_j A_ij y_j >= 1 - COVER_TOL."""
BUILD_TOL = COVER_TOL / 2
"""Covers built here reach 1 - BUILD_TOL, a margin for summation order."""

SparseLike: TypeAlias = sp.csr_array | sp.csr_matrix


def as_csr(A: Any) -> sp.csr_array:
    """(M, N) canonical float64 CSR copy of A: sorted indices, no duplicates, no stored zeros."""
    if not (sp.issparse(A) or isinstance(A, np.ndarray)):
        raise SolverError(f"coverage matrix must be a scipy sparse array, got {type(A).__name__}")
    if len(A.shape) != 2:
        raise SolverError(f"coverage matrix must be 2-D, got shape {A.shape}")
    csr = sp.csr_array(A, dtype=np.float64, copy=True)
    csr.sum_duplicates()
    csr.eliminate_zeros()
    csr.sort_indices()
    data = csr.data
    if not np.all(np.isfinite(data)):
        raise SolverError("coverage matrix holds NaN or infinite values")
    if data.size and (data.min() < 0.0 or data.max() > 1.0 + COVER_TOL):
        raise SolverError(
            f"coverage coefficients must lie in (0, 1], got [{data.min():g}, {data.max():g}]"
        )
    np.minimum(data, 1.0, out=data)
    csr.indices = csr.indices.astype(np.int64, copy=False)
    csr.indptr = csr.indptr.astype(np.int64, copy=False)
    return csr


def as_costs(costs: np.ndarray | None, n: int) -> np.ndarray:
    """(N,) float64 costs, all finite and > 0; all ones when None."""
    if costs is None:
        return np.ones(n, dtype=np.float64)
    c = np.asarray(costs, dtype=np.float64).reshape(-1)
    if c.shape != (n,):
        raise SolverError(f"costs must have shape ({n},), got {np.shape(costs)}")
    if not np.all(np.isfinite(c)) or (n and c.min() <= 0.0):
        raise SolverError("costs must be finite and > 0")
    return c


def integral_costs(costs: np.ndarray) -> bool:
    """Every cost (N,) is a whole number, so every cover's cost is one too."""
    return bool(np.all(costs == np.floor(costs)))


def check_coverable(A: sp.csr_array) -> None:
    """Raise SolverError when some row of A (M, N) is not covered even by all columns."""
    short = np.flatnonzero(np.asarray(A.sum(axis=1)).reshape(-1) < 1.0 - BUILD_TOL)
    if short.size:
        raise SolverError(
            f"{short.size} of {A.shape[0]} rows cannot be covered even with all "
            f"{A.shape[1]} columns (first: row {int(short[0])})"
        )


def indicator(n: int, selected: np.ndarray) -> np.ndarray:
    """(N,) float64 0/1 vector of the column indices `selected` (K,)."""
    idx = np.asarray(selected, dtype=np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise ValueError(f"selected column index out of range [0, {n})")
    y = np.zeros(n, dtype=np.float64)
    y[idx] = 1.0
    return y


def coverage(A: sp.csr_array, selected: np.ndarray) -> np.ndarray:
    """(M,) row coverage sum_j A_ij y_j of the selected columns (K,)."""
    return np.asarray(A @ indicator(A.shape[1], selected), dtype=np.float64).reshape(-1)


def is_cover(A: SparseLike, selected: np.ndarray, tol: float = COVER_TOL) -> bool:
    """True when every row i of A (M, N) has sum_j A_ij y_j >= 1 - tol for y = selected (K,)."""
    csr = sp.csr_array(A, dtype=np.float64)
    return bool(np.all(coverage(csr, selected) >= 1.0 - tol))


def fewest_partial(A: sp.csr_array, tol: float = COVER_TOL) -> np.ndarray:
    """(M,) per row of A (M, N): the fewest of its fractional entries (< 1 - tol) whose sum
    reaches 1 - tol, the largest first; 0 where all of them together fall short."""
    m = A.shape[0]
    frac = A.data < 1.0 - tol
    rows = np.repeat(np.arange(m), np.diff(A.indptr))[frac]
    vals = A.data[frac]
    order = np.lexsort((-vals, rows))
    rows, vals = rows[order], vals[order]
    starts = np.searchsorted(rows, np.arange(m))
    before = np.concatenate([[0.0], np.cumsum(vals)])
    within = before[1:] - before[starts[rows]]  # running sum inside each row
    rank = np.arange(rows.size) - starts[rows] + 1
    reached = within >= 1.0 - tol
    fewest = np.zeros(m, dtype=np.int64)
    first, at = np.unique(rows[reached], return_index=True)
    fewest[first] = rank[reached][at]
    return fewest


def fractional_rows(A: sp.csr_array, tol: float = COVER_TOL) -> np.ndarray:
    """(K,) int64 rows of A (M, N) holding an entry below 1 - tol (a share of a column)."""
    row_of = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    return np.flatnonzero(np.bincount(row_of[A.data < 1.0 - tol], minlength=A.shape[0]))


def count_rows(A: sp.csr_array, rows: np.ndarray, tol: float = COVER_TOL) -> sp.csr_array:
    """Valid rows that strengthen A's LP relaxation: B (K, N) for the rows (K,) of A (M, N),
    such that every y binary covering row i of A (A_i y >= 1 - tol) has B y >= 1 on its row.
    A row covered without a whole entry (>= 1 - tol) needs at least k of its fractional ones
    (`fewest_partial`), so B holds 1 for a whole entry and 1/k for a fractional one (0 where
    no number of them reaches 1 - tol); on rows without a fractional entry B is A. Where no
    single view covers a patch, A's own row lets two views at half weight cover it in the LP;
    B's row asks for two whole views: a cube's 0.99 cover gets LP bound 3.7 instead of 2.3
    (4 views)."""
    k = fewest_partial(A, tol)
    whole = A.data >= 1.0 - tol
    row_of = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    share = np.divide(1.0, k, out=np.zeros(k.size), where=k > 0)
    B = sp.csr_array((np.where(whole, 1.0, share[row_of]), A.indices, A.indptr), shape=A.shape)
    B = sp.csr_array(B[rows])
    B.eliminate_zeros()
    return B
