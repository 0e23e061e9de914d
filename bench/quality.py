"""Plan quality on real meshes: the default against the paper profile, today's best flags and
the view-sphere baseline; one JSON line per (mesh, formulation, setting).

    python bench/quality.py [MESH...] [--formulations density visibility]
                            [--settings default paper tilt best open4 world] [--time-limit 60]
                            [--sphere 1000] [--elements 1] [--points 100000] [--out DIR]

Every setting runs `vpp plan MESH --units U ... -q -o DIR/<name>.json` as a child process (the
paper's camera, r̄ = 0.18 mm, seed 0) and reports its count, solver status and bound, the
SPEC §5 coverage and met area (per face), the patch figures of the default (sampled and met
area), wall time and the child's peak RSS, and an independent re-check: the selected views
re-traced on the part split into area elements of at most `--elements` mm², the shares of the
area they sample and meet at r̄ (SPEC §3 density per element, whatever the plan's rows were);
and the same judged at `--points` area-weighted random points with no pixel grid (a point is
seen when the straight line from a camera reaches it: sub-pixel faces count by their area,
not by whether a ray happened to land on them).
The settings:

- `default`: nothing but --units (and --formulation);
- `paper`: --profile paper (the previous default: gazes along the normal at 500 mm, face rows);
- `tilt`: --profile paper --tilt 30 --min-coverage 0.999 (the flags docs/cad-meshes.md named);
- `best`: the same with --candidates 2000;
- `open4`: --open-min 4 (recessed patches weigh nothing in the partial cover);
- `world`: --roll world (the world's +Z as every camera's image-up, the default before
  session 51).

The element and point figures come on lines of their own after the plans, `sphere` lines last: Linux
keeps a parent's peak RSS in the `ru_maxrss` of the children it forks, so tracing in this
process first would inflate the children's figures. `sphere` lines give what `--sphere`
viewpoints on view spheres around the part reach (vpp_core.candidates.sphere), traced in this
process: the share of the counted area any of them sees (per face, SPEC §5), the share of
the patch area they sample, and the point figures of all of them together. Meshes and units
as bench/plan.py takes them (../shared/meshes and its MANIFEST.csv by default).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from plan import default_meshes, manifest_units, run_child, vpp_command  # noqa: E402
from surfacerows import point_views, random_points  # noqa: E402

from vpp_core.camera.pose import Viewpoints, make_viewpoints  # noqa: E402
from vpp_core.camera.sensor import Sensor  # noqa: E402
from vpp_core.candidates.sphere import view_sphere  # noqa: E402
from vpp_core.cover.density import density_sum, meets, stray_free  # noqa: E402
from vpp_core.mesh.part import Part  # noqa: E402
from vpp_core.mesh.refine import refine  # noqa: E402
from vpp_core.mesh.tessellate import load_part  # noqa: E402
from vpp_core.plan.document import Target  # noqa: E402
from vpp_core.plan.metrics import evaluate, seen  # noqa: E402
from vpp_core.plan.pipeline import cover_patches  # noqa: E402
from vpp_core.trace.embree import EmbreeBackend  # noqa: E402
from vpp_core.trace.raytrace import trace_counts  # noqa: E402

SETTINGS = {
    "default": [],
    "paper": ["--profile", "paper"],
    "tilt": ["--profile", "paper", "--tilt", "30", "--min-coverage", "0.999"],
    "best": ["--profile", "paper", "--tilt", "30", "--min-coverage", "0.999"]
    + ["--candidates", "2000"],
    "open4": ["--open-min", "4"],
    "world": ["--roll", "world"],
}


def run_setting(
    mesh: Path, units: str, formulation: str, setting: str, args: argparse.Namespace, out: Path
) -> dict[str, Any]:
    """One `vpp plan` child; its figures as a JSON-able dict."""
    doc_path = out / f"{mesh.stem}-{formulation}-{setting}.json"
    cmd = [*vpp_command(), "plan", str(mesh), "--units", units, "--formulation", formulation]
    cmd += ["--time-limit", str(args.time_limit), *SETTINGS[setting], "-q", "-o", str(doc_path)]
    code, wall, rss, err, killed = run_child(cmd, args.time_limit * 6 + 300)
    line: dict[str, Any] = {"mesh": mesh.name, "formulation": formulation, "setting": setting}
    line |= {"wall_s": round(wall, 2), "peak_rss_mib": round(rss)}
    if code != 0:
        return line | {"error": (err.strip().splitlines() or ["killed"])[-1], "killed": killed}
    doc = json.loads(doc_path.read_text())
    m, s, rows = doc["metrics"], doc["solver"], doc.get("cover_rows") or {}
    return line | {
        "views": len(doc["viewpoints"]),
        "candidates": len(doc["candidates"]),
        "status": s["status"],
        "bound": s["bound"],
        "coverage_area": round(m["coverage"]["area"], 4),
        "max_area": round(m["coverage"]["max_area"], 4),
        "met_area": round(m["resolution"]["met_area"], 4),
        "patch_sampled": rows.get("sampled_area"),
        "patch_met": rows.get("met_area"),
        "recessed": rows.get("recessed_area"),
        "points": (doc.get("partial") or {}).get("points"),
        "rounds": [
            (r["candidates"], r["views"], r["added"] - r.get("removed", 0))
            for r in doc.get("adaptive", [])
        ],
    }


def point_check(
    part: Part, sensor: Sensor, views: Viewpoints, resolution_mm: float, count: int
) -> dict[str, Any]:
    """The shares of the counted area that `views` see and meet at `resolution_mm`, judged at
    `count` area-weighted random points (seed 0) with no pixel grid: a point is seen when the
    straight line from a camera reaches it within the image, the depth of field and the
    incidence limit (bench/surfacerows.py), and met when the sampling densities
    sqrt(rays/mm²) of the views that see it add up to 1 / r̄. Sub-pixel faces count by their
    area, not by whether a ray happened to land on them."""
    points = random_points(part, count, 0)
    seen, density = np.zeros(count, bool), np.zeros(count)
    for _, idx, delta in point_views(part, sensor, views, points, EmbreeBackend(part)):
        seen[idx] = True
        density[idx] += delta
    return {
        "point_seen": round(float(seen.mean()), 4),
        "point_met": round(float(meets(density, 1 / resolution_mm).mean()), 4),
    }


def plan_check(
    mesh: Path, units: str, doc: dict[str, Any], max_area: float, points: int
) -> dict[str, Any]:
    """The plan's selected views re-traced on the part split into elements of at most
    `max_area` mm² (vpp_core.mesh.refine, by area alone as before session 43: a sliver stays
    one element; 0: not), independent of its rows: the shares of the
    counted area they sample (a ray lands) and meet (SPEC §3 density, summed over the views,
    ≥ 1 / r̄); and the same at `points` random points (point_check; 0: not)."""
    whole = load_part(mesh.read_bytes(), mesh.suffix[1:].lower(), units)
    vp = doc["viewpoints"]
    pose = [np.array([v[k] for v in vp], dtype=float) for k in ("position", "gaze", "up")]
    views = make_viewpoints(*pose)
    sensor, resolution = Sensor(**doc["sensor"]), doc["target"]["resolution_mm"]
    line = point_check(whole, sensor, views, resolution, points) if points else {}
    if not max_area:
        return line
    part = refine(whole, max_area, max_edge_mm=np.inf)
    counts = trace_counts(part, sensor, views).counts
    r = sp.csc_array(counts)
    density = density_sum(r, part.areas)
    k, a = part.counted, part.areas
    hit = seen(r)
    met = meets(density, 1 / resolution)
    return line | {
        "element_seen": round(float(a[k & hit].sum() / a[k].sum()), 4),
        "element_met": round(float(a[k & met].sum() / a[k].sum()), 4),
    }


def sphere_reach(mesh: Path, units: str, count: int, points: int) -> dict[str, Any]:
    """What `count` view-sphere viewpoints reach of the part (faces seen, patches sampled,
    and at `points` random points: point_check)."""
    part = load_part(mesh.read_bytes(), mesh.suffix[1:].lower(), units)
    sensor = Sensor()
    views = view_sphere(part, sensor, count)
    counts = trace_counts(part, sensor, views).counts
    every = sorted(range(len(views)))
    metrics = evaluate(counts, part.areas, part.counted, every, 0.18)  # type: ignore[arg-type]
    patches = cover_patches(part, Target(rows="patches"))
    assert patches is not None
    r = stray_free(patches.sum_rows(counts))
    sampled = patches.areas[np.diff(r.indptr) > 0].sum() / patches.areas.sum()
    at_points = point_check(part, sensor, views, 0.18, points) if points else {}
    return at_points | {
        "mesh": mesh.name,
        "setting": "sphere",
        "views": len(views),
        "max_area": round(metrics.coverage.max_area, 4),
        "max_met_area": round(metrics.resolution.max_met_area, 4),
        "patch_sampled": round(float(sampled), 4),
    }


def main(argv: list[str] | None = None) -> int:
    """Run the settings on the meshes; JSON lines on stdout."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("meshes", nargs="*", type=Path)
    ap.add_argument("--formulations", nargs="+", default=["density", "visibility"])
    ap.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    ap.add_argument("--time-limit", type=float, default=60.0)
    ap.add_argument("--sphere", type=int, default=1000, help="view-sphere viewpoints (0: none)")
    ap.add_argument("--out", type=Path, help="keep the plan documents here")
    ap.add_argument(
        "--elements", type=float, default=1.0, help="re-check plans on elements of this mm² (0: no)"
    )
    ap.add_argument(
        "--points", type=int, default=100_000, help="and at this many random points (0: no)"
    )
    args = ap.parse_args(argv)
    meshes = args.meshes or default_meshes()
    if not meshes:
        print("no meshes: ../shared/meshes is absent", file=sys.stderr)
        return 0
    units: dict[str, str] = {}  # each mesh's units from the MANIFEST.csv beside it
    for folder in dict.fromkeys(mesh.parent for mesh in meshes):
        units |= manifest_units(folder)
    out = args.out or Path(tempfile.mkdtemp(prefix="vpp-quality-"))
    out.mkdir(parents=True, exist_ok=True)
    checks = []  # traced here after every child: Linux keeps a parent's peak RSS in ru_maxrss
    for mesh in meshes:  # of the children it forks, so a grown bench would inflate theirs
        unit = units.get(mesh.name, "mm")
        for formulation in args.formulations:
            for setting in args.settings:
                line = run_setting(mesh, unit, formulation, setting, args, out)
                print(json.dumps(line), flush=True)
                if (args.elements or args.points) and "views" in line:
                    doc = out / f"{mesh.stem}-{formulation}-{setting}.json"
                    checks.append((mesh, unit, line, doc))
    for mesh, unit, line, doc in checks:
        check = plan_check(mesh, unit, json.loads(doc.read_text()), args.elements, args.points)
        print(json.dumps({k: line[k] for k in ("mesh", "formulation", "setting")} | check))
    for mesh in meshes if args.sphere else []:
        reach = sphere_reach(mesh, units.get(mesh.name, "mm"), args.sphere, args.points)
        print(json.dumps(reach), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
