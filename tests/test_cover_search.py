"""LP/Lagrangian bounds and reduced-cost fixing, checked against brute force."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, linprog, milp

from vpp_core.cover.lpbound import IPM_TALL, columns_worth_keeping, lagrangian, lp_bound
from vpp_core.cover.problem import is_cover
from vpp_core.cover.setcover import solve_cover
from vpp_core.samples import window_cover


def random_instance(
    seed: int, real: bool, m: int = 14, n: int = 11
) -> tuple[sp.csr_array, np.ndarray]:
    """A small coverable instance (m, n) with integer costs in [1, 5]."""
    rng = np.random.default_rng(seed)
    dense = (rng.random((m, n)) < 0.35) * (rng.uniform(0.3, 1.0, (m, n)) if real else 1.0)
    dense[np.arange(m), rng.integers(0, n, m)] = 1.0  # every row coverable
    return sp.csr_array(dense), rng.integers(1, 6, n).astype(float)


def all_covers(A: sp.csr_array, costs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(S, N) bool of every subset of columns that covers A, and (S,) their costs."""
    n = A.shape[1]
    subsets = np.array(list(itertools.product([0.0, 1.0], repeat=n)))
    ok = np.all(subsets @ A.T.toarray() >= 1.0 - 1e-9, axis=1)
    return subsets[ok].astype(bool), subsets[ok] @ costs


@pytest.mark.parametrize("real", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_lagrangian_bound_never_exceeds_the_optimum(seed: int, real: bool) -> None:
    A, costs = random_instance(seed, real)
    _, cost = all_covers(A, costs)
    rng = np.random.default_rng(seed)
    for u in [rng.random(A.shape[0]) * s for s in (0.5, 2.0, 10.0)]:
        assert lagrangian(A, costs, u)[0] <= cost.min() + 1e-9


@pytest.mark.parametrize("rows", [14, 40])  # 40 x 11: tall, the interior point's models
@pytest.mark.parametrize("real", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_lp_bound_is_the_lp_value(seed: int, real: bool, rows: int) -> None:
    A, costs = random_instance(seed, real, m=rows)
    assert (rows > IPM_TALL * A.shape[1]) == (rows == 40)  # both of lp_bound's LP solvers
    ref = linprog(costs, A_ub=-A.toarray(), b_ub=-np.ones(A.shape[0]), bounds=(0, 1))
    lp = lp_bound(A, costs, 10.0)
    assert lp.status == "optimal"
    assert lp.bound == pytest.approx(ref.fun, rel=1e-7)
    assert lp.bound <= all_covers(A, costs)[1].min() + 1e-9


@pytest.mark.parametrize("rows", [14, 40])
@pytest.mark.parametrize("real", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_reduced_cost_fixing_keeps_every_cheaper_cover(seed: int, real: bool, rows: int) -> None:
    A, costs = random_instance(seed, real, m=rows)
    subsets, cost = all_covers(A, costs)
    lp = lp_bound(A, costs, 10.0)
    for incumbent in np.unique(cost)[:4]:
        keep = columns_worth_keeping(lp, float(incumbent), 1.0)
        cheaper = subsets[cost <= incumbent - 1.0]
        assert not np.any(cheaper & ~keep), "a column of a cheaper cover was fixed out"


def test_window_cover_shape_and_values() -> None:
    A = window_cover(5000, 200, width=0.02, drop=0.05, seed=3)
    assert A.shape == (5000, 200)
    per_col = np.diff(sp.csc_array(A).indptr)
    assert 0.9 * 100 <= per_col.mean() <= 100  # 2 % of the rows, 5 % dropped
    assert A.data.min() >= 0.26 and A.data.max() <= 0.55
    binary = window_cover(5000, 200, values=None, seed=3)
    assert set(np.unique(binary.data)) == {1.0}


@pytest.mark.parametrize("binary", [False, True])
def test_optimal_claim_on_window_instance_matches_an_independent_milp(binary: bool) -> None:
    A = window_cover(1500, 40, width=0.2, values=None if binary else (0.26, 0.55), seed=2)
    res = solve_cover(A, time_limit=60.0)
    assert is_cover(A, res.selected)
    ref = milp(
        np.ones(A.shape[1]),
        constraints=LinearConstraint(A, lb=np.ones(A.shape[0])),
        integrality=np.ones(A.shape[1]),
        bounds=Bounds(0, 1),
    )
    assert ref.success
    if res.status == "optimal":
        assert res.objective == pytest.approx(ref.fun)
    assert res.bound is not None and res.bound <= ref.fun + 1e-6
    assert ref.fun <= res.objective + 1e-6


def test_time_limit_is_kept_on_a_hard_instance() -> None:
    A = window_cover(40000, 800, seed=4)
    res = solve_cover(A, time_limit=3.0)
    assert res.time_s < 3.0 + 2.0
    assert is_cover(A, res.selected) and res.status in ("time_limit", "optimal")
    assert res.bound is not None and res.bound <= res.objective


def test_lp_bound_survives_a_change_of_thread_count() -> None:
    A, costs = random_instance(0, True)
    ref = linprog(costs, A_ub=-A.toarray(), b_ub=-np.ones(A.shape[0]), bounds=(0, 1))
    for threads in (1, 2, 1):
        assert lp_bound(A, costs, 10.0, threads).bound == pytest.approx(ref.fun, rel=1e-7)
