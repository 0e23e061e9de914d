"""Cycle time: the plan objective, the travel model and the tour through the chosen views.

A cell visits the views in tour order from its home pose and back: cycle time (s) = dwell_s
per view + the travel time of each leg. A leg of d mm takes d / v at speed v (mm/s), or with
an acceleration a (mm/s²) the trapezoidal profile from rest to rest: d / v + v / a when
d >= v² / a, else 2 sqrt(d / a). Reorientation is not modelled (the leg's translation only).
Without a home the tour is an open path (it starts at its first view, no legs to or from home).
"""

from __future__ import annotations

import time
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field
from scipy.spatial.distance import cdist

from vpp_core.plan.route import route_cost, solve_route


class Objective(BaseModel):
    """What a plan minimises and the cell's travel model (mm, s)."""

    model_config = ConfigDict(extra="forbid")

    name: Literal["views", "cycle_time"] = Field(
        "views",
        description="`views`: the fewest views (SPEC §4); `cycle_time`: also a cover weighted "
        "by dwell + travel, kept when its toured cycle is shorter (measured)",
    )
    dwell_s: float = Field(1.0, ge=0, le=3600, description="time spent at each view, s")
    speed_mm_s: float = Field(250.0, gt=0, le=1e5, description="travel speed, mm/s")
    accel_mm_s2: float | None = Field(
        None, gt=0, le=1e7, description="acceleration, mm/s² (none: speed reached at once)"
    )
    home: Annotated[list[float], Field(min_length=3, max_length=3)] | None = Field(
        None, description="start and end position of the cycle, mm, part frame; none: open path"
    )


class TourOut(BaseModel):
    """The visiting order and what it costs: candidate ids, mm, s."""

    order: list[int]
    """Candidate ids in visiting order (the order of `viewpoints`)."""
    length_mm: float
    """Travel length, the legs from and back to home included."""
    travel_s: float
    dwell_s: float
    cycle_time_s: float
    """dwell_s × views + travel time of every leg."""
    home: list[float] | None = None
    solver: str
    """`ortools` (guided local search from nearest neighbour + 2-opt) or `exact` (≤ 8 views)."""
    cover: Literal["views", "weighted"] = "views"
    """Which cover the tour is of: the fewest views, or the cycle-time weighted one."""
    time_s: float


def leg_seconds(dist_mm: np.ndarray, objective: Objective) -> np.ndarray:
    """Travel time (s) of legs of length `dist_mm` under the objective's motion model."""
    d, v, a = np.asarray(dist_mm, dtype=np.float64), objective.speed_mm_s, objective.accel_mm_s2
    if a is None:
        return d / v
    return np.where(d >= v * v / a, d / v + v / a, 2.0 * np.sqrt(d / a))


def route_matrix(positions: np.ndarray, home: list[float] | None) -> np.ndarray:
    """(K+1, K+1) leg lengths (mm) between the K positions and the depot (home, or a free
    dummy at zero distance: an open path), depot last."""
    k = len(positions)
    dist = np.zeros((k + 1, k + 1))
    dist[:k, :k] = cdist(positions, positions)
    if home is not None:
        dist[k, :k] = dist[:k, k] = np.linalg.norm(positions - np.asarray(home), axis=1)
    return dist


def make_tour(
    positions: np.ndarray, selected: np.ndarray, objective: Objective, seconds: float | None = None
) -> TourOut:
    """The cheapest-travel-time tour through the views `selected` (ids into (N, 3) `positions`)."""
    t0 = time.perf_counter()
    selected = np.asarray(selected, dtype=np.int64)
    dist = route_matrix(positions[selected], objective.home)
    order, solver = solve_route(leg_seconds(dist, objective), seconds)
    return tour_of(positions, selected[order], objective, solver, time.perf_counter() - t0)


def tour_of(
    positions: np.ndarray, ids: np.ndarray, objective: Objective, solver: str, seconds: float
) -> TourOut:
    """The record of visiting the candidates `ids` in this order (lengths, times recomputed)."""
    dist = route_matrix(positions[ids], objective.home)
    path = np.arange(len(ids))
    length = route_cost(dist, path) if len(ids) else 0.0
    travel = route_cost(leg_seconds(dist, objective), path) if len(ids) else 0.0
    dwell = objective.dwell_s * len(ids)
    return TourOut(
        order=[int(i) for i in ids],
        length_mm=length,
        travel_s=travel,
        dwell_s=dwell,
        cycle_time_s=dwell + travel,
        home=objective.home,
        solver=solver,
        time_s=round(seconds, 4),
    )


def view_costs(positions: np.ndarray, anchors: np.ndarray, objective: Objective) -> np.ndarray:
    """Per candidate (N,) its estimated share of a cycle (s): dwell + half the travel time to
    and from its two nearest `anchors` (A, 3) mm (the first cover's views and home; a tour
    enters and leaves each view, the classic two-neighbour bound)."""
    dist = np.sort(cdist(positions, anchors), axis=1)
    near = dist[:, 1:3] if len(anchors) > 2 else dist[:, :2]
    return np.asarray(objective.dwell_s + 0.5 * leg_seconds(near, objective).sum(axis=1))
