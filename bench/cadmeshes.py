"""Strict vs partial view counts and diagnostics, CAD mesh vs an isotropic remesh of it.

    python bench/cadmeshes.py MESH UNITS EDGE_MM [--candidates 500] [--seed 0] [--tilt 0]
                              [--fractions 1,0.999,0.99] [--time-limit 30] [--cad-only]
                              [--remesh MM] [--max-face-area MM2] [--subdivide MM]
                              [--formulations ...]

MESH is traced once per tessellation (the file itself, "cad", and a pymeshlab isotropic
remesh with ~EDGE_MM edges and features over 30° kept, "iso"). Then each formulation is solved at
each fraction from the same R. One JSON line per (tessellation, formulation, fraction) goes to
stdout: views, solver status and bound, covered fraction, and the diagnostics' counts. With
both tessellations, each plan's viewpoints are then traced on the other tessellation, and
`cross_seen` says which share of that tessellation's reachable area (seen by its own
candidates) they see: the plan's coverage, judged by an independent trace on other faces.
The tables of docs/cad-meshes.md come from this. Needs pymeshlab (`pip install -e '.[remesh]'`;
the test extra has it too). --remesh MM remeshes both tessellations again, at MM mm edges
(vpp_core.mesh.remesh.remesh, what `vpp plan --remesh` does); --max-face-area MM2 splits both
tessellations' faces into area elements of at most MM2 mm² (vpp_core.mesh.refine, what
`vpp plan --max-face-area` does); --subdivide MM splits them until every edge is at most
MM mm (trimesh.remesh.subdivide_to_size).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
import trimesh

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.mesh.part import Part, load_mesh, part_from_arrays
from vpp_core.mesh.refine import refine
from vpp_core.mesh.remesh import isotropic_remesh, remesh
from vpp_core.plan.document import CandidateGenerator, PlanRequest, SolverSettings, Target
from vpp_core.plan.pipeline import candidates_for, finish
from vpp_core.trace.raytrace import make_backend, trace_counts


def rows(part: Part, label: str, args: argparse.Namespace) -> dict[tuple[str, float], Plan]:
    """Trace `part` once, print one JSON line per formulation and fraction; the plans."""
    request = PlanRequest(
        candidates=CandidateGenerator(count=args.candidates, seed=args.seed, tilt_deg=args.tilt),
        solver=SolverSettings(time_limit_s=args.time_limit),
    )
    backend = make_backend(part)
    t0 = time.perf_counter()
    views, info = candidates_for(part, request, backend)
    trace = trace_counts(part, request.sensor, views, backend=backend)
    trace_s = time.perf_counter() - t0
    reachable = np.diff(sp.csr_array(trace.counts).indptr) > 0
    plans = {}
    for formulation in args.formulations:
        for fraction in args.fractions:
            target = Target(formulation=formulation, min_coverage=fraction)
            doc = finish(
                part, request.model_copy(update={"target": target}), views, info, trace,
                backend=backend,
            )  # fmt: skip
            d = doc.diagnostics
            assert d is not None and d.undersampled is not None
            print(
                json.dumps(
                    {
                        "mesh": args.mesh.name,
                        "tessellation": label,
                        "seed": args.seed,
                        "tilt_deg": args.tilt,
                        "remesh_mm": args.remesh,
                        "max_face_area_mm2": args.max_face_area,
                        "faces": part.n_faces,
                        "median_face_mm2": float(np.median(part.areas)),
                        "formulation": formulation,
                        "min_coverage": fraction,
                        "views": len(doc.viewpoints),
                        "status": doc.solver.status,
                        "bound": doc.solver.bound,
                        "covered": doc.partial.covered_fraction if doc.partial else 1.0,
                        "seen_area": doc.metrics.coverage.area,
                        "met_area": doc.metrics.resolution.met_area,
                        "uncoverable_mm2": doc.uncoverable.area_mm2,
                        "subpixel": d.subpixel.faces,
                        "single_candidate": d.single_candidate.faces,
                        "one_ray": d.single_candidate.one_ray,
                        "forced_views": d.single_candidate.forced_views,
                        "enclosed": d.internal.enclosed.faces,
                        "back_to_back": d.internal.back_to_back.faces,
                        "driven_views": d.driven_views,
                        "driven_area_mm2": d.driven_area_mm2,
                        "undersampled": d.undersampled.faces,
                        "unsampled_mm2": d.undersampled.unsampled_mm2,
                        "hint": d.hint,
                        "trace_s": round(trace_s, 2),
                        "solve_s": doc.timings_s.solve,
                        "diagnostics_s": doc.timings_s.diagnostics,
                    }
                ),
                flush=True,
            )
            chosen = np.array([v.id for v in doc.viewpoints], dtype=np.int64)
            plans[formulation, fraction] = Plan(part, views.take(chosen), reachable)
    return plans


@dataclass(frozen=True)
class Plan:
    """A plan's part, its selected viewpoints and the part's reachable faces (M,) bool."""

    part: Part
    views: Viewpoints
    reachable: np.ndarray


def cross(plans: dict[str, dict[tuple[str, float], Plan]], args: argparse.Namespace) -> None:
    """Each plan's viewpoints traced on the other tessellation: one JSON line per plan with
    `cross_seen`, the share of that tessellation's reachable area they see (per face)."""
    (a, by_a), (b, by_b) = plans.items()
    for (src, mine), (dst, theirs) in (((a, by_a), (b, by_b)), ((b, by_b), (a, by_a))):
        for key, plan in mine.items():
            other = theirs[key].part
            counts = sp.csr_array(trace_counts(other, Sensor(), plan.views).counts)
            seen = np.diff(counts.indptr) > 0
            reach = theirs[key].reachable & other.counted
            share = other.areas[seen & reach].sum() / other.areas[reach].sum()
            line = {"mesh": args.mesh.name, "plan_of": src, "traced_on": dst}
            line |= {"formulation": key[0], "min_coverage": key[1], "views": len(plan.views)}
            print(json.dumps(line | {"cross_seen": float(share)}), flush=True)


def pair_parser(doc: str) -> argparse.ArgumentParser:
    """Arguments of a CAD-against-remesh bench: MESH UNITS EDGE_MM, --seed, --time-limit,
    --fractions (comma-separated)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("mesh", type=Path)
    parser.add_argument("units")
    parser.add_argument("edge_mm", type=float)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--time-limit", type=float, default=30.0)
    parser.add_argument(
        "--fractions", type=lambda s: [float(x) for x in s.split(",")], default=[1, 0.999, 0.99]
    )
    return parser


def load_cad(args: argparse.Namespace) -> Part:
    """The CAD mesh of `args`, in mm."""
    return load_mesh(args.mesh.read_bytes(), args.mesh.suffix.lstrip("."), args.units)


def load_pair(args: argparse.Namespace) -> tuple[Part, Part, str]:
    """The CAD mesh of `args`, its isotropic remesh and the remesh's label."""
    cad = load_cad(args)
    return cad, isotropic_remesh(cad, args.edge_mm), f"iso {args.edge_mm:g} mm"


def subdivided(part: Part, args: argparse.Namespace) -> Part:
    """`part` remeshed (--remesh), split into area elements (--max-face-area) or short edges
    (--subdivide)."""
    if args.remesh is not None:
        part = remesh(part, args.remesh)
    if args.max_face_area is not None:
        part = refine(part, args.max_face_area)
    if args.subdivide is None:
        return part
    vertices, faces = trimesh.remesh.subdivide_to_size(part.vertices, part.faces, args.subdivide)
    return part_from_arrays(vertices, faces)


def main() -> None:
    parser = pair_parser(__doc__)
    parser.add_argument("--candidates", type=int, default=500)
    parser.add_argument("--tilt", type=float, default=0.0, help="candidates.tilt_deg")
    parser.add_argument("--cad-only", action="store_true", help="skip the remesh")
    parser.add_argument("--remesh", type=float, metavar="MM", help="remesh both at MM mm edges")
    parser.add_argument("--max-face-area", type=float, metavar="MM2", help="area elements")
    parser.add_argument("--subdivide", type=float, metavar="MM", help="split faces to edges <= MM")
    parser.add_argument(
        "--formulations", nargs="+", default=["visibility", "density"], help="which to solve"
    )
    args = parser.parse_args()
    if args.cad_only:
        rows(subdivided(load_cad(args), args), "cad", args)
        return
    cad, iso, label = load_pair(args)
    plans = {"cad": rows(subdivided(cad, args), "cad", args)}
    plans[label] = rows(subdivided(iso, args), label, args)
    cross(plans, args)


if __name__ == "__main__":
    main()
