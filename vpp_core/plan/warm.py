"""Compile the ray tracers' numba kernels before they are needed, and say so while it takes.

numba compiles a kernel at its first call and caches the machine code on disk (`cache=True`,
vpp_core.jit): on a fresh install the first plan's trace sat at "trace 0/N" for half a minute
while the rasteriser compiled. `warm` traces a tetrahedron with one small view through every
kernel a plan's trace uses (the backend's own, Embree packets for dense views, arbitrary rays for
candidate checks), groups its faces into patches (the default rows' two kernels) and has the
final cover's local search compiled (vpp_core.cover.rowweight): from the cache that is a
fraction of a second; otherwise it compiles them (20 s on a 2-core EPYC, docs/raytrace.md),
and when that takes longer than `NOTICE_S` it reports the stage `compiling` to the progress
callback (`compiling 0/1` as it starts, `1/1` once done); once per process and backend.
A plan does not count this stage in its time limit (vpp_core.plan.pipeline.spent_s), so a
fresh install's first plan is the plan a warm one makes, later by the compile.
`python -m vpp_core.plan.warm` fills the cache (the Docker image runs it at build time;
`vpp serve` and `vpp worker` run it in the background as they start, without delaying
readiness).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Callable
from typing import get_args

import numpy as np

from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cover import rowweight
from vpp_core.cover.patches import make_patches
from vpp_core.mesh.part import Part, part_from_arrays
from vpp_core.trace.raster import RasterBackend
from vpp_core.trace.rays import DEFAULT_BACKEND, BackendName
from vpp_core.trace.raytrace import make_backend, trace_counts

NOTICE_S = 2.0
"""Warming that takes longer than this (s) is compiling, not reading the cache: report it."""
STAGE = "compiling"
Progress = Callable[[str, int, int], None]
_warmed: set[str] = set()
"""Backends whose kernels this process has run (warm returns at once for them)."""


def tetrahedron() -> Part:
    """A regular-ish tetrahedron, 100 mm across, centred on the origin."""
    vertices = np.array([[50, 50, 50], [-50, -50, 50], [-50, 50, -50], [50, -50, -50]], float)
    faces = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    return part_from_arrays(vertices, faces)


def trace_tiny(backend: str | None = None) -> None:
    """Trace the tetrahedron once through every kernel a plan with `backend` uses."""
    part = tetrahedron()
    sensor = Sensor(width_px=32, height_px=24)
    views = make_viewpoints(np.array([[0.0, 0.0, -500.0]]), np.array([[0.0, 0.0, 1.0]]))
    traced = make_backend(part, backend)
    trace_counts(part, sensor, views, backend=traced, threads=1)
    if isinstance(traced, RasterBackend):  # its dense views go to Embree packets
        dense = RasterBackend(part, max_faces_per_pixel=0.0)
        trace_counts(part, sensor, views, backend=dense, threads=1)
    traced.first_hits(np.zeros(3), np.array([[0.0, 0.0, 1.0]], np.float32), 1e3)


def group_tiny() -> None:
    """Group the tetrahedron's faces into patches once: the normal smoothing's and the seeds'
    kernels (vpp_core.cover.patches), which every plan's default rows use."""
    part = tetrahedron()
    centres = part.vertices[part.faces].mean(axis=1)
    make_patches(centres, part.normals, part.areas, part.counted, 50.0, corners=part.faces)


_log = logging.getLogger(__name__)


def warm(backend: str | None = None, progress: Progress | None = None) -> float:
    """Have the kernels of `backend` (default: the default backend) and the set cover's local
    search compiled or loaded, telling
    `progress` about it when it takes longer than NOTICE_S; the seconds it took. A failure (say
    a numba cache written by another process at that moment) is logged, not raised: the plan's
    own trace compiles what it needs."""
    name = backend or DEFAULT_BACKEND
    if name in _warmed or name not in get_args(BackendName):
        return 0.0  # done, or a backend of the caller's own (tests)
    start = time.perf_counter()
    failed: list[BaseException] = []

    def run() -> None:
        try:
            trace_tiny(name)
            group_tiny()
            rowweight.compiled(3600.0)  # the final cover's local search
        except BaseException as exc:  # raised in the caller's thread below
            failed.append(exc)

    worker = threading.Thread(target=run, name="vpp-warm", daemon=True)
    worker.start()
    worker.join(NOTICE_S)
    if worker.is_alive() and progress:
        progress(STAGE, 0, 1)
    worker.join()
    if failed:  # not the plan's failure: its own trace compiles (or fails) as it would have
        _log.warning("warming the %s kernels failed: %r", name, failed[0])
        return time.perf_counter() - start
    _warmed.add(name)
    if progress and time.perf_counter() - start > NOTICE_S:
        progress(STAGE, 1, 1)
    return time.perf_counter() - start


def main(argv: list[str] | None = None) -> int:
    """`python -m vpp_core.plan.warm [BACKEND...]`: fill numba's cache for the backends (default:
    the default one, whose kernels include the packets backend's) and the set cover's search."""
    names = (argv if argv is not None else sys.argv[1:]) or [DEFAULT_BACKEND]
    for name in names:
        if name not in get_args(BackendName):
            print(f"unknown backend {name!r}; available: {get_args(BackendName)}", file=sys.stderr)
            return 2
        print(f"vpp warm: {name} kernels ready in {warm(name):.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
