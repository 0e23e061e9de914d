"""Reductions of the covering ILP keep the optimum: checked against brute force on small models."""

from __future__ import annotations

import itertools

import numpy as np
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from vpp_core.cover.reduce import reduce_cover, undominated_columns
from vpp_core.cover.setcover import COVER_TOL, is_cover, solve_cover


def brute_optimum(A: np.ndarray, costs: np.ndarray) -> float:
    """Least cost of a cover of dense A (m, n) by enumeration (n small)."""
    best = np.inf
    for k in range(A.shape[1] + 1):
        for cols in itertools.combinations(range(A.shape[1]), k):
            cols_a = list(cols)
            if np.all(A[:, cols_a].sum(axis=1) >= 1 - COVER_TOL) and costs[cols_a].sum() < best:
                best = float(costs[cols_a].sum())
    return best


@st.composite
def models(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """Coverable models: 0/1 or real coefficients (partial coverage), unit or integer costs."""
    m, n = draw(st.integers(1, 9)), draw(st.integers(1, 8))
    real = draw(st.booleans())
    seed = draw(st.integers(0, 2**31))
    rng = np.random.default_rng(seed)
    A = (rng.random((m, n)) < draw(st.floats(0.15, 0.6))).astype(float)
    if real:
        A *= rng.choice([0.25, 0.5, 0.6, 1.0], size=(m, n))
    A[A.sum(axis=1) < 1, rng.integers(0, n)] = 1.0  # every row coverable
    costs = rng.integers(1, 4, n).astype(float) if draw(st.booleans()) else np.ones(n)
    return A, costs


@settings(max_examples=300, deadline=None)
@given(models())
def test_reductions_keep_the_optimum(model: tuple[np.ndarray, np.ndarray]) -> None:
    A, costs = model
    red = reduce_cover(sp.csr_array(A), costs)
    R = red.matrix.toarray()
    assert set(red.fixed).isdisjoint(red.columns)
    rest = brute_optimum(R, costs[red.columns]) if R.shape[0] else 0.0
    assert costs[red.fixed].sum() + rest == brute_optimum(A, costs)


@settings(max_examples=150, deadline=None)
@given(models())
def test_solve_cover_with_reductions_is_optimal_and_a_cover(model) -> None:
    A, costs = model
    result = solve_cover(sp.csr_array(A), costs, time_limit=10)
    assert is_cover(sp.csr_array(A), result.selected)
    assert result.status == "optimal"
    assert result.objective == brute_optimum(A, costs) == result.bound


def dominates(A: np.ndarray, costs: np.ndarray, k: int, j: int) -> bool:
    """Column k fully covers every row j touches at no higher cost; of two equal full columns
    at one cost the first dominates (the definition, pair by pair). A column that touches no
    row is left alone (`blocks` leaves it out)."""
    rows = A[:, j] > 0
    if k == j or not rows.any() or costs[k] > costs[j] or np.any(A[rows, k] < 1 - COVER_TOL):
        return False
    twin = np.array_equal(A[:, k] > 0, rows) and np.all(A[rows, j] >= 1 - COVER_TOL)
    return not (twin and costs[k] == costs[j] and k > j)


@settings(max_examples=300, deadline=None)
@given(models(), st.integers(0, 3))
def test_a_column_is_dropped_exactly_when_another_dominates_it(model, copies: int) -> None:
    """Pair by pair against the definition, with copied columns (ties) in the model."""
    A, costs = model
    for j in range(min(copies, A.shape[1] - 1)):
        A[:, j + 1], costs[j + 1] = A[:, j], costs[j]
    n = A.shape[1]
    expected = [j for j in range(n) if not any(dominates(A, costs, k, j) for k in range(n))]
    assert undominated_columns(sp.csr_array(A), costs).tolist() == expected


def test_dominated_and_identical_columns_go_essential_columns_are_fixed() -> None:
    A = np.array(
        [
            [1, 1, 0, 0, 0],  # col 1 covers what col 0 covers and more
            [0, 1, 0, 1, 1],  # cols 3 and 4 identical: col 3 kept
            [0, 0, 1, 1, 1],
            [0, 0, 1, 0, 0],  # only col 2: essential
        ],
        dtype=float,
    )
    red = reduce_cover(sp.csr_array(A), np.ones(5))
    # col 2 is essential; then col 1 dominates 0, 3 and 4, and becomes essential itself
    assert red.fixed.tolist() == [1, 2] and red.matrix.shape == (0, 0)
    assert red.sizes["dominated_cols"] == 3 and red.sizes["rows_after"] == 0
    costly = reduce_cover(sp.csr_array(A), np.array([1.0, 5.0, 1.0, 1.0, 1.0]))
    assert 1 in costly.columns and 4 not in costly.columns  # no dominance at a higher cost


def test_partial_coverage_is_rescaled_after_fixing() -> None:
    # row 0 needs col 0 (alone) ... col 0 gives row 1 half its demand; 0.25 + 0.25 then suffices
    A = np.array([[1.0, 0, 0], [0.5, 0.25, 0.25], [0, 0.5, 0.5]])
    red = reduce_cover(sp.csr_array(A), np.ones(3))
    assert red.fixed.tolist() == [0]
    assert brute_optimum(red.matrix.toarray(), np.ones(len(red.columns))) + 1 == brute_optimum(
        A, np.ones(3)
    )
