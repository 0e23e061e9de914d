"""Benchmark the set-cover solvers; one JSON line per instance and solver (stdout).

    python bench/setcover.py FILE... [--solver milp|greedy|highs|both] [--time-limit S]
                             [--threads T] [--unicost]
    python bench/setcover.py --mesh [MESH...] [--candidates 500 2000]
                             [--formulation density visibility] [--save DIR] [...]
    python bench/setcover.py --synthetic ROWSxCOLS [--binary] [--seed K] [--lp] [...]

FILE: OR-Library SCP files; `best_known` comes from `optima.csv` beside them (null when absent).
--unicost: the same files with every cost set to 1 (named <file>_unicost, as in optima.csv).
A FILE ending in .npz is an instance saved with --save (unit costs).
--mesh: viewpoint instances built from real meshes (every mesh of ../shared/meshes without
MESH; units from its MANIFEST.csv) with the paper's camera and the default target, one per
candidate count and formulation; the trace is made once per mesh and count. --save DIR
writes each instance's matrix to DIR/<mesh>_<count>_<formulation>.npz as it is built.
--solver highs: the reference of HiGHS alone (`scipy.optimize.milp`, one uninterrupted run)
on the model `vpp_core.cover.reduce.reduce_cover` leaves, its fixed columns added to the objective
and the bound; `both` is greedy and milp.
--synthetic: the viewpoint-like window instance of `vpp_core.samples.window_cover`; with
--lp the LP relaxation is also solved on its own (HiGHS interior point), so that the
solver's bound can be compared with it (`lp` in the line).

Fields: instance, solver, rows, cols (after reductions), blocks (independent covers the solver
split those into; null for greedy and highs), objective, bound, gap, status,
time_s, time_to_best_s, best_known, input_rows, input_cols, build_s, peak_rss_mib.
"""

from __future__ import annotations

import argparse
import csv
import json
import resource
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, milp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from plan import default_meshes, manifest_units  # noqa: E402

from vpp_core.camera.sensor import make_sensor  # noqa: E402
from vpp_core.cover.density import cover_model  # noqa: E402
from vpp_core.cover.lpbound import lp_bound  # noqa: E402
from vpp_core.cover.mip import child_peak_rss_mib  # noqa: E402
from vpp_core.cover.orlib import parse_orlib  # noqa: E402
from vpp_core.cover.reduce import reduce_cover  # noqa: E402
from vpp_core.cover.setcover import CoverResult, solve_cover  # noqa: E402
from vpp_core.mesh.part import load_mesh  # noqa: E402
from vpp_core.plan.document import CandidateGenerator, PlanRequest  # noqa: E402
from vpp_core.plan.pipeline import candidates_for  # noqa: E402
from vpp_core.samples import window_cover  # noqa: E402
from vpp_core.trace.raytrace import make_backend, trace_counts  # noqa: E402

Instance = tuple[str, Any, np.ndarray | None, float | None, float]  # name, A, costs, known, s


def best_known(path: Path, name: str) -> float | None:
    """Best known objective of the instance `name` from optima.csv beside path, else None."""
    table = path.parent / "optima.csv"
    if not table.is_file():
        return None
    with table.open(newline="") as fh:
        for row in csv.DictReader(fh):
            if row["instance"] == name:
                return float(row["best_known"])
    return None


def file_instances(files: list[Path], unicost: bool = False) -> Iterator[Instance]:
    """OR-Library files (or .npz instances saved with --save) as instances; with `unicost`
    every cost is 1 and the instance is named <stem>_unicost, as in optima.csv."""
    for path in files:
        t0 = time.perf_counter()
        if path.suffix == ".npz":
            yield path.stem, sp.load_npz(path), None, None, time.perf_counter() - t0
            continue
        A, costs = parse_orlib(path.read_text())
        name = f"{path.stem}_unicost" if unicost else path.stem
        costs = np.ones_like(costs) if unicost else costs
        yield name, A, costs, best_known(path, name), time.perf_counter() - t0


def saved(instances: Iterator[Instance], folder: Path | None) -> Iterator[Instance]:
    """The instances, each also written to folder/<name>.npz when a folder is given."""
    for inst in instances:
        if folder is not None:
            folder.mkdir(parents=True, exist_ok=True)
            sp.save_npz(folder / f"{inst[0].replace('/', '_')}.npz", sp.csr_matrix(inst[1]))
        yield inst


def mesh_instances(
    meshes: list[Path], counts: list[int], formulations: list[str]
) -> Iterator[Instance]:
    """Viewpoint instances: paper camera, default target, each count and formulation."""
    units = {p.name: manifest_units(p.parent).get(p.name, "mm") for p in meshes}
    for path in meshes:
        part = load_mesh(path.read_bytes(), path.suffix.lstrip("."), units[path.name])
        backend = make_backend(part)
        for count in counts:
            t0 = time.perf_counter()
            generator = CandidateGenerator(count=count)
            request = PlanRequest(sensor=make_sensor(None), candidates=generator)
            views, _ = candidates_for(part, request, backend)
            trace = trace_counts(part, request.sensor, views, backend=backend)
            trace_s = time.perf_counter() - t0
            for form in formulations:
                t1 = time.perf_counter()
                model = cover_model(
                    trace.counts, part.areas, part.counted, request.target.resolution_mm, form
                )
                build_s = trace_s + time.perf_counter() - t1
                yield f"{path.stem}/{count}/{form}", model.matrix, None, None, build_s


def synthetic_instance(shape: str, binary: bool, seed: int) -> Iterator[Instance]:
    """The window instance ROWSxCOLS (real coefficients unless binary)."""
    rows, cols = (int(v) for v in shape.lower().split("x"))
    t0 = time.perf_counter()
    A = window_cover(rows, cols, values=None if binary else (0.26, 0.55), seed=seed)
    name = f"window-{rows}x{cols}-{'binary' if binary else 'real'}-s{seed}"
    yield name, A, None, None, time.perf_counter() - t0


def peak_rss_mib() -> float:
    """Peak resident memory so far (MiB): this process's plus that of its HiGHS process (both
    peaks added, an upper bound on what they held at once)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0 + child_peak_rss_mib()


def highs_alone(A: Any, costs: np.ndarray | None, time_limit: float) -> CoverResult:
    """The reference: one HiGHS run (scipy's `milp`) on the reduced model, fixed columns added."""
    t0 = time.perf_counter()
    csr = sp.csr_array(A, dtype=np.float64)
    c = np.ones(csr.shape[1]) if costs is None else np.asarray(costs, dtype=np.float64)
    red = reduce_cover(csr, c)
    R, cr, fixed = red.matrix, c[red.columns], float(c[red.fixed].sum())
    res = milp(cr, constraints=LinearConstraint(R, lb=np.ones(R.shape[0]), ub=np.inf),
               integrality=np.ones(R.shape[1]), bounds=Bounds(0, 1),
               options={"time_limit": time_limit})  # fmt: skip
    picked = np.zeros(0, np.int64) if res.x is None else np.flatnonzero(res.x > 0.5)
    objective = fixed + float(cr[picked].sum()) if res.x is not None else np.nan
    bound = fixed + float(getattr(res, "mip_dual_bound", np.nan))
    status = "optimal" if res.status == 0 else "time_limit" if res.status == 1 else res.message
    gap = (objective - bound) / objective if objective > 0 else None
    selected = np.union1d(red.fixed, red.columns[picked]).astype(np.int64)
    elapsed = time.perf_counter() - t0
    return CoverResult(selected, "highs", status, objective, bound, gap, elapsed,
                       R.shape[0], R.shape[1])  # fmt: skip


def run(inst: Instance, solver: str, args: argparse.Namespace) -> dict[str, Any]:
    """Solve one instance with one solver; the JSON line as a dict."""
    name, A, costs, known, build_s = inst
    if solver == "highs":
        res = highs_alone(A, costs, args.time_limit)
    else:
        res = solve_cover(A, costs, method=solver, time_limit=args.time_limit, threads=args.threads)
    return {
        "instance": name,
        "solver": res.solver,
        "rows": res.rows,
        "cols": res.cols,
        "blocks": res.presolve.get("blocks"),
        "objective": res.objective,
        "bound": res.bound,
        "gap": None if res.gap is None else round(res.gap, 6),
        "status": res.status,
        "time_s": round(res.time_s, 3),
        "time_to_best_s": None if res.time_to_best_s is None else round(res.time_to_best_s, 3),
        "best_known": known,
        "input_rows": A.shape[0],
        "input_cols": A.shape[1],
        "build_s": round(build_s, 3),
        "peak_rss_mib": round(peak_rss_mib(), 1),
    }


def lp_line(inst: Instance, args: argparse.Namespace) -> dict[str, Any]:
    """The LP relaxation solved on its own, without reductions (time limit 10× the solve's)."""
    name, A, costs, _, _ = inst
    csr = sp.csr_array(A, dtype=np.float64)
    c = np.ones(csr.shape[1]) if costs is None else np.asarray(costs, dtype=np.float64)
    lp = lp_bound(csr, c, 10 * args.time_limit, args.threads)
    return {"instance": name, "solver": "lp", "lp": lp.bound, "status": lp.status,
            "time_s": round(lp.time_s, 3)}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("files", nargs="*", type=Path, metavar="FILE")
    ap.add_argument("--mesh", action="store_true", help="FILEs are meshes (none: all shared)")
    ap.add_argument("--candidates", type=int, nargs="+", default=[500, 2000])
    ap.add_argument("--formulation", nargs="+", default=["density", "visibility"])
    ap.add_argument("--synthetic", metavar="ROWSxCOLS", help="window instance, e.g. 200000x2000")
    ap.add_argument("--binary", action="store_true", help="synthetic with 0/1 coefficients")
    ap.add_argument("--unicost", action="store_true", help="FILEs with every cost set to 1")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lp", action="store_true", help="also solve the LP relaxation on its own")
    ap.add_argument("--time-limit", type=float, default=60.0, help="seconds per solve")
    ap.add_argument("--solver", choices=["milp", "greedy", "highs", "both"], default="both")
    ap.add_argument("--save", type=Path, metavar="DIR", help="write each instance as .npz")
    ap.add_argument("--threads", type=int, default=None, help="HiGHS threads (default: HiGHS)")
    args = ap.parse_args(argv)
    solvers = ["greedy", "milp"] if args.solver == "both" else [args.solver]
    missing = [str(f) for f in args.files if not f.is_file()]
    if missing:
        print(f"no such file: {', '.join(missing)}", file=sys.stderr)
        return 2
    if args.synthetic:
        instances = synthetic_instance(args.synthetic, args.binary, args.seed)
    elif args.mesh:
        meshes = args.files or default_meshes()
        if not meshes:
            print("no meshes: ../shared/meshes is absent", file=sys.stderr)
            return 0
        instances = mesh_instances(meshes, args.candidates, args.formulation)
    else:
        instances = file_instances(args.files, args.unicost)
    for inst in saved(instances, args.save):
        for solver in solvers:
            print(json.dumps(run(inst, solver, args)), flush=True)
        if args.lp:
            print(json.dumps(lp_line(inst, args)), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
