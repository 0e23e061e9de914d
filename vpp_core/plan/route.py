"""The visiting order as a travelling-salesman tour through a depot: OR-Tools routing.

Nodes 0..K-1 are the views, node K the depot: the home pose (the tour leaves it and comes
back) or, without one, a dummy node at zero cost from and to every view (the tour is then an
open path with free ends). Costs are any (K+1, K+1) matrix (mm of travel, or seconds).
OR-Tools' guided local search starts from nearest neighbour + 2-opt and keeps the best tour
it finds, so it is never longer than that start (docs/cell.md for the measurements).
"""

from __future__ import annotations

import itertools

import numpy as np

EXACT_UP_TO = 8
"""Tours through at most this many views are found by enumeration (8! = 40 320 orders)."""
STARTS = 8
"""First views tried by the nearest-neighbour start (each improved by 2-opt)."""
SCALE = 1e6
"""Largest arc cost after scaling to the integers OR-Tools works on."""
LAMBDA = 0.5
"""Guided local search penalty coefficient (OR-Tools' default 0.1 barely moved 2-opt tours
of 100 random points in 2 s; 0.5 shortened them 1.2 %, bench/tour.py)."""


def search_seconds(views: int) -> float:
    """Time given to the guided local search for `views` views (s): 0.2 s + 4 ms per view,
    at most 3 s."""
    return min(0.2 + 0.004 * views, 3.0)


def solve_route(cost: np.ndarray, seconds: float | None = None) -> tuple[np.ndarray, str]:
    """(order of the views 0..K-1, solver name) for the (K+1, K+1) cost matrix, depot last."""
    k = len(cost) - 1
    if k <= 1:
        return np.arange(k, dtype=np.int64), "exact"
    if k <= EXACT_UP_TO:
        return _exact(cost), "exact"
    start = seed_route(cost)
    limit = search_seconds(k) if seconds is None else seconds
    return _ortools(cost, start, limit), "ortools"


def route_cost(cost: np.ndarray, order: np.ndarray) -> float:
    """Cost of depot → order → depot."""
    nodes = np.concatenate([[len(cost) - 1], order, [len(cost) - 1]]).astype(np.int64)
    return float(cost[nodes[:-1], nodes[1:]].sum())


def seed_route(cost: np.ndarray) -> np.ndarray:
    """Nearest neighbour from the depot (STARTS first views), then 2-opt: the shortest."""
    k = len(cost) - 1
    firsts = np.unique(np.linspace(0, k - 1, STARTS).astype(int))
    routes = [_two_opt(_greedy(cost, int(f)), cost) for f in firsts]
    return min(routes, key=lambda r: route_cost(cost, r))


def _exact(cost: np.ndarray) -> np.ndarray:
    """The cheapest route by enumerating every order of the views (small K only)."""
    k = len(cost) - 1
    perms = np.array(list(itertools.permutations(range(k))))
    inner = cost[perms[:, :-1], perms[:, 1:]].sum(axis=1)
    total = inner + cost[k, perms[:, 0]] + cost[perms[:, -1], k]
    return np.asarray(perms[int(np.argmin(total))], dtype=np.int64)


def _greedy(cost: np.ndarray, first: int) -> np.ndarray:
    """Depot → `first`, then always on to the cheapest unvisited view."""
    k = len(cost) - 1
    order, free = [first], np.ones(k, dtype=bool)
    free[first] = False
    for _ in range(k - 1):
        nxt = int(np.argmin(np.where(free, cost[order[-1], :k], np.inf)))
        order.append(nxt)
        free[nxt] = False
    return np.asarray(order, dtype=np.int64)


def _two_opt(order: np.ndarray, cost: np.ndarray, rounds: int = 100) -> np.ndarray:
    """Reverse runs of the route (ends at the depot fixed) while that makes it cheaper.
    Costs are taken as symmetric."""
    depot = len(cost) - 1
    path = np.concatenate([[depot], order, [depot]]).astype(np.int64)
    for _ in range(rounds):
        improved = False
        for i in range(1, len(path) - 2):
            ks = np.arange(i + 1, len(path) - 1)
            a, b, c, d = path[i - 1], path[i], path[ks], path[ks + 1]
            gain = cost[a, b] + cost[c, d] - cost[a, c] - cost[b, d]
            j = int(np.argmax(gain))
            if gain[j] > 1e-12 * max(1.0, float(cost[a, b])):
                path[i : ks[j] + 1] = path[i : ks[j] + 1][::-1]
                improved = True
        if not improved:
            break
    return path[1:-1]


def _ortools(cost: np.ndarray, start: np.ndarray, seconds: float) -> np.ndarray:
    """OR-Tools routing (guided local search for `seconds`) from the route `start`."""
    from ortools.constraint_solver import pywrapcp, routing_enums_pb2

    depot = len(cost) - 1
    top = float(cost.max()) or 1.0
    arcs = np.rint(cost * (SCALE / top)).astype(np.int64)
    manager = pywrapcp.RoutingIndexManager(len(cost), 1, depot)
    model = pywrapcp.RoutingModel(manager)
    model.SetArcCostEvaluatorOfAllVehicles(model.RegisterTransitMatrix(arcs.tolist()))
    params = pywrapcp.DefaultRoutingSearchParameters()
    params.local_search_metaheuristic = (
        routing_enums_pb2.LocalSearchMetaheuristic.GUIDED_LOCAL_SEARCH
    )
    params.guided_local_search_lambda_coefficient = LAMBDA
    params.time_limit.FromMilliseconds(max(1, int(seconds * 1000)))
    model.CloseModelWithParameters(params)
    initial = model.ReadAssignmentFromRoutes([start.tolist()], True)
    found = model.SolveFromAssignmentWithParameters(initial, params)
    if found is None:
        return start
    order, index = [], model.Start(0)
    index = found.Value(model.NextVar(index))
    while not model.IsEnd(index):
        order.append(manager.IndexToNode(index))
        index = found.Value(model.NextVar(index))
    best = np.asarray(order, dtype=np.int64)
    return best if route_cost(cost, best) <= route_cost(cost, start) else start
