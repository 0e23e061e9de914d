"""Exact reductions of the covering ILP min c·y, A y >= 1, y binary, A in [0, 1] (M × N).

Each keeps the optimum value (and maps any optimum of the reduced model to one of the
original), so a proven optimum of the reduced model is a proven optimum of A:

- essential columns: a row covered by a single column forces that column in; its coverage
  is taken off every row it touches (rows left with demand b < 1 are rescaled to
  min(1, a / b), which keeps exactly the same 0/1 solutions);
- identical rows: one is kept;
- implied rows: row i is dropped when another row k asks for less everywhere it can
  (A[k] <= A[i] coefficient-wise): any cover of k covers i (skipped on huge models);
- dominated columns: column j is dropped when another column k fully covers every row j
  touches (A[i, k] = 1 wherever A[i, j] > 0) at no higher cost; of identical 0/1 columns
  the first is kept. (With partial coverage a merely larger k is not enough: k and j add.)

`blocks` then splits what is left into independent covers (rows that share no column),
whose optima add up.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

TOL = 1e-9
"""A row counts as covered when its demand left is <= TOL (as `setcover.COVER_TOL`)."""
MAX_PAIR_WORK = 30_000_000
"""Skip the implied-row test when its row-overlap product would cost more (Σ column nnz²)."""
MAX_ROUNDS = 20
"""Reduction rounds at most (each round that changes nothing ends the loop)."""


@dataclass(frozen=True)
class Reduced:
    """The reduced model and how to map its columns back."""

    matrix: sp.csr_array  # (m, n) rows still to cover, in [0, 1]
    columns: np.ndarray  # (n,) int64 original index of each column of `matrix`
    fixed: np.ndarray  # (f,) int64 original columns forced into the cover
    sizes: dict[str, int] = field(default_factory=dict)  # rows/cols before and after


def reduce_cover(A: sp.csr_array, costs: np.ndarray) -> Reduced:
    """Reduce the cover of A (M, N) float64 csr with costs (N,) until nothing changes."""
    m0, n0 = A.shape
    matrix, columns = sp.csr_array(A, copy=True), np.arange(n0)
    fixed: list[np.ndarray] = []
    dropped_cols = dropped_rows = 0
    for _ in range(MAX_ROUNDS):
        before = matrix.shape
        matrix, columns, forced = _fix_essential(matrix, columns)
        fixed.append(forced)
        matrix.sort_indices()
        matrix = sp.csr_array(matrix[unique_rows(matrix)])
        implied = _unimplied_rows(matrix)
        dropped_rows += matrix.shape[0] - len(implied)
        matrix = sp.csr_array(matrix[implied])
        keep = undominated_columns(matrix, costs[columns])
        dropped_cols += matrix.shape[1] - len(keep)
        matrix, columns = sp.csr_array(matrix[:, keep]), columns[keep]
        if matrix.shape == before:
            break
    forced_all = np.sort(np.concatenate(fixed)).astype(np.int64)
    sizes = {
        "rows_before": m0,
        "cols_before": n0,
        "rows_after": matrix.shape[0],
        "cols_after": matrix.shape[1],
        "fixed": len(forced_all),
        "dominated_cols": dropped_cols,
        "implied_rows": dropped_rows,
    }
    return Reduced(matrix, columns.astype(np.int64), forced_all, sizes)


def _fix_essential(
    A: sp.csr_array, columns: np.ndarray
) -> tuple[sp.csr_array, np.ndarray, np.ndarray]:
    """Force the only column of single-column rows; (reduced A, its columns, forced originals)."""
    single = np.diff(A.indptr) == 1
    forced = np.unique(A.indices[A.indptr[:-1][single]])
    if len(forced) == 0:
        return A, columns, np.zeros(0, np.int64)
    got = np.asarray(A[:, forced].sum(axis=1)).ravel()
    demand = 1.0 - got
    rows = np.flatnonzero(demand > TOL)
    free = np.setdiff1d(np.arange(A.shape[1]), forced)
    rest = sp.csr_array(A[rows][:, free])
    scale = 1.0 / demand[rows]
    rest = sp.csr_array(sp.diags_array(scale) @ rest)
    rest.data = np.minimum(rest.data, 1.0)
    rest.eliminate_zeros()
    return rest, columns[free], columns[forced]


def _splitmix(x: np.ndarray) -> np.ndarray:
    """(L,) uint64 avalanche hash of (L,) uint64 (splitmix64 finaliser, wrapping arithmetic)."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return np.asarray(x ^ (x >> np.uint64(31)), dtype=np.uint64)


def _row_hashes(A: sp.csr_array) -> np.ndarray:
    """(M,) uint64 hash of each row's (column, value) pairs and length."""
    keys = _splitmix(_splitmix(A.indices.astype(np.uint64)) ^ A.data.view(np.uint64))
    cums = np.concatenate([np.zeros(1, np.uint64), np.cumsum(keys, dtype=np.uint64)])
    sums = cums[A.indptr[1:]] - cums[A.indptr[:-1]]
    return np.asarray(sums ^ _splitmix(np.diff(A.indptr).astype(np.uint64)), dtype=np.uint64)


def _rows_equal(A: sp.csr_array, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(P,) bool: row a[p] of A equals row b[p] exactly (sparsity and values)."""
    ip = A.indptr
    lens = ip[a + 1] - ip[a]
    same = lens == ip[b + 1] - ip[b]
    a, b, lens = a[same], b[same], lens[same]
    seg = np.repeat(np.arange(a.size), lens)
    off = np.arange(seg.size) - np.repeat(np.cumsum(lens) - lens, lens)
    pa, pb = ip[a][seg] + off, ip[b][seg] + off
    bad = (A.indices[pa] != A.indices[pb]) | (A.data[pa] != A.data[pb])
    ok = np.zeros(same.size, dtype=bool)
    ok[np.flatnonzero(same)] = np.bincount(seg[bad], minlength=a.size) == 0
    return ok


def row_groups(A: sp.csr_array) -> np.ndarray:
    """(M,) int64: for each row of A (M, N) (sorted indices), the first row identical to it."""
    _, first, inverse = np.unique(_row_hashes(A), return_index=True, return_inverse=True)
    rep = first[inverse.reshape(-1)].astype(np.int64)
    dup = np.flatnonzero(rep != np.arange(A.shape[0]))
    collided = dup[~_rows_equal(A, dup, rep[dup])]  # hash collisions stay separate rows
    rep[collided] = collided
    return rep


def unique_rows(A: sp.csr_array) -> np.ndarray:
    """(R,) int64 sorted indices of the first row of each group of identical rows of A (M, N)."""
    rep = row_groups(A)
    return np.flatnonzero(rep == np.arange(A.shape[0]))


def _unimplied_rows(A: sp.csr_array) -> np.ndarray:
    """(m',) sorted indices of the rows no other kept row implies (A[k] <= A[i] drops i)."""
    m = A.shape[0]
    col_nnz = np.bincount(A.indices, minlength=A.shape[1]).astype(np.float64)
    if m < 2 or float(col_nnz @ col_nnz) > MAX_PAIR_WORK:
        return np.arange(m)
    binary = sp.csr_array((np.ones_like(A.data), A.indices, A.indptr), shape=A.shape)
    overlap = sp.csr_array(binary @ binary.T)
    size = np.diff(A.indptr)
    alive = np.ones(m, bool)
    for i in np.argsort(-size, kind="stable"):
        lo, hi = overlap.indptr[i], overlap.indptr[i + 1]
        ks = overlap.indices[lo:hi]
        ks = ks[overlap.data[lo:hi] == size[ks]]  # rows whose support lies inside row i's
        for k in ks:
            if k != i and alive[k] and _implies(A, k, i):
                alive[i] = False
                break
    return np.flatnonzero(alive)


def _implies(A: sp.csr_array, k: int, i: int) -> bool:
    """Row k asks no more than row i of every column: A[k] <= A[i] (support of k inside i's)."""
    cols_k = A.indices[A.indptr[k] : A.indptr[k + 1]]
    cols_i = A.indices[A.indptr[i] : A.indptr[i + 1]]
    vals_i = A.data[A.indptr[i] : A.indptr[i + 1]][np.searchsorted(cols_i, cols_k)]
    return bool(np.all(vals_i >= A.data[A.indptr[k] : A.indptr[k + 1]] - TOL))


def undominated_columns(A: sp.csr_array, costs: np.ndarray) -> np.ndarray:
    """(n',) sorted indices of the columns no other column dominates (ties: first kept).

    Column k dominates j when it fully covers every row j touches (A[i, k] >= 1 - TOL wherever
    A[i, j] > 0) at no higher cost; of two that dominate each other (the same rows, each full
    on all of them, equal costs) the first stays. Full cover (not just A[:, k] >= A[:, j]) is
    what makes j redundant when k is chosen too: with partial coverage two columns add up, so
    a merely larger k does not replace j. Domination is transitive, so a column is dropped
    exactly when some other column dominates it: counted for all pairs at once as
    |rows(j) ∩ full rows(k)| = size(j), one sparse product."""
    n = A.shape[1]
    if n < 2 or A.shape[0] == 0:
        return np.arange(n)
    csc = sp.csc_array(A)
    ones = np.ones(csc.nnz, np.float32)  # counts of rows: exact in float32 below 2**24
    touched = sp.csc_array((ones, csc.indices, csc.indptr), shape=csc.shape)
    full = sp.csc_array((ones * (csc.data >= 1.0 - TOL), csc.indices, csc.indptr), csc.shape)
    size, full_size = np.diff(csc.indptr), np.asarray(full.sum(axis=0)).ravel()
    within = sp.coo_array(touched.T @ full)  # [j, k]: rows of j on which k is full
    inside = within.data == size[within.row]  # k full on all of j's rows; the rest on these only
    j, k = within.row[inside], within.col[inside]
    dominated = (j != k) & (costs[k] <= costs[j])
    mirror = (size[k] == size[j]) & (full_size[j] == size[j]) & (costs[k] == costs[j])
    dominated &= ~(mirror & (k > j))
    alive = np.ones(n, bool)
    alive[j[dominated]] = False
    return np.flatnonzero(alive)


def blocks(A: sp.csr_array) -> list[tuple[np.ndarray, np.ndarray]]:
    """Independent sub-covers of A (M, N): (rows, columns) int64 sorted index pairs of the
    connected components of its row-column graph, fewest nonzeros first; columns that touch
    no row are left out."""
    m, n = A.shape
    if m == 0:
        return []
    pattern = sp.csr_array((np.ones(A.nnz, np.int8), A.indices, A.indptr), shape=A.shape)
    graph = sp.block_array([[None, pattern], [pattern.T, None]], format="csr")
    k, label = csgraph.connected_components(graph, directed=False)
    ids, row_block = np.unique(label[:m], return_inverse=True)
    block_of = np.full(k, len(ids))  # components without rows: one bin past the blocks
    block_of[ids] = np.arange(len(ids))
    rows, cols = _groups(row_block, len(ids)), _groups(block_of[label[m:]], len(ids) + 1)
    nnz = np.bincount(row_block, weights=np.diff(A.indptr), minlength=len(ids))
    return [(rows[b], cols[b]) for b in np.argsort(nnz, kind="stable")]


def _groups(keys: np.ndarray, count: int) -> list[np.ndarray]:
    """For each key 0..count-1, the sorted int64 positions of `keys` (L,) that hold it."""
    order = np.argsort(keys, kind="stable").astype(np.int64)
    return np.split(order, np.cumsum(np.bincount(keys, minlength=count))[:-1])
