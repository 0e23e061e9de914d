"""Lagrangian heuristic for the cover min c·y, A y >= 1, y binary (A in [0, 1], M × N).

After Caprara, Fischetti and Toth (Oper. Res. 47, 1999). Subgradient steps on multipliers
u >= 0 raise the Lagrangian bound L(u) = Σ_i r_i u_i + Σ_j min(0, c_j - (Aᵀu)_j); near good u
a greedy on Lagrangian scores builds covers. Column fixing then fixes the columns of negative
reduced cost that share no row and the first picks of that greedy, and solves what is left
the same way; refinement fixes the part of the best cover that the multipliers find
cheapest and starts again from CFT's first multipliers; starting over, rather than from the
best ones, is what finds the best-known covers of OR-Library's NRE/NRF classes
(docs/setcover.md). Everything works on residual demands r (M,) in [0, 1],
so real coefficients (partial coverage) work as 0/1 ones do.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpp_core.cover import BUILD_TOL, coverage
from vpp_core.jit import kernel
from vpp_core.lpbound import lagrangian

Arr = np.ndarray

PATIENCE = 30
"""Subgradient iterations without a better L after which the step factor halves (Beasley)."""
MIN_STEP = 0.005
"""A subgradient run stops when its step factor falls below this."""
MAX_ITERATIONS = 5000
"""At most this many subgradient iterations per run."""
CHUNK = 100
"""Subgradient iterations between two looks at the clock."""
HEURISTIC_ITERATIONS = 100
"""Subgradient iterations of a heuristic phase; each runs the Lagrangian greedy."""
HEURISTIC_STEP = 0.1
"""Step factor of the heuristic phase's iterates: small, so they stay near the best u."""
START_STEP = 0.5
"""Step factor of the subgradient runs inside column fixing."""
FIX_SHARE = 1 / 200
"""Columns fixed per round of column fixing: this share of the rows left (at least 1)."""
IDLE_CYCLES = 3
"""The search stops after this many refinement cycles (30 % up to all rows) without a
cheaper cover."""
CORE_PER_ROW = 10
"""Column fixing chooses among the columns of least reduced cost of each row (and the best
cover's): this many per row, at the multipliers of the first subgradient run."""
REFINE_START = 0.3
"""Refinement first fixes best-cover columns covering this share of the rows; x1.1 each round."""


@dataclass(frozen=True)
class Model:
    """A (M, N) as CSC and CSR arrays for the kernels, with the costs (N,) and A itself."""

    cp: np.ndarray
    ci: np.ndarray
    cd: np.ndarray
    rp: np.ndarray
    ri: np.ndarray
    rd: np.ndarray
    costs: np.ndarray
    A: sp.csr_array

    @classmethod
    def of(cls, A: sp.csr_array, costs: np.ndarray) -> Model:
        """The model of the cover of A (M, N) with costs (N,)."""
        csc = sp.csc_array(A)
        i64 = np.int64
        return cls(
            csc.indptr.astype(i64), csc.indices.astype(i64), csc.data, A.indptr.astype(i64),
            A.indices.astype(i64), A.data, np.asarray(costs, dtype=np.float64),
            A,
        )  # fmt: skip

    @property
    def m(self) -> int:
        return int(self.rp.size - 1)

    @property
    def n(self) -> int:
        return int(self.costs.size)


@dataclass(frozen=True)
class LagrangeResult:
    """Best cover found (K,), and the best Lagrangian bound on the whole model with its u (M,)."""

    selected: np.ndarray
    bound: float
    duals: np.ndarray


# ---------------------------------------------------------------------------- kernels


@kernel
def _subgradient(
    cp: Arr, ci: Arr, cd: Arr, costs: Arr, r: Arr, free: Arr, u: Arr, best_u: Arr,
    ub: float, iterations: int, lam: float, best: float,
) -> tuple[float, float, bool]:  # fmt: skip
    """Subgradient steps on u (M,) for demands r (M,), free columns (N,) bool, target ub.

    Step u += lam (ub - L) s / |s|², s the projected subgradient; lam halves after PATIENCE
    iterations without a better L and the run stops below MIN_STEP. u ends at the last
    iterate, best_u gets the best iterate if its L beats `best`; returns (best L, last step
    factor, whether the run stopped before `iterations`).
    """
    m, n = r.size, costs.size
    s = np.empty(m)
    since = 0
    for i in range(m):
        if r[i] <= 0.0:
            u[i] = 0.0
    for _ in range(iterations):
        value = 0.0
        for i in range(m):
            s[i] = r[i]
            value += r[i] * u[i]
        for j in range(n):
            if not free[j]:
                continue
            red = costs[j]
            for k in range(cp[j], cp[j + 1]):
                red -= cd[k] * u[ci[k]]
            if red < 0.0:
                value += red
                for k in range(cp[j], cp[j + 1]):
                    s[ci[k]] -= cd[k]
        since += 1
        if since == 1 and best == -np.inf or value > best + 1e-9 * max(1.0, abs(best)):
            best, since = value, 0
            best_u[:] = u
        elif since >= PATIENCE:
            lam, since = 0.5 * lam, 0
            if lam < MIN_STEP:
                return best, lam, True
        norm = 0.0
        for i in range(m):
            if r[i] <= 0.0 or (u[i] <= 0.0 and s[i] < 0.0):
                s[i] = 0.0
            norm += s[i] * s[i]
        gap = ub - value
        if norm == 0.0 or gap <= 1e-9:
            return best, lam, True
        step = lam * gap / norm
        for i in range(m):
            u[i] = max(0.0, u[i] + step * s[i])
    return best, lam, False


@kernel
def _greedy(
    cp: Arr, ci: Arr, cd: Arr, rp: Arr, ri: Arr, rd: Arr, costs: Arr, u: Arr, r0: Arr,
    free: Arr, picked: Arr,
) -> int:  # fmt: skip
    """Lagrangian greedy for demands r0 (M,) from free columns (N,) bool at multipliers u (M,).

    Score of column j: γ/μ when γ > 0 else γ·μ, where μ is the demand it would still meet
    and γ = c_j - Σ u_i·(demand met in row i). Writes the picks in order into `picked` (N,)
    and returns their number, or -1 when some demand cannot be met.
    """
    m, n = r0.size, costs.size
    r = r0.copy()
    gamma = np.zeros(n)
    mu = np.zeros(n)
    left = 0
    for i in range(m):
        if r[i] <= BUILD_TOL:
            r[i] = 0.0
        else:
            left += 1
    for j in range(n):
        if free[j]:
            g, w = costs[j], 0.0
            for k in range(cp[j], cp[j + 1]):
                a = min(cd[k], r[ci[k]])
                w += a
                g -= u[ci[k]] * a
            gamma[j], mu[j] = g, w
    count = 0
    while left > 0:
        pick, score = -1, np.inf
        for j in range(n):
            if free[j] and mu[j] > 0.0:
                v = gamma[j] / mu[j] if gamma[j] > 0.0 else gamma[j] * mu[j]
                if v < score:
                    pick, score = j, v
        if pick < 0:
            return -1
        free[pick] = False
        picked[count] = pick
        count += 1
        for k in range(cp[pick], cp[pick + 1]):
            i = ci[k]
            old = r[i]
            if old <= 0.0:
                continue
            new = old - cd[k]
            if new <= BUILD_TOL:
                new = 0.0
                left -= 1
            r[i] = new
            for q in range(rp[i], rp[i + 1]):
                j = ri[q]
                if free[j]:
                    delta = min(rd[q], old) - min(rd[q], new)
                    mu[j] -= delta
                    gamma[j] += u[i] * delta
    for q in range(count):
        free[picked[q]] = True
    return count


@kernel
def _prune(cp: Arr, ci: Arr, cd: Arr, costs: Arr, r0: Arr, chosen: Arr) -> Arr:
    """Drop columns of `chosen` (K,) not needed for demands r0 (M,): dearest, then latest first.

    Returns the kept mask (K,).
    """
    cov = np.zeros(r0.size)
    for q in range(chosen.size):
        j = chosen[q]
        for k in range(cp[j], cp[j + 1]):
            cov[ci[k]] += cd[k]
    size = chosen.size
    keep = np.ones(size, dtype=np.bool_)
    order = np.argsort(-costs[chosen[::-1]], kind="mergesort")  # equal costs: latest first
    for t in range(size):
        q = size - 1 - order[t]
        j = chosen[q]
        ok = True
        for k in range(cp[j], cp[j + 1]):
            if r0[ci[k]] > 0.0 and cov[ci[k]] - cd[k] < r0[ci[k]] - BUILD_TOL:
                ok = False
                break
        if ok:
            keep[q] = False
            for k in range(cp[j], cp[j + 1]):
                cov[ci[k]] -= cd[k]
    return keep


# ---------------------------------------------------------------------------- search


@dataclass
class _Search:
    """The model, the best cover so far and when to stop."""

    model: Model
    best: np.ndarray  # (K,) sorted cover
    integral: bool  # integer costs: a cover must be cheaper by 1 to count
    target: float  # stop when the best cover costs this much
    deadline: float
    rng: np.random.Generator

    @property
    def ub(self) -> float:
        return float(self.model.costs[self.best].sum())

    def running(self) -> bool:
        return time.perf_counter() < self.deadline and self.ub > self.target + 1e-9

    def can_improve(self, lower: float) -> bool:
        """Whether a cover whose cost is known to be >= lower can be cheaper than the best."""
        if self.integral:
            return float(np.ceil(lower - 1e-6)) < self.ub - 0.5
        return lower < self.ub - 1e-9 * max(1.0, self.ub)

    def greedy(self, r: np.ndarray, free: np.ndarray, u: np.ndarray) -> np.ndarray | None:
        """(k,) the Lagrangian greedy's picks, in order, for demands r (M,) at u (M,)."""
        M = self.model
        picked = np.empty(M.n, dtype=np.int64)
        k = _greedy(M.cp, M.ci, M.cd, M.rp, M.ri, M.rd, M.costs, u, r, free, picked)
        return None if k < 0 else picked[:k]

    def offer(self, cover: np.ndarray) -> None:
        """Prune the cover (K,) of the whole model and keep it if cheaper than the best."""
        M = self.model
        keep = _prune(M.cp, M.ci, M.cd, M.costs, np.ones(M.m), cover)
        cover = np.sort(cover[keep])
        if M.costs[cover].sum() < self.ub - 1e-9 * max(1.0, self.ub):
            self.best = cover


def search(
    A: sp.csr_array,
    costs: np.ndarray,
    selected: np.ndarray,
    deadline: float,
    *,
    duals: np.ndarray | None = None,
    target: float = -np.inf,
    seed: int = 0,
) -> LagrangeResult:
    """A cover of A (M, N) costing <= the cover `selected` (K,), and a Lagrangian bound.

    Runs until time.perf_counter() passes `deadline`, the cost reaches `target` or IDLE_CYCLES
    refinement cycles find nothing cheaper; `duals` (M,) >= 0 (e.g. the LP's) start the
    multipliers of the bound.
    """
    M = Model.of(A, costs)
    integral = bool(np.all(M.costs == np.floor(M.costs)))
    S = _Search(M, np.sort(selected), integral, target, deadline, np.random.default_rng(seed))
    start = _initial(A, M.costs)
    u = start.copy() if duals is None else np.maximum(duals, 0.0)
    best_u = u.copy()
    ones, free = np.ones(M.m), np.ones(M.n, dtype=np.bool_)
    _ascend(S, ones, free, u, best_u, S.ub, 2.0)
    bound, reduced = lagrangian(A, M.costs, best_u)
    if duals is not None:
        bound = max(bound, lagrangian(A, M.costs, np.maximum(duals, 0.0))[0])
    cheap = core(A, reduced, CORE_PER_ROW)
    share, fixed = REFINE_START, np.zeros(0, dtype=np.int64)
    idle, cycle_start = 0, S.ub
    while S.running() and idle < IDLE_CYCLES:
        before = S.ub
        columns = cheap.copy()
        columns[S.best] = True
        _three_phase(S, fixed, start.copy(), columns)
        share = REFINE_START if S.ub < before else share * 1.1
        if share > 1.0:  # every refinement tried: start over from perturbed multipliers
            idle = idle + 1 if S.ub >= cycle_start else 0
            share, cycle_start = REFINE_START, S.ub
            start = _initial(A, M.costs) * S.rng.uniform(0.9, 1.1, size=M.m)
        fixed = _refine(S, best_u, share)
    return LagrangeResult(S.best, bound, best_u)


def core(A: sp.csr_array, reduced: np.ndarray, per_row: int) -> np.ndarray:
    """(N,) bool: the `per_row` columns of least reduced cost (N,) of every row of A (M, N)."""
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    order = np.lexsort((reduced[A.indices], rows))
    rank = np.arange(order.size) - A.indptr[rows[order]]
    core = np.zeros(A.shape[1], dtype=bool)
    core[A.indices[order[rank < per_row]]] = True
    return core


def _ascend(
    S: _Search, r: np.ndarray, free: np.ndarray, u: np.ndarray, best_u: np.ndarray, ub: float,
    lam: float,
) -> float:  # fmt: skip
    """`_subgradient` for at most MAX_ITERATIONS, in chunks that keep to the deadline; best L."""
    M, best = S.model, -np.inf
    for _ in range(0, MAX_ITERATIONS, CHUNK):
        best, lam, stopped = _subgradient(
            M.cp, M.ci, M.cd, M.costs, r, free, u, best_u, ub, CHUNK, lam, best
        )
        if stopped or time.perf_counter() >= S.deadline:
            break
    return best


def _initial(A: sp.csr_array, costs: np.ndarray) -> np.ndarray:
    """(M,) u_i = min over the row's columns of c_j / (column sum of A) (CFT's start)."""
    ratio = costs / np.asarray(A.sum(axis=0)).reshape(-1).clip(min=1e-12)
    if A.nnz == 0:
        return np.zeros(A.shape[0])
    starts = A.indptr[:-1].clip(max=A.nnz - 1)
    return np.where(np.diff(A.indptr) > 0, np.minimum.reduceat(ratio[A.indices], starts), 0.0)


def _residual(M: Model, fixed: np.ndarray, demand: np.ndarray | None = None) -> np.ndarray:
    """(M,) demand left of `demand` (M,) (default all 1) once the columns `fixed` (F,) are in;
    0 where met."""
    r = (1.0 if demand is None else demand) - coverage(M.A, fixed)
    r[r <= BUILD_TOL] = 0.0
    return np.maximum(r, 0.0)


def _three_phase(S: _Search, fixed: np.ndarray, u: np.ndarray, columns: np.ndarray) -> None:
    """Subgradient, heuristic and column-fixing phases from multipliers u (M,) with the columns
    `fixed` (F,) in, choosing among `columns` (N,) bool."""
    M = S.model
    while S.running():
        r = _residual(M, fixed)
        if not r.any():
            S.offer(fixed)
            return
        free = columns.copy()
        free[fixed] = False
        paid = float(M.costs[fixed].sum())
        best_u = u.copy()
        low = _ascend(S, r, free, u, best_u, S.ub - paid, START_STEP)
        if not S.can_improve(paid + low):
            return
        _heuristic(S, fixed, r, free, best_u, S.ub - paid, HEURISTIC_STEP)
        more = _to_fix(S, r, free, best_u)
        if more is None:
            return
        fixed = np.append(fixed, more)
        u = best_u * S.rng.uniform(0.9, 1.1, size=M.m)


def _to_fix(S: _Search, r: np.ndarray, free: np.ndarray, u: np.ndarray) -> np.ndarray | None:
    """(F,) columns to fix next: those of reduced cost < -0.001 at u (M,) that share no row
    with another, then max(1, m/200) picks of the Lagrangian greedy (CFT); None if stuck."""
    M = S.model
    reduced = lagrangian(M.A, M.costs, u)[1]
    taken = np.zeros(M.m, dtype=np.bool_)
    sure = []
    for j in np.flatnonzero(free & (reduced < -1e-3)):
        rows = M.ci[M.cp[j] : M.cp[j + 1]]
        rows = rows[r[rows] > 0.0]
        if rows.size and not taken[rows].any():
            taken[rows] = True
            sure.append(j)
    fixed = np.asarray(sure, dtype=np.int64)
    rest, rest_free = _residual(M, fixed, r), free.copy()
    rest_free[fixed] = False
    if not rest.any():
        return fixed
    picks = S.greedy(rest, rest_free, u)
    if picks is None:
        return None
    return np.append(fixed, picks[: max(1, int(FIX_SHARE * np.count_nonzero(rest)))])


def _heuristic(
    S: _Search,
    fixed: np.ndarray,
    r: np.ndarray,
    free: np.ndarray,
    u: np.ndarray,
    ub: float,
    lam: float,
) -> None:
    """Greedy covers at each of HEURISTIC_ITERATIONS subgradient iterates from u (M,)."""
    M = S.model
    u, scratch = u.copy(), u.copy()
    for _ in range(HEURISTIC_ITERATIONS):
        if not S.running():
            return
        picks = S.greedy(r, free, u)
        if picks is not None:
            S.offer(np.append(fixed, picks))
        _subgradient(M.cp, M.ci, M.cd, M.costs, r, free, u, scratch, ub, 1, lam, -np.inf)


def _refine(S: _Search, u: np.ndarray, share: float) -> np.ndarray:
    """(F,) the best cover's columns the multipliers u (M,) find cheapest, covering `share`
    of the rows: least δ_j = max(0, c̃_j) + Σ_i u_i a_ij (cov_i - 1) / cov_i first (CFT)."""
    M, best = S.model, S.best
    cov = coverage(M.A, best)
    delta = np.empty(best.size)
    for q, j in enumerate(best):
        s = slice(M.cp[j], M.cp[j + 1])
        rows, a = M.ci[s], M.cd[s]
        over = (cov[rows] - 1.0).clip(min=0.0) / cov[rows]
        delta[q] = max(0.0, M.costs[j] - (u[rows] * a).sum()) + (u[rows] * a * over).sum()
    order = best[np.argsort(delta, kind="stable")]
    met = np.zeros(M.m)
    fixed = []
    for j in order:
        if np.count_nonzero(met >= 1.0 - BUILD_TOL) >= share * M.m:
            break
        s = slice(M.cp[j], M.cp[j + 1])
        met[M.ci[s]] += M.cd[s]
        fixed.append(j)
    return np.asarray(fixed, dtype=np.int64)
