"""Set cover (SPEC §4): OR-Library optima, brute force on real coefficients, reductions, errors."""

from __future__ import annotations

import csv
import itertools
import math
import time
from pathlib import Path

import highspy
import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from vpp_core.cover import mip, setcover
from vpp_core.cover.lpbound import LpBound
from vpp_core.cover.orlib import parse_orlib
from vpp_core.cover.reduce import blocks, unique_rows
from vpp_core.cover.setcover import (
    CoverResult,
    greedy_cover,
    is_cover,
    remove_redundant,
    solve_cover,
)
from vpp_core.errors import SolverError

ORLIB = Path(__file__).resolve().parents[1].parent / "shared/data/orlib-scp"
ORLIB_EXACT = [f"scp4{i}" for i in range(1, 11)] + [f"scp5{i}" for i in range(1, 11)]


def orlib_instance(name: str) -> tuple[sp.csr_array, np.ndarray, float]:
    """A, costs and the proven optimum of an OR-Library instance; skip when the data is absent."""
    path = ORLIB / f"{name}.txt"
    if not path.is_file() or not (ORLIB / "optima.csv").is_file():
        pytest.skip(f"OR-Library data not found at {ORLIB} (shared/data/orlib-scp)")
    with (ORLIB / "optima.csv").open(newline="") as fh:
        optima = {r["instance"]: r for r in csv.DictReader(fh)}
    assert optima[name]["optimal_proven"] == "true"
    A, costs = parse_orlib(path.read_text())
    return A, costs, float(optima[name]["best_known"])


def brute_force(dense: np.ndarray, costs: np.ndarray) -> float:
    """Minimum cost over all 2^N column subsets that cover every row (inf when none does)."""
    n = dense.shape[1]
    subsets = ((np.arange(1 << n)[:, None] >> np.arange(n)) & 1).astype(np.float64)
    ok = np.all(dense @ subsets.T >= 1.0 - 1e-9, axis=0)
    return float((subsets[ok] @ costs).min()) if ok.any() else math.inf


def random_instance(seed: int, m: int = 30, n: int = 12) -> tuple[np.ndarray, np.ndarray | None]:
    """Dense (m, n) real coverage in (0, 1] with every row coverable, and costs (n,) or None."""
    rng = np.random.default_rng(seed)
    if seed % 3 == 0:  # quantised levels: exact sums such as 1/3 + 1/3 + 1/3 and 0.25 + 0.75
        vals = rng.choice([0.25, 1 / 3, 0.5, 0.75, 1.0], size=(m, n))
    else:
        vals = rng.uniform(0.05, 1.0, size=(m, n))
    dense = np.where(rng.random((m, n)) < 0.3, vals, 0.0)
    for i in np.flatnonzero(dense.sum(axis=1) < 1.0):
        dense[i, rng.integers(n)] = 1.0
    costs = [None, rng.integers(1, 6, n).astype(np.float64), rng.uniform(0.5, 3.0, n)][seed % 3]
    return dense, costs


def unit(costs: np.ndarray | None, n: int) -> np.ndarray:
    """Costs, or all ones when None."""
    return np.ones(n) if costs is None else costs


# ---------------------------------------------------------------------------- OR-Library


@pytest.mark.parametrize("name", ORLIB_EXACT)
def test_orlib_milp_reaches_proven_optimum(name: str) -> None:
    A, costs, optimum = orlib_instance(name)
    res = solve_cover(A, costs, time_limit=60.0)
    assert res.status == "optimal"
    assert res.objective == optimum
    assert res.bound == optimum and res.gap == 0.0
    assert is_cover(A, res.selected)
    assert costs[res.selected].sum() == res.objective
    assert np.all(np.diff(res.selected) > 0) and res.selected.dtype == np.int64
    pre = res.presolve
    assert (pre["rows_before"], pre["cols_before"]) == A.shape
    assert (res.rows, res.cols) == (pre["rows_after"], pre["cols_after"]) <= A.shape


@pytest.mark.parametrize("name", ORLIB_EXACT)
def test_orlib_greedy_is_a_cover_no_better_than_optimum(name: str) -> None:
    A, costs, optimum = orlib_instance(name)
    sel = greedy_cover(A, costs)
    assert is_cover(A, sel)
    assert costs[sel].sum() >= optimum
    assert costs[sel].sum() <= 1.25 * optimum  # sanity: the greedy is a decent heuristic here
    res = solve_cover(A, costs, method="greedy")
    assert (res.status, res.bound, res.gap, res.solver) == ("heuristic", None, None, "greedy")
    np.testing.assert_array_equal(res.selected, sel)


def test_orlib_time_limit_returns_verified_incumbent_and_valid_bound() -> None:
    A, costs, optimum = orlib_instance("scpnre1")  # HiGHS cannot close this in 0.5 s
    res = solve_cover(A, costs, time_limit=0.5)
    assert res.status == "time_limit"
    assert is_cover(A, res.selected)
    assert res.bound is not None and res.gap is not None
    assert res.bound <= optimum <= res.objective
    assert res.gap == pytest.approx((res.objective - res.bound) / res.objective)
    assert res.time_s < 5.0


def stacked(*names: str) -> tuple[sp.csr_array, np.ndarray, list[float]]:
    """OR-Library instances side by side as one block-diagonal cover, and their optima."""
    parts = [orlib_instance(name) for name in names]
    A = sp.csr_array(sp.block_diag([a for a, _, _ in parts], format="csr"))
    return A, np.concatenate([c for _, c, _ in parts]), [o for _, _, o in parts]


def test_blocks_are_the_independent_covers_smallest_first() -> None:
    rng = np.random.default_rng(3)
    sizes = [(40, 9), (5, 3), (20, 6)]  # (rows, cols) of each block
    dense = sp.block_diag([(rng.random(s) < 0.5) + np.eye(*s) for s in sizes]).toarray()
    dense = np.hstack([dense, np.zeros((dense.shape[0], 1))])  # a column that sees nothing
    rows, cols = rng.permutation(dense.shape[0]), rng.permutation(dense.shape[1])
    found = blocks(sp.csr_array(dense[rows][:, cols]))
    row_of, col_of = np.argsort(rows), np.argsort(cols)  # where each original row/col went
    r0, c0 = np.cumsum([0] + [r for r, _ in sizes]), np.cumsum([0] + [c for _, c in sizes])
    expected = [
        (np.sort(row_of[r0[b] : r0[b + 1]]), np.sort(col_of[c0[b] : c0[b + 1]]))
        for b in np.argsort([dense[r0[b] : r0[b + 1]].sum() for b in range(3)])
    ]
    assert len(found) == 3
    for (rows_f, cols_f), (rows_e, cols_e) in zip(found, expected, strict=True):
        np.testing.assert_array_equal(rows_f, rows_e)
        np.testing.assert_array_equal(cols_f, cols_e)


def test_independent_blocks_are_solved_apart_and_their_optima_add_up() -> None:
    A, costs, optima = stacked("scp41", "scp51")
    res = solve_cover(A, costs, time_limit=60.0)
    assert res.presolve["blocks"] >= 2
    assert res.status == "optimal" and res.objective == res.bound == sum(optima)
    assert is_cover(A, res.selected)


def test_a_block_out_of_time_leaves_the_proven_blocks_proven() -> None:
    # scpnre1 cannot be closed in 8 s; its reductions alone take 1-3.5 s (the column
    # domination product of a 10 %-dense 500 x 5000 matrix), which a tighter limit would
    # leave to chance on a slow machine.
    A, costs, optima = stacked("scp41", "scpnre1")
    res = solve_cover(A, costs, time_limit=8.0)
    assert res.status == "time_limit" and is_cover(A, res.selected)
    assert res.bound is not None and optima[0] < res.bound <= sum(optima) <= res.objective
    assert res.time_s < 11.0


def test_a_small_block_gets_time_for_its_proof_beside_a_big_one(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    A, costs, _ = stacked("scpnre1")
    pair = sp.csr_array([[0.6, 0.6]])  # needs both columns: LP 1, optimum 2
    A = sp.csr_array(sp.block_diag([A, pair], format="csr"))
    closed: list[tuple[int, bool]] = []
    solve_block = setcover._solve_block

    def spy(sub: sp.csr_array, *args: object) -> object:
        S = solve_block(sub, *args)  # type: ignore[arg-type]
        closed.append((sub.shape[0], S.closed()))
        return S

    monkeypatch.setattr(setcover, "_solve_block", spy)
    res = solve_cover(A, np.append(costs, [1.0, 1.0]), time_limit=6.0)  # reductions: 1-3.5 s
    assert closed[0] == (1, True)  # the pair, first: proven, not starved by its tiny share
    assert res.status == "time_limit" and res.bound is not None and res.bound < res.objective


def test_time_limit_spent_before_highs_returns_greedy() -> None:
    A, costs, _ = orlib_instance("scp41")
    res = solve_cover(A, costs, time_limit=1e-9)
    assert res.status == "time_limit"
    np.testing.assert_array_equal(res.selected, greedy_cover(A, costs))
    assert res.bound is not None and 0.0 < res.bound < res.objective


def test_orlib_gap_limit_is_not_reported_as_optimal() -> None:
    A, costs, optimum = orlib_instance("scp48")  # greedy 525, optimum 492, root bound ~489
    res = solve_cover(A, costs, mip_rel_gap=0.2)
    assert res.status == "gap_limit"
    assert res.bound is not None and res.gap is not None
    assert res.bound <= optimum <= res.objective
    assert 0.0 < res.gap <= 0.2


def test_threads_option_can_change_between_calls() -> None:
    A, costs, optimum = orlib_instance("scp41")
    for threads in (1, 2, 1):
        assert solve_cover(A, costs, threads=threads).objective == optimum


# ---------------------------------------------------------------------------- brute force


@pytest.mark.parametrize("seed", range(36))
def test_milp_equals_brute_force_on_real_coefficients(seed: int) -> None:
    dense, costs = random_instance(seed)
    best = brute_force(dense, unit(costs, dense.shape[1]))
    res = solve_cover(sp.csr_array(dense), costs)
    assert res.status == "optimal" and res.gap == 0.0
    assert res.objective == pytest.approx(best, abs=1e-6)
    assert res.bound is not None and res.bound <= res.objective
    assert is_cover(sp.csr_array(dense), res.selected)


@pytest.mark.parametrize("seed", range(36))
def test_greedy_is_irredundant_cover_no_better_than_brute_force(seed: int) -> None:
    dense, costs = random_instance(seed)
    A = sp.csr_array(dense)
    sel = greedy_cover(A, costs)
    assert is_cover(A, sel)
    assert unit(costs, A.shape[1])[sel].sum() >= brute_force(dense, unit(costs, A.shape[1])) - 1e-9
    for k in range(sel.size):
        assert not is_cover(A, np.delete(sel, k)), "greedy left a redundant column"


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    m=st.integers(1, 40),
    n=st.integers(1, 10),
    density=st.floats(0.05, 0.9),
)
def test_property_greedy_and_milp_on_random_covers(
    seed: int, m: int, n: int, density: float
) -> None:
    rng = np.random.default_rng(seed)
    dense = np.where(rng.random((m, n)) < density, rng.uniform(0.01, 1.0, (m, n)), 0.0)
    costs = rng.uniform(0.1, 5.0, n)
    best = brute_force(dense, costs)
    A = sp.csr_array(dense)
    if math.isinf(best):
        with pytest.raises(SolverError):
            solve_cover(A, costs)
        return
    sel = greedy_cover(A, costs)
    assert is_cover(A, sel) and costs[sel].sum() >= best - 1e-9
    res = solve_cover(A, costs)
    assert res.status == "optimal"
    assert res.objective == pytest.approx(best, abs=1e-6)


# ---------------------------------------------------------------------------- reductions


def test_duplicate_rows_are_dropped_without_changing_the_optimum() -> None:
    dense, costs = random_instance(4)
    base = solve_cover(sp.csr_array(dense), costs)
    rng = np.random.default_rng(7)
    rows = np.concatenate([np.arange(dense.shape[0]), rng.integers(0, dense.shape[0], 50)])
    doubled = sp.csr_array(dense[rng.permutation(rows)])
    res = solve_cover(doubled, costs)
    assert res.rows == base.rows and res.presolve["rows_before"] == doubled.shape[0]
    assert res.objective == pytest.approx(base.objective, abs=1e-9)
    assert res.status == "optimal" and is_cover(doubled, res.selected)


def test_near_duplicate_rows_are_kept() -> None:
    row = np.array([0.5, 0.5, 0.0, 1.0])
    dense = np.vstack([row, row, np.nextafter(row, 2.0) * (row > 0), row[[1, 0, 2, 3]]])
    kept = unique_rows(sp.csr_array(np.minimum(dense, 1.0)))
    assert len(kept) == 2  # rows 0 and 1 merge; the 1-ulp row stays; row 3 equals row 0


def test_unique_rows_matches_exact_reference() -> None:
    rng = np.random.default_rng(3)
    base = np.where(rng.random((40, 9)) < 0.4, rng.choice([0.5, 1.0], (40, 9)), 0.0)
    dense = base[rng.integers(0, 40, 400)]
    A = sp.csr_array(dense)
    seen: dict[bytes, int] = {}
    for i, r in enumerate(dense):
        seen.setdefault(r.tobytes(), i)
    np.testing.assert_array_equal(unique_rows(A), sorted(seen.values()))


# ---------------------------------------------------------------------------- errors, edges


def test_uncoverable_rows_raise_solver_error_with_count() -> None:
    dense = np.array([[1.0, 0.0], [0.4, 0.5], [0.3, 0.3], [0.0, 1.0]])
    for method in ("milp", "greedy"):
        with pytest.raises(SolverError, match=r"\b2 of 4 rows\b"):
            solve_cover(sp.csr_array(dense), method=method)
    with pytest.raises(SolverError):
        greedy_cover(sp.csr_array(dense))
    with pytest.raises(SolverError):
        solve_cover(sp.csr_array((3, 0)))


def test_row_sum_within_tolerance_is_coverable() -> None:
    dense = np.array([[0.5, 0.5 - 2e-10, 0.0], [0.0, 0.0, 1.0]])
    res = solve_cover(sp.csr_array(dense))
    np.testing.assert_array_equal(res.selected, [0, 1, 2])
    assert is_cover(sp.csr_array(dense), res.selected)
    assert not is_cover(sp.csr_array(dense), res.selected, tol=1e-12)


def test_zero_rows_give_empty_optimal_selection() -> None:
    res = solve_cover(sp.csr_array((0, 5)))
    assert isinstance(res, CoverResult)
    assert res.selected.shape == (0,) and res.selected.dtype == np.int64
    assert (res.status, res.objective, res.rows, res.cols) == ("optimal", 0.0, 0, 5)


def test_costs_change_the_optimum() -> None:
    A = sp.csr_array(np.array([[1.0, 1.0, 0.0], [1.0, 0.0, 1.0]]))
    np.testing.assert_array_equal(solve_cover(A).selected, [0])
    np.testing.assert_array_equal(solve_cover(A, np.array([5.0, 1.0, 1.0])).selected, [1, 2])
    np.testing.assert_array_equal(greedy_cover(A, np.array([5.0, 1.0, 1.0])), [1, 2])


@pytest.mark.parametrize(
    "costs", [np.array([1.0, 0.0]), np.array([1.0, -1.0]), np.array([1.0, np.nan]), np.ones(3)]
)
def test_bad_costs_raise(costs: np.ndarray) -> None:
    with pytest.raises(SolverError):
        solve_cover(sp.csr_array(np.eye(2)), costs)


@pytest.mark.parametrize("value", [1.5, -0.5, np.inf, np.nan])
def test_bad_coefficients_raise(value: float) -> None:
    with pytest.raises(SolverError):
        solve_cover(sp.csr_array(np.array([[1.0, value]])))


def test_bad_options_raise() -> None:
    A = sp.csr_array(np.eye(2))
    with pytest.raises(ValueError):
        solve_cover(A, method="simplex")
    with pytest.raises(ValueError):
        solve_cover(A, time_limit=0.0)
    with pytest.raises(ValueError):
        solve_cover(A, mip_rel_gap=-0.1)


def test_partial_coverage_needs_several_columns() -> None:
    A = sp.csr_array(np.array([[0.5, 0.5, 0.4, 0.0], [0.0, 0.6, 0.3, 1.0]]))
    assert not is_cover(A, np.array([0]))
    assert is_cover(A, np.array([0, 1, 3]))
    assert not is_cover(A, np.array([1, 2]))  # 0.9 < 1
    res = solve_cover(A)
    assert res.objective == 3.0 and is_cover(A, res.selected)
    assert res.selected.tolist() == [0, 1, 3]


def test_greedy_ties_pick_lowest_index_and_removal_keeps_it() -> None:
    A = sp.csr_array(np.ones((3, 4)))
    np.testing.assert_array_equal(greedy_cover(A), [0])
    np.testing.assert_array_equal(remove_redundant(A, np.arange(4)), [0])


def test_remove_redundant_drops_expensive_first() -> None:
    A = sp.csr_array(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 1.0]]))
    np.testing.assert_array_equal(remove_redundant(A, np.array([0, 1, 2])), [0])
    np.testing.assert_array_equal(
        remove_redundant(A, np.array([0, 1]), np.array([3.0, 1.0, 1.0])), [1]
    )
    with pytest.raises(ValueError):
        remove_redundant(A, np.array([2]))


# ---------------------------------------------------------------------------- status truth

TINY = sp.csr_array(np.array([[1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]]))
TINY_COSTS = np.array([1.0, 1.0, 3.0])  # optimum {0, 1} = 2, also the greedy's answer


def fake_highs(monkeypatch: pytest.MonkeyPatch, sel: list[int], status: str, bound: float) -> None:
    """Make solve_cover see HiGHS return `sel` with model `status` and dual `bound`."""
    x = np.zeros(TINY.shape[1])
    x[sel] = 1.0
    outcome = mip.MipAnswer(x, getattr(highspy.HighsModelStatus, status), bound)
    monkeypatch.setattr(setcover, "_start_highs", lambda *args, **kwargs: Answered(outcome))
    everything = np.ones(TINY.shape[1], dtype=bool)  # no column fixed
    monkeypatch.setattr(setcover, "columns_worth_keeping", lambda lp, *a: everything.copy())
    monkeypatch.setattr(setcover, "lp_bound", weak_lp)


class Answered(mip.Pending):
    """A HiGHS run that has already answered `outcome`."""

    def __init__(self, outcome: mip.MipAnswer) -> None:
        super().__init__(None, 0.0, 0.0)
        self.outcome = outcome

    def answer(self) -> mip.MipAnswer:
        return self.outcome


def weak_lp(A: sp.csr_array, costs: np.ndarray, *args: object) -> LpBound:
    """An LP bound of zero (multipliers all zero), so only the faked HiGHS can close the gap."""
    z = np.zeros(A.shape[0])
    return LpBound(0.0, z, costs.copy(), np.zeros(A.shape[1]), "fake", 0.0)


def random_cover_model(seed: int) -> tuple[sp.csr_array, np.ndarray, np.ndarray]:
    """A small random cover model (0/1 for even seeds, real coefficients for odd), unit costs,
    and row weights in [0.1, 1) for partial covers."""
    rng = np.random.default_rng(seed)
    m, n = rng.integers(5, 40), rng.integers(5, 30)
    A = (rng.random((m, n)) < rng.uniform(0.1, 0.5)).astype(float)
    if seed % 2:
        A *= rng.choice([0.25, 0.5, 0.6, 1.0], size=(m, n))
    A[A.sum(axis=1) < 1, rng.integers(0, n)] = 1.0
    return sp.csr_array(A), np.ones(n), rng.uniform(0.1, 1.0, m)


def fewest_columns(A: np.ndarray) -> int:
    """The least number of columns of dense A (m, n) whose sums reach 1 in every row."""
    for k in range(1, A.shape[1] + 1):
        combos = np.array(list(itertools.combinations(range(A.shape[1]), k)))
        if (A[:, combos].sum(axis=2) >= 1 - 1e-9).all(axis=0).any():
            return k
    raise AssertionError("not coverable")


@pytest.mark.parametrize("seed", [60, 108, 141, 147])
def test_highs_answer_that_contradicts_itself_is_not_trusted(seed: int) -> None:
    # Warm-started from the greedy cover, HiGHS 1.16 says "optimal" on these models at an
    # objective below the cost of the solution it returns (the greedy start, or worse than
    # the optimum); the driver then saw a false gap ("gap_limit") or kept a worse cover.
    A, costs, _ = random_cover_model(seed)
    best = fewest_columns(A.toarray())
    with setcover._start_highs(A, costs, greedy_cover(A, costs), 5.0, 0.0, None) as run:
        out = run.answer()
    assert out.x is not None
    selected = np.flatnonzero(out.x > 0.5)
    assert is_cover(A, selected) and costs[selected].sum() == best
    assert best - 1e-6 <= out.dual_bound <= best + 1e-9
    result = solve_cover(A, costs, time_limit=5)
    assert (result.status, result.objective, result.bound) == ("optimal", best, best)


def test_infeasible_highs_solution_is_repaired_and_not_optimal(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    fake_highs(monkeypatch, [0], "kOptimal", 2.0)
    res = solve_cover(TINY, TINY_COSTS)
    assert res.selected.tolist() == [0, 1] and is_cover(TINY, res.selected)
    assert res.status == "heuristic"


def test_open_gap_with_model_optimal_is_gap_limit(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_highs(monkeypatch, [0, 1], "kOptimal", 1.0)
    res = solve_cover(TINY, TINY_COSTS)
    assert (res.status, res.bound, res.gap) == ("gap_limit", 1.0, 0.5)


def test_integer_costs_round_the_bound_up(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_highs(monkeypatch, [0, 1], "kOptimal", 1.2)
    res = solve_cover(TINY, TINY_COSTS)
    assert (res.status, res.bound, res.gap) == ("optimal", 2.0, 0.0)


def test_large_integer_costs_need_the_gap_closed_exactly(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_highs(monkeypatch, [0, 1], "kOptimal", 2e7 - 1)
    res = solve_cover(TINY, TINY_COSTS * 1e7)
    assert (res.status, res.bound, res.objective) == ("gap_limit", 2e7 - 1, 2e7)


def test_real_costs_do_not_round_the_bound(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_highs(monkeypatch, [0, 1], "kOptimal", 2.0)
    res = solve_cover(TINY, TINY_COSTS + 0.1)
    assert res.status == "gap_limit" and res.bound == 2.0


def test_worse_highs_incumbent_loses_to_greedy(monkeypatch: pytest.MonkeyPatch) -> None:
    fake_highs(monkeypatch, [2], "kTimeLimit", 0.9)
    res = solve_cover(TINY, TINY_COSTS)
    assert (res.selected.tolist(), res.status, res.objective) == ([0, 1], "time_limit", 2.0)


@pytest.mark.parametrize("threads", [None, 1])
@pytest.mark.parametrize("bound, one_unit", [(3.0, True), (2.0, False)])
def test_gap_of_one_unit_after_the_quick_run_goes_to_one_cold_highs_run(
    monkeypatch: pytest.MonkeyPatch, bound: float, one_unit: bool, threads: int | None
) -> None:
    # Costs 2, 2, 6: greedy and optimum cost 4. A quick HiGHS run that leaves bound 3 leaves
    # one unit: the rest of the time goes at once to one cold HiGHS run, the search beside it.
    # Otherwise the search runs first, then HiGHS from its cover, the search again beside it.
    # With one thread, the search never runs beside HiGHS.
    fake_highs(monkeypatch, [0, 1], "kTimeLimit", bound)
    runs: list[tuple[object, float]] = []  # (start, time limit) of each HiGHS run
    faked = setcover._start_highs
    monkeypatch.setattr(setcover, "_start_highs", lambda *a, **k: runs.append(a[2:4]) or faked())
    walks: list[bool] = []  # whether each walk ran beside HiGHS
    monkeypatch.setattr(
        setcover._Search, "walk", lambda self, deadline, *a, stop=None: walks.append(bool(stop))
    )
    res = solve_cover(TINY, TINY_COSTS * 2, time_limit=60, threads=threads)
    assert (res.objective, res.bound, res.status) == (4.0, bound, "time_limit")
    assert len(runs) == 2 and runs[1][1] > 5 * runs[0][1] > 0 and runs[0][0] is not None
    assert walks == ([] if one_unit else [False]) + ([True] if threads is None else [])
    assert (runs[1][0] is None) == one_unit  # the long run starts cold after a one-unit gap


def test_no_highs_run_starts_once_the_lp_has_spent_the_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # On a loaded machine the in-process LP can overrun its share; each HiGHS run started after
    # that could add its grace (mip.GRACE_S) past the limit. None starts: the greedy cover stays.
    fake_highs(monkeypatch, [0, 1], "kOptimal", 2.0)
    runs: list[object] = []
    monkeypatch.setattr(
        setcover, "_start_highs", lambda *a, **k: runs.append(a) or Answered(mip.NO_ANSWER)
    )
    monkeypatch.setattr(setcover, "lp_bound", lambda *a: time.sleep(0.3) or weak_lp(*a))
    res = solve_cover(TINY, TINY_COSTS, time_limit=0.2)
    assert runs == [] and (res.status, res.objective) == ("time_limit", 2.0)


# ---------------------------------------------------------------------------- OR-Library parser


def test_parse_orlib_small_text_any_line_breaks() -> None:
    text = "3 4\n 2 1\n 3 1 \n 1\n1 2 3\n 4 2\n 2 3"
    A, costs = parse_orlib(text)
    np.testing.assert_array_equal(costs, [2, 1, 3, 1])
    expected = np.array([[1, 0, 0, 0], [0, 0, 1, 1], [0, 1, 1, 0]], dtype=np.float64)
    np.testing.assert_array_equal(A.toarray(), expected)
    assert A.dtype == np.float64 and costs.dtype == np.float64


def test_parse_orlib_repeated_column_counts_once() -> None:
    A, _ = parse_orlib("1 2  1 1  2 2 2")
    np.testing.assert_array_equal(A.toarray(), [[0.0, 1.0]])


@pytest.mark.parametrize(
    "text",
    [
        "",
        "3",
        "2 2 1 1 1 1",  # second row missing
        "1 2 1 1 1 3",  # column 3 > n
        "1 2 1 1 1 0",  # column 0 (ids are 1-based)
        "1 2 1 1 1 1 7",  # trailing number
        "1 2 1 x 1 1",  # not a number
        "1 2 1 1 1.5 1",  # fractional count
        "1 2 1 nan 1 1",  # cost not finite
    ],
)
def test_parse_orlib_rejects_malformed_text(text: str) -> None:
    with pytest.raises(SolverError):
        parse_orlib(text)


def test_parse_orlib_real_file_shape() -> None:
    A, costs, _ = orlib_instance("scp41")
    assert A.shape == (200, 1000) and costs.shape == (1000,)
    assert set(np.unique(A.data)) == {1.0}
    assert A.nnz == 4009  # sum of the 200 row counts in scp41.txt
