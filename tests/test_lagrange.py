"""The Lagrangian heuristic (vpp_core.lagrange): its kernels against plain references, its
covers and bounds against exact optima."""

from __future__ import annotations

import time

import numpy as np
import pytest
import scipy.sparse as sp

from tests.test_setcover import brute_force, orlib_instance, random_instance, unit
from vpp_core import lagrange
from vpp_core.cover import as_csr, coverage, is_cover
from vpp_core.greedy import greedy_cover, lazy_greedy
from vpp_core.lpbound import lagrangian, lp_bound
from vpp_core.samples import window_cover


def sparse_instance(seed: int, binary: bool) -> tuple[sp.csr_array, np.ndarray]:
    """(300, 1500) random cover, 3 % dense, every row coverable; integer costs in [1, 100]."""
    rng = np.random.default_rng(seed)
    A = sp.random_array((300, 1500), density=0.03, rng=rng, format="csr")
    A.data = np.ones_like(A.data) if binary else rng.uniform(0.2, 1.0, A.data.size)
    one = sp.csr_array((np.ones(300), (np.arange(300), rng.integers(0, 1500, 300))), shape=A.shape)
    A = sp.csr_array(A + one)
    A.data = np.minimum(A.data, 1.0)
    return as_csr(A), rng.integers(1, 101, 1500).astype(np.float64)


def run_subgradient(A: sp.csr_array, costs: np.ndarray, ub: float) -> tuple[float, np.ndarray]:
    """(best L, its multipliers) of a full subgradient run from CFT's start."""
    M = lagrange.Model.of(A, costs)
    u = lagrange._initial(A, costs)
    best = u.copy()
    free = np.ones(M.n, dtype=np.bool_)
    value, _, _ = lagrange._subgradient(
        M.cp, M.ci, M.cd, M.costs, np.ones(M.m), free, u, best, ub, lagrange.MAX_ITERATIONS, 2.0,
        -np.inf,
    )  # fmt: skip
    return value, best


@pytest.mark.parametrize("binary", [True, False])
def test_subgradient_bound_is_the_lagrangian_and_near_the_lp(binary: bool) -> None:
    A, costs = sparse_instance(1, binary)
    lp = lp_bound(A, costs, 30.0)
    value, u = run_subgradient(A, costs, float(costs[greedy_cover(A, costs)].sum()))
    assert np.all(u >= 0.0)
    assert value == pytest.approx(lagrangian(A, costs, u)[0], rel=1e-9)
    assert value <= lp.bound * (1 + 1e-9)  # L(u) never passes the LP optimum
    assert value >= 0.98 * lp.bound  # and the steps get close to it


@pytest.mark.parametrize("binary", [True, False])
def test_greedy_picks_the_best_lagrangian_score_each_time(binary: bool) -> None:
    A, costs = sparse_instance(2, binary)
    M = lagrange.Model.of(A, costs)
    u = np.random.default_rng(2).uniform(0.0, 5.0, M.m)
    free = np.ones(M.n, dtype=np.bool_)
    picked = np.empty(M.n, dtype=np.int64)
    k = lagrange._greedy(M.cp, M.ci, M.cd, M.rp, M.ri, M.rd, M.costs, u, np.ones(M.m), free, picked)
    assert free.all()  # the kernel hands `free` back as it got it
    r, csc = np.ones(M.m), sp.csc_array(A)
    for q, j in enumerate(picked[:k]):  # replay: recompute every score from scratch
        met = csc.copy()
        met.data = np.minimum(csc.data, r[csc.indices])  # the demand each entry would meet
        mu = np.asarray(met.sum(axis=0)).reshape(-1)
        gamma = costs - np.asarray(met.T @ u).reshape(-1)
        score = np.where(gamma > 0, gamma / np.maximum(mu, 1e-300), gamma * mu)
        score[mu <= 0] = np.inf
        score[picked[:q]] = np.inf  # a column is picked once
        assert score[j] <= score.min() + 1e-9 * max(1.0, abs(score.min()))
        r = np.maximum(r - csc[:, [j]].toarray().reshape(-1), 0.0)
        r[r <= 5e-10] = 0.0
    assert np.all(r == 0.0)
    if binary:  # at u = 0 it is the cost-effectiveness greedy
        k0 = lagrange._greedy(
            M.cp, M.ci, M.cd, M.rp, M.ri, M.rd, M.costs, np.zeros(M.m), np.ones(M.m), free, picked
        )
        assert picked[:k0].tolist() == lazy_greedy(csc, costs, np.ones(M.m))


def test_greedy_meets_residual_demand_and_reports_the_impossible() -> None:
    A, costs = sparse_instance(3, binary=False)
    M = lagrange.Model.of(A, costs)
    rng = np.random.default_rng(0)
    r = rng.uniform(0.0, 1.0, M.m) * (rng.random(M.m) < 0.5)
    free = rng.random(M.n) < 0.9
    picked = np.empty(M.n, dtype=np.int64)
    u = rng.uniform(0.0, 20.0, M.m)
    k = lagrange._greedy(M.cp, M.ci, M.cd, M.rp, M.ri, M.rd, M.costs, u, r, free.copy(), picked)
    if k >= 0:
        sel = picked[:k]
        assert free[sel].all() and np.unique(sel).size == k
        assert np.all(coverage(A, sel) >= r - 1e-9)
    short = sp.csr_array(A[:, :10])  # ten columns leave rows without any column
    Ms = lagrange.Model.of(short, costs[:10])
    out = np.empty(10, dtype=np.int64)
    args = (Ms.cp, Ms.ci, Ms.cd, Ms.rp, Ms.ri, Ms.rd, Ms.costs, np.zeros(Ms.m), np.ones(Ms.m))
    assert lagrange._greedy(*args, np.ones(10, dtype=np.bool_), out) == -1


@pytest.mark.parametrize("binary", [True, False])
def test_prune_leaves_a_cover_without_redundant_columns(binary: bool) -> None:
    A, costs = sparse_instance(4, binary)
    M = lagrange.Model.of(A, costs)
    everything = np.arange(M.n, dtype=np.int64)
    kept = everything[lagrange._prune(M.cp, M.ci, M.cd, M.costs, np.ones(M.m), everything)]
    assert is_cover(A, kept)
    for j in kept:  # dropping any one column uncovers a row
        assert not is_cover(A, kept[kept != j])


@pytest.mark.parametrize("seed", range(12))
def test_search_on_small_instances_reaches_the_brute_force_optimum(seed: int) -> None:
    dense, costs = random_instance(seed)
    c = unit(costs, dense.shape[1])
    A = as_csr(sp.csr_array(dense))
    optimum = brute_force(dense, c)
    start = greedy_cover(A, c)
    res = lagrange.search(A, c, start, time.perf_counter() + 0.5, target=optimum)
    assert is_cover(A, res.selected)
    assert c[res.selected].sum() <= c[start].sum()
    assert c[res.selected].sum() == pytest.approx(optimum)
    assert res.bound <= optimum + 1e-9
    assert res.bound == pytest.approx(lagrangian(A, c, res.duals)[0], rel=1e-9, abs=1e-12)


@pytest.mark.parametrize("name", ["scp41", "scp51", "scp61", "scpa1"])
def test_search_comes_within_one_percent_of_orlib_optima_quickly(name: str) -> None:
    A, costs, optimum = orlib_instance(name)
    A = as_csr(A)
    lp = lp_bound(A, costs, 10.0)
    res = lagrange.search(
        A, costs, greedy_cover(A, costs), time.perf_counter() + 5.0, duals=lp.duals, target=optimum
    )
    assert is_cover(A, res.selected)
    assert optimum <= costs[res.selected].sum() <= 1.01 * optimum  # the NR target: within 1 %
    assert lp.bound - 1e-6 <= res.bound <= optimum


def test_search_bound_without_duals_is_valid_on_real_coefficients() -> None:
    A = window_cover(4000, 300, width=0.05, seed=3)
    costs = np.ones(300)
    lp = lp_bound(A, costs, 30.0)
    res = lagrange.search(A, costs, greedy_cover(A, costs), time.perf_counter() + 1.0)
    assert is_cover(A, res.selected)
    assert res.bound == pytest.approx(lagrangian(A, costs, res.duals)[0], rel=1e-9)
    assert 0.9 * lp.bound <= res.bound <= lp.bound * (1 + 1e-9)  # partial cover: slower steps
