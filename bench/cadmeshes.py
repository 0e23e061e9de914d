"""Strict vs partial view counts and diagnostics, CAD mesh vs an isotropic remesh of it.

    python bench/cadmeshes.py MESH UNITS EDGE_MM [--candidates 500] [--seed 0] [--tilt 0]
                              [--fractions 1,0.999,0.99] [--time-limit 30] [--cad-only]
                              [--subdivide MM]

MESH is traced once per tessellation (the file itself, "cad", and a pymeshlab isotropic
remesh with ~EDGE_MM edges and features over 30° kept, "iso"). Then each formulation is solved at
each fraction from the same R. One JSON line per (tessellation, formulation, fraction) goes to
stdout: views, solver status and bound, covered fraction, and the diagnostics' counts. The
tables of docs/cad-meshes.md come from this. Needs pymeshlab (`pip install -e '.[remesh]'`;
the test extra has it too). --subdivide MM splits both tessellations' faces until every edge is
at most MM mm (trimesh.remesh.subdivide_to_size: the same surface, smaller faces) first.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import trimesh

from vpp_core.document import CandidateGenerator, PlanRequest, SolverSettings, Target
from vpp_core.mesh import Part, load_mesh, part_from_arrays
from vpp_core.plan import candidates_for, finish
from vpp_core.raytrace import make_backend, trace_counts
from vpp_core.remesh import isotropic_remesh


def rows(part: Part, label: str, args: argparse.Namespace) -> None:
    """Trace `part` once, then print one JSON line per formulation and fraction."""
    request = PlanRequest(
        candidates=CandidateGenerator(count=args.candidates, seed=args.seed, tilt_deg=args.tilt),
        solver=SolverSettings(time_limit_s=args.time_limit),
    )
    backend = make_backend(part)
    t0 = time.perf_counter()
    views, info = candidates_for(part, request, backend)
    trace = trace_counts(part, request.sensor, views, backend=backend)
    trace_s = time.perf_counter() - t0
    for formulation in ("visibility", "density"):
        for fraction in args.fractions:
            target = Target(formulation=formulation, min_coverage=fraction)
            doc = finish(
                part, request.model_copy(update={"target": target}), views, info, trace,
                backend=backend,
            )  # fmt: skip
            d = doc.diagnostics
            assert d is not None
            print(
                json.dumps(
                    {
                        "mesh": args.mesh.name,
                        "tessellation": label,
                        "seed": args.seed,
                        "tilt_deg": args.tilt,
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
                        "hint": d.hint,
                        "trace_s": round(trace_s, 2),
                        "solve_s": doc.timings_s.solve,
                        "diagnostics_s": doc.timings_s.diagnostics,
                    }
                ),
                flush=True,
            )


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


def subdivided(part: Part, max_edge_mm: float | None) -> Part:
    """`part` with its faces split until no edge is longer than `max_edge_mm` (None: as is)."""
    if max_edge_mm is None:
        return part
    vertices, faces = trimesh.remesh.subdivide_to_size(part.vertices, part.faces, max_edge_mm)
    return part_from_arrays(vertices, faces)


def main() -> None:
    parser = pair_parser(__doc__)
    parser.add_argument("--candidates", type=int, default=500)
    parser.add_argument("--tilt", type=float, default=0.0, help="candidates.tilt_deg")
    parser.add_argument("--cad-only", action="store_true", help="skip the remesh")
    parser.add_argument("--subdivide", type=float, metavar="MM", help="split faces to edges <= MM")
    args = parser.parse_args()
    if args.cad_only:
        rows(subdivided(load_cad(args), args.subdivide), "cad", args)
        return
    cad, iso, label = load_pair(args)
    rows(subdivided(cad, args.subdivide), "cad", args)
    rows(subdivided(iso, args.subdivide), label, args)


if __name__ == "__main__":
    main()
