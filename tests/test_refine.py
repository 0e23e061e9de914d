"""Tests of vpp_core.mesh.refine: area elements keep the surface, and count what a view sees."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from tests.conftest import MESHES, look_down, plate, shared_dir
from vpp_core.camera.sensor import Sensor
from vpp_core.errors import LimitError, MeshError
from vpp_core.mesh.part import load_mesh, part_from_arrays
from vpp_core.mesh.refine import bisect, generations, refine, refined_faces
from vpp_core.trace.raytrace import trace_counts


def longest_edges(tri: np.ndarray) -> np.ndarray:
    """(M,) longest edge (mm) of each triangle of corners (M, 3, 3) mm."""
    return np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)


def test_plate_splits_into_equal_elements_no_larger_than_asked():
    part = part_from_arrays(*plate(side=20.0))  # two triangles of 200 mm²
    out = refine(part, 1.0)
    # 200 / 2^8 = 0.78 <= 1 < 200 / 2^7: each triangle becomes 256 elements
    assert out.n_faces == 512 == refined_faces(part, 1.0)
    assert np.allclose(out.areas, 200.0 / 256, rtol=1e-12)
    assert out.area_mm2 == pytest.approx(400.0, rel=1e-12)
    assert np.allclose(out.normals, [0.0, 0.0, 1.0])
    assert out.counted.all()
    assert out.id != part.id
    assert out.warnings[-1] == "faces larger than 1 mm² or longer than 2 mm split: 2 faces -> 512"


def test_children_lie_in_their_parent_with_its_winding_and_an_exact_share_of_its_area():
    rng = np.random.default_rng(7)
    tri = rng.normal(size=(40, 3, 3)) * [[[30.0, 3.0, 0.2]]]  # slivers among them
    vertices = tri.reshape(-1, 3)
    faces = np.arange(120).reshape(40, 3)
    k = rng.integers(0, 7, size=40)
    v, f, parent = bisect(vertices, faces, k)
    assert np.array_equal(np.bincount(parent, minlength=40), 2**k)
    assert np.all(np.diff(parent) >= 0)  # children next to each other, in parent order
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    pcross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[parent]
    area, parea = np.linalg.norm(cross, axis=1), np.linalg.norm(pcross, axis=1)
    assert np.allclose(area, parea / 2.0 ** k[parent], rtol=1e-9)
    assert np.all(np.einsum("ij,ij->i", cross, pcross) > 0)  # same winding, same plane side
    # every corner of a child has barycentric coordinates in [0, 1] in its parent
    for corner in range(3):
        p = v[f[:, corner]]
        a, b, c = (tri[parent, i] for i in range(3))
        lam = _barycentric(p, a, b, c)
        assert lam.min() > -1e-9 and lam.max() < 1 + 1e-9
        assert np.allclose(lam.sum(axis=1), 1.0)


def test_slivers_are_bisected_until_no_edge_is_longer_than_asked():
    """Long thin triangles (30 x 3 x 0.2 mm spreads) bisected to edges of at most 5 mm: the
    children tile their parent (areas add up, corners inside it, same winding)."""
    rng = np.random.default_rng(7)
    tri = rng.normal(size=(40, 3, 3)) * [[[30.0, 3.0, 0.2]]]
    vertices, faces = tri.reshape(-1, 3), np.arange(120).reshape(40, 3)
    v, f, parent = bisect(vertices, faces, np.zeros(40, dtype=np.int64), max_edge_mm=5.0)
    assert longest_edges(v[f]).max() <= 5.0 * (1 + 1e-9)
    assert longest_edges(tri).min() > 5.0 and len(f) > 4 * 40  # every one was split
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    pcross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.bincount(parent, weights=np.linalg.norm(cross, axis=1), minlength=40)
    assert np.allclose(area, np.linalg.norm(pcross, axis=1), rtol=1e-9)
    assert np.all(np.einsum("ij,ij->i", cross, pcross[parent]) > 0)
    for corner in range(3):
        lam = _barycentric(v[f[:, corner]], *(tri[parent, i] for i in range(3)))
        assert lam.min() > -1e-9 and lam.max() < 1 + 1e-9


def _barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """(K, 3) barycentric coordinates of points p (K, 3) in triangles (a, b, c) (K, 3) each."""
    v0, v1, v2 = b - a, c - a, p - a
    d00, d01, d11 = (v0 * v0).sum(1), (v0 * v1).sum(1), (v1 * v1).sum(1)
    d20, d21 = (v2 * v0).sum(1), (v2 * v1).sum(1)
    den = d00 * d11 - d01 * d01
    y = (d11 * d20 - d01 * d21) / den
    z = (d00 * d21 - d01 * d20) / den
    return np.column_stack([1 - y - z, y, z])


def test_refined_box_keeps_its_outward_normals_and_is_deterministic():
    box = trimesh.creation.box(extents=(10.0, 20.0, 30.0))
    part = part_from_arrays(box.vertices, box.faces[:, ::-1])  # wound inward: oriented on load
    out = refine(part, 2.0)
    centroids = out.vertices[out.faces].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", out.normals, centroids) > 0)
    assert out.area_mm2 == pytest.approx(2 * (200 + 300 + 600), rel=1e-12)
    assert out.areas.max() <= 2.0
    assert refine(part, 2.0).id == out.id
    assert refine(out, 2.0) is out  # nothing left to split


def test_bad_sizes_and_too_many_faces_are_refused():
    part = part_from_arrays(*plate(side=20.0))
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(MeshError, match="positive"):
            refine(part, bad)
    with pytest.raises(LimitError, match="gives at least 512 faces, the limit is 100"):
        refine(part, 1.0, max_faces=100)
    assert generations(np.array([0.0, 1.0, 1.0 + 1e-9, 4.0]), 1.0).tolist() == [0, 0, 1, 2]


def test_elements_count_the_area_a_view_really_sees_where_faces_count_it_all():
    """A 20 mm plate of two faces, half of it under a bar 5 mm above: one view from 500 mm.
    Per face the whole plate is seen (one ray on a face is enough); per element of <= 1 mm²,
    the unshadowed half, to within the elements along the shadow's edge."""
    v, f = plate(side=20.0)
    bar = np.array([[-10.0, -10, 5], [0, -10, 5], [0, 10, 5], [-10, 10, 5]])
    vertices = np.vstack([v, bar])
    faces = np.vstack([f, [[4, 5, 6], [4, 6, 7]]])
    part = part_from_arrays(vertices, faces)
    out = refine(part, 1.0)
    view = look_down((0.0, 0.0, 500.0))
    r_faces = trace_counts(part, Sensor(), view).counts.toarray()[:, 0]
    r_elems = trace_counts(out, Sensor(), view).counts.toarray()[:, 0]
    on_plate = out.vertices[out.faces][:, :, 2].max(axis=1) < 1.0
    plate_faces = part.vertices[part.faces][:, :, 2].max(axis=1) < 1.0
    assert part.areas[plate_faces & (r_faces > 0)].sum() == pytest.approx(400.0)
    seen = out.areas[on_plate & (r_elems > 0)].sum()
    band = 20.0 * 1.5  # elements straddling the 20 mm shadow edge, <= ~1.4 mm across
    assert 200.0 - band < seen < 200.0 + band
    # the same rays land on the same surface: counts add up per plate and per bar
    assert r_elems[on_plate].sum() == pytest.approx(r_faces[plate_faces].sum(), abs=2)
    assert r_elems[~on_plate].sum() == pytest.approx(r_faces[~plate_faces].sum(), abs=2)


def test_a_cad_part_keeps_its_surface():
    path = shared_dir(MESHES) / "featuretype.STL"
    part = load_mesh(path.read_bytes(), "stl", "in")
    out = refine(part, 1.0)
    assert out.n_faces == refined_faces(part, 1.0)
    assert out.areas.max() <= 1.0
    assert longest_edges(out.vertices[out.faces]).max() <= 2.0 * (1 + 1e-9)
    assert out.area_mm2 == pytest.approx(part.area_mm2, rel=1e-9)
    assert np.allclose(out.bounds, part.bounds)
    # faces already small and short enough are kept as they are, the others split
    long = longest_edges(part.vertices[part.faces]) > 2.0
    small = (part.areas <= 1.0) & ~long
    kept = {tuple(sorted(map(tuple, part.vertices[face]))) for face in part.faces[small]}
    have = {tuple(sorted(map(tuple, out.vertices[face]))) for face in out.faces}
    assert kept <= have
    assert (part.areas[long] <= 1.0).sum() > 100  # slivers: split for their length alone
    children = np.maximum(2 ** generations(part.areas, 1.0), np.where(long, 2, 1))
    assert out.counted.sum() >= children[part.counted].sum()
    by_area = refine(part, 1.0, max_edge_mm=np.inf)  # by area alone: 2^k children each
    assert by_area.n_faces == (2 ** generations(part.areas, 1.0)).sum() < out.n_faces
    assert by_area.n_faces == refined_faces(part, 1.0, max_edge_mm=np.inf)
