"""Visiting order: a permutation, and no longer than the given order or nearest neighbour."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from vpp_core.plan.tour import _nearest_neighbour, path_length, visiting_order


@pytest.mark.parametrize("seed", range(5))
def test_order_is_a_short_permutation(seed):
    pts = np.random.default_rng(seed).random((40, 3)) * 500
    order = visiting_order(pts)
    assert sorted(order.tolist()) == list(range(40))
    nn = _nearest_neighbour(cdist(pts, pts))
    assert path_length(pts, order) <= path_length(pts, nn) + 1e-9
    assert path_length(pts, order) < 0.5 * path_length(pts, np.arange(40))


def test_small_sets_are_optimal():
    pts = np.random.default_rng(7).random((7, 3))
    best = min(path_length(pts, np.array(p)) for p in itertools.permutations(range(7)))
    assert path_length(pts, visiting_order(pts)) <= best * 1.05
    assert visiting_order(pts[:1]).tolist() == [0] and len(visiting_order(pts[:0])) == 0
