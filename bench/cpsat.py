"""OR-Tools CP-SAT on OR-Library set-cover files, as a yardstick for `vpp_core.cover.setcover`.

    pip install ortools
    python bench/cpsat.py ../shared/data/orlib-scp/scpnre2.txt ... [--time-limit 60] [--workers 2]

Model: one Boolean per column, one `AddBoolOr` per row, minimise the cost; the greedy cover
(`vpp_core.cover.greedy.complete_cover`) as a hint. One JSON line per instance: objective, bound,
status, time_s, time_to_best_s, the last improvements (time s, objective) and `best_known`
from optima.csv. Not a project solver (issue 4: chosen by measurement, and it did not win).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vpp_core.cover.greedy import complete_cover  # noqa: E402
from vpp_core.cover.orlib import parse_orlib  # noqa: E402


def solve(path: Path, time_limit: float, workers: int) -> dict[str, object]:
    """CP-SAT on one file, greedy-hinted."""
    from ortools.sat.python import cp_model

    A, costs = parse_orlib(path.read_text())
    A = sp.csr_array(A)
    t0 = time.perf_counter()
    greedy = set(complete_cover(A, costs, np.zeros(0, np.int64)).tolist())
    model = cp_model.CpModel()
    x = [model.NewBoolVar(f"x{j}") for j in range(A.shape[1])]
    for i in range(A.shape[0]):
        model.AddBoolOr([x[j] for j in A.indices[A.indptr[i] : A.indptr[i + 1]]])
    model.Minimize(sum(int(c) * v for c, v in zip(costs, x, strict=True)))
    for j, v in enumerate(x):
        model.AddHint(v, j in greedy)
    solver = cp_model.CpSolver()
    solver.parameters.max_time_in_seconds = time_limit
    solver.parameters.num_workers = workers
    found: list[tuple[float, float]] = []

    class Found(cp_model.CpSolverSolutionCallback):  # type: ignore[misc]
        def on_solution_callback(self) -> None:
            found.append((round(time.perf_counter() - t0, 2), self.ObjectiveValue()))

    status = solver.Solve(model, Found())
    return {
        "instance": path.stem,
        "solver": "cpsat",
        "rows": A.shape[0],
        "cols": A.shape[1],
        "greedy": float(costs[sorted(greedy)].sum()),
        "objective": solver.ObjectiveValue(),
        "bound": solver.BestObjectiveBound(),
        "status": solver.StatusName(status),
        "time_s": round(time.perf_counter() - t0, 2),
        "time_to_best_s": found[-1][0] if found else None,
        "improvements": found[-3:],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="+", type=Path)
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    for path in args.files:
        line = solve(path, args.time_limit, args.workers)
        optima = path.parent / "optima.csv"
        if optima.exists():
            known = {r["instance"]: r["best_known"] for r in csv.DictReader(optima.open())}
            line["best_known"] = float(known[path.stem]) if path.stem in known else None
        print(json.dumps(line), flush=True)


if __name__ == "__main__":
    main()
