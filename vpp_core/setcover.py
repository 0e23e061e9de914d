"""The covering ILP of SPEC §4: min c·y s.t. A y >= 1, y binary, A real in (0, 1].

A is (M rows × N columns); rows are faces, columns candidate viewpoints. A is either 0/1
(visibility, the classical set cover) or real partial coverage S (several partial columns
may add up to cover a row). Two solvers: a lazy greedy with redundancy removal
(`greedy_cover`) and HiGHS branch-and-cut (`solve_cover(method="milp")`) warm-started from it.

Tolerance: a row counts as covered when its coverage is >= 1 - 1e-9 (`COVER_TOL`),
everywhere: the feasibility check, the greedy, `remove_redundant` and `is_cover`.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field
from typing import Any, TypeAlias

import highspy
import numpy as np
import scipy.sparse as sp

from vpp_core.errors import SolverError
from vpp_core.reduce import reduce_cover

COVER_TOL = 1e-9
"""A row i is covered by y when sum_j A_ij y_j >= 1 - COVER_TOL."""

_HIGHS_FEAS_TOL = 1e-9
_HIGHS_START_FEASIBLE = 2  # HiGHS kSolutionStatusFeasible
_INT_BOUND_EPS = 1e-6  # ceil(bound - eps) for integer costs
_REAL_GAP_TOL = 1e-6  # non-integer costs: gap closed when obj - bound <= 1e-6 max(1, obj)

SparseLike: TypeAlias = sp.csr_array | sp.csr_matrix


@dataclass(frozen=True)
class CoverResult:
    """Outcome of `solve_cover`; `selected` is a verified cover of A."""

    selected: np.ndarray  # (K,) int64 sorted column indices
    solver: str  # "milp" | "greedy"
    status: str  # "optimal" | "time_limit" | "gap_limit" | "heuristic"
    objective: float  # sum of costs of selected
    bound: float | None  # proven lower bound (dual bound); None for greedy
    gap: float | None  # (objective - bound) / objective, 0.0 when optimal; None for greedy
    time_s: float
    rows: int  # rows of the model handed to the solver (after reductions)
    cols: int
    presolve: dict[str, int] = field(default_factory=dict)  # sizes before/after reductions


# ---------------------------------------------------------------------------- input checks


def _as_csr(A: Any) -> sp.csr_array:
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


def _as_costs(costs: np.ndarray | None, n: int) -> np.ndarray:
    """(N,) float64 costs, all finite and > 0; all ones when None."""
    if costs is None:
        return np.ones(n, dtype=np.float64)
    c = np.asarray(costs, dtype=np.float64).reshape(-1)
    if c.shape != (n,):
        raise SolverError(f"costs must have shape ({n},), got {np.shape(costs)}")
    if not np.all(np.isfinite(c)) or (n and c.min() <= 0.0):
        raise SolverError("costs must be finite and > 0")
    return c


def _check_coverable(A: sp.csr_array) -> None:
    """Raise SolverError when some row of A (M, N) is not covered even by all columns."""
    short = np.flatnonzero(np.asarray(A.sum(axis=1)).reshape(-1) < 1.0 - COVER_TOL)
    if short.size:
        raise SolverError(
            f"{short.size} of {A.shape[0]} rows cannot be covered even with all "
            f"{A.shape[1]} columns (first: row {int(short[0])})"
        )


def _indicator(n: int, selected: np.ndarray) -> np.ndarray:
    """(N,) float64 0/1 vector of the column indices `selected` (K,)."""
    idx = np.asarray(selected, dtype=np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise ValueError(f"selected column index out of range [0, {n})")
    y = np.zeros(n, dtype=np.float64)
    y[idx] = 1.0
    return y


def _coverage(A: sp.csr_array, selected: np.ndarray) -> np.ndarray:
    """(M,) row coverage sum_j A_ij y_j of the selected columns (K,)."""
    return np.asarray(A @ _indicator(A.shape[1], selected), dtype=np.float64).reshape(-1)


def is_cover(A: SparseLike, selected: np.ndarray, tol: float = COVER_TOL) -> bool:
    """True when every row i of A (M, N) has sum_j A_ij y_j >= 1 - tol for y = selected (K,)."""
    csr = sp.csr_array(A, dtype=np.float64)
    return bool(np.all(_coverage(csr, selected) >= 1.0 - tol))


# ---------------------------------------------------------------------------- greedy


def _lazy_greedy(csc: sp.csc_array, costs: np.ndarray, r: np.ndarray) -> list[int]:
    """Columns of csc (M, N) picked greedily until residual demand r (M,) is 0 (r is updated)."""
    ip, ix, dv = csc.indptr, csc.indices, csc.data
    r[r <= COVER_TOL] = 0.0

    def gain(j: int) -> float:
        s = slice(ip[j], ip[j + 1])
        return float(np.minimum(r[ix[s]], dv[s]).sum())

    heap = [(-g / costs[j], j) for j in range(csc.shape[1]) if (g := gain(j)) > 0.0]
    heapq.heapify(heap)
    uncovered, picked = int(np.count_nonzero(r)), []
    while uncovered and heap:
        _, j = heapq.heappop(heap)
        g = gain(j)  # scores only decrease: the popped key is an upper bound
        if g <= 0.0:
            continue
        key = (-g / costs[j], j)
        if heap and key > heap[0]:
            heapq.heappush(heap, key)
            continue
        rows = ix[ip[j] : ip[j + 1]]
        new = r[rows] - dv[ip[j] : ip[j + 1]]
        new[new <= COVER_TOL] = 0.0
        uncovered -= int(np.count_nonzero((r[rows] > 0.0) & (new == 0.0)))
        r[rows] = new
        picked.append(j)
    if uncovered:
        raise SolverError(f"{uncovered} rows cannot be covered even with all columns")
    return picked


def _complete(A: sp.csr_array, costs: np.ndarray, selected: np.ndarray) -> np.ndarray:
    """(K',) sorted cover of A (M, N): `selected` (K,) + greedy columns, redundancy removed."""
    r = np.maximum(0.0, 1.0 - _coverage(A, selected))
    extra = _lazy_greedy(sp.csc_array(A), costs, r)
    union = np.union1d(np.asarray(selected, dtype=np.int64), np.asarray(extra, dtype=np.int64))
    return _remove_redundant(A, union, costs)


def greedy_cover(A: SparseLike, costs: np.ndarray | None = None) -> np.ndarray:
    """(K,) int64 sorted cover of A (M, N): cost-effectiveness greedy + redundancy removal."""
    csr = _as_csr(A)
    c = _as_costs(costs, csr.shape[1])
    _check_coverable(csr)
    return _complete(csr, c, np.zeros(0, dtype=np.int64))


def _remove_redundant(A: sp.csr_array, sel: np.ndarray, costs: np.ndarray) -> np.ndarray:
    """(K',) sorted subset of cover `sel` (K,) of A (M, N) with no column droppable on its own."""
    sel = np.unique(np.asarray(sel, dtype=np.int64))
    cov = _coverage(A, sel)
    if np.any(cov < 1.0 - COVER_TOL):
        raise ValueError("remove_redundant needs a cover; some rows are not covered")
    csc = sp.csc_array(A[:, sel]) if sel.size else sp.csc_array(A.shape, dtype=np.float64)
    useful = np.asarray(csc.sum(axis=0)).reshape(-1)
    keep = np.ones(sel.size, dtype=bool)
    for k in np.lexsort((-sel, useful, -costs[sel])):  # expensive, least useful, highest j first
        s = slice(csc.indptr[k], csc.indptr[k + 1])
        rows, vals = csc.indices[s], csc.data[s]
        left = cov[rows] - vals
        if np.all(left >= 1.0 - COVER_TOL):
            cov[rows] = left
            keep[k] = False
    return sel[keep]


def remove_redundant(
    A: SparseLike, selected: np.ndarray, costs: np.ndarray | None = None
) -> np.ndarray:
    """(K',) int64 sorted subset of the cover `selected` (K,) of A (M, N), no redundant column."""
    csr = _as_csr(A)
    return _remove_redundant(csr, selected, _as_costs(costs, csr.shape[1]))


# ---------------------------------------------------------------------------- reductions


def _trivial_bound(A: sp.csr_array, costs: np.ndarray) -> float:
    """Lower bound max_i min_{j: A_ij > 0} c_j (every row needs one of its columns); 0 if M = 0."""
    if A.shape[0] == 0:
        return 0.0
    return float(np.minimum.reduceat(costs[A.indices], A.indptr[:-1]).max())


# ---------------------------------------------------------------------------- HiGHS


def _highs_lp(A: sp.csr_array, costs: np.ndarray) -> highspy.HighsLp:
    """HiGHS model of min c·y, A y >= 1, y in {0, 1} for A (M, N), costs (N,)."""
    csc = sp.csc_array(A)
    m, n = A.shape
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = n, m
    lp.col_cost_ = costs
    lp.col_lower_, lp.col_upper_ = np.zeros(n), np.ones(n)
    lp.row_lower_, lp.row_upper_ = np.ones(m), np.full(m, highspy.kHighsInf)
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = csc.indptr.astype(np.int32)
    lp.a_matrix_.index_ = csc.indices.astype(np.int32)
    lp.a_matrix_.value_ = csc.data
    lp.integrality_ = [highspy.HighsVarType.kInteger] * n
    return lp


def _highs(time_limit: float, mip_rel_gap: float, threads: int | None) -> highspy.Highs:
    """A silent HiGHS instance with the solve options set."""
    h = highspy.Highs()  # type: ignore[no-untyped-call]
    options: dict[str, bool | int | float] = {
        "output_flag": False,
        "log_to_console": False,
        "time_limit": float(time_limit),
        "mip_rel_gap": float(mip_rel_gap),
        "primal_feasibility_tolerance": _HIGHS_FEAS_TOL,
        "mip_feasibility_tolerance": _HIGHS_FEAS_TOL,
    }
    if threads is not None:
        options["threads"] = int(threads)
    for name, value in options.items():
        if h.setOptionValue(name, value) != highspy.HighsStatus.kOk:
            raise ValueError(f"HiGHS rejected option {name}={value!r}")
    return h


@dataclass(frozen=True)
class _MipOutcome:
    """What HiGHS returned: its selection (or None), model status and dual bound."""

    selected: np.ndarray | None
    model_status: highspy.HighsModelStatus
    dual_bound: float


def _run_highs(
    A: sp.csr_array,
    costs: np.ndarray,
    start: np.ndarray,
    time_limit: float,
    mip_rel_gap: float,
    threads: int | None,
) -> _MipOutcome:
    """Solve the cover of A (M, N) with HiGHS, warm-started from the cover `start` (K,)."""
    h = _highs(time_limit, mip_rel_gap, threads)
    h.passModel(_highs_lp(A, costs))
    warm = highspy.HighsSolution()
    warm.col_value = _indicator(A.shape[1], start).tolist()
    warm.value_valid = True
    h.setSolution(warm)
    if h.run() == highspy.HighsStatus.kError and threads is not None:
        highspy.Highs.resetGlobalScheduler(True)  # scheduler was started with another count
        h.setSolution(warm)
        h.run()
    info = h.getInfo()
    selected = None
    if info.primal_solution_status == _HIGHS_START_FEASIBLE:
        x = np.asarray(h.getSolution().col_value, dtype=np.float64)
        selected = np.flatnonzero(x > 0.5).astype(np.int64)
    bound = float(info.mip_dual_bound)
    return _MipOutcome(selected, h.getModelStatus(), bound if math.isfinite(bound) else -math.inf)


# ---------------------------------------------------------------------------- driver


def _best_selection(
    A: sp.csr_array, costs: np.ndarray, greedy: np.ndarray, mip: np.ndarray | None
) -> tuple[np.ndarray, bool]:
    """(K,) cheaper of the greedy cover and HiGHS's selection (verified, repaired if needed)."""
    if mip is None:
        return greedy, False
    repaired = not is_cover(A, mip)
    mip = _complete(A, costs, mip) if repaired else _remove_redundant(A, mip, costs)
    if costs[greedy].sum() < costs[mip].sum():
        return greedy, False
    return mip, repaired


def _proven_bound(
    A: sp.csr_array, costs: np.ndarray, dual: float, objective: float
) -> tuple[float, bool]:
    """Best valid lower bound (HiGHS's dual or the trivial one) and whether it closes the gap."""
    bound = max(dual, _trivial_bound(A, costs))
    if np.all(costs == np.floor(costs)):  # integer costs: the optimum is an integer
        bound = min(float(math.ceil(bound - _INT_BOUND_EPS)), objective)
        return bound, bound >= objective - 1e-9
    bound = min(bound, objective)
    return bound, objective - bound <= _REAL_GAP_TOL * max(1.0, objective)


def _status(model_status: highspy.HighsModelStatus, closed: bool, repaired: bool) -> str:
    """Truthful status: "optimal" only for a HiGHS optimum with the gap closed, unrepaired."""
    if model_status == highspy.HighsModelStatus.kOptimal:
        return "heuristic" if repaired else ("optimal" if closed else "gap_limit")
    if model_status == highspy.HighsModelStatus.kTimeLimit:
        return "time_limit"
    return "heuristic"


def _solve_milp(
    A: sp.csr_array,
    costs: np.ndarray,
    t0: float,
    time_limit: float,
    mip_rel_gap: float,
    threads: int | None,
) -> CoverResult:
    """Exact solve of the cover of A (M, N): reductions, greedy start, HiGHS on what is left."""
    red = reduce_cover(A, costs)
    R, c = red.matrix, costs[red.columns]
    fixed_cost = float(costs[red.fixed].sum())
    greedy = _complete(R, c, np.zeros(0, dtype=np.int64)) if R.shape[0] else red.columns[:0]
    left = time_limit - (time.perf_counter() - t0)
    if R.shape[0] == 0:
        out = _MipOutcome(greedy, highspy.HighsModelStatus.kOptimal, 0.0)
    elif left > 0.0:
        out = _run_highs(R, c, greedy, left, mip_rel_gap, threads)
    else:
        out = _MipOutcome(None, highspy.HighsModelStatus.kTimeLimit, -math.inf)
    chosen, repaired = (
        _best_selection(R, c, greedy, out.selected) if R.shape[0] else (greedy, False)
    )
    selected = np.union1d(red.fixed, red.columns[chosen]).astype(np.int64)
    if not is_cover(A, selected):  # cannot happen if the reductions are exact: stay safe
        selected, repaired = _complete(A, costs, selected), True
    objective = float(costs[selected].sum())
    bound, closed = _proven_bound(R, c, out.dual_bound, objective - fixed_cost)
    bound += fixed_cost
    status = _status(out.model_status, closed, repaired)
    gap = 0.0 if status == "optimal" else (objective - bound) / objective
    elapsed = time.perf_counter() - t0
    return CoverResult(
        selected, "milp", status, objective, bound, gap, elapsed, R.shape[0], R.shape[1], red.sizes
    )


def solve_cover(
    A: SparseLike,
    costs: np.ndarray | None = None,
    *,
    method: str = "milp",
    time_limit: float = 60.0,
    mip_rel_gap: float = 0.0,
    threads: int | None = None,
) -> CoverResult:
    """Minimum-cost cover of A (M, N) with costs (N,): HiGHS MILP ("milp") or greedy ("greedy")."""
    t0 = time.perf_counter()
    if method not in ("milp", "greedy"):
        raise ValueError(f"method must be 'milp' or 'greedy', got {method!r}")
    if not time_limit > 0.0 or not mip_rel_gap >= 0.0:
        raise ValueError("time_limit must be > 0 and mip_rel_gap >= 0")
    csr = _as_csr(A)
    c = _as_costs(costs, csr.shape[1])
    m, n = csr.shape
    if m == 0:
        empty = np.zeros(0, dtype=np.int64)
        return CoverResult(empty, method, "optimal", 0.0, 0.0, 0.0, time.perf_counter() - t0, 0, n)
    _check_coverable(csr)
    if method == "milp":
        return _solve_milp(csr, c, t0, time_limit, mip_rel_gap, threads)
    greedy = _complete(csr, c, np.zeros(0, dtype=np.int64))
    objective = float(c[greedy].sum())
    return CoverResult(
        greedy, "greedy", "heuristic", objective, None, None, time.perf_counter() - t0, m, n
    )
