"""Row-weighting local search: covers it returns, its incremental scores, its stops, its reach."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from tests.test_cover_search import all_covers, random_instance
from tests.test_partial import brute_partial, partial_model, random_model
from vpp_core.cover import rowweight
from vpp_core.cover.greedy import greedy_cover
from vpp_core.cover.orlib import parse_orlib
from vpp_core.cover.partial import greedy_partial
from vpp_core.cover.problem import BUILD_TOL, is_cover
from vpp_core.samples import window_cover

ORLIB = Path("../shared/data/orlib-scp")


@pytest.mark.parametrize("real", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_it_finds_the_optimum_of_small_models(seed: int, real: bool) -> None:
    A, costs = random_instance(seed, real, m=40, n=16)
    start = greedy_cover(A, costs)
    optimum = all_covers(A, costs)[1].min()
    t0 = time.perf_counter()
    found, at = rowweight.search(A, costs, start, t0 + 20.0, target=optimum, seed=seed)
    assert is_cover(A, found) and at is not None and t0 < at <= time.perf_counter()
    assert costs[found].sum() == pytest.approx(optimum)


@pytest.mark.parametrize("seed", [1, 3, 9, 26])  # models where the greedy start is not optimal
def test_it_finds_the_optimum_of_small_partial_models(seed: int) -> None:
    rng = np.random.default_rng(seed)
    A = random_model(rng, 60, 16, binary=seed % 2 == 0)
    optimum = brute_partial(A.toarray(), w := rng.random(60), 0.95, np.ones(16))
    A, costs, w, required = partial_model(A, w, 0.95)  # identical rows merged, weights > 0
    start = greedy_partial(A, costs, w, required)
    t0 = time.perf_counter()
    found, at = rowweight.search(
        A, costs, start, t0 + 20.0, target=optimum, area=w, budget=w.sum() - required + 1e-9
    )
    met = A @ np.isin(np.arange(A.shape[1]), found) >= 1.0 - BUILD_TOL
    assert at is not None and found.size == optimum < start.size
    assert w[met].sum() >= required - 1e-9


@pytest.mark.parametrize("partial", [False, True])
@pytest.mark.parametrize("real", [False, True])
def test_incremental_scores_equal_a_recount(real: bool, partial: bool) -> None:
    A, costs = random_instance(3, real, m=60, n=20)
    dense = A.toarray()
    area = np.random.default_rng(3).random(60) + 0.1 if partial else None
    model = rowweight._model(A, costs, area)
    assert np.array_equal(model[-2], dense.max(axis=1))
    budget = 0.1 * area.sum() if partial else rowweight.EVERY_ROW
    S = rowweight._start(greedy_cover(A, costs), model, 0, budget)
    kappa = rowweight.PARTIAL_CREDIT  # what a row short of 1 counts per unit of coverage
    f = np.vectorize(lambda c: 1.0 if c >= 1.0 - BUILD_TOL else kappa * c)
    for _ in range(5):
        rowweight._walk(37, 1.0 - 1e-9, -np.inf, 10**9, *model, *rowweight._fields(S))
        cov = dense @ S.x
        assert S.cov == pytest.approx(cov, abs=1e-12)
        gain = (S.w[:, None] * (f(cov[:, None] + dense) - f(cov[:, None]))).sum(axis=0)
        loss = (S.w[:, None] * (f(cov[:, None]) - f(cov[:, None] - dense))).sum(axis=0)
        assert S.score == pytest.approx(np.where(S.x, -loss, gain), abs=1e-9)
        short = np.flatnonzero(cov < 1.0 - BUILD_TOL)
        assert sorted(S.short[: S.count[1]]) == list(short)
        assert sorted(S.sel[: S.count[0]]) == list(np.flatnonzero(S.x))
        assert S.money[0] == pytest.approx(costs[S.x].sum())
        assert S.money[2] == pytest.approx(model[-1][short].sum())
        best_short = dense @ S.best < 1.0 - BUILD_TOL
        assert model[-1][best_short].sum() <= budget and S.money[1] == costs[S.best].sum()


def test_it_stops_at_target_and_deadline() -> None:
    A = window_cover(3000, 150, width=0.1, seed=1)
    costs = np.ones(150)
    start = greedy_cover(A)
    t0 = time.perf_counter()
    rowweight.search(A, costs, start, t0 + 0.5)
    assert time.perf_counter() - t0 < 1.5
    t0 = time.perf_counter()
    same, _ = rowweight.search(A, costs, start, t0 + 30.0, target=len(start))  # at target
    assert time.perf_counter() - t0 < 1.0 and np.array_equal(same, np.sort(start))
    t0 = time.perf_counter()
    same, _ = rowweight.search(A, costs, start, t0 + 30.0, stop=lambda: True)  # told to stop
    assert time.perf_counter() - t0 < 1.0 and np.array_equal(same, np.sort(start))


@pytest.mark.parametrize("name, optimum", [("scp41", 429), ("scpnrf5", 13)])
def test_it_reaches_known_optima_of_or_library(name: str, optimum: int) -> None:
    path = ORLIB / f"{name}.txt"
    if not path.is_file():
        pytest.skip(f"{path} absent (shared OR-Library data)")
    A, costs = parse_orlib(path.read_text())
    start = greedy_cover(A, costs)
    assert costs[start].sum() > optimum  # greedy alone does not get there
    found, _ = rowweight.search(A, costs, start, time.perf_counter() + 10.0, target=optimum)
    assert is_cover(A, found) and costs[found].sum() == optimum
