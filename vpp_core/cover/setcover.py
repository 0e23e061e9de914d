"""The covering ILP of SPEC §4: min c·y s.t. A y >= 1, y binary, A real in (0, 1].

A is (M rows × N columns); rows are faces, columns candidate viewpoints. A is either 0/1
(visibility, the classical set cover) or real partial coverage S (several partial columns
may add up to cover a row). `solve_cover(method="greedy")` is greedy + redundancy removal;
`method="milp"` reduces the model, then spends its time on the LP bound, a quick exact
HiGHS try, a row-weighting local search, HiGHS on a core and HiGHS on the
reduced-cost-fixed model (docs/setcover.md). Tolerances are those of `vpp_core.cover.problem`.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import highspy
import numpy as np
import scipy.sparse as sp

from vpp_core.cover import mip, rowweight
from vpp_core.cover.greedy import complete_cover, greedy_cover, prune_cover, remove_redundant
from vpp_core.cover.lpbound import (
    LpBound,
    columns_worth_keeping,
    highs_model,
    lp_bound,
)
from vpp_core.cover.problem import (
    COVER_TOL,
    SparseLike,
    as_costs,
    as_csr,
    check_coverable,
    indicator,
    integral_costs,
    is_cover,
)
from vpp_core.cover.reduce import blocks, reduce_cover

__all__ = [
    "COVER_TOL",
    "CoverResult",
    "greedy_cover",
    "is_cover",
    "remove_redundant",
    "solve_cover",
]

_INT_BOUND_EPS = 1e-6  # ceil(bound - eps) for integer costs
_REAL_GAP_TOL = 1e-6  # non-integer costs: gap closed when obj - bound <= 1e-6 max(1, obj)
LP_SHARE = 0.4
"""At most this share of the time limit goes to the LP bound."""
QUICK_SHARE = 0.1
"""At most this share of the time left after the LP goes to a first exact HiGHS run."""
SEARCH_SHARE = 0.5
"""At most this share of the time left then goes to the row-weighting search alone; HiGHS
then gets the rest, with the search beside it on another core."""
SEARCH_PATIENCE = 100
"""The row-weighting search stops after this many steps per column without a cheaper cover."""
LOCAL_SEARCH_NNZ = 2_000_000
"""Reduced models with more nonzeros get the row-weighting search instead of HiGHS
branch-and-bound."""


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
    time_to_best_s: float | None = None  # seconds from the start until the cover was found


# ---------------------------------------------------------------------------- reductions


def _trivial_bound(A: sp.csr_array, costs: np.ndarray) -> float:
    """Lower bound max_i min_{j: A_ij > 0} c_j (every row needs one of its columns); M > 0."""
    return float(np.minimum.reduceat(costs[A.indices], A.indptr[:-1]).max())


# ---------------------------------------------------------------------------- HiGHS


def _start_highs(
    A: sp.csr_array,
    costs: np.ndarray,
    start: np.ndarray | None,
    time_limit: float,
    mip_rel_gap: float,
    threads: int | None,
) -> mip.Pending:
    """Start HiGHS on the cover of A (M, N) in its process, warm-started from the cover `start`
    (K,) if any."""
    model = partial(highs_model, A, costs, integer=True)
    x0 = None if start is None else indicator(A.shape[1], start)
    return mip.submit(model, x0, time_limit, mip_rel_gap, threads)


# ---------------------------------------------------------------------------- driver


def _verified(
    A: sp.csr_array, costs: np.ndarray, mip: np.ndarray | None
) -> tuple[np.ndarray | None, bool]:
    """(HiGHS's selection as a pruned cover of A (M, N), whether it had to be repaired)."""
    if mip is None:
        return None, False
    if is_cover(A, mip):
        return prune_cover(A, mip, costs), False
    return complete_cover(A, costs, mip), True


def closes_gap(bound: float, objective: float, integral: bool) -> tuple[float, bool]:
    """(bound rounded up for integer costs and capped at objective, whether it closes the gap)."""
    if integral:  # integer costs: the optimum is an integer
        bound = min(float(math.ceil(bound - _INT_BOUND_EPS)), objective)
        return bound, bound >= objective - 1e-9
    bound = min(bound, objective)
    return bound, objective - bound <= _REAL_GAP_TOL * max(1.0, objective)


@dataclass
class _Search:
    """The reduced model being solved and the best cover and bound found so far."""

    A: sp.csr_array  # (m, n)
    costs: np.ndarray  # (n,)
    best: np.ndarray  # (K,) cover of A
    bound: float
    integral: bool
    deadline: float
    threads: int | None
    mip_status: highspy.HighsModelStatus | None = None
    repaired: bool = False
    found_at: float = field(default_factory=time.perf_counter)

    @property
    def objective(self) -> float:
        return float(self.costs[self.best].sum())

    def left(self, share: float = 1.0) -> float:
        return share * (self.deadline - time.perf_counter())

    def closed(self) -> bool:
        return closes_gap(self.bound, self.objective, self.integral)[1]

    def offer(self, cover: np.ndarray | None, found_at: float | None = None) -> None:
        """Keep `cover` (found at time.perf_counter() `found_at`, else now) if it is cheaper."""
        if cover is None or self.costs[cover].sum() >= self.objective:
            return
        if is_cover(self.A, cover):  # a cover from any step is checked before it counts
            self.best, self.found_at = cover, found_at or time.perf_counter()

    def walk(
        self, deadline: float, patience: int = 10**12, stop: Callable[[], bool] | None = None
    ) -> None:
        """Row-weighting search from the best cover until `deadline`, `stop()`, the bound or
        `patience` steps without a cheaper cover."""
        if not rowweight.compiled(deadline - time.perf_counter()):
            return
        target = closes_gap(self.bound, self.objective, self.integral)[0]
        found, at = rowweight.search(
            self.A, self.costs, self.best, deadline, target=target, patience=patience, stop=stop
        )
        self.offer(found, at)

    def mip(
        self, keep: np.ndarray, time_limit: float, gap: float, warm: bool, alongside: bool
    ) -> mip.MipAnswer:
        """HiGHS on the columns `keep` (n,) bool (which must hold the incumbent), started from
        the incumbent when `warm`; with `alongside`, the search runs here meanwhile, and HiGHS
        is stopped if the search closes the gap."""
        cols = np.flatnonzero(keep)
        start = np.flatnonzero(np.isin(cols, self.best)) if warm else None
        A, costs = self.A[:, cols], self.costs[cols]
        with _start_highs(A, costs, start, time_limit, gap, self.threads) as run:
            if alongside:
                self.walk(time.perf_counter() + time_limit, stop=run.ready)
                if self.closed():  # the search met the bound: HiGHS is stopped unheard
                    return mip.NO_ANSWER
            out = run.answer()
        selected = None if out.x is None else cols[np.flatnonzero(out.x > 0.5)]
        cover, repaired = _verified(self.A, self.costs, selected)
        self.offer(cover)
        self.repaired |= repaired  # HiGHS's answer broke a row: its bound is not trusted
        return out


def _search(S: _Search, mip_rel_gap: float) -> None:
    """LP bound, a quick exact try, the row-weighting search, then HiGHS on what can win with
    the search beside it (at once, when the quick try left the gap at one unit)."""
    lp = lp_bound(S.A, S.costs, S.left(LP_SHARE), S.threads)
    S.bound = max(S.bound, lp.bound)
    if S.closed():
        return
    if S.A.nnz > LOCAL_SEARCH_NNZ:  # HiGHS cannot branch on this: search locally instead
        S.walk(S.deadline)
        return
    _exact(S, lp, S.left(QUICK_SHARE), mip_rel_gap)
    if S.closed() or S.mip_status == highspy.HighsModelStatus.kOptimal:
        return
    # One unit short: only the proof, or a cover one unit cheaper, is missing. HiGHS looks for
    # both at once, cold: started from a near-optimal cover it proved more slowly
    # (docs/setcover.md). Otherwise the search first gives HiGHS a better cover to start from.
    # HiGHS then has the rest of the time, the search beside it unless one thread is all the
    # solve may use.
    one_unit = S.integral and closes_gap(S.bound + 1.0, S.objective, True)[1]
    if not one_unit:
        S.walk(time.perf_counter() + S.left(SEARCH_SHARE), SEARCH_PATIENCE * S.A.shape[1])
        if S.closed():
            return
    _exact(S, lp, S.left(), mip_rel_gap, warm=not one_unit, alongside=S.threads != 1)


def _exact(
    S: _Search,
    lp: LpBound,
    time_limit: float,
    mip_rel_gap: float,
    warm: bool = True,
    alongside: bool = False,
) -> None:
    """HiGHS on the columns that can still beat the incumbent; its bound then holds for A.
    Nothing runs once the time is up: a run started late may outlive its wall (mip.GRACE_S)."""
    if time_limit <= 0.0:
        return
    keep = columns_worth_keeping(lp, S.objective, 1.0 if S.integral else 0.0)
    keep[S.best] = True
    out = S.mip(keep, time_limit, mip_rel_gap, warm, alongside)
    S.mip_status = out.status
    if not S.repaired:  # the kept columns hold every cheaper cover
        S.bound = max(S.bound, min(out.dual_bound, S.objective))


def _solve_milp(
    A: sp.csr_array,
    costs: np.ndarray,
    t0: float,
    time_limit: float,
    mip_rel_gap: float,
    threads: int | None,
) -> CoverResult:
    """Exact solve of the cover of A (M, N): reductions, then each independent block of what
    is left (greedy, LP bound, HiGHS ...) on its share of the time."""
    mip.warm()  # the HiGHS process and the search's compile start while the model is reduced
    rowweight.compiled(0.0)
    red = reduce_cover(A, costs)
    R, c = red.matrix, costs[red.columns]
    integral = integral_costs(costs)
    parts = blocks(R)
    searches, work_left = [], float(R.nnz)
    for k, (rows, cols) in enumerate(parts):
        sub = sp.csr_array(R[rows][:, cols])
        # smallest first, each with at least an even share: what a block leaves rolls on
        share = max(sub.nnz / work_left, 1.0 / (len(parts) - k))
        work_left -= sub.nnz
        deadline = time.perf_counter() + share * (t0 + time_limit - time.perf_counter())
        searches.append(_solve_block(sub, c[cols], integral, deadline, mip_rel_gap, threads))
    picked = [red.columns[cols[S.best]] for (_, cols), S in zip(parts, searches, strict=True)]
    selected = np.union1d(red.fixed, np.concatenate([red.columns[:0], *picked])).astype(np.int64)
    if not is_cover(A, selected):  # cannot happen if the reductions are exact: stay safe
        selected = complete_cover(A, costs, selected)
    objective = float(costs[selected].sum())
    fixed_cost = float(costs[red.fixed].sum())
    block_bounds = (closes_gap(S.bound, S.objective, integral)[0] for S in searches)
    bound, closed = closes_gap(fixed_cost + sum(block_bounds), objective, integral)
    status = _status_of(searches, closed)
    gap = 0.0 if status == "optimal" else (objective - bound) / objective
    found = max((S.found_at for S in searches), default=time.perf_counter())
    sizes = {**red.sizes, "blocks": len(parts)}
    elapsed = time.perf_counter() - t0
    return CoverResult(
        selected, "milp", status, objective, bound, gap, elapsed, R.shape[0], R.shape[1],
        sizes, found - t0,
    )  # fmt: skip


def _solve_block(
    A: sp.csr_array,
    costs: np.ndarray,
    integral: bool,
    deadline: float,
    mip_rel_gap: float,
    threads: int | None,
) -> _Search:
    """The search on one block A (m, n) with costs (n,), from its greedy cover, until `deadline`."""
    greedy = complete_cover(A, costs, np.zeros(0, dtype=np.int64))
    S = _Search(A, costs, greedy, _trivial_bound(A, costs), integral, deadline, threads)
    if not S.closed() and S.left() > 0:
        _search(S, mip_rel_gap)
    return S


def _status_of(searches: list[_Search], closed: bool) -> str:
    """Truthful status of the blocks together: "optimal" only when the summed bound meets the
    cover's cost (`closed`); otherwise time_limit or gap_limit if some block has it, else
    heuristic."""
    if closed:
        return "optimal"
    statuses = {_status(S, S.closed()) for S in searches}
    return next((s for s in ("time_limit", "gap_limit") if s in statuses), "heuristic")


def _status(S: _Search, closed: bool) -> str:
    """Truthful status: "optimal" only when a proven bound meets the cover's cost."""
    if closed:
        return "optimal"
    if S.left() <= 0 or S.mip_status == highspy.HighsModelStatus.kTimeLimit:
        return "time_limit"
    if S.mip_status == highspy.HighsModelStatus.kOptimal and not S.repaired:  # stopped at its gap
        return "gap_limit"
    return "heuristic"


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
    csr = as_csr(A)
    c = as_costs(costs, csr.shape[1])
    m, n = csr.shape
    if m == 0:
        empty = np.zeros(0, dtype=np.int64)
        return CoverResult(empty, method, "optimal", 0.0, 0.0, 0.0, time.perf_counter() - t0, 0, n)
    check_coverable(csr)
    if method == "milp":
        return _solve_milp(csr, c, t0, time_limit, mip_rel_gap, threads)
    greedy = complete_cover(csr, c, np.zeros(0, dtype=np.int64))
    objective = float(c[greedy].sum())
    elapsed = time.perf_counter() - t0
    return CoverResult(
        greedy, "greedy", "heuristic", objective, None, None, elapsed, m, n, {}, elapsed
    )
