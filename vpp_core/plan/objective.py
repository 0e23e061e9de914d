"""The plan objective applied to the cover: `views` keeps the fewest-views cover; `cycle_time`
also solves a cover weighted by each candidate's estimated share of a cycle (s) and keeps
whichever of the two has the shorter toured cycle (both measured with vpp_core.plan.cycle)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vpp_core.cover.partial import PartialCover
from vpp_core.plan.cycle import Objective, TourOut, make_tour, view_costs

MIN_COST = 1e-6
"""Least column cost (s): the solvers need costs > 0 (dwell 0 next to another view)."""


def by_objective(
    cover: PartialCover,
    objective: Objective,
    positions: np.ndarray,
    resolve: Callable[[np.ndarray], PartialCover],
) -> tuple[PartialCover, TourOut | None]:
    """The cover the objective keeps and its tour (None: tour it later, objective `views`).
    `cover` is the fewest-views cover; `resolve(costs)` solves the same cover with (N,) column
    costs (s); `positions` (N, 3) mm are the candidates'."""
    if objective.name == "views" or len(cover.result.selected) == 0:
        return cover, None
    first = make_tour(positions, cover.result.selected, objective)
    anchors = positions[cover.result.selected]
    if objective.home is not None:
        anchors = np.vstack([anchors, objective.home])
    weighted = resolve(np.maximum(view_costs(positions, anchors, objective), MIN_COST))
    second = make_tour(positions, weighted.result.selected, objective)
    if second.cycle_time_s < first.cycle_time_s:
        return weighted, second.model_copy(update={"cover": "weighted"})
    return cover, first
