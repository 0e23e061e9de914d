"""Tours in joint space: travel time between joint vectors, the visiting order, path checks.

A move from q_a to q_b takes max_j |q_b,j − q_a,j| / qdot_max,j seconds: every joint moves
at once and the slowest sets the time (synchronous point-to-point motion at the speed
limits; acceleration is not modelled). The visiting order is the project's routing
(`plan.route`, passed in: exact up to 8 views, else OR-Tools guided local search) on it, from
and back to a home joint vector or as an open path. The straight joint-space path between
consecutive views can be checked for collisions at samples every `step` (rad, mm).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from vpp_core.robot.collision import Checker

Route = Callable[[np.ndarray], tuple[np.ndarray, str]]


def travel_seconds(qa: np.ndarray, qb: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """(K, M) seconds from each row of qa (K, n) to each row of qb (M, n) at joint speeds
    `speed` (n,) (rad/s, mm/s)."""
    d = np.abs(np.asarray(qa)[:, None, :] - np.asarray(qb)[None, :, :])
    return np.asarray((d / np.asarray(speed)).max(axis=2))


def travel_matrix(q: np.ndarray, speed: np.ndarray, home: np.ndarray | None) -> np.ndarray:
    """(K+1, K+1) seconds between the K joint vectors and the depot (home, or a dummy at zero
    cost from and to every view: an open path), depot last."""
    k = len(q)
    cost = np.zeros((k + 1, k + 1))
    cost[:k, :k] = travel_seconds(q, q, speed)
    if home is not None:
        cost[k, :k] = travel_seconds(home[None], q, speed)[0]
        cost[:k, k] = travel_seconds(q, home[None], speed)[:, 0]
    return cost


@dataclass(frozen=True)
class JointTour:
    """The visiting order (indices into the views) and its legs' travel times (s)."""

    order: np.ndarray
    legs_s: np.ndarray
    travel_s: float
    solver: str


def joint_tour(
    q: np.ndarray, speed: np.ndarray, home: np.ndarray | None, solve_route: Route
) -> JointTour:
    """The visiting order of joint vectors q (K, n) that is short in travel time; `solve_route`
    is the plan's routing (`plan.route.solve_route`: (K+1, K+1) cost, depot last → order)."""
    cost = travel_matrix(q, speed, home)
    order, solver = solve_route(cost) if len(q) else (np.zeros(0, dtype=np.int64), "exact")
    nodes = list(order)
    if home is not None:
        nodes = [len(q), *nodes, len(q)]
    legs = np.array([cost[a, b] for a, b in zip(nodes[:-1], nodes[1:], strict=False)])
    return JointTour(np.asarray(order, dtype=np.int64), legs, float(legs.sum()), solver)


def path_violations(
    checker: Checker, q: np.ndarray, step: float, home: np.ndarray | None = None
) -> list[dict[str, object]]:
    """Legs of the straight joint-space path through q (K, n) in the given order (and from
    and to home) whose samples every `step` (rad, mm) touch something: [{leg, from, to,
    at}] with `from`/`to` view indices (-1 = home) and `at` the first colliding fraction."""
    nodes = list(range(len(q)))
    points = list(q)
    if home is not None:
        nodes, points = [-1, *nodes, -1], [home, *points, home]
    out: list[dict[str, object]] = []
    if step <= 0:
        return out
    for leg, (a, b) in enumerate(zip(points[:-1], points[1:], strict=False)):
        count = max(2, int(np.ceil(np.abs(b - a).max() / step)) + 1)
        t = np.linspace(0.0, 1.0, count)[1:-1]
        if not len(t):
            continue
        hits = checker.colliding(a[None] + t[:, None] * (b - a)[None])
        if hits.any():
            out.append(
                {
                    "leg": leg,
                    "from": nodes[leg],
                    "to": nodes[leg + 1],
                    "at": float(t[np.argmax(hits)]),
                }
            )
    return out
