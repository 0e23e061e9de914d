"""Partial cover: the cheapest columns that satisfy rows holding a fraction f of the weight.

    min c·x   s.t.  Σ_j A_ij x_j >= z_i   (every row i)
                    Σ_i w_i z_i >= f Σ_i w_i
                    x binary, z_i in {0, 1}

A (M × N) in [0, 1] as in `vpp_core.cover.problem`, w (M,) >= 0 (face areas, mm²). Row i counts as
satisfied only when its whole demand is met (coverage >= 1 - COVER_TOL), so a row covered
halfway by partial coefficients earns nothing. The model stays exact after:

- identical rows merged, their weights added (they are satisfied together);
- rows of zero weight dropped (they earn nothing and cost nothing);
- dominated columns dropped (column k fully covers every row of j at no higher cost: swapping
  j for k, or dropping j when k is in, never unsatisfies a row);
- rows heavier than the weight that may be left out are forced (z_i = 1);
- z_i continuous on rows whose coefficients are all 1: there any x makes A_i·x an integer, so
  z_i > 0 only where the row is really satisfied.

The LP relaxation gives a bound (HiGHS's dual simplex in a thread, until the deadline; the
bound is recomputed from its clipped row duals as a Lagrangian: `lpbound.row_lagrangian`).
Its model also holds count rows (`problem.count_rows`): a row no single column covers needs
two or more of its columns, which A's own row does not say to the LP (two columns at half
weight cover it there). A cube's model (768 patch rows, 500 candidates) then has LP bound 3.7
instead of 2.3 and its 4 views are proven at the LP in 0.5 s instead of by HiGHS's MIP in 5.7
s. The MIP is given A's rows only: with count rows too it proved the 36-tooth coupling
stand-in's 6 views, where it stops at bound 5, but took 8 views on hirth_sample_small where
it finds 7 (docs/setcover.md).
When it meets the greedy start's cost within LP_HEAD_START_S, that is the answer. Otherwise
HiGHS solves the MIP in its child process (vpp_core.cover.mip) while the LP goes on beside it
(HiGHS releases the GIL); the bound is the larger of the two. So a model too big for the
MIP's root in time still gets its LP bound (plate_holes on 1 mm² elements at 30 s: 6 for an
8-view cover, where the MIP alone gave 0). Meanwhile the row-weighting search
(`vpp_core.cover.rowweight`, short rows of at most (1 - f) Σ w allowed) walks from the greedy
start on the other core until HiGHS answers; the cheaper of the two is the answer. HiGHS
starts cold: given the greedy cover as its incumbent, it proved the stepped test part's
partial model (1 010 rows, 30 candidates; the greedy cover was already optimal) in 6 375
nodes and 21 s instead of 1 node and 1.5 s, and on the 19 shared and stand-in meshes
(docs/quality.md) cold starts gave the same counts and bounds. Neither
wins everywhere: on the crankshaft stand-in's patch model (7 090 rows, 543 candidates, 40 s)
the search found 27 views where HiGHS kept 28, on the counter's (7 889 rows) HiGHS 78 where
the search reached 83. With one thread (a service worker on a machine with as many cores as
workers) they take turns, as in the strict cover: HiGHS a quick try of QUICK_SHARE of the
time (a model it proves at once is answered at once), the search SEARCH_SHARE of what is
left or until SEARCH_PATIENCE steps per column find no cheaper cover (as the strict cover's;
session 60: a 30-column model of 1 104 rows the search had no cheaper cover for took 32 s of
its 50 s limit, 10 s since, HiGHS proving it in 4.3 s), then HiGHS again: on one core over
nine default models at 36 s, 2 views fewer in all than HiGHS alone (docs/setcover.md;
measured without the quick try, which session 41 added when a 49-camera plan spent half its
minute in the search, and with HiGHS then started from the search's cover, not cold; not
measured again). The status is "optimal" only when the bound meets the cover's cost.
f = 1 is the strict cover (`solve_cover`).
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import highspy
import numpy as np
import scipy.sparse as sp

from vpp_core.cover import rowweight
from vpp_core.cover.greedy import lazy_picks
from vpp_core.cover.lpbound import Relaxation, RowModel
from vpp_core.cover.mip import GRACE_S, TIMED_OUT, MipAnswer, submit, warm
from vpp_core.cover.problem import (
    BUILD_TOL,
    COVER_TOL,
    SparseLike,
    as_costs,
    as_csr,
    count_rows,
    coverage,
    fractional_rows,
    integral_costs,
)
from vpp_core.cover.reduce import row_groups, undominated_columns
from vpp_core.cover.setcover import (
    QUICK_SHARE,
    SEARCH_PATIENCE,
    SEARCH_SHARE,
    CoverResult,
    closes_gap,
    solve_cover,
)
from vpp_core.errors import SolverError

LP_HEAD_START_S = 0.5
"""The LP runs alone this long (at most) before the MIP starts beside it."""
WEIGHT_RTOL = 1e-9
"""Satisfied weight may fall short of f·W by this fraction of W (float summation)."""


@dataclass(frozen=True)
class PartialCover:
    """A partial cover and what it satisfies."""

    result: CoverResult  # selected columns, status, bound, over the original columns
    satisfied: np.ndarray  # (M,) bool rows whose demand the selection meets
    required: float  # f · Σ w
    achieved: float  # Σ w over satisfied rows


def _slack(w: np.ndarray) -> float:
    """Shortfall of satisfied weight tolerated for weights (M,): WEIGHT_RTOL of their total."""
    return WEIGHT_RTOL * max(float(w.sum()), 1.0)


def _reaches(
    A: sp.csr_array, selected: np.ndarray, w: np.ndarray, required: float, tol: float = BUILD_TOL
) -> bool:
    """The columns `selected` (K,) satisfy rows of A (M, N) of weight (M,) >= required."""
    return float(w[satisfied_rows(A, selected, tol)].sum()) >= required - _slack(w)


def satisfied_rows(A: sp.csr_array, selected: np.ndarray, tol: float = COVER_TOL) -> np.ndarray:
    """(M,) bool: rows of A (M, N) whose coverage by the columns `selected` (K,) reaches 1 - tol."""
    return coverage(A, selected) >= 1.0 - tol


def solve_partial(
    A: SparseLike,
    weights: np.ndarray,
    fraction: float,
    costs: np.ndarray | None = None,
    *,
    method: str = "milp",
    time_limit: float = 60.0,
    mip_rel_gap: float = 0.0,
    threads: int | None = None,
) -> PartialCover:
    """Cheapest columns of A (M, N) satisfying rows of weight (M,) >= fraction of the total."""
    t0 = time.perf_counter()
    csr, c = as_csr(A), as_costs(costs, A.shape[1])
    w = np.asarray(weights, dtype=np.float64).reshape(-1)
    if w.shape != (csr.shape[0],) or not np.all(np.isfinite(w)) or (w.size and w.min() < 0):
        raise SolverError(f"weights must be ({csr.shape[0]},) finite and >= 0")
    if not 0.0 < fraction <= 1.0:
        raise SolverError(f"coverage fraction must lie in (0, 1], got {fraction}")
    required = fraction * float(w.sum())
    if required <= _slack(w):
        empty = CoverResult(np.zeros(0, np.int64), method, "optimal", 0.0, 0.0, 0.0, 0.0, 0, 0)
        return _outcome(csr, w, empty, required)
    if fraction == 1.0:
        res = solve_cover(
            csr, c, method=method, time_limit=time_limit, mip_rel_gap=mip_rel_gap, threads=threads
        )
        return _outcome(csr, w, res, required)
    if method == "milp":
        warm()  # the HiGHS process starts (and the search compiles) while greedy runs
        rowweight.compiled(0.0)
    groups = _merged(csr, w, c)
    start = greedy_partial(groups.A, c[groups.cols], groups.w, required)
    if method == "greedy":
        selected, status, bound, best_at = groups.cols[start], "heuristic", None, None
    else:
        selected, status, bound, best_at = _milp(
            groups, c, start, required, t0 + time_limit, mip_rel_gap, threads
        )
    objective = float(c[selected].sum())
    gap = None if bound is None else (0.0 if status == "optimal" else 1.0 - bound / objective)
    elapsed = time.perf_counter() - t0
    res = CoverResult(
        np.sort(selected),
        method,
        status,
        objective,
        bound,
        gap,
        elapsed,
        groups.A.shape[0],
        groups.A.shape[1],
        {"rows_before": csr.shape[0], "cols_before": csr.shape[1], **groups.sizes},
        elapsed if best_at is None else best_at - t0,
    )
    return _outcome(csr, w, res, required)


def _outcome(A: sp.csr_array, w: np.ndarray, res: CoverResult, required: float) -> PartialCover:
    """Check the selection against A and the weight it must reach."""
    ok = satisfied_rows(A, res.selected)
    achieved = float(w[ok].sum())
    if achieved < required - _slack(w):  # a bug, never the input
        raise SolverError(f"partial cover reaches weight {achieved:g} < required {required:g}")
    return PartialCover(res, ok, required, achieved)


@dataclass(frozen=True)
class _Merged:
    """The reduced model: distinct weighted rows, undominated columns."""

    A: sp.csr_array  # (m, n)
    w: np.ndarray  # (m,) summed weights
    cols: np.ndarray  # (n,) original column of each column
    sizes: dict[str, int]


def _merged(A: sp.csr_array, w: np.ndarray, costs: np.ndarray) -> _Merged:
    """Identical rows merged (weights summed), zero-weight rows and dominated columns dropped."""
    rep = row_groups(A)
    first = np.flatnonzero(rep == np.arange(A.shape[0]))
    summed = np.bincount(np.searchsorted(first, rep), weights=w, minlength=len(first))
    heavy = summed > 0
    rows, summed = first[heavy], summed[heavy]
    sub = sp.csr_array(A[rows])
    cols = undominated_columns(sub, costs)
    sub = sp.csr_array(sub[:, cols])
    merged = len(w) - len(first)
    sizes = {"rows_after": sub.shape[0], "cols_after": sub.shape[1], "merged_rows": merged}
    return _Merged(sub, summed, cols.astype(np.int64), sizes)


def greedy_partial(
    A: sp.csr_array, costs: np.ndarray, w: np.ndarray, required: float
) -> np.ndarray:
    """(K,) int64 columns of A (M, N) picked greedily by weighted progress per cost, then pruned.

    Lazily (`lazy_picks`): a column's progress Σ_i w_i min(r_i, A_ij) only falls as the
    residual demands r fall (the picks of evaluating every column each turn, in a fraction of
    the time on a model of 10⁶ entries)."""
    csc = sp.csc_array(A)
    ip, ix, dv = csc.indptr, csc.indices, csc.data
    r = np.ones(A.shape[0])

    def gain(j: int) -> float:
        """Column j's progress, summed in row order (ties between columns stay exact)."""
        rows = ix[ip[j] : ip[j + 1]]
        progress = np.minimum(r[rows], dv[ip[j] : ip[j + 1]]) * w[rows]
        return float(np.cumsum(progress)[-1]) if len(rows) else 0.0

    picks = lazy_picks(A.shape[1], costs, gain)
    picked: list[int] = []
    enough = required - _slack(w)
    while float(w[r <= BUILD_TOL].sum()) < enough:
        if (j := next(picks, None)) is None:
            raise SolverError("the required weight cannot be reached even with all columns")
        rows = ix[ip[j] : ip[j + 1]]
        r[rows] = np.maximum(r[rows] - dv[ip[j] : ip[j + 1]], 0.0)
        picked.append(j)
    return prune_partial(A, np.array(picked, dtype=np.int64), costs, w, required)


def prune_partial(
    A: sp.csr_array, sel: np.ndarray, costs: np.ndarray, w: np.ndarray, required: float
) -> np.ndarray:
    """(K',) sorted subset of `sel` (K,) still reaching `required` weight; none droppable alone."""
    sel = np.unique(sel)
    for j in sel[np.argsort(-costs[sel], kind="stable")]:
        rest = sel[sel != j]
        if _reaches(A, rest, w, required):
            sel = rest
    return np.sort(sel)


def _milp(
    g: _Merged,
    costs: np.ndarray,
    start: np.ndarray,
    required: float,
    deadline: float,
    mip_rel_gap: float,
    threads: int | None,
) -> tuple[np.ndarray, str, float | None, float | None]:
    """The LP bound (in a thread) and, if it leaves a gap, HiGHS on the merged model beside it
    and the search from `start`: (original columns, status, bound, time found)."""
    c = costs[g.cols]
    model = functools.partial(_model, g, c, required, False)
    integral = integral_costs(c)
    relaxation = Relaxation(_rows(g, c, required, True), deadline - time.perf_counter(), threads)
    try:
        lp = max(relaxation.bound(min(LP_HEAD_START_S, deadline - time.perf_counter())), 0.0)
        bound, closed = closes_gap(lp, c[start].sum(), integral)
        if closed:
            return g.cols[start], "optimal", bound, None
        best, found, h = start, None, TIMED_OUT  # a MIP started late could outlive the deadline
        quick = QUICK_SHARE * (deadline - time.perf_counter())
        if threads == 1 and quick > 0.0:  # one core: a quick exact try, the search, then HiGHS
            with submit(model, None, quick, mip_rel_gap, threads) as run:
                h = run.answer()
            best, found = _offered(g, c, required, best, found, h)
            if h.status != highspy.HighsModelStatus.kOptimal:  # the search from the better
                ahead = time.perf_counter() + SEARCH_SHARE * (deadline - time.perf_counter())
                patience = SEARCH_PATIENCE * g.A.shape[1]  # as the strict cover's search alone
                best, found = _walk(g, c, best, required, ahead, bound, lambda: False, patience)
        time_limit = deadline - time.perf_counter()
        proven = h.status == highspy.HighsModelStatus.kOptimal
        if time_limit > 0.0 and not proven and not closes_gap(bound, c[best].sum(), integral)[1]:
            with submit(model, None, time_limit, mip_rel_gap, threads) as run:
                if threads != 1:
                    best, found = _walk(g, c, start, required, deadline, bound, run.ready)
                h = run.answer()
            best, found = _offered(g, c, required, best, found, h)
        dual = h.dual_bound if np.isfinite(h.dual_bound) else 0.0
        if not closes_gap(dual, c[best].sum(), integral)[1]:  # the LP may still close it
            dual = max(dual, relaxation.bound(deadline + GRACE_S - time.perf_counter()))
    finally:
        relaxation.cancel()
    bound, closed = closes_gap(max(dual, 0.0), c[best].sum(), integral)
    return g.cols[best], _status(h.status, closed), bound, found


def _offered(
    g: _Merged,
    c: np.ndarray,
    required: float,
    best: np.ndarray,
    found: float | None,
    h: MipAnswer,
) -> tuple[np.ndarray, float | None]:
    """The cover `best` (found at `found`) or HiGHS's answer `h`, whichever is cheaper; on a
    tie HiGHS's, which does not depend on how far the search got."""
    mip = None if h.x is None else np.flatnonzero(h.x[: g.A.shape[1]] > 0.5)
    if mip is None or not _reaches(g.A, mip, g.w, required) or c[mip].sum() > c[best].sum():
        return best, found
    cheaper = c[mip].sum() < c[best].sum()
    return prune_partial(g.A, mip, c, g.w, required), time.perf_counter() if cheaper else found


def _walk(
    g: _Merged,
    c: np.ndarray,
    start: np.ndarray,
    required: float,
    deadline: float,
    bound: float,
    stop: Callable[[], bool],
    patience: int = 10**12,
) -> tuple[np.ndarray, float | None]:
    """The row-weighting search on the merged model from the partial cover `start` until
    `deadline`, `stop()`, the cost `bound` or `patience` steps without a cheaper cover: (a
    partial cover no dearer, time found or None)."""
    if not rowweight.compiled(deadline - time.perf_counter()):
        return start, None
    budget = float(g.w.sum()) - required + _slack(g.w)
    found, at = rowweight.search(
        g.A,
        c,
        start,
        deadline,
        target=bound,
        patience=patience,
        stop=stop,
        area=g.w,
        budget=budget,
    )
    if at is None or not _reaches(g.A, found, g.w, required) or c[found].sum() >= c[start].sum():
        return start, None
    return prune_partial(g.A, found, c, g.w, required), at


def _status(model_status: highspy.HighsModelStatus, closed: bool) -> str:
    """Truthful status: "optimal" only when the dual bound meets the cost."""
    if closed:
        return "optimal"
    if model_status == highspy.HighsModelStatus.kTimeLimit:
        return "time_limit"
    return "gap_limit" if model_status == highspy.HighsModelStatus.kOptimal else "heuristic"


def _model(g: _Merged, c: np.ndarray, required: float, counts: bool) -> highspy.HighsLp:
    """`_rows`'s model as HiGHS takes it (what the MIP's process builds)."""
    return _rows(g, c, required, counts).highs()


def _rows(g: _Merged, c: np.ndarray, required: float, counts: bool) -> RowModel:
    """The model over columns (x (n), z (m)) and rows (A x - z >= 0 (m), w·z/W >= f), with
    `counts` also B x - z >= 0 on the rows with a fractional entry (`problem.count_rows`)."""
    m, n = g.A.shape
    total = float(g.w.sum())
    fractional = fractional_rows(g.A)
    counted = fractional if counts else fractional[:0]
    B = count_rows(g.A, counted) if counts else sp.csr_array((0, n))
    x_part = sp.vstack([g.A, sp.csr_array((1, n)), B])
    eye = sp.eye_array(m, format="csr")
    z_part = sp.vstack([-eye, sp.csr_array(g.w[None, :] / total), -eye[counted]])
    forced = g.w > total - required  # cannot be left out
    integral_z = np.zeros(m, dtype=bool)  # z_i continuous where every coefficient is 1
    integral_z[fractional] = True
    return RowModel(
        M=sp.csc_array(sp.hstack([x_part, z_part])),
        cost=np.concatenate([c, np.zeros(m)]),
        col_lower=np.concatenate([np.zeros(n), forced.astype(float)]),
        col_upper=np.ones(n + m),
        row_lower=np.concatenate([np.zeros(m), [required / total], np.zeros(counted.size)]),
        integer=np.concatenate([np.ones(n, dtype=bool), integral_z]),
    )


def seen_columns(
    A: sp.csr_array, w: np.ndarray, selected: np.ndarray, fraction: float, costs: np.ndarray
) -> np.ndarray:
    """`selected` (K,) columns grown until the rows of A (M, N) their coefficients add up to 1
    in weigh at least `fraction` of the weight w (M,) of the rows any column has an entry in:
    greedily (`lazy_picks`), the column adding the most Σ_i w_i min(r_i, A_ij) per cost
    (costs, (N,)) first, as greedy_partial does; sorted. With A what each view samples of a
    row at whatever density (CoverModel.seen_rows), a partial cover's rows left short of the
    target are still seen."""
    csc = sp.csc_array(A)
    ip, ix, dv = csc.indptr, csc.indices, csc.data
    need = seen_need(A, w, fraction) - _slack(w)
    r = np.maximum(1.0 - coverage(A, selected), 0.0)
    r[r <= BUILD_TOL] = 0.0
    chosen = set(int(j) for j in selected)

    def gain(j: int) -> float:
        """Column j's progress on the rows still short."""
        if j in chosen:
            return 0.0
        rows = ix[ip[j] : ip[j + 1]]
        return float((np.minimum(r[rows], dv[ip[j] : ip[j + 1]]) * w[rows]).sum())

    picks = lazy_picks(A.shape[1], costs, gain)
    while float(w[r <= BUILD_TOL].sum()) < need and (j := next(picks, None)) is not None:
        rows = ix[ip[j] : ip[j + 1]]
        r[rows] = np.maximum(r[rows] - dv[ip[j] : ip[j + 1]], 0.0)
        r[r <= BUILD_TOL] = 0.0
        chosen.add(j)
    return np.array(sorted(chosen), dtype=np.int64)


def prune_seen(
    A: sp.csr_array,
    w: np.ndarray,
    required: float,
    seen: tuple[sp.csr_array, np.ndarray, float],
    selected: np.ndarray,
    costs: np.ndarray,
) -> np.ndarray:
    """(K',) sorted subset of `selected` (K,) that still satisfies rows of A (M, N) weighing
    `required` of w (M,), and with `seen` = (V, v, fraction) as seen_columns takes them, rows
    of V weighing `fraction` of v's rows with an entry (prune)."""
    V, v, fraction = seen
    return prune([(A, w, required), (V, v, seen_need(V, v, fraction))], selected, costs)


def seen_need(V: sp.csr_array, v: np.ndarray, fraction: float) -> float:
    """The weight of rows of V (M, N) that must be seen: `fraction` of v (M,) over the rows
    some column has an entry in (seen_columns' target)."""
    return fraction * float(v[np.diff(V.indptr) > 0].sum())


def prune(
    checks: Sequence[tuple[sp.csr_array, np.ndarray, float]],
    selected: np.ndarray,
    costs: np.ndarray,
) -> np.ndarray:
    """(K',) sorted subset of `selected` (K,) whose columns still satisfy, for each
    (A (M, N), w (M,), need) of `checks`, rows of A weighing `need` of w: each column dropped,
    the costliest first, where all hold without it (a column the cover picked may be
    redundant once others were added for another rule)."""
    tallies = [_Tally(sp.csc_array(m), coverage(m, selected), wt, need) for m, wt, need in checks]
    keep = [int(j) for j in selected]
    for j in selected[np.argsort(-costs[selected], kind="stable")]:
        lost = [t.lost(int(j)) for t in tallies]
        if all(t.met - x >= t.need - _slack(t.w) for t, x in zip(tallies, lost, strict=True)):
            keep.remove(int(j))
            for t, x in zip(tallies, lost, strict=True):
                t.drop(int(j), x)
    return np.array(sorted(keep), dtype=np.int64)


class _Tally:
    """Rows of `csc` (M, N) at coverage `cov` (M,): the weight w (M,) they satisfy (`met`,
    kept as columns are dropped) against the weight they must (`need`)."""

    def __init__(self, csc: sp.csc_array, cov: np.ndarray, w: np.ndarray, need: float) -> None:
        self.csc, self.cov, self.w, self.need = csc, cov, w, need
        self.met = float(w[cov >= 1.0 - BUILD_TOL].sum())

    def lost(self, j: int) -> float:
        """The satisfied weight column j's removal would unsatisfy."""
        part = slice(self.csc.indptr[j], self.csc.indptr[j + 1])
        rows, cov = self.csc.indices[part], self.cov[self.csc.indices[part]]
        gone = (cov >= 1.0 - BUILD_TOL) & (cov - self.csc.data[part] < 1.0 - BUILD_TOL)
        return float(self.w[rows][gone].sum())

    def drop(self, j: int, lost: float) -> None:
        """Column j removed, unsatisfying `lost` of the weight."""
        part = slice(self.csc.indptr[j], self.csc.indptr[j + 1])
        self.cov[self.csc.indices[part]] -= self.csc.data[part]
        self.met -= lost


def grown(
    A: sp.csr_array, w: np.ndarray, cover: PartialCover, selected: np.ndarray, costs: np.ndarray
) -> PartialCover:
    """`cover` (of A (M, N), weights w (M,)) with the columns `selected` (K,) instead, which
    still reach its required weight, at costs (N,): the bound stays a bound, and a proven
    cover that changed is proven only where it costs no more ("heuristic" else)."""
    r = cover.result
    if np.array_equal(selected, r.selected):
        return cover
    objective = float(costs[selected].sum())
    gap = None if r.bound is None else (objective - r.bound) / max(objective, 1e-12)
    proven = r.bound is not None and objective <= r.bound + 1e-9
    status = "optimal" if proven else ("heuristic" if r.status == "optimal" else r.status)
    res = replace(r, selected=selected, objective=objective, gap=gap, status=status)
    return _outcome(A, w, res, cover.required)
