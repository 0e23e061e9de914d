"""Visiting orders compared: the old nearest neighbour + 2-opt (vpp_core.plan.tour), the new
OR-Tools route (vpp_core.plan.route) and LKH-3 through elkai (if installed; one run), on
random camera positions and on a real plan's viewpoints. Open paths: lengths in mm, times in
s; one JSON line per instance.

    python bench/tour.py [--plan PLAN.json ...] [--sizes 25,50,100,200,500] [--seeds 5]
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.distance import cdist

from vpp_core.plan.route import _ortools, route_cost, search_seconds, seed_route
from vpp_core.plan.tour import path_length, visiting_order


def open_cost(points: np.ndarray) -> np.ndarray:
    """(K+1, K+1) distances with a free dummy depot last (an open path)."""
    cost = np.zeros((len(points) + 1,) * 2)
    cost[:-1, :-1] = cdist(points, points)
    return cost


def timed(fn: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """(result, seconds) of fn(*args)."""
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def compare(points: np.ndarray) -> dict[str, float]:
    """Open-path lengths (mm) and solve times (s) of each solver on `points` (K, 3) mm."""
    cost = open_cost(points)
    old, t_old = timed(visiting_order, points)
    seed, t_seed = timed(seed_route, cost)
    new, t_new = timed(_ortools, cost, seed, search_seconds(len(points)))
    row = {
        "K": len(points),
        "old_mm": path_length(points, old),
        "old_s": t_old,
        "ortools_mm": route_cost(cost, new),
        "ortools_s": t_seed + t_new,
    }
    try:
        import elkai

        lkh, t_lkh = timed(lambda: elkai.DistanceMatrix(cost.tolist()).solve_tsp(runs=1))
        row["lkh_mm"] = route_cost(cost, _rotate(lkh[:-1], len(points)))
        row["lkh_s"] = t_lkh
    except ImportError:
        pass
    return row


def _rotate(tour: list[int], depot: int) -> np.ndarray:
    """A closed elkai tour (its end not repeated) as the views' order after the depot."""
    i = tour.index(depot)
    return np.asarray((tour[i + 1 :] + tour[:i]), dtype=np.int64)


def main() -> None:
    """Print one JSON line per instance."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--plan", type=Path, nargs="*", default=[])
    ap.add_argument("--sizes", default="25,50,100,200,500")
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args()
    for k in [int(s) for s in args.sizes.split(",")]:
        for seed in range(args.seeds):
            pts = np.random.default_rng(seed).uniform(0, 400, (k, 3))
            show({"instance": f"random K={k} seed={seed}", **compare(pts)})
    for path in args.plan:
        doc = json.loads(path.read_text())
        pts = np.array([v["position"] for v in doc["viewpoints"]])
        show({"instance": path.name, **compare(pts)})


def show(row: dict[str, object]) -> None:
    """Print one instance's row as a JSON line, floats rounded."""
    out = {k: round(v, 4) if isinstance(v, float) else v for k, v in row.items()}
    print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()
