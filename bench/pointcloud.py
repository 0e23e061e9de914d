"""Simulated point cloud at the paper's sensor: wall time, points/s and peak memory.

    python bench/pointcloud.py [MESH] [--units mm] [--views 10] [--threads N]

Default: the shared tray (a 356 mm plate, filling most of the frame at 500 mm), seen by
`--views` cameras on a cone of 20° around its normal: about 2 M points per view.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

from vpp_core.camera.pose import make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.mesh.part import load_mesh
from vpp_core.report.pointcloud import cloud_stats, hit_points, neighbour_counts
from vpp_core.trace.raytrace import make_backend

TRAY = Path("../shared/meshes/1002_tray_bottom.STL")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mesh", nargs="?", type=Path, default=TRAY)
    ap.add_argument("--units", default="mm")
    ap.add_argument("--views", type=int, default=10)
    ap.add_argument("--threads", type=int, default=-1)
    ap.add_argument("--radius", type=float, default=0.18)
    args = ap.parse_args()
    if not args.mesh.exists():
        sys.exit(f"pointcloud bench: {args.mesh} not found (the shared meshes)")
    part = load_mesh(args.mesh.read_bytes(), args.mesh.suffix.lstrip("."), args.units)
    centre = part.vertices.mean(axis=0)
    normal = np.linalg.svd(part.vertices - centre)[2][2]  # least-variance axis of the part
    a = np.radians(20)
    ring = np.linspace(0, 2 * np.pi, args.views, endpoint=False)
    side = np.linalg.svd(np.eye(3) - np.outer(normal, normal))[0][:, :2]
    dirs = np.cos(a) * normal + np.sin(a) * (
        np.cos(ring)[:, None] * side[:, 0] + np.sin(ring)[:, None] * side[:, 1]
    )
    views = make_viewpoints(centre + 500 * dirs, -dirs)
    backend = make_backend(part)
    t0 = time.perf_counter()
    cloud = hit_points(part, Sensor(), views, backend, max_points=10**9)
    t1 = time.perf_counter()
    counts, nearest = neighbour_counts(cloud.points, args.radius, args.threads)
    t2 = time.perf_counter()
    stats = cloud_stats(cloud, counts, nearest, args.radius)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    n = stats.points
    print(f"{args.mesh.name}: {part.n_faces} faces, {args.views} views, {n:,} points")
    print(f"  hit points      {t1 - t0:6.2f} s  ({n / (t1 - t0) / 1e6:.1f} M points/s)")
    print(f"  neighbour count {t2 - t1:6.2f} s  ({n / (t2 - t1) / 1e6:.2f} M points/s)")
    print(f"  total           {t2 - t0:6.2f} s, peak RSS {peak:,.0f} MiB")
    print(
        f"  neighbours within {args.radius} mm: mean {stats.neighbours_mean:.2f}, "
        f"median {stats.neighbours_median:g}; mean spacing {stats.spacing_mean_mm:.4f} mm"
    )


if __name__ == "__main__":
    main()
