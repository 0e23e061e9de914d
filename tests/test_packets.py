"""The Embree packet backend against Embree single rays (embreex), with Embree 3 and 4."""

from __future__ import annotations

import functools
import math
import os
from typing import Any

import numpy as np
import pytest

from tests.conftest import MANIFEST_UNITS, MESHES, manifest_rows, plate, plate_part, shared_dir
from tests.test_raster import (
    CENTRE,
    EDGE_PX,
    PAPER,
    compare_views,
    embree_ids,
    reference_ids,
    triangle_soup,
    unexplained,
)
from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.generator import GeneratorSettings, generate
from vpp_core.errors import VppError
from vpp_core.mesh.part import Part, load_mesh, part_from_arrays
from vpp_core.trace.embree import EmbreeBackend, block_directions
from vpp_core.trace.packets import PacketBackend, library
from vpp_core.trace.raster import MAX_FACES_PER_PIXEL, RasterBackend
from vpp_core.trace.rays import Block
from vpp_core.trace.raytrace import _hull_points, make_backend, trace_counts, view_windows


def packets(part: Part, major: int) -> PacketBackend:
    """The packet backend over Embree `major`; Embree 3 skips where the system lacks it
    (fails where VPP_REQUIRE_EMBREE3 is set, as in CI)."""
    try:
        return PacketBackend(part, major)
    except VppError as exc:
        if major == 3 and not os.environ.get("VPP_REQUIRE_EMBREE3"):
            pytest.skip(f"no system Embree 3 (apt install libembree3-3): {exc}")
        raise


def first_ids(backend: PacketBackend, block: Block) -> np.ndarray:
    """The face first hit through each pixel of the block (-1 = none), flattened: the valid
    hits of a sensor that takes any depth and any incidence."""
    sensor = block.sensor.model_dump() | {"near_mm": 1e-3, "max_incidence_deg": 90.0}
    sensor["working_distance_mm"] = None
    hits = backend.pixel_hits(
        Block(Sensor(**sensor), block.position, block.rotation, block.rows, block.cols)
    )
    out = np.full((block.rows[1] - block.rows[0]) * (block.cols[1] - block.cols[0]), -1, np.int32)
    out[hits.pixels] = hits.faces
    return out


def reaches_incidence_limit(part: Part, views: Viewpoints, j: int, face: int) -> bool:
    """Whether some point of the face is seen from view j at (or beyond) the largest
    incidence angle, to 1e-4 in cos: on a plane |cos| = h / distance (h: the camera's
    distance to the plane), smallest at the farthest vertex."""
    corners = part.vertices[part.faces[face]] - views.positions[j]
    h = abs(float(part.normals[face] @ corners[0]))
    cos_min = math.cos(math.radians(PAPER.max_incidence_deg))
    return h / float(np.linalg.norm(corners, axis=1).max()) <= cos_min + 1e-4


SHARED = [(r["file"], MANIFEST_UNITS[r["units_guess"]]) for r in manifest_rows()]


@functools.lru_cache(maxsize=1)  # one mesh at a time: its Embree 3 and 4 cases run in a row
def embree_reference(name: str, units: str) -> tuple[Part, Viewpoints, list[np.ndarray], Any]:
    """A shared mesh, its 20 paper-camera candidates, Embree single rays' first face per pixel
    of each view (`reference_ids`) and R traced with Embree single rays, both in the central
    quarter of the image (`CENTRE`): what both Embree majors are compared with, computed once
    for the two."""
    path = shared_dir(MESHES) / name
    part = load_mesh(path.read_bytes(), path.suffix, units)
    views = generate(part, PAPER, GeneratorSettings(count=20, seed=0)).views
    ids = reference_ids(part, CENTRE, views)
    counts = trace_counts(part, CENTRE, views, backend=make_backend(part, "embree")).counts
    return part, views, ids, counts


@pytest.mark.parametrize("major", [3, 4])
@pytest.mark.parametrize("name, units", SHARED or [("absent", "mm")])
def test_packets_agree_with_embree_rays_on_shared_meshes(name: str, units: str, major: int) -> None:
    part, views, ids, reference = embree_reference(name, units)
    backend = packets(part, major)

    def ids_of(j: int, window: tuple[int, int, int, int]) -> np.ndarray:
        block = Block(CENTRE, views.positions[j], views.rotations()[j], window[:2], window[2:])
        return first_ids(backend, block)

    hits, bad, touched, worst = compare_views(part, CENTRE, views, ids_of, ids)
    assert hits > 0
    if major == 4:  # the very library embreex calls, on the very same rays
        assert bad == 0, f"{bad} of {hits} hit pixels differ from Embree 4 single rays"
    assert bad <= 1e-4 * hits, f"{bad} of {hits} hit pixels differ"
    assert worst < EDGE_PX, f"a disagreement {worst:.2g} px from any edge, and no depth tie"
    counts = trace_counts(part, CENTRE, views, backend=backend).counts.toarray().astype(np.int64)
    # R differs by the disagreeing pixels above, and by rays at the incidence limit: packets
    # test it on Embree's float32 Ng, the embree backend on the part's normals in float32
    excess = np.maximum(np.abs(counts - reference.toarray()) - touched, 0)
    assert excess.sum() <= 2e-5 * reference.sum()
    for f, j in zip(*np.nonzero(excess), strict=True):
        assert reaches_incidence_limit(part, views, int(j), int(f)), (f, j, excess[f, j])


@pytest.mark.parametrize("major", [3, 4])
def test_arbitrary_rays_are_embrees_answer(major: int) -> None:
    path = shared_dir(MESHES) / "hirth_sample_small.stl"
    part = load_mesh(path.read_bytes(), "stl")
    rng = np.random.default_rng(major)
    centre, size = part.vertices.mean(axis=0), np.ptp(part.vertices, axis=0).max()
    origin = centre + np.array([2.0, 0.5, 0.3]) * size
    aim = centre + rng.normal(0, 0.4 * size, (10_007, 3))  # not a multiple of 16
    directions = (aim - origin).astype(np.float32)
    prim, t = packets(part, major).first_hits(origin, directions, 1e4)
    ref_prim, ref_t = EmbreeBackend(part).first_hits(origin, directions, 1e4)
    assert (prim >= 0).sum() > 1000 and (prim < 0).sum() > 100
    assert np.array_equal(prim, ref_prim)
    assert np.array_equal(t[prim >= 0], ref_t[prim >= 0])
    assert np.all(np.isinf(t[prim < 0]))


@pytest.mark.parametrize("major", [3, 4])
@pytest.mark.parametrize("seed", range(4))
def test_random_triangle_soup_around_the_camera(seed: int, major: int) -> None:
    # triangles crossing the camera plane or behind it, of all sizes: every pixel must agree
    # with Embree rays but for edges and ties; a window that is not a multiple of the tile
    part, views = triangle_soup(np.random.default_rng(seed))
    sensor = Sensor(width_px=98, height_px=63, near_mm=1.0, far_mm=2000.0, fov_x_deg=100)
    window = (1, sensor.height_px, 2, sensor.width_px - 1)
    block = Block(sensor, views.positions[0], views.rotations()[0], window[:2], window[2:])
    a = first_ids(packets(part, major), block)
    b = embree_ids(EmbreeBackend(part), sensor, views, 0, window)
    assert (b >= 0).sum() > 0.3 * b.size
    width = window[3] - window[2]
    for k in np.flatnonzero(a != b):
        uv = np.array([window[2] + k % width, window[0] + k // width], dtype=float)
        assert unexplained(part, sensor, views, 0, (a[k], b[k]), uv) < EDGE_PX, (k, a[k], b[k])


def test_raster_hands_views_with_more_faces_than_pixels_to_packets() -> None:
    # a fine plate seen by a small sensor: more faces than pixels, so the rasteriser's
    # answer is the packet tracer's, and both count what Embree rays count
    part = plate_part(side=150.0, n=60)  # 7200 faces on about 1300 pixels
    sensor = Sensor(width_px=64, height_px=40)
    views = make_viewpoints(np.array([[0.4, -0.3, 300.0]]), np.array([[0.0, 0.0, -1.0]]))
    hull = _hull_points(part.vertices)
    ((v0, v1, u0, u1),) = view_windows(sensor, views, hull)
    assert part.n_faces > MAX_FACES_PER_PIXEL * (v1 - v0) * (u1 - u0)
    raster = RasterBackend(part)
    r = trace_counts(part, sensor, views, backend=raster).counts
    assert raster._packets is not None  # the view went to packets
    ref = trace_counts(part, sensor, views, backend=make_backend(part, "embree")).counts
    assert r.sum() > 500
    assert np.abs(r.toarray() - ref.toarray()).max() <= 2


@pytest.mark.parametrize("major", [3, 4])
def test_counts_do_not_depend_on_blocks_threads_or_reuse(major: int) -> None:
    # R in whole-view blocks on one thread (counters fresh) against blocks of 4 rows on 2
    # threads, traced twice over one backend (its counters reused, so they must come back
    # zero), and against Embree single rays; duplicate faces count on their representative
    v, f = plate(side=60.0, n=12, tilt_deg=15.0)
    part = part_from_arrays(v, np.vstack([f, f[::5, [1, 2, 0]]]))  # 58 duplicate faces
    assert (part.representative != np.arange(part.n_faces)).sum() == len(f[::5])
    sensor = Sensor(width_px=160, height_px=100)
    positions = np.array([[0.0, 0.0, 400.0], [20.0, -10.0, 450.0], [-5.0, 30.0, 380.0]])
    views = make_viewpoints(positions, -positions / np.linalg.norm(positions, axis=1)[:, None])
    whole = trace_counts(part, sensor, views, backend=packets(part, major), threads=1).counts
    split = packets(part, major)
    split.block_rays = 4 * 160  # several blocks per view, merged per view
    again = [trace_counts(part, sensor, views, backend=split, threads=2).counts for _ in "ab"]
    ref = trace_counts(part, sensor, views, backend=EmbreeBackend(part), threads=1).counts
    assert whole.sum() > 3000 and whole.has_sorted_indices
    assert all((r != whole).nnz == 0 and r.has_sorted_indices for r in again)
    assert not whole[np.flatnonzero(part.representative != np.arange(part.n_faces))].nnz
    assert np.abs((whole - ref).toarray()).sum() <= (0 if major == 4 else 6)


def test_library_choice() -> None:
    assert library(4).major == 4
    if os.environ.get("VPP_REQUIRE_EMBREE3"):  # where installed, Embree 3 is the default
        assert library().major == 3
    with pytest.raises(VppError, match="no Embree 5"):
        library(5)


def test_directions_are_those_of_the_embree_backend() -> None:
    # the kernel builds the pixel rays itself: bit for bit block_directions' float32 rays,
    # checked through their hit distances on a plane facing the camera at a slant
    part = plate_part(side=400.0, tilt_deg=20.0)
    views = make_viewpoints(np.array([[3.0, -2.0, 500.0]]), np.array([[0.01, 0.02, -1.0]]))
    block = Block(PAPER, views.positions[0], views.rotations()[0], (100, 140), (300, 333))
    hits = PacketBackend(part, 4).pixel_hits(block)
    dirs = block_directions(block)
    prim, t = EmbreeBackend(part).first_hits(views.positions[0], dirs, PAPER.far_mm)
    assert (prim >= 0).all() and len(hits.pixels) == len(prim)
    assert np.array_equal(hits.depth, t)
