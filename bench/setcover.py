"""Benchmark the set-cover solvers on OR-Library SCP files; one JSON line per instance and solver.

    python bench/setcover.py FILE... [--time-limit S] [--solver milp|greedy|both] [--threads T]

`best_known` comes from `optima.csv` next to each file (null when absent).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from vpp_core.orlib import parse_orlib  # noqa: E402
from vpp_core.setcover import solve_cover  # noqa: E402


def best_known(path: Path) -> float | None:
    """Best known objective of the instance in path from optima.csv beside it, else None."""
    table = path.parent / "optima.csv"
    if not table.is_file():
        return None
    with table.open(newline="") as fh:
        for row in csv.DictReader(fh):
            if row["instance"] == path.stem:
                return float(row["best_known"])
    return None


def bench_file(path: Path, solvers: list[str], time_limit: float, threads: int | None) -> None:
    """Parse one OR-Library file and print one JSON line per solver."""
    t0 = time.perf_counter()
    A, costs = parse_orlib(path.read_text())
    parse_s = time.perf_counter() - t0
    known = best_known(path)
    for solver in solvers:
        res = solve_cover(A, costs, method=solver, time_limit=time_limit, threads=threads)
        line = {
            "instance": path.stem,
            "solver": res.solver,
            "rows": res.rows,
            "cols": res.cols,
            "objective": res.objective,
            "bound": res.bound,
            "gap": None if res.gap is None else round(res.gap, 6),
            "status": res.status,
            "time_s": round(res.time_s, 3),
            "best_known": known,
            "input_rows": A.shape[0],
            "parse_s": round(parse_s, 3),
        }
        print(json.dumps(line), flush=True)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("files", nargs="+", type=Path, metavar="FILE")
    ap.add_argument("--time-limit", type=float, default=60.0, help="seconds per solve")
    ap.add_argument("--solver", choices=["milp", "greedy", "both"], default="both")
    ap.add_argument("--threads", type=int, default=None, help="HiGHS threads (default: HiGHS)")
    args = ap.parse_args(argv)
    solvers = ["greedy", "milp"] if args.solver == "both" else [args.solver]
    for path in args.files:
        bench_file(path, solvers, args.time_limit, args.threads)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
