"""Mesh bytes → raw (vertices, faces): own binary/ASCII STL checks, trimesh for the rest.

trimesh returns an *empty* mesh for most garbage without raising; every path here either
returns triangles or raises MeshError with one line naming the problem.
"""

from __future__ import annotations

import io
import json
import re

import numpy as np
import trimesh
from numpy.typing import NDArray
from trimesh import Trimesh

from vpp_core.errors import MeshError

_STL_HEADER_BYTES = 84
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("vertices", "<f4", (3, 3)), ("attr", "<u2")])
_STL_PLAUSIBLE_ABS = 1e15
"""Binary STL records with |float| above this (or non-finite) are treated as not STL data."""

_TEXT_FORMATS = ("stl", "obj", "off")  # "stl" reaches trimesh only as checked ASCII STL
_OBJ_ZERO_INDEX = re.compile(rb"(?m)^[ \t]*f[ \t](?:[^\n]*?[ \t])?-?0+(?=[/ \t\r\n]|$)")

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
Bool = NDArray[np.bool_]


def parse_mesh_bytes(data: bytes, fmt: str) -> tuple[F64, I64, list[str]]:
    """Raw (V, 3) vertices, (M, 3) faces and notes from bytes of a known format."""
    return _parse_stl(data) if fmt == "stl" else _parse_trimesh(data, fmt)


def announced_size(data: bytes, fmt: str) -> tuple[int, int]:
    """Cheap lower bounds (faces, vertices) of what parsing `data` would give; 0 when unknown.

    Read from headers (binary STL count, PLY `element`, OFF counts) or counted lines (ASCII STL
    `endfacet`, OBJ `f`/`v`), in well under a second for any upload, so a mesh over the limits
    is refused before trimesh spends seconds and gigabytes on it. Counted lines never exceed
    what the parse returns; a header may announce more than its body holds (a lying header),
    and such a file is refused as announced.
    """
    if fmt == "stl":
        return _stl_announced(data), 0
    if fmt == "obj":
        return _line_count(data, b"f"), _line_count(data, b"v")
    if fmt == "ply":
        return _ply_element(data, b"face"), _ply_element(data, b"vertex")
    if fmt == "off":
        return _off_counts(data)
    return 0, 0


def _stl_announced(data: bytes) -> int:
    """Triangles a binary STL's bytes hold (at most its header count), or ASCII `endfacet`s."""
    n = len(data)
    count = int(np.frombuffer(data, "<u4", 1, 80)[0]) if n >= _STL_HEADER_BYTES else 0
    held = max(n - _STL_HEADER_BYTES, 0) // _STL_RECORD.itemsize
    if n >= _STL_HEADER_BYTES and _STL_HEADER_BYTES + _STL_RECORD.itemsize * count == n:
        return count
    if _looks_like_ascii_stl(data):
        return data.count(b"endfacet") + data.count(b"ENDFACET")
    return min(count, held)


def _line_count(data: bytes, keyword: bytes) -> int:
    """Lines starting with `keyword` and a space or tab (an OBJ face or vertex)."""
    head = data.startswith(keyword + b" ") or data.startswith(keyword + b"\t")
    return int(head) + sum(data.count(b"\n" + keyword + sep) for sep in (b" ", b"\t"))


_PLY_HEADER_BYTES = 1 << 16
"""Where a PLY header must have ended."""


def _ply_element(data: bytes, name: bytes) -> int:
    """The count of PLY element `name` in the header (0 when absent or unreadable)."""
    header = data[:_PLY_HEADER_BYTES].split(b"end_header", 1)[0]
    found = re.search(rb"(?m)^[ \t]*element[ \t]+" + name + rb"[ \t]+(\d{1,19})\b", header)
    return int(found.group(1)) if found else 0


def _off_counts(data: bytes) -> tuple[int, int]:
    """(faces, vertices) of an OFF header `OFF [nv nf ne]`, comments skipped; (0, 0) unreadable."""
    text = data[:_PLY_HEADER_BYTES].decode("latin-1")
    words = re.sub(r"#[^\n]*", " ", text).split()
    if not words or not words[0].upper().endswith("OFF"):
        return 0, 0
    counts = words[1:3]
    if len(counts) < 2 or not all(w.isdigit() for w in counts):
        return 0, 0
    return int(counts[1]), int(counts[0])


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


_PLY_FACE = np.dtype([("n", "u1"), ("v", "<i4", (3,))])


def ply_bytes(vertices: F64, faces: I64, comment: str = "") -> bytes:
    """Binary little-endian PLY of (V, 3) float64 vertices and (M, 3) faces, exact: vertices
    as doubles, faces in their order and winding (so it loads back to the same mesh id)."""
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {comment}"] if comment else []
    header += [f"element vertex {len(vertices)}"]
    header += [f"property double {axis}" for axis in "xyz"]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    records = np.empty(len(faces), dtype=_PLY_FACE)
    records["n"], records["v"] = 3, faces
    body = np.ascontiguousarray(vertices, dtype="<f8").tobytes() + records.tobytes()
    return ("\n".join([*header, "end_header"]) + "\n").encode() + body
