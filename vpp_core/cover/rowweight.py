"""Row-weighting local search for the cover min c·y, A y >= 1, y binary (A in [0, 1], M × N).

After Gao, Weise and Li's RWLS (2015), extended to costs, to real coefficients and to
partial covers (short rows of at most a budget of area). The search
keeps a set of columns cheaper than the best cover and walks from one such set to the next:
it drops the selected column that loses the least weighted demand per unit cost, adds the
column that meets the most weighted demand per unit cost in a random row left short, and
raises the weight of every row left short, so that rows the search keeps failing become
expensive to leave. Whenever the set covers the rows (all of them, or all but a budget of
their area) it is the new best, and columns are
dropped until it is cheaper again. Configuration checking (a dropped column may come back
only once a column sharing one of its rows has changed) and a tabu on the last column added
stop it from cycling.

A row's demand is 1 and its coverage c_i = Σ_j A_ij y_j counts 1 once it reaches it (from
1 - BUILD_TOL on) and PARTIAL_CREDIT · c_i below; the score of a column is the weighted
change of Σ_i w_i f(c_i) that adding (or, for a selected one, dropping) it makes. On 0/1
rows this is RWLS's score.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache

import numpy as np
import scipy.sparse as sp

from vpp_core.cover.problem import BUILD_TOL, integral_costs
from vpp_core.jit import inline, kernel

Arr = np.ndarray

CHUNK_S = 0.05
"""Seconds between two looks at the clock (the step count per call adapts to it)."""
_MET = 1.0 - BUILD_TOL
PARTIAL_CREDIT = 0.5
"""What a row short of its demand counts per unit of coverage (a met row counts 1). Counted
in full (f(c) = min(1, c)) a column that brings several rows of shares part of the way
scored as if it met them, and on patch rows, where most need two views adding up, the walk
stalled: the one-throw crankshaft stand-in's final cover stayed at 14 views on 8 seeds and
300 s, where at 0.5 it finds 13 in 3.4 s (0 found it too; docs/setcover.md, "Partial
credit"). No effect on 0/1 rows."""
EVERY_ROW = 0.5
"""The budget of short-row area that asks for every row to be met, rows weighing 1 each."""


@inline
def _f(c: float) -> float:
    """Coverage that counts toward a row's demand of 1."""
    return 1.0 if c >= _MET else PARTIAL_CREDIT * c


@inline
def _contrib(c: float, a: float, w: float, selected: bool) -> float:
    """Score a column with entry a gets from a row of coverage c and weight w."""
    if selected:
        return -w * (_f(c) - _f(c - a))
    return w * (_f(c + a) - _f(c))


@dataclass
class _State:
    """The walk: selection, coverage, weights, scores and the best cover so far."""

    x: Arr  # (N,) bool, selected
    sel: Arr  # (N,) int64, the selected columns in sel[:count[0]]
    where: Arr  # (N,) int64, position in sel or -1
    cov: Arr  # (M,) coverage
    w: Arr  # (M,) row weights
    score: Arr  # (N,) score of adding (not selected) or dropping (selected)
    stamp: Arr  # (N,) int64, step of the last change
    canadd: Arr  # (N,) bool, configuration checking
    short: Arr  # (M,) int64, the rows left short in short[:count[1]]
    spot: Arr  # (M,) int64, position in short or -1
    best: Arr  # (N,) bool, best cover
    count: Arr  # (5,) int64: selected, short rows, step, tabu column, step of the best
    money: Arr  # (5,) float64: current cost, best cost, area of the short rows, budget,
    # 1 / mean row area


@kernel
def _flip(
    j: int, cp: Arr, ci: Arr, cd: Arr, rp: Arr, ri: Arr, rd: Arr, costs: Arr, rowmax: Arr,
    area: Arr, x: Arr, sel: Arr, where: Arr, cov: Arr, w: Arr, score: Arr, stamp: Arr,
    canadd: Arr, short: Arr, spot: Arr, count: Arr, money: Arr,
) -> None:  # fmt: skip
    """Select column j if it is not selected, else drop it; keep every score up to date."""
    on = not x[j]
    for q in range(cp[j], cp[j + 1]):
        i, a = ci[q], cd[q]
        old = cov[i]
        new = old + a if on else old - a
        if new < 0.5 * BUILD_TOL:
            new = 0.0
        quiet = min(old, new) - rowmax[i] >= _MET  # every column's share of row i stays 0
        for p in range(rp[i], rp[i + 1]):
            k = ri[p]
            canadd[k] = True
            if k != j and not quiet:
                score[k] += _contrib(new, rd[p], w[i], x[k]) - _contrib(old, rd[p], w[i], x[k])
        cov[i] = new
        if old >= _MET and new < _MET:
            spot[i], short[count[1]] = count[1], i
            count[1] += 1
            money[2] += area[i]
        elif old < _MET and new >= _MET:
            last = short[count[1] - 1]
            short[spot[i]], spot[last] = last, spot[i]
            spot[i] = -1
            count[1] -= 1
            money[2] -= area[i]
    x[j] = on
    s = 0.0
    for q in range(cp[j], cp[j + 1]):
        s += _contrib(cov[ci[q]], cd[q], w[ci[q]], on)
    score[j] = s
    stamp[j] = count[2]
    if on:
        where[j], sel[count[0]] = count[0], j
        count[0] += 1
        money[0] += costs[j]
    else:
        last = sel[count[0] - 1]
        sel[where[j]], where[last] = last, where[j]
        where[j] = -1
        count[0] -= 1
        money[0] -= costs[j]
        canadd[j] = False


@kernel
def _walk(
    steps: int, need: float, target: float, patience: int, cp: Arr, ci: Arr, cd: Arr,
    rp: Arr, ri: Arr, rd: Arr, costs: Arr, rowmax: Arr, area: Arr, x: Arr, sel: Arr,
    where: Arr, cov: Arr, w: Arr, score: Arr, stamp: Arr, canadd: Arr, short: Arr, spot: Arr,
    best: Arr, count: Arr, money: Arr,
) -> bool:  # fmt: skip
    """Run `steps` steps; a cover must be cheaper than the best by `need`. A selection is a
    cover when the rows it leaves short weigh (area) no more than the budget (money[3]).

    True once the best costs `target` or `patience` steps went by without a cheaper cover.
    """
    args = (cp, ci, cd, rp, ri, rd, costs, rowmax, area, x, sel, where, cov, w, score, stamp,
            canadd, short, spot, count, money)  # fmt: skip
    for _ in range(steps):
        count[2] += 1
        if money[2] <= money[3] and money[0] <= money[1] - need:  # a cheaper cover: keep it
            best[:] = x
            money[1], count[4] = money[0], count[2]
            if money[1] <= target + 1e-9:
                return True
        if count[2] - count[4] >= patience:
            return True
        while money[0] > money[1] - need and count[0] > 0:  # cheaper than the best again
            _flip(_drop_pick(-1, sel, count, score, costs, stamp), *args)
        if money[2] <= money[3]:
            continue
        if count[0] > 0:
            _flip(_drop_pick(count[3], sel, count, score, costs, stamp), *args)
        while money[2] > money[3]:  # add for rows left short while the money allows
            i = short[np.random.randint(count[1])]
            k = _add_pick(i, rp, ri, x, canadd, score, costs, stamp)
            if k < 0 or money[0] + costs[k] > money[1] - need:  # k < 0: only by rounding
                _weigh(rp, ri, rd, area, x, cov, w, score, short, count, money)
                break
            _flip(k, *args)
            count[3] = k
            _weigh(rp, ri, rd, area, x, cov, w, score, short, count, money)
            t = 0
            while t < count[0]:  # drop what the new column made redundant
                j = sel[t]
                if score[j] > -1e-9 and j != k:
                    _flip(j, *args)
                else:
                    t += 1
    return False


@inline
def _weigh(rp: Arr, ri: Arr, rd: Arr, area: Arr, x: Arr, cov: Arr, w: Arr, score: Arr,
           short: Arr, count: Arr, money: Arr) -> None:  # fmt: skip
    """Raise the weight of every row left short by its area over the mean area (money[4]:
    1 / mean area; 1 each where rows have no area)."""
    for t in range(count[1]):
        r = short[t]
        lift = area[r] * money[4]
        for p in range(rp[r], rp[r + 1]):
            score[ri[p]] += _contrib(cov[r], rd[p], lift, x[ri[p]])
        w[r] += lift


@inline
def _drop_pick(tabu: int, sel: Arr, count: Arr, score: Arr, costs: Arr, stamp: Arr) -> int:
    """The selected column (not `tabu` unless alone) losing least per unit cost; oldest first."""
    pick, value = -1, -np.inf
    for t in range(count[0]):
        j = sel[t]
        if j == tabu and count[0] > 1:
            continue
        v = score[j] / costs[j]
        if v > value or (v == value and stamp[j] < stamp[pick]):
            pick, value = j, v
    return pick


@inline
def _add_pick(
    i: int, rp: Arr, ri: Arr, x: Arr, canadd: Arr, score: Arr, costs: Arr, stamp: Arr
) -> int:
    """The column of row i meeting most per unit cost, allowed ones first; oldest first."""
    pick, value, checked = -1, -np.inf, False
    for p in range(rp[i], rp[i + 1]):
        k = ri[p]
        if x[k]:
            continue
        v = score[k] / costs[k]
        ok = bool(canadd[k])
        if (ok and not checked) or (
            ok == checked and (v > value or (v == value and stamp[k] < stamp[pick]))
        ):
            pick, value, checked = k, v, ok
    return pick


def search(
    A: sp.csr_array,
    costs: np.ndarray,
    selected: np.ndarray,
    deadline: float,
    *,
    target: float = -np.inf,
    patience: int = 10**12,
    seed: int = 0,
    stop: Callable[[], bool] | None = None,
    area: np.ndarray | None = None,
    budget: float = 0.0,
) -> tuple[np.ndarray, float | None]:
    """((K',) sorted cover of A (M, N) costing <= that of the cover `selected` (K,), the
    time.perf_counter() by which the walk found it: None when the walk held no cover).

    With `area` (M,) > 0 (mm²) a cover is a partial one: the rows it leaves short weigh at
    most `budget` (mm²) in all. Without, every row must be met.

    Runs until time.perf_counter() passes `deadline`, `stop()` says so (asked every CHUNK_S),
    the cost reaches `target` or `patience` steps in a row find no cheaper cover; stopped by
    either of the last two, the answer does not depend on the machine's speed. With integer
    costs a better cover must be cheaper by 1, otherwise by any amount.
    """
    m, n = A.shape
    c = np.asarray(costs, dtype=np.float64)
    start = np.sort(np.asarray(selected, dtype=np.int64))
    if m == 0 or n == 0:
        return start, None
    need = 1.0 - 1e-9 if integral_costs(c) else 1e-9 * max(1.0, float(c[selected].sum()))
    model = _model(A, c, area)
    S = _start(selected, model, seed, EVERY_ROW if area is None else budget)
    steps, found_at = 64, None
    while time.perf_counter() < deadline and not (stop is not None and stop()):
        t, best_step = time.perf_counter(), S.count[4]
        S.money[2] = model[-1][S.short[: S.count[1]]].sum()  # no drift from the running sum
        done = _walk(steps, need, float(target), patience, *model, *_fields(S))
        if S.count[4] != best_step:
            found_at = time.perf_counter()
        if done:
            break
        took = time.perf_counter() - t
        steps = int(np.clip(steps * CHUNK_S / max(took, 1e-6), 16, 10**6))
    if found_at is None:  # `selected` was not a cover and the walk found none
        return start, None
    return np.flatnonzero(S.best).astype(np.int64), found_at


def compiled(timeout: float) -> bool:
    """Whether `search` is compiled, waiting up to `timeout` s for it.

    The first call starts compiling it in a thread: numba takes about 4 s on a machine's
    first run (then loads it from its cache in a fraction of a second), and a caller that
    starts this early keeps its own time limit while it compiles.
    """
    thread = _compiling()
    thread.join(max(timeout, 0.0))
    return not thread.is_alive()


@cache
def _compiling() -> threading.Thread:
    """The thread compiling the kernels on a 2-row model (started once per process)."""
    A = sp.csr_array(np.eye(2))
    args = (A, np.ones(2), np.arange(2), time.perf_counter() + 60.0)
    thread = threading.Thread(target=search, args=args, kwargs={"patience": 1}, daemon=True)
    thread.start()
    return thread


def _finish_compiling() -> None:
    """Before a fork: let a compile under way end (numba's lock must not be held in the child)."""
    if _compiling.cache_info().currsize:
        _compiling().join()


os.register_at_fork(before=_finish_compiling)


def _fields(S: _State, best: bool = True) -> tuple[Arr, ...]:
    """The state's arrays in `_walk`'s order (`_flip`'s without `best`)."""
    head = (S.x, S.sel, S.where, S.cov, S.w, S.score, S.stamp, S.canadd, S.short, S.spot)
    return (*head, S.best, S.count, S.money) if best else (*head, S.count, S.money)


def _model(A: sp.csr_array, costs: Arr, area: Arr | None = None) -> tuple[Arr, ...]:
    """A (M, N) for the kernels: CSC and CSR arrays (int64 indices), costs (N,), row maxima
    (M,), row areas (M,) (None: 1 each)."""
    csc, i64 = sp.csc_array(A), np.int64
    rowmax = A.max(axis=1).toarray().ravel()  # entries are > 0: an empty row's max is 0
    area = np.ones(A.shape[0]) if area is None else np.asarray(area, dtype=np.float64)
    return (csc.indptr.astype(i64), csc.indices.astype(i64), csc.data, A.indptr.astype(i64),
            A.indices.astype(i64), A.data, costs, rowmax, area)  # fmt: skip


def _start(selected: Arr, model: tuple[Arr, ...], seed: int, budget: float = EVERY_ROW) -> _State:
    """The walk's state at the empty selection, then with the cover `selected` (K,) added;
    a selection is a cover when its short rows' area is at most `budget`."""
    cp, ci, cd, area = *model[:3], model[-1]
    m, n = model[3].size - 1, cp.size - 1
    scale = 1.0 / float(area.mean()) if m else 1.0
    w = area * scale  # a row's weight starts at its area over the mean area
    credit = np.where(cd >= _MET, 1.0, PARTIAL_CREDIT * cd)  # f(a) - f(0) of each entry
    gain = np.bincount(np.repeat(np.arange(n), np.diff(cp)), credit * w[ci], n)
    S = _State(
        x=np.zeros(n, dtype=np.bool_), sel=np.zeros(n, dtype=np.int64),
        where=np.full(n, -1, dtype=np.int64), cov=np.zeros(m), w=w,
        score=gain.astype(np.float64),
        stamp=np.zeros(n, dtype=np.int64), canadd=np.ones(n, dtype=np.bool_),
        short=np.arange(m, dtype=np.int64), spot=np.arange(m, dtype=np.int64),
        best=np.zeros(n, dtype=np.bool_), count=np.array([0, m, 0, -1, 0], dtype=np.int64),
        money=np.array([0.0, np.inf, float(area.sum()), budget, scale]),
    )  # fmt: skip
    _seed(seed)
    for j in np.asarray(selected, dtype=np.int64):
        _flip(int(j), *model, *_fields(S, best=False))
    return S


@kernel
def _seed(seed: int) -> None:
    """Seed numba's own random generator."""
    np.random.seed(seed)
