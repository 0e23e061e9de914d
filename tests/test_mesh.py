"""Tests of vpp_core.mesh.part: loading, validation, canonical id, degenerate faces, orientation."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from tests.conftest import MANIFEST_UNITS, manifest_rows
from vpp_core.errors import LimitError, MeshError
from vpp_core.mesh.part import FORMATS, UNITS_TO_MM, Part, load_mesh, mesh_id, part_from_arrays

MESHES = Path(__file__).resolve().parents[1].parent / "shared/meshes"
BAD = MESHES / "bad"
needs_meshes = pytest.mark.skipif(
    not MESHES.is_dir(), reason=f"shared test meshes not found at {MESHES}"
)


def read(path: Path) -> bytes:
    return path.read_bytes()


def load(path: Path, units: str = "mm") -> Part:
    return load_mesh(read(path), path.suffix, units)


def export(mesh: trimesh.Trimesh, file_type: str, **kwargs: Any) -> bytes:
    """trimesh export to bytes (text formats encoded)."""
    blob: Any = mesh.export(file_type=file_type, **kwargs)
    return blob.encode() if isinstance(blob, str) else bytes(blob)


def plate_holes_raw() -> trimesh.Trimesh:
    """plate_holes.STL as trimesh reads it, unprocessed (3 vertices per face)."""
    mesh = trimesh.load(MESHES / "plate_holes.STL", process=False)
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def box_arrays() -> tuple[np.ndarray, np.ndarray]:
    """A closed, outward-wound 10 mm cube: (8, 3) vertices, (12, 3) faces."""
    box = trimesh.creation.box(extents=(10.0, 10.0, 10.0))
    return np.asarray(box.vertices), np.asarray(box.faces)


def assert_outward(part: Part, centre: np.ndarray | None = None) -> None:
    """Counted normals point away from `centre` ((3,) or per face (M, 3); default centroid)."""
    centre = part.vertices.mean(axis=0) if centre is None else centre
    face_centres = part.vertices[part.faces].mean(axis=1)
    dots = np.einsum("ij,ij->i", part.normals, face_centres - centre)
    assert np.all(dots[part.counted] > 0)


# ---------------------------------------------------------------- malformed inputs

REJECTED = {
    "empty.stl": "empty file",
    "not_a_mesh.stl": "not a valid STL file",
    "random_bytes.stl": "not a valid STL file",
    "zero_triangles.stl": "empty mesh: 0 triangles",
    "truncated_binary.stl": "truncated binary STL: header says 1252 triangles, file holds 751",
    "truncated_ascii.stl": "truncated ASCII STL",
    "nan_vertices.stl": "3 vertices have non-finite coordinates",
    "nan_vertices.obj": "2 vertices have non-finite coordinates",
    "bad_index.obj": "invalid face index",
}
ACCEPTED = {
    "count_mismatch_extra_bytes.stl",
    "degenerate_faces.stl",
    "single_triangle.stl",
    "cube_inverted_winding.stl",
}


@needs_meshes
def test_every_bad_file_has_a_treatment() -> None:
    on_disk = {p.name for p in BAD.iterdir() if p.suffix != ".md"}
    assert on_disk == set(REJECTED) | ACCEPTED


@needs_meshes
@pytest.mark.parametrize(("name", "message"), sorted(REJECTED.items()))
def test_bad_file_rejected(name: str, message: str) -> None:
    with pytest.raises(MeshError, match=message) as info:
        load(BAD / name)
    assert "\n" not in info.value.detail


@needs_meshes
def test_count_mismatch_read_by_file_size() -> None:
    part = load(BAD / "count_mismatch_extra_bytes.stl")
    assert part.n_faces == 12
    assert any("header says 10 triangles" in w for w in part.warnings)


@needs_meshes
def test_degenerate_and_duplicate_faces() -> None:
    part = load(BAD / "degenerate_faces.stl")
    assert part.n_faces == 17
    assert part.counted.sum() == 12
    assert part.area_mm2 == pytest.approx(600.0)
    assert list(np.flatnonzero(~part.counted)) == [12, 13, 14, 15, 16]
    assert part.representative[16] == 0
    assert np.array_equal(part.representative[:16], np.arange(16))
    assert np.all(part.normals[12:16] == 0)
    assert np.allclose(np.linalg.norm(part.normals[part.counted], axis=1), 1.0)
    assert np.array_equal(part.normals[16], part.normals[0])
    assert "4 zero-area faces (excluded from coverage)" in part.warnings
    assert "1 duplicate face (excluded from coverage)" in part.warnings
    assert not any("open" in w for w in part.warnings)  # stray zero-area faces do not open it
    assert_outward(part)


@needs_meshes
def test_inverted_cube_gets_outward_normals() -> None:
    part = load(BAD / "cube_inverted_winding.stl")
    assert_outward(part)
    assert "inverted winding: normals flipped on 1 of 1 closed shells" in part.warnings
    tm = part.trimesh()  # the trimesh copy is re-wound to agree with the normals
    assert np.allclose(tm.face_normals, part.normals)
    assert tm.volume > 0


@needs_meshes
def test_single_triangle_accepted() -> None:
    part = load(BAD / "single_triangle.stl")
    assert part.n_faces == 1
    assert part.area_mm2 > 0
    assert "1 of 1 shells are open: normals follow the file's winding" in part.warnings


# ---------------------------------------------------------------- real parts


@needs_meshes
@pytest.mark.parametrize("row", manifest_rows(), ids=lambda r: r["file"])
def test_manifest_mesh_loads(row: dict[str, str]) -> None:
    part = load(MESHES / row["file"], MANIFEST_UNITS[row["units_guess"]])
    assert part.n_faces == int(row["faces"])
    assert part.areas.sum() == pytest.approx(float(row["area_mm2"]), rel=0.01)
    assert part.area_mm2 <= part.areas.sum()
    assert np.isfinite(part.normals).all()
    assert not any("flipped" in w or "open" in w for w in part.warnings), part.warnings


@needs_meshes
def test_binary_stl_with_solid_header() -> None:
    assert read(MESHES / "plate_holes.STL")[:5] == b"solid"
    assert load(MESHES / "plate_holes.STL").n_faces == 1252


# ---------------------------------------------------------------- canonical id


@needs_meshes
def test_same_geometry_same_id_across_formats() -> None:
    source = plate_holes_raw()
    reference = load(MESHES / "plate_holes.STL")
    exports = {
        "stl": export(source, "stl"),
        "stl_ascii": export(source, "stl_ascii"),
        "ply": export(source, "ply"),
        "obj": export(source, "obj", digits=17),  # enough digits to round-trip float64
        "glb": export(source, "glb"),
    }
    for fmt, data in exports.items():
        part = load_mesh(data, fmt.removesuffix("_ascii"))
        assert part.id == reference.id, fmt
        assert np.array_equal(part.faces, reference.faces), fmt


@needs_meshes
def test_rotated_copy_has_another_id() -> None:
    source = plate_holes_raw()
    reference = load(MESHES / "plate_holes.STL")
    c, s = np.cos(0.3), np.sin(0.3)
    rotation = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    rotated = trimesh.Trimesh(source.vertices @ rotation.T, source.faces, process=False)
    part = load_mesh(export(rotated, "ply"), "ply")
    assert part.id != reference.id
    assert part.area_mm2 == pytest.approx(reference.area_mm2)


def test_id_is_hash_of_canonical_arrays() -> None:
    v, f = box_arrays()
    part = part_from_arrays(v, f)
    assert part.id == mesh_id(part.vertices, part.faces)
    order = np.lexsort(part.vertices.T[::-1])
    assert np.array_equal(order, np.arange(len(part.vertices)))
    assert np.all(part.faces.argmin(axis=1) == 0)


def test_vertex_order_and_negative_zero_do_not_change_id() -> None:
    v, f = box_arrays()
    perm = np.random.default_rng(0).permutation(len(v))
    inverse = np.argsort(perm)
    shuffled = part_from_arrays(v[perm], inverse[f])
    signed_zero = part_from_arrays(np.where(v == 0, -0.0, v), f)
    assert shuffled.id == part_from_arrays(v, f).id == signed_zero.id


def test_winding_kept_in_faces() -> None:
    v, f = box_arrays()
    part = part_from_arrays(v, f[:, ::-1])
    assert part.id != part_from_arrays(v, f).id  # geometry as given, winding included
    assert_outward(part)


# ---------------------------------------------------------------- orientation


def test_inconsistent_winding_made_consistent() -> None:
    v, f = box_arrays()
    f = f.copy()
    f[::3] = f[::3, ::-1]
    part = part_from_arrays(v, f)
    assert_outward(part)
    assert any(w.startswith("inconsistent winding") for w in part.warnings)


def test_one_of_two_shells_inverted() -> None:
    v, f = box_arrays()
    vertices = np.vstack([v, v + 100.0])
    faces = np.vstack([f, f[:, ::-1] + len(v)])
    part = part_from_arrays(vertices, faces)
    assert_outward(part, np.repeat([[0.0, 0.0, 0.0], [100.0, 100.0, 100.0]], 12, axis=0))
    assert "inverted winding: normals flipped on 1 of 2 closed shells" in part.warnings


def test_open_mesh_keeps_file_winding() -> None:
    v, f = box_arrays()
    part = part_from_arrays(v, f[2:])
    raw = trimesh.Trimesh(v, f[2:], process=False).face_normals
    assert np.allclose(part.normals, raw)


# ---------------------------------------------------------------- hints, units, limits


@needs_meshes
@pytest.mark.parametrize("hint", ["stl", "STL", ".Stl", " .STL "])
def test_format_hint_case_insensitive(hint: str) -> None:
    assert load_mesh(read(BAD / "single_triangle.stl"), hint).n_faces == 1


def test_unknown_format_and_units_rejected() -> None:
    with pytest.raises(MeshError, match="accepted: " + ", ".join(FORMATS)):
        load_mesh(b"solid x\nendsolid x\n", "3mf")
    with pytest.raises(MeshError, match="accepted: " + ", ".join(UNITS_TO_MM)):
        load_mesh(b"solid x\nendsolid x\n", "stl", units="ft")


@pytest.mark.parametrize(("units", "factor"), sorted(UNITS_TO_MM.items()))
def test_units_converted_to_mm(units: str, factor: float) -> None:
    v, f = box_arrays()
    part = part_from_arrays(v, f, units=units)
    assert part.area_mm2 == pytest.approx(600.0 * factor**2)
    assert np.allclose(part.bounds, np.array([[-5.0] * 3, [5.0] * 3]) * factor)


@needs_meshes
def test_units_on_load() -> None:
    part = load(MESHES / "ADIS16480.STL", "m")
    assert np.allclose(part.bounds[1] - part.bounds[0], [44.0, 14.0, 47.0], atol=0.01)


@needs_meshes
def test_face_limit() -> None:
    with pytest.raises(LimitError, match="1252 faces"):
        load_mesh(read(MESHES / "plate_holes.STL"), "stl", max_faces=1000)


# ---------------------------------------------------------------- robustness in memory


def test_garbage_in_other_formats() -> None:
    for fmt in ("obj", "ply", "off", "glb", "gltf"):
        with pytest.raises(MeshError, match=f"{fmt.upper()}"):
            load_mesh(b"\x00\x01 definitely not a mesh \xff" * 10, fmt)


def test_obj_index_beyond_vertex_count() -> None:
    obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99\n"
    with pytest.raises(MeshError, match="invalid face index"):
        load_mesh(obj, "obj")


@pytest.mark.parametrize("bad", [-1, 8])
def test_arrays_with_bad_index(bad: int) -> None:
    v, f = box_arrays()
    f = f.copy()
    f[3, 1] = bad
    with pytest.raises(MeshError, match=f"invalid face index {bad}"):
        part_from_arrays(v, f)


def test_arrays_with_nan_rejected() -> None:
    v, f = box_arrays()
    v = v.copy()
    v[0, 0] = np.nan
    with pytest.raises(MeshError, match="1 vertices have non-finite"):
        part_from_arrays(v, f)


def test_all_faces_degenerate_rejected() -> None:
    v = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    with pytest.raises(MeshError, match="no usable faces"):
        part_from_arrays(v, np.array([[0, 1, 2]]))


def test_trailing_bytes_after_binary_stl() -> None:
    v, f = box_arrays()
    data = export(trimesh.Trimesh(v, f, process=False), "stl") + b"\x00" * 7
    part = load_mesh(data, "stl")
    assert part.n_faces == 12
    assert any("7 bytes after the last triangle ignored" in w for w in part.warnings)


def test_crlf_ascii_stl() -> None:
    v, f = box_arrays()
    text = export(trimesh.Trimesh(v, f, process=False), "stl_ascii")
    part = load_mesh(text.replace(b"\n", b"\r\n"), "stl")
    assert part.n_faces == 12
    assert part.id == part_from_arrays(v, f).id


def test_unused_vertices_ignored() -> None:
    v, f = box_arrays()
    part = part_from_arrays(np.vstack([v, [[50.0, 50.0, 50.0]]]), f)
    assert part.id == part_from_arrays(v, f).id
    assert "1 unused vertices ignored" in part.warnings


def test_part_is_read_only() -> None:
    part = part_from_arrays(*box_arrays())
    with pytest.raises(ValueError):
        part.normals[0, 0] = 1.0
    with pytest.raises(AttributeError):
        part.id = "x"  # type: ignore[misc]
    assert part.trimesh() is part.trimesh()


def test_trimesh_roundtrip_via_bytes() -> None:
    part = part_from_arrays(*box_arrays())
    again = load_mesh(export(part.trimesh(), "ply"), "ply")
    assert again.area_mm2 == pytest.approx(part.area_mm2)
    assert np.array_equal(again.vertices, part.vertices)


def test_gltf_embedded_and_external_buffers() -> None:
    from trimesh.exchange import gltf

    exporter: Any = gltf.export_gltf
    box = trimesh.Trimesh(*box_arrays(), process=False)
    embedded = exporter(box, embed_buffers=True)["model.gltf"]
    assert load_mesh(embedded, ".gltf").area_mm2 == pytest.approx(600.0)
    external = exporter(box)["model.gltf"]
    with pytest.raises(MeshError, match="external buffer"):
        load_mesh(external, "gltf")


def test_polygons_triangulated_and_negative_obj_indices() -> None:
    obj = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf -4 -3 -2 -1\n"
    part = load_mesh(obj, "obj")
    assert part.n_faces == 2
    assert part.area_mm2 == pytest.approx(1.0)
    assert np.allclose(part.normals, [0.0, 0.0, 1.0])


def test_garbage_message_names_no_internal_module() -> None:
    for fmt in ("obj", "off"):
        with pytest.raises(MeshError) as info:
            load_mesh(bytes(range(256)) * 4, fmt)
        assert "ModuleNotFound" not in info.value.detail


def test_absurd_coordinates_rejected() -> None:
    v, f = box_arrays()
    with pytest.raises(MeshError, match="beyond"):
        part_from_arrays(v * 1e300, f, units="m")


def test_ply_bytes_load_back_to_the_same_mesh():
    """Exact PLY (`vpp plan --mesh-out`): doubles and the faces' order and winding survive, so
    the id does; a float32 export (trimesh's PLY) would not keep it."""
    rng = np.random.default_rng(3)
    vertices = rng.normal(scale=100.0, size=(40, 3)) + np.pi
    faces = rng.integers(0, 40, size=(60, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])]
    faces = faces[faces[:, 0] != faces[:, 2]]
    part = part_from_arrays(vertices, faces)
    again = load_mesh(part.ply(), "ply")
    assert again.id == part.id
    np.testing.assert_array_equal(again.faces, part.faces)
    f32 = trimesh.Trimesh(part.vertices, part.faces, process=False).export(file_type="ply")
    assert load_mesh(f32, "ply").id != part.id
