"""Experiment (issue 10): do surface-sampled rows and geometric candidates make counts
tessellation-invariant? Not a product path; the results are in docs/cad-meshes.md.

    python bench/surfacerows.py MESH UNITS EDGE_MM [--rows random|grid] [--samples 20000]
                                [--candidates default|grid|grid-cells] [--shared]
                                [--seed 0] [--time-limit 30] [--fractions 1,0.999,0.99]

Rows are surface points instead of faces, each weighted by the area it stands for:
- `random`: area-weighted random points (`--samples` of them, weight A / K);
- `grid`: every hit of three axis-parallel grids of rays (all layers), on a spacing snapped
  to powers of 2^(1/4) and anchored to the world origin, so that the same geometry gives the
  same points whatever its tessellation; weight g² / (|n_x| + |n_y| + |n_z|), unbiased.
A point is seen by a view when it projects inside the image, its depth lies in the depth of
field, the incidence is within the limit and the ray from the camera reaches it first
(face id, or depth within 1e-5). Its density from that view is analytic: rays per mm² =
fx·fy·cos θ / (z² cos φ), δ = sqrt of that; then S and V as in SPEC §3.

Candidates: `default` (the product's generator), or targets taken from the grid points in
a geometric order (a hash of ray index and layer), thinned greedily (`grid`) or one per cell
of a spacing-sized voxel grid (`grid-cells`), then placed as the product places them.
--shared: the CAD mesh's candidates are used on the remesh too. --seed picks the candidates;
the rows always use seed 0.
One JSON line per (tessellation, formulation, fraction).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from cadmeshes import load_pair, pair_parser  # noqa: E402

from vpp_core.camera.pose import Viewpoints, make_viewpoints  # noqa: E402
from vpp_core.camera.sensor import Sensor  # noqa: E402
from vpp_core.candidates.generator import _thin, place, smoothed_normals  # noqa: E402
from vpp_core.cover.partial import solve_partial  # noqa: E402
from vpp_core.mesh.part import Part  # noqa: E402
from vpp_core.plan.document import CandidateGenerator, PlanRequest  # noqa: E402
from vpp_core.plan.pipeline import candidates_for  # noqa: E402
from vpp_core.trace.embree import EmbreeBackend  # noqa: E402

Points = tuple[np.ndarray, np.ndarray, np.ndarray]  # (k, 3) mm, (k,) face ids, (k,) mm²


def random_points(part: Part, k: int, seed: int) -> Points:
    """k area-weighted random points on the counted faces, each standing for A / k."""
    rng = np.random.default_rng(seed)
    w = np.where(part.counted, part.areas, 0.0)
    faces = rng.choice(len(w), size=k, p=w / w.sum())
    r = rng.random((k, 2))
    r[r.sum(1) > 1] = 1 - r[r.sum(1) > 1]
    tri = part.vertices[part.faces[faces]]
    pts = tri[:, 0] + r[:, :1] * (tri[:, 1] - tri[:, 0]) + r[:, 1:] * (tri[:, 2] - tri[:, 0])
    return pts, faces, np.full(k, w.sum() / k)


def _mix(x: np.ndarray) -> np.ndarray:
    """splitmix64 finaliser: a geometric, seed-free pseudo-random order key."""
    x = x.astype(np.uint64)
    with np.errstate(over="ignore"):
        x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def grid_points(part: Part, emb: EmbreeBackend, k: int, seed: int) -> Points:
    """About k points: all hits of three axis grids of rays, in a geometric order."""
    g = float(np.sqrt(1.5 * part.areas[part.counted].sum() / k))
    g = 2.0 ** (np.floor(4 * np.log2(g)) / 4)
    lo, hi = part.bounds[0] - g, part.bounds[1] + g
    off = np.random.default_rng(seed).random((3, 2)) * g
    pts, faces, keys = [], [], []
    for a in range(3):
        b, c = [i for i in range(3) if i != a]
        kb = np.arange(np.floor((lo[b] - off[a, 0]) / g), np.ceil((hi[b] - off[a, 0]) / g) + 1)
        kc = np.arange(np.floor((lo[c] - off[a, 1]) / g), np.ceil((hi[c] - off[a, 1]) / g) + 1)
        KB, KC = (m.ravel().astype(np.int64) for m in np.meshgrid(kb, kc, indexing="ij"))
        o = np.zeros((KB.size, 3))
        o[:, b], o[:, c], o[:, a] = KB * g + off[a, 0], KC * g + off[a, 1], lo[a]
        ray = (KB * 1_000_003 + KC) * 4 + a
        d = np.zeros((1, 3), np.float32)
        d[0, a] = 1
        span = hi[a] - lo[a]
        for layer in range(64):
            prim, t = emb.first_hits(o, np.repeat(d, len(o), axis=0), span)
            hit = prim >= 0
            if not hit.any():
                break
            o, ray = o[hit], ray[hit]
            o[:, a] += t[hit]
            pts.append(o.copy())
            faces.append(prim[hit].astype(np.int64))
            keys.append(_mix(ray * 131 + layer + seed * 7919))
            o[:, a] += 1e-5 * span
    order = np.argsort(np.concatenate(keys), kind="stable")
    p, f = np.concatenate(pts)[order], np.concatenate(faces)[order]
    keep = part.counted[f]
    p, f = p[keep], f[keep]
    return p, f, g * g / np.abs(part.normals[f]).sum(1)


def grid_candidates(
    part: Part, sensor: Sensor, emb: EmbreeBackend, count: int, seed: int, cells: bool
) -> Viewpoints:
    """The product's placement, on targets thinned from grid points (greedy or per cell)."""
    pts, faces, _ = grid_points(part, emb, 8 * count, seed)
    spacing = float(np.sqrt(part.areas[part.counted].sum() / count))
    spacing = 2.0 ** (np.floor(8 * np.log2(spacing)) / 8)
    for _ in range(60):
        if cells:
            _, first = np.unique(
                np.floor(pts / spacing).astype(np.int64), axis=0, return_index=True
            )
            keep = np.sort(first)
        else:
            keep = _thin(pts, spacing)
        if len(keep) >= count:
            break
        spacing *= 2 ** (-1 / 8)
    keep = keep[:count]
    normals = smoothed_normals(part.trimesh(), pts[keep], faces[keep], spacing / 2)
    pos, gaze = place(part, emb, pts[keep], [normals], sensor.working_distance, 20.0)
    ok = np.isfinite(pos).all(1)
    return make_viewpoints(pos[ok], gaze[ok])


def point_views(
    part: Part, sensor: Sensor, views: Viewpoints, points: Points, emb: EmbreeBackend
) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Per view j: (j, ids of the points it sees, δ = sqrt(rays/mm²) there). A point is seen
    when it projects inside the image, its depth lies in the depth of field, the incidence is
    within the limit and the ray from the camera reaches it first (face id or depth)."""
    pts, faces, _ = points
    normals, rot = part.normals[faces], views.rotations()
    cos_max = np.cos(np.radians(sensor.max_incidence_deg))
    for j in range(len(views)):
        d = pts - views.positions[j]
        x, y, z = (d @ rot[j]).T
        dist = np.linalg.norm(d, axis=1)
        cos_t = np.abs((normals * d).sum(1)) / dist
        with np.errstate(divide="ignore", invalid="ignore"):
            u = sensor.fx * x / z + sensor.width_px / 2
            w = sensor.fy * y / z + sensor.height_px / 2
            ok = (z >= sensor.near_mm) & (z <= sensor.far_mm) & (cos_t >= cos_max)
            ok &= (u >= 0) & (u < sensor.width_px) & (w >= 0) & (w < sensor.height_px)
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            continue
        dirs = (d[idx] / dist[idx, None]).astype(np.float32)
        prim, t = emb.first_hits(views.positions[j], dirs, float(dist[idx].max() * 1.001))
        idx = idx[(prim == faces[idx]) | (np.abs(t - dist[idx]) <= 1e-5 * dist[idx] + 1e-4)]
        yield j, idx, np.sqrt(sensor.fx * sensor.fy * cos_t[idx] * dist[idx] / z[idx] ** 3)


def point_densities(
    part: Part, sensor: Sensor, views: Viewpoints, points: Points, emb: EmbreeBackend
) -> sp.csr_array:
    """δ: (k, N) csr, sqrt(rays/mm²) of each view at each point it sees (0 = not seen)."""
    r, c, v = [np.zeros(0, int)], [np.zeros(0, int)], [np.zeros(0)]
    for j, idx, delta in point_views(part, sensor, views, points, emb):
        r.append(idx)
        c.append(np.full(len(idx), j))
        v.append(delta)
    shape = (len(points[0]), len(views))
    return sp.csr_array((np.concatenate(v), (np.concatenate(r), np.concatenate(c))), shape=shape)


def models(delta: sp.csr_array, resolution_mm: float) -> dict[str, sp.csr_array]:
    """V and S (SPEC §3) over the points some view sees."""
    seen = np.diff(delta.indptr) > 0
    d = sp.csr_array(delta[seen])
    vis = d.copy()
    vis.data[:] = 1.0
    dense = np.asarray(d.sum(axis=1)).ravel() >= 1 / resolution_mm
    s = d * resolution_mm
    s.data = np.minimum(s.data, 1.0)
    s = sp.csr_array(sp.diags_array(dense * 1.0) @ s) + sp.csr_array(
        sp.diags_array(~dense * 1.0) @ vis
    )
    return {"visibility": vis, "density": s, "seen": seen}  # type: ignore[dict-item]


def run(part: Part, label: str, views: Viewpoints, args: argparse.Namespace) -> None:
    """Rows from `part`'s points, then one JSON line per formulation and fraction."""
    sensor, emb = Sensor(), EmbreeBackend(part)
    t0 = time.perf_counter()
    if args.rows == "grid":
        points = grid_points(part, emb, args.samples, 0)
    else:
        points = random_points(part, args.samples, 0)
    m = models(point_densities(part, sensor, views, points, emb), 0.18)
    weights = points[2][m["seen"]]
    rows_s = time.perf_counter() - t0
    for formulation in ("visibility", "density"):
        for f in args.fractions:
            t1 = time.perf_counter()
            pc = solve_partial(m[formulation], weights, f, time_limit=args.time_limit)
            line = dict(
                tessellation=label, faces=part.n_faces, points=len(points[0]),
                candidates=len(views), formulation=formulation, min_coverage=f,
                views=len(pc.result.selected), status=pc.result.status, bound=pc.result.bound,
                rows_s=round(rows_s, 2), solve_s=round(time.perf_counter() - t1, 2),
            )  # fmt: skip
            print(json.dumps(line), flush=True)


def candidates(part: Part, args: argparse.Namespace) -> Viewpoints:
    """The candidates the experiment asks for, on `part`."""
    if args.candidates == "default":
        request = PlanRequest(candidates=CandidateGenerator(count=500, seed=args.seed))
        return candidates_for(part, request, EmbreeBackend(part))[0]
    cells = args.candidates == "grid-cells"
    return grid_candidates(part, Sensor(), EmbreeBackend(part), 500, args.seed, cells)


def main() -> None:
    parser = pair_parser(__doc__)
    parser.add_argument("--rows", choices=["random", "grid"], default="grid")
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--candidates", choices=["default", "grid", "grid-cells"], default="grid")
    parser.add_argument("--shared", action="store_true")
    args = parser.parse_args()
    cad, iso, label = load_pair(args)
    cad_views = candidates(cad, args)
    run(cad, "cad", cad_views, args)
    run(iso, label, cad_views if args.shared else candidates(iso, args), args)


if __name__ == "__main__":
    main()
