"""The rasterising backend against Embree: per-pixel first hits and R on every shared mesh."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest

from tests.conftest import MANIFEST_UNITS, MESHES, manifest_rows, plate_part, shared_dir
from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.generator import GeneratorSettings, generate
from vpp_core.mesh.part import Part, load_mesh, part_from_arrays
from vpp_core.plan.document import PlanRequest
from vpp_core.plan.pipeline import plan
from vpp_core.trace.embree import EmbreeBackend, block_directions
from vpp_core.trace.raster import RasterBackend, pixel_scale, view_first_hits
from vpp_core.trace.rays import Block
from vpp_core.trace.raytrace import _hull_points, make_backend, trace_counts, view_windows

PAPER = Sensor()


def central(sensor: Sensor, share: int = 2) -> Sensor:
    """The sensor's central 1/share × 1/share of the image: the same pixels (focal length in
    pixels) and optics, share² times fewer rays; the shared-mesh comparisons ray by ray use it
    on the paper camera's poses, so that they cost a quarter of the full images."""

    def narrower(fov_deg: float) -> float:
        return 2 * math.degrees(math.atan(math.tan(math.radians(fov_deg / 2)) / share))

    return sensor.model_copy(
        update={
            "width_px": sensor.width_px // share,
            "height_px": sensor.height_px // share,
            "fov_x_deg": narrower(sensor.fov_x_deg),
            "fov_y_deg": narrower(sensor.fov_y_deg),
        }
    )


CENTRE = central(PAPER)
"""The paper camera's central quarter."""
EDGE_PX = 1e-2
"""A disagreeing pixel must lie this close (pixels) to an edge of one of the two faces (Embree's
float32 puts edges ~1e-7 x |world coordinates| off: 2e-3 px on the exhaust manifold)..."""
TIE_REL = 1e-6
"""...or the two faces must lie at the same depth there to this relative precision (coplanar
overlapping faces: Embree's float32 cannot order them, ~1e-7, and either answer is right)."""


def raster_ids(part: Part, sensor: Sensor, views: Viewpoints, j: int, window) -> np.ndarray:
    """The rasteriser's first face per pixel of the window, flattened row-major."""
    ids, _ = view_first_hits(
        part.vertices.astype(np.float64),
        part.faces.astype(np.int32),
        np.arange(part.n_faces, dtype=np.int32),
        views.positions[j].astype(np.float64),
        views.rotations()[j],
        sensor.pixel_x,
        sensor.pixel_y,
        pixel_scale(sensor),
        np.array(window, dtype=np.int64),
        sensor.far_mm,
    )
    return ids.reshape(-1)


def embree_ids(embree: EmbreeBackend, sensor: Sensor, views: Viewpoints, j: int, window):
    """Embree's first face per pixel ray of the window (the rays the trace casts), flattened."""
    v0, v1, u0, u1 = window
    block = Block(sensor, views.positions[j], views.rotations()[j], (v0, v1), (u0, u1))
    prim, _ = embree.first_hits(views.positions[j], block_directions(block), sensor.far_mm)
    return prim


def face_in_camera(part: Part, views: Viewpoints, j: int, face: int) -> np.ndarray:
    """(3, 3) float64 camera-frame corners of `face` seen from view j."""
    return np.asarray((part.vertices[part.faces[face]] - views.positions[j]) @ views.rotations()[j])


def pixel_ray(sensor: Sensor, uv) -> np.ndarray:
    """(3,) camera-frame direction (x, y, 1) through pixel centre uv (pinhole, SPEC §8)."""
    return np.array(
        [
            (uv[0] - sensor.width_px / 2 + 0.5) / sensor.fx,
            (uv[1] - sensor.height_px / 2 + 0.5) / sensor.fy,
            1.0,
        ]
    )


def edge_distance_px(part: Part, sensor: Sensor, views: Viewpoints, j: int, face: int, uv) -> float:
    """Distance in pixels from pixel centre uv to the nearest edge of `face`'s projection;
    for a face crossing the camera plane, to the nearest of its edges' lines (a lower bound)."""
    if face < 0:
        return math.inf
    cam = face_in_camera(part, views, j, face)
    if (cam[:, 2] <= 0).any():
        ray = pixel_ray(sensor, uv)
        ray /= np.linalg.norm(ray)
        sines = [
            abs(np.cross(cam[e], cam[(e + 1) % 3]) @ ray)
            / max(np.linalg.norm(np.cross(cam[e], cam[(e + 1) % 3])), 1e-300)
            for e in range(3)
        ]
        return float(min(sines)) * sensor.fx  # radians off the edge's plane, in pixels
    p = np.c_[cam[:, 0] / cam[:, 2] * sensor.fx, cam[:, 1] / cam[:, 2] * sensor.fy]
    p += [sensor.width_px / 2 - 0.5, sensor.height_px / 2 - 0.5]
    best = math.inf
    for a, b in ((p[0], p[1]), (p[1], p[2]), (p[2], p[0])):
        t = np.clip(np.dot(uv - a, b - a) / max(np.dot(b - a, b - a), 1e-300), 0.0, 1.0)
        best = min(best, float(np.linalg.norm(a + t * (b - a) - uv)))
    return best


def ray_depth(part: Part, sensor: Sensor, views: Viewpoints, j: int, face: int, uv) -> float:
    """Depth (mm) at which the ray through pixel centre uv meets `face`'s plane."""
    if face < 0:
        return math.inf
    cam = face_in_camera(part, views, j, face)
    normal = np.cross(cam[1] - cam[0], cam[2] - cam[0])
    return float(normal @ cam[0] / (normal @ pixel_ray(sensor, uv)))


def unexplained(part: Part, sensor: Sensor, views: Viewpoints, j: int, pair, uv) -> float:
    """0 when a disagreement is a tie (equal depths), else its distance to an edge in px."""
    za, zb = (ray_depth(part, sensor, views, j, int(f), uv) for f in pair)
    if abs(za - zb) <= TIE_REL * min(za, zb):
        return 0.0
    return min(edge_distance_px(part, sensor, views, j, int(f), uv) for f in pair)


IdsOf = Callable[[int, tuple[int, int, int, int]], np.ndarray]
"""A backend's first face per pixel of view j's window, flattened row-major."""


def reference_ids(part: Part, sensor: Sensor, views: Viewpoints) -> list[np.ndarray]:
    """Embree's first face per pixel ray of each view's window (`embree_ids`), in view order."""
    embree = EmbreeBackend(part)
    windows = view_windows(sensor, views, _hull_points(part.vertices))
    return [embree_ids(embree, sensor, views, j, window) for j, window in enumerate(windows)]


def compare_views(
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    ids_of: IdsOf,
    reference: list[np.ndarray] | None = None,
) -> tuple[int, int, np.ndarray, float]:
    """ids_of against Embree rays (`reference`: `reference_ids` of the same views, computed
    here when not given): (hit pixels, disagreeing pixels, (M, N) of those per face and view
    (either side), largest distance to an edge of a disagreement that is not a depth tie, px)."""
    if reference is None:
        reference = reference_ids(part, sensor, views)
    hull = _hull_points(part.vertices)
    hits, bad, worst = 0, 0, 0.0
    touched = np.zeros((part.n_faces + 1, len(views)), dtype=np.int64)  # last row: misses
    for j, window in enumerate(view_windows(sensor, views, hull)):
        a = ids_of(j, window)
        b = reference[j]
        rep = np.append(part.representative, -1)  # duplicates of a face count as that face
        differ = np.flatnonzero(rep[a] != rep[b])
        hits += int(((a >= 0) | (b >= 0)).sum())
        bad += len(differ)
        np.add.at(touched[:, j], rep[a[differ]], 1)
        np.add.at(touched[:, j], rep[b[differ]], 1)
        width = window[3] - window[2]
        for k in differ:
            uv = np.array([window[2] + k % width, window[0] + k // width], dtype=float)
            worst = max(worst, unexplained(part, sensor, views, j, (a[k], b[k]), uv))
    return hits, bad, touched[:-1], worst


SHARED = [(r["file"], MANIFEST_UNITS[r["units_guess"]]) for r in manifest_rows()]


@pytest.mark.parametrize("name, units", SHARED or [("absent", "mm")])
def test_raster_agrees_with_embree_on_shared_meshes(name: str, units: str) -> None:
    path = shared_dir(MESHES) / name
    part = load_mesh(path.read_bytes(), path.suffix, units)
    views = generate(part, PAPER, GeneratorSettings(count=20, seed=0)).views
    hits, bad, touched, worst = compare_views(
        part, CENTRE, views, lambda j, window: raster_ids(part, CENTRE, views, j, window)
    )
    assert hits > 0
    assert bad <= 1e-3 * hits, f"{bad} of {hits} hit pixels differ"
    assert worst < EDGE_PX, f"a disagreement {worst:.2g} px from any edge, and no depth tie"
    rasteriser = RasterBackend(part, max_faces_per_pixel=math.inf)  # no view to packets
    r_raster = trace_counts(part, CENTRE, views, backend=rasteriser).counts
    r_embree = trace_counts(part, CENTRE, views, backend=make_backend(part, "embree")).counts
    a, b = r_raster.toarray().astype(np.int64), r_embree.toarray().astype(np.int64)
    # R within 0.1 %, but for the disagreeing pixels above, each of which moves one ray
    # between two faces (rays exactly at a validity threshold, float64 here and float32
    # there, would show here too)
    assert np.all(np.abs(a - b) <= 1e-3 * b + touched)


def fan(centre: tuple[float, float], radius: float, n: int, z: float) -> tuple:
    """(vertices, faces) of n triangles around `centre` at height z (a disc, normal +Z)."""
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.c_[centre[0] + radius * np.cos(ang), centre[1] + radius * np.sin(ang), np.full(n, z)]
    vertices = np.vstack([[centre[0], centre[1], z], ring])
    faces = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
    return vertices, faces


def test_shared_vertex_and_edges_on_pixel_centres_leave_no_hole() -> None:
    # a fan whose centre and spokes pass exactly through pixel centres: the top-left rule must
    # give every pixel centre of the disc to exactly one triangle (no hole, and the z-buffer
    # shows each pixel once); the ray through the axis hits the fan's shared vertex
    sensor = Sensor(width_px=64, height_px=64, fov_x_deg=60, fov_y_deg=60)
    depth = 500.0
    pitch = depth / sensor.fx
    cx = (0.5 - sensor.width_px / 2 + 32) * pitch  # pixel (32, 32) centre, at depth
    part = part_from_arrays(*fan((cx, cx), 10 * pitch, 8, 0.0))
    views = make_viewpoints(np.array([[0.0, 0.0, depth]]), np.array([[0.0, 0.0, -1.0]]))
    window = (0, sensor.height_px, 0, sensor.width_px)
    ids = raster_ids(part, sensor, views, 0, window).reshape(sensor.height_px, sensor.width_px)
    embree = embree_ids(EmbreeBackend(part), sensor, views, 0, window).reshape(ids.shape)
    assert (ids >= 0).sum() == (embree >= 0).sum() > 250
    assert ids[np.where(embree >= 0)].min() >= 0


def test_triangles_crossing_the_camera_plane_are_clipped() -> None:
    # a floor much larger than the view, camera 50 mm above it looking obliquely down: floor
    # triangles reach behind the camera, which only clipping draws correctly
    v = np.array([[-5000, -5000, 0], [5000, -5000, 0], [5000, 5000, 0], [-5000, 5000, 0.0]])
    part = part_from_arrays(v, np.array([[0, 1, 2], [0, 2, 3]]))
    gaze = np.array([[0.0, 0.6, -0.8]])
    views = make_viewpoints(np.array([[0.0, 0.0, 50.0]]), gaze)
    sensor = Sensor(width_px=160, height_px=100, far_mm=100000.0, near_mm=1.0)
    window = (0, sensor.height_px, 0, sensor.width_px)
    a = raster_ids(part, sensor, views, 0, window)
    b = embree_ids(EmbreeBackend(part), sensor, views, 0, window)
    assert (a >= 0).sum() > 0.3 * a.size
    assert (a >= 0).sum() == (b >= 0).sum()


@pytest.mark.parametrize("depth", [350.0, 500.0])
def test_backends_give_the_same_counts_on_a_plate(depth: float) -> None:
    part = plate_part(side=20.0, n=7)
    views = make_viewpoints(np.array([[1.3, -2.1, depth]]), np.array([[0.05, 0.02, -1.0]]))
    r = [
        trace_counts(part, PAPER, views, backend=make_backend(part, n)).counts
        for n in ("raster", "packets", "embree")
    ]
    assert r[0].sum() > 1000
    assert np.abs(r[0].toarray() - r[2].toarray()).max() <= 2
    assert np.abs(r[1].toarray() - r[2].toarray()).max() <= 2


def test_unknown_backend_is_refused() -> None:
    from vpp_core.errors import VppError

    with pytest.raises(
        VppError, match="unknown ray backend 'optix'; available: raster, packets, embree"
    ):
        make_backend(plate_part(), "optix")


def test_plans_from_every_backend_agree() -> None:
    path = shared_dir(MESHES) / "hirth_sample_small.stl"
    part = load_mesh(path.read_bytes(), "stl")
    docs = {
        name: plan(part, PlanRequest(profile="paper", candidates={"count": 80}, backend=name))
        for name in ("raster", "packets", "embree")
    }
    assert [d.rays.backend for d in docs.values()] == ["raster", "packets", "embree"]
    embree = docs["embree"]
    for doc in (docs["raster"], docs["packets"]):
        assert doc.viewpoints == embree.viewpoints
        assert doc.rays.cast == embree.rays.cast
        assert abs(doc.rays.valid - embree.rays.valid) <= 1e-4 * embree.rays.valid
        assert doc.metrics.coverage == embree.metrics.coverage
        assert doc.metrics.resolution.met_area == pytest.approx(
            embree.metrics.resolution.met_area, abs=1e-3
        )


def triangle_soup(rng: np.random.Generator) -> tuple[Part, Viewpoints]:
    """150 random triangles of all sizes around the origin, and a camera there."""
    centres = rng.uniform(-300, 300, (150, 3))
    vertices = (centres[:, None, :] + rng.normal(0, 120, (150, 3, 3))).reshape(-1, 3)
    part = part_from_arrays(vertices, np.arange(450).reshape(150, 3))
    return part, make_viewpoints(np.zeros((1, 3)), rng.normal(size=(1, 3)))


@pytest.mark.parametrize("seed", range(8))
def test_random_triangle_soup_around_the_camera(seed: int) -> None:
    # triangles everywhere around a camera, many crossing its plane or behind it, of all
    # sizes and orientations: every pixel must agree with Embree but for edges and ties
    rng = np.random.default_rng(seed)
    part, views = triangle_soup(rng)
    sensor = Sensor(width_px=96, height_px=64, near_mm=1.0, far_mm=2000.0, fov_x_deg=100)
    window = (0, sensor.height_px, 0, sensor.width_px)
    a = raster_ids(part, sensor, views, 0, window)
    b = embree_ids(EmbreeBackend(part), sensor, views, 0, window)
    assert (b >= 0).sum() > 0.3 * b.size
    width = sensor.width_px
    for k in np.flatnonzero(a != b):
        uv = np.array([k % width, k // width], dtype=float)
        assert unexplained(part, sensor, views, 0, (a[k], b[k]), uv) < EDGE_PX, (k, a[k], b[k])
