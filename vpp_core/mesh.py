"""Mesh loading: bytes in any supported format -> a validated, canonical triangle `Part` in mm.

Pipeline: parse (own binary/ASCII STL checks, trimesh for the rest) -> validate indices and
coordinates -> scale to mm -> canonicalize (merge identical vertices, lexicographic vertex
order, each face rotated so its smallest index comes first; face order and winding kept) ->
areas, unit normals, degenerate and duplicate faces -> outward orientation of closed shells.

Orientation: shells are sets of faces connected through shared edges (vertices merged within
TOPOLOGY_MERGE_REL for this only). A shell is closed when every edge is used equally often in
both directions (so touching solids with non-manifold edges count too); an inconsistently wound
manifold closed shell is first made consistent by a BFS over its faces. Closed shells with
negative signed volume get their normals flipped. `faces` always keep the file's winding.

The id is a SHA-256 of the canonical geometry, so the same part as STL, PLY or OBJ (with the
same float values) gets the same id, while a moved or rotated copy gets a different one.
"""

from __future__ import annotations

import hashlib
import io
import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import trimesh
from numpy.typing import NDArray
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree
from trimesh import Trimesh

from vpp_core.errors import LimitError, MeshError

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

TOPOLOGY_MERGE_REL = 1e-8
"""Vertices closer than this times the bounding-box diagonal count as one vertex when deciding
which shells are closed (CAD exports write 'the same' vertex with round-off differences); the
canonical geometry and the id keep every distinct vertex."""

ID_PREFIX = b"vpp-mesh-v1"
"""Version tag hashed in front of the canonical arrays; bump it if canonicalization changes."""

_STL_HEADER_BYTES = 84
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
_STL_PLAUSIBLE_ABS = 1e15
"""Binary STL records with |float| above this (or non-finite) are treated as not STL data."""

_TEXT_FORMATS = ("stl", "obj", "off")  # "stl" reaches trimesh only as checked ASCII STL
_OBJ_ZERO_INDEX = re.compile(rb"(?m)^[ \t]*f[ \t](?:[^\n]*?[ \t])?-?0+(?=[/ \t\r\n]|$)")

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
    vertices, faces, notes = _parse_stl(data) if fmt == "stl" else _parse_trimesh(data, fmt)
    if len(faces) == 0:
        raise MeshError(f"empty mesh: 0 triangles in {fmt.upper()} file")
    if len(faces) > max_faces:
        raise LimitError(f"mesh has {len(faces)} faces, the limit is {max_faces}")
    return _build_part(vertices, faces, scale, notes)


def part_from_arrays(
    vertices: NDArray[Any], faces: NDArray[Any], units: str = "mm", warnings: Sequence[str] = ()
) -> Part:
    """Build a `Part` from (V, 3) vertices in `units` and (M, 3) integer faces."""
    return _build_part(vertices, faces, _unit_scale(units), list(warnings))


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


# ---------------------------------------------------------------- STL


def _parse_stl(data: bytes) -> tuple[F64, I64, list[str]]:
    """Binary or ASCII STL bytes -> (3M, 3) vertices, (M, 3) faces, notes."""
    n = len(data)
    count = int(np.frombuffer(data, "<u4", 1, 80)[0]) if n >= _STL_HEADER_BYTES else -1
    if count >= 0 and _STL_HEADER_BYTES + _STL_RECORD.itemsize * count == n:
        return _stl_binary(data, count, [])
    if _looks_like_ascii_stl(data):
        return _stl_ascii(data)
    if count < 0:
        raise MeshError(f"not a valid STL file: not ASCII STL and only {n} bytes (binary needs 84)")
    return _stl_binary_mismatch(data, count)


def _stl_records(data: bytes, count: int) -> NDArray[np.void]:
    """The first `count` 50-byte binary STL records."""
    return np.frombuffer(data, _STL_RECORD, count, _STL_HEADER_BYTES)


def _stl_binary(data: bytes, count: int, notes: list[str]) -> tuple[F64, I64, list[str]]:
    """Read `count` binary STL records as unmerged triangles."""
    verts = _stl_records(data, count)["vertices"].reshape(-1, 3).astype(np.float64)
    return verts, np.arange(3 * count, dtype=np.int64).reshape(-1, 3), notes


def _plausible(records: NDArray[np.void]) -> bool:
    """True if every float of the records is finite and not absurdly large."""
    floats = np.concatenate([records["normal"].ravel(), records["vertices"].ravel()])
    with np.errstate(invalid="ignore", over="ignore"):
        return bool(np.all(np.abs(floats.astype(np.float64)) < _STL_PLAUSIBLE_ABS))


def _stl_binary_mismatch(data: bytes, count: int) -> tuple[F64, I64, list[str]]:
    """Binary STL whose size disagrees with its header count: truncated, extra, or not STL."""
    held, extra = divmod(len(data) - _STL_HEADER_BYTES, _STL_RECORD.itemsize)
    if held < count:
        if not _plausible(_stl_records(data, held)):
            raise MeshError(
                f"not a valid STL file: not ASCII STL, and as binary STL the header claims "
                f"{count} triangles but the {len(data)} bytes hold {held} implausible records"
            )
        raise MeshError(
            f"truncated binary STL: header says {count} triangles, "
            f"file holds {held} complete records"
        )
    if extra == 0 and _plausible(_stl_records(data, held)):
        note = f"binary STL header says {count} triangles but the file holds {held}; read all"
        return _stl_binary(data, held, [note])
    tail = len(data) - _STL_HEADER_BYTES - _STL_RECORD.itemsize * count
    return _stl_binary(data, count, [f"binary STL: {tail} bytes after the last triangle ignored"])


def _looks_like_ascii_stl(data: bytes) -> bool:
    """Text (no NUL bytes) starting with 'solid'."""
    return data.lstrip()[:5].lower() == b"solid" and b"\x00" not in data


def _stl_ascii(data: bytes) -> tuple[F64, I64, list[str]]:
    """Check ASCII STL structure, then parse it with trimesh."""
    text = data.decode("latin-1").lower()
    n_open = len(re.findall(r"(?m)^\s*facet\b", text))
    n_done = text.count("endfacet")
    lines = text.rstrip().splitlines()
    if not lines[-1].strip().startswith("endsolid"):
        raise MeshError(
            f"truncated ASCII STL: no closing 'endsolid' ({n_done} complete facets before the end)"
        )
    if n_open != n_done:
        raise MeshError(f"malformed ASCII STL: {n_open} 'facet' but {n_done} 'endfacet'")
    vertices, faces = _trimesh_arrays(data, "stl")
    if len(faces) != n_done:
        raise MeshError(f"malformed ASCII STL: {n_done} facets but {len(faces)} triangles parsed")
    return vertices, faces, []


# ---------------------------------------------------------------- other formats


def _parse_trimesh(data: bytes, fmt: str) -> tuple[F64, I64, list[str]]:
    """OBJ/PLY/OFF/GLB/GLTF bytes -> vertices, faces, notes (via trimesh)."""
    if fmt == "obj" and _OBJ_ZERO_INDEX.search(data):
        raise MeshError("invalid face index 0 in OBJ file (OBJ vertex indices start at 1)")
    vertices, faces = _trimesh_arrays(data, fmt)
    if len(faces) == 0:
        what = f"{len(vertices)} vertices but no triangles" if len(vertices) else "no geometry"
        raise MeshError(f"not a valid {fmt.upper()} file or empty mesh: {what}")
    return vertices, faces, []


def _trimesh_arrays(data: bytes, fmt: str) -> tuple[F64, I64]:
    """trimesh.load(process=False, force='mesh'), every failure turned into MeshError."""
    name = f"{fmt.upper()} file"
    if fmt == "gltf":
        _check_json(data)
    if fmt in _TEXT_FORMATS:
        data = _as_utf8(data)
    try:
        mesh = trimesh.load(io.BytesIO(data), file_type=fmt, process=False, force="mesh")
    except IndexError as exc:
        raise MeshError(f"invalid face index in {name}: {_one_line(exc)}") from exc
    except Exception as exc:
        raise MeshError(f"not a valid {name}: {type(exc).__name__}: {_one_line(exc)}") from exc
    if not isinstance(mesh, Trimesh):
        raise MeshError(f"not a valid {name}: holds a {type(mesh).__name__}, no triangle mesh")
    vertices = np.asarray(mesh.vertices, dtype=np.float64).reshape(-1, 3)
    return vertices, np.asarray(mesh.faces, dtype=np.int64).reshape(-1, 3)


def _as_utf8(data: bytes) -> bytes:
    """Text bytes as UTF-8 (non-UTF-8 read as Latin-1), so trimesh never guesses encodings."""
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1").encode("utf-8")
    return data


def _check_json(data: bytes) -> None:
    """Reject a .gltf that is not a JSON object or needs external buffer files."""
    try:
        doc = json.loads(data)
    except ValueError as exc:
        raise MeshError(f"not a valid GLTF file: not JSON ({_one_line(exc)})") from exc
    if not isinstance(doc, dict):
        raise MeshError("not a valid GLTF file: the JSON is not an object")
    buffers = doc.get("buffers")
    for buf in buffers if isinstance(buffers, list) else []:
        uri = buf.get("uri") if isinstance(buf, dict) else None
        if isinstance(uri, str) and not uri.startswith("data:"):
            raise MeshError(
                f"GLTF file needs the external buffer {uri[:80]!r}: upload a GLB or embed buffers"
            )


def _one_line(exc: BaseException, limit: int = 200) -> str:
    """An exception message on one line, at most `limit` characters."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


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
    signs, orient_notes = _orientation(v, f, counted, rep, degenerate)
    normals *= signs[:, None]
    dup = ~degenerate & ~counted
    normals[dup] = normals[rep[dup]]
    for a in (v, f, areas, normals, counted, rep):
        a.setflags(write=False)
    notes += _exclusion_notes(degenerate, counted) + orient_notes
    return Part(
        vertices=v,
        faces=f,
        areas=areas,
        normals=normals,
        counted=counted,
        representative=rep,
        id=mesh_id(v, f),
        warnings=tuple(notes),
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


# ---------------------------------------------------------------- orientation of closed shells


def _orientation(
    vertices: F64, faces: I64, counted: Bool, rep: I64, degenerate: Bool
) -> tuple[F64, list[str]]:
    """(M,) +-1 per face so closed shells point outward, and notes on what changed."""
    topo = _topology_ids(vertices)[faces]
    edges = _EdgeTable(topo, _in_topology(topo, faces, rep))
    stray = degenerate & edges.has_free_edge(len(faces))
    if stray.any():  # zero-area faces that close no T-junction would only open their shell
        edges = _EdgeTable(topo, (edges.used > 0) & ~stray)
    comp, n_comp = edges.shells(len(faces))
    shells = np.bincount(comp[counted], minlength=n_comp) > 0  # shells holding a counted face
    signs = np.ones(len(faces))
    open_c = edges.unbalanced(comp, signs, n_comp)
    fixable = shells & open_c & ~edges.nonmanifold(comp, n_comp)
    fixed = np.zeros(n_comp, dtype=bool)
    if fixable.any():
        trial = edges.propagate_signs(comp, fixable)
        fixed = fixable & ~edges.unbalanced(comp, trial, n_comp)
        signs = np.where(fixed[comp], trial, signs)
        open_c &= ~fixed
    vol = np.bincount(comp, _signed_volume_terms(vertices, faces) * signs * edges.used, n_comp)
    inverted = shells & ~open_c & (vol < 0)
    signs = np.where(inverted[comp], -signs, signs)
    n_closed = int((shells & ~open_c).sum())
    notes = _orientation_notes(int(shells.sum()), n_closed, int(fixed.sum()), int(inverted.sum()))
    return signs, notes


def _orientation_notes(n_shells: int, n_closed: int, n_fixed: int, n_inverted: int) -> list[str]:
    """Human-readable orientation report."""
    notes = []
    of_closed = f"of {n_closed} closed shells"
    if n_fixed:
        notes.append(f"inconsistent winding: normals made consistent on {n_fixed} {of_closed}")
    if n_inverted:
        notes.append(f"inverted winding: normals flipped on {n_inverted} {of_closed}")
    if n_closed < n_shells:
        n_open = n_shells - n_closed
        notes.append(f"{n_open} of {n_shells} shells are open: normals follow the file's winding")
    return notes


def _topology_ids(vertices: F64) -> I64:
    """(V,) vertex ids after merging vertices closer than TOPOLOGY_MERGE_REL * bbox diagonal."""
    n = len(vertices)
    radius = TOPOLOGY_MERGE_REL * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    pairs = cKDTree(vertices).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(n, dtype=np.int64)
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    labels: I64 = csgraph.connected_components(graph, directed=False)[1].astype(np.int64)
    return labels


def _in_topology(topo: I64, faces: I64, rep: I64) -> Bool:
    """(M,) faces that take part in edge balance: 3 distinct vertices, not a same-winding copy.

    Collinear zero-area faces stay in (they may close T-junctions); a duplicate with opposite
    winding stays in (two solids glued face to face), an identical copy does not.
    """
    distinct = (topo[:, 0] != topo[:, 1]) & (topo[:, 1] != topo[:, 2]) & (topo[:, 2] != topo[:, 0])
    copy = (rep != np.arange(len(faces))) & (faces == faces[rep]).all(axis=1)
    used: Bool = distinct & ~copy
    return used


def _signed_volume_terms(vertices: F64, faces: I64) -> F64:
    """(M,) signed tetrahedron volumes (mm^3) of each face with the bounding-box centre."""
    tri = vertices[faces] - 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    terms: F64 = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    return terms


class _EdgeTable:
    """Directed edges of the faces in the edge balance, grouped by undirected edge."""

    def __init__(self, topo: I64, used: Bool) -> None:
        """Build the (3m,) edge arrays from (M, 3) topological faces and the (M,) used mask."""
        self.used = used.astype(np.float64)
        ids = np.flatnonzero(used)
        f = topo[ids]
        a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
        b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
        self.face = np.tile(ids, 3)
        self.direction = np.where(a < b, 1.0, -1.0)
        key = np.minimum(a, b) * (int(topo.max()) + 1) + np.maximum(a, b)
        _, self.edge, self.count = np.unique(key, return_inverse=True, return_counts=True)
        self.order = np.argsort(self.edge, kind="stable")
        self.start = np.cumsum(self.count) - self.count

    def shells(self, n_faces: int) -> tuple[I64, int]:
        """(M,) label of the edge-connected shell of every face, and the number of labels."""
        group_first = self.face[self.order[self.start]][self.edge]
        graph = sparse.coo_matrix(
            (np.ones(len(self.face)), (self.face, group_first)), shape=(n_faces, n_faces)
        )
        n, labels = csgraph.connected_components(graph, directed=False)
        return labels.astype(np.int64), int(n)

    def has_free_edge(self, n_faces: int) -> Bool:
        """(M,) True for faces with an edge that no other face in the table uses."""
        free = self.face[self.count[self.edge] == 1]
        return np.bincount(free, minlength=n_faces) > 0

    def unbalanced(self, comp: I64, signs: F64, n_comp: int) -> Bool:
        """(n_comp,) True where some edge is not used equally often in both directions."""
        net = np.bincount(self.edge, self.direction * signs[self.face], len(self.count))
        bad = net[self.edge] != 0
        return np.bincount(comp[self.face[bad]], minlength=n_comp) > 0

    def nonmanifold(self, comp: I64, n_comp: int) -> Bool:
        """(n_comp,) True where some edge is not shared by exactly two faces."""
        bad = self.count[self.edge] != 2
        return np.bincount(comp[self.face[bad]], minlength=n_comp) > 0

    def propagate_signs(self, comp: I64, targets: Bool) -> F64:
        """(M,) +-1 making winding consistent in target (manifold) shells, by BFS over faces."""
        n_faces = len(comp)
        pairs = self.start[self.count == 2]
        first, second = self.order[pairs], self.order[pairs + 1]
        pick = targets[comp[self.face[first]]]
        first, second = first[pick], second[pick]
        f0, f1 = self.face[first], self.face[second]
        # weight 1: the two faces agree (opposite edge directions); 2: one must be flipped
        weight = np.where(self.direction[first] != self.direction[second], 1, 2)
        roots = f0[np.unique(comp[f0], return_index=True)[1]]
        rows = np.concatenate([f0, np.full(len(roots), n_faces)])
        cols = np.concatenate([f1, roots])
        vals = np.concatenate([weight, np.ones(len(roots), dtype=np.int64)])
        shape = (n_faces + 1, n_faces + 1)
        graph = sparse.coo_matrix((vals, (rows, cols)), shape=shape).tocsr()
        graph = (graph + graph.T).tocsr()
        bfs, pred = csgraph.breadth_first_order(graph, n_faces, directed=False)
        nodes = bfs[1:]
        parents = pred[nodes]
        rel = np.asarray(graph[nodes, parents]).ravel()
        s = [1.0] * (n_faces + 1)
        for node, parent, r in zip(nodes.tolist(), parents.tolist(), rel.tolist(), strict=True):
            s[node] = s[parent] if r == 1 else -s[parent]
        return np.asarray(s[:n_faces])
