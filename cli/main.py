"""`vpp plan MESH ...`: plan viewpoints for a mesh file; bad input → one line on stderr, exit 2."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any, NoReturn

from pydantic import ValidationError
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from cli import STARTED
from vpp_core.camera.sensor import make_sensor
from vpp_core.cell.geometry import Cell, resolve
from vpp_core.cell.setup import MeshShape
from vpp_core.cover.access import DIRECTIONS
from vpp_core.errors import VppError
from vpp_core.mesh.part import UNITS_TO_MM, Part
from vpp_core.mesh.tessellate import load_part
from vpp_core.plan.cycle import Objective
from vpp_core.plan.diagnostics import Undersampled
from vpp_core.plan.document import (
    CandidateGenerator,
    PlanDocument,
    PlanRequest,
    SolverSettings,
    Target,
)
from vpp_core.plan.pipeline import plan
from vpp_core.report.pointcloud import CloudStats, simulate_plan, write_ply
from vpp_core.report.studies import (
    DEFAULT_RATIOS,
    DEFAULT_RESOLUTIONS,
    DecimationRow,
    Study,
    decimation_study,
    resolution_sweep,
    study_csv,
)
from vpp_core.samples import sample_stl
from vpp_core.trace.rays import DEFAULT_BACKEND
from vpp_core.trace.raytrace import BACKENDS
from worker.settings import Settings, get_settings

EXIT_INPUT = 2
"""Exit code for anything wrong with the input (files, options, mesh, sensor, limits)."""


class InputError(Exception):
    """A problem with the command line's input, reported as one line and exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message}\n")


def _positive_int(text: str) -> int:
    """argparse type: an integer ≥ 1."""
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of `vpp`."""
    parser = _Parser(prog="vpp", description="Inspection viewpoint planning (SPEC v1).")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    p = sub.add_parser("plan", help="plan the fewest viewpoints covering a mesh")
    _plan_options(p)
    p.add_argument("-o", "--output", type=Path, help="write the plan document (JSON) here")
    p.add_argument(
        "--point-cloud",
        type=Path,
        metavar="OUT.ply",
        help="simulate the selected views' point cloud: PLY with neighbours within r̄ per point",
    )
    p.add_argument("--plots", type=Path, metavar="DIR", help="write PNG plots and data here")
    p.add_argument(
        "--mesh-out",
        type=Path,
        metavar="OUT.ply",
        help="write the mesh the plan refers to (after --remesh / --max-face-area), exact PLY",
    )
    p.set_defaults(run=run_plan)
    st = sub.add_parser("study", help="the paper's studies: resolution sweep, decimation")
    kinds = st.add_subparsers(dest="kind", required=True, parser_class=_Parser)
    r = kinds.add_parser("resolution", help="#viewpoints against target resolution, one trace")
    _plan_options(r)
    r.add_argument(
        "--resolutions",
        type=_floats,
        default=DEFAULT_RESOLUTIONS,
        help="comma-separated target resolutions, mm",
    )
    d = kinds.add_parser("decimation", help="plans on decimated meshes, judged on the original")
    _plan_options(d)
    d.add_argument(
        "--ratios", type=_floats, default=DEFAULT_RATIOS, help="comma-separated face ratios"
    )
    for q in (r, d):
        q.add_argument("-o", "--output", type=Path, help="write the study (JSON) here")
        q.add_argument("--csv", type=Path, help="write the rows as CSV here")
        q.add_argument("--plots", type=Path, metavar="DIR", help="write PNG plots and data here")
        q.set_defaults(run=run_study)
    _export_options(sub.add_parser("export", help="a plan's poses for the cell: CSV or JSON"))
    e = sub.add_parser("sample", help="write the sample part (a flanged bushing, mm) as STL")
    e.add_argument("output", type=Path, help="STL file to write")
    e.set_defaults(run=run_sample)
    s = sub.add_parser(
        "serve", help="run the HTTP API (with an embedded Redis and workers if no VPP_REDIS_URL)"
    )
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=int, default=8000)
    s.add_argument(
        "--workers", type=_positive_int, help="local workers (embedded mode; default VPP_WORKERS)"
    )
    s.set_defaults(run=_run_serve)
    w = sub.add_parser("worker", help="run workers on the queue at VPP_REDIS_URL")
    w.add_argument("--url", help="Redis URL (default: VPP_REDIS_URL)")
    w.add_argument("--workers", type=_positive_int, help="worker processes (default VPP_WORKERS)")
    w.add_argument("--burst", action="store_true", help="exit when the queue is empty")
    w.set_defaults(run=_run_workers)
    return parser


def _run_serve(args: argparse.Namespace) -> int:
    """`vpp serve`; the service is imported only here, so that `vpp plan` starts faster."""
    from cli import serve

    return serve.run_serve(args)


def _run_workers(args: argparse.Namespace) -> int:
    """`vpp worker`; the worker pool is imported only here."""
    from cli import serve

    return serve.run_workers(args)


def _plan_options(p: argparse.ArgumentParser) -> None:
    """The options `vpp plan` and the studies share: mesh, sensor, target, candidates, solver."""
    p.add_argument("mesh", type=Path, help="mesh file: STL, OBJ, PLY, OFF, GLB, GLTF")
    p.add_argument("--units", default="mm", choices=sorted(UNITS_TO_MM), help="mesh file units")
    p.add_argument("--format", help="mesh format if the extension does not tell")
    p.add_argument(
        "--remesh",
        type=float,
        metavar="MM",
        help="plan on an isotropic remesh with edges of about MM mm (needs pymeshlab): the "
        "count of the surface, not of its export (docs/cad-meshes.md)",
    )
    p.add_argument(
        "--max-face-area",
        type=float,
        metavar="MM2",
        help="split faces larger than this, mm², or longer than 2·sqrt(this) mm (big CAD "
        "facets, slivers; 1 for the paper camera)",
    )
    p.add_argument("--sensor", type=Path, help="sensor JSON (SPEC §2); default: paper camera")
    p.add_argument(
        "--setup",
        type=Path,
        metavar="SETUP.json",
        help="the part in its cell: part_to_cell, floor, fixtures (mesh files relative to the "
        "JSON), workspace, keep_out (docs/cell.md)",
    )
    p.add_argument("--resolution", type=float, default=0.18, help="target resolution, mm")
    p.add_argument("--formulation", default="density", choices=["density", "visibility"])
    p.add_argument(
        "--min-coverage",
        type=float,
        help="cover this fraction of the coverable area (partial cover; what is left out is "
        "listed); default profile 0.99 (0.999 still seen), paper 1 = all",
    )
    p.add_argument(
        "--open-min",
        type=int,
        default=0,
        metavar="K",
        help=f"patch rows: a patch open along fewer than K of {DIRECTIONS} directions is "
        "recessed (seen through a clearance or a slot) and weighs nothing in a partial cover; "
        "default 0: none is; 4 keeps a closed housing's inside from driving the count",
    )
    cand = p.add_mutually_exclusive_group()
    cand.add_argument("--candidates", type=int, default=500, help="candidates to generate")
    cand.add_argument("--candidates-file", type=Path, help="JSON list of {position, gaze, up?}")
    p.add_argument("--decimate", type=float, help="generate candidates on this face fraction")
    p.add_argument("--clearance", type=float, default=20.0, help="least camera-part distance")
    p.add_argument(
        "--profile",
        default="default",
        choices=["default", "paper"],
        help="default: the project's best plans (docs/quality.md); paper: the paper's method "
        "as SPEC §2-4 wrote it (gazes along the normal at the working distance, face rows)",
    )
    p.add_argument(
        "--rows",
        choices=["patches", "faces"],
        help="cover rows: connected patches of surface about 32 r̄ across (default profile) "
        "or faces (SPEC §3, paper profile)",
    )
    p.add_argument(
        "--tilt",
        type=float,
        help="tilt generated gazes up to this angle off the normal, deg "
        "(default profile 30, paper 0)",
    )
    p.add_argument(
        "--retry-tilt",
        type=float,
        help="blocked samples try gazes within this wider angle before being dropped, deg "
        "(default profile 60, paper 0)",
    )
    p.add_argument(
        "--adaptive",
        action=argparse.BooleanOptionalAction,
        help="add candidates aimed at what drives the count after a quick cover "
        "(default profile: on, paper: off)",
    )
    p.add_argument(
        "--sphere",
        type=int,
        metavar="N",
        help="trace N views on spheres around the part and add those that see surface no "
        "generated candidate samples (default profile 200, paper 0; 0: none)",
    )
    p.add_argument(
        "--roll",
        choices=["fitted", "world"],
        help="cameras' roll: fitted turns a camera where that frames more of the surface "
        "(default profile), world keeps world +Z as image up (paper)",
    )
    p.add_argument(
        "--tiles",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also lay head-on cameras side by side over each flat face no frame holds whole "
        "(default profile: on; paper: off)",
    )
    p.add_argument(
        "--standoff",
        type=float,
        metavar="MM",
        help="camera-sample distance, mm (default profile: where a pixel is r̄/1.2, "
        "paper: the working distance)",
    )
    p.add_argument(
        "--regions",
        type=Path,
        metavar="REGIONS.json",
        help="regions of interest with their own resolution_mm or ignore: true: a JSON list of "
        '{"name", "faces"|"box"|"sphere"|"label", "resolution_mm"|"ignore"} (docs/cell.md)',
    )
    p.add_argument(
        "--labels",
        type=Path,
        metavar="LABELS",
        help="face labels for `label` regions: a JSON list or .npy array, one int per face "
        "(default: the file's PLY face property, OBJ groups or glTF primitives)",
    )
    _objective_options(p)
    p.add_argument("--solver", default="milp", choices=["milp", "greedy"])
    p.add_argument("--time-limit", type=float, default=60.0, help="solver time limit, s")
    p.add_argument("--gap", type=float, default=0.0, help="relative MIP gap accepted")
    p.add_argument("--seed", type=int, default=0, help="candidate generator seed")
    p.add_argument("--threads", type=_positive_int, help="threads (default: all cores)")
    p.add_argument(
        "--backend",
        default=DEFAULT_BACKEND,
        choices=BACKENDS,
        help=f"ray backend for R (default {DEFAULT_BACKEND}: the fastest)",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def _objective_options(p: argparse.ArgumentParser) -> None:
    """The objective and the cell's travel model (docs/cell.md)."""
    p.add_argument(
        "--objective",
        default="views",
        choices=["views", "cycle_time"],
        help="views: the fewest views; cycle_time: also a cover weighted by dwell + travel, "
        "kept when its cycle is shorter",
    )
    p.add_argument("--dwell", type=float, default=1.0, metavar="S", help="time per view, s")
    p.add_argument("--speed", type=float, default=250.0, metavar="MM_PER_S", help="mm/s")
    p.add_argument("--accel", type=float, metavar="MM_PER_S2", help="acceleration, mm/s²")
    p.add_argument(
        "--home", type=_floats, metavar="X,Y,Z", help="start/end of the cycle, mm (part frame)"
    )


def _export_options(x: argparse.ArgumentParser) -> None:
    """`vpp export PLAN.json --format csv|json [--frame cell|part] [--unit mm|m] [-o FILE]`."""
    x.add_argument("plan", type=Path, help="plan document (JSON) written by vpp plan -o")
    x.add_argument("--format", default="csv", choices=["csv", "json"])
    x.add_argument(
        "--frame",
        default="cell",
        choices=["cell", "part"],
        help="cell: setup.part_to_cell applied (the part frame when the plan has no setup)",
    )
    x.add_argument("--unit", default="mm", choices=["mm", "m"])
    x.add_argument("-o", "--output", type=Path, help="write here (default: stdout)")
    x.set_defaults(run=run_export)


def run_export(args: argparse.Namespace) -> int:
    """Write the plan's poses in visiting order as CSV or JSON."""
    from vpp_core.report.export import poses_csv, poses_json

    try:
        doc = PlanDocument.model_validate_json(_read(args.plan, 256 * 2**20))
    except ValidationError as exc:
        raise InputError(f"{args.plan}: not a plan document ({exc.error_count()} errors)") from None
    if args.format == "csv":
        text = poses_csv(doc, args.unit, args.frame)
    else:
        text = poses_json(doc, args.unit, args.frame) + "\n"
    if args.output:
        _write(args.output, text)
    else:
        sys.stdout.write(text)
    return 0


def _floats(text: str) -> list[float]:
    """argparse type: comma-separated numbers."""
    try:
        return [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"not a comma-separated list of numbers: {text!r}"
        ) from None


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `vpp` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.run(args))
    except (VppError, InputError) as exc:
        detail = exc.detail if isinstance(exc, VppError) else str(exc)
        print(f"vpp: error: {detail}", file=sys.stderr)
        return EXIT_INPUT
    except KeyboardInterrupt:
        print("vpp: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug of ours: still one line, unless asked for the trace
        if os.environ.get("VPP_DEBUG"):
            raise
        print(f"vpp: internal error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1


def run_plan(args: argparse.Namespace) -> int:
    """Load, plan, print the summary and write the document, point cloud and plots."""
    settings = get_settings()
    request = _request(args)
    part = _load(args, settings)
    threads = args.threads or settings.threads
    cell = _cell(args, request, settings)
    with _progress(args.quiet) as report:
        doc = plan(
            part,
            request,
            limits=settings.limits(),
            threads=threads,
            progress=report,
            load_s=time.perf_counter() - STARTED,  # the budget counts from the command's start
            cell=cell,
        )
    text = doc.model_dump_json(indent=1)
    if args.output:  # before anything is printed: nothing printed can lose the plan
        _write(args.output, text)
    console = Console()
    console.print(summary(doc))
    if doc.diagnostics and doc.diagnostics.hint:
        console.print(f"[yellow]note:[/] {escape(doc.diagnostics.hint)}", highlight=False)
    if doc.metrics.regions:
        console.print(regions_table(doc))
    for warning in doc.regions.warnings if doc.regions else []:  # they quote region names
        console.print(f"[yellow]warning:[/] {escape(warning)}", highlight=False)
    if args.output:
        print(f"plan written to {args.output}")
    if args.mesh_out:
        _write_bytes(args.mesh_out, part.ply())
        print(f"mesh written to {args.mesh_out}")
    stats = _point_cloud(args, part, doc, settings.max_cloud_points, threads)
    if args.plots:
        from vpp_core.plan.cellplan import setup_backend
        from vpp_core.report.plots import (
            plan_plots,  # matplotlib: imported only when plots are asked
        )
        from vpp_core.report.scene import selected_face_results

        backend = setup_backend(part, request, cell)  # the setup's fixtures occlude, as planned
        faces = selected_face_results(part, doc, threads, backend)  # cameras.png: r* colours
        pngs = plan_plots(part, doc, stats, faces=(faces.state, faces.resolution_mm))
        files = {"plan.json": text.encode(), **pngs}
        if stats is not None:
            files["point-cloud.json"] = stats.model_dump_json(indent=1).encode()
        _write_all(args.plots, files)
    return 0


def _point_cloud(
    args: argparse.Namespace, part: Part, doc: PlanDocument, max_points: int, threads: int | None
) -> CloudStats | None:
    """Simulate and write the plan's point cloud when asked (--point-cloud); its summary."""
    if not args.point_cloud:
        return None
    start = time.perf_counter()
    cloud, counts, stats = simulate_plan(part, doc, max_points=max_points, workers=threads or -1)
    try:
        with args.point_cloud.open("wb") as out:
            write_ply(out, cloud, counts)
    except OSError as exc:
        raise InputError(f"{args.point_cloud}: {exc.strerror or exc}") from None
    print(
        f"point cloud written to {args.point_cloud}: {stats.points:,} points, neighbours within "
        f"{stats.radius_mm:g} mm mean {stats.neighbours_mean:.2f} (median "
        f"{stats.neighbours_median:g}), mean spacing {_g(stats.spacing_mean_mm)} mm, "
        f"{time.perf_counter() - start:.1f} s"
    )
    return stats


def run_study(args: argparse.Namespace) -> int:
    """Run a resolution sweep or a decimation study; print its rows, write JSON/CSV/plots."""
    settings = get_settings()
    request = _request(args)
    part = _load(args, settings)
    cell = _cell(args, request, settings)
    run = resolution_sweep if args.kind == "resolution" else decimation_study
    values = args.resolutions if args.kind == "resolution" else args.ratios
    with _progress(args.quiet) as report:
        study = run(
            part,
            request,
            values,
            limits=settings.limits(),
            threads=args.threads or settings.threads,
            progress=report,
            cell=cell,
        )
    Console().print(study_table(study))
    text = study.model_dump_json(indent=1)
    if args.output:
        _write(args.output, text)
        print(f"study written to {args.output}")
    if args.csv:
        _write(args.csv, study_csv(study))
        print(f"rows written to {args.csv}")
    if args.plots:
        from vpp_core.report.plots import study_plots

        data = {"study.json": text.encode(), "study.csv": study_csv(study).encode()}
        _write_all(args.plots, {**data, **study_plots(study)})
    return 0


def regions_table(doc: PlanDocument) -> Table:
    """The plan's figures per region (metrics.regions)."""
    table = Table(title="regions (each face against its own target)")
    for head in ["region", "r̄ mm", "faces", "area mm²", "coverage area", "met area", "max met"]:
        table.add_column(head, justify="right")
    for r in doc.metrics.regions:
        table.add_row(
            Text(r.name),  # a user's name, not rich markup
            "ignored" if r.ignored else f"{r.resolution_mm:g}",
            str(r.faces),
            f"{r.area_mm2:,.1f}",
            f"{r.coverage_area:.2%}",
            "-" if r.ignored else f"{r.met_area:.2%}",
            "-" if r.ignored else f"{r.max_met_area:.2%}",
        )
    return table


def study_table(study: Study) -> Table:
    """The study's rows as a table."""
    t = study.timings_s
    table = Table(
        title=f"vpp study {study.kind} — mesh {study.mesh.id[:12]} ({study.mesh.faces} faces); "
        f"trace {t.trace_s:.1f} s, {len(t.solve_s)} solves {sum(t.solve_s):.1f} s"
    )
    decimation = study.kind == "decimation"
    heads = ["ratio", "faces"] if decimation else []
    for head in [*heads, "r̄ mm", "formulation", "#OVP", "coverage area", "met area", "solver"]:
        table.add_column(head, justify="right")
    for row in study.rows:
        extra = (
            [f"{row.ratio:g}", str(row.planning_faces)] if isinstance(row, DecimationRow) else []
        )
        table.add_row(
            *extra,
            f"{row.resolution_mm:g}",
            row.formulation,
            str(row.viewpoints),
            f"{row.coverage.area:.2%}",
            f"{row.resolution.met_area:.2%}",
            f"{row.solver.status} (gap {_g(row.solver.gap)})",
        )
    return table


def _load(args: argparse.Namespace, settings: Settings) -> Part:
    """The mesh file of the command line as a Part, within the settings' limits."""
    data = _read(args.mesh, settings.max_upload_bytes)
    fmt = args.format or args.mesh.suffix.lstrip(".") or "stl"
    labels = _read(args.labels, settings.max_upload_bytes) if args.labels else None
    return load_part(
        data,
        fmt,
        args.units,
        remesh_mm=args.remesh,
        max_face_area_mm2=args.max_face_area,
        max_faces=settings.max_faces,
        labels=labels,
    )


def _cell(args: argparse.Namespace, request: PlanRequest, settings: Settings) -> Cell | None:
    """The request's setup with its fixture and keep-out mesh files read (paths relative to
    the SETUP.json)."""
    folder = args.setup.parent if args.setup else Path(".")

    def load(shape: MeshShape) -> tuple[Any, Any]:
        path = folder / shape.mesh
        data = _read(path, settings.max_upload_bytes)
        fmt = path.suffix.lstrip(".") or "stl"
        try:
            mesh = load_part(data, fmt, shape.units, max_faces=settings.max_faces)
        except VppError as exc:
            raise InputError(f"{path}: {exc.detail}") from None
        return mesh.vertices, mesh.faces

    return resolve(request.setup, load)


def _write_all(folder: Path, files: dict[str, bytes]) -> None:
    """Write files into `folder` (created), one line saying where."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"{folder}: {exc.strerror or exc}") from None
    for name, data in files.items():
        _write_bytes(folder / name, data)
    print(f"{', '.join(files)} written to {folder}")


def run_sample(args: argparse.Namespace) -> int:
    """Write the sample part."""
    _write_bytes(args.output, sample_stl())
    print(f"sample part written to {args.output} (flanged bushing, mm)")
    return 0


def _request(args: argparse.Namespace) -> PlanRequest:
    """The plan request from the command line options."""
    try:
        sensor = make_sensor(_read_json(args.sensor) if args.sensor else None)
        candidates: Any = (
            _read_json(args.candidates_file)
            if args.candidates_file
            else CandidateGenerator(
                count=args.candidates,
                seed=args.seed,
                decimate=args.decimate,
                clearance_mm=args.clearance,
                tilt_deg=args.tilt,
                retry_tilt_deg=args.retry_tilt,
                standoff_mm=args.standoff,
                adaptive=args.adaptive,
                sphere=args.sphere,
                roll=args.roll,
                tiles=args.tiles,
            )
        )
        return PlanRequest(
            profile=args.profile,
            sensor=sensor,
            target=Target(
                resolution_mm=args.resolution,
                formulation=args.formulation,
                min_coverage=args.min_coverage,
                rows=args.rows,
                open_min=args.open_min,
            ),
            candidates=candidates,
            solver=SolverSettings(
                name=args.solver, time_limit_s=args.time_limit, mip_rel_gap=args.gap
            ),
            objective=Objective(
                name=args.objective,
                dwell_s=args.dwell,
                speed_mm_s=args.speed,
                accel_mm_s2=args.accel,
                home=args.home,
            ),
            backend=args.backend,
            setup=_setup_json(args.setup) if args.setup else None,
            regions=_read_json(args.regions) if args.regions else [],
        )
    except ValidationError as exc:
        err = exc.errors()[0]
        where = ".".join(str(p) for p in err["loc"])
        raise InputError(f"{where}: {err['msg']}") from None


def _read(path: Path, max_bytes: int) -> bytes:
    """File bytes, or InputError when missing, unreadable or too large."""
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise InputError(
                f"{path}: {size} bytes exceed the limit of {max_bytes} (VPP_MAX_UPLOAD_BYTES)"
            )
        return path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path}: {exc.strerror or exc}") from None


def _setup_json(path: Path) -> Any:
    """SETUP.json, a robot's `urdf` file (a path relative to it) read into its text."""
    setup = _read_json(path)
    robot = setup.get("robot") if isinstance(setup, dict) else None
    urdf = robot.get("urdf") if isinstance(robot, dict) else None
    if isinstance(robot, dict) and isinstance(urdf, str) and not urdf.lstrip().startswith("<"):
        try:
            robot["urdf"] = _read(path.parent / urdf, 4 * 2**20).decode()
        except UnicodeDecodeError:
            raise InputError(f"{path.parent / urdf}: not a URDF text file") from None
    return setup


def _read_json(path: Path) -> Any:
    """Parsed JSON of a small file, or InputError."""
    try:
        return json.loads(_read(path, 64 * 2**20))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid JSON ({exc})") from None


def _write(path: Path, text: str) -> None:
    """Write text, or InputError when the path cannot be written."""
    _write_bytes(path, text.encode())


def _write_bytes(path: Path, data: bytes) -> None:
    """Write bytes, or InputError when the path cannot be written."""
    try:
        path.write_bytes(data)
    except OSError as exc:
        raise InputError(f"{path}: {exc.strerror or exc}") from None


class _progress:
    """Rich progress bars on stderr, one per stage; a no-op when quiet or not a terminal."""

    def __init__(self, quiet: bool) -> None:
        console = Console(stderr=True)
        self.bars = (
            None
            if quiet
            else Progress(
                TextColumn("{task.description:<10}"),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                console=console,
                transient=True,
            )
        )
        self.tasks: dict[str, Any] = {}

    def __enter__(self) -> _progress:
        if self.bars:
            self.bars.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.bars:
            self.bars.stop()

    def __call__(self, stage: str, done: int, total: int) -> None:
        if not self.bars:
            return
        for name, task in self.tasks.items():
            if name != stage:
                self.bars.update(task, completed=self.bars.tasks[task].total)
        if stage not in self.tasks:
            self.tasks[stage] = self.bars.add_task(stage, total=total)
        self.bars.update(self.tasks[stage], completed=done)


def summary(doc: PlanDocument) -> Table:
    """The short summary table printed on stdout."""
    m, s, t = doc.metrics, doc.solver, doc.timings_s
    table = Table(title=f"vpp plan — mesh {doc.mesh.id[:12]} ({doc.mesh.faces} faces)")
    table.add_column("item")
    table.add_column("value", justify="right")
    rows = [
        ("viewpoints", f"{len(doc.viewpoints)} of {len(doc.candidates)} candidates"),
        (
            "solver",
            f"{s.name} {s.status}, objective {s.objective:g}, bound {_g(s.bound)}, gap {_g(s.gap)}",
        ),
        ("coverage (area)", f"{m.coverage.area:.2%} (max {m.coverage.max_area:.2%})"),
        ("coverage (faces)", f"{m.coverage.faces:.2%} (max {m.coverage.max_faces:.2%})"),
        (
            f"resolution ≤ {doc.target.resolution_mm:g} mm (area)",
            f"{m.resolution.met_area:.2%} (max {m.resolution.max_met_area:.2%})",
        ),
        ("median resolution", f"{_g(m.resolution.median_mm)} mm"),
        ("uncoverable faces", f"{doc.uncoverable.faces} ({doc.uncoverable.area_mm2:.4g} mm²)"),
        *_setup_rows(doc),
        *_robot_rows(doc),
        *_tour_rows(doc),
        *_partial_rows(doc),
        *_diagnostic_rows(doc),
        (
            "rays",
            f"{doc.rays.pixels:.3g} pixels, {doc.rays.cast:.3g} cast "
            f"at {doc.rays.cast_per_s / 1e6:.1f} Mrays/s ({doc.rays.backend})",
        ),
        ("time per stage, s", " ".join(f"{k} {v:.2f}" for k, v in t.model_dump().items())),
    ]
    for row in rows:
        table.add_row(*row)
    return table


def _setup_rows(doc: PlanDocument) -> list[tuple[str, str]]:
    """The summary row of the setup: uncoverable faces it hides (none without a setup)."""
    o = doc.setup_occluded
    if o is None:
        return []
    return [
        (
            "of them setup_occluded",
            f"{o.faces} ({o.area_mm2:.4g} mm²: {o.touching} touching, {o.blocked} blocked, "
            f"{o.unreachable} unreachable)",
        )
    ]


def _robot_rows(doc: PlanDocument) -> list[tuple[str, str]]:
    """The summary rows of a robot or turntable: what its reach dropped, its joint tour."""
    r = doc.robot
    if r is None:
        return []
    why = ", ".join(f"{n} {k}" for k, n in r.dropped.items())
    rows = [(f"robot ({r.name})", f"{r.checked} poses checked, dropped: {why}")]
    if r.tour is not None:
        t = r.tour
        rows.append(
            (
                "joint-space tour",
                f"travel {t.travel_s:.3g} s, cycle {t.cycle_time_s:.3g} s ({t.solver}), "
                f"{len(t.path_violations)} legs touching",
            )
        )
    return rows


def _tour_rows(doc: PlanDocument) -> list[tuple[str, str]]:
    """The summary row of the tour: length, cycle time, solver."""
    t = doc.tour
    if t is None:
        return []
    home = "from home" if t.home is not None else "open path"
    return [
        (
            "tour",
            f"{t.length_mm:.0f} mm {home}, cycle {t.cycle_time_s:.1f} s "
            f"(dwell {t.dwell_s:.1f} + travel {t.travel_s:.1f}; {t.solver}, {t.cover} cover)",
        )
    ]


def _partial_rows(doc: PlanDocument) -> list[tuple[str, str]]:
    """Summary rows of a partial cover (none for the strict cover)."""
    p = doc.partial
    if p is None:
        return []
    out = [
        (
            f"partial cover (min {p.min_coverage:.2%})",
            f"{p.covered_fraction:.3%} of the coverable area; left out {p.left_out.faces} "
            f"faces ({p.left_out.area_mm2:.4g} mm²)",
        )
    ]
    if p.points is not None:
        q, more = p.points, len(p.points.added)
        added = f"; {more} view{'s' if more != 1 else ''} added for it" if more else ""
        out.append(
            (
                f"seen at {q.points} points",
                f"{q.seen_fraction:.2%} (the candidates {q.reach_fraction:.2%}){added}",
            )
        )
    rows = doc.cover_rows
    if rows is not None and rows.recessed_area:
        r = rows.recessed
        unmet = f"; {r.faces} faces ({r.area_mm2:.4g} mm²) of them unmet" if r else ""
        out.append(("recessed (not counted)", f"{rows.recessed_area:.2%} of the area{unmet}"))
    return out


def _diagnostic_rows(doc: PlanDocument) -> list[tuple[str, str]]:
    """Summary rows of the diagnostics: the faces that can force views."""
    d = doc.diagnostics
    if d is None:
        return []
    sc, inner = d.single_candidate, d.internal
    under = [] if d.undersampled is None else [_undersampled_row(d.undersampled)]
    return [
        (
            "sub-pixel faces",
            f"{d.subpixel.faces} ({d.subpixel.area_mm2:.4g} mm²) below "
            f"{d.pixel_footprint_mm:.3g}² mm²",
        ),
        (
            "single-candidate faces",
            f"{sc.faces} ({sc.area_mm2:.4g} mm²), {sc.one_ray} hit by one ray",
        ),
        (
            "internal faces",
            f"{inner.enclosed.faces} enclosed ({inner.tested} tested), "
            f"{inner.back_to_back.faces} back-to-back",
        ),
        (
            "views only for such faces",
            f"{d.driven_views} of {len(d.viewpoints)} ({d.driven_area_mm2:.4g} mm²)",
        ),
        *under,
    ]


def _undersampled_row(u: Undersampled) -> tuple[str, str]:
    """The summary row of seen faces larger than an element that the rays sample in part."""
    return (
        f"seen faces > {u.element_mm2:g} mm²",
        f"{u.unsampled_mm2:.4g} mm² get no ray; {u.faces} ({u.area_mm2:.4g} mm²) under half",
    )


def _g(x: float | None) -> str:
    """Compact number or '-'."""
    return "-" if x is None else f"{x:.4g}"


if __name__ == "__main__":
    sys.exit(main())
