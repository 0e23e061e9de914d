"""Benchmark the ray tracer against bare Embree on the same rays; one JSON line per measurement.

    python bench/raytrace.py [--meshes MESH...] [--views 8] [--threads 1,2]
                             [--synthetic-faces 1000000] [--distance 500] [--repeat 1]
                             [--malloc fixed|default] [--wait-idle S]

Every mesh is seen by `--views` cameras of the paper's sensor (1920 x 1200 px) placed
`--distance` mm from the centre of its bounding box, along directions spread evenly on a
sphere (Fibonacci lattice), looking at the centre. For each mesh and thread count T:

- `bare`: `EmbreeScene.run(origins, directions, dists=far, output=1)` on each view's
  world-space float32 ray directions (exactly those `trace_counts` builds), in chunks of
  whole image rows (~`CHUNK_RAYS` rays, as `trace_counts` splits them) over a T-thread pool,
  no post-processing: the reference rate. The scene is built as `EmbreeBackend` builds it
  (robust); the directions and origins are made before the clock starts.
- `bare_primid`: the same with plain `run(origins, directions)` (primID only, no far limit),
  for information.
- `full`: `trace_counts(..., threads=T, cull=False)` (all pixels, post-processing and
  sparse assembly included); rays/s = views x pixels / wall.
- `cull`: `trace_counts(..., threads=T, cull=True)` (pixels inside the projected hull only);
  pixel rays/s = views x pixels / wall, cast rays/s = rays_cast / wall.

The scene is built once per mesh (its build time is reported on the `mesh` line, not in any
rate) and shared by all measurements; each measurement is warmed up once on one view, then
timed `--repeat` times (the fastest run is reported). The `mesh` line also gives the hit
fraction and the depth range of first hits over all views (from an untimed pass), which
shows whether the part lies in the depth of field. `--synthetic-faces N` adds an icosphere
of radius 150 mm (subdivision level chosen so its face count is nearest N on a log scale;
0 = none); seen from 500 mm its visible surface lies at depths 350-455 mm, inside the
300-700 mm depth of field.

Each `measure` line also has `own_cores` (this process's CPU seconds / wall: a 1-thread
run above 1 means helper threads, e.g. OpenBLAS's, are spinning), `others_cores` (other
processes' use of the machine meanwhile: above ~0.2 the numbers are disturbed; `--wait-idle S`
waits up to S s for quiet before each measurement) and `page_faults`. By default glibc's
malloc thresholds are pinned first (`--malloc fixed`, see `fix_malloc`), which makes the
rates repeatable. A summary table goes to stderr at the end (stdout stays JSON lines).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vpp_core.mesh import Part, load_mesh, part_from_arrays  # noqa: E402
from vpp_core.pose import Viewpoints, make_viewpoints  # noqa: E402
from vpp_core.raytrace import CHUNK_RAYS, EmbreeBackend, _hull_points, trace_counts  # noqa: E402
from vpp_core.sensor import Sensor  # noqa: E402

MESH_DIR = ROOT.parent / "shared" / "meshes"
DEFAULT_MESHES = ["1002_tray_bottom.STL", "counter.unitsmm.STL", "turbineblade.ply"]
UNITS = {  # shared meshes not in mm (see ../shared/meshes/README.md)
    "ADIS16480.STL": "m",
    "abc_00000006_pipe_fitting.stl": "m",
    "featuretype.STL": "in",
    "42400-IDGH_exhaust_manifold.stl": "in",
}
SPHERE_RADIUS_MM = 150.0


@dataclass
class Row:
    """One (mesh, threads) line of the summary table."""

    mesh: str
    faces: int
    threads: int
    build_s: float
    hit_fraction: float
    rates: dict[str, float] = field(default_factory=dict)  # Mrays/s by measurement
    walls: dict[str, float] = field(default_factory=dict)  # seconds by measurement
    cast_fraction: float = math.nan
    others: float = 0.0  # most cores other processes used during one of the row's timings


def rnd(x: float | None, digits: int = 2) -> float | None:
    """x rounded, None kept."""
    return None if x is None else round(x, digits)


def fix_malloc() -> bool:
    """Stop glibc from returning freed blocks of up to 32 MiB to the OS; True if done.

    Embree's `run(output=1)` allocates ~32 bytes per ray of fresh result arrays per call.
    With glibc's default, sliding mmap/trim thresholds, whether those come back as recycled
    heap memory or as new pages (page faults, ~20 % of the trace time) depends on the
    process's allocation history, so the same measurement runs at two speeds from one
    process to the next. Fixed thresholds remove that lottery for every measurement alike.
    """
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(mallopt(m_mmap_threshold, 32 << 20)) and bool(mallopt(m_trim_threshold, 1 << 30))


def emit(record: dict[str, Any]) -> None:
    """Print one JSON line."""
    print(json.dumps(record), flush=True)


def fibonacci_directions(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread evenly on the sphere."""
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = i * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def ring_views(part: Part, n: int, distance: float) -> Viewpoints:
    """n cameras at `distance` mm from the part's bounding-box centre, looking at it."""
    centre = part.bounds.mean(axis=0)
    dirs = fibonacci_directions(n)
    return make_viewpoints(centre + distance * dirs, -dirs)


def synthetic_part(target_faces: int) -> tuple[str, Part]:
    """An icosphere of radius SPHERE_RADIUS_MM with about target_faces faces (20 * 4**s)."""
    import trimesh

    level = max(0, round(math.log(max(target_faces, 20) / 20, 4)))
    sphere = trimesh.creation.icosphere(subdivisions=level, radius=SPHERE_RADIUS_MM)
    name = f"icosphere(s={level}, r={SPHERE_RADIUS_MM:g}mm)"
    return name, part_from_arrays(np.asarray(sphere.vertices), np.asarray(sphere.faces))


def load_part(path: Path, units: str | None) -> Part:
    """Load a mesh file into a Part (units from the table of shared meshes unless given)."""
    return load_mesh(path.read_bytes(), path.suffix, units or UNITS.get(path.name, "mm"))


@dataclass
class Rays:
    """Every view's world-space ray directions and origins, as trace_counts builds them."""

    origins: list[np.ndarray]  # (P, 3) float32 per view (a broadcast row)
    directions: list[np.ndarray]  # (P, 3) float32, per view
    chunks: list[tuple[int, int, int]]  # (view, first ray, end ray)

    @classmethod
    def build(cls, sensor: Sensor, views: Viewpoints) -> Rays:
        rotations = views.rotations()
        dirs = [sensor.camera_rays @ r.T.astype(np.float32) for r in rotations]
        origins = [  # one row seen n times, as EmbreeBackend.first_hits passes it
            np.broadcast_to(p.astype(np.float32), d.shape)
            for p, d in zip(views.positions, dirs, strict=True)
        ]
        step = max(1, CHUNK_RAYS // sensor.width_px) * sensor.width_px
        chunks = [
            (j, s, min(s + step, sensor.n_pixels))
            for j in range(len(views))
            for s in range(0, sensor.n_pixels, step)
        ]
        return cls(origins, dirs, chunks)

    @property
    def total(self) -> int:
        return sum(len(d) for d in self.directions)


def run_bare(
    scene: Any, rays: Rays, far: float, threads: int, primid_only: bool, views: int | None = None
) -> None:
    """Trace the chunks (of the first `views` views) over a pool; results are dropped."""
    chunks = [c for c in rays.chunks if views is None or c[0] < views]

    def work(chunk: tuple[int, int, int]) -> None:
        j, s, e = chunk
        if primid_only:
            scene.run(rays.origins[j][s:e], rays.directions[j][s:e])
        else:
            scene.run(rays.origins[j][s:e], rays.directions[j][s:e], dists=far, output=1)

    with ThreadPoolExecutor(threads) as pool:
        for _ in pool.map(work, chunks):
            pass


def hit_stats(scene: Any, rays: Rays, far: float, threads: int) -> tuple[float, list[float]]:
    """Fraction of all rays that hit before far, and [min, max] depth of the hits (untimed)."""

    def work(chunk: tuple[int, int, int]) -> tuple[int, float, float]:
        j, s, e = chunk
        out = scene.run(rays.origins[j][s:e], rays.directions[j][s:e], dists=far, output=1)
        t = out["tfar"][out["primID"] >= 0]
        return len(t), float(t.min(initial=np.inf)), float(t.max(initial=-np.inf))

    with ThreadPoolExecutor(threads) as pool:
        res = list(pool.map(work, rays.chunks))
    hits = sum(r[0] for r in res)
    lo, hi = min(r[1] for r in res), max(r[2] for r in res)
    return hits / rays.total, [round(lo, 1), round(hi, 1)] if hits else []


def busy_seconds() -> tuple[float, float] | None:
    """(CPU seconds used by the whole machine, by this process) so far; None off Linux."""
    try:
        with open("/proc/stat") as fh:
            f = [int(x) for x in fh.readline().split()[1:9]]
    except (OSError, ValueError):
        return None
    t = os.times()
    return (sum(f) - f[3] - f[4]) / os.sysconf("SC_CLK_TCK"), t.user + t.system


def minor_faults() -> int | None:
    """Minor page faults of this process so far (None where unsupported)."""
    try:
        import resource
    except ImportError:
        return None
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_minflt)


def others_cores(before: tuple[float, float] | None, wall: float) -> float | None:
    """Cores used on average by other processes since `before` (wall seconds ago)."""
    after = busy_seconds()
    if before is None or after is None or wall <= 0:
        return None
    return max(0.0, ((after[0] - before[0]) - (after[1] - before[1])) / wall)


def wait_idle(limit_s: float, max_cores: float = 0.25) -> None:
    """Wait (at most limit_s) until other processes use under max_cores over a 1 s sample."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        before = busy_seconds()
        time.sleep(1.0)
        used = others_cores(before, 1.0)
        if used is None or used < max_cores:
            return


@dataclass
class Timing:
    """Fastest wall time of a measurement and the CPU use around it."""

    wall: float = math.inf
    own_cores: float | None = None  # this process's CPU seconds / wall (all its threads)
    others_cores: float | None = None  # other processes' CPU seconds / wall
    page_faults: int | None = None  # this process's minor page faults during it


def timed(fn: Callable[[], Any], repeat: int) -> tuple[Timing, Any]:
    """Fastest of `repeat` calls of fn, with this and other processes' average core use
    during it (a noisy machine, or helper threads spinning, show here), and the last result."""
    best, result = Timing(), None
    for _ in range(repeat):
        before, faults = busy_seconds(), minor_faults()
        t0 = time.perf_counter()
        result = fn()
        wall = time.perf_counter() - t0
        if wall < best.wall:
            end = minor_faults()
            faults = None if faults is None or end is None else end - faults
            own = None
            if before is not None and (after := busy_seconds()) is not None:
                own = (after[1] - before[1]) / wall
            best = Timing(wall, own, others_cores(before, wall), faults)
    return best, result


def bench_part(
    name: str, part: Part, args: argparse.Namespace, sensor: Sensor, rows: list[Row]
) -> None:
    """All measurements on one part; JSON lines to stdout, table rows appended to rows."""
    views = ring_views(part, args.views, args.distance)
    n, far = len(views), sensor.far_mm
    pixels = n * sensor.n_pixels
    t0 = time.perf_counter()
    backend = EmbreeBackend(part.vertices, part.faces)  # robust=True, as make_backend
    scene = backend._scene
    scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # commit = BVH build
    build_s = time.perf_counter() - t0
    rays = Rays.build(sensor, views)
    t0 = time.perf_counter()
    hull = _hull_points(part.vertices)
    hull_s = time.perf_counter() - t0
    hit_fraction, depth = hit_stats(scene, rays, far, max(args.threads))
    emit(
        {
            "kind": "mesh",
            "mesh": name,
            "faces": part.n_faces,
            "vertices": len(part.vertices),
            "bbox_mm": [round(float(x), 2) for x in np.ptp(part.bounds, axis=0)],
            "distance_mm": args.distance,
            "views": n,
            "pixels": pixels,
            "build_s": round(build_s, 4),
            "hull_points": len(hull),
            "hull_s": round(hull_s, 4),
            "hit_fraction": round(hit_fraction, 4),
            "hit_depth_mm": depth,
            "dof_mm": [sensor.near_mm, far],
        }
    )
    first = views.take(np.array([0]))
    for threads in args.threads:
        row = Row(name, part.n_faces, threads, build_s, hit_fraction)
        rows.append(row)
        base = {"kind": "measure", "mesh": name, "faces": part.n_faces, "threads": threads}
        base |= {"views": n, "pixels": pixels}

        for mode, primid in (("bare", False), ("bare_primid", True)):
            wait_idle(args.wait_idle)
            run_bare(scene, rays, far, threads, primid, views=1)  # warm-up
            tm, _ = timed(partial(run_bare, scene, rays, far, threads, primid), args.repeat)
            wall = tm.wall
            row.rates[mode], row.walls[mode] = pixels / wall / 1e6, wall
            row.others = max(row.others, tm.others_cores or 0.0)
            record = base | {"mode": mode, "rays": pixels, "wall_s": round(wall, 4)}
            record |= {"mrays_s": round(pixels / wall / 1e6, 3), "own_cores": rnd(tm.own_cores)}
            emit(record | {"others_cores": rnd(tm.others_cores), "page_faults": tm.page_faults})

        for mode, cull in (("full", False), ("cull", True)):
            wait_idle(args.wait_idle)
            trace_counts(part, sensor, first, backend=backend, threads=threads, cull=cull)
            trace = partial(trace_counts, part, sensor, views, backend=backend, threads=threads)
            tm, tr = timed(partial(trace, cull=cull), args.repeat)
            assert tr.pixels == pixels
            wall = tm.wall
            rate = pixels / wall / 1e6
            row.rates[mode], row.walls[mode] = rate, wall
            row.others = max(row.others, tm.others_cores or 0.0)
            record = base | {"mode": mode, "rays": tr.rays_cast, "wall_s": round(wall, 4)}
            record |= {"mrays_s": round(rate, 3)}
            record |= {"cast_mrays_s": round(tr.rays_cast / wall / 1e6, 3)}
            record |= {
                "ratio_to_bare": round(rate / row.rates["bare"], 3),
                "cast_fraction": round(tr.rays_cast / pixels, 4),
                "valid_rays": int(tr.counts.sum()),
                "valid_fraction": round(int(tr.counts.sum()) / pixels, 4),
                "own_cores": rnd(tm.own_cores),
                "others_cores": rnd(tm.others_cores),
                "page_faults": tm.page_faults,
            }
            if cull:
                row.cast_fraction = tr.rays_cast / pixels
                row.rates["cull_cast"] = tr.rays_cast / wall / 1e6
            emit(record)


def print_table(rows: list[Row], target: float) -> None:
    """Human-readable summary on stderr."""
    head = (
        f"{'mesh':<36} {'faces':>8} {'T':>2} {'build s':>7} {'hit%':>6} {'bare':>6} "
        f"{'primID':>6} {'full':>6} {'b/a':>5} {'cull px':>7} {'cull cast':>9} {'cast%':>6}  "
        f"{'wall s bare/full/cull':>21} {'other':>5}"
    )
    title = (
        "Mrays/s (bare = Embree run(output=1) reference; primID = plain run(); "
        "full = trace_counts cull=False; cull = cull=True, per pixel and per cast ray)"
    )
    out = ["", title, head, "-" * len(head)]
    for r in rows:
        ratio = r.rates["full"] / r.rates["bare"]
        flag = "" if ratio >= target else " <"
        walls = "/".join(f"{r.walls[k]:.2f}" for k in ("bare", "full", "cull"))
        out.append(
            f"{r.mesh[:36]:<36} {r.faces:>8} {r.threads:>2} {r.build_s:>7.3f} "
            f"{100 * r.hit_fraction:>5.1f}% {r.rates['bare']:>6.2f} {r.rates['bare_primid']:>6.2f} "
            f"{r.rates['full']:>6.2f} {ratio:>5.2f} {r.rates['cull']:>7.2f} "
            f"{r.rates['cull_cast']:>9.2f} {100 * r.cast_fraction:>5.1f}%  {walls:>21} "
            f"{r.others:>5.2f}{flag}"
        )
    out.append(
        f"(b/a target >= {target}; '<' marks a miss; other = most cores other processes used "
        "during the row's timings: above ~0.2 the rates are disturbed)"
    )
    print("\n".join(out), file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument(
        "--meshes",
        nargs="*",
        type=Path,
        default=[MESH_DIR / m for m in DEFAULT_MESHES],
        help="mesh files (default: a few of ../shared/meshes)",
    )
    ap.add_argument("--units", default=None, help="units of all meshes (default: per file, mm)")
    ap.add_argument("--views", type=int, default=8, help="cameras per mesh")
    ap.add_argument("--threads", default="1,2", help="comma-separated thread counts")
    ap.add_argument(
        "--synthetic-faces", type=int, default=1_000_000, help="icosphere faces (~), 0 = none"
    )
    ap.add_argument("--distance", type=float, default=None, help="camera distance, mm (def. WD)")
    ap.add_argument("--repeat", type=int, default=1, help="timed runs per measurement (fastest)")
    ap.add_argument("--target", type=float, default=0.80, help="target full/bare ratio")
    ap.add_argument(
        "--malloc",
        choices=["fixed", "default"],
        default="fixed",
        help="fixed: glibc mmap/trim thresholds pinned (stable rates, see fix_malloc); "
        "default: leave glibc's sliding thresholds",
    )
    ap.add_argument(
        "--wait-idle",
        type=float,
        default=0.0,
        metavar="S",
        help="before each measurement wait up to S s for other processes to go idle",
    )
    args = ap.parse_args(argv)
    args.threads = [int(t) for t in args.threads.split(",") if t.strip()]
    malloc_fixed = args.malloc == "fixed" and fix_malloc()
    sensor = Sensor()
    args.distance = args.distance or sensor.working_distance
    emit(
        {
            "kind": "setup",
            "sensor": [sensor.width_px, sensor.height_px],
            "threads": args.threads,
            "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "chunk_rays": CHUNK_RAYS,
            "malloc_fixed": malloc_fixed,
            "openblas_num_threads": os.environ.get("OPENBLAS_NUM_THREADS"),
            "numpy": np.__version__,
        }
    )
    rows: list[Row] = []
    for path in args.meshes:
        if not path.is_file():
            print(f"skipping {path}: not found", file=sys.stderr)
            continue
        bench_part(path.name, load_part(path, args.units), args, sensor, rows)
    if args.synthetic_faces > 0:
        t0 = time.perf_counter()
        name, part = synthetic_part(args.synthetic_faces)
        took = time.perf_counter() - t0
        print(f"built {name}: {part.n_faces} faces in {took:.1f} s", file=sys.stderr)
        bench_part(name, part, args, sensor, rows)
    if rows:
        print_table(rows, args.target)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
