"""A short visiting order over camera positions: nearest neighbour, then 2-opt (open path)."""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial.distance import cdist

EXACT_UP_TO = 8
"""Paths over at most this many points are found by enumeration (8! = 40 320 orders)."""
STARTS = 8
"""Nearest-neighbour starts tried (each improved by 2-opt) above EXACT_UP_TO."""


def visiting_order(positions: np.ndarray) -> np.ndarray:
    """(K,) int64 permutation of (K, 3) positions giving a short open path."""
    if len(positions) <= 2:
        return np.arange(len(positions))
    dist = cdist(positions, positions)
    if len(positions) <= EXACT_UP_TO:
        return _exact(dist)
    starts = np.unique(np.linspace(0, len(dist) - 1, STARTS).astype(int))
    tours = [_two_opt(_nearest_neighbour(dist, int(s)), dist) for s in starts]
    return min(tours, key=lambda t: _length(dist, t))


def _length(dist: np.ndarray, order: np.ndarray) -> float:
    """Length of an open path given the distance matrix."""
    return float(dist[order[:-1], order[1:]].sum())


def _exact(dist: np.ndarray) -> np.ndarray:
    """Shortest open path by enumerating all orders (small K only)."""
    perms = np.array(list(itertools.permutations(range(len(dist)))))
    lengths = dist[perms[:, :-1], perms[:, 1:]].sum(axis=1)
    return np.asarray(perms[int(np.argmin(lengths))], dtype=np.int64)


def path_length(positions: np.ndarray, order: np.ndarray) -> float:
    """Length (mm) of the open path visiting `positions` in `order`."""
    pts = positions[order]
    return float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())


def _nearest_neighbour(dist: np.ndarray, start: int = 0) -> np.ndarray:
    """Greedy path from `start`, always on to the nearest unvisited point."""
    order = [start]
    free = np.ones(len(dist), dtype=bool)
    free[start] = False
    for _ in range(len(dist) - 1):
        row = np.where(free, dist[order[-1]], np.inf)
        nxt = int(np.argmin(row))
        order.append(nxt)
        free[nxt] = False
    return np.asarray(order, dtype=np.int64)


def _two_opt(order: np.ndarray, dist: np.ndarray, max_rounds: int = 100) -> np.ndarray:
    """Reverse segments of an open path while that shortens it (best k for each i)."""
    order = order.copy()
    for _ in range(max_rounds):
        improved = False
        for i in range(len(order) - 1):
            gain = _gains(order, dist, i)
            k = int(np.argmax(gain))
            if gain[k] > 1e-9:
                order[i : i + k + 2] = order[i : i + k + 2][::-1]
                improved = True
        if not improved:
            break
    return order


def _gains(order: np.ndarray, dist: np.ndarray, i: int) -> np.ndarray:
    """Length saved by reversing order[i..k], for k = i+1 .. K-1."""
    b, c = order[i], order[i + 1 :]
    d = np.append(order[i + 2 :], -1)
    tail = np.where(d >= 0, dist[c, np.maximum(d, 0)] - dist[b, np.maximum(d, 0)], 0.0)
    if i == 0:
        return tail
    a = order[i - 1]
    return np.asarray(tail + dist[a, b] - dist[a, c])
