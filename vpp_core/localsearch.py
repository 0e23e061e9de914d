"""Destroy-and-repair local search for the cover min c·y, A y >= 1, y binary (A in [0, 1], M × N).

Each move drops a few chosen columns that share rows with a random chosen column, repairs
the rows left short with a greedy on randomly perturbed costs (restricted to the columns
touching those rows), prunes the columns made redundant, and keeps the result when it costs
no more. Equal-cost moves are kept too, so the search walks plateaus.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from vpp_core.cover import BUILD_TOL, coverage
from vpp_core.greedy import lazy_greedy

DROP = (4, 20)
"""Columns removed per move: uniform in this range."""
PATIENCE = 3000
"""Moves in a row without a cheaper cover after which the search gives up."""
NOISE = 0.1
"""Repair costs are multiplied by uniform(1, 1 + NOISE); dropped columns by 1 + 2·NOISE."""


def improve(
    A: sp.csr_array,
    costs: np.ndarray,
    selected: np.ndarray,
    deadline: float,
    *,
    target: float = -np.inf,
    seed: int = 0,
    guide: np.ndarray | None = None,
) -> np.ndarray:
    """(K',) sorted cover of A (M, N) costing <= that of the cover `selected` (K,).

    Runs until time.perf_counter() passes `deadline`, the cost reaches `target` or PATIENCE
    moves in a row find nothing cheaper. Repairs
    score columns by `guide` (N,) > 0 (default: the costs), moves are judged by the costs.
    """
    score = costs if guide is None else guide
    rng = np.random.default_rng(seed)
    csc = sp.csc_array(A)
    chosen = np.zeros(A.shape[1], dtype=bool)
    chosen[selected] = True
    cov = coverage(A, selected)
    cost = float(costs[chosen].sum())
    idle = 0
    while time.perf_counter() < deadline and cost > target + 1e-9 and idle < PATIENCE:
        drop = _pick_drop(A, csc, chosen, rng)
        added, pruned, new_cov = _repair(A, csc, score, chosen, cov, drop, rng)
        delta = costs[added].sum() - costs[drop].sum() - costs[pruned].sum()
        if delta <= 1e-9 * max(1.0, cost):
            chosen[drop] = False
            chosen[added] = True
            chosen[pruned] = False
            idle = 0 if delta < -1e-9 * max(1.0, cost) else idle + 1
            cov, cost = new_cov, float(costs[chosen].sum())
        else:
            idle += 1
    return np.flatnonzero(chosen).astype(np.int64)


def _pick_drop(
    A: sp.csr_array, csc: sp.csc_array, chosen: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """(k,) chosen columns sharing rows with a random chosen column (itself included)."""
    j0 = int(rng.choice(np.flatnonzero(chosen)))
    rows = csc.indices[csc.indptr[j0] : csc.indptr[j0 + 1]]
    near = np.unique(A[rows].indices) if rows.size else np.zeros(0, np.int64)
    near = near[chosen[near] & (near != j0)]
    k = int(rng.integers(DROP[0], DROP[1] + 1))
    if near.size >= k:
        near = rng.choice(near, size=k - 1, replace=False)
    return np.append(near, j0).astype(np.int64)


def _repair(
    A: sp.csr_array,
    csc: sp.csc_array,
    costs: np.ndarray,
    chosen: np.ndarray,
    cov: np.ndarray,
    drop: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(added, pruned, new coverage (M,)) after dropping `drop` from the chosen columns."""
    cov = cov - _coverage_of(csc, drop, A.shape[0])
    short = np.flatnonzero(cov < 1.0 - BUILD_TOL)
    cand = np.unique(A[short].indices)
    dropped = np.isin(cand, drop)
    usable = ~chosen[cand] | dropped
    cand, dropped = cand[usable], dropped[usable]
    noisy = costs[cand] * rng.uniform(1.0, 1.0 + NOISE, size=cand.size)
    noisy[dropped] *= 1.0 + 2.0 * NOISE
    sub = sp.csc_array(A[short][:, cand])
    added = cand[np.asarray(lazy_greedy(sub, noisy, 1.0 - cov[short]), dtype=np.int64)]
    cov = cov + _coverage_of(csc, added, A.shape[0])
    keep = chosen.copy()
    keep[drop] = False
    pruned = _prune_near(A, csc, costs, keep, cov, added, rng)
    return added, pruned, cov - _coverage_of(csc, pruned, A.shape[0])


def _coverage_of(csc: sp.csc_array, cols: np.ndarray, m: int) -> np.ndarray:
    """(M,) summed coverage of the columns `cols` (k,) of csc (M, N).

    `cover.coverage` multiplies the whole matrix; this touches only the k columns.
    """
    if cols.size == 0:
        return np.zeros(m)
    block = csc[:, cols]
    return np.bincount(block.indices, weights=block.data, minlength=m)


def _prune_near(
    A: sp.csr_array,
    csc: sp.csc_array,
    costs: np.ndarray,
    keep: np.ndarray,
    cov: np.ndarray,
    added: np.ndarray,
    rng: np.random.Generator,
) -> np.ndarray:
    """(p,) kept columns sharing rows with `added` that the cover no longer needs."""
    rows = np.unique(csc[:, added].indices) if added.size else np.zeros(0, np.int64)
    near = np.unique(A[rows].indices) if rows.size else np.zeros(0, np.int64)
    near = near[keep[near]]
    near = near[np.lexsort((rng.random(near.size), -costs[near]))]
    cov = cov.copy()
    pruned = []
    for j in near:
        s = slice(csc.indptr[j], csc.indptr[j + 1])
        left = cov[csc.indices[s]] - csc.data[s]
        if np.all(left >= 1.0 - BUILD_TOL):
            cov[csc.indices[s]] = left
            pruned.append(j)
    return np.asarray(pruned, dtype=np.int64)
