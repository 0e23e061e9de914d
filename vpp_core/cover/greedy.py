"""Greedy covers of min c·y, A y >= 1, y binary (A in [0, 1], M × N), and redundancy removal."""

from __future__ import annotations

import heapq
from collections.abc import Callable, Iterator

import numpy as np
import scipy.sparse as sp

from vpp_core.cover.problem import (
    BUILD_TOL,
    COVER_TOL,
    SparseLike,
    as_costs,
    as_csr,
    check_coverable,
    coverage,
)
from vpp_core.errors import SolverError


def lazy_picks(n: int, costs: np.ndarray, gain: Callable[[int], float]) -> Iterator[int]:
    """Columns 0..n-1 in greedy order of gain(j) / costs[j], lowest j on ties, evaluated
    lazily: the caller updates what `gain` reads after each pick, and gains may only fall, so
    a heap of stale values is re-checked at its top only. Ends when no column gains."""
    heap = [(-g / costs[j], j) for j in range(n) if (g := gain(j)) > 0.0]
    heapq.heapify(heap)
    while heap:
        _, j = heapq.heappop(heap)
        g = gain(j)  # scores only decrease: the popped key is an upper bound
        if g <= 0.0:
            continue
        key = (-g / costs[j], j)
        if heap and key > heap[0]:
            heapq.heappush(heap, key)
            continue
        yield j


def lazy_greedy(csc: sp.csc_array, costs: np.ndarray, r: np.ndarray) -> list[int]:
    """Columns of csc (M, N) picked greedily until residual demand r (M,) is 0 (r is updated)."""
    ip, ix, dv = csc.indptr, csc.indices, csc.data
    r[r <= BUILD_TOL] = 0.0

    def gain(j: int) -> float:
        s = slice(ip[j], ip[j + 1])
        return float(np.minimum(r[ix[s]], dv[s]).sum())

    picks = lazy_picks(csc.shape[1], costs, gain)
    uncovered, picked = int(np.count_nonzero(r)), []
    while uncovered and (j := next(picks, None)) is not None:
        rows = ix[ip[j] : ip[j + 1]]
        new = r[rows] - dv[ip[j] : ip[j + 1]]
        new[new <= BUILD_TOL] = 0.0
        uncovered -= int(np.count_nonzero((r[rows] > 0.0) & (new == 0.0)))
        r[rows] = new
        picked.append(j)
    if uncovered:
        raise SolverError(f"{uncovered} rows cannot be covered even with all columns")
    return picked


def complete_cover(A: sp.csr_array, costs: np.ndarray, selected: np.ndarray) -> np.ndarray:
    """(K',) sorted cover of A (M, N): `selected` (K,) + greedy columns, redundancy removed."""
    r = np.maximum(0.0, 1.0 - coverage(A, selected))
    extra = lazy_greedy(sp.csc_array(A), costs, r)
    union = np.union1d(np.asarray(selected, dtype=np.int64), np.asarray(extra, dtype=np.int64))
    return prune_cover(A, union, costs)


def greedy_cover(A: SparseLike, costs: np.ndarray | None = None) -> np.ndarray:
    """(K,) int64 sorted cover of A (M, N): cost-effectiveness greedy + redundancy removal."""
    csr = as_csr(A)
    c = as_costs(costs, csr.shape[1])
    check_coverable(csr)
    return complete_cover(csr, c, np.zeros(0, dtype=np.int64))


def prune_cover(A: sp.csr_array, sel: np.ndarray, costs: np.ndarray) -> np.ndarray:
    """(K',) sorted subset of cover `sel` (K,) of A (M, N) with no column droppable on its own."""
    sel = np.unique(np.asarray(sel, dtype=np.int64))
    cov = coverage(A, sel)
    if np.any(cov < 1.0 - COVER_TOL):
        raise ValueError("remove_redundant needs a cover; some rows are not covered")
    csc = sp.csc_array(A[:, sel]) if sel.size else sp.csc_array(A.shape, dtype=np.float64)
    useful = np.asarray(csc.sum(axis=0)).reshape(-1)
    keep = np.ones(sel.size, dtype=bool)
    for k in np.lexsort((-sel, useful, -costs[sel])):  # expensive, least useful, highest j first
        s = slice(csc.indptr[k], csc.indptr[k + 1])
        rows, vals = csc.indices[s], csc.data[s]
        left = cov[rows] - vals
        if np.all(left >= 1.0 - BUILD_TOL):
            cov[rows] = left
            keep[k] = False
    return sel[keep]


def remove_redundant(
    A: SparseLike, selected: np.ndarray, costs: np.ndarray | None = None
) -> np.ndarray:
    """(K',) int64 sorted subset of the cover `selected` (K,) of A (M, N), no redundant column."""
    csr = as_csr(A)
    return prune_cover(csr, selected, as_costs(costs, csr.shape[1]))
