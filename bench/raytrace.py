"""Ray tracing speed: the C++ Embree packet ceiling, bare embreex and every project backend.

    python bench/raytrace.py [--faces 10000,100000,1000000] [--sizes large,small]
                             [--meshes MESH...] [--views 8] [--threads 1,2] [--repeat 3]
                             [--min-time 1] [--backends raster,embree] [--no-ceiling]
                             [--wait-idle S]

Scenes: a sphere of about each `--faces` count (trimesh UV sphere) in two sizes, `large`
(radius 195 mm: its silhouette covers the whole frame, 100 % of pixels hit) and `small`
(radius 38 mm: about 6 % of pixels), and every `--meshes` file (units from the MANIFEST.csv
beside it). Each is seen by `--views` cameras of the paper's sensor (1920 x 1200 px) placed
500 mm from its centre along directions spread evenly on a sphere, looking at it.

Every method traces the same rays: one per pixel centre of each view's window (the pixels
inside the image of the part's hull, as `trace_counts` culls them); a rate is those rays
over the wall time (Mrays/s), and `px/s` counts whole frames (views x 2.3 Mpx / wall).

- `ceiling`: bench/ceiling.cpp, Embree from C++ (`rtcIntersect16`, coherent flag, 4x4 pixel
  tiles, T std::threads), first hits only. Compiled here with g++ against Embree 4 headers
  if found, else Embree 3 (Debian: `apt install libembree-dev`); skipped with a message when
  neither is installed.
- `bare`: embreex `EmbreeScene.run(origins, directions, dists=far, output=1)` on each view's
  window rays in chunks of whole rows (~CHUNK_RAYS) over a T-thread pool, first hits only.
- one row per project backend: `trace_counts(..., backend=B, threads=T)`: R complete,
  post-processing (depth of field, incidence, per-face counts, sparse assembly) included.
  `packets` uses the system's Embree 3 where installed (the ceiling's library), else
  embreex's Embree 4 (no coherent packet path): the setup line says which.

Each scene is measured in a fresh process, as the ceiling's harness runs and as a plan does
(in one process, a scene traced after others ran up to 13 % slower: the turbine blade after
the spheres, 31.0 → 34.9 ms on 1 thread). The scene of each method is built once per part
(not timed); each measurement is warmed up on one view, then timed `--repeat` times and
more, as many as fit in `--min-time` seconds
(the fastest is kept; the ceiling's harness repeats as often, so fast scenes get the same
many chances on both sides). One JSON line per
measurement goes to stdout; a summary table with the ratio of each backend to the ceiling and
to bare embreex goes to stderr. `others` in the table is the most cores other processes used
during the row's timings (above ~0.2 the rates are disturbed).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import itertools
import json
import math
import multiprocessing
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from vpp_core.camera.pose import Viewpoints, make_viewpoints  # noqa: E402
from vpp_core.camera.sensor import Sensor  # noqa: E402
from vpp_core.mesh.part import Part, load_mesh, part_from_arrays  # noqa: E402
from vpp_core.trace.embree import CHUNK_RAYS, EmbreeBackend, block_directions  # noqa: E402
from vpp_core.trace.packets import library as packets_library  # noqa: E402
from vpp_core.trace.rays import Block  # noqa: E402
from vpp_core.trace.raytrace import (  # noqa: E402
    BACKENDS,
    _chunks,
    _hull_points,
    make_backend,
    trace_counts,
    view_windows,
)

MESH_DIR = ROOT.parent / "shared" / "meshes"
UNITS = {"mm": "mm", "mm?": "mm", "unknown": "mm", "m": "m", "inch": "in", "inch?": "in"}
SIZES_MM = {"large": 195.0, "small": 38.0}
"""Sphere radius per part size: seen from 500 mm, the large one's silhouette covers the frame's
diagonal (every pixel hits; its front lies at 305 mm, inside the 300-700 mm depth of field),
the small one covers about 6 % of the pixels."""
DISTANCE_MM = 500.0


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


def sphere(faces: int, radius: float) -> tuple[str, Part]:
    """A geodesic sphere of about `faces` faces and `radius` mm: each icosahedron face cut
    into n^2 triangles (20 n^2 in all), projected onto the sphere (well-shaped triangles)."""
    import trimesh

    n = max(1, round(math.sqrt(faces / 20)))
    ico = trimesh.creation.icosahedron()
    a, b, c = (ico.vertices[ico.faces[:, k]] for k in range(3))
    ij = [(i, j) for i in range(n + 1) for j in range(n + 1 - i)]
    index = {p: k for k, p in enumerate(ij)}
    w = np.array(ij, dtype=float) / n  # barycentric weights of b and c per lattice point
    points = (
        a[:, None] * (1 - w.sum(1))[None, :, None]
        + b[:, None] * w[None, :, :1]
        + c[:, None] * w[None, :, 1:]
    )
    tris = [(index[i, j], index[i + 1, j], index[i, j + 1]) for i, j in ij if i + j < n]
    tris += [
        (index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]) for i, j in ij if i + j < n - 1
    ]
    local = np.array(tris)
    verts = points.reshape(-1, 3)
    tri = (local[None] + (np.arange(20) * len(ij))[:, None, None]).reshape(-1, 3)
    mesh = trimesh.Trimesh(verts / np.linalg.norm(verts, axis=1, keepdims=True) * radius, tri)
    mesh.merge_vertices()
    part = part_from_arrays(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    return f"sphere r={radius:g}mm", part


def mesh_units(path: Path) -> str:
    """Units of a shared mesh from the MANIFEST.csv beside it, else mm."""
    table = path.parent / "MANIFEST.csv"
    if table.is_file():
        with open(table, newline="") as fh:
            for row in csv.DictReader(fh):
                if row["file"] == path.name:
                    return UNITS.get(row["units_guess"].strip().lower(), "mm")
    return "mm"


@dataclass
class Scene:
    """A part, its views and their pixel windows (the rays every method traces)."""

    name: str
    part: Part
    views: Viewpoints
    windows: list[tuple[int, int, int, int]]
    sensor: Sensor

    @property
    def rays(self) -> int:
        return sum((w[1] - w[0]) * (w[3] - w[2]) for w in self.windows)

    @property
    def pixels(self) -> int:
        return len(self.views) * self.sensor.n_pixels

    def blocks(self) -> list[Block]:
        """Each view's window in blocks of whole rows of about CHUNK_RAYS rays, as
        `trace_counts` splits it for the `embree` backend."""
        rotations = self.views.rotations()
        return [
            Block(self.sensor, self.views.positions[c.view], rotations[c.view], c.rows, c.cols)
            for j, window in enumerate(self.windows)
            for c in _chunks(j, *window, CHUNK_RAYS)
        ]


def make_scene(name: str, part: Part, views: int, sensor: Sensor) -> Scene:
    """The part seen by `views` ring cameras at DISTANCE_MM, with their culled windows."""
    ring = ring_views(part, views, DISTANCE_MM)
    windows = view_windows(sensor, ring, _hull_points(part.vertices))
    return Scene(name, part, ring, windows, sensor)


# ------------------------------------------------------------------------ the C++ ceiling


def build_ceiling() -> Path | str:
    """The compiled bench/ceiling.cpp (cached by source hash), or why it cannot be built."""
    src = Path(__file__).with_name("ceiling.cpp")
    include = [
        p
        for p in (
            "/usr/include/embree4",
            "/usr/local/include/embree4",
            "/usr/include/embree3",
            "/usr/local/include/embree3",
        )
        if Path(p).is_dir()
    ]
    if not include or not shutil.which("g++"):
        return "no Embree headers or no g++ (Debian: apt install g++ libembree-dev)"
    lib = "embree4" if "embree4" in include[0] else "embree3"
    digest = hashlib.sha256(src.read_bytes() + lib.encode()).hexdigest()[:12]
    exe = Path(tempfile.gettempdir()) / f"vpp-ceiling-{digest}"
    if not exe.is_file():
        cmd = [
            "g++",
            "-O3",
            "-march=native",
            "-std=c++17",
            "-o",
            str(exe),
            str(src),
            f"-l{lib}",
            "-lpthread",
        ]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode:
            return f"g++ failed: {done.stderr.strip()[:300]}"
    return exe


def write_scene(scene: Scene, threads: int, repeat: int, path: Path) -> None:
    """The ceiling's input file (layout in bench/ceiling.cpp)."""
    s, part = scene.sensor, scene.part
    with open(path, "wb") as fh:
        fh.write(
            struct.pack(
                "<7if",
                len(part.vertices),
                part.n_faces,
                len(scene.views),
                threads,
                repeat,
                s.width_px,
                s.height_px,
                s.far_mm,
            )
        )
        fh.write(part.vertices.astype("<f4").tobytes() + part.faces.astype("<i4").tobytes())
        fh.write(s.pixel_x.astype("<f4").tobytes() + s.pixel_y.astype("<f4").tobytes())
        rot = scene.views.rotations()
        for j, w in enumerate(scene.windows):
            fh.write(scene.views.positions[j].astype("<f4").tobytes())
            fh.write(rot[j].astype("<f4").tobytes() + np.array(w, "<i4").tobytes())


def run_ceiling(
    exe: Path, scene: Scene, threads: int, repeat: int, min_time: float = 0.0
) -> dict[str, Any]:
    """Run the ceiling on the scene: {"wall_s", "rays", "hits", "embree"}, the fastest of at
    least `repeat` runs and, on fast scenes, of as many as fit in `min_time` s (as `timed`)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "scene.bin"

        def fastest_of(runs: int) -> dict[str, Any]:
            write_scene(scene, threads, runs + 1, path)  # its first run is the warm-up
            done = subprocess.run([str(exe), str(path)], capture_output=True, text=True, check=True)
            return dict(json.loads(done.stdout))

        out = fastest_of(repeat)
        if out["wall_s"] * repeat < min_time:  # a fast scene: as many runs as fit in min_time
            more = fastest_of(math.ceil(min_time / max(out["wall_s"], 1e-6)))
            out = min(out, more, key=lambda o: float(o["wall_s"]))
    return out


# ------------------------------------------------------------------------ bare embreex and backends


def run_bare(
    embree: EmbreeBackend, blocks: list[tuple[np.ndarray, np.ndarray]], far: float, threads: int
) -> None:
    """First hits of every block's rays through embreex over a T-thread pool (results dropped)."""
    scene = embree._scene

    def work(item: tuple[np.ndarray, np.ndarray]) -> None:
        origins, directions = item
        scene.run(origins, directions, dists=far, output=1)

    with ThreadPoolExecutor(threads) as pool:
        for _ in pool.map(work, blocks):
            pass


def bare_rays(scene: Scene) -> list[tuple[np.ndarray, np.ndarray]]:
    """(origins, directions) float32 of every block, made before any clock starts."""
    out = []
    for block in scene.blocks():
        d = block_directions(block)
        out.append((np.broadcast_to(block.position.astype(np.float32), d.shape), d))
    return out


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


def timed(fn: Callable[[], Any], repeat: int, min_time: float) -> tuple[Timing, Any]:
    """Fastest of at least `repeat` calls of fn, and of as many more as fit in `min_time` s in
    all, with this and other processes' average core use during it (a noisy machine, or
    helper threads spinning, show here), and the last result."""
    best, result = Timing(), None
    start = time.perf_counter()
    for done in itertools.count():
        if done >= repeat and time.perf_counter() - start >= min_time:
            break
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


@dataclass
class Row:
    """One (scene, threads) line of the summary table: Mrays/s by method."""

    scene: str
    faces: int
    threads: int
    hit: float
    cast: float
    rates: dict[str, float] = field(default_factory=dict)
    walls: dict[str, float] = field(default_factory=dict)
    others: float = 0.0


def bench_scene(
    scene: Scene, args: argparse.Namespace, ceiling: Path | str, rows: list[Row]
) -> None:
    """Every method on one scene at each thread count; JSON lines out, table rows appended."""
    sensor, far = scene.sensor, scene.sensor.far_mm
    embree = EmbreeBackend(scene.part)
    embree._scene.run(np.zeros((1, 3), np.float32), np.ones((1, 3), np.float32))  # BVH build
    backends = {name: make_backend(scene.part, name) for name in args.backends}
    rays = bare_rays(scene)
    hits = sum(int((embree.first_hits(o[:1][0], d, far)[0] >= 0).sum()) for o, d in rays)
    emit(
        {
            "kind": "scene",
            "scene": scene.name,
            "faces": scene.part.n_faces,
            "views": len(scene.views),
            "pixels": scene.pixels,
            "rays": scene.rays,
            "cast_fraction": round(scene.rays / scene.pixels, 4),
            "hit_fraction": round(hits / scene.pixels, 4),
        }
    )
    first = scene.views.take(np.array([0]))
    for threads in args.threads:
        row = Row(
            scene.name, scene.part.n_faces, threads, hits / scene.pixels, scene.rays / scene.pixels
        )
        rows.append(row)
        methods: dict[str, Callable[[], Any]] = {}
        if isinstance(ceiling, Path):
            methods["ceiling"] = lambda: None  # timed inside the harness
        methods["bare"] = lambda t=threads: run_bare(embree, rays, far, t)
        for name, backend in backends.items():
            methods[name] = lambda b=backend, t=threads: trace_counts(
                scene.part, sensor, scene.views, backend=b, threads=t
            )
        for method, fn in methods.items():
            wait_idle(args.wait_idle)
            if method == "ceiling":
                assert isinstance(ceiling, Path)
                out = run_ceiling(ceiling, scene, threads, args.repeat, args.min_time)
                tm = Timing(out["wall_s"])  # another process: no core accounting
                extra: dict[str, Any] = {"embree_major": out["embree"], "hits": out["hits"]}
            else:
                if method in backends:
                    trace_counts(
                        scene.part, sensor, first, backend=backends[method], threads=threads
                    )
                else:
                    run_bare(embree, rays[:1], far, threads)
                tm, result = timed(fn, args.repeat, args.min_time)
                extra = {"valid_rays": int(result.counts.sum())} if method in backends else {}
            rate = scene.rays / tm.wall / 1e6
            row.rates[method], row.walls[method] = rate, tm.wall
            row.others = max(row.others, tm.others_cores or 0.0)
            emit(
                {
                    "kind": "measure",
                    "scene": scene.name,
                    "faces": scene.part.n_faces,
                    "threads": threads,
                    "method": method,
                    "rays": scene.rays,
                    "wall_s": round(tm.wall, 4),
                    "mrays_s": round(rate, 2),
                    "mpx_s": round(scene.pixels / tm.wall / 1e6, 2),
                    "own_cores": rnd(tm.own_cores),
                    "others_cores": rnd(tm.others_cores),
                    **extra,
                }
            )


def measure_scene(
    spec: tuple[int, str] | Path, args: argparse.Namespace, ceiling: Path | str
) -> list[Row]:
    """bench_scene on a sphere (faces, size) or a mesh file: the table rows."""
    fix_malloc()
    sensor = Sensor()
    if isinstance(spec, Path):
        part = load_mesh(spec.read_bytes(), spec.suffix, mesh_units(spec))
        name = spec.name
    else:
        t0 = time.perf_counter()
        label, part = sphere(spec[0], SIZES_MM[spec[1]])
        print(
            f"built {label}: {part.n_faces} faces in {time.perf_counter() - t0:.1f} s",
            file=sys.stderr,
        )
        name = f"{spec[1]} {part.n_faces // 1000}k"
    rows: list[Row] = []
    bench_scene(make_scene(name, part, args.views, sensor), args, ceiling, rows)
    return rows


def rnd(x: float | None, digits: int = 2) -> float | None:
    """x rounded, None kept."""
    return None if x is None else round(x, digits)


def print_table(rows: list[Row], backends: list[str]) -> None:
    """Human-readable summary on stderr."""
    methods = ["ceiling", "bare", *backends]
    head = (
        f"{'scene':<22} {'faces':>8} {'T':>2} {'hit%':>5} {'cast%':>5} "
        + " ".join(f"{m:>8}" for m in methods)
        + " "
        + " ".join(f"{b + '/ceil':>11} {b + '/bare':>11}" for b in backends)
        + f" {'others':>6}"
    )
    out = [
        "",
        "Mrays/s over the same rays (one per pixel of each view's culled window)",
        head,
        "-" * len(head),
    ]
    for r in rows:
        cells = " ".join(f"{r.rates[m]:>8.1f}" if m in r.rates else f"{'-':>8}" for m in methods)
        ratios = " ".join(
            (f"{r.rates[b] / r.rates['ceiling']:>11.2f}" if "ceiling" in r.rates else f"{'-':>11}")
            + f" {r.rates[b] / r.rates['bare']:>11.2f}"
            for b in backends
        )
        out.append(
            f"{r.scene[:22]:<22} {r.faces:>8} {r.threads:>2} {100 * r.hit:>5.1f} "
            f"{100 * r.cast:>5.1f} {cells} {ratios} {r.others:>6.2f}"
        )
    print("\n".join(out), file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    """Command-line entry point."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument(
        "--faces", default="10000,100000,1000000", help="sphere face counts (empty: none)"
    )
    ap.add_argument("--sizes", default="large,small", help=f"sphere sizes: {', '.join(SIZES_MM)}")
    ap.add_argument("--meshes", nargs="*", type=Path, default=[], help="mesh files to add")
    ap.add_argument("--views", type=int, default=8, help="cameras per scene")
    ap.add_argument("--threads", default="1,2", help="comma-separated thread counts")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per measurement (fastest)")
    ap.add_argument(
        "--min-time",
        type=float,
        default=1.0,
        metavar="S",
        help="and more timed runs, as many as fit in S s per measurement (fast scenes)",
    )
    ap.add_argument("--backends", default=",".join(BACKENDS), help="project backends to time")
    ap.add_argument("--no-ceiling", action="store_true", help="skip the C++ ceiling")
    ap.add_argument(
        "--wait-idle",
        type=float,
        default=0.0,
        metavar="S",
        help="before each measurement wait up to S s for other processes to go idle",
    )
    args = ap.parse_args(argv)
    args.threads = [int(t) for t in args.threads.split(",") if t.strip()]
    args.backends = [b for b in args.backends.split(",") if b.strip()]
    malloc_fixed = fix_malloc()
    sensor = Sensor()
    ceiling: Path | str = "skipped (--no-ceiling)" if args.no_ceiling else build_ceiling()
    if not isinstance(ceiling, Path):
        print(f"ceiling: {ceiling}", file=sys.stderr)
    emit(
        {
            "kind": "setup",
            "sensor": [sensor.width_px, sensor.height_px],
            "threads": args.threads,
            "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "ceiling": str(ceiling),
            "malloc_fixed": malloc_fixed,
            "packets_embree": f"{packets_library().major} ({packets_library().path})",
            "numpy": np.__version__,
        }
    )
    specs: list[tuple[int, str] | Path] = [
        (int(f), size)
        for f in args.faces.split(",")
        if f.strip()
        for size in args.sizes.split(",")
        if size.strip()
    ]
    for path in args.meshes:
        if path.is_file():
            specs.append(path)
        else:
            print(f"skipping {path}: not found", file=sys.stderr)
    rows: list[Row] = []
    spawn = multiprocessing.get_context("spawn")
    for spec in specs:  # each scene in a fresh process, as the ceiling's harness runs
        with ProcessPoolExecutor(1, mp_context=spawn) as child:
            rows += child.submit(measure_scene, spec, args, ceiling).result()
    if rows:
        print_table(rows, args.backends)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
