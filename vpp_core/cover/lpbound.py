"""Lower bounds on the cover min c·y, A y >= 1, y binary (A in [0, 1], M × N) from its LP.

The bound is the Lagrangian L(u) = Σ_i u_i + Σ_j min(0, c_j - (Aᵀu)_j), valid for every
u >= 0 (for y binary with A y >= 1: c·y >= Σ u + Σ_j (c - Aᵀu)_j y_j >= L(u)). HiGHS solves
the LP relaxation for u (dual simplex on small models, interior point without crossover on
large or tall ones); L(u) is then recomputed here from the clipped duals, so the bound holds
whatever the LP solver's tolerances were. At the LP optimum L(u) equals the LP value.

Reduced-cost fixing: a cover holding column j costs at least L(u) + max(0, c_j - (Aᵀu)_j),
so columns past the incumbent's cost cannot be in a cheaper cover.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import highspy
import numpy as np
import scipy.sparse as sp

IPM_NNZ = 1_000_000
"""Models with more nonzeros go to HiGHS's interior point method (no crossover)."""
IPM_TALL = 2.0
"""So do models with more than this many rows per column: measured on the reduced viewpoint
models at 2000 candidates (docs/setcover.md), dual simplex took 6.4 s where the interior
point took 0.3 s (fandisk, 4568 × 1967) and had not finished after 200 s where it took 2.6 s
(turbine blade, 31997 × 1910); on the squarer models it is the faster, by under a second."""
_FIX_TOL = 1e-6  # relative slack kept when fixing columns by reduced cost


@dataclass(frozen=True)
class LpBound:
    """A proven lower bound and the multipliers that give it."""

    bound: float  # L(u), a lower bound on every cover's cost
    duals: np.ndarray  # (M,) u >= 0
    reduced: np.ndarray  # (N,) reduced costs c - Aᵀu
    x: np.ndarray  # (N,) LP primal values (zeros when HiGHS gave none)
    status: str  # "optimal" when HiGHS solved the LP, else why it stopped
    time_s: float


def lagrangian(A: sp.csr_array, costs: np.ndarray, u: np.ndarray) -> tuple[float, np.ndarray]:
    """(L(u), (N,) reduced costs c - Aᵀu) for A (M, N), costs (N,), multipliers u (M,) >= 0."""
    reduced = costs - np.asarray(A.T @ u, dtype=np.float64)
    return float(u.sum() + np.minimum(reduced, 0.0).sum()), reduced


@dataclass(frozen=True)
class RowModel:
    """min cost·x, M x >= row_lower (no upper), col_lower <= x <= col_upper (finite), columns
    marked in `integer` integral: the arrays of a HiGHS model, kept beside it. Reading them
    back out of a HighsLp makes a Python object of every entry: on the fine coupling
    stand-in's face-row model (237 k rows) the Lagrangian then took 18 s and GBs of memory,
    and the plan ran 30 s past its time limit waiting for it."""

    M: sp.csc_array  # (rows, cols)
    cost: np.ndarray  # (cols,)
    col_lower: np.ndarray  # (cols,)
    col_upper: np.ndarray  # (cols,)
    row_lower: np.ndarray  # (rows,)
    integer: np.ndarray  # (cols,) bool

    def highs(self, relaxed: bool = False) -> highspy.HighsLp:
        """The HiGHS model; with `relaxed`, every column continuous."""
        lp = highspy.HighsLp()
        (lp.num_row_, lp.num_col_), M = self.M.shape, self.M
        lp.col_cost_, lp.col_lower_, lp.col_upper_ = self.cost, self.col_lower, self.col_upper
        lp.row_lower_, lp.row_upper_ = self.row_lower, np.full(M.shape[0], highspy.kHighsInf)
        lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
        lp.a_matrix_.start_ = M.indptr.astype(np.int32)
        lp.a_matrix_.index_ = M.indices.astype(np.int32)
        lp.a_matrix_.value_ = M.data
        if not relaxed:
            kinds = (highspy.HighsVarType.kContinuous, highspy.HighsVarType.kInteger)
            lp.integrality_ = [kinds[k] for k in self.integer.tolist()]
        return lp


def highs_model(A: sp.csr_array, costs: np.ndarray, integer: bool = False) -> highspy.HighsLp:
    """HiGHS model min c·y, A y >= 1, 0 <= y <= 1 (y integer if asked) for A (M, N), costs (N,)."""
    m, n = A.shape
    cover = RowModel(sp.csc_array(A), costs, np.zeros(n), np.ones(n), np.ones(m), np.ones(n, bool))
    return cover.highs(relaxed=not integer)


HighsOption = bool | int | float | str


@cache
def _banner_to_stderr() -> None:
    """HiGHS writes its banner to the C-level stdout on a process's first Highs(): let that
    one go to stderr, so that stdout keeps only what the caller prints (tables, JSON lines)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        highspy.Highs()  # type: ignore[no-untyped-call]
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def silent_highs(options: dict[str, HighsOption], threads: int | None) -> highspy.Highs:
    """A HiGHS instance with logging off and `options` set (ValueError on a rejected one)."""
    _banner_to_stderr()
    h = highspy.Highs()  # type: ignore[no-untyped-call]
    options = {"output_flag": False, "log_to_console": False, **options}
    if threads is not None:
        options["threads"] = int(threads)
    for name, value in options.items():
        if h.setOptionValue(name, value) != highspy.HighsStatus.kOk:
            raise ValueError(f"HiGHS rejected option {name}={value!r}")
    return h


def run_highs(
    h: highspy.Highs, threads: int | None, prepare: Callable[[], object] = lambda: None
) -> None:
    """prepare(), h.run(); again after a scheduler reset if HiGHS's threads were set otherwise."""
    prepare()
    if h.run() == highspy.HighsStatus.kError and threads is not None:
        highspy.Highs.resetGlobalScheduler(True)  # scheduler was started with another count
        prepare()
        h.run()


def clipped_duals(solution: highspy.HighsSolution) -> np.ndarray:
    """HiGHS's row duals of `solution`, NaN as 0 and clipped to >= 0: multipliers of a
    Lagrangian bound that holds whatever the LP solver's tolerances were."""
    return np.maximum(np.nan_to_num(np.asarray(solution.row_dual, dtype=np.float64)), 0.0)


def lp_bound(
    A: sp.csr_array, costs: np.ndarray, time_limit: float, threads: int | None = None
) -> LpBound:
    """Lagrangian bound of the cover of A (M, N), costs (N,) at the LP duals HiGHS finds."""
    t0 = time.perf_counter()
    m, n = A.shape
    options: dict[str, HighsOption] = {"time_limit": max(float(time_limit), 0.01)}
    if A.nnz > IPM_NNZ or m > IPM_TALL * n:
        options |= {"solver": "ipm", "run_crossover": "off"}
    h = silent_highs(options, threads)
    h.passModel(highs_model(A, costs))
    run_highs(h, threads)
    solution = h.getSolution()
    u = clipped_duals(solution) if solution.dual_valid else np.zeros(m)
    x = np.zeros(n)
    if solution.value_valid:
        x = np.clip(np.asarray(solution.col_value, dtype=np.float64), 0.0, 1.0)
    bound, reduced = lagrangian(A, costs, u)
    status = h.modelStatusToString(h.getModelStatus()).lower().replace(" ", "_")
    return LpBound(max(bound, 0.0), u, reduced, x, status, time.perf_counter() - t0)


def columns_worth_keeping(lp: LpBound, incumbent: float, step: float) -> np.ndarray:
    """(N,) bool: columns that may lie in a cover costing <= incumbent - step (by reduced cost).

    `step` is the smallest improvement that counts (1 for integer costs, 0 otherwise).
    """
    target = incumbent - step
    slack = _FIX_TOL * max(1.0, abs(target))
    return np.asarray(lp.bound + np.maximum(lp.reduced, 0.0) <= target + slack)


RELAXATION_OPTIONS: dict[str, HighsOption] = {"solver": "simplex"}
"""The partial cover's LP goes to dual simplex: on 1 mm² element models (featuretype, 17 008
× 471 after merging, F = 0.999 / 0.99; plate_holes, 45 296 × 488) it took 5 / 17 s and 14 s
where the interior point took 27 / 27 s and had not finished after 60 s."""


def row_lagrangian(model: RowModel, y: np.ndarray) -> float:
    """Lagrangian bound of `model` at multipliers y (rows,) >= 0: Σ y·row_lower + Σ_k
    min(d_k lo_k, d_k up_k) with d = cost - Mᵀy. It bounds every feasible x's cost, whatever
    y is."""
    d = model.cost - np.asarray(model.M.T @ y)
    lo, up = model.col_lower, model.col_upper
    return float(y @ model.row_lower + np.minimum(d * lo, d * up).sum())


class Relaxation:
    """The LP relaxation of a model (integrality dropped), solved by HiGHS in a thread (it
    releases the GIL) until its time limit or `cancel()`."""

    def __init__(self, model: RowModel, time_limit: float, threads: int | None = None):
        options = {"time_limit": max(float(time_limit), 0.01), **RELAXATION_OPTIONS}
        self._h = silent_highs(options, threads)
        self._h.HandleUserInterrupt = True  # cancelSolve() stops it
        self._h.passModel(model.highs(relaxed=True))
        self._model, self._bound = model, -np.inf
        self._thread = threading.Thread(target=self._run, args=(threads,), daemon=True)
        self._thread.start()

    def _run(self, threads: int | None) -> None:
        run_highs(self._h, threads)
        solution = self._h.getSolution()
        if solution.dual_valid:
            self._bound = row_lagrangian(self._model, clipped_duals(solution))

    def bound(self, wait: float | None = None) -> float:
        """`row_lagrangian` at the clipped row duals, once solved within `wait` s (None: until
        done): a lower bound on the model's MIP; -inf if not solved by then."""
        self._thread.join(None if wait is None else max(wait, 0.0))
        return -np.inf if self._thread.is_alive() else self._bound

    def cancel(self) -> None:
        """Stop HiGHS if it is still running, and wait for its thread: HiGHS stops at its next
        iteration (within milliseconds once it iterates), and a HiGHS thread still running
        when the process exits aborts it ("terminate called without an active exception")."""
        self._h.cancelSolve()  # type: ignore[no-untyped-call]
        self._thread.join()


def relaxation_bound(model: RowModel, time_limit: float, threads: int | None = None) -> float:
    """`Relaxation(model, time_limit, threads).bound()`: the LP relaxation's bound, solved here."""
    return Relaxation(model, time_limit, threads).bound()
