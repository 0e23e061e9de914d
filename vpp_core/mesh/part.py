"""Mesh loading: bytes in any supported format -> a validated, canonical triangle `Part` in mm.

Pipeline: parse (own binary/ASCII STL checks, trimesh for the rest) -> validate indices and
coordinates -> scale to mm -> canonicalize (merge identical vertices, lexicographic vertex
order, each face rotated so its smallest index comes first; face order and winding kept) ->
areas, unit normals, degenerate and duplicate faces -> outward orientation of closed shells.

Orientation (vpp_core.mesh.orientation): shells are faces connected through shared edges (merged
within TOPOLOGY_MERGE_REL for this only). A shell is closed when every edge is used equally often in
both directions (so touching solids with non-manifold edges count too); an inconsistently wound
manifold closed shell is first made consistent by a BFS over its faces. Closed shells with
negative signed volume get their normals flipped. `faces` always keep the file's winding.

The id is a SHA-256 of the canonical geometry, so the same part as STL, PLY or OBJ (with the
same float values) gets the same id, while a moved or rotated copy gets a different one.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from trimesh import Trimesh

from vpp_core.errors import LimitError, MeshError
from vpp_core.mesh.labels import FaceLabels, file_labels
from vpp_core.mesh.meshio import announced_size, parse_mesh_bytes, ply_bytes
from vpp_core.mesh.orientation import orientation_signs

UNITS_TO_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "in": 25.4}
"""Length unit name -> millimetres per unit."""

FORMATS = ("stl", "obj", "ply", "off", "glb", "gltf")
"""Accepted `file_type` hints (file extensions, case-insensitive, leading dot allowed)."""

DEFAULT_MAX_FACES = 5_000_000
"""Largest accepted face count; more raises `LimitError`."""

DEGENERATE_REL_AREA = 1e-12
"""A face is degenerate when area <= DEGENERATE_REL_AREA * (longest edge)^2, i.e. its height
is below ~2e-12 of its longest edge: exactly zero area (repeated or collinear vertices) and
float64 round-off of collinear points. Thin but real CAD slivers (height/edge >= 1e-7 in the
shared test meshes) are kept."""

MAX_COORD_MM = 1e9
"""Largest accepted |coordinate| in mm (1000 km); beyond it areas and normals lose meaning."""

ID_PREFIX = b"vpp-mesh-v1"
"""Version tag hashed in front of the canonical arrays; bump it if canonicalization changes."""

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
Bool = NDArray[np.bool_]


@dataclass(frozen=True, eq=False)
class Part:
    """A triangle mesh in mm, ready for planning; arrays are read-only."""

    vertices: F64
    """(V, 3) float64 mm, unique vertices in lexicographic (x, y, z) order, all referenced."""
    faces: I64
    """(M, 3) int64 vertex indices in the file's face order, winding as given, min index first."""
    areas: F64
    """(M,) float64 mm^2 (as computed, also for degenerate faces)."""
    normals: F64
    """(M, 3) float64 unit normals, outward on closed shells; zero rows for degenerate faces."""
    counted: Bool
    """(M,) bool: not degenerate and not a duplicate of an earlier face; counts in coverage."""
    representative: I64
    """(M,) int64 index of the first face with the same vertex set (itself if unique)."""
    id: str
    """SHA-256 hex of ID_PREFIX + vertices '<f8' bytes + faces '<i8' bytes."""
    warnings: tuple[str, ...]
    """Human-readable notes on what was repaired, ignored or excluded."""
    labels: FaceLabels | None = None
    """Region labels of the faces (from the file or uploaded with it); not part of the id."""

    @property
    def n_faces(self) -> int:
        """Number of faces M, counted or not."""
        return int(len(self.faces))

    @property
    def area_mm2(self) -> float:
        """Surface area in mm^2 over counted faces."""
        return float(self.areas[self.counted].sum())

    @property
    def bounds(self) -> F64:
        """(2, 3) float64 mm: [min corner, max corner]."""
        return np.array([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    def ply(self) -> bytes:
        """Exact binary PLY of this mesh: loads back (`load_mesh`) to the same id."""
        return ply_bytes(self.vertices, self.faces, f"vpp mesh {self.id}")

    def trimesh(self) -> Trimesh:
        """Cached process=False Trimesh: same vertices and face order, wound to match normals."""
        cached: Trimesh | None = self.__dict__.get("_trimesh_cache")
        if cached is None:
            raw = _face_cross(self.vertices, self.faces)
            flip = np.einsum("ij,ij->i", raw, self.normals) < 0
            faces = self.faces.copy()
            faces[flip] = faces[flip][:, ::-1]
            cached = Trimesh(
                vertices=self.vertices.copy(), faces=faces, process=False, validate=False
            )
            object.__setattr__(self, "_trimesh_cache", cached)
        return cached


def load_mesh(
    data: bytes, file_type: str, units: str = "mm", *, max_faces: int = DEFAULT_MAX_FACES
) -> Part:
    """Parse mesh bytes of format `file_type` in `units` into a canonical `Part` in mm."""
    fmt = _normalize_format(file_type)
    scale = _unit_scale(units)
    if len(data) == 0:
        raise MeshError("empty file: 0 bytes")
    _check_announced(*announced_size(data, fmt), max_faces)
    vertices, faces, notes = parse_mesh_bytes(data, fmt)
    if len(faces) == 0:
        raise MeshError(f"empty mesh: 0 triangles in {fmt.upper()} file")
    if len(faces) > max_faces:
        raise LimitError(f"mesh has {len(faces)} faces, the limit is {max_faces}")
    part = _build_part(vertices, faces, scale, notes)
    labels = file_labels(data, fmt, vertices, faces)  # face order is kept by _build_part
    return with_labels(part, labels) if labels is not None else part


def with_labels(part: Part, labels: FaceLabels | None) -> Part:
    """`part` carrying `labels` (one per face, in its face order); same id."""
    if labels is not None and len(labels.values) != part.n_faces:
        raise MeshError(f"labels: {len(labels.values)} values for {part.n_faces} faces")
    if labels is not None:
        labels.values.setflags(write=False)
    return replace(part, labels=labels)


def _check_announced(faces: int, vertices: int, max_faces: int) -> None:
    """LimitError, before parsing, when the file's header or lines say it is over the limit."""
    if faces > max_faces:
        raise LimitError(f"mesh has {faces} faces (read before parsing), the limit is {max_faces}")
    if vertices > 3 * max_faces:
        raise LimitError(
            f"mesh has {vertices} vertices (read before parsing), the limit is "
            f"{3 * max_faces} (3 per face of the {max_faces}-face limit)"
        )


def part_from_arrays(
    vertices: NDArray[Any], faces: NDArray[Any], units: str = "mm", warnings: Sequence[str] = ()
) -> Part:
    """Build a `Part` from (V, 3) vertices in `units` and (M, 3) integer faces."""
    return _build_part(vertices, faces, _unit_scale(units), list(warnings))


def part_from_children(part: Part, vertices: F64, faces: I64, parent: I64, note: str) -> Part:
    """A Part (mm) whose face k is a piece of `part`'s face parent[k] (M',): in its plane, so it
    keeps its outward normal and whether it counts; `note` joins the warnings."""
    v, f = _canonical(np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64))
    areas, _, degenerate = _areas_normals(v, f)
    rep = _representatives(f)
    counted = part.counted[parent] & ~degenerate & (rep == np.arange(len(f)))
    normals = np.where(degenerate[:, None], 0.0, part.normals[parent])
    child = _frozen_part(v, f, areas, normals, counted, rep, (*part.warnings, note))
    if part.labels is None:
        return child
    labels = part.labels
    return with_labels(child, FaceLabels(labels.values[parent], labels.names, labels.source))


# ---------------------------------------------------------------- input hints


def _normalize_format(file_type: str) -> str:
    """'.STL' -> 'stl'; unknown formats raise MeshError listing the accepted ones."""
    fmt = file_type.strip().lower().lstrip(".")
    if fmt not in FORMATS:
        raise MeshError(f"unknown mesh format {file_type!r}; accepted: {', '.join(FORMATS)}")
    return fmt


def _unit_scale(units: str) -> float:
    """Millimetres per unit; unknown units raise MeshError listing the accepted ones."""
    key = units.strip().lower()
    if key not in UNITS_TO_MM:
        raise MeshError(f"unknown units {units!r}; accepted: {', '.join(UNITS_TO_MM)}")
    return UNITS_TO_MM[key]


# ---------------------------------------------------------------- validation, canonical form


def _build_part(
    vertices: NDArray[Any], faces: NDArray[Any], scale: float, notes: list[str]
) -> Part:
    """Validate, scale, canonicalize and analyse raw arrays into a Part."""
    v, f = _prepared(vertices, faces, scale, notes)
    areas, normals, degenerate = _areas_normals(v, f)
    rep = _representatives(f)
    counted = ~degenerate & (rep == np.arange(len(f)))
    if not counted.any():
        raise MeshError(f"no usable faces: all {len(f)} faces have zero area")
    signs, orient_notes = orientation_signs(v, f, counted, rep, degenerate)
    normals *= signs[:, None]
    dup = ~degenerate & ~counted
    normals[dup] = normals[rep[dup]]
    notes += _exclusion_notes(degenerate, counted) + orient_notes
    return _frozen_part(v, f, areas, normals, counted, rep, tuple(notes))


def _frozen_part(
    v: F64,
    f: I64,
    areas: F64,
    normals: F64,
    counted: NDArray[np.bool_],
    rep: I64,
    warnings: tuple[str, ...],
) -> Part:
    """The Part of these arrays, made read-only, with its content id."""
    for a in (v, f, areas, normals, counted, rep):
        a.setflags(write=False)
    return Part(
        vertices=v,
        faces=f,
        areas=areas,
        normals=normals,
        counted=counted,
        representative=rep,
        id=mesh_id(v, f),
        warnings=warnings,
    )


def _prepared(
    vertices: NDArray[Any], faces: NDArray[Any], scale: float, notes: list[str]
) -> tuple[F64, I64]:
    """Checked, scaled to mm, unused vertices dropped, canonical (vertices, faces)."""
    v, f = _validated(vertices, faces)
    used = _used_vertices(f, len(v))
    if len(used) < len(v):
        notes.append(f"{len(v) - len(used)} unused vertices ignored")
    remap = np.zeros(len(v), dtype=np.int64)
    remap[used] = np.arange(len(used))
    with np.errstate(over="ignore"):
        v = v[used] * scale
    f = remap[f]
    _check_coordinates(v, f)
    return _canonical(v, f)


def mesh_id(vertices: F64, faces: I64) -> str:
    """SHA-256 hex of ID_PREFIX, V and M, canonical (V, 3) '<f8' vertices, (M, 3) '<i8' faces."""
    h = hashlib.sha256(ID_PREFIX)
    h.update(np.array([len(vertices), len(faces)], dtype="<u8").tobytes())
    h.update(np.ascontiguousarray(vertices, dtype="<f8").tobytes())
    h.update(np.ascontiguousarray(faces, dtype="<i8").tobytes())
    return h.hexdigest()


def _validated(vertices: NDArray[Any], faces: NDArray[Any]) -> tuple[F64, I64]:
    """Shape/dtype checks; (V, 3) float64 and (M, 3) int64 with indices in range."""
    try:
        v = np.array(vertices, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"vertices are not numbers: {exc}") from exc
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"vertices must have shape (V, 3), got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and not np.issubdtype(f.dtype, np.integer)):
        raise MeshError(f"faces must be (M, 3) integer vertex indices, got {f.shape} {f.dtype}")
    if len(f) == 0:
        raise MeshError("empty mesh: 0 triangles")
    f = f.astype(np.int64)
    lo, hi = int(f.min()), int(f.max())
    if lo < 0 or hi >= len(v):
        bad = lo if lo < 0 else hi
        raise MeshError(f"invalid face index {bad}: the mesh has {len(v)} vertices (0-based)")
    return v, f


def _used_vertices(faces: I64, n_vertices: int) -> I64:
    """Sorted ids of the vertices referenced by at least one face."""
    mask = np.zeros(n_vertices, dtype=bool)
    mask[faces.ravel()] = True
    return np.flatnonzero(mask)


def _check_coordinates(vertices: F64, faces: I64) -> None:
    """Reject NaN/inf coordinates and coordinates beyond MAX_COORD_MM."""
    finite = np.isfinite(vertices).sum(axis=1) == 3
    n_bad = int(len(vertices) - finite.sum())
    if n_bad:
        n_faces = int((~finite)[faces].any(axis=1).sum())
        raise MeshError(
            f"{n_bad} vertices have non-finite coordinates (NaN or inf), used by {n_faces} faces"
        )
    n_far = int((np.abs(vertices) > MAX_COORD_MM).any(axis=1).sum())
    if n_far:
        raise MeshError(f"{n_far} vertices lie beyond {MAX_COORD_MM:g} mm from the origin")


def _canonical(vertices: F64, faces: I64) -> tuple[F64, I64]:
    """Merge identical vertices, sort them lexicographically, rotate faces min-index first."""
    v = vertices + 0.0  # -0.0 -> 0.0, so equal coordinates have equal bytes
    order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))
    vs = v[order]
    new = np.ones(len(vs), dtype=bool)
    new[1:] = np.any(vs[1:] != vs[:-1], axis=1)
    canon = np.empty(len(v), dtype=np.int64)
    canon[order] = np.cumsum(new) - 1
    f = canon[faces]
    shift = (np.argmin(f, axis=1)[:, None] + np.arange(3)) % 3
    return np.ascontiguousarray(vs[new]), np.take_along_axis(f, shift, axis=1)


# ---------------------------------------------------------------- per-face quantities


def _face_cross(vertices: F64, faces: I64) -> F64:
    """(M, 3) cross products (v1 - v0) x (v2 - v0): twice the area times the unit normal."""
    tri = vertices[faces]
    return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def _areas_normals(vertices: F64, faces: I64) -> tuple[F64, F64, Bool]:
    """(M,) areas mm^2, (M, 3) unit normals by winding (zero if degenerate), (M,) degenerate."""
    tri = vertices[faces]
    cross = _face_cross(vertices, faces)
    twice = np.linalg.norm(cross, axis=1)
    edges = tri - np.roll(tri, -1, axis=1)
    longest2 = np.einsum("ijk,ijk->ij", edges, edges).max(axis=1)
    degenerate = 0.5 * twice <= DEGENERATE_REL_AREA * longest2
    normals = np.zeros_like(cross)
    ok = ~degenerate
    normals[ok] = cross[ok] / twice[ok, None]
    return 0.5 * twice, normals, degenerate


def _representatives(faces: I64) -> I64:
    """(M,) index of the first face with the same vertex set (winding ignored)."""
    s = np.sort(faces, axis=1)
    order = np.lexsort((s[:, 2], s[:, 1], s[:, 0]))  # stable: earlier faces first in a group
    ss = s[order]
    start = np.ones(len(s), dtype=bool)
    start[1:] = np.any(ss[1:] != ss[:-1], axis=1)
    rep = np.empty(len(s), dtype=np.int64)
    rep[order] = order[start][np.cumsum(start) - 1]
    return rep


def _exclusion_notes(degenerate: Bool, counted: Bool) -> list[str]:
    """Warnings for zero-area and duplicate faces."""
    notes = []
    n_deg = int(degenerate.sum())
    n_dup = int((~degenerate & ~counted).sum())
    if n_deg:
        notes.append(f"{n_deg} zero-area face{'s' * (n_deg != 1)} (excluded from coverage)")
    if n_dup:
        notes.append(f"{n_dup} duplicate face{'s' * (n_dup != 1)} (excluded from coverage)")
    return notes
